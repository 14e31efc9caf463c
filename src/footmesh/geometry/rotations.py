"""Rotations: cross-product matrices and the rotation between two directions."""

from __future__ import annotations

from typing import Any

import numpy as np


def skew(w: Any) -> Any:
    """(..., 3) -> (..., 3, 3) cross-product matrices, ``skew(w) @ u = w x u`` (NumPy or torch, as given)."""
    if hasattr(w, "new_zeros"):  # a torch tensor
        import torch

        z = torch.zeros_like(w[..., 0])
        rows = [z, -w[..., 2], w[..., 1], w[..., 2], z, -w[..., 0], -w[..., 1], w[..., 0], z]
        return torch.stack(rows, dim=-1).reshape(*w.shape, 3)
    w = np.asarray(w)
    z = np.zeros_like(w[..., 0])
    rows = [z, -w[..., 2], w[..., 1], w[..., 2], z, -w[..., 0], -w[..., 1], w[..., 0], z]
    return np.stack(rows, axis=-1).reshape(*w.shape, 3)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) turning unit vector ``a`` onto unit vector ``b`` (Rodrigues), the shortest turn."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:  # opposite: turn by pi about any axis perpendicular to a
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = skew(v)
    return np.eye(3) + vx + vx @ vx / (1.0 + c)
