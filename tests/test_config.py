"""The typed configuration of the networks and their training (``footmesh.config``)."""

from __future__ import annotations

import json

import pytest

from footmesh.config import (
    INPUT_CHANNELS,
    CuesLossConfig,
    CuesNetConfig,
    CuesTrainingConfig,
    MeasureConfig,
    TrainConfig,
    load_config,
)


def test_defaults_are_valid_and_build_a_network():
    from footmesh.cues.net import CuesNet

    config = CuesTrainingConfig()
    assert config.net.input == "rgbd" and config.net.in_channels == 4
    assert config.net.image_size % 32 == 0
    assert config.train.steps > config.train.warmup_steps > 0
    assert 0 < config.train.val_fraction < 1
    CuesNet(config.net)  # the default architecture is constructible as it is
    MeasureConfig()
    CuesLossConfig()
    for kind, channels in INPUT_CHANNELS.items():
        assert CuesNetConfig(input=kind).in_channels == channels


def test_thesis_network_is_three_resnet18_stacks_at_224():
    thesis = CuesNetConfig.thesis("rgb")
    assert thesis.input == "rgb" and thesis.in_channels == 3
    assert thesis.stacks == 3
    assert thesis.widths == (64, 128, 256, 512)  # ResNet-18's stage widths
    assert thesis.blocks == (2, 2, 2, 2)  # ResNet-18's two basic blocks per stage
    assert thesis.image_size == 224
    assert thesis.head == "sigmoid"
    assert CuesNetConfig.thesis().input == "rgbd"


def test_load_config_overrides_nested_fields_from_json(tmp_path):
    path = tmp_path / "config.json"
    path.write_text(json.dumps({"net": {"stacks": 2, "widths": [16, 32, 48, 64]}, "train": {"batch_size": 8}}))
    config = load_config(path)
    assert config.net.stacks == 2
    assert config.net.widths == (16, 32, 48, 64)  # JSON lists become the dataclass' tuples
    assert config.train.batch_size == 8
    # everything not in the file keeps its default
    assert config.net.image_size == CuesNetConfig().image_size
    assert config.train.lr == TrainConfig().lr
    assert config.loss == CuesLossConfig()
    # keyword overrides apply to the network on top of the file; None means "not given"
    config = load_config(path, input="depth", stacks=None)
    assert config.net.input == "depth" and config.net.stacks == 2
    assert load_config(None) == CuesTrainingConfig()


@pytest.mark.parametrize(
    ("data", "key"),
    [
        ({"nett": {}}, "nett"),
        ({"net": {"stack": 2}}, "stack"),
        ({"train": {"learning_rate": 0.1}}, "learning_rate"),
        ({"loss": {"silhouete": 1.0}}, "silhouete"),
    ],
)
def test_unknown_keys_are_refused_by_name(tmp_path, data, key):
    path = tmp_path / "config.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=key):
        load_config(path)


BAD_VALUES_CHECKED = [
    ({"net": {"input": "infrared"}}, "input"),
    ({"net": {"head": "argmax"}}, "head"),
    ({"net": {"stacks": 0}}, "stacks"),
    ({"net": {"image_size": 100}}, "image_size"),
    ({"net": {"widths": [8, 16]}}, "widths"),
    ({"net": "three stacks"}, "net"),
]
# values of the wrong type, and training settings, are not validated yet (see the reason)
BAD_VALUES_UNCHECKED = [
    ({"net": {"widths": 5}}, "widths"),
    ({"net": {"image_size": "big"}}, "image_size"),
    ({"net": {"stacks": 1.5}}, "stacks"),
    ({"train": {"batch_size": 0}}, "batch_size"),
    ({"train": {"steps": "many"}}, "steps"),
    ({"train": {"lr": -0.1}}, "lr"),
    ({"train": {"val_fraction": 1.5}}, "val_fraction"),
    ({"loss": {"heatmap": -1.0}}, "heatmap"),
]


@pytest.mark.parametrize(("data", "key"), BAD_VALUES_CHECKED)
def test_bad_values_raise_value_error_naming_the_key(tmp_path, data, key):
    path = tmp_path / "config.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=key):
        load_config(path)


@pytest.mark.parametrize(("data", "key"), BAD_VALUES_UNCHECKED)
def test_bad_types_and_training_values_raise_value_error_naming_the_key(tmp_path, data, key):
    path = tmp_path / "config.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError, match=key):
        load_config(path)


def test_broken_and_missing_files_are_clear_errors(tmp_path):
    path = tmp_path / "config.json"
    path.write_text('{"net": {"stacks": 2,}}')
    with pytest.raises(ValueError, match="not valid JSON"):
        load_config(path)
    path.write_text("[1, 2]")
    with pytest.raises(ValueError, match="JSON object"):
        load_config(path)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_config(tmp_path / "missing.json")


def test_to_dict_from_dict_round_trip():
    for config in (
        CuesTrainingConfig(),
        CuesTrainingConfig(
            net=CuesNetConfig.thesis("depth"),
            train=TrainConfig(steps=7, max_minutes=1.5, threads=2, init_from="w.pt", augment=False),
            loss=CuesLossConfig(joints_px=0.2),
        ),
    ):
        data = config.to_dict()
        assert CuesTrainingConfig.from_dict(data) == config
        # and through JSON (tuples become lists and back), as in a --config file or a checkpoint
        assert CuesTrainingConfig.from_dict(json.loads(json.dumps(data))) == config


def test_a_fit_held_standing_bears_on_its_heel_and_ball_and_carries_more_starts():
    from footmesh.fit import FitConfig

    config, free = MeasureConfig(), FitConfig(joint_sigma_px=2.0)
    assert config.held_fit(free, None) == free
    upright = config.held_fit(free, "upright")
    assert upright.upright_robust == config.flat_refit_upright_robust != free.upright_robust
    assert not upright.sole_contact and upright.full_starts == free.full_starts
    standing = config.held_fit(free, "standing")
    assert standing.sole_contact and standing.full_starts == config.standing_full_starts != free.full_starts
    assert standing.upright_robust == upright.upright_robust and standing.joint_sigma_px == 2.0
