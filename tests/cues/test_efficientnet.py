"""The pretrained EfficientNet-Lite0 cues network: its ImageNet weights come from the installed package, its
outputs have the shapes the scratch network's have, and every part of it learns (side head included)."""

from __future__ import annotations

import pytest
import torch

from footmesh.config import CuesLossConfig, CuesNetConfig
from footmesh.cues.efficientnet import PYRAMID_CHANNELS, EfficientNetLite0Features, pretrained_path
from footmesh.cues.net import NUM_JOINTS, PretrainedCuesNet, build_network


def test_imagenet_weights_come_from_the_installed_package():
    path = pretrained_path()
    assert path.name == "efficientnet-lite0-57934424.pth" and path.stat().st_size > 10_000_000
    features = EfficientNetLite0Features(3)
    state = torch.load(path, map_location="cpu", weights_only=True)
    copied = features.load_pretrained()
    assert copied == len(features.state_dict())  # every tensor of the features, none left at its initial value
    for name in ("_conv_stem.weight", "_blocks.7._depthwise_conv.weight", "_blocks.15._bn2.running_var"):
        assert torch.equal(features.state_dict()[name], state[name])


def test_a_four_channel_stem_keeps_the_rgb_filters_and_starts_depth_at_zero():
    state = torch.load(pretrained_path(), map_location="cpu", weights_only=True)
    features = EfficientNetLite0Features(4)
    features.load_pretrained()
    stem = features.state_dict()["_conv_stem.weight"]
    assert torch.equal(stem[:, :3], state["_conv_stem.weight"]) and not stem[:, 3].any()


@pytest.mark.parametrize("size", [128, 160])
def test_outputs_have_the_scratch_networks_shapes(size):
    config = CuesNetConfig(input="rgb", image_size=size, encoder="efficientnet_lite0")
    model = build_network(config).eval()
    assert isinstance(model, PretrainedCuesNet)
    features = model.encoder(torch.rand(1, 3, size, size))
    assert [f.shape[1] for f in features] == list(PYRAMID_CHANNELS)
    assert [f.shape[-1] for f in features] == [size // s for s in (2, 4, 8, 16, 32)]
    (out,) = model(torch.rand(2, 3, size, size))
    assert out.silhouette_logits.shape == (2, 1, size // 2, size // 2)
    assert out.heatmap_logits.shape == (2, NUM_JOINTS, size // 4, size // 4)
    assert out.joints.shape == (2, NUM_JOINTS, 2) and out.visibility_logits.shape == (2, NUM_JOINTS)
    assert out.side_logits.shape == (2,)
    assert (out.joints >= -0.5).all() and (out.joints <= size - 0.5).all()


def test_gradients_reach_every_parameter_with_the_side_term():
    from footmesh.train.cues import cues_loss
    from footmesh.train.data import Batch, inside_image

    config = CuesNetConfig(input="rgb", image_size=64, encoder="efficientnet_lite0", decoder_width=16)
    model = build_network(config).train()
    g = torch.Generator().manual_seed(0)
    joints = torch.rand(2, NUM_JOINTS, 2, generator=g) * 64
    batch = Batch(
        rgb=torch.rand(2, 3, 64, 64, generator=g),
        depth=torch.zeros(2, 1, 64, 64),
        silhouette=(torch.rand(2, 1, 64, 64, generator=g) > 0.5).float(),
        joints=joints,
        visible=torch.ones(2, NUM_JOINTS),
        inside=inside_image(joints, 64),
        side=torch.tensor([0.0, 1.0]),
    )
    loss, terms = cues_loss(model(batch.rgb), batch, config, CuesLossConfig())
    assert "side" in terms and terms["side"] > 0
    loss.backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum() > 0]
    assert not missing, missing
    # without side labels the side head is simply not trained
    _, terms = cues_loss(model(batch.rgb), Batch(**{**batch.__dict__, "side": None}), config, CuesLossConfig())
    assert "side" not in terms


def test_weights_round_trip_gives_the_same_outputs(tmp_path):
    from footmesh.cues.weights import load_network, save_weights

    config = CuesNetConfig(input="rgb", image_size=64, encoder="efficientnet_lite0", decoder_width=16)
    torch.manual_seed(0)
    model = build_network(config).eval()
    save_weights(tmp_path / "w.pt", model, config, {})
    loaded, loaded_config, _ = load_network(tmp_path / "w.pt")
    assert loaded_config == config
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        a, b = model(x)[-1], loaded(x)[-1]
    # weights are stored in half precision
    assert torch.allclose(a.side_logits, b.side_logits, atol=0.05)
    assert (a.joints - b.joints).abs().max() < 0.5
