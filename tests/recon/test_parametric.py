"""The model-based head (``footmesh.recon.parametric``) and ``ReconNet(kind="model")``."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from footmesh.model import skeleton as sk
from footmesh.model.layer import default_model
from footmesh.recon.decoder import DecoderConfig
from footmesh.recon.model import EFFICIENTNET_WIDTHS, ReconConfig, ReconNet, recon_input
from footmesh.recon.parametric import (
    NUM_SHAPE,
    ModelOutput,
    ParametricHead,
    rotation_from_6d,
    rotation_to_6d,
)

SIZE = 64
TINY_MODEL = ReconConfig.for_widths(
    (8, 8, 16, 16), 16, image_size=SIZE, decoder=DecoderConfig(channels=(8,) * 5), kind="model", loss="structure"
)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-10, 10, allow_nan=False), min_size=6, max_size=6))
def test_6d_gives_a_rotation_and_round_trips(values):
    x = torch.tensor([values], dtype=torch.float64)
    a, b = x[:, :3], x[:, 3:]
    # Gram-Schmidt needs two independent vectors (the network's outputs are, almost surely)
    assume(a.norm() > 1e-3 and b.norm() > 1e-3 and torch.linalg.cross(a, b).norm() > 1e-3 * a.norm() * b.norm())
    r = rotation_from_6d(x)
    assert torch.allclose(r @ r.transpose(1, 2), torch.eye(3, dtype=x.dtype)[None], atol=1e-9)
    assert torch.allclose(torch.linalg.det(r), torch.ones(1, dtype=x.dtype))
    assert torch.allclose(rotation_from_6d(rotation_to_6d(r)), r, atol=1e-9)


def test_angles_stay_inside_the_joint_limits_and_the_start_is_the_mean_foot():
    head = ParametricHead(8)
    start = head(torch.zeros(2, 8), torch.zeros(2))
    assert torch.equal(start.shape, torch.zeros(2, NUM_SHAPE))
    assert torch.allclose(start.rotation, torch.eye(3).expand(2, 3, 3))
    assert torch.equal(start.right_logit, torch.zeros(2))
    lower, upper = torch.tensor(sk.DOF_LOWER), torch.tensor(sk.DOF_UPPER)
    inside = (lower < 0) & (upper > 0)  # where the zero pose lies inside the limits, the start is exactly it
    assert torch.allclose(start.angles[:, inside], torch.zeros(2, int(inside.sum())), atol=1e-6)
    with torch.no_grad():
        head.linear.weight.normal_(0, 100.0)  # wild latents still give angles inside the limits
    g = torch.Generator().manual_seed(0)
    wild = head(torch.randn(64, 8, generator=g), torch.randn(64, generator=g))
    assert ((wild.angles >= lower) & (wild.angles <= upper)).all()


def test_the_mesh_is_the_foot_models_centred_and_mirrored_for_right_feet():
    head = ParametricHead(8)
    with torch.no_grad():
        head.linear.weight.normal_(0, 0.3)
    params = head(torch.randn(2, 8, generator=torch.Generator().manual_seed(1)), torch.zeros(2))
    right = torch.tensor([False, True])
    vertices, joints = ParametricHead.mesh(params, right)
    assert torch.allclose(vertices.mean(1), torch.zeros(2, 3), atol=1e-3)
    truth = default_model()(params.shape, params.angles, side=["left", "right"], rotation=params.rotation)
    assert torch.allclose(vertices, truth.vertices - truth.vertices.mean(1, keepdim=True), atol=1e-3)
    assert joints.shape == (2, sk.NUM_JOINTS, 3)


@pytest.mark.parametrize("residual", [False, True])
def test_model_network_places_the_foot_models_mesh_and_starts_without_residual(hierarchy, residual):
    net = ReconNet(replace(TINY_MODEL, residual=residual), hierarchy if residual else None)
    g = torch.Generator().manual_seed(0)
    rgb, depth = torch.rand(2, 3, SIZE, SIZE, generator=g), 400 + 100 * torch.rand(2, 1, SIZE, SIZE, generator=g)
    x, ref = recon_input("rgbd", rgb, depth)
    K = torch.tensor([[60.0, 0, 31.5], [0, 60.0, 31.5], [0, 0, 1]]).expand(2, 3, 3)  # noqa: N806
    out = net(x, K, ref)
    assert isinstance(out, ModelOutput)
    assert torch.equal(out.right, out.parameters.right_logit > 0)  # no side given: the network's own
    assert torch.allclose(out.vertices, out.model_vertices)  # zero-started residual heads
    assert torch.allclose(out.model_vertices.mean(1), out.centre, atol=1e-3)
    assert (net.decoder is not None) == residual and net.faces.shape == default_model().faces_left.shape
    out.vertices[:, :100].sum().backward()  # everything on the way is differentiable
    assert net.parametric.linear.weight.grad.abs().sum() > 0


def test_the_pretrained_encoder_is_efficientnet_and_checks_its_widths():
    with pytest.raises(ValueError, match="EfficientNet-Lite0"):
        ReconConfig(encoder="efficientnet_lite0")
    cfg = ReconConfig.for_widths(EFFICIENTNET_WIDTHS, 32, encoder="efficientnet_lite0", kind="model", residual=False)
    net = ReconNet(cfg)
    assert net.pretrained_submodules == ("encoder",)
    assert net.encoder.load_pretrained() > 200  # the packaged ImageNet weights
    features = net.encoder(torch.zeros(1, cfg.in_channels, 128, 128))
    assert [f.shape[1] for f in features] == list(EFFICIENTNET_WIDTHS)
    assert [f.shape[-1] for f in features] == [32, 16, 8, 4]
