"""The first pass's side: silhouette IoU of an RGB network on synthetic whole photos at several input sides.

The pipeline's first pass runs the network on the whole photo padded to a square and resized to the side the
network was trained at, where the foot is far smaller than in its training crops. This benchmark renders whole
photos with our generator (farther views, the other foot beside the first, views down the legs; seed 77, apart
from every training and test seed) and prints the mean IoU, precision and recall of the silhouette (>= 0.5)
with the rendered foot mask per side, beside the side the pipeline uses.

Measured (docs/cues.md): on renders a larger side helps the pretrained RGB network (shipped: IoU 0.72 at 128 px,
0.82 at 256); on the real photos of ``footmesh eval real`` it did not (its first training run: 0.43 at 128, 0.39
at 256, more of the shins taken for foot), so the pipeline keeps the side the network was trained at.

Run: ``python benchmarks/bench_first_pass.py [--weights W] [--photos N]`` (or ``python -m benchmarks
bench_first_pass``).
"""

from __future__ import annotations

import argparse

import numpy as np

SIDES = (128, 192, 256, 320)
SEED = 77


def render_whole_photos(count: int) -> list[dict[str, np.ndarray]]:
    """``count`` synthetic whole photos (384 px) with their foot masks and sides."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    config = SynthConfig(size=384, other_foot_fraction=0.6, first_person_fraction=0.5, distance_mm=(550.0, 1000.0))
    renderer = Renderer(config)
    return [renderer.render(SEED, i) for i in range(count)]


def score_sides(weights: str | None, photos: list[dict[str, np.ndarray]]) -> dict[int, tuple[float, float, float]]:
    """Mean (IoU, precision, recall) of the whole-photo silhouette per first-pass side."""
    from footmesh.eval.real import mask_scores
    from footmesh.pipeline import whole_photo_cues

    table = {}
    for side in SIDES:
        scores = []
        for photo in photos:
            predicted = whole_photo_cues("rgb", photo["rgb"], None, weights, side).silhouette >= 0.5
            scores.append(mask_scores(predicted, photo["silhouette"] >= 0.5))
        table[side] = tuple(float(v) for v in np.mean(scores, axis=0))
    return table


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--weights", help="an RGB 2D-cues weights file (default: the shipped one)")
    parser.add_argument("--photos", type=int, default=120, help="synthetic whole photos to score (default 120)")
    parser.add_argument("--quick", action="store_true", help="24 photos")
    args = parser.parse_args(argv)
    from footmesh.cues.weights import network_for

    photos = render_whole_photos(24 if args.quick else args.photos)
    table = score_sides(args.weights, photos)
    config = network_for("rgb", args.weights)[1]
    print(
        f"first pass on {len(photos)} synthetic whole photos, RGB network ({config.encoder}, trained and used "
        f"at {config.image_size} px)"
    )
    print(f"  {'side px':>8}  {'IoU':>6}  {'precision':>9}  {'recall':>6}")
    for side, (iou, precision, recall) in table.items():
        mark = "  <- used" if side == config.image_size else ""
        print(f"  {side:>8}  {iou:6.3f}  {precision:9.3f}  {recall:6.3f}{mark}")


if __name__ == "__main__":
    main()
