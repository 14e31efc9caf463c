"""``footmesh eval cues``: thesis Tables 4.1 (silhouettes), 4.2 (joints) and 4.3 (joints per viewpoint).

The networks see each 224 x 224 test image resized to their input side, exactly as ``predict_cues`` does; the
silhouette and joints are mapped back to 224 x 224 and compared there with the ground truth, so the numbers are
in the thesis' units. Joint errors are averaged over the joints that project inside the image (visible or
hidden behind the foot, like the thesis' labels); the mean over visible joints only is given as well.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from footmesh.cues.predict import MIRROR_AVERAGED_INPUTS, predict_batch, resize_inputs
from footmesh.cues.weights import load_network, packaged_weights
from footmesh.eval import thesis
from footmesh.model.skeleton import JOINT_NAMES

INPUTS = ("rgb", "rgbd", "depth")
KEYS = ["rgb", "depth", "silhouette", "joints2d", "joints_visible", "view_id", "side"]


@dataclass
class CuesScores:
    """Per-sample results of one network on one split."""

    input: str
    wrong: list[float] = field(default_factory=list)
    false_pos: list[float] = field(default_factory=list)
    false_neg: list[float] = field(default_factory=list)
    joint_err: list[np.ndarray] = field(default_factory=list)  # (18,) px, NaN where the joint is outside
    visible: list[np.ndarray] = field(default_factory=list)
    view_id: list[int] = field(default_factory=list)
    side_right: list[bool] = field(default_factory=list)  # empty for a network without a left/right head
    seconds: float = 0.0

    def summary(self) -> dict:
        err = np.array(self.joint_err)
        vis = np.array(self.visible)
        return {
            "samples": len(self.wrong),
            "silhouette_pct": {
                "incorrect": float(np.mean(self.wrong)),
                "false_positive": float(np.mean(self.false_pos)),
                "false_negative": float(np.mean(self.false_neg)),
            },
            "joint_px": {name: float(np.nanmean(err[:, j])) for j, name in enumerate(JOINT_NAMES)},
            "joint_px_mean": float(np.nanmean(err)),
            "joint_px_median": float(np.nanmedian(err)),
            "joint_px_visible_mean": float(np.nanmean(np.where(vis, err, np.nan))),
            "ms_per_image": 1000 * self.seconds / max(len(self.wrong), 1),
            "side_right_pct": 100 * float(np.mean(self.side_right)) if self.side_right else None,
        }


def evaluate(
    data: str | os.PathLike, input_kind: str, weights: str | os.PathLike | None = None, batch: int = 64
) -> CuesScores:
    """Scores of the ``input_kind`` network (shipped weights by default) on every sample of a test folder."""
    import time

    from footmesh.synth.dataset import SynthDataset

    model, config, _ = load_network(weights or packaged_weights(input_kind))
    if config.input != input_kind:
        raise ValueError(f"{weights} is a network for {config.input!r} input, not {input_kind!r}")
    dataset = SynthDataset(data, keys=KEYS)
    scores = CuesScores(input_kind)
    for start in range(0, len(dataset), batch):
        samples = [dataset[i] for i in range(start, min(start + batch, len(dataset)))]
        size = samples[0]["rgb"].shape[0]
        rgbs, depths = [], []
        for s in samples:
            r, d = resize_inputs(s["rgb"], s["depth"].astype(np.float32), config.image_size)
            rgbs.append(r)
            depths.append(d)
        t0 = time.perf_counter()
        sil, joints, _, right = predict_batch(
            model,
            config,
            np.stack(rgbs) if input_kind != "depth" else None,
            np.stack(depths) if input_kind != "rgb" else None,
            out_size=(size, size),
            mirror_average=input_kind in MIRROR_AVERAGED_INPUTS,
        )
        scores.seconds += time.perf_counter() - t0
        if right is not None:
            scores.side_right += [bool(p >= 0.5) == bool(s["side"]) for s, p in zip(samples, right, strict=True)]
        for s, p_sil, p_joints in zip(samples, sil, joints, strict=True):
            truth = s["silhouette"].astype(bool)
            pred = p_sil >= 0.5
            n = truth.size
            scores.false_pos.append(100 * float((pred & ~truth).sum()) / n)
            scores.false_neg.append(100 * float((~pred & truth).sum()) / n)
            scores.wrong.append(scores.false_pos[-1] + scores.false_neg[-1])
            inside = ((s["joints2d"] >= -0.5) & (s["joints2d"] <= size - 0.5)).all(-1)
            err = np.linalg.norm(p_joints - s["joints2d"], axis=-1)
            scores.joint_err.append(np.where(inside, err, np.nan))
            scores.visible.append(s["joints_visible"].astype(bool))
            scores.view_id.append(int(s["view_id"]))
    return scores


def view_table(scores: CuesScores) -> dict[tuple[str, int], tuple[float, float, int]]:
    """Mean and SD of all joints' errors per thesis viewpoint: {(axis, degrees): (mean, sd, samples)}."""
    from footmesh.synth.scene import NUM_THESIS_VIEWS, thesis_view

    err = np.array(scores.joint_err)
    views = np.array(scores.view_id)
    out = {}
    for v in range(NUM_THESIS_VIEWS):
        rows = views == v
        if not rows.any():
            continue
        _, _, axis, deg = thesis_view(v, "left")
        e = err[rows]
        out[(axis, deg)] = (float(np.nanmean(e)), float(np.nanstd(e)), int(rows.sum()))
    return out


def format_tables(results: dict[str, CuesScores], view_results: dict[str, CuesScores] | None = None) -> str:
    """Markdown Tables 4.1, 4.2 (and 4.3 with the viewpoint split), ours beside the thesis'."""
    kinds = [k for k in INPUTS if k in results]
    summ = {k: results[k].summary() for k in kinds}
    n = summ[kinds[0]]["samples"]
    head = "| | " + " | ".join(f"{k} ours | {k} thesis" for k in kinds) + " |"
    rule = "|---|" + "---:|---:|" * len(kinds)
    lines = [f"Table 4.1: silhouette pixels wrong, % of 224 x 224 ({n} test images)", "", head, rule]
    for metric in ("incorrect", "false_positive", "false_negative"):
        cells = " | ".join(
            f"{summ[k]['silhouette_pct'][metric]:.2f} | {thesis.SILHOUETTE_PCT[metric][k]:.2f}" for k in kinds
        )
        lines.append(f"| {metric.replace('_', ' ')} | {cells} |")
    lines += ["", "Table 4.2: 2D joint error, px of 224 x 224 (joints inside the image)", "", head, rule]
    for j, name in enumerate(JOINT_NAMES):
        cells = " | ".join(f"{summ[k]['joint_px'][name]:.1f} | {thesis.JOINT_PX[k][j]:.1f}" for k in kinds)
        lines.append(f"| {name} | {cells} |")
    cells = " | ".join(f"**{summ[k]['joint_px_mean']:.2f}** | {thesis.JOINT_PX_MEAN[k]:.1f}" for k in kinds)
    lines.append(f"| **mean** | {cells} |")
    cells = " | ".join(f"{summ[k]['joint_px_median']:.2f} | - " for k in kinds)
    lines.append(f"| median | {cells} |")
    cells = " | ".join(f"{summ[k]['joint_px_visible_mean']:.2f} | - " for k in kinds)
    lines.append(f"| mean, visible joints only | {cells} |")
    cells = " | ".join(f"{summ[k]['ms_per_image']:.1f} | - " for k in kinds)
    lines.append(f"| network time, ms per image (batch 64) | {cells} |")
    sides = [summ[k]["side_right_pct"] for k in kinds]
    cells = " | ".join("no head | -" if p is None else f"{p:.1f} | -" for p in sides)
    lines.append(f"| left/right right, % of images | {cells} |")
    if view_results:
        vkinds = [k for k in INPUTS if k in view_results]
        tables = {k: view_table(view_results[k]) for k in vkinds}
        n_views = len(view_results[vkinds[0]].wrong)
        lines += [
            "",
            f"Table 4.3: 2D joint error per thesis viewpoint, mean (SD) px ({n_views} images, ours | thesis)",
            "",
            "| axis | deg | " + " | ".join(f"{k} ours | {k} thesis" for k in vkinds) + " |",
            "|---|---:|" + "---:|---:|" * len(vkinds),
        ]
        for key in sorted(tables[vkinds[0]], key=lambda a: (a[0], a[1])):
            cells = []
            for k in vkinds:
                m, sd, _ = tables[k][key]
                tm, tsd = thesis.JOINT_PX_BY_VIEW[key][k]
                cells.append(f"{m:.1f} ({sd:.1f}) | {tm:.1f} ({tsd:.1f})")
            lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_eval(
    data: str | os.PathLike,
    inputs: list[str],
    views_data: str | os.PathLike | None = None,
    weights: dict[str, str] | None = None,
    json_out: str | os.PathLike | None = None,
) -> str:
    """Evaluate the networks for ``inputs`` and return the tables (and write the summaries as JSON)."""
    weights = weights or {}
    results = {k: evaluate(data, k, weights.get(k)) for k in inputs}
    view_results = {k: evaluate(views_data, k, weights.get(k)) for k in inputs} if views_data else None
    text = format_tables(results, view_results)
    if json_out:
        from footmesh.report import write_json

        payload = {k: v.summary() for k, v in results.items()}
        if view_results:
            payload["by_view"] = {
                k: {f"{a}{d}": list(v) for (a, d), v in view_table(s).items()} for k, s in view_results.items()
            }
        write_json(Path(json_out), json.loads(json.dumps(payload)))
    return text
