"""The shared box-limited Levenberg-Marquardt step (footmesh.optim) on problems with known answers."""

from __future__ import annotations

import torch

from footmesh import optim


def test_an_undamped_step_solves_linear_least_squares_and_a_held_parameter_stays():
    torch.manual_seed(0)
    jac = torch.randn(3, 10, 4, dtype=torch.float64)  # a batch of 3 linear problems r = J x - b
    truth = torch.randn(3, 4, dtype=torch.float64)
    b = (jac @ truth.unsqueeze(-1)).squeeze(-1)
    x = torch.zeros(3, 4, dtype=torch.float64)
    descent = (jac.transpose(1, 2) @ b.unsqueeze(-1)).squeeze(-1)  # -J^T r at x = 0
    none = torch.zeros(3, 4, dtype=torch.bool)
    step = optim.damped_step(jac, descent, torch.zeros(3, dtype=torch.float64), none, floor=1e-9)
    torch.testing.assert_close(step, truth)
    # parameter 2 on its upper bound, pushed outwards: held, the others solve the rest of the problem
    upper = torch.full((4,), torch.inf, dtype=torch.float64)
    upper[2] = 0.0
    push = descent.clone()
    push[:, 2] = 1.0
    held = optim.held_at_bounds(x, push, torch.full_like(upper, -torch.inf), upper)
    assert held[:, 2].all() and not held[:, [0, 1, 3]].any()
    step = optim.damped_step(jac, push, torch.zeros(3, dtype=torch.float64), held, floor=1e-9)
    assert (step[:, 2] == 0).all()
    free = [0, 1, 3]
    expected = torch.linalg.lstsq(jac[..., free], b).solution
    torch.testing.assert_close(step[:, free], expected)


def test_damping_falls_after_a_better_step_and_rises_after_a_worse_one_within_its_limits():
    damping = torch.tensor([1e-3, 1e-3, 5e7])
    better = torch.tensor([True, False, False])
    out = optim.next_damping(damping, better, 1 / 3, 4.0, (1e-9, 1e8))
    torch.testing.assert_close(out, torch.tensor([1e-3 / 3, 4e-3, 1e8]))
