"""The spiral mesh decoder: shapes, skips, centroid, gradients, checkpoints, and overfitting one posed foot."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from footmesh.recon.decoder import DecoderConfig, DecoderOutput, OutputScale, SpiralDecoder
from footmesh.recon.losses import mesh_loss

TINY = DecoderConfig(in_features=16, channels=(8, 16, 16, 32, 32))


def test_shapes_levels_and_centre(hierarchy):
    torch.manual_seed(0)
    decoder = SpiralDecoder(DecoderConfig(in_features=32), hierarchy)
    out = decoder(torch.randn(2, 32))
    assert isinstance(out, DecoderOutput)
    assert out.vertices.shape == (2, 4002, 3) and out.centre.shape == (2, 3)
    assert [lv.shape[1] for lv in out.levels] == list(hierarchy.num_vertices)
    assert out.levels[0] is out.vertices
    for level in out.levels:
        assert torch.allclose(level.mean(dim=1), out.centre, atol=1e-3)
    # the centroid starts at the configured prior
    assert torch.allclose(out.centre, torch.tensor([[0.0, 0.0, 500.0]] * 2))
    assert tuple(decoder.faces.shape) == (8000, 3)
    assert "parameters=" in repr(decoder)


def test_output_scale_is_applied(hierarchy):
    torch.manual_seed(0)
    z = torch.randn(1, 16)
    small = SpiralDecoder(TINY, hierarchy)
    scaled_cfg = replace(TINY, output=OutputScale(shape_scale_mm=200.0, centre_mean_mm=(1.0, 2.0, 3.0)))
    scaled = SpiralDecoder(scaled_cfg, hierarchy)
    scaled.load_state_dict(small.state_dict())
    a, b = small(z), scaled(z)
    assert torch.allclose(b.centre, torch.tensor([[1.0, 2.0, 3.0]]))
    assert torch.allclose(b.vertices - b.centre[:, None], 2.0 * (a.vertices - a.centre[:, None]), atol=1e-3)


def test_skips_reach_the_output_and_every_parameter_learns(hierarchy):
    torch.manual_seed(1)
    cfg = DecoderConfig(in_features=16, channels=(8, 8, 8, 8, 8), skip_in_channels=(12, 8, 6, 4))
    decoder = SpiralDecoder(cfg, hierarchy)
    z = torch.randn(2, 16)
    skips = [torch.randn(2, 12, 7, 7), torch.randn(2, 8, 14, 14), torch.randn(2, 6), torch.randn(2, 4, 56, 56)]
    out = decoder(z, skips)
    changed = decoder(z, [skips[0], skips[1] + 1.0, skips[2], skips[3]])
    assert not torch.allclose(out.vertices, changed.vertices)
    (out.vertices - torch.tensor([10.0, -5.0, 480.0])).abs().mean().backward()
    for name, p in decoder.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert p.grad.abs().sum() > 0, name


def test_checkpoint_round_trip(hierarchy):
    torch.manual_seed(2)
    a, b = SpiralDecoder(TINY, hierarchy), SpiralDecoder(TINY, hierarchy)
    b.load_state_dict(a.state_dict())
    z = torch.randn(3, 16)
    assert torch.equal(a(z).vertices, b(z).vertices)
    # derived tables (spirals, up-sampling, faces) are rebuilt from the hierarchy, not stored
    assert not any("indices" in k or "index" in k or "faces" in k for k in a.state_dict())


def test_overfits_one_posed_foot(hierarchy, foot_target):
    """40 Adam steps of the thesis loss bring a tiny decoder from ~10 cm to a few mm on one camera-frame foot."""
    torch.manual_seed(0)
    decoder = SpiralDecoder(TINY, hierarchy)
    z = torch.randn(1, 16)
    optimiser = torch.optim.Adam(decoder.parameters(), lr=3e-3)
    errors = []
    for _ in range(40):
        out = decoder(z)
        loss = mesh_loss(out.vertices, foot_target, decoder.faces)
        optimiser.zero_grad()
        loss.total.backward()
        optimiser.step()
        errors.append(float((out.vertices.detach() - foot_target).norm(dim=-1).mean()))
    with torch.no_grad():
        final = float((decoder(z).vertices - foot_target).norm(dim=-1).mean())
    assert errors[0] > 50.0
    assert final < 0.1 * errors[0] and final < 10.0, (errors[0], final)


def test_bad_input(hierarchy):
    with pytest.raises(ValueError, match="channels has 3 entries"):
        SpiralDecoder(DecoderConfig(channels=(8, 8, 8)), hierarchy)
    decoder = SpiralDecoder(TINY, hierarchy)
    with pytest.raises(ValueError, match=r"latent must be \(B, 16\)"):
        decoder(torch.randn(2, 15))
    with pytest.raises(ValueError, match="expected 0 skip"):
        decoder(torch.randn(2, 16), [torch.randn(2, 4)])
    skipping = SpiralDecoder(replace(TINY, skip_in_channels=(4,)), hierarchy)
    with pytest.raises(ValueError, match="skip 0 must be"):
        skipping(torch.randn(2, 16), [torch.randn(2, 5)])
