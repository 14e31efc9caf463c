"""``footmesh eval recon``: thesis Tables 4.4 (vertex error), 4.5 (3D joints) and 4.6 (3D joints per viewpoint).

The networks see each test image resized to their input side with the intrinsics resized alike, exactly as in
training; their meshes (mm, camera frame) are compared with the synthetic ground truth:

- **per-vertex error** (Table 4.4): mean Euclidean distance between each predicted vertex and the same vertex of
  the true mesh, as predicted (*raw*, the thesis' measure), after moving the prediction's centroid onto the
  true centroid (*centroid-aligned*: the shape and orientation alone), and after that plus the least-squares
  scale about the centroid (*scale-aligned*: the shape up to size; the measure for RGB without a scale cue,
  whose size is a guess). The least-squares factor itself (true / predicted size) is reported too;
- **Chamfer error**: the mean of both directions' mean nearest-point distance (``recon.edgeconv``), the only
  measure of the EdgeConv baseline's unordered points, given for the mesh networks too as the like-for-like
  comparison;
- **3D joints** (Tables 4.5, 4.6): ``joints_from_vertices`` of the predicted mesh against the true joints after
  moving the midfoot onto the true one (``midfoot_aligned_error``; means over the 17 other joints), and for
  scale-aligned reporting additionally scaled about the midfoot by the least-squares factor. The same
  regressor applied to the *true* mesh gives the floor this reading of joints off a mesh has on posed feet.
"""

from __future__ import annotations

import functools
import json
import os
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from footmesh.eval import thesis
from footmesh.model.skeleton import JOINT_NAMES
from footmesh.recon.joints import joints_from_vertices, midfoot_aligned_error

INPUTS = ("rgb", "rgbd", "depth")
KEYS = ["index", "rgb", "depth", "vertices", "joints3d", "K", "view_id", "side"]
MODEL_KEYS = ["shape", "angles", "cam_from_foot"]
"""The foot model's true parameters, read for a model-based network (``PARAMETER_GROUPS``)."""
PARAMETER_GROUPS: dict[str, tuple[str, ...]] = {
    "as predicted": (),
    "true rotation": ("rotation",),
    "true shape": ("shape",),
    "true angles": ("angles",),
    "true shape and angles": ("shape", "angles"),
}
"""The model-based head's parameters replaced by the truth, group by group, in ``ReconScores.model_parts``."""


@dataclass
class ReconScores:
    """Per-sample results of one network on one split (mm)."""

    input: str
    kind: str
    residual: bool = False
    """``kind="model"``: whether the network adds the ISM decoder's residual."""
    vertex: list[float] = field(default_factory=list)
    vertex_centred: list[float] = field(default_factory=list)
    vertex_scaled: list[float] = field(default_factory=list)
    scale: list[float] = field(default_factory=list)
    chamfer: list[float] = field(default_factory=list)
    joint: list[np.ndarray] = field(default_factory=list)  # (18,) midfoot-aligned, column 0 = 0
    joint_scaled: list[np.ndarray] = field(default_factory=list)  # (18,) midfoot- and scale-aligned
    joint_floor: list[np.ndarray] = field(default_factory=list)  # (18,) joints of the true mesh vs the truth
    vertex_side_given: list[float] = field(default_factory=list)
    """``kind="model"``: the raw vertex error when the mesh is built for the true side (as when the user or the
    2D-cues network's side head gives it), beside ``vertex`` with the network's own side."""
    joint_side_given: list[np.ndarray] = field(default_factory=list)
    side_correct: list[bool] = field(default_factory=list)
    model_parts: dict[str, list[float]] = field(default_factory=dict)
    """``kind="model"``: the centroid-aligned error of the foot model's mesh (before any residual, true side) as
    predicted and with one group of its parameters replaced by the truth (``PARAMETER_GROUPS``): where its error
    comes from."""
    view_id: list[int] = field(default_factory=list)
    seconds: float = 0.0
    latency_ms: dict[str, float] = field(default_factory=dict)
    no_depth: int = 0
    """Samples left out because their depth map holds no valid pixel (views from below the floor), depth inputs."""
    index: list[int] = field(default_factory=list)
    """The dataset index of each scored sample (the lists above, in order)."""
    refused: int = 0
    """``kind="pipeline"``: photos the whole pipeline refused or could not scale (not scored)."""

    @property
    def samples(self) -> int:
        return len(self.chamfer)

    def summary(self) -> dict:
        """Means over the samples (and per joint), as plain numbers for JSON."""
        out = {
            "input": self.input,
            "kind": self.kind,
            "samples": self.samples,
            "left_out_no_depth": self.no_depth,
            "refused": self.refused,
            "chamfer_mm": _mean(self.chamfer),
            # per image tried: the pipeline's refused photos took their time too
            "ms_per_image": 1000 * self.seconds / max(self.samples + self.refused, 1),
            "latency_ms_batch1": dict(self.latency_ms),
        }
        if self.kind == "edgeconv":
            return out
        joint, scaled, floor = np.array(self.joint), np.array(self.joint_scaled), np.array(self.joint_floor)
        out.update(
            {
                "vertex_mm": _mean(self.vertex),
                "vertex_mm_median": float(np.median(self.vertex)),
                "vertex_mm_centroid_aligned": _mean(self.vertex_centred),
                "vertex_mm_scale_aligned": _mean(self.vertex_scaled),
                "scale_factor_mean": _mean(self.scale),
                "scale_factor_sd": float(np.std(self.scale)),
                "joint_mm": {name: float(joint[:, j].mean()) for j, name in enumerate(JOINT_NAMES)},
                "joint_mm_mean": float(joint[:, 1:].mean()),
                "joint_mm_scale_aligned": {name: float(scaled[:, j].mean()) for j, name in enumerate(JOINT_NAMES)},
                "joint_mm_scale_aligned_mean": float(scaled[:, 1:].mean()),
                "joint_mm_floor": {name: float(floor[:, j].mean()) for j, name in enumerate(JOINT_NAMES)},
                "joint_mm_floor_mean": float(floor[:, 1:].mean()),
            }
        )
        if self.model_parts:
            out["model_mesh_centred_mm"] = {name: _mean(v) for name, v in self.model_parts.items()}
        if self.vertex_side_given:
            out["vertex_mm_side_given"] = _mean(self.vertex_side_given)
            out["joint_mm_mean_side_given"] = float(np.array(self.joint_side_given)[:, 1:].mean())
            out["side_accuracy"] = _mean([float(c) for c in self.side_correct])
        return out


def _mean(values: list[float]) -> float:
    return float(np.mean(values)) if len(values) else float("nan")


# --- metrics ------------------------------------------------------------------------------------------------------


def vertex_errors(pred: torch.Tensor, true: torch.Tensor) -> dict[str, torch.Tensor]:
    """Per-sample mean per-vertex errors (B,) mm of meshes (B, V, 3): raw, centroid-aligned, scale-aligned, and
    the least-squares scale factor (B,) that the scale-aligned error applies about the centroid."""
    raw = (pred - true).norm(dim=-1).mean(1)
    p = pred - pred.mean(1, keepdim=True)
    t = true - true.mean(1, keepdim=True)
    k = (p * t).sum((1, 2)) / (p * p).sum((1, 2)).clamp_min(1e-12)  # argmin_k sum |k p - t|^2
    return {
        "raw": raw,
        "centred": (p - t).norm(dim=-1).mean(1),
        "scaled": (k.view(-1, 1, 1) * p - t).norm(dim=-1).mean(1),
        "scale": k,
    }


def scale_aligned_joint_error(pred: torch.Tensor, true: torch.Tensor) -> torch.Tensor:
    """(B, 18) joint errors mm after moving the midfoot onto the truth's and the least-squares scale about it."""
    p = pred - pred[:, :1]
    t = true - true[:, :1]
    k = (p * t).sum((1, 2)) / (p * p).sum((1, 2)).clamp_min(1e-12)
    return (k.view(-1, 1, 1) * p - t).norm(dim=-1)


def chamfer_mm(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Symmetric Chamfer distance (B,) mm of clouds (B, N, 3) and (B, M, 3), as ``recon.edgeconv.chamfer_distance``
    but with one distance matrix per pair (evaluation only: no gradient)."""
    out = []
    with torch.no_grad():
        for ai, bi in zip(a, b, strict=True):
            centre = bi.mean(0, keepdim=True)  # centred: the fast matrix-product distances pick the right pairs
            d = torch.cdist((ai - centre)[None], (bi - centre)[None])[0]
            # the chosen pairs' distances by subtraction: exact (0 for identical points), as the training loss
            to_b = (ai - bi[d.argmin(1)]).norm(dim=-1).mean()
            to_a = (bi - ai[d.argmin(0)]).norm(dim=-1).mean()
            out.append(0.5 * (to_b + to_a))
    return torch.stack(out)


# --- evaluation ---------------------------------------------------------------------------------------------------


def network_inputs(
    samples: list[dict], input_kind: str, size: int
) -> tuple[np.ndarray | None, np.ndarray | None, np.ndarray]:
    """Synthetic samples resized to the network's side as in training: rgb (B, S, S, 3) uint8 and depth (B, S, S)
    mm (None where ``input_kind`` does not use them) and K (B, 3, 3) px of that side, for ``predict_batch``."""
    from footmesh.cues.predict import resize_inputs
    from footmesh.geometry.camera import resize_intrinsics

    rgbs, depths, ks = [], [], []
    for s in samples:
        r, d = resize_inputs(s["rgb"], s["depth"].astype(np.float32), size)
        rgbs.append(r)
        depths.append(d)
        ks.append(resize_intrinsics(s["K"], size / s["rgb"].shape[0]))
    rgb = np.stack(rgbs) if input_kind != "depth" else None
    depth = np.stack(depths) if input_kind != "rgb" else None
    return rgb, depth, np.stack(ks)


def evaluate(
    data: str | os.PathLike,
    input_kind: str,
    weights: str | os.PathLike | None = None,
    batch: int = 32,
    limit: int | None = None,
    mirror_average: bool = False,
) -> ReconScores:
    """Scores of the ``input_kind`` network (shipped weights by default) on the samples of a test folder.

    Args:
        data: synthetic test folder (``footmesh synth``, another seed than training).
        weights: a ``weights.pt`` of ``footmesh train recon`` (ISM or EdgeConv) instead of the shipped one.
        limit: evaluate only the first ``limit`` samples.
        mirror_average: each mesh the average of the network's answers for the image and its mirror image
            (``recon.model.predict_batch``).
    """
    from footmesh.recon.model import predict_batch
    from footmesh.recon.weights import load_network, packaged_weights
    from footmesh.synth.dataset import SynthDataset

    path = weights or packaged_weights(input_kind)
    model, config, _ = load_network(path)
    if config.input != input_kind:
        raise ValueError(f"{path} is a network for {config.input!r} input, not {input_kind!r}")
    dataset = SynthDataset(data, keys=KEYS + (MODEL_KEYS if config.kind == "model" else []))
    n = len(dataset) if limit is None else min(limit, len(dataset))
    scores = ReconScores(input_kind, config.kind, config.kind == "model" and config.residual)
    size = config.image_size
    for start in range(0, n, batch):
        samples = [dataset[i] for i in range(start, min(start + batch, n))]
        if input_kind != "rgb":
            # a depth map without a single valid pixel (a view from below the one-sided floor) gives no scale
            with_depth = [s for s in samples if (s["depth"] > 0).any()]
            scores.no_depth += len(samples) - len(with_depth)
            samples = with_depth
            if not samples:
                continue
        rgb, depth, K = network_inputs(samples, input_kind, size)  # noqa: N806
        t0 = time.perf_counter()
        out = predict_batch(model, rgb, depth, K, mirror_average=mirror_average)
        scores.seconds += time.perf_counter() - t0
        true_v = torch.from_numpy(np.stack([s["vertices"] for s in samples]).astype(np.float32))
        true_j = torch.from_numpy(np.stack([s["joints3d"] for s in samples]).astype(np.float32))
        pred = out.points if config.kind == "edgeconv" else out.vertices
        scores.chamfer += chamfer_mm(pred, true_v).tolist()
        scores.view_id += [int(s["view_id"]) for s in samples]
        scores.index += [int(s["index"]) for s in samples]
        if config.kind == "edgeconv":
            continue
        _score_meshes(scores, pred, true_v, true_j)
        if config.kind == "model":
            right = np.array([bool(s["side"]) for s in samples])
            scores.side_correct += (out.right.numpy() == right).tolist()
            given = predict_batch(model, rgb, depth, K, right, mirror_average=mirror_average)
            scores.vertex_side_given += vertex_errors(given.vertices, true_v)["raw"].tolist()
            scores.joint_side_given += list(midfoot_aligned_error(joints_from_vertices(given.vertices), true_j).numpy())
            for name, errors in _parameter_parts(given.parameters, samples, true_v).items():
                scores.model_parts.setdefault(name, []).extend(errors)
    scores.latency_ms = latency(model)
    return scores


def _parameter_parts(parameters, samples: list[dict], true_v: torch.Tensor) -> dict[str, list[float]]:
    """Centroid-aligned errors (mm) of the foot model's mesh built from ``parameters`` (the true sides), as
    predicted and with each of ``PARAMETER_GROUPS`` replaced by the samples' true values."""
    from footmesh.recon.parametric import NUM_SHAPE, ParametricHead

    truth = {
        "shape": torch.from_numpy(np.stack([s["shape"][:NUM_SHAPE] for s in samples]).astype(np.float32)),
        "angles": torch.from_numpy(np.stack([s["angles"] for s in samples]).astype(np.float32)),
        "rotation": torch.from_numpy(np.stack([s["cam_from_foot"][:3, :3] for s in samples]).astype(np.float32)),
    }
    right = torch.tensor([bool(s["side"]) for s in samples])
    centred = true_v - true_v.mean(1, keepdim=True)
    out = {}
    for name, group in PARAMETER_GROUPS.items():
        mesh, _ = ParametricHead.mesh(replace(parameters, **{k: truth[k] for k in group}), right)
        out[name] = (mesh - centred).norm(dim=-1).mean(1).tolist()
    return out


def _score_meshes(scores: ReconScores, pred: torch.Tensor, true_v: torch.Tensor, true_j: torch.Tensor) -> None:
    """Add the vertex and joint errors of predicted meshes (B, V, 3) against the truth to ``scores``."""
    errors = vertex_errors(pred, true_v)
    scores.vertex += errors["raw"].tolist()
    scores.vertex_centred += errors["centred"].tolist()
    scores.vertex_scaled += errors["scaled"].tolist()
    scores.scale += errors["scale"].tolist()
    joints = joints_from_vertices(pred)
    scores.joint += list(midfoot_aligned_error(joints, true_j).numpy())
    scores.joint_scaled += list(scale_aligned_joint_error(joints, true_j).numpy())
    scores.joint_floor += list(midfoot_aligned_error(joints_from_vertices(true_v), true_j).numpy())


def evaluate_pipeline(
    data: str | os.PathLike, input_kind: str, limit: int | None = None, progress: bool = False
) -> ReconScores:
    """Scores of the whole pipeline's mesh (``footmesh measure``'s ``mesh.obj``: the fit to the cues and depth,
    started from the decoder where ``MeasureConfig.decoder_start_inputs`` says) on the samples of a test folder,
    each written as the files a user gives. Photos the pipeline refuses, or answers unscaled, are counted in
    ``refused``, not scored."""
    import tempfile

    import trimesh
    from tqdm import tqdm

    from footmesh.errors import Refusal
    from footmesh.eval.measure import write_inputs
    from footmesh.pipeline import measure_photo
    from footmesh.synth.dataset import SynthDataset

    dataset = SynthDataset(data, keys=KEYS)
    n = len(dataset) if limit is None else min(limit, len(dataset))
    scores = ReconScores(input_kind, "pipeline")
    with tempfile.TemporaryDirectory(prefix="footmesh-eval-recon-") as tmp:
        for i in tqdm(range(n), desc=f"pipeline {input_kind}", disable=not progress):
            sample = dataset[i]
            if input_kind != "rgb" and not (sample["depth"] > 0).any():
                scores.no_depth += 1
                continue
            folder = Path(tmp) / str(i)
            paths = write_inputs(sample, folder, with_depth=input_kind != "rgb")
            t0 = time.perf_counter()
            try:
                result = measure_photo(
                    paths["image"], folder / "out", depth=paths.get("depth"), intrinsics=paths["intrinsics"],
                    input=input_kind,
                )  # fmt: skip
            except Refusal:
                scores.refused += 1
                continue
            finally:
                scores.seconds += time.perf_counter() - t0
            if not result["scaled"]:
                scores.refused += 1
                continue
            mesh = trimesh.load(folder / "out" / result["files"]["mesh_obj"], process=False)
            pred = torch.as_tensor(np.asarray(mesh.vertices), dtype=torch.float32)[None]
            true_v = torch.as_tensor(sample["vertices"], dtype=torch.float32)[None]
            true_j = torch.as_tensor(sample["joints3d"], dtype=torch.float32)[None]
            scores.chamfer += chamfer_mm(pred, true_v).tolist()
            scores.view_id.append(int(sample["view_id"]))
            scores.index.append(int(sample["index"]))
            _score_meshes(scores, pred, true_v, true_j)
    return scores


@torch.inference_mode()
def latency(model, runs: int = 20) -> dict[str, float]:
    """Median CPU time (ms) of one forward pass at batch 1 of the whole network and of its decoder alone,
    with the current torch threads."""
    cfg = model.config
    x = torch.zeros(1, cfg.in_channels - (2 if cfg.coord_channels else 0), cfg.image_size, cfg.image_size)
    f = 0.75 * cfg.image_size
    K = torch.tensor([[[f, 0.0, (cfg.image_size - 1) / 2], [0.0, f, (cfg.image_size - 1) / 2], [0, 0, 1]]])  # noqa: N806
    ref = torch.full((1,), 500.0) if cfg.input != "rgb" else None
    latent = torch.zeros(1, cfg.latent_features)
    skips = [torch.zeros(1, c) for c in cfg.decoder.skip_in_channels]

    def decode() -> None:
        """Everything after the latent code: the mesh decoder, the point generator, or the model-based head
        (its parameters, the foot model and the residual decoder)."""
        if cfg.kind == "model":
            from footmesh.recon.parametric import ParametricHead

            parameters = model.parametric(latent, torch.zeros(1))
            ParametricHead.mesh(parameters, parameters.right_logit > 0)
            if model.decoder is not None:
                model.decoder(latent, skips, torch.zeros(1, 3))
        elif model.decoder is not None:
            model.decoder(latent, skips)
        else:
            model.generator(latent)

    def median(fn) -> float:
        fn()
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            fn()
            times.append(time.perf_counter() - t0)
        return 1000 * float(np.median(times))

    return {
        "network": median(lambda: model(x, K, ref)),
        "decoder": median(decode),
    }


def view_table(scores: ReconScores) -> dict[tuple[str, int], tuple[float, float, int]]:
    """Mean and SD (mm) of all 17 non-midfoot joints' errors per thesis viewpoint: {(axis, deg): (mean, sd, n)}."""
    from footmesh.synth.scene import NUM_THESIS_VIEWS, thesis_view

    err = np.array(scores.joint)
    views = np.array(scores.view_id)
    out = {}
    for v in range(NUM_THESIS_VIEWS):
        rows = views == v
        if not rows.any() or err.size == 0:
            continue
        _, _, axis, deg = thesis_view(v, "left")
        e = err[rows][:, 1:]
        out[(axis, deg)] = (float(e.mean()), float(e.std()), int(rows.sum()))
    return out


# --- tables -------------------------------------------------------------------------------------------------------


def format_tables(
    results: dict[str, ReconScores],
    view_results: dict[str, ReconScores] | None = None,
    edgeconv: ReconScores | None = None,
    model: ReconScores | None = None,
    model_views: ReconScores | None = None,
    pipeline: dict[str, ReconScores] | None = None,
) -> str:
    """Markdown Tables 4.4, 4.5 (and 4.6 with the viewpoint split), ours beside the thesis'; ``model``: the
    model-based network's scores, a row / column of their own beside the pure ISM decoder's (same thesis cell);
    ``pipeline``: the whole pipeline's mesh per input (``evaluate_pipeline``), rows of their own with the ISM
    decoder's error on the same photos beside."""
    results = dict(results)
    view_results = dict(view_results) if view_results else {}
    if model is not None:
        results[MODEL_LABEL] = model
        if model_views is not None:
            view_results[MODEL_LABEL] = model_views
    kinds = [k for k in (*INPUTS, MODEL_LABEL) if k in results]
    summ = {k: results[k].summary() for k in kinds}
    n = summ[kinds[0]]["samples"] if kinds else (edgeconv.samples if edgeconv else 0)
    lines = [
        f"Table 4.4: mean per-vertex error, mm ({n} test images). *raw*: as predicted, the thesis' measure; "
        "*centroid-aligned*: the prediction moved onto the true centroid; *scale-aligned*: then also scaled about "
        "the centroid by the least-squares factor (the measure for RGB, which has no depth to give the size); "
        "*scale*: that factor, true / predicted size; Chamfer: mean nearest-point distance both ways.",
        "",
        "| method | raw ours | thesis | centroid-aligned | scale-aligned | scale | Chamfer |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    if edgeconv is not None:
        s = edgeconv.summary()
        lines.append(
            f"| EdgeConv ({edgeconv.input} image) | - | {thesis.VERTEX_MM['edgeconv']:.2f} | - | - | - | "
            f"**{s['chamfer_mm']:.2f}** |"
        )
    else:
        lines.append(f"| EdgeConv | not evaluated (--edgeconv-weights) | {thesis.VERTEX_MM['edgeconv']:.2f} | | | | |")
    for k in kinds:
        s = summ[k]
        lines.append(
            f"| {_row_name(k, results[k])} | **{s['vertex_mm']:.2f}** | {thesis.VERTEX_MM[results[k].input]:.2f} | "
            f"{s['vertex_mm_centroid_aligned']:.2f}"
            f" | {s['vertex_mm_scale_aligned']:.2f} | {s['scale_factor_mean']:.3f} | {s['chamfer_mm']:.2f} |"
        )
        if "vertex_mm_side_given" in s:
            lines.append(
                f"| ... the same, built for the true side (its own side right on {100 * s['side_accuracy']:.0f} %) | "
                f"{s['vertex_mm_side_given']:.2f} | | | | | |"
            )
        if "model_mesh_centred_mm" in s:  # a model-based network: where its error comes from
            for name, value in s["model_mesh_centred_mm"].items():
                lines.append(f"| ... the foot model's mesh (true side), {name} | | | {value:.2f} | | | |")
    for k, scored in (pipeline or {}).items():
        if not scored.samples:
            lines.append(f"| {PIPELINE_ROW}, {k} | none of {scored.refused} photos measured | | | | | |")
            continue
        s = scored.summary()
        lines.append(
            f"| {PIPELINE_ROW}, {k} ({scored.samples} of {scored.samples + scored.refused} photos measured) | "
            f"**{s['vertex_mm']:.2f}** | {thesis.VERTEX_MM[k]:.2f} | {s['vertex_mm_centroid_aligned']:.2f} | "
            f"{s['vertex_mm_scale_aligned']:.2f} | {s['scale_factor_mean']:.3f} | {s['chamfer_mm']:.2f} |"
        )
        if k in results:
            same = _on_samples(results[k], scored.index)
            lines.append(f"| ... ISM, {k}, on the same photos | {_mean(same.vertex):.2f} | | | | | |")
    if "rgb" in summ:
        s = summ["rgb"]
        lines += [
            "",
            f"RGB: {s['vertex_mm']:.2f} mm as predicted (raw); {s['vertex_mm_scale_aligned']:.2f} mm after aligning "
            f"scale (scale-aligned); predicted sizes are off by a factor {s['scale_factor_mean']:.3f} +- "
            f"{s['scale_factor_sd']:.3f} on average.",
        ]
    if kinds:
        head = "| joint | " + " | ".join(f"{k} ours | {k} thesis" for k in kinds)
        rule = "|---|" + "---:|---:|" * len(kinds)
        if "rgb" in summ:
            head += " | rgb scale-aligned"
            rule += "---:|"
        head += " | floor |"
        rule += "---:|"
        lines += [
            "",
            "Table 4.5: 3D joint error after aligning the midfoot, mm (joints from the mesh by the template's vertex "
            "groups). *floor*: the same joints of the true mesh against the true joints.",
            "",
            head,
            rule,
        ]
        first = summ[kinds[0]]
        for j, name in enumerate(JOINT_NAMES):
            cells = [f"{summ[k]['joint_mm'][name]:.2f} | {thesis.JOINT_MM[results[k].input][j]:.2f}" for k in kinds]
            if "rgb" in summ:
                cells.append(f"{summ['rgb']['joint_mm_scale_aligned'][name]:.2f}")
            cells.append(f"{first['joint_mm_floor'][name]:.2f}")
            lines.append(f"| {name} | " + " | ".join(cells) + " |")
        cells = [f"**{summ[k]['joint_mm_mean']:.2f}** | {thesis.JOINT_MM_MEAN[results[k].input]:.2f}" for k in kinds]
        if "rgb" in summ:
            cells.append(f"{summ['rgb']['joint_mm_scale_aligned_mean']:.2f}")
        cells.append(f"{first['joint_mm_floor_mean']:.2f}")
        lines.append("| **mean (17 joints)** | " + " | ".join(cells) + " |")
        lat = " | ".join(
            f"{summ[k]['latency_ms_batch1']['network']:.1f} / {summ[k]['latency_ms_batch1']['decoder']:.1f}"
            for k in kinds
        )
        lines += ["", f"CPU ms per image at batch 1, whole network / decoder ({', '.join(kinds)}): {lat}"]
    for k, scored in (pipeline or {}).items():
        if not scored.samples:
            continue
        s = scored.summary()
        beside = ""
        if k in results:
            same = np.array(_on_samples(results[k], scored.index).joint)
            beside = f" (ISM, {k}, on the same photos: {same[:, 1:].mean():.2f} mm)"
        lines += [
            "",
            f"{PIPELINE_ROW}, {k}: mean 3D joint error (17 joints, the same reading off the mesh) "
            f"{s['joint_mm_mean']:.2f} mm{beside}; thesis {thesis.JOINT_MM_MEAN[k]:.2f}; "
            f"{s['ms_per_image'] / 1000:.2f} s per photo.",
        ]
    if view_results:
        vkinds = [k for k in (*INPUTS, MODEL_LABEL) if k in view_results]
        tables = {k: view_table(view_results[k]) for k in vkinds}
        n_views = max(view_results[k].samples for k in vkinds)
        left_out = "".join(
            f"; {view_results[k].no_depth} without any depth pixel left out for {k}"
            for k in vkinds
            if view_results[k].no_depth
        )
        lines += [
            "",
            f"Table 4.6: 3D joint error per thesis viewpoint, mean (SD) over all joints, mm ({n_views} images"
            f"{left_out}; ours | thesis)",
            "",
            "| axis | deg | " + " | ".join(f"{k} ours | {k} thesis" for k in vkinds) + " |",
            "|---|---:|" + "---:|---:|" * len(vkinds),
        ]
        for key in sorted(tables[vkinds[0]], key=lambda a: (a[0], a[1])):
            cells = []
            for k in vkinds:
                tm, tsd = thesis.JOINT_MM_BY_VIEW[key][view_results[k].input]
                ours = f"{tables[k][key][0]:.2f} ({tables[k][key][1]:.2f})" if key in tables[k] else "-"
                cells.append(f"{ours} | {tm:.2f} ({tsd:.2f})")
            lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


MODEL_LABEL = "model"
"""The key of the model-based network's scores beside the per-input ISM decoders' in ``format_tables``."""
PIPELINE_ROW = "whole pipeline (decoder start + fit)"


def _on_samples(scores: ReconScores, index: list[int]) -> ReconScores:
    """``scores`` kept to the samples of dataset ``index`` (vertex and joint errors only)."""
    where = {i: n for n, i in enumerate(scores.index)}
    keep = [where[i] for i in index if i in where]
    return ReconScores(
        scores.input,
        scores.kind,
        vertex=[scores.vertex[n] for n in keep],
        joint=[scores.joint[n] for n in keep],
        index=[scores.index[n] for n in keep],
    )


def _row_name(key: str, scores: ReconScores) -> str:
    if key != MODEL_LABEL:
        return f"ISM, {key}"
    return f"model-based{' + ISM residual' if scores.residual else ''}, {scores.input}"


def run_eval(
    data: str | os.PathLike,
    inputs: list[str],
    views_data: str | os.PathLike | None = None,
    weights: dict[str, str] | None = None,
    json_out: str | os.PathLike | None = None,
    edgeconv_weights: str | os.PathLike | None = None,
    limit: int | None = None,
    model_weights: str | os.PathLike | None = None,
    pipeline: list[str] | None = None,
    pipeline_limit: int | None = None,
    mirror_average: bool = False,
) -> str:
    """Evaluate the networks for ``inputs`` (and the EdgeConv baseline and a model-based network if given) on the
    first ``limit`` samples (all by default) of each folder, and the whole pipeline for the inputs ``pipeline`` on
    the first ``pipeline_limit`` (about a second a photo); return the tables and write the summaries as JSON.
    ``mirror_average``: every network's meshes are the average of its answers for the image and its mirror."""
    weights = weights or {}
    scored = functools.partial(evaluate, limit=limit, mirror_average=mirror_average)
    results = {k: scored(data, k, weights.get(k)) for k in inputs}
    for k, s in results.items():
        if s.kind != "ism":
            flag = "--edgeconv-weights" if s.kind == "edgeconv" else "--model-weights"
            raise ValueError(f"the {k} weights hold a {s.kind} network, not the ISM decoder; give it with {flag}")
    model = model_views = None
    if model_weights:
        from footmesh.recon.weights import read_weights

        _, cfg, _ = read_weights(model_weights)
        if cfg.kind != "model":
            raise ValueError(f"{model_weights} holds a {cfg.kind} network, not a model-based one")
        model = scored(data, cfg.input, model_weights)
        if views_data:
            model_views = scored(views_data, cfg.input, model_weights)
    view_results = None
    if views_data:
        view_results = {k: scored(views_data, k, weights.get(k)) for k in inputs}
    edgeconv = None
    if edgeconv_weights:
        from footmesh.recon.weights import read_weights

        _, cfg, _ = read_weights(edgeconv_weights)
        if cfg.kind != "edgeconv":
            raise ValueError(f"{edgeconv_weights} holds a mesh network, not the EdgeConv baseline")
        edgeconv = evaluate(data, cfg.input, edgeconv_weights, limit=limit)
    whole = {k: evaluate_pipeline(data, k, pipeline_limit, progress=True) for k in pipeline or []}
    text = format_tables(results, view_results, edgeconv, model, model_views, whole)
    if mirror_average:
        text = "Networks' meshes: the average of each network's answers for the image and its mirror image.\n\n" + text
    if json_out:
        from footmesh.report import write_json

        payload: dict = {k: v.summary() for k, v in results.items()}
        if edgeconv is not None:
            payload["edgeconv"] = edgeconv.summary()
        if model is not None:
            payload[MODEL_LABEL] = model.summary()
        for k, scored in whole.items():
            payload[f"pipeline_{k}"] = scored.summary() if scored.samples else {"refused": scored.refused}
        if view_results:
            payload["by_view"] = {
                k: {f"{a}{d}": list(v) for (a, d), v in view_table(s).items()} for k, s in view_results.items()
            }
        write_json(Path(json_out), json.loads(json.dumps(payload)))
    return text
