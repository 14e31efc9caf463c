"""Canonicalisation (``footmesh.model.canonical``): any placement, scale and side back to the zero pose."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from _toy_model import model_asset

from footmesh.geometry.alignment import weighted_procrustes
from footmesh.measure import stick_length_mm
from footmesh.model import ik, lbs
from footmesh.model.canonical import Canonical, canonicalise
from footmesh.model.layer import FootModel

NUM_SHAPE = 8  # components drawn and fitted (keeps the test fast on the full packaged model)


@pytest.fixture(scope="module")
def model() -> FootModel:
    return FootModel(model_asset(), dtype=torch.float64)


def _random_rotation(g: torch.Generator, b: int) -> torch.Tensor:
    q, r = torch.linalg.qr(torch.randn(b, 3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r, dim1=1, dim2=2)).unsqueeze(1)
    return q * torch.sign(torch.linalg.det(q)).reshape(-1, 1, 1)  # proper


def _random_feet(model: FootModel, b: int, seed: int):
    g = torch.Generator().manual_seed(seed)
    k = min(NUM_SHAPE, model.num_components)
    shape = torch.randn(b, k, generator=g, dtype=torch.float64)
    angles = ik.sample_poses(None, g, b, method="natural")  # everyday poses: what photos show
    rotation = _random_rotation(g, b)
    translation = 300.0 * torch.randn(b, 3, generator=g, dtype=torch.float64)
    scale = 0.8 + 0.4 * torch.rand(b, generator=g, dtype=torch.float64)
    side = ["left", "right"] * (b // 2) + ["left"] * (b % 2)
    out = model(shape, angles, scale, side, rotation, translation)
    return out, dict(shape=shape, angles=angles, rotation=rotation, translation=translation, scale=scale, side=side)


def test_round_trip(model):
    out, truth = _random_feet(model, 2, seed=0)
    can = canonicalise(out.vertices, model, truth["side"], num_shape=truth["shape"].shape[1])
    assert isinstance(can, Canonical)
    true_rest = out.rest_vertices * truth["scale"].reshape(-1, 1, 1)
    assert (can.rest_vertices - true_rest).norm(dim=-1).max() < 0.1  # mm
    # Uniform in-limit poses fold small toe segments that move few vertices: their angles are the least
    # determined by the mesh (measured: 2e-3 rad at worst on the packaged model, rest mesh within 0.03 mm).
    assert (can.angles - truth["angles"]).abs().max() < 5e-3  # rad
    # scale is not compared: the PCA space itself holds foot size, so scale and shape trade against each other;
    # their product, the rest mesh in mm, is what is determined (checked above).
    torch.testing.assert_close(can.rotation, truth["rotation"], atol=1e-3, rtol=0)
    torch.testing.assert_close(can.translation, truth["translation"], atol=0.1, rtol=0)
    assert can.residual_mm.max() < 0.02
    true_joints = torch.einsum("jv,bvc->bjc", model.joint_regressor, true_rest)
    assert (can.rest_joints - true_joints).norm(dim=-1).max() < 0.1  # mm
    # the fitted parameters reproduce the input through the layer
    again = model(can.shape, can.angles, can.scale, truth["side"], can.rotation, can.translation)
    assert (again.vertices - out.vertices).norm(dim=-1).max() < 0.1


def test_round_trip_with_joints(model):
    out, truth = _random_feet(model, 2, seed=1)
    can = canonicalise(out.vertices, model, truth["side"], posed_joints=out.joints, num_shape=truth["shape"].shape[1])
    assert (can.angles - truth["angles"]).abs().max() < 1e-3
    assert (can.rest_vertices - out.rest_vertices * truth["scale"].reshape(-1, 1, 1)).norm(dim=-1).max() < 0.05


def test_noise_keeps_stick_length(model):
    """0.5 mm noise per coordinate: the unposed mesh keeps the noise (details survive), and its stick length
    agrees within 0.5 mm with that of the same noisy mesh unposed by the true parameters."""
    out, truth = _random_feet(model, 4, seed=2)
    g = torch.Generator().manual_seed(9)
    noisy = out.vertices + 0.5 * torch.randn(out.vertices.shape, generator=g, dtype=torch.float64)
    can = canonicalise(noisy, model, truth["side"], num_shape=truth["shape"].shape[1])
    s = truth["scale"].reshape(-1, 1, 1)
    mirror = torch.tensor([[1.0, -1.0 if side == "right" else 1.0, 1.0] for side in truth["side"]])
    in_model = ((noisy - truth["translation"].unsqueeze(1)) @ truth["rotation"]) * mirror.unsqueeze(1) / s
    reference = lbs.inverse_skin(in_model, out.transforms, model.skin_weights) * s
    for i in range(len(noisy)):
        got = stick_length_mm(can.rest_vertices[i].numpy())
        assert abs(got - stick_length_mm(reference[i].numpy())) < 0.5
    assert (can.residual_mm > 0.5).all() and (can.residual_mm < 1.0).all()  # ~ 0.5 * sqrt(3) minus the fit


def test_weighted_procrustes_recovers_a_similarity():
    g = torch.Generator().manual_seed(4)
    source = torch.randn(50, 3, generator=g, dtype=torch.float64)
    rotation = _random_rotation(g, 3)
    scale = torch.tensor([0.5, 1.0, 2.0], dtype=torch.float64)
    translation = torch.randn(3, 3, generator=g, dtype=torch.float64)
    target = scale.reshape(-1, 1, 1) * source @ rotation.transpose(1, 2) + translation.unsqueeze(1)
    weights = torch.rand(50, generator=g, dtype=torch.float64)
    r, s, t = weighted_procrustes(source, target, weights)
    torch.testing.assert_close(r, rotation)
    torch.testing.assert_close(s, scale)
    torch.testing.assert_close(t, translation)


def test_bad_inputs(model):
    with pytest.raises(ValueError, match="topology"):
        canonicalise(torch.zeros(1, 10, 3), model)
    v = torch.from_numpy(np.asarray(model.asset.mean_vertices, dtype=np.float64))[None]
    with pytest.raises(ValueError):
        canonicalise(v, model, posed_joints=torch.zeros(1, 17, 3))
    with pytest.raises(ValueError):
        canonicalise(v, model, side="middle")


def test_closed_form_jacobian_matches_autodiff(model):
    """The rigid, scale and angle columns of the LM Jacobian are written by hand: check them against jacfwd."""
    from torch.func import jacfwd, vmap

    from footmesh.model import canonical

    out, truth = _random_feet(model, 2, seed=5)
    k = truth["shape"].shape[1]
    problem = canonical._Problem(model, k)
    params = torch.zeros(2, canonical._SHAPE_START + k, dtype=torch.float64)
    params[:, canonical._TRANS] = truth["translation"]
    params[:, canonical._LOG_SCALE] = truth["scale"].log()
    params[:, canonical._ANGLES] = truth["angles"]
    params[:, canonical._SHAPE_START :] = truth["shape"]
    rot0 = truth["rotation"]
    for joints in (None, out.joints):
        _, jac = problem.batch_jacobian(params, rot0, out.vertices, joints)
        if joints is None:
            ref = vmap(jacfwd(lambda p, r, d: problem.residual(p, r, d, None)))(params, rot0, out.vertices)
        else:
            ref = vmap(jacfwd(problem.residual))(params, rot0, out.vertices, joints)
        torch.testing.assert_close(jac, ref, atol=1e-9, rtol=1e-9)
