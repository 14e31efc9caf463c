"""Inverse kinematics and random poses (``footmesh.model.ik``): FK -> IK round trips, limits, distributions."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _toy_model import model_asset
from hypothesis import given, settings
from hypothesis import strategies as st

from footmesh.model import ik, lbs
from footmesh.model import skeleton as sk

TIPS = list(sk.TIP_JOINTS)
LOWER = torch.tensor(sk.DOF_LOWER, dtype=torch.float64)
UPPER = torch.tensor(sk.DOF_UPPER, dtype=torch.float64)


@pytest.fixture(scope="module")
def rest_joints() -> torch.Tensor:
    asset = model_asset()
    return torch.from_numpy((asset.joint_regressor @ asset.mean_vertices).astype(np.float64))


def _in_limits(angles: torch.Tensor) -> bool:
    return bool(((angles >= LOWER) & (angles <= UPPER)).all())


in_limit_angles = st.tuples(*[st.floats(lo, hi) for lo, hi in zip(sk.DOF_LOWER, sk.DOF_UPPER, strict=True)])


def test_angles_from_joints_inverts_fk(rest_joints):
    angles = ik.uniform_angles(1000, 0)
    posed, _ = lbs.forward_kinematics(angles, rest_joints)
    recovered = ik.angles_from_joints(posed, rest_joints)
    assert (recovered - angles).abs().max() < 1e-6  # brief: 1e-3 rad
    # per-item rest joints (B, 18, 3), float32
    rest = rest_joints.expand(1000, -1, -1).float()
    recovered32 = ik.angles_from_joints(posed.float(), rest)
    assert (recovered32.double() - angles).abs().max() < 1e-3


@settings(max_examples=60, deadline=None)
@given(in_limit_angles)
def test_angles_from_joints_property(rest_joints, values):
    angles = torch.tensor([values], dtype=torch.float64)
    posed, _ = lbs.forward_kinematics(angles, rest_joints)
    torch.testing.assert_close(ik.angles_from_joints(posed, rest_joints), angles, atol=1e-8, rtol=0)


def test_angles_from_joints_clamps_out_of_limit_poses(rest_joints):
    wild = torch.linspace(-2.5, 2.5, 10 * sk.NUM_DOFS, dtype=torch.float64).reshape(10, sk.NUM_DOFS)
    posed, _ = lbs.forward_kinematics(wild, rest_joints)
    recovered = ik.angles_from_joints(posed, rest_joints)
    assert _in_limits(recovered)
    inside = (wild >= LOWER) & (wild <= UPPER)
    assert inside[:, 0].any()  # the first segment below the root is never compensated by a parent
    torch.testing.assert_close(recovered[:, 0][inside[:, 0]], wild[:, 0][inside[:, 0]])


def test_solve_branch_ik_reaches_reachable_targets(rest_joints):
    angles = ik.uniform_angles(500, 1)
    posed, _ = lbs.forward_kinematics(angles, rest_joints)
    solved = ik.solve_branch_ik(rest_joints, posed[:, TIPS])
    assert _in_limits(solved)
    reached, _ = lbs.forward_kinematics(solved, rest_joints)
    assert (reached[:, TIPS] - posed[:, TIPS]).norm(dim=-1).max() < 0.1  # mm


def test_solve_branch_ik_stays_put_at_the_solution(rest_joints):
    angles = ik.uniform_angles(20, 2)
    posed, _ = lbs.forward_kinematics(angles, rest_joints)
    assert torch.equal(ik.solve_branch_ik(rest_joints, posed[:, TIPS], init=angles), angles)


def test_solve_branch_ik_improves_on_unreachable_targets(rest_joints):
    """Targets pulled off the workspace: still inside the limits, and no worse than the closed-form start."""
    g = torch.Generator().manual_seed(3)
    angles = ik.uniform_angles(50, g)
    posed, _ = lbs.forward_kinematics(angles, rest_joints)
    targets = posed[:, TIPS] + 8.0 * torch.randn(50, 6, 3, generator=g, dtype=torch.float64)
    solved = ik.solve_branch_ik(rest_joints, targets)
    none = ik.solve_branch_ik(rest_joints, targets, iters=0)
    assert _in_limits(solved)
    err = lambda a: (lbs.forward_kinematics(a, rest_joints)[0][:, TIPS] - targets).norm(dim=-1)  # noqa: E731
    assert (err(solved) <= err(none) + 1e-9).all()
    assert err(solved).mean() < err(none).mean()


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-400.0, 400.0), min_size=18, max_size=18))
def test_solve_branch_ik_never_leaves_the_limits(rest_joints, coords):
    targets = torch.tensor(coords, dtype=torch.float64).reshape(1, 6, 3)
    assert _in_limits(ik.solve_branch_ik(rest_joints, targets, iters=10))


@pytest.mark.parametrize("method", ["ik", "uniform", "natural"])
def test_sample_poses(rest_joints, method):
    a = ik.sample_poses(rest_joints, 11, 300, method=method)
    assert a.shape == (300, sk.NUM_DOFS) and a.dtype == torch.float64
    assert _in_limits(a)
    assert torch.equal(a, ik.sample_poses(rest_joints, 11, 300, method=method))  # deterministic
    b = ik.sample_poses(rest_joints.expand(300, -1, -1), np.random.default_rng(0), 300, method=method)
    assert _in_limits(b) and not torch.equal(a, b)


def test_sample_poses_ik_reaches_the_drawn_tips(rest_joints):
    """ "ik": the tips are those of uniform angles; the heel branch (not redundant) keeps the uniform angles."""
    n = 400
    drawn = ik.uniform_angles(n, 5)
    solved = ik.sample_poses(rest_joints, 5, n, method="ik")
    tips = lambda a: lbs.forward_kinematics(a, rest_joints)[0][:, TIPS]  # noqa: E731
    assert (tips(solved) - tips(drawn)).norm(dim=-1).max() < 0.1
    torch.testing.assert_close(solved[:, :2], drawn[:, :2])


def test_uniform_moments():
    a = ik.sample_poses(torch.zeros(18, 3), 0, 20000, method="uniform")
    mid, half = (UPPER + LOWER) / 2, (UPPER - LOWER) / 2
    torch.testing.assert_close(a.mean(0), mid, atol=0.02 * 2 * half.max().item(), rtol=0)
    torch.testing.assert_close(a.std(0), half / 3**0.5, atol=0.02, rtol=0.05)


def test_bad_inputs(rest_joints):
    with pytest.raises(ValueError):
        ik.angles_from_joints(torch.zeros(2, 17, 3), rest_joints)
    with pytest.raises(ValueError):
        ik.solve_branch_ik(rest_joints, torch.zeros(2, 5, 3))
    with pytest.raises(ValueError):
        ik.angles_from_joints(torch.zeros(2, 18, 3, dtype=torch.float64), rest_joints.expand(3, -1, -1))
    with pytest.raises(ValueError):
        ik.sample_poses(rest_joints, 0, 3, method="gaussian")
