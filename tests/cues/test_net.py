"""The 2D-cues network (``footmesh.cues.net``): shapes, decoding of joints, targets, gradients, and learning."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from footmesh.config import CuesLossConfig, CuesNetConfig
from footmesh.cues.net import (
    HEATMAP_STRIDE,
    NUM_JOINTS,
    SILHOUETTE_STRIDE,
    CuesNet,
    gaussian_targets,
    hard_argmax,
    soft_argmax,
)

SIZE = 64
WIDTHS = (8, 8, 16, 16)


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


def tiny(input_kind: str = "rgbd", head: str = "soft_argmax", stacks: int = 1) -> CuesNetConfig:
    return CuesNetConfig(input=input_kind, image_size=SIZE, widths=WIDTHS, head=head, stacks=stacks)


@pytest.mark.parametrize("stacks", [1, 3])
@pytest.mark.parametrize("head", ["soft_argmax", "sigmoid"])
@pytest.mark.parametrize(("input_kind", "channels"), [("rgb", 3), ("rgbd", 4), ("depth", 1)])
def test_output_shapes(input_kind, channels, head, stacks):
    config = tiny(input_kind, head, stacks)
    assert config.in_channels == channels
    torch.manual_seed(0)
    model = CuesNet(config).eval()
    with torch.no_grad():
        outputs = model(torch.randn(2, channels, SIZE, SIZE))
    assert len(outputs) == stacks  # one prediction per stack (intermediate supervision)
    for out in outputs:
        side = SIZE // SILHOUETTE_STRIDE
        assert out.silhouette_logits.shape == (2, 1, side, side)
        assert out.heatmap_logits.shape == (2, NUM_JOINTS, SIZE // HEATMAP_STRIDE, SIZE // HEATMAP_STRIDE)
        assert out.joints.shape == (2, NUM_JOINTS, 2)
        assert out.visibility_logits.shape == (2, NUM_JOINTS)
        # joints are decoded inside the input image (input pixels, centre of the top-left pixel at 0)
        assert out.joints.min() >= -0.5 and out.joints.max() <= SIZE - 0.5
    with pytest.raises(RuntimeError):  # the wrong number of channels is not silently accepted
        model(torch.randn(1, channels + 1, SIZE, SIZE))


def test_soft_argmax_gives_the_exact_sub_pixel_centre_of_a_symmetric_bump():
    h, w, sigma = 24, 32, 1.5
    centres = torch.tensor([[[10.3, 7.6], [20.75, 15.2], [8.5, 12.0]]], dtype=torch.float64)  # (1, 3, 2) x, y
    ys, xs = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    # log of a Gaussian: its softmax is the normalised bump, whose mean is the centre (far enough from borders)
    d2 = (xs - centres[..., 0, None, None]) ** 2 + (ys - centres[..., 1, None, None]) ** 2
    heat = -d2 / (2 * sigma**2)
    joints, prob = soft_argmax(heat)
    np.testing.assert_allclose(joints.numpy(), centres.numpy(), atol=1e-6)
    np.testing.assert_allclose(prob.sum((2, 3)).numpy(), 1.0, atol=1e-12)
    # adding a constant to the logits changes nothing (softmax)
    np.testing.assert_allclose(soft_argmax(heat + 5.0)[0].numpy(), centres.numpy(), atol=1e-6)
    # the same in float32, as in the network
    np.testing.assert_allclose(soft_argmax(heat.float())[0].numpy(), centres.numpy(), atol=1e-4)


def test_hard_argmax_gives_the_integer_peak_and_its_value():
    heat = torch.zeros(2, 3, 16, 20)
    peaks = [[(5, 9), (0, 0), (19, 15)], [(7, 3), (12, 1), (3, 14)]]  # (x, y)
    for b, row in enumerate(peaks):
        for j, (x, y) in enumerate(row):
            heat[b, j, y, x] = 2.0 + j
            heat[b, j, y, (x + 1) % 20] = 1.5 + j  # a lower neighbour does not pull the answer
    joints, peak = hard_argmax(heat)
    assert joints.tolist() == [[[float(x), float(y)] for x, y in row] for row in peaks]
    np.testing.assert_array_equal(peak.numpy(), [[2.0, 3.0, 4.0], [2.0, 3.0, 4.0]])


def test_gaussian_targets_peak_at_the_joint_and_vanish_for_joints_not_inside():
    size, sigma = 16, 1.0
    joints = torch.tensor([[[4.0, 9.0], [10.4, 3.7], [7.0, 7.0]]])  # map pixels (x, y)
    inside = torch.tensor([[1.0, 1.0, 0.0]])
    maps = gaussian_targets(joints, inside, size, sigma)
    assert maps.shape == (1, 3, size, size)
    assert float(maps[0, 0, 9, 4]) == pytest.approx(1.0)  # peak 1 on an integer position, at (y, x)
    assert int(maps[0, 0].argmax()) == 9 * size + 4
    assert int(maps[0, 1].argmax()) == 4 * size + 10  # the pixel nearest to (10.4, 3.7)
    assert float(maps[0, 1].max()) < 1.0
    assert float(maps[0, 2].abs().max()) == 0.0
    # the bump is symmetric: its mean is the joint
    m = maps[0, 1]
    grid = torch.arange(size, dtype=m.dtype)
    mean = torch.stack([(m.sum(0) * grid).sum(), (m.sum(1) * grid).sum()]) / m.sum()
    np.testing.assert_allclose(mean.numpy(), [10.4, 3.7], atol=1e-3)


def _random_batch(config: CuesNetConfig, b: int = 2, seed: int = 0):
    """A random ``Batch`` at the config's side: noise images, disc silhouettes, joints in and out of the image."""
    from footmesh.train.data import Batch, inside_image

    g = torch.Generator().manual_seed(seed)
    s = config.image_size
    yy, xx = torch.meshgrid(torch.arange(s), torch.arange(s), indexing="ij")
    sil = (((xx - s / 2) ** 2 + (yy - s / 2) ** 2) < (s / 4) ** 2).float().expand(b, 1, s, s)
    joints = torch.rand(b, NUM_JOINTS, 2, generator=g) * (s + 8) - 4
    return Batch(
        rgb=torch.rand(b, 3, s, s, generator=g),
        depth=400 + 100 * torch.rand(b, 1, s, s, generator=g),
        silhouette=sil.clone(),
        joints=joints,
        visible=(torch.rand(b, NUM_JOINTS, generator=g) < 0.7).float(),
        inside=inside_image(joints, s),
    )


@pytest.mark.parametrize(("head", "stacks"), [("soft_argmax", 1), ("soft_argmax", 2), ("sigmoid", 2)])
def test_gradients_reach_every_parameter(head, stacks):
    from footmesh.cues.inputs import network_input
    from footmesh.train.cues import cues_loss

    config = tiny("rgbd", head, stacks)
    torch.manual_seed(1)
    model = CuesNet(config).train()
    batch = _random_batch(config)
    loss, terms = cues_loss(model(network_input("rgbd", batch.rgb, batch.depth)), batch, config, CuesLossConfig())
    assert torch.isfinite(loss) and terms["loss"] == pytest.approx(loss.item())
    loss.backward()
    missing = [name for name, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert missing == []
    assert all(torch.isfinite(p.grad).all() for p in model.parameters())


@pytest.fixture(scope="module")
def rendered_batch():
    """Four rendered 64 px scenes as a ``Batch`` (the real task, not noise)."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig
    from footmesh.train.data import Batch, inside_image

    samples = [Renderer(SynthConfig(size=SIZE)).render(21, i) for i in range(4)]
    joints = torch.from_numpy(np.stack([s["joints2d"] for s in samples])).float()
    return Batch(
        rgb=torch.from_numpy(np.stack([s["rgb"] for s in samples])).permute(0, 3, 1, 2).float() / 255,
        depth=torch.from_numpy(np.stack([s["depth"] for s in samples]).astype(np.float32))[:, None],
        silhouette=torch.from_numpy(np.stack([s["silhouette"] for s in samples])).float()[:, None],
        joints=joints,
        visible=torch.from_numpy(np.stack([s["joints_visible"] for s in samples])).float(),
        inside=inside_image(joints, SIZE),
    )


def _target_entropy(batch, config: CuesNetConfig) -> float:
    """Mean entropy of the normalised heatmap targets: the lowest value the soft-argmax heatmap loss can reach."""
    centres = (batch.joints + 0.5) / HEATMAP_STRIDE - 0.5
    maps = gaussian_targets(centres, batch.inside, SIZE // HEATMAP_STRIDE, config.heatmap_sigma_px).flatten(2)
    p = maps / maps.sum(-1, keepdim=True).clamp(min=1e-12)
    entropy = -(p * torch.log(p.clamp(min=1e-30))).sum(-1)
    return float((entropy * batch.inside).sum() / batch.inside.sum())


@pytest.mark.parametrize("head", ["soft_argmax", "sigmoid"])
def test_a_tiny_network_overfits_one_batch(rendered_batch, head):
    from footmesh.cues.inputs import network_input
    from footmesh.train.cues import cues_loss

    config = tiny("rgbd", head)
    torch.manual_seed(2)
    model = CuesNet(config).train()
    optimizer = torch.optim.Adam(model.parameters(), lr=1e-2)
    x = network_input("rgbd", rendered_batch.rgb, rendered_batch.depth)
    history = []
    for _ in range(30):
        loss, terms = cues_loss(model(x), rendered_batch, config, CuesLossConfig())
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        history.append(terms)
    first, last = history[0], history[-1]
    assert last["sil"] < 0.2 * first["sil"], (first, last)
    if head == "soft_argmax":
        # the heatmap cross-entropy cannot go below the targets' entropy: compare what is above it
        floor = _target_entropy(rendered_batch, config)
        assert last["heat"] - floor < 0.5 * (first["heat"] - floor), (floor, first, last)
        assert last["joint_px"] < 0.5 * first["joint_px"], (first, last)  # the joints move to their targets
    else:
        assert last["loss"] < 0.3 * first["loss"], (first, last)
        assert last["heat"] < 0.5 * first["heat"], (first, last)
