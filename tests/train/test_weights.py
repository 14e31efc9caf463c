"""Weights files of the 2D-cues network (``footmesh.cues.weights``) and warm starts (``train.cues.copy_matching``)."""

from __future__ import annotations

import pytest
import torch

from footmesh.config import CuesNetConfig
from footmesh.cues.net import CuesNet
from footmesh.cues.weights import FORMAT, load_network, load_state, network_for, save_weights
from footmesh.train.cues import copy_matching

SIZE = 64
WIDTHS = (8, 8, 16, 16)


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


def _trained_like(config: CuesNetConfig, seed: int = 0) -> CuesNet:
    """A network with non-trivial BatchNorm statistics (a few forward passes in training mode)."""
    torch.manual_seed(seed)
    model = CuesNet(config).train()
    with torch.no_grad():
        for _ in range(3):
            model(torch.randn(2, config.in_channels, config.image_size, config.image_size) * 2 + 0.5)
    return model.eval()


@pytest.mark.parametrize(("head", "stacks"), [("soft_argmax", 1), ("sigmoid", 2)])
def test_save_and_load_round_trip_in_half_precision(tmp_path, head, stacks):
    config = CuesNetConfig(input="rgbd", image_size=SIZE, widths=WIDTHS, head=head, stacks=stacks)
    model = _trained_like(config)
    path = tmp_path / "w.pt"
    save_weights(path, model, config, {"validation": {"joint_px224": 1.5}})
    raw = torch.load(path, weights_only=True)
    assert raw["format"] == FORMAT
    assert all(v.dtype == torch.float16 for v in raw["state_dict"].values() if v.is_floating_point())
    assert raw["state_dict"]["stem1.1.num_batches_tracked"].dtype == torch.int64  # integers stay integers

    loaded, loaded_config, info = load_network(path)
    assert loaded_config == config and info == {"validation": {"joint_px224": 1.5}}
    assert not loaded.training
    state = load_state(path)
    assert all(v.dtype == torch.float32 for v in state.values() if v.is_floating_point())
    for name, value in model.state_dict().items():
        torch.testing.assert_close(state[name], value.to(state[name].dtype), rtol=1e-3, atol=1e-4, msg=name)
    x = torch.randn(2, 4, SIZE, SIZE)
    with torch.no_grad():
        want, got = model(x)[-1], loaded(x)[-1]
    assert len(loaded(x)) == stacks
    # half precision changes the outputs by far less than they matter (pixels, probabilities)
    assert (torch.sigmoid(got.silhouette_logits) - torch.sigmoid(want.silhouette_logits)).abs().max() < 0.01
    assert (got.joints - want.joints).abs().max() < 0.05  # input pixels
    assert (torch.sigmoid(got.visibility_logits) - torch.sigmoid(want.visibility_logits)).abs().max() < 0.01


def test_network_for_checks_the_input_kind(tmp_path):
    config = CuesNetConfig(input="depth", image_size=SIZE, widths=WIDTHS)
    path = tmp_path / "depth.pt"
    save_weights(path, _trained_like(config), config, {})
    model, loaded = network_for("depth", path)
    assert loaded == config and network_for("depth", path)[0] is model  # loaded once per process
    with pytest.raises(ValueError, match="'depth'"):
        network_for("rgb", path)


def test_a_file_of_another_kind_is_a_clear_value_error(tmp_path):
    checkpoint = tmp_path / "checkpoint.pt"
    torch.save({"model": {"w": torch.zeros(2)}, "step": 3}, checkpoint)
    with pytest.raises(ValueError, match="not a footmesh 2D-cues weights file"):
        load_network(checkpoint)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        load_network(tmp_path / "missing.pt")


@pytest.mark.parametrize("content", [b"hello", b'{"format": "footmesh-cues-1"}', b"PK\x03\x04 broken zip"])
def test_a_file_that_is_not_a_torch_file_is_a_clear_value_error(tmp_path, content):
    path = tmp_path / "photo.pt"
    path.write_bytes(content)
    with pytest.raises(ValueError, match="not a footmesh 2D-cues weights file"):
        load_network(path)


@pytest.mark.parametrize(("target", "channels"), [("rgb", slice(0, 3)), ("depth", slice(3, 4))])
def test_copy_matching_adapts_the_first_convolution(target, channels):
    source = _trained_like(CuesNetConfig(input="rgbd", image_size=SIZE, widths=WIDTHS))
    torch.manual_seed(5)
    model = CuesNet(CuesNetConfig(input=target, image_size=SIZE, widths=WIDTHS))
    state = source.state_dict()
    copied = copy_matching(model, state)
    assert copied == len(state)  # every tensor: all but one as they are, the first convolution adapted
    own = model.state_dict()
    first = "stem1.0.weight"
    assert own[first].shape[1] == (3 if target == "rgb" else 1)
    # RGB-D -> RGB keeps the colour channels' filters, -> depth the depth channel's
    assert torch.equal(own[first], state[first][:, channels])
    for name, value in state.items():
        if name != first:
            assert torch.equal(own[name], value), name
    # and the adapted network behaves as the source with the other channels blanked (equal features)
    model.eval()
    x = torch.randn(1, 4, SIZE, SIZE)
    blank = torch.zeros_like(x)
    blank[:, channels] = x[:, channels]
    with torch.no_grad():
        torch.testing.assert_close(model(x[:, channels])[-1].joints, source(blank)[-1].joints)


def test_copy_matching_skips_what_does_not_fit():
    source = CuesNet(CuesNetConfig(input="rgbd", image_size=SIZE, widths=WIDTHS, head="sigmoid"))
    model = CuesNet(CuesNetConfig(input="rgbd", image_size=SIZE, widths=WIDTHS, head="soft_argmax"))
    before = {k: v.clone() for k, v in model.state_dict().items()}
    copied = copy_matching(model, {**source.state_dict(), "not.a.layer": torch.zeros(3)})
    own = model.state_dict()
    # the heads have other output maps (19 vs 37): kept as they were; everything else copied
    assert torch.equal(own["heads.0.weight"], before["heads.0.weight"])
    assert copied == len(own) - 2  # heads.0.weight and heads.0.bias


@pytest.mark.parametrize(("src", "dst"), [((8, 8, 16, 16), (8, 16, 16, 16)), ((8, 16, 16, 16), (8, 8, 16, 16))])
def test_copy_matching_between_other_widths_copies_only_equal_shapes(src, dst):
    source = CuesNet(CuesNetConfig(image_size=SIZE, widths=src))
    model = CuesNet(CuesNetConfig(image_size=SIZE, widths=dst))
    before = model.state_dict()
    equal = [k for k, v in source.state_dict().items() if k in before and v.shape == before[k].shape]
    assert copy_matching(model, source.state_dict()) == len(equal)
