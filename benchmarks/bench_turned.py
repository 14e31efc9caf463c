"""The same photos turned by quarter turns: how much the answer depends on which way up the photo was taken.

The cue networks learnt feet with the leg rising up the picture (renders of a camera held upright). A phone
pointed straight down cannot tell which way is up, people hold phones sideways, and photos looking down at one's
own feet show the legs entering from the bottom. Each photo (``footmesh eval measure``'s renders of ``--views``,
RGB + A4 sheet, K.json given) is measured as rendered and turned 90, 180 and 270 deg counter-clockwise (the photo
and its K turned together), with the pipeline's turned looks (``pipeline.turned_where_needed``: the floor's up,
the ankle below the toes, the foot past the edge) and without them. The table gives per turn the photos
answered, those with millimetres, the length MAE on those and how many were read turned.

Run: ``python benchmarks/bench_turned.py [--n 16] [--views front guided] [--seed 4242]``.
Real photos beside it: ``footmesh eval real --set ../shared/real/rafiansyah --measure`` (first-person photos,
the legs from the bottom; docs/results-history.md).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np

TURNS = (0, 1, 2, 3)


def measure_turned(sample: dict, quarter_turns: int, folder: Path, config) -> tuple[str, float | None, bool]:
    """(outcome "mm" / "unscaled" / "refused", length mm or None, read turned) of one render turned."""
    from footmesh.errors import Refusal
    from footmesh.eval.measure import turned_sample, write_inputs
    from footmesh.pipeline import measure_photo

    paths = write_inputs(turned_sample(sample, quarter_turns), folder, with_depth=False)
    try:
        result = measure_photo(paths["image"], folder / "out", intrinsics=paths["intrinsics"], config=config)
    except Refusal:
        return "refused", None, False
    read_turned = any("turned" in message for message in result["messages"])
    if not result["scaled"]:
        return "unscaled", None, read_turned
    return "mm", float(result["measurements"]["stick_length"]["value_mm"]), read_turned


def run(views: list[str], n: int, seed: int) -> str:
    """Markdown table of each view set's photos measured at every turn, with and without the turned looks."""
    from footmesh.config import MeasureConfig
    from footmesh.eval.measure import true_measurements
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import view_config

    configs = {
        "turned looks": MeasureConfig(),
        "upright only": replace(
            MeasureConfig(),
            turned_looks=(),
            upside_down_deg=None,
            upside_down_min_confidence_gain=None,
            floor_up_turn_deg=None,
        ),
    }
    lines = [
        "| views | turned deg | pipeline | answered | with mm | length MAE mm | read turned |",
        "|---|---:|---|---:|---:|---:|---:|",
    ]
    with tempfile.TemporaryDirectory() as tmp:
        for name in views:
            renderer = Renderer(view_config(name, size=640, reference="a4"))
            samples = [renderer.render(seed, i) for i in range(n)]
            truths = [
                true_measurements(s["shape"], "right" if int(s["side"]) else "left")["stick_length"] for s in samples
            ]
            for quarter_turns in TURNS:
                for label, config in configs.items():
                    outcomes = [
                        measure_turned(s, quarter_turns, Path(tmp) / f"{name}_{quarter_turns}_{label}_{i}", config)
                        for i, s in enumerate(samples)
                    ]
                    errors = [abs(length - t) for (kind, length, _), t in zip(outcomes, truths, strict=True) if length]
                    answered = sum(kind != "refused" for kind, _, _ in outcomes)
                    mae = f"{np.mean(errors):.2f}" if errors else "-"
                    turned = sum(t for _, _, t in outcomes)
                    row = (name, 90 * quarter_turns, label, f"{answered} / {n}", len(errors), mae, turned)
                    lines.append("| " + " | ".join(str(cell) for cell in row) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--n", type=int, default=16, help="photos per view set")
    parser.add_argument("--views", nargs="+", default=["front", "guided"], help="eval measure's view sets")
    parser.add_argument("--seed", type=int, default=4242, help="seed of the renders")
    args = parser.parse_args()
    print(run(args.views, args.n, args.seed))


if __name__ == "__main__":
    main()
