"""Box-limited Levenberg-Marquardt: the damped, bounds-aware solve that every solver of footmesh takes its steps
with (batched, torch).

``model.ik.solve_branch_ik`` and ``model.canonical.canonicalise`` use ``damped_step`` (from the Jacobian),
``fit.core`` uses ``solve_damped`` (from the normal equations it has already formed): Marquardt's diagonal
scaling, a damping per item, and a projection for the box limits of the joint angles (the ``held`` parameters are
fixed for the step; the caller clamps the step into the box). What differs between the solvers is their policy
around it: which parameters are held (``held_at_bounds``: pushed out by the gradient; the fit: pushed out by the
step itself, re-solved), and how the damping moves (``next_damping``; the fit: Nielsen's rule).
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
    return solve_damped(jac.transpose(-1, -2) @ jac, descent, damping, held, relative_floor=floor)


def solve_damped(
    normal: torch.Tensor,
    descent: torch.Tensor,
    damping: torch.Tensor | float,
    held: torch.Tensor,
    relative_floor: float = 0.0,
    absolute_floor: float = 1e-12,
) -> torch.Tensor:
    """The step (..., P) solving ``(N + damping diag(s)) d = descent`` over the parameters not ``held`` (held: 0).

    Args:
        normal: (..., P, P) ``J^T J``. descent: (..., P) ``-J^T r``. damping: (...,) or a number.
        held: (..., P) bool, fixed for this step.
        relative_floor, absolute_floor: Marquardt's scale is ``s = diag(N) + relative_floor * mean(diag(N)) +
            absolute_floor`` (a parameter with no effect still gets a finite, damped step).
    """
    free = (~held).to(normal.dtype)
    normal = normal * free.unsqueeze(-1) * free.unsqueeze(-2)  # a held parameter couples to nothing
    diag = torch.diagonal(normal, dim1=-2, dim2=-1)
    scale = diag + relative_floor * diag.mean(-1, keepdim=True) + absolute_floor
    damping = torch.as_tensor(damping, dtype=normal.dtype)
    system = normal + torch.diag_embed(damping.unsqueeze(-1) * scale + held.to(normal.dtype))
    return torch.linalg.solve(system, (descent * free).unsqueeze(-1)).squeeze(-1) * free


def next_damping(
    damping: torch.Tensor, better: torch.Tensor, down: float, up: float, limits: tuple[float, float]
) -> torch.Tensor:
    """Damping after a trial step: times ``down`` where it lowered the cost, times ``up`` where not, clamped."""
    return torch.where(better, damping * down, damping * up).clamp(*limits)
