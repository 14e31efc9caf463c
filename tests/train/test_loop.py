"""The resumable training loop (``footmesh.train.loop``) driving the 2D-cues task (``footmesh.train.cues``)."""

from __future__ import annotations

import csv
import math
import os
import signal
from collections import Counter
from dataclasses import replace

import pytest
import torch
from _tiny_cues import tiny_config

from footmesh.config import TrainConfig
from footmesh.cues.weights import load_network
from footmesh.train import cues as cues_module
from footmesh.train.cues import WEIGHTS, train_cues
from footmesh.train.loop import CHECKPOINT, LOG_CSV, lr_at, param_groups


def _checkpoint(out) -> dict:
    return torch.load(out / CHECKPOINT, map_location="cpu", weights_only=False)


def _log(out) -> list[dict]:
    with open(out / LOG_CSV, newline="") as f:
        return list(csv.DictReader(f))


def _interrupt_at(monkeypatch, step: int) -> None:
    """Make the task send this process SIGINT while computing ``step``, as Ctrl-C or a scheduler would."""
    original = cues_module.CuesTask.loss

    def loss(self, model, at, generator, rank, world):
        if at == step:
            os.kill(os.getpid(), signal.SIGINT)
        return original(self, model, at, generator, rank, world)

    monkeypatch.setattr(cues_module.CuesTask, "loss", loss)


def test_stopped_and_resumed_run_equals_an_uninterrupted_one(tiny_data, tmp_path, monkeypatch):
    config = tiny_config("rgbd", steps=6)
    whole = train_cues(tiny_data, tmp_path / "whole", config, progress=False)
    assert whole.finished and whole.steps_done == 6

    with monkeypatch.context() as m:
        _interrupt_at(m, 2)
        first = train_cues(tiny_data, tmp_path / "split", config, progress=False)
    # the signal is honoured after the step it arrived in: checkpoint at step 3, not finished
    assert not first.finished and first.steps_done == 3
    assert _checkpoint(tmp_path / "split")["step"] == 3
    second = train_cues(tiny_data, tmp_path / "split", config, progress=False)
    assert second.finished and second.steps_done == 6

    a, b = _checkpoint(tmp_path / "whole"), _checkpoint(tmp_path / "split")
    assert a["step"] == b["step"] == 6
    assert a["model"].keys() == b["model"].keys()
    for name, value in a["model"].items():
        assert torch.equal(value, b["model"][name]), name  # bit for bit, BatchNorm statistics included
    for state_a, state_b in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values(), strict=True):
        assert torch.equal(state_a["exp_avg_sq"], state_b["exp_avg_sq"])
    # the same per-step losses were logged (the resumed run appends to the same log)
    losses = lambda rows: [(r["step"], r["value"]) for r in rows if r["name"] == "loss"]  # noqa: E731
    assert losses(_log(tmp_path / "whole")) == losses(_log(tmp_path / "split"))
    assert a["metrics"] == pytest.approx(b["metrics"])


def test_resuming_with_another_configuration_is_refused(tiny_data, tmp_path):
    out = tmp_path / "run"
    config = tiny_config("rgbd", steps=1)
    train_cues(tiny_data, out, config, progress=False)
    before = (out / CHECKPOINT).read_bytes()
    other = replace(config, train=replace(config.train, lr=config.train.lr / 2))
    with pytest.raises(ValueError, match="another configuration"):
        train_cues(tiny_data, out, other, progress=False)
    with pytest.raises(ValueError, match="another configuration"):
        train_cues(tiny_data, out, replace(config, net=replace(config.net, heatmap_sigma_px=2.0)), progress=False)
    assert (out / CHECKPOINT).read_bytes() == before  # the refused runs touched nothing


def test_time_budget_stops_early_with_checkpoint_and_weights(tiny_data, tmp_path):
    out = tmp_path / "run"
    config = tiny_config("depth", steps=50, max_minutes=1e-4)  # 6 ms: out of time after the first step
    result = train_cues(tiny_data, out, config, progress=False)
    assert not result.finished and 1 <= result.steps_done < 50
    assert _checkpoint(out)["step"] == result.steps_done
    model, net, info = load_network(out / WEIGHTS)
    assert net == config.net and not model.training
    assert info["training"] == config.to_dict()
    # the same command resumes where it stopped
    again = train_cues(tiny_data, out, config, progress=False)
    assert again.steps_done > result.steps_done


def test_log_csv_holds_the_loss_terms_and_validation(tiny_data, tmp_path):
    out = tmp_path / "run"
    config = tiny_config("rgb", steps=3)
    result = train_cues(tiny_data, out, config, progress=False)
    rows = _log(out)
    assert list(rows[0]) == ["step", "elapsed_s", "name", "value"]
    names = Counter(r["name"] for r in rows)
    for term in ("loss", "sil", "heat", "joint_px", "vis", "lr", "step_s"):
        assert names[term] == 3, term  # one row per step
    assert names["val_silhouette_wrong_pct"] == names["val_joint_px224"] == 1  # at the last step
    assert all(math.isfinite(float(r["value"])) for r in rows)
    for r in rows:
        if r["name"] == "loss":
            terms = {q["name"]: float(q["value"]) for q in rows if q["step"] == r["step"]}
            w = config.loss
            parts = w.silhouette * terms["sil"] + w.heatmap * terms["heat"] + w.joints_px * terms["joint_px"]
            # the logged loss is the weighted sum of the logged terms (one stack)
            assert float(r["value"]) == pytest.approx(parts + w.visibility * terms["vis"], rel=1e-4)
    lrs = [float(r["value"]) for r in rows if r["name"] == "lr"]
    assert lrs == pytest.approx([lr_at(s, config.train) for s in range(3)], rel=1e-5)
    assert result.metrics.keys() == {"val_silhouette_wrong_pct", "val_joint_px224"}


def test_lr_warms_up_then_decays():
    config = TrainConfig(steps=1000, warmup_steps=100, lr=1e-3)
    lrs = [lr_at(s, config) for s in range(1001)]
    assert lrs[0] == pytest.approx(1e-5)  # 1 / warm-up of the peak
    assert all(a < b for a, b in zip(lrs[:100], lrs[1:100], strict=False))  # linear rise
    assert lrs[99] == pytest.approx(1e-3) and lrs[100] == pytest.approx(1e-3)
    assert all(a >= b for a, b in zip(lrs[100:], lrs[101:], strict=False))  # then never rises
    assert lrs[550] == pytest.approx(1e-3 * (0.02 + 0.98 * 0.5), rel=1e-6)  # cosine half way
    assert lrs[1000] == pytest.approx(2e-5)  # 2 % of the peak at the end
    assert lr_at(5000, config) == pytest.approx(2e-5)  # and it stays there
    assert lr_at(0, TrainConfig(steps=10, warmup_steps=0, lr=1.0)) == pytest.approx(1.0)


def test_pretrained_parts_get_their_own_learning_rate_scale():
    from footmesh.config import CuesNetConfig
    from footmesh.cues.net import build_network

    model = build_network(CuesNetConfig(encoder="efficientnet_lite0", input="rgb"))
    everything = {id(p) for p in model.parameters()}
    assert [g["lr_scale"] for g in param_groups(model, TrainConfig())] == [1.0]  # one group, as old checkpoints
    rest, encoder = param_groups(model, TrainConfig(pretrained_lr_scale=0.1))
    assert encoder["lr_scale"] == 0.1 and rest["lr_scale"] == 1.0
    assert {id(p) for p in encoder["params"]} == {id(p) for p in model.encoder.parameters()}
    assert {id(p) for p in rest["params"]} | {id(p) for p in encoder["params"]} == everything
    assert len(rest["params"]) + len(encoder["params"]) == len(everything)  # each parameter in one group
    with pytest.raises(ValueError, match="pretrained_lr_scale"):
        TrainConfig(pretrained_lr_scale=2.0)
