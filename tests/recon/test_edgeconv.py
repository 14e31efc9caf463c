"""EdgeConv baseline: Chamfer distance, k-NN graph, EdgeConv against its naive form, the generator."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from footmesh.recon.edgeconv import (
    EdgeConv,
    EdgeConvConfig,
    EdgeConvGenerator,
    PointCloudOutput,
    chamfer_distance,
    knn,
)


def _brute_chamfer(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    d = ((a[:, :, None] - b[:, None]) ** 2).sum(-1).sqrt()
    return 0.5 * (d.amin(2).mean(1) + d.amin(1).mean(1))


def test_chamfer_zero_symmetric_and_exact():
    gen = torch.Generator().manual_seed(0)
    camera = torch.tensor([0.0, 0.0, 500.0], dtype=torch.float64)  # clouds ~500 mm in front of the camera
    a = torch.randn(3, 200, 3, generator=gen, dtype=torch.float64) * 80 + camera
    b = torch.randn(3, 150, 3, generator=gen, dtype=torch.float64) * 80 + camera
    assert torch.equal(chamfer_distance(a, a.clone()), torch.zeros(3, dtype=torch.float64))
    shuffled = a[:, torch.randperm(200, generator=gen)]
    assert torch.equal(chamfer_distance(a, shuffled), torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(chamfer_distance(a, b), chamfer_distance(b, a))
    assert torch.allclose(chamfer_distance(a, b), _brute_chamfer(a, b))
    assert (chamfer_distance(a, b) > 0).all()
    # float32 camera-frame coordinates: still exactly zero for identical clouds
    a32 = a.float()
    assert torch.equal(chamfer_distance(a32, a32.clone()), torch.zeros(3))
    # a shift by t mm costs at most t
    assert (chamfer_distance(a, a + torch.tensor([0.0, 0.0, 2.0], dtype=torch.float64)) <= 2.0 + 1e-9).all()
    squared = chamfer_distance(a, b, squared=True)
    d2 = ((a[:, :, None] - b[:, None]) ** 2).sum(-1)
    assert torch.allclose(squared, 0.5 * (d2.amin(2).mean(1) + d2.amin(1).mean(1)))


def test_chamfer_gradients():
    gen = torch.Generator().manual_seed(1)
    b = torch.randn(1, 40, 3, generator=gen, dtype=torch.float64)
    a = (b + 0.3 * torch.randn(b.shape, generator=gen, dtype=torch.float64)).requires_grad_()
    assert torch.autograd.gradcheck(lambda x: chamfer_distance(x, b), (a,))
    same = b.clone().requires_grad_()
    chamfer_distance(same, b).sum().backward()
    assert torch.isfinite(same.grad).all()
    with pytest.raises(ValueError, match="point clouds"):
        chamfer_distance(a, b[0])


def test_knn_puts_each_point_first():
    gen = torch.Generator().manual_seed(2)
    x = torch.randn(2, 50, 4, generator=gen)
    idx = knn(x, 5)
    assert idx.shape == (2, 50, 5)
    assert torch.equal(idx[..., 0], torch.arange(50).expand(2, -1))
    d = torch.cdist(x, x)
    nearest = d.topk(5, largest=False).indices
    assert torch.equal(idx.sort(-1).values, nearest.sort(-1).values)
    with pytest.raises(ValueError, match="k must lie"):
        knn(x, 51)


def test_edgeconv_matches_its_definition():
    """max_j LeakyReLU(W [x_i, x_j - x_i] + b) over the k nearest neighbours, computed edge by edge."""
    torch.manual_seed(3)
    conv = EdgeConv(4, 6, k=5).double()
    x = torch.randn(2, 30, 4, dtype=torch.float64)
    idx = knn(x, 5)
    neighbours = torch.stack([x[b, idx[b]] for b in range(2)])  # (B, N, k, C)
    centre = x.unsqueeze(2).expand_as(neighbours)
    edges = F.leaky_relu(conv.linear(torch.cat([centre, neighbours - centre], dim=-1)), 0.2)
    assert torch.allclose(conv(x), edges.amax(dim=2))
    pointwise = EdgeConv(4, 6, k=1).double()
    expected = F.leaky_relu(pointwise.linear(torch.cat([x, torch.zeros_like(x)], dim=-1)), 0.2)
    assert torch.allclose(pointwise(x), expected)


def test_generator_shapes_and_fitting_one_cloud(foot_target):
    torch.manual_seed(4)
    cfg = EdgeConvConfig(in_features=16, seed_points=64, channels=(32, 32, 16), k=(8, 8, 1), up_factors=(4, 4))
    net = EdgeConvGenerator(cfg)
    z = torch.randn(1, 16)
    out = net(z)
    assert isinstance(out, PointCloudOutput)
    assert out.points.shape == (1, cfg.num_points, 3) == (1, 1024, 3)
    assert torch.allclose(out.points.mean(dim=1), out.centre, atol=1e-3)
    target = foot_target[:, ::4]
    optimiser = torch.optim.Adam(net.parameters(), lr=3e-3)
    losses = []
    for _ in range(30):
        loss = chamfer_distance(net(z).points, target).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        losses.append(float(loss.detach()))
    assert losses[-1] < 0.3 * losses[0], (losses[0], losses[-1])


def test_bad_config():
    with pytest.raises(ValueError, match="stages need"):
        EdgeConvGenerator(EdgeConvConfig(channels=(8, 8), k=(4,), up_factors=(2,)))
    with pytest.raises(ValueError, match="k exceeds"):
        EdgeConvGenerator(EdgeConvConfig(seed_points=4, channels=(8, 8), k=(8, 1), up_factors=(2,)))
    net = EdgeConvGenerator(EdgeConvConfig(in_features=8, seed_points=8, channels=(8, 8), k=(4, 4), up_factors=(2,)))
    with pytest.raises(ValueError, match="latent"):
        net(torch.randn(2, 9))
