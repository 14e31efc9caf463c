"""Reference-object detection on synthetic phone photos: how often each object is found, and how good its scale is.

Photos are rendered like ``footmesh eval measure``'s ``rgb_ref`` mode (same seed, same cycle A4 sheet, card,
marker). Each is given to ``detect_reference`` with the true foot silhouette (dilated, as the pipeline does with
the predicted one) as the excluded region. The scale error is that of the camera-to-floor distance along the
optical axis through the object, the error every millimetre measured through the floor plane inherits.

Run: ``python benchmarks/bench_reference.py [--n 60] [--size 640] [--seed 4242]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import cv2
import numpy as np

KINDS = ("a4", "card", "marker")


def floor_distance_mm(normal: np.ndarray, point: np.ndarray) -> float:
    """Distance from the camera centre to the plane through ``point`` with ``normal`` (camera frame, mm)."""
    return float(abs(normal @ point) / np.linalg.norm(normal))


def run(n: int, size: int, seed: int) -> dict[str, list[dict]]:
    """One record per photo and kind: found, relative scale error, visible corners, seconds."""
    from footmesh.cues.reference import detect_reference
    from footmesh.eval.measure import MODES
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    records: dict[str, list[dict]] = {k: [] for k in KINDS}
    renderers = {k: Renderer(SynthConfig(size=size, reference=k, frame_reference=True)) for k in KINDS}
    for i in range(n):
        kind = KINDS[i % 3]
        sample = renderers[kind].render(seed + MODES.index("rgb_ref"), i)
        corners = sample["ref_corners3d"].astype(np.float64)
        true_normal = np.cross(corners[1] - corners[0], corners[3] - corners[0])
        true_distance = floor_distance_mm(true_normal, corners[0])
        exclude = cv2.dilate(sample["silhouette"].astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
        t = time.perf_counter()
        found = detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude)
        rec = {
            "found": found is not None and found.kind == kind,
            "wrong_kind": found is not None and found.kind != kind,
            "corners_visible": int(sample["ref_corners_visible"].sum()),
            "seconds": time.perf_counter() - t,
            "rel_error": float("nan"),
        }
        if found is not None:
            pose = found.cam_from_floor
            rec["rel_error"] = floor_distance_mm(pose[:3, 2], pose[:3, 3]) / true_distance - 1.0
        records[kind].append(rec)
    return records


def format_table(records: dict[str, list[dict]]) -> str:
    """Markdown table: per kind, found / photos, found among photos with all 4 corners visible, scale error."""
    lines = [
        "| object | photos | found | found, 4 corners visible | wrong kind | scale error % median (max) | ms |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for kind, recs in records.items():
        whole = [r for r in recs if r["corners_visible"] == 4]
        errors = [abs(r["rel_error"]) * 100 for r in recs if r["found"]]
        err = f"{statistics.median(errors):.2f} ({max(errors):.2f})" if errors else "-"
        ms = 1000 * statistics.median(r["seconds"] for r in recs)
        lines.append(
            f"| {kind} | {len(recs)} | {sum(r['found'] for r in recs)} | "
            f"{sum(r['found'] for r in whole)} / {len(whole)} | {sum(r['wrong_kind'] for r in recs)} | {err} | "
            f"{ms:.0f} |"
        )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=60, help="photos (cycling A4, card, marker)")
    parser.add_argument("--size", type=int, default=640, help="photo side, px")
    parser.add_argument("--seed", type=int, default=4242, help="seed of the photos (eval measure's default)")
    args = parser.parse_args()
    print(format_table(run(args.n, args.size, args.seed)))


if __name__ == "__main__":
    main()
