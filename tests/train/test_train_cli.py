"""``footmesh train cues`` on the command line (``footmesh.cli.main``)."""

from __future__ import annotations

import json

import pytest
import torch

from footmesh.cli import main
from footmesh.cues.weights import load_network
from footmesh.train.loop import CHECKPOINT


def _train(*args: str) -> list[str]:
    return ["train", "cues", "--no-progress", *args]


def test_train_cues_writes_weights(tiny_data, tiny_config_file, tmp_path):
    out = tmp_path / "run"
    args = ["--input", "rgbd", "--data", str(tiny_data), "--out", str(out), "--config", str(tiny_config_file)]
    assert main(_train(*args, "--steps", "2")) == 0
    model, net, info = load_network(out / "weights.pt")
    assert net.input == "rgbd" and net.image_size == 64 and net.widths == (8, 8, 16, 16)  # from the JSON file
    assert info["training"]["train"]["steps"] == 2  # the flag overrides the file
    assert info["training"]["train"]["batch_size"] == 4
    assert set(info["validation"]) == {"val_silhouette_wrong_pct", "val_joint_px224"}
    assert torch.load(out / CHECKPOINT, weights_only=False)["step"] == 2


def test_input_flag_overrides_the_file(tiny_data, tmp_path):
    config = tmp_path / "c.json"
    config.write_text(json.dumps({"net": {"input": "rgbd", "image_size": 64, "widths": [8, 8, 16, 16]}}))
    out = tmp_path / "run"
    args = ["--input", "depth", "--data", str(tiny_data), "--out", str(out), "--config", str(config)]
    assert main(_train(*args, "--steps", "1", "--batch-size", "2", "--threads", "1")) == 0
    _, net, info = load_network(out / "weights.pt")
    assert net.input == "depth" and info["training"]["train"]["batch_size"] == 2


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("footmesh: error: ")
    return err[0]


def test_missing_data_folder_exits_2_with_one_line(tiny_config_file, tmp_path, capsys):
    missing = tmp_path / "nowhere"
    args = ["--input", "rgb", "--data", str(missing), "--out", str(tmp_path / "run"), "--config", str(tiny_config_file)]
    assert main(_train(*args)) == 2
    assert "nowhere" in _one_line_error(capsys)
    empty = tmp_path / "empty"
    empty.mkdir()
    args[3] = str(empty)
    assert main(_train(*args)) == 2
    assert "chunk" in _one_line_error(capsys)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ('{"net": {"stacks": 2,}}', "not valid JSON"),
        ('{"net": {"stackz": 2}}', "stackz"),
        ('{"net": {"head": "argmax"}}', "head"),
        ('{"train": {"batch_size": 4}, "optimiser": "sgd"}', "optimiser"),
    ],
)
def test_bad_config_file_exits_2_with_one_line(tiny_data, tmp_path, capsys, content, message):
    config = tmp_path / "bad.json"
    config.write_text(content)
    args = ["--input", "rgb", "--data", str(tiny_data), "--out", str(tmp_path / "run"), "--config", str(config)]
    assert main(_train(*args)) == 2
    assert message in _one_line_error(capsys)
    assert not (tmp_path / "run").exists()  # refused before anything was written


def test_missing_config_file_and_bad_flags_exit_2(tiny_data, tmp_path, capsys):
    base = ["--input", "rgb", "--data", str(tiny_data), "--out", str(tmp_path / "run")]
    assert main(_train(*base, "--config", str(tmp_path / "nope.json"))) == 2
    assert "nope.json" in _one_line_error(capsys)
    assert main(_train(*base, "--steps", "0")) == 2
    assert "--steps" in _one_line_error(capsys)
    assert main(_train(*base, "--batch-size", "64")) == 2  # more than the 24-sample folder holds
    assert "too few" in _one_line_error(capsys)


def test_config_value_of_the_wrong_type_exits_2(tiny_data, tmp_path, capsys):
    config = tmp_path / "bad.json"
    config.write_text('{"net": {"widths": 32}}')
    args = ["--input", "rgb", "--data", str(tiny_data), "--out", str(tmp_path / "run"), "--config", str(config)]
    assert main(_train(*args)) == 2
    assert "widths" in _one_line_error(capsys)
