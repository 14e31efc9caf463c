"""Turning images and depth maps into network input tensors, the same way for training and for prediction."""

from __future__ import annotations

import numpy as np
import torch

RGB_MEAN = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
RGB_STD = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
DEPTH_UNIT_MM = 100.0
"""Depth is fed relative to the image's median valid depth, in units of 100 mm (a foot spans about +-1.5)."""
DEPTH_CLIP = 4.0


def normalise_rgb(rgb: torch.Tensor) -> torch.Tensor:
    """(B, 3, S, S) float in [0, 1] -> standardised channels."""
    return (rgb - RGB_MEAN.to(rgb)) / RGB_STD.to(rgb)


def normalise_depth(depth_mm: torch.Tensor) -> torch.Tensor:
    """(B, 1, S, S) mm (0 = missing) -> depth relative to each image's median valid depth, 0 where missing.

    Relative depth makes the network independent of the camera distance (which the fit stage gets from the depth
    map itself); missing pixels read as the median, the least surprising value.
    """
    valid = depth_mm > 0
    flat = torch.where(valid, depth_mm, torch.nan).flatten(1)
    ref = torch.nanmedian(flat, dim=1).values.nan_to_num(0.0).view(-1, 1, 1, 1)
    rel = ((depth_mm - ref) / DEPTH_UNIT_MM).clamp(-DEPTH_CLIP, DEPTH_CLIP)
    return torch.where(valid, rel, torch.zeros_like(rel))


def network_input(input_kind: str, rgb: torch.Tensor | None, depth_mm: torch.Tensor | None) -> torch.Tensor:
    """Stack the channels of ``input_kind`` (rgb: 3, rgbd: 4, depth: 1) from (B, 3, S, S) [0, 1] and (B, 1, S, S) mm."""
    parts = []
    if input_kind in ("rgb", "rgbd"):
        if rgb is None:
            raise ValueError(f"{input_kind} input needs an RGB image")
        parts.append(normalise_rgb(rgb))
    if input_kind in ("rgbd", "depth"):
        if depth_mm is None:
            raise ValueError(f"{input_kind} input needs a depth map")
        parts.append(normalise_depth(depth_mm))
    if not parts:
        raise ValueError(f"unknown input kind {input_kind!r}")
    return torch.cat(parts, dim=1)


def to_tensors(rgb: np.ndarray | None, depth_mm: np.ndarray | None) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """(S, S, 3) uint8 and (S, S) mm arrays -> (1, 3, S, S) [0, 1] and (1, 1, S, S) float tensors."""
    t_rgb = None if rgb is None else torch.from_numpy(np.ascontiguousarray(rgb)).permute(2, 0, 1)[None].float() / 255
    t_depth = None if depth_mm is None else torch.from_numpy(np.asarray(depth_mm, dtype=np.float32))[None, None]
    return t_rgb, t_depth
