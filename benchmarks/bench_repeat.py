"""Repeatability: the same photo measured again after changes no one would call another photo.

Two photos of the same foot must agree within 3 mm (issue 19). Before two photos can, one photo must agree with
itself: each real photo (``../shared/real/a4/photos`` by default, no ground truth there) is measured as it is and
after small changes a phone or a messenger makes every day: sensor noise (SD 8 of 255), half the resolution, JPEG
at quality 60, a warm cast (an indoor lamp: blue x0.75, green x0.9), a cool one (shade: red x0.85), and the phone
held sideways (the photo turned 90 deg either way, as a phone that wrote no orientation leaves it). The table
gives each photo's lengths and their spread (largest minus smallest, over the versions with millimetres); the
summary the median spread, the mean SD of a photo's versions and the photos whose every version lies within 3 mm.
With ``--renders N`` the same on ``N`` renders of ``--views`` (RGB + A4 sheet, K.json given), with the true length
beside them.

Run: ``python benchmarks/bench_repeat.py [--photos DIR] [--renders 8] [--views front] [--versions NAME ...]``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from footmesh.geometry.camera import Camera

ROOT = Path(__file__).resolve().parents[1]
REAL_PHOTOS = ROOT / ".." / "shared" / "real" / "a4" / "photos"
WITHIN_MM = 3.0
"""Issue 19's target for two photos of the same foot."""


Version = Callable[[np.ndarray, Camera | None], tuple[np.ndarray, Camera | None]]
"""A photo's change: (BGR uint8, its camera or None) -> the changed photo and its camera."""


def _pixels(change: Callable[[np.ndarray], np.ndarray]) -> Version:
    return lambda bgr, camera: (change(bgr), camera)


def _noise(bgr: np.ndarray) -> np.ndarray:
    rng = np.random.default_rng(0)
    return np.clip(bgr + rng.normal(0.0, 8.0, bgr.shape), 0, 255).astype(np.uint8)


def _half(bgr: np.ndarray, camera: Camera | None) -> tuple[np.ndarray, Camera | None]:
    half = cv2.resize(bgr, (bgr.shape[1] // 2, bgr.shape[0] // 2), interpolation=cv2.INTER_AREA)
    return half, None if camera is None else camera.resized(half.shape[1], half.shape[0])


def _jpeg(bgr: np.ndarray) -> np.ndarray:
    return cv2.imdecode(cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 60])[1], cv2.IMREAD_COLOR)


def _cast(gains_bgr: tuple[float, float, float]) -> Version:
    return _pixels(lambda bgr: np.clip(bgr * np.array(gains_bgr), 0, 255).astype(np.uint8))


def _turned(quarter_turns: int) -> Version:
    def turn(bgr: np.ndarray, camera: Camera | None) -> tuple[np.ndarray, Camera | None]:
        turned = np.ascontiguousarray(np.rot90(bgr, quarter_turns))
        return turned, None if camera is None else camera.turned(quarter_turns)

    return turn


VERSIONS: dict[str, Version] = {
    "as taken": _pixels(lambda bgr: bgr),
    "noise": _pixels(_noise),
    "half size": _half,
    "JPEG 60": _pixels(_jpeg),
    "warm": _cast((0.75, 0.9, 1.0)),
    "cool": _cast((1.0, 1.0, 0.85)),
    "turned left": _turned(1),
    "turned right": _turned(3),
}
"""Each version of a photo."""


def measure_versions(
    bgr: np.ndarray, folder: Path, K: np.ndarray | None = None, versions: list[str] | None = None
) -> dict[str, float | None]:
    """Length (mm; None where unscaled or refused) of each version of one photo (``versions``: their names, None:
    all); ``K``: (3, 3) intrinsics of the photo as it is (changed with it, given as K.json), or None (the photo's
    own guess)."""
    from footmesh.errors import Refusal
    from footmesh.eval.measure import write_inputs
    from footmesh.pipeline import measure_photo

    camera = None if K is None else Camera(np.asarray(K, np.float64), bgr.shape[1], bgr.shape[0])
    lengths: dict[str, float | None] = {}
    for index, name in enumerate(versions or list(VERSIONS)):
        image, changed = VERSIONS[name](bgr, camera)
        if changed is None:
            path, k_path = folder / f"{index}.png", None
            cv2.imwrite(str(path), image)
        else:
            paths = write_inputs({"rgb": image[..., ::-1], "K": changed.K}, folder / str(index), with_depth=False)
            path, k_path = paths["image"], paths["intrinsics"]
        try:
            result = measure_photo(path, folder / f"out{index}", intrinsics=k_path)
        except Refusal:
            lengths[name] = None
            continue
        lengths[name] = float(result["measurements"]["stick_length"]["value_mm"]) if result["scaled"] else None
    return lengths


def spread(lengths: dict[str, float | None]) -> float | None:
    """Largest minus smallest of the lengths measured (None where fewer than two were)."""
    measured = [v for v in lengths.values() if v is not None]
    return max(measured) - min(measured) if len(measured) > 1 else None


def format_rows(rows: list[tuple[str, dict[str, float | None], float | None]]) -> str:
    """Markdown table of (photo, lengths per version, true length or None) and a summary line."""
    names = list(rows[0][1]) if rows else []
    lines = [
        "| photo | " + " | ".join(names) + " | spread mm | truth mm |",
        "|---|" + "---:|" * (len(names) + 2),
    ]
    spreads = []
    for photo, lengths, truth in rows:
        s = spread(lengths)
        spreads.append(s)
        cells = [f"{lengths[n]:.1f}" if lengths[n] is not None else "-" for n in names]
        lines.append(
            f"| {photo} | " + " | ".join(cells) + f" | {'-' if s is None else f'{s:.1f}'} | "
            f"{'-' if truth is None else f'{truth:.1f}'} |"
        )
    known = [s for s in spreads if s is not None]
    median = f"{statistics.median(known):.1f}" if known else "-"
    within = sum(s <= WITHIN_MM for s in known)
    # one odd version sets a spread; the SD over all of a photo's versions says how far they scatter as a whole
    measured = ([v for v in lengths.values() if v is not None] for _, lengths, _ in rows)
    sds = [statistics.pstdev(m) for m in measured if len(m) > 1]
    mean_sd = f"{statistics.mean(sds):.1f}" if sds else "-"
    lines.append(
        f"\nmedian spread {median} mm; mean SD over a photo's versions {mean_sd} mm; "
        f"every version within {WITHIN_MM:.0f} mm: {within} of {len(rows)}"
    )
    if all(truth is not None for _, _, truth in rows):
        errors = {n: [abs(lengths[n] - truth) for _, lengths, truth in rows if lengths[n] is not None] for n in names}
        lines.append(
            "length error (mean |error| mm, photos with mm): "
            + "; ".join(f"{n} {statistics.mean(e):.2f} ({len(e)})" if e else f"{n} - (0)" for n, e in errors.items())
        )
    return "\n".join(lines)


def real_rows(
    photos: Path, versions: list[str] | None = None
) -> list[tuple[str, dict[str, float | None], float | None]]:
    """One row per photo in the folder (``versions``: see ``measure_versions``)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for index, path in enumerate(sorted(p for p in photos.iterdir() if p.is_file())):
            folder = Path(tmp) / str(index)
            folder.mkdir()
            rows.append((path.name, measure_versions(cv2.imread(str(path)), folder, None, versions), None))
    return rows


def render_rows(
    n: int, views: str, seed: int, versions: list[str] | None = None
) -> list[tuple[str, dict[str, float | None], float | None]]:
    """One row per render of ``views`` with an A4 sheet, its K.json given (``versions``: see ``measure_versions``)."""
    from footmesh.eval.measure import true_measurements
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import view_config

    renderer = Renderer(view_config(views, size=640, reference="a4"))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(n):
            sample = renderer.render(seed, i)
            side = "right" if int(sample["side"]) else "left"
            folder = Path(tmp) / str(i)
            folder.mkdir()
            bgr = cv2.cvtColor(sample["rgb"], cv2.COLOR_RGB2BGR)
            truth = true_measurements(sample["shape"], side)["stick_length"]
            rows.append((f"{views} {i}", measure_versions(bgr, folder, sample["K"], versions), truth))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--photos", type=Path, default=REAL_PHOTOS, help="folder of real photos")
    parser.add_argument("--renders", type=int, default=0, help="renders of --views measured the same way")
    parser.add_argument("--views", default="front", help="eval measure's view set of the renders")
    parser.add_argument("--seed", type=int, default=4242, help="seed of the renders")
    parser.add_argument("--versions", nargs="+", choices=list(VERSIONS), help="only these versions (default: all)")
    args = parser.parse_args()
    if args.photos.is_dir():
        print(f"real photos ({args.photos}):\n")
        print(format_rows(real_rows(args.photos, args.versions)))
    else:
        print(f"(real photos not found at {args.photos})")
    if args.renders:
        print(f"\nrenders ({args.views}, seed {args.seed}, K.json given):\n")
        print(format_rows(render_rows(args.renders, args.views, args.seed, args.versions)))


if __name__ == "__main__":
    main()
