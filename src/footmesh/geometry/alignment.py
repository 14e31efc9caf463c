"""Least-squares alignment of corresponding points: ``target ~ s R source + t`` (Umeyama 1991), weighted.

One implementation, batched in torch (differentiable; the canonicalisation fits it inside its optimisation);
``umeyama`` is its NumPy face for single point sets.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Similarity:
    """``x -> scale * rotation @ x + translation``."""

    scale: float
    rotation: np.ndarray  # (3, 3) proper rotation
    translation: np.ndarray  # (3,)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, 3)."""
        return self.scale * points @ self.rotation.T + self.translation

    def inverse_apply(self, points: np.ndarray) -> np.ndarray:
        """The inverse of ``apply``."""
        return (points - self.translation) @ self.rotation / self.scale


def weighted_procrustes(source: Any, target: Any, weights: Any) -> tuple[Any, Any, Any]:
    """Similarity transform ``target ~ s R source + t`` by weighted least squares (torch).

    Args:
        source: (B, N, 3) or (N, 3). target: (B, N, 3). weights: (N,) non-negative, not all zero.
    Returns:
        rotation (B, 3, 3) proper, scale (B,), translation (B, 3).
    """
    import torch

    if source.dim() == 2:
        source = source.unsqueeze(0).expand_as(target)
    w = (weights / weights.sum()).to(target).reshape(1, -1, 1)
    mu_s, mu_t = (w * source).sum(1), (w * target).sum(1)  # (B, 3)
    xs, xt = source - mu_s.unsqueeze(1), target - mu_t.unsqueeze(1)
    cov = (w * xt).transpose(1, 2) @ xs  # (B, 3, 3) = sum_i w_i t_i s_i^T
    u, sv, vh = torch.linalg.svd(cov)
    sign = torch.sign(torch.linalg.det(u @ vh))
    d = torch.stack([torch.ones_like(sign), torch.ones_like(sign), sign], dim=-1)  # (B, 3)
    rotation = u @ torch.diag_embed(d) @ vh
    scale = (sv * d).sum(-1) / (w * xs**2).sum((1, 2))
    translation = mu_t - scale.unsqueeze(-1) * (rotation @ mu_s.unsqueeze(-1)).squeeze(-1)
    return rotation, scale, translation


def umeyama(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None) -> Similarity:
    """Least-squares similarity with ``target ~ s R source + t`` for (N, 3) point sets, optional (N,) weights."""
    import torch

    src = torch.as_tensor(np.asarray(source, dtype=np.float64))
    dst = torch.as_tensor(np.asarray(target, dtype=np.float64))
    w = torch.ones(len(src), dtype=torch.float64) if weights is None else torch.as_tensor(weights, dtype=torch.float64)
    rotation, scale, translation = weighted_procrustes(src, dst[None], w)
    return Similarity(float(scale[0]), rotation[0].numpy(), translation[0].numpy())
