"""The shipped 2D-cues weights (``weights/<input>.pt``, half precision) and their loading and saving."""

from __future__ import annotations

import os
import pickle
from dataclasses import asdict
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any

import torch
from torch import nn

from footmesh.config import CuesNetConfig
from footmesh.report import atomic_path

FORMAT = "footmesh-cues-1"


def packaged_weights(input_kind: str) -> Path:
    """Path of the shipped weights for ``input_kind`` (rgb, rgbd, depth)."""
    path = Path(str(resources.files("footmesh.cues") / "weights" / f"{input_kind}.pt"))
    if not path.is_file():
        raise FileNotFoundError(f"no shipped 2D-cues weights for {input_kind!r} input ({path})")
    return path


def save_weights(path: str | os.PathLike, model: nn.Module, config: CuesNetConfig, info: dict[str, Any]) -> None:
    """Write ``model``'s weights in half precision (half the size; no measurable change in the outputs)."""
    state = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, "config": asdict(config), "state_dict": state, "info": info}, tmp)


def _read(path: str | os.PathLike) -> dict[str, Any]:
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"weights file not found: {path}") from None
    except (pickle.UnpicklingError, RuntimeError, KeyError, EOFError, ValueError) as exc:
        raise ValueError(f"{path} is not a footmesh 2D-cues weights file ({type(exc).__name__})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path} is not a footmesh 2D-cues weights file")
    return data


def load_state(path: str | os.PathLike) -> dict[str, torch.Tensor]:
    """The float32 state dict of a weights file."""
    return _float_state(_read(path))


def _float_state(data: dict[str, Any]) -> dict[str, torch.Tensor]:
    return {k: (v.float() if v.is_floating_point() else v) for k, v in data["state_dict"].items()}


def load_network(path: str | os.PathLike) -> tuple[nn.Module, CuesNetConfig, dict[str, Any]]:
    """The network of a weights file, in eval mode, its configuration and its info (training, metrics)."""
    from footmesh.cues.net import build_network

    data = _read(path)
    cfg = data["config"]
    config = CuesNetConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in cfg.items()})
    model = build_network(config)
    model.load_state_dict(_float_state(data))
    model.eval()
    return model, config, data.get("info", {})


@lru_cache(maxsize=8)
def _cached_network(path: str) -> tuple[nn.Module, CuesNetConfig, dict[str, Any]]:
    return load_network(path)


def network_for(input_kind: str, path: str | os.PathLike | None = None) -> tuple[nn.Module, CuesNetConfig]:
    """The shipped network for ``input_kind`` (or the one at ``path``), loaded once per process."""
    path = path or packaged_weights(input_kind)
    model, config, _ = _cached_network(str(path))
    if config.input != input_kind:
        raise ValueError(f"{path} holds a network for {config.input!r} input, not {input_kind!r}")
    return model, config
