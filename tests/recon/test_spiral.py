"""SpiralConv and the Inception Spiral Module: shapes, the thesis' formula against a naive version, gradients."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from footmesh.recon.hierarchy import spiral_sequences
from footmesh.recon.spiral import InceptionSpiralModule, SpiralConv, gather_spirals


@pytest.fixture(scope="module")
def spirals(sphere) -> torch.Tensor:
    v, f = sphere
    return torch.from_numpy(spiral_sequences(v, f, length=9))


def _naive_spiral_conv(x: torch.Tensor, indices: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor):
    """A loop over vertices: y_v = W [x_s0, x_s1, ...] + b."""
    out = []
    for v in range(x.shape[1]):
        feats = torch.cat([x[:, int(i)] for i in indices[v]], dim=-1)  # (B, L * C)
        out.append(feats @ weight.T + bias)
    return torch.stack(out, dim=1)


def test_spiral_conv_shapes_and_naive_loop(spirals):
    torch.manual_seed(0)
    conv = SpiralConv(5, 7, spirals).double()
    x = torch.randn(2, spirals.shape[0], 5, dtype=torch.float64)
    y = conv(x)
    assert y.shape == (2, spirals.shape[0], 7)
    assert torch.allclose(y, _naive_spiral_conv(x, spirals, conv.linear.weight, conv.linear.bias))
    # the gather's layout: the first k * C features are the first k spiral entries
    g = gather_spirals(x, spirals)
    assert torch.equal(g[:, 3, :5], x[:, 3]) and torch.equal(g[:, 3, 5:10], x[:, int(spirals[3, 1])])


def test_ism_is_the_thesis_formula(spirals):
    """relu(cat(f_1, f_1/3, f_2/3) + f_full), each filter a SpiralConv on a prefix of the spiral."""
    torch.manual_seed(1)
    ism = InceptionSpiralModule(4, 10, spirals).double()
    assert ism.prefixes == (1, 3, 6, 9) and sum(ism.split) == 10
    x = torch.randn(3, spirals.shape[0], 4, dtype=torch.float64)
    parts = []
    for layer, k in zip((ism.filter_1, ism.filter_third, ism.filter_two_thirds), ism.prefixes[:3], strict=True):
        parts.append(_naive_spiral_conv(x, spirals[:, :k], layer.weight, layer.bias))
    full = _naive_spiral_conv(x, spirals, ism.filter_full.weight, ism.filter_full.bias)
    expected = F.relu(torch.cat(parts, dim=-1) + full)
    assert torch.allclose(ism(x), expected)


def test_gradcheck(spirals):
    torch.manual_seed(2)
    small = spirals[:, :6]
    conv = SpiralConv(2, 3, small).double()
    ism = InceptionSpiralModule(2, 4, small).double()
    x = torch.randn(1, small.shape[0], 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(conv, (x,))
    # random inputs sit away from the ReLU's kink (within gradcheck's 1e-6 step) almost surely
    assert torch.autograd.gradcheck(ism, (x,))
    ism(x).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in ism.parameters())


def test_bad_input(spirals):
    with pytest.raises(ValueError, match="length >= 3"):
        InceptionSpiralModule(4, 8, spirals[:, :2])
    with pytest.raises(ValueError, match="out_channels >= 4"):
        InceptionSpiralModule(4, 3, spirals)
    with pytest.raises(ValueError, match=r"\(V, L\)"):
        SpiralConv(4, 8, spirals[:, 0])
    with pytest.raises(ValueError, match="must lie in"):
        SpiralConv(4, 8, spirals + 1000)
    conv = SpiralConv(4, 8, spirals)
    with pytest.raises(ValueError, match="features must be"):
        conv(torch.randn(1, spirals.shape[0], 5))
    with pytest.raises(ValueError, match="features must be"):
        conv(torch.randn(spirals.shape[0], 4))
