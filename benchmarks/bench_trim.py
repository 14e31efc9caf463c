"""How far a foot's image reaches past its joints, per view set: where ``cues.trim`` may cut a silhouette.

Photos are rendered like ``footmesh eval measure --views V`` (seed 4242, the reference objects in turn). For each,
every vertex of the foot model (its leg cap included, whether the leg hides it or not) is projected and placed in
the frame of the true joints (``cues.trim.foot_axes``): how far it lies behind the heel joint, past the farthest
toe tip and to the side of the heel -> toes axis, in units of the foot's image size S. The table gives the 99th
percentile and the largest value per view set beside ``TrimConfig``'s limits, and the largest share of a true
silhouette's pixels (this foot's: the other foot of the ood views left out) the cut would remove with the true
joints (0 where the limits hold).

With ``--real DIR`` (a set like ``../shared/real/rafiansyah``, for evaluation only) it also gives the pipeline's
located foot against the hand-drawn feet, with and without the cut (``MeasureConfig.trim_silhouette``; see
``footmesh eval real``).

Run: ``python benchmarks/bench_trim.py [--n 200] [--views guided,front,ood,tele,front_tele] [--real DIR]``.
Measured (2026-12-05): docs/cues.md.
"""

from __future__ import annotations

import argparse

import numpy as np

VIEW_SETS = ("guided", "front", "ood", "tele", "front_tele")


def reach(views: str, n: int, seed: int = 4242) -> dict[str, np.ndarray]:
    """Per photo of ``views``: the foot's reach behind the heel, past the toes and across (each (n,), units of S),
    and the share of true silhouette pixels outside ``foot_region`` of the true joints."""
    from footmesh.cues.trim import foot_axes, foot_region
    from footmesh.eval.measure import MODES, REFERENCES
    from footmesh.fit import projected_mask
    from footmesh.geometry.camera import project
    from footmesh.model.layer import default_model
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import view_config

    renderers: dict[str, Renderer] = {}
    faces = {side: default_model().faces(side).numpy() for side in ("left", "right")}
    behind, past, across, cut = [], [], [], []
    for i in range(n):
        reference = REFERENCES[i % len(REFERENCES)]
        if reference not in renderers:
            renderers[reference] = Renderer(view_config(views, size=640, reference=reference))
        sample = renderers[reference].render(seed + MODES.index("rgb_ref"), i)
        axes = foot_axes(sample["joints2d"])
        if axes is None:
            continue
        uv, _ = project(sample["vertices"].astype(np.float64), sample["K"])
        along, side = axes.coordinates(uv[:, 0], uv[:, 1])
        behind.append(-along.min())
        past.append(along.max() - axes.length / axes.size)
        across.append(side.max())
        # this foot's pixels (the ood views' other foot is foot in the silhouette too)
        side = "right" if int(sample["side"]) else "left"
        own = projected_mask(
            sample["vertices"].astype(np.float64), faces[side], sample["K"], sample["silhouette"].shape
        )
        silhouette = sample["silhouette"] & own
        kept = foot_region(silhouette.shape, sample["joints2d"])
        cut.append(float((silhouette & ~kept).sum() / max(silhouette.sum(), 1)))
    return {"behind": np.array(behind), "past": np.array(past), "across": np.array(across), "cut": np.array(cut)}


def reach_table(results: dict[str, dict]) -> str:
    """Markdown table: p99 / max reach per view set and the cut's share of the true silhouette."""
    from footmesh.cues.trim import TrimConfig

    config = TrimConfig()
    lines = [
        "| view set | photos | behind the heel p99 / max | past the toes p99 / max | across p99 / max | "
        "silhouette cut (true joints) max |",
        "|---|---:|---:|---:|---:|---:|",
    ]
    for views, r in results.items():
        cells = [f"{np.percentile(r[k], 99):.2f} / {r[k].max():.2f}" for k in ("behind", "past", "across")]
        lines.append(f"| {views} | {len(r['behind'])} | {' | '.join(cells)} | {100 * r['cut'].max():.2f} % |")
    lines.append(f"| `TrimConfig` | | {config.behind_heel:.2f} | {config.past_toes:.2f} | {config.across:.2f} | |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--n", type=int, default=200, help="photos per view set")
    parser.add_argument("--views", default=",".join(VIEW_SETS))
    parser.add_argument("--real", default=None, help="also score the located feet of this real set")
    args = parser.parse_args(argv)
    results = {views: reach(views, args.n) for views in args.views.split(",")}
    print(reach_table(results))
    if args.real:
        from dataclasses import replace

        from footmesh.config import MeasureConfig
        from footmesh.eval.real import located_scores

        for trim in (False, True):
            ious = located_scores(args.real, replace(MeasureConfig(), trim_silhouette=trim))
            print(
                f"real {args.real}: located foot IoU per hand-drawn foot, cut {'on' if trim else 'off'}: "
                f"mean {np.mean(ious):.3f}, median {np.median(ious):.3f} ({len(ious)} feet)"
            )


if __name__ == "__main__":
    main()
