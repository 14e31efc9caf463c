"""The foot model layer: a pure function of (shape, angles, scale, side) on the packaged asset."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from footmesh.model import skeleton as sk
from footmesh.model.ik import sample_poses, uniform_angles
from footmesh.model.layer import FootModel, foot_model, mirror_faces


@pytest.fixture(scope="module")
def model() -> FootModel:
    return FootModel().double()


def test_zero_pose_gives_the_rest_mesh_exactly(model):
    shape = torch.randn(3, model.num_components, dtype=torch.float64)
    out = model(shape, torch.zeros(3, sk.NUM_DOFS, dtype=torch.float64))
    assert torch.equal(out.vertices, out.rest_vertices)
    assert torch.allclose(out.joints, out.rest_joints, atol=0, rtol=0)


def test_mean_shape_is_the_asset_mean(model):
    out = model()
    np.testing.assert_allclose(out.vertices[0].numpy(), model.asset.mean_vertices, atol=1e-4)


def test_function_form_matches_layer(model):
    shape = torch.randn(2, 4, dtype=torch.float64)
    angles = uniform_angles(2, 0)
    v, j = foot_model(shape, angles, 1.1, "right", model=model)
    out = model(shape, angles, 1.1, "right")
    assert v.shape == (2, model.num_vertices, 3) and j.shape == (2, sk.NUM_JOINTS, 3)
    assert torch.equal(v, out.vertices) and torch.equal(j, out.joints)


def test_right_foot_is_the_mirror_of_the_left(model):
    shape = torch.randn(2, model.num_components, dtype=torch.float64)
    angles = uniform_angles(2, 1)
    left = model(shape, angles, side="left")
    right = model(shape, angles, side=["right", "right"])
    mirror = torch.tensor([1.0, -1.0, 1.0], dtype=torch.float64)
    assert torch.allclose(right.vertices, left.vertices * mirror)
    assert torch.allclose(right.joints, left.joints * mirror)
    import trimesh

    mesh_right = trimesh.Trimesh(right.vertices[0].numpy(), model.faces("right").numpy(), process=False)
    mesh_left = trimesh.Trimesh(left.vertices[0].numpy(), model.faces("left").numpy(), process=False)
    assert mesh_left.volume > 0 and mesh_right.volume > 0  # outward normals on both sides
    assert mesh_right.volume == pytest.approx(mesh_left.volume, rel=1e-9)
    assert np.array_equal(mirror_faces(mirror_faces(model.faces_left)), model.faces_left)


def test_scale_and_placement(model):
    shape = torch.randn(1, model.num_components, dtype=torch.float64)
    base = model(shape)
    rot = torch.linalg.qr(torch.randn(3, 3, dtype=torch.float64))[0]
    rot = rot * torch.sign(torch.det(rot))
    t = torch.tensor([[10.0, -20.0, 500.0]], dtype=torch.float64)
    placed = model(shape, scale=torch.tensor([0.9], dtype=torch.float64), rotation=rot[None], translation=t)
    expected = 0.9 * base.vertices @ rot.T + t[:, None]
    assert torch.allclose(placed.vertices, expected, atol=1e-9)


def test_gradients_flow_to_every_parameter(model):
    shape = torch.zeros(1, model.num_components, dtype=torch.float64, requires_grad=True)
    angles = torch.full((1, sk.NUM_DOFS), 0.05, dtype=torch.float64, requires_grad=True)
    scale = torch.ones(1, dtype=torch.float64, requires_grad=True)
    out = model(shape, angles, scale)
    (out.vertices.square().sum() + out.joints.square().sum()).backward()
    for p in (shape, angles, scale):
        assert p.grad is not None and torch.isfinite(p.grad).all() and p.grad.abs().sum() > 0


def test_bad_arguments_are_refused(model):
    with pytest.raises(ValueError, match="side"):
        model(side="middle")
    with pytest.raises(ValueError, match="angles"):
        model(angles=torch.zeros(1, 5, dtype=torch.float64))
    with pytest.raises(ValueError, match="shape"):
        model(shape=torch.zeros(1, model.num_components + 1, dtype=torch.float64))
    with pytest.raises(ValueError, match="batch"):
        model(shape=torch.zeros(2, 3, dtype=torch.float64), angles=torch.zeros(3, 22, dtype=torch.float64))


def _edges(faces: np.ndarray) -> np.ndarray:
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def test_natural_poses_keep_the_mesh_sound(model):
    """Natural poses: no zero-area face, 99 % of edges within 30 % of their rest length, and faces folded over
    (on the underside of strongly curled toes, where linear blend skinning collapses) under 0.1 %."""
    n = 200
    rng = np.random.default_rng(7)
    shape = torch.from_numpy(rng.normal(size=(n, model.num_components)))
    rest = model(shape)
    angles = sample_poses(rest.rest_joints, rng, n, method="natural")
    assert (angles >= torch.tensor(sk.DOF_LOWER, dtype=torch.float64) - 1e-12).all()
    assert (angles <= torch.tensor(sk.DOF_UPPER, dtype=torch.float64) + 1e-12).all()
    posed = model(shape, angles).vertices.numpy()
    rest_v = rest.vertices.numpy()
    faces = model.faces_left.numpy()
    edges = _edges(faces)
    stretch = np.linalg.norm(posed[:, edges[:, 0]] - posed[:, edges[:, 1]], axis=2) / np.linalg.norm(
        rest_v[:, edges[:, 0]] - rest_v[:, edges[:, 1]], axis=2
    )

    def normals(v):
        t = v[:, faces]
        return np.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0])

    n_rest, n_posed = normals(rest_v), normals(posed)
    area_ratio = np.linalg.norm(n_posed, axis=2) / np.linalg.norm(n_rest, axis=2)
    flipped = (n_rest * n_posed).sum(axis=2) < 0
    assert flipped.mean() < 1e-3
    assert area_ratio.min() > 0.01
    assert np.quantile(np.abs(stretch - 1.0), 0.99) < 0.3
