"""Training the image -> mesh network: ``footmesh train recon --input rgb|rgbd|depth --data DIR``.

Data: the images come from the 2D-cues cache (``footmesh.train.data.load_arrays``, shared with ``train cues``);
the 3D targets from a second cache beside it, ``recon-cache-<S>/`` (``vertices.npy`` (N, 4002, 3) float32 mm,
``joints3d.npy`` (N, 18, 3) float32 mm, both camera frame, and ``K.npy`` (N, 3, 3) float32, the intrinsics
resized to S px), built once from the chunk files and memory-mapped afterwards.

Augmentation changes the image only in ways that keep the 3D targets consistent: photometric changes and depth
noise (``footmesh.train.data``), and three camera-exact geometric ones about the principal point: a rotation
about the optical axis (the targets turn with it), a mirror (x -> -x: a left foot becomes a right foot, and the
template's vertex order is that of a mirrored left foot, so the targets just flip x) and a zoom (the focal
length scales; the targets stay). The cues' shifts are left out: a shifted image is another camera's only if
the principal point moves with it, and the centred crops of photos do not do that.
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

from footmesh.config import TrainConfig
from footmesh.geometry.camera import resize_intrinsics
from footmesh.recon.edgeconv import PointCloudOutput, chamfer_distance
from footmesh.recon.joints import joints_from_vertices, midfoot_aligned_error
from footmesh.recon.losses import LossWeights, mesh_loss
from footmesh.recon.model import ReconConfig, ReconNet, recon_input, update_config
from footmesh.recon.parametric import ModelOutput
from footmesh.report import atomic_path
from footmesh.train.data import _depth_noise, _photometric, load_arrays
from footmesh.train.loop import CHECKPOINT, TrainResult, run_training

log = logging.getLogger("footmesh.train")

WEIGHTS = "weights.pt"
MODEL_CARD = "MODEL_CARD.md"
HIERARCHY = "mesh_hierarchy.npz"
TARGET_KEYS = ("vertices", "joints3d", "K", "shape", "angles", "rotation", "right")
"""Cached per sample: the mesh and joints, the intrinsics, and the foot model's parameters (``kind="model"``)."""
VAL_CHAMFER_SAMPLES = 64
"""Validation of the EdgeConv baseline uses the first this many validation samples (~0.2 s per Chamfer pair)."""


# --- configuration ------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ReconAugment:
    """Ranges of the augmentation (module docstring); photometric names and meanings as ``train.data.Augment``."""

    rotate_deg: float = 25.0
    """Rotation about the optical axis, uniform in +-this."""
    flip: float = 0.5
    """Probability of mirroring the image (x -> -x)."""
    zoom: tuple[float, float] = (0.9, 1.12)
    """Focal-length factor (log-uniform); > 1 enlarges the foot."""
    brightness: tuple[float, float] = (0.6, 1.4)
    contrast: tuple[float, float] = (0.7, 1.3)
    saturation: tuple[float, float] = (0.5, 1.4)
    white_balance: float = 0.1
    noise_sd: tuple[float, float] = (0.0, 0.04)
    blur_p: float = 0.3
    jpeg_p: float = 0.4
    jpeg_quality: tuple[int, int] = (30, 95)
    depth_noise_mm: tuple[float, float] = (0.0, 2.0)
    depth_dropout_p: float = 0.3


@dataclass(frozen=True)
class ParameterLoss:
    """Weights of the model-based head's parameter terms (``kind="model"``), added to the mesh losses.

    Scales: an L1 of 0.1 SD on the shape, 0.05 rad on the angles or 0.05 on the rotation matrix's entries
    (~3 deg) each weigh about as much as 0.5-1 mm on the vertices, the size of the errors they cause.
    """

    shape: float = 5.0
    """L1 of the PCA coefficients (SD units)."""
    angles: float = 10.0
    """L1 of the 22 joint angles (rad)."""
    rotation: float = 20.0
    """L1 of the rotation matrix's 9 entries."""
    side: float = 1.0
    """Binary cross-entropy of the left/right logit."""
    centre: float = 1.0
    """L1 (mm) of the vertex centroid (the translation): without it, while the pose is still far off, the mesh
    loss pulls the centroid away from where the depth puts it (measured: 9 -> 30 mm in 30 steps from an ISM start)."""
    model_mesh: float = 1.0
    """Weight of the mesh loss on the foot model's mesh (before the residual); the final mesh weighs 1."""


def _recon_train_default() -> TrainConfig:
    # ~35 min on 2 cores at the measured speed (docs/recon.md, "Training and evaluation")
    return TrainConfig(steps=3000, batch_size=16, lr=1e-3, warmup_steps=150, val_every=500)


@dataclass(frozen=True)
class ReconTrainingConfig:
    """Everything ``footmesh train recon`` needs besides the data folder."""

    model: ReconConfig = field(default_factory=ReconConfig)
    train: TrainConfig = field(default_factory=_recon_train_default)
    augment: ReconAugment = field(default_factory=ReconAugment)
    parameter_loss: ParameterLoss = field(default_factory=ParameterLoss)
    chamfer_points: int = 1024
    """EdgeConv: target vertices drawn per sample and step for the Chamfer loss (all 4,002 cost 3x the step)."""
    residual_from: str | None = None
    """``kind="model"`` with ``residual``: an ISM network's weights whose spiral decoder layers start the residual
    decoder (its coordinate heads still start at zero), copied after ``train.init_from`` (e.g. a model-based run
    trained without the residual)."""

    train_only: tuple[str, ...] = ()
    """Submodules that train (e.g. ``["centre_refiner"]``), the rest frozen as ``train.init_from`` left them (no
    gradient, batch-norm statistics kept: ``ReconNet.train_only``); empty: the whole network."""

    def __post_init__(self) -> None:
        if self.chamfer_points < 1:
            raise ValueError(f"chamfer_points must be at least 1, got {self.chamfer_points}")
        if self.residual_from is not None and not (self.model.kind == "model" and self.model.residual):
            raise ValueError("residual_from starts a model-based network's residual decoder (kind model, residual)")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ReconTrainingConfig:
        """The defaults updated by a (partial, nested) dict; unknown keys are an error."""
        return update_config(cls(), data, "config")


def load_recon_config(path: str | os.PathLike | None) -> ReconTrainingConfig:
    """The defaults, updated from a JSON file (any subset of the fields) when given."""
    if path is None:
        return ReconTrainingConfig()
    try:
        data = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"config file not found: {path}") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"config file {path} is not valid JSON: {exc}") from None
    return ReconTrainingConfig.from_dict(data)


# --- data ---------------------------------------------------------------------------------------------------------


@dataclass
class ReconArrays:
    """Samples of one folder at side ``size``: ``rgb`` (N, S, S, 3) uint8, ``depth`` (N, S, S) uint16 mm,
    ``vertices`` (N, 4002, 3) float32 mm, ``joints3d`` (N, 18, 3) float32 mm (camera frame), ``K`` (N, 3, 3)
    float32 px of the S-side image, the foot model's ``shape`` (N, 10), ``angles`` (N, 22), ``rotation``
    (N, 3, 3) camera from foot and ``right`` (N,) 0/1, ``view_id`` (N,), ``index`` (N,)."""

    rgb: np.ndarray
    depth: np.ndarray
    vertices: np.ndarray
    joints3d: np.ndarray
    K: np.ndarray
    shape: np.ndarray
    angles: np.ndarray
    rotation: np.ndarray
    right: np.ndarray
    view_id: np.ndarray
    index: np.ndarray
    size: int

    def __len__(self) -> int:
        return len(self.index)

    def subset(self, rows: np.ndarray) -> ReconArrays:
        names = ("rgb", "depth", *TARGET_KEYS, "view_id", "index")
        return ReconArrays(**{k: getattr(self, k)[rows] for k in names}, size=self.size)


def load_recon_arrays(folder: str | os.PathLike, size: int, progress: bool = True) -> ReconArrays:
    """The images (2D-cues cache) and 3D targets (``recon-cache-<S>``) of a synthetic folder, built if missing."""
    from footmesh.synth.dataset import SynthDataset

    folder = Path(folder)
    images = load_arrays(folder, size, progress=progress)
    dataset = SynthDataset(folder, keys=["vertices", "joints3d", "K", "shape", "angles", "cam_from_foot", "side"])
    cache = folder / f"recon-cache-{size}"
    chunks = [[f.name, f.stat().st_size, f.stat().st_mtime_ns] for f in dataset.files]
    stamp = {"samples": len(dataset), "size": size, "chunks": chunks, "keys": list(TARGET_KEYS)}
    if not (cache / "stamp.json").is_file() or json.loads((cache / "stamp.json").read_text()) != stamp:
        _build_target_cache(dataset, cache, size, stamp, progress)
    targets = {k: np.load(cache / f"{k}.npy", mmap_mode="r") for k in TARGET_KEYS}
    if len(targets["vertices"]) != len(images) or not np.array_equal(np.asarray(dataset.indices), images.index):
        raise ValueError(f"{folder}: the image cache and the 3D targets hold different samples; delete the caches")
    return ReconArrays(
        rgb=images.rgb,
        depth=images.depth,
        **targets,
        view_id=images.view_id,
        index=images.index,
        size=size,
    )


def _build_target_cache(dataset, cache: Path, size: int, stamp: dict, progress: bool) -> None:
    from tqdm import tqdm

    n = len(dataset)
    cache.mkdir(parents=True, exist_ok=True)
    (cache / "stamp.json").unlink(missing_ok=True)
    first = dataset[0]
    out = {
        "vertices": np.zeros((n, *first["vertices"].shape), np.float32),
        "joints3d": np.zeros((n, *first["joints3d"].shape), np.float32),
        "K": np.zeros((n, 3, 3), np.float32),
        "shape": np.zeros((n, *first["shape"].shape), np.float32),
        "angles": np.zeros((n, *first["angles"].shape), np.float32),
        "rotation": np.zeros((n, 3, 3), np.float32),
        "right": np.zeros(n, np.float32),
    }
    for i in tqdm(range(n), desc=f"caching 3D targets of {dataset.root.name}", disable=not progress, unit="sample"):
        s = dataset[i]
        out["vertices"][i] = s["vertices"]
        out["joints3d"][i] = s["joints3d"]
        out["K"][i] = resize_intrinsics(s["K"], size / _source_size(dataset, s["K"]))
        out["shape"][i] = s["shape"]
        out["angles"][i] = s["angles"]
        out["rotation"][i] = s["cam_from_foot"][:3, :3]
        out["right"][i] = s["side"]
    for k, v in out.items():
        with atomic_path(cache / f"{k}.npy") as tmp, open(tmp, "wb") as f:
            np.save(f, v)
    with atomic_path(cache / "stamp.json") as tmp:
        tmp.write_text(json.dumps(stamp))


def _source_size(dataset, K: np.ndarray) -> int:  # noqa: N803
    """Image side of a synthetic folder: ``meta.json``'s, else from the centred principal point c = (S - 1) / 2."""
    return int(dataset.meta.get("config", {}).get("size", round(2 * float(K[0, 2]) + 1)))


@dataclass
class ReconBatch:
    """Float tensors of one batch: ``rgb`` (B, 3, S, S) in [0, 1], ``depth`` (B, 1, S, S) mm (0 = missing),
    ``K`` (B, 3, 3) px, ``vertices`` (B, V, 3) and ``joints3d`` (B, 18, 3) mm, camera frame, the foot model's
    ``shape`` (B, 10), ``angles`` (B, 22), ``rotation`` (B, 3, 3) (camera from foot) and ``right`` (B,) 0/1."""

    rgb: torch.Tensor
    depth: torch.Tensor
    K: torch.Tensor
    vertices: torch.Tensor
    joints3d: torch.Tensor
    shape: torch.Tensor
    angles: torch.Tensor
    rotation: torch.Tensor
    right: torch.Tensor

    def rows(self, keep: torch.Tensor) -> ReconBatch:
        """The samples where ``keep`` (B,) bool is True."""
        return ReconBatch(**{f.name: getattr(self, f.name)[keep] for f in fields(self)})


def make_recon_batch(arrays: ReconArrays, rows: np.ndarray) -> ReconBatch:
    """The rows of ``arrays`` as a ``ReconBatch`` (no augmentation)."""
    rows = np.sort(rows)  # sorted reads are much faster on memory-mapped arrays
    rgb = torch.from_numpy(np.ascontiguousarray(arrays.rgb[rows])).permute(0, 3, 1, 2).float() / 255
    depth = torch.from_numpy(arrays.depth[rows].astype(np.float32))[:, None]

    def tensor(a: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(a[rows], dtype=np.float32))

    return ReconBatch(rgb, depth, **{k: tensor(getattr(arrays, k)) for k in TARGET_KEYS})


def augment_recon(
    batch: ReconBatch, aug: ReconAugment, generator: torch.Generator, input_kind: str = "rgbd"
) -> ReconBatch:
    """A randomly changed copy of ``batch`` whose images, intrinsics and 3D targets still agree.

    Photometric changes are applied only where ``input_kind`` uses the image, depth noise only where it uses the
    depth map (saving their time).

    Geometry (image side S, principal point c): pixels move as ``p' - c = k R F (p - c)`` (F mirrors x, R turns
    by theta, k zooms), which is exactly the image of the targets ``(x', y') = R F (x, y)``, ``z' = z`` taken
    with the focal length ``k f`` (needs square pixels, f_x = f_y, as the synthetic cameras have). The foot
    model's rotation turns likewise; a mirror makes the foot the other side, ``R' = R F R M`` with M mirroring
    the foot frame's y (as ``FootModel`` mirrors a right foot), so that R' stays a rotation.
    """
    b, _, size, _ = batch.rgb.shape
    if not torch.allclose(batch.K[:, 0, 0], batch.K[:, 1, 1], rtol=1e-4):
        raise ValueError("rotation about the optical axis needs square pixels (f_x = f_y)")

    def uniform(lo: float, hi: float, *shape: int) -> torch.Tensor:
        return lo + (hi - lo) * torch.rand(shape or (b,), generator=generator)

    angle = torch.deg2rad(uniform(-aug.rotate_deg, aug.rotate_deg))
    flip = torch.where(torch.rand(b, generator=generator) < aug.flip, -1.0, 1.0)
    zoom = torch.exp(uniform(math.log(aug.zoom[0]), math.log(aug.zoom[1])))
    cos, sin = torch.cos(angle), torch.sin(angle)
    rot = torch.stack([torch.stack([cos, -sin], -1), torch.stack([sin, cos], -1)], -2)  # (B, 2, 2)
    rf = torch.stack([rot[..., 0] * flip.view(b, 1), rot[..., 1]], dim=-1)  # R @ diag(flip, 1)
    # affine_grid maps output to input normalised coordinates: n_in = c_n + M^-1 (n_out - c_n), M = k R F
    m_inv = torch.linalg.inv(rf * zoom.view(b, 1, 1))
    c_n = (2 * batch.K[:, :2, 2] + 1) / size - 1  # (B, 2) principal point, normalised
    shift = c_n - (m_inv @ c_n.unsqueeze(-1)).squeeze(-1)
    theta = torch.cat([m_inv, shift.unsqueeze(-1)], -1)
    grid = F.affine_grid(theta, [b, 1, size, size], align_corners=False)
    rgb = F.grid_sample(batch.rgb, grid, mode="bilinear", padding_mode="border", align_corners=False)
    depth = F.grid_sample(batch.depth, grid, mode="nearest", padding_mode="border", align_corners=False)

    def turn(points: torch.Tensor) -> torch.Tensor:
        xy = points[..., :2] @ rf.transpose(1, 2)
        return torch.cat([xy, points[..., 2:]], -1)

    K = batch.K.clone()  # noqa: N806
    K[:, 0, 0] *= zoom
    K[:, 1, 1] *= zoom
    if input_kind != "depth":
        rgb = _photometric(rgb, aug, generator, uniform)
    if input_kind != "rgb":
        depth = _depth_noise(depth, aug, generator, uniform)
    turn3 = torch.zeros(b, 3, 3)
    turn3[:, :2, :2] = rf
    turn3[:, 2, 2] = 1.0
    mirror_y = torch.ones(b, 3)
    mirror_y[:, 1] = flip
    rotation = turn3 @ batch.rotation * mirror_y.unsqueeze(1)  # (R F R) @ diag(1, flip, 1)
    right = torch.where(flip < 0, 1.0 - batch.right, batch.right)
    return ReconBatch(
        rgb, depth, K, turn(batch.vertices), turn(batch.joints3d), batch.shape, batch.angles, rotation, right
    )


MIN_DEPTH_PIXELS = 64
"""A training sample whose (augmented) depth map has fewer valid pixels than this is left out of its batch: a
zoom or a dropout blob can empty a map that had only a few foot pixels, and such a map cannot give the scale."""


def keep_with_depth(batch: ReconBatch) -> ReconBatch:
    """The samples of ``batch`` with at least ``MIN_DEPTH_PIXELS`` valid depth pixels (at least one sample kept:
    the one with the most, so that a batch is never empty)."""
    counts = (batch.depth > 0).flatten(1).sum(1)
    keep = counts >= MIN_DEPTH_PIXELS
    if bool(keep.all()):
        return batch
    if not bool(keep.any()):
        keep = counts == counts.max()
    return batch.rows(keep)


# --- loss and validation ----------------------------------------------------------------------------------------


def recon_loss(
    output, batch: ReconBatch, faces: torch.Tensor | None, config: ReconTrainingConfig, generator: torch.Generator
) -> tuple[torch.Tensor, dict[str, float]]:
    """The mesh loss of ``config.model.loss`` (ISM), or the Chamfer distance (EdgeConv), and its logged terms."""
    if isinstance(output, PointCloudOutput):
        n = batch.vertices.shape[1]
        k = min(config.chamfer_points, n)
        rows = torch.randperm(n, generator=generator)[:k]
        loss = chamfer_distance(output.points, batch.vertices[:, rows]).mean()
        return loss, {"loss": float(loss.detach()), "chamfer_mm": float(loss.detach())}
    weights = LossWeights.thesis() if config.model.loss == "thesis" else LossWeights.structure()
    terms = mesh_loss(output.vertices, batch.vertices, faces, weights)
    logged = terms.as_dict()
    total = terms.total
    if isinstance(output, ModelOutput):
        total = total + _parameter_loss(output, batch, faces, weights, config.parameter_loss, logged)
    logged["loss"] = float(total.detach())
    del logged["total"]
    with torch.no_grad():
        logged["vertex_mm"] = float((output.vertices - batch.vertices).norm(dim=-1).mean())
        # how much of the error is placement: the centroid's distance from the true one
        logged["centre_mm"] = float((output.centre - batch.vertices.mean(1)).norm(dim=-1).mean())
    return total, logged


def _parameter_loss(
    output: ModelOutput,
    batch: ReconBatch,
    faces: torch.Tensor,
    weights: LossWeights,
    w: ParameterLoss,
    logged: dict[str, float],
) -> torch.Tensor:
    """The model-based head's terms (``ParameterLoss``): the mesh loss on the foot model's mesh, L1 on its
    parameters, the side's cross-entropy; adds each to ``logged``."""
    p = output.parameters
    model_mesh = mesh_loss(output.model_vertices, batch.vertices, faces, weights).total
    k = p.shape.shape[1]
    terms = {
        "model_mesh": w.model_mesh * model_mesh,
        "shape": w.shape * (p.shape - batch.shape[:, :k]).abs().mean(),
        "angles": w.angles * (p.angles - batch.angles).abs().mean(),
        "rotation": w.rotation * (p.rotation - batch.rotation).abs().mean(),
        "side": w.side * F.binary_cross_entropy_with_logits(p.right_logit, batch.right),
        "centre": w.centre * (output.centre - batch.vertices.mean(1)).abs().sum(-1).mean(),
    }
    for name, value in terms.items():
        logged[name] = float(value.detach())
    with torch.no_grad():
        logged["model_vertex_mm"] = float((output.model_vertices - batch.vertices).norm(dim=-1).mean())
    return sum(terms.values())


class ReconTask:
    """Batches of the training folder (augmented) and the metrics of its validation slice."""

    def __init__(self, train: ReconArrays, val: ReconArrays, config: ReconTrainingConfig, faces) -> None:
        self.train, self.val, self.config, self.faces = train, val, config, faces
        self.steps_done = 0
        """Steps whose loss was asked for, i.e. the step count after the current one (for the exported info)."""

    def loss(self, model: nn.Module, step: int, generator: torch.Generator, rank: int, world: int):
        self.steps_done = step + 1
        bs = self.config.train.batch_size
        rows = torch.randint(len(self.train), (bs * world,), generator=generator)[rank * bs : (rank + 1) * bs]
        batch = make_recon_batch(self.train, rows.numpy())
        if self.config.train.augment:
            batch = augment_recon(batch, self.config.augment, generator, self.config.model.input)
        if self.config.model.input != "rgb":
            batch = keep_with_depth(batch)
        x, ref = recon_input(self.config.model.input, batch.rgb, batch.depth)
        # the model-based head builds the mesh for the true side (its side logit learns from the cross-entropy)
        right = batch.right > 0.5 if self.config.model.kind == "model" else None
        return recon_loss(model(x, batch.K, ref, right), batch, self.faces, self.config, generator)

    @torch.no_grad()
    def validate(self, model: nn.Module) -> dict[str, float]:
        return evaluate_arrays(model, self.val)


@torch.no_grad()
def evaluate_arrays(model: ReconNet, arrays: ReconArrays, batch_size: int = 32) -> dict[str, float]:
    """Mean per-vertex error and midfoot-aligned joint error (mm) of a mesh network, or the mean Chamfer
    distance (mm, first ``VAL_CHAMFER_SAMPLES`` samples) of the EdgeConv baseline."""
    edgeconv = model.config.kind == "edgeconv"
    n = min(len(arrays), VAL_CHAMFER_SAMPLES) if edgeconv else len(arrays)
    total = {"vertex_mm": 0.0, "joint_mm": 0.0} if not edgeconv else {"chamfer_mm": 0.0}
    for start in range(0, n, batch_size):
        rows = np.arange(start, min(start + batch_size, n))
        batch = make_recon_batch(arrays, rows)
        x, ref = recon_input(model.config.input, batch.rgb, batch.depth)
        out = model(x, batch.K, ref)
        if edgeconv:
            total["chamfer_mm"] += float(chamfer_distance(out.points, batch.vertices).sum())
            continue
        total["vertex_mm"] += float((out.vertices - batch.vertices).norm(dim=-1).mean(1).sum())
        joints = joints_from_vertices(out.vertices)
        total["joint_mm"] += float(midfoot_aligned_error(joints, batch.joints3d)[:, 1:].mean(1).sum())
    return {k: v / max(n, 1) for k, v in total.items()}


FIRST_CONVS = ("encoder.stem.0.0.weight", "encoder.net._conv_stem.weight")
"""The convolutions that see the input channels (ResNet, EfficientNet; adapted between input kinds by
``copy_matching``)."""
_CHANNELS = {"rgb": ("r", "g", "b"), "rgbd": ("r", "g", "b", "d"), "depth": ("d",)}


def copy_matching(model: ReconNet, state: dict[str, torch.Tensor], source: ReconConfig) -> int:
    """Copy the tensors of ``state`` (a network for ``source``) whose names and shapes match into ``model``.

    The first convolution is adapted between input kinds channel by channel (RGB-D -> RGB keeps the colour
    filters, -> depth the depth filter, the coordinate channels follow); channels the source lacks start at 0.
    Returns the number of tensors copied.
    """
    own = model.state_dict()
    copied = 0
    for source_name, value in state.items():
        name = _target_name(source_name, source, model.config)
        if name not in own:
            continue
        target = own[name]
        if value.shape == target.shape:
            own[name] = value.to(target.dtype)
            copied += 1
        elif name in FIRST_CONVS and value.shape[0] == target.shape[0] and value.shape[2:] == target.shape[2:]:
            src = _CHANNELS[source.input] + (("x", "y") if source.coord_channels else ())
            dst = _CHANNELS[model.config.input] + (("x", "y") if model.config.coord_channels else ())
            adapted = torch.zeros_like(target)
            for i, channel in enumerate(dst):
                if channel in src:
                    adapted[:, i] = value[:, src.index(channel)]
            own[name] = adapted
            copied += 1
    model.load_state_dict(own)
    return copied


def _target_name(name: str, source: ReconConfig, target: ReconConfig) -> str | None:
    """Where a tensor of a ``source`` network goes in a ``target`` one (None: nowhere). From an ISM decoder to
    the model-based head: its centroid head places the foot model's mesh, its spiral layers start the residual
    decoder, and its coordinate heads are left out (the residual starts at zero, the first mesh the foot model's)."""
    if source.kind == "ism" and target.kind == "model":
        if name.startswith("decoder.heads."):
            return None
        if name.startswith("decoder.output."):
            return "placement." + name.removeprefix("decoder.output.")
    return name


# --- the run ------------------------------------------------------------------------------------------------------


def train_recon(
    data: str | os.PathLike, out: str | os.PathLike, config: ReconTrainingConfig, progress: bool = True
) -> TrainResult:
    """Train (or resume training) the reconstruction network on a synthetic folder.

    Writes ``out/checkpoint.pt`` and ``log.csv`` (``footmesh.train.loop``), and at every checkpoint
    ``out/weights.pt`` (``footmesh.recon.weights``, half precision) and ``out/MODEL_CARD.md``.
    """
    from footmesh.recon.hierarchy import template_hierarchy
    from footmesh.recon.weights import read_weights, save_weights, write_model_card

    cfg = config.model
    arrays = load_recon_arrays(data, cfg.image_size, progress=progress)
    n_val = max(1, int(round(len(arrays) * config.train.val_fraction)))
    if len(arrays) - n_val < config.train.batch_size:
        raise ValueError(f"{data} has {len(arrays)} samples: too few for batches of {config.train.batch_size}")
    train = arrays.subset(np.arange(len(arrays) - n_val))
    val = arrays.subset(np.arange(len(arrays) - n_val, len(arrays)))
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    hierarchy = None
    if cfg.spiral_decoder:
        hierarchy = template_hierarchy(
            cache=out / HIERARCHY, spiral_length=cfg.decoder.spiral_length, dilation=cfg.decoder.dilation
        )
    torch.manual_seed(config.train.seed)
    model = ReconNet(cfg, hierarchy)
    fresh = not (out / CHECKPOINT).is_file()  # a resumed run loads everything from its checkpoint
    if fresh and config.train.init_from:
        state, source, _ = read_weights(config.train.init_from)
        copied = copy_matching(model, state, source)
        log.info("initialised %d tensors from %s", copied, config.train.init_from)
    elif fresh and cfg.encoder == "efficientnet_lite0":
        log.info("encoder: %d ImageNet tensors from the packaged EfficientNet-Lite0", model.encoder.load_pretrained())
    if fresh and config.residual_from:
        state, source, _ = read_weights(config.residual_from)
        if source.kind != "ism":
            raise ValueError(f"residual_from must hold an ISM network, {config.residual_from} holds {source.kind!r}")
        # the spiral layers only: the placement stays the init_from network's (and _target_name drops the heads)
        layers = {k: v for k, v in state.items() if k.startswith("decoder.") and not k.startswith("decoder.output.")}
        log.info("residual decoder: %d tensors from %s", copy_matching(model, layers, source), config.residual_from)
    # decided from the configuration, not from ``fresh``: a resumed run must rebuild the same parameter groups
    model.initialised_from_network = bool(config.train.init_from)
    if config.train_only:
        model.train_only(config.train_only)
    task = ReconTask(train, val, config, None if cfg.kind == "edgeconv" else model.faces)
    data_info = {"folder": str(Path(data)), "samples": len(arrays), "train": len(train), "val": len(val)}
    meta = Path(data) / "meta.json"
    if meta.is_file():
        m = json.loads(meta.read_text())
        data_info.update({"seed": m.get("seed"), "size": m.get("config", {}).get("size")})

    def export(model: nn.Module, metrics: dict[str, float]) -> None:
        info = {"training": config.to_dict(), "validation": metrics, "data": data_info, "steps_done": task.steps_done}
        save_weights(out / WEIGHTS, model, cfg, info, hierarchy)
        write_model_card(out / MODEL_CARD, cfg, info, model)

    return run_training(model, task, out, config.train, config.to_dict(), progress, on_checkpoint=export)
