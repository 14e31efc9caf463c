"""Forward kinematics and linear blend skinning (``footmesh.model.lbs``): gradients, identities, a naive loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _toy_model import model_asset

from footmesh.model import lbs
from footmesh.model import skeleton as sk
from footmesh.model.ik import uniform_angles


@pytest.fixture(scope="module")
def asset():
    return model_asset()


@pytest.fixture(scope="module")
def rest_joints(asset) -> torch.Tensor:
    return torch.from_numpy((asset.joint_regressor @ asset.mean_vertices).astype(np.float64))


def _naive_fk(angles: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One item, joint by joint from the definitions: P_c = P_p + G_c (J_c - J_p), G_c = G_p R_y R_z."""

    def ry(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])

    def rz(a):
        c, s = np.cos(a), np.sin(a)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    y, z = np.zeros(sk.NUM_JOINTS), np.zeros(sk.NUM_JOINTS)
    for value, dof in zip(angles, sk.DOFS, strict=True):
        (y if dof.axis == "y" else z)[dof.joint] = value
    rot = [np.eye(3)]
    pos = [rest[0]]
    for c in range(1, sk.NUM_JOINTS):
        p = sk.PARENTS[c]
        rot.append(rot[p] @ ry(y[c]) @ rz(z[c]))
        pos.append(pos[p] + rot[c] @ (rest[c] - rest[p]))
    return np.array(pos), np.array(rot)


def test_rotation_conventions():
    a = torch.tensor([0.3], dtype=torch.float64)
    x = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    assert (lbs.rot_y(a)[0] @ x)[2] < 0  # positive Y turns +x towards -z (toes bend down)
    assert (lbs.rot_z(a)[0] @ x)[1] > 0  # positive Z turns +x towards +y
    angles = uniform_angles(4, 0)
    local = lbs.local_rotations(angles)
    torch.testing.assert_close(local[:, 0], torch.eye(3, dtype=torch.float64).expand(4, 3, 3))
    # toe 1 proximal phalanx (segment ending at joint 2): R_y(y) @ R_z(z)
    i_y, i_z = sk.DOF_NAMES.index("toe1_proximal_y"), sk.DOF_NAMES.index("toe1_proximal_z")
    torch.testing.assert_close(local[:, 2], lbs.rot_y(angles[:, i_y]) @ lbs.rot_z(angles[:, i_z]))


def test_zero_pose_is_identity(rest_joints):
    posed, transforms = lbs.forward_kinematics(torch.zeros(3, sk.NUM_DOFS, dtype=torch.float64), rest_joints)
    torch.testing.assert_close(posed, rest_joints.expand(3, -1, -1))
    eye = torch.eye(3, 4, dtype=torch.float64).expand(3, sk.NUM_JOINTS, 3, 4)
    torch.testing.assert_close(transforms, eye)


def test_bone_lengths_and_root_preserved(rest_joints):
    posed, transforms = lbs.forward_kinematics(uniform_angles(64, 1), rest_joints)
    parents = list(sk.PARENTS[1:])
    rest_len = (rest_joints[1:] - rest_joints[parents]).norm(dim=-1)
    posed_len = (posed[:, 1:] - posed[:, parents]).norm(dim=-1)
    torch.testing.assert_close(posed_len, rest_len.expand_as(posed_len))
    torch.testing.assert_close(posed[:, 0], rest_joints[0].expand(64, 3))
    rot = transforms[..., :3]
    eye = torch.eye(3, dtype=torch.float64).expand_as(rot)
    torch.testing.assert_close(rot @ rot.transpose(-1, -2), eye)
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(rot.shape[:2], dtype=torch.float64))


def test_vectorised_fk_matches_naive_loop(rest_joints):
    angles = uniform_angles(16, 2)
    rest = rest_joints + torch.randn(
        16, sk.NUM_JOINTS, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64
    )
    posed, transforms = lbs.forward_kinematics(angles, rest)
    for i in range(len(angles)):
        pos, rot = _naive_fk(angles[i].numpy(), rest[i].numpy())
        np.testing.assert_allclose(posed[i].numpy(), pos, atol=1e-10)
        np.testing.assert_allclose(transforms[i, :, :, :3].numpy(), rot, atol=1e-12)
        # each transform maps its segment's rest joint onto the posed joint
        moved = (transforms[i, :, :, :3] @ rest[i].unsqueeze(-1)).squeeze(-1) + transforms[i, :, :, 3]
        np.testing.assert_allclose(moved.numpy(), pos, atol=1e-10)


def test_fk_gradcheck(rest_joints):
    angles = uniform_angles(1, 3).requires_grad_(True)
    rest = (rest_joints / 100.0).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, r: lbs.forward_kinematics(a, r), (angles, rest), fast_mode=True)


def test_skin_gradcheck(asset, rest_joints):
    idx = torch.arange(0, asset.num_vertices, max(1, asset.num_vertices // 20))
    weights = torch.from_numpy(asset.skin_weights[idx.numpy()].astype(np.float64))
    weights = weights / weights.sum(1, keepdim=True)
    vertices = (torch.from_numpy(asset.mean_vertices[idx.numpy()].astype(np.float64)) / 100.0).unsqueeze(0)
    angles = uniform_angles(1, 4).requires_grad_(True)
    vertices.requires_grad_(True)

    def fn(a, v):
        _, transforms = lbs.forward_kinematics(a, rest_joints / 100.0)
        return lbs.skin(v, transforms, weights), lbs.inverse_skin(v, transforms, weights)

    assert torch.autograd.gradcheck(fn, (angles, vertices))


def test_blend_shapes_gradcheck():
    g = torch.Generator().manual_seed(0)
    mean = torch.randn(7, 3, generator=g, dtype=torch.float64)
    comps = torch.randn(4, 7, 3, generator=g, dtype=torch.float64)
    sd = torch.rand(4, generator=g, dtype=torch.float64)
    shape = torch.randn(2, 3, generator=g, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda s: lbs.blend_shapes(s, mean, comps, sd), (shape,))


def test_skin_inverse_skin_round_trip(asset, rest_joints):
    vertices = torch.from_numpy(asset.mean_vertices.astype(np.float64)).expand(8, -1, -1)
    weights = torch.from_numpy(asset.skin_weights.astype(np.float64))
    _, transforms = lbs.forward_kinematics(uniform_angles(8, 5), rest_joints)
    posed = lbs.skin(vertices, transforms, weights)
    torch.testing.assert_close(lbs.inverse_skin(posed, transforms, weights), vertices)
    # zero pose: skinning is the identity
    _, eye = lbs.forward_kinematics(torch.zeros(8, sk.NUM_DOFS, dtype=torch.float64), rest_joints)
    torch.testing.assert_close(lbs.skin(vertices, eye, weights), vertices)


def test_clamp_angles():
    wild = torch.linspace(-5.0, 5.0, 44, dtype=torch.float64).reshape(2, sk.NUM_DOFS)
    clamped = lbs.clamp_angles(wild)
    assert (clamped >= torch.tensor(sk.DOF_LOWER, dtype=torch.float64)).all()
    assert (clamped <= torch.tensor(sk.DOF_UPPER, dtype=torch.float64)).all()
    inside = uniform_angles(5, 6)
    assert torch.equal(lbs.clamp_angles(inside), inside)
