"""Reference-object detection on synthetic phone photos: how often each object is found, and how good its scale is.

Photos are rendered like ``footmesh eval measure``'s ``rgb_ref`` mode (same seed, same cycle A4 sheet, card,
marker), from random views (``random``: any side and height) and from each named view set of ``--views`` (``eval
measure --views``: ``front``, the way most real photos of a foot on a sheet are taken; ``ood``, unlike the
training renders). Each is given to ``detect_reference`` with the true foot silhouette (dilated, as the
pipeline does with the predicted one) as the excluded region. The scale error is that of the camera-to-floor
distance along the optical axis through the object, the error every millimetre measured through the floor plane
inherits.

Real photos beside them: the seven phone photos of a foot on an A4 sheet in ``../shared/real/a4/photos``, against
their corners marked by hand (``tests/data/real_a4_corners.json``), searched the way ``footmesh measure`` does
(``footmesh.eval.real_reference``): found, the corners' error (px at 1600 on the photo's longer side) and the
error of the camera-to-sheet distance against the marked corners' pose; the same photos turned by quarter
turns (a phone held sideways or upside down), where the search must find the same sheet; and cropped so that the
photo's edge cuts the sheet (a photo framed on the foot), where its far corners are placed from its other sides,
or cuts off one corner (a sheet lying askew), which is placed where its two sides meet.

A4 and US letter sheets told apart (by their side ratio, 1.414 and 1.294): photos of each searched for every kind,
as ``footmesh measure`` does by default, and for that sheet alone (``--reference``), as the user who names it.

Run: ``python benchmarks/bench_reference.py [--n 60] [--n-sheets 30] [--size 640] [--seed 4242] [--views random front
ood] [--real DIR]``.
"""

from __future__ import annotations

import argparse
import re
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

KINDS = ("a4", "card", "marker")
ROOT = Path(__file__).resolve().parents[1]
REAL_PHOTOS = ROOT / ".." / "shared" / "real" / "a4" / "photos"
REAL_CORNERS = ROOT / "tests" / "data" / "real_a4_corners.json"
NO_REFERENCE_PHOTOS = ROOT / ".." / "shared" / "real" / "rafiansyah" / "photos"
"""Real photos of feet on patterned tiles with no reference object in any: whatever is found is false."""


def floor_distance_mm(normal: np.ndarray, point: np.ndarray) -> float:
    """Distance from the camera centre to the plane through ``point`` with ``normal`` (camera frame, mm)."""
    return float(abs(normal @ point) / np.linalg.norm(normal))


def _config(views: str, size: int, kind: str):
    """The renderer's settings for ``views`` ("random" or a name of ``synth.scene.VIEW_PRESETS``) and object."""
    from footmesh.synth.scene import SynthConfig, view_config

    if views == "random":
        return SynthConfig(size=size, reference=kind, frame_reference=True)
    return view_config(views, size=size, reference=kind)


def _searched(sample: dict, kinds: tuple[str, ...] | None = None, focal_log_sd: float = 0.0) -> dict:
    """The detector on one rendered photo (``kinds``: those looked for; None: every kind; ``focal_log_sd``: how
    well its focal length is known), as the pipeline calls it: the kind found (None), whether it was assumed
    (``kind_assumed``), the relative error of its camera-to-floor distance, visible corners, seconds."""
    from footmesh import references
    from footmesh.cues.reference import detect_reference

    corners = sample["ref_corners3d"].astype(np.float64)
    true_normal = np.cross(corners[1] - corners[0], corners[3] - corners[0])
    true_distance = floor_distance_mm(true_normal, corners[0])
    exclude = cv2.dilate(sample["silhouette"].astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    t = time.perf_counter()
    found = detect_reference(
        sample["rgb"], sample["K"], kinds or references.NAMES, exclude_mask=exclude, focal_prior_log_sd=focal_log_sd
    )
    rec = {
        "kind": None if found is None else found.kind,
        "assumed": found is not None and found.kind_assumed,
        "corners_visible": int(sample["ref_corners_visible"].sum()),
        "seconds": time.perf_counter() - t,
        "rel_error": float("nan"),
    }
    if found is not None:
        pose = found.cam_from_floor
        rec["rel_error"] = floor_distance_mm(pose[:3, 2], pose[:3, 3]) / true_distance - 1.0
    return rec


def run(n: int, size: int, seed: int, views: str = "random") -> dict[str, list[dict]]:
    """One record per photo and kind: found, relative scale error, visible corners, seconds; ``views``: "random" or
    a name of ``synth.scene.VIEW_PRESETS``."""
    from footmesh.eval.measure import MODES
    from footmesh.synth.render import Renderer

    records: dict[str, list[dict]] = {k: [] for k in KINDS}
    renderers = {k: Renderer(_config(views, size, k)) for k in KINDS}
    for i in range(n):
        kind = KINDS[i % 3]
        rec = _searched(renderers[kind].render(seed + MODES.index("rgb_ref"), i))
        rec |= {"found": rec["kind"] == kind, "wrong_kind": rec["kind"] not in (None, kind)}
        records[kind].append(rec)
    return records


def format_table(records_by_views: dict[str, dict[str, list[dict]]]) -> str:
    """Markdown table: per view set and kind, found / photos, found among photos with all 4 corners visible,
    scale error."""
    lines = [
        "| views | object | photos | found | found, 4 corners visible | wrong kind | scale error % median (max) | ms |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    rows = [(views, kind, recs) for views, records in records_by_views.items() for kind, recs in records.items()]
    for views, kind, recs in rows:
        whole = [r for r in recs if r["corners_visible"] == 4]
        errors = [abs(r["rel_error"]) * 100 for r in recs if r["found"]]
        err = f"{statistics.median(errors):.2f} ({max(errors):.2f})" if errors else "-"
        ms = 1000 * statistics.median(r["seconds"] for r in recs)
        lines.append(
            f"| {views} | {kind} | {len(recs)} | {sum(r['found'] for r in recs)} | "
            f"{sum(r['found'] for r in whole)} / {len(whole)} | {sum(r['wrong_kind'] for r in recs)} | {err} | "
            f"{ms:.0f} |"
        )
    return "\n".join(lines)


SHEETS = ("a4", "letter")


EXIF_FOCAL_LOG_SD = 0.1
"""The focal length's SD (log) where it comes from a photo's EXIF (``MeasureConfig.focal_prior_log_sd``)."""


def run_sheets(n: int, size: int, seed: int, views: str) -> list[tuple[str, str, str, list[dict]]]:
    """(sheet, searched, focal length, records) of ``n`` photos of each sheet (``SHEETS``) searched for every kind
    ("any") and for that sheet alone (as ``footmesh measure --reference`` names it), with the focal length known
    ("K.json") and known as EXIF's is ("EXIF", ``EXIF_FOCAL_LOG_SD``)."""
    from footmesh.eval.measure import MODES
    from footmesh.synth.render import Renderer

    rows = []
    for sheet in SHEETS:
        renderer = Renderer(_config(views, size, sheet))
        samples = [renderer.render(seed + MODES.index("rgb_ref"), i) for i in range(n)]
        for searched in ("any", sheet):
            kinds = None if searched == "any" else (sheet,)
            for focal, log_sd in (("K.json", 0.0), ("EXIF", EXIF_FOCAL_LOG_SD)):
                rows.append((sheet, searched, focal, [_searched(s, kinds, log_sd) for s in samples]))
    return rows


def format_sheets_table(rows_by_views: dict[str, list[tuple[str, str, str, list[dict]]]]) -> str:
    """Markdown table of ``run_sheets``: what each sheet was found as (assumed: completed or cut, its proportions
    not seen), and the scale errors of the right and of the wrong names."""
    lines = [
        "| views | sheet | searched for | focal length | photos | as A4 (assumed) | as letter (assumed) | none | "
        "scale error % median (max): right kind | wrong kind |",
        "|---|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for views, rows in rows_by_views.items():
        for sheet, searched, focal, recs in rows:
            right = [abs(r["rel_error"]) * 100 for r in recs if r["kind"] == sheet]
            wrong = [100 * r["rel_error"] for r in recs if r["kind"] is not None and r["kind"] != sheet]
            cells = [
                f"{sum(r['kind'] == k for r in recs)} ({sum(r['kind'] == k and r['assumed'] for r in recs)})"
                for k in SHEETS
            ]
            right_cell = f"{statistics.median(right):.2f} ({max(right):.2f})" if right else "-"
            wrong_cell = ", ".join(f"{e:+.1f}" for e in wrong) or "-"
            lines.append(
                f"| {views} | {sheet} | {searched} | {focal} | {len(recs)} | {cells[0]} | {cells[1]} | "
                f"{sum(r['kind'] is None for r in recs)} | {right_cell} | {wrong_cell} |"
            )
    return "\n".join(lines)


def format_real_table(photos: Path) -> str:
    """Markdown table of the detector on the real A4 photos, one row per photo and a summary row."""
    from footmesh.eval.real_reference import score_set

    scores = score_set(photos, REAL_CORNERS)
    lines = [
        "| real photo | found | corner error px at 1600, median (max) | distance error % (its SD) | ms |",
        "|---|---:|---:|---:|---:|",
    ]
    for s in scores:
        if not s.found:
            lines.append(f"| {s.photo} | no: {s.rejected} | - | - | {1000 * s.seconds:.0f} |")
            continue
        err = np.array(s.corner_errors_px)
        lines.append(
            f"| {s.photo} | yes | {np.median(err):.1f} ({err.max():.1f}) | "
            f"{100 * s.centre_distance_error:+.2f} ({100 * s.scale_rel_sd:.2f}) | {1000 * s.seconds:.0f} |"
        )
    found = [s for s in scores if s.found]
    if found:
        worst = [max(s.corner_errors_px) for s in found]
        distance = [abs(s.centre_distance_error) * 100 for s in found]
        lines.append(
            f"| **all** | **{len(found)} / {len(scores)}** | max per photo: median {statistics.median(worst):.1f} | "
            f"abs median {statistics.median(distance):.2f} (max {max(distance):.2f}) | "
            f"{1000 * statistics.median(s.seconds for s in scores):.0f} |"
        )
    return "\n".join(lines)


def format_turned_table(photos: Path) -> str:
    """Markdown table of the detector on the real A4 photos turned 0, 90, 180 and 270 deg: per photo the worst
    corner of each turn and the distance errors' range."""
    import tempfile

    from footmesh.eval.real_reference import read_corners, score_turned

    marked = read_corners(REAL_CORNERS)
    lines = [
        "| real photo turned | found | worst corner px at 1600: 0 / 90 / 180 / 270 deg | distance error % range |",
        "|---|---:|---:|---:|",
    ]
    worst_all, found_all = [], 0
    with tempfile.TemporaryDirectory() as tmp:
        for name in sorted(marked):
            scores = [score_turned(photos / name, marked[name], k, tmp) for k in range(4)]
            found = [s for s in scores if s.found]
            found_all += len(found)
            worst = [max(s.corner_errors_px) if s.found else float("nan") for s in scores]
            worst_all += [w for w in worst if np.isfinite(w)]
            distance = [100 * s.centre_distance_error for s in found]
            spread = f"{min(distance):+.2f} to {max(distance):+.2f}" if distance else "-"
            cells = " / ".join("-" if not np.isfinite(w) else f"{w:.1f}" for w in worst)
            lines.append(f"| {name} | {len(found)} / 4 | {cells} | {spread} |")
    lines.append(
        f"| **all** | **{found_all} / {4 * len(marked)}** | median {statistics.median(worst_all):.1f}, "
        f"max {max(worst_all):.1f} | |"
    )
    return "\n".join(lines)


CROP_DEPTHS = (0.25, 0.45)
"""How far across the sheet the crops' edges lie (``score_cropped``'s depth)."""


MIN_CORNER_GAP_PX = 8.0
"""A crop cutting off one corner of a sheet is scored where that corner lies at least this far (px at 1600) beyond
the next corner across the crop's edge."""


def _corner_gap_px(marked_px: np.ndarray, edge: str) -> float:
    """How far (px) the sheet's corner nearest the photo's ``edge`` lies beyond the next nearest, across it."""
    axis = 1 if edge in ("top", "bottom") else 0
    signed = marked_px[:, axis] if edge in ("top", "left") else -marked_px[:, axis]
    first, second = np.sort(signed)[:2]
    return float(second - first)


def format_cropped_table(photos: Path, corners_cut: int = 2) -> str:
    """Markdown table of the detector on the real A4 photos cropped so that one edge of the photo cuts the sheet
    and leaves ``corners_cut`` of its corners beyond it (each edge, ``CROP_DEPTHS``;
    ``eval.real_reference.score_cropped``): per photo how many were found (a crop that leaves no foot, puts the
    principal point outside it or, for one corner, cuts the sheet where its corners lie within ``MIN_CORNER_GAP_PX``
    of each other across the edge, is not scored), the worst corner (all four, those beyond the crop too) and the
    distance error against its SD; and the reasons the others were not taken."""
    import collections
    import tempfile

    from footmesh.errors import Refusal
    from footmesh.eval.real_reference import read_corners, score_cropped

    marked = read_corners(REAL_CORNERS)
    cut = "the sheet" if corners_cut == 2 else "one corner of the sheet"
    lines = [
        f"| real photo cropped across {cut} | found / scored | worst corner px at 1600 | distance error % (SD) |",
        "|---|---:|---:|---:|",
    ]
    reasons: collections.Counter[str] = collections.Counter()
    found_all = scored_all = 0
    with tempfile.TemporaryDirectory() as tmp:
        for name in sorted(marked):
            scores = []
            for edge in ("top", "bottom", "left", "right"):
                if corners_cut == 1 and _corner_gap_px(marked[name], edge) < MIN_CORNER_GAP_PX:
                    continue  # the sheet lies square to that edge: no crop cuts off one corner alone
                for depth in CROP_DEPTHS:
                    try:
                        scores.append(score_cropped(photos / name, marked[name], edge, depth, tmp, corners_cut))
                    except (Refusal, ValueError):  # no foot left in the crop, or its principal point outside it
                        continue
            found = [s for s in scores if s.found]
            reasons.update(re.sub(r"\d+ %", "N %", s.rejected.split(" (")[0]) for s in scores if s.rejected)
            found_all, scored_all = found_all + len(found), scored_all + len(scores)
            worst = ", ".join(f"{max(s.corner_errors_px):.1f}" for s in found) or "-"
            errors = ", ".join(f"{100 * s.centre_distance_error:+.2f} ({100 * s.scale_rel_sd:.2f})" for s in found)
            lines.append(f"| {name} | {len(found)} / {len(scores)} | {worst} | {errors or '-'} |")
    lines.append(f"| **all** | **{found_all} / {scored_all}** | | |")
    lines.append("")
    lines.append("Not taken, by reason: " + "; ".join(f"{n} x {why}" for why, n in reasons.most_common()))
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=60, help="photos (cycling A4, card, marker)")
    parser.add_argument("--n-sheets", type=int, default=30, help="photos of each sheet (A4, letter) per view set")
    parser.add_argument("--size", type=int, default=640, help="photo side, px")
    parser.add_argument("--seed", type=int, default=4242, help="seed of the photos (eval measure's default)")
    parser.add_argument(
        "--views",
        nargs="+",
        default=["random", "front", "ood"],
        help="view sets: random and names of eval measure's --views (guided, front, ood, ...)",
    )
    parser.add_argument("--real", type=Path, default=REAL_PHOTOS, help="folder of the real A4 photos")
    parser.add_argument(
        "--no-reference", type=Path, default=NO_REFERENCE_PHOTOS, help="folder of real photos without any reference"
    )
    args = parser.parse_args()
    print(format_table({views: run(args.n, args.size, args.seed, views) for views in args.views}))
    print()
    print(format_sheets_table({views: run_sheets(args.n_sheets, args.size, args.seed, views) for views in args.views}))
    print()
    if args.real.is_dir():
        print(format_real_table(args.real))
        print()
        print(format_turned_table(args.real))
        print()
        print(format_cropped_table(args.real))
        print()
        print(format_cropped_table(args.real, corners_cut=1))
    else:
        print(f"(real photos not found at {args.real}: the synthetic table only)")
    if args.no_reference.is_dir():
        from footmesh.eval.real_reference import false_references

        photos = [p for p in args.no_reference.iterdir() if p.is_file()]
        false = false_references(args.no_reference)
        print(f"\nreal photos without any reference object ({args.no_reference}): {len(false)} of {len(photos)} give a"
              f" false one: {', '.join(f'{name} ({kind})' for name, kind in false) or 'none'}")  # fmt: skip


if __name__ == "__main__":
    main()
