"""Box-limited Levenberg-Marquardt, batched in torch: the step and the damping of the model's solvers.

``model.ik.solve_branch_ik`` and ``model.canonical.canonicalise`` take their steps here: Marquardt's diagonal
scaling, a damping per item, and a projection for the box limits of the joint angles (a parameter on a bound that
the gradient pushes outwards is held for the step; the step is then clamped into the box by the caller). The fit
(``fit.core``) runs its own staged solver on NumPy (active sets re-solved within a step, Nielsen's damping
update), which these two do not need.
"""

from __future__ import annotations

import torch


def held_at_bounds(x: torch.Tensor, descent: torch.Tensor, lower: torch.Tensor, upper: torch.Tensor) -> torch.Tensor:
    """(..., P) bool: parameters on a bound that the descent direction pushes out of the box."""
    return ((x <= lower) & (descent < 0)) | ((x >= upper) & (descent > 0))


def damped_step(
    jac: torch.Tensor, descent: torch.Tensor, damping: torch.Tensor, held: torch.Tensor, floor: float
) -> torch.Tensor:
    """The Levenberg-Marquardt step (..., P) with the ``held`` parameters fixed.

    Args:
        jac: (..., M, P) Jacobian of the residuals. descent: (..., P) ``-J^T r`` (the direction that lowers
            the cost). damping: (...,) per item. held: (..., P) bool.
        floor: Marquardt's scale ``diag(J^T J)`` is kept at least ``floor`` times its mean, so that a
            parameter with no effect still gets a finite, damped step.
    """
    free = (~held).to(jac.dtype)
    jac = jac * free.unsqueeze(-2)
    descent = descent * free
    jtj = jac.transpose(-1, -2) @ jac  # (..., P, P)
    diag = torch.diagonal(jtj, dim1=-2, dim2=-1)
    scale = diag + floor * diag.mean(-1, keepdim=True) + 1e-12
    system = jtj + torch.diag_embed(damping.unsqueeze(-1) * scale + held.to(jac.dtype))
    return torch.linalg.solve(system, descent.unsqueeze(-1)).squeeze(-1) * free


def next_damping(
    damping: torch.Tensor, better: torch.Tensor, down: float, up: float, limits: tuple[float, float]
) -> torch.Tensor:
    """Damping after a trial step: times ``down`` where it lowered the cost, times ``up`` where not, clamped."""
    return torch.where(better, damping * down, damping * up).clamp(*limits)
