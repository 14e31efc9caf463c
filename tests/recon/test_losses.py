"""Mesh losses: zero at the target, positive away from it, the structure term's scale freedom, gradients."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from footmesh.geometry.mesh import batch_vertex_normals as vertex_normals
from footmesh.model.layer import default_model, mirror_faces
from footmesh.recon.losses import (
    LossWeights,
    edge_length_loss,
    l1_vertex_loss,
    laplacian_coordinates,
    laplacian_loss,
    mesh_edges,
    mesh_loss,
    normal_loss,
)

TERMS = (l1_vertex_loss, edge_length_loss, normal_loss, laplacian_loss)


def _call(term, pred, target, faces):
    return term(pred, target) if term is l1_vertex_loss else term(pred, target, faces)


@pytest.fixture(scope="module")
def foot() -> tuple[torch.Tensor, torch.Tensor]:
    """Two template feet (2, V, 3) mm of random shapes, and the template's faces (F, 3)."""
    model = default_model()
    gen = torch.Generator().manual_seed(0)
    vertices = model(torch.randn(2, model.num_components, generator=gen)).vertices
    return vertices.detach(), model.faces_left


def test_every_term_is_zero_at_the_target_and_positive_away(foot):
    target, faces = foot
    noisy = target + torch.randn(target.shape, generator=torch.Generator().manual_seed(1))
    for term in TERMS:
        assert float(_call(term, target.clone(), target, faces)) == pytest.approx(0.0, abs=1e-6), term.__name__
        assert float(_call(term, noisy, target, faces)) > 1e-3, term.__name__
    total = mesh_loss(target.clone(), target, faces)
    assert float(total.total) == pytest.approx(0.0, abs=1e-6)
    assert float(mesh_loss(noisy, target, faces).total) > 0.1


def test_thesis_weights_and_logging(foot):
    target, faces = foot
    noisy = target + 0.5
    noisy[:, :100] += 3.0
    parts = mesh_loss(noisy, target, faces, LossWeights(l1=1.0, edge=2.0, normal=0.1, laplacian=3.0))
    expected = parts.l1 + 2.0 * parts.edge + 0.1 * parts.normal + 3.0 * parts.laplacian
    assert torch.allclose(parts.total, expected)
    assert float(parts.l1) == pytest.approx(0.5 + 3.0 * 100 / target.shape[1], rel=1e-4)
    assert set(parts.as_dict()) == {"total", "l1", "edge", "normal", "laplacian"}
    assert LossWeights.thesis() == LossWeights(1.0, 1.0, 0.1, 0.0)
    assert LossWeights.structure().edge == 0.0 and LossWeights.structure().laplacian > 0


def test_structure_term_ignores_size_but_not_shape(foot):
    """A scaled, shifted copy costs nothing in the Laplacian term but does in edge length; crumpling costs."""
    target, faces = foot
    grown = 1.1 * target + torch.tensor([5.0, -3.0, 40.0])
    shrunk = 0.8 * target
    assert float(laplacian_loss(grown, target, faces)) < 1e-4
    assert float(laplacian_loss(shrunk, target, faces)) < 1e-4
    assert float(edge_length_loss(shrunk, target, faces)) > 0.1
    gen = torch.Generator().manual_seed(2)
    crumpled = target + 1.5 * torch.randn(target.shape, generator=gen)
    assert float(laplacian_loss(crumpled, target, faces)) > 0.5


def test_mirrored_faces_give_the_same_values(foot):
    """Right feet are mirrored and wound the other way: the normal loss compares like with like."""
    target, faces = foot
    mirror = torch.tensor([1.0, -1.0, 1.0])
    noisy = target + torch.randn(target.shape, generator=torch.Generator().manual_seed(3))
    left = normal_loss(noisy, target, faces)
    right = normal_loss(noisy * mirror, target * mirror, mirror_faces(faces))
    assert torch.allclose(left, right, atol=1e-5)
    normals = vertex_normals(target, faces)
    centred = target - target.mean(dim=1, keepdim=True)
    assert float((normals * centred).sum(dim=-1).gt(0).float().mean()) > 0.9  # mostly outward


def test_mesh_helpers(foot):
    target, faces = foot
    edges = mesh_edges(faces)
    assert edges.shape == (12000, 2)  # closed genus-0 mesh: E = 3F / 2
    assert (edges[:, 0] < edges[:, 1]).all()
    assert torch.equal(mesh_edges(faces.numpy()), edges)
    # a vertex and its neighbours on a flat regular patch: Laplacian coordinate zero at the centre
    hexagon = np.array([[np.cos(a), np.sin(a), 0.0] for a in np.linspace(0, 2 * np.pi, 7)[:-1]])
    v = torch.tensor(np.vstack([[0.0, 0.0, 0.0], hexagon]))[None]
    f = torch.tensor([[0, 1 + i, 1 + (i + 1) % 6] for i in range(6)])
    assert torch.allclose(laplacian_coordinates(v, f)[0, 0], torch.zeros(3, dtype=torch.float64))


def test_gradcheck(sphere):
    v, f = sphere
    target = torch.tensor(v)[None]
    gen = torch.Generator().manual_seed(4)
    pred = (target + torch.randn(target.shape, generator=gen, dtype=torch.float64)).requires_grad_()
    faces = torch.tensor(f)
    for term in (edge_length_loss, normal_loss, laplacian_loss):
        assert torch.autograd.gradcheck(lambda p, t=term: t(p, target, faces), (pred,)), term.__name__
    # L1 at the target itself: a finite (sub)gradient, not NaN
    at_target = target.clone().requires_grad_()
    mesh_loss(at_target, target, faces, LossWeights.structure()).total.backward()
    assert torch.isfinite(at_target.grad).all()


def test_bad_input(foot):
    target, faces = foot
    with pytest.raises(ValueError, match=r"\(B, V, 3\)"):
        l1_vertex_loss(target, target[:, :10])
    with pytest.raises(ValueError, match=r"\(B, V, 3\)"):
        edge_length_loss(target[0], target[0], faces)
    with pytest.raises(ValueError, match=r"faces must be \(F, 3\)"):
        normal_loss(target, target, faces[:, :2])
