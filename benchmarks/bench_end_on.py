"""How the length error grows as a foot is seen more end-on, per input: where the end-on refusal belongs.

Photos are rendered like ``footmesh eval measure --views sweep`` (flat feet seen from any side, straight behind
the heel included, and any height from just above the floor to straight down; the reference object in view) and
measured with the end-on refusals turned off (``max_rgb_end_on``, ``max_rgbd_end_on`` and ``max_depth_end_on``
at 1). Each photo's true view angle is the angle between the foot's heel-to-toe axis and the line of sight to its
middle (0 deg: end-on; 90: seen square to its length, from the side or from above).
The table gives, per band of that angle, the photos, the share measured (any other refusal still applies), the
length MAE and the share within half a shoe size (4.23 mm); then the angle below which every band's MAE passes
half a size (from 0 deg up to the first band within it): the end-on limit the evidence supports. The
pipeline's limits (``MeasureConfig``) apply to the fitted pose's angle, which is close to the true one where the
fit is right.

Run: ``python benchmarks/bench_end_on.py [--n 90] [--modes rgb_ref,rgbd,depth] [--size 640] [--seed 4242]
[--views sweep|front]`` (``front``: the views most real photos of a foot on a sheet are taken from).
Measured (2026-12-04, n 90 each): the table in docs/measure.md; with depth the limit the errors support is 40 deg.
"""

from __future__ import annotations

import argparse
import math

import numpy as np

BANDS_DEG = (0.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0)
HALF_SIZE_MM = 4.23


def band_table(records_by_mode: dict[str, list]) -> str:
    """Markdown table of length error per view-angle band and input, and the limit each input's errors support."""
    lines = [
        "| input | view angle deg | photos | measured | length MAE mm | within half a size |",
        "|---|---|---:|---:|---:|---:|",
    ]
    limits = []
    for mode, records in records_by_mode.items():
        crossing, rising = None, True
        for lo, hi in zip(BANDS_DEG[:-1], BANDS_DEG[1:], strict=True):
            band = [r for r in records if lo <= r.view_angle_deg < hi]
            if not band:
                continue
            errors = np.array([abs(r.length_err) for r in band if r.ok and math.isfinite(r.length_err)])
            mae = float(errors.mean()) if len(errors) else math.nan
            within = float(np.mean(errors <= HALF_SIZE_MM)) if len(errors) else math.nan
            lines.append(
                f"| {mode} | {lo:.0f}-{hi:.0f} | {len(band)} | {len(errors)} | {mae:.2f} | {100 * within:.0f} % |"
                if len(errors)
                else f"| {mode} | {lo:.0f}-{hi:.0f} | {len(band)} | 0 | - | - |"
            )
            if len(errors) >= 3 and rising:
                if mae > HALF_SIZE_MM:
                    crossing = hi  # the bands from end-on up to here are all past half a size
                else:
                    rising = False
        limits.append(
            f"{mode}: length MAE over half a size below {crossing:.0f} deg"
            if crossing is not None
            else f"{mode}: the most end-on band (of 3+ photos) is within half a size"
        )
    return "\n".join(lines + [""] + limits)


def main() -> None:
    from footmesh.config import MeasureConfig
    from footmesh.eval.measure import evaluate_mode

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=90, help="photos per input")
    parser.add_argument("--modes", default="rgb_ref,rgbd,depth", help="inputs (eval measure's modes)")
    parser.add_argument("--size", type=int, default=640, help="photo side, px")
    parser.add_argument("--seed", type=int, default=4242, help="seed of the photos")
    parser.add_argument(
        "--views", default="sweep", help="view set (eval measure's --views): sweep, or front (as most real photos)"
    )
    args = parser.parse_args()
    config = MeasureConfig(max_rgb_end_on=1.0, max_rgbd_end_on=1.0, max_depth_end_on=1.0)
    records = {
        mode: evaluate_mode(mode, args.n, args.size, args.views, progress=False, seed=args.seed, config=config).records
        for mode in args.modes.split(",")
    }
    print(band_table(records))
    limits = MeasureConfig()
    degrees = {
        name: math.degrees(math.acos(getattr(limits, f"max_{name}_end_on"))) for name in ("rgb", "rgbd", "depth")
    }
    print(
        f"\nMeasureConfig now refuses (fitted angle): RGB within {degrees['rgb']:.0f} deg, RGB-D within "
        f"{degrees['rgbd']:.0f} deg, depth alone within {degrees['depth']:.0f} deg of the line of sight"
    )


if __name__ == "__main__":
    main()
