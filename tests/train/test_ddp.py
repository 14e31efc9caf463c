"""``footmesh train cues`` under ``torchrun --nproc_per_node 2`` (gloo on CPU): real processes, a few steps."""

from __future__ import annotations

import csv
import os
import shutil
import signal
import subprocess
import sys
import textwrap
from collections import Counter
from pathlib import Path

import pytest
import torch

from footmesh.train.loop import CHECKPOINT, LOG_CSV

TIMEOUT_S = 300
"""Generous: two processes start torch and render nothing, but the machine may be busy."""


def _descendants(pid: int) -> list[int]:
    """Ids of the processes below ``pid`` (torchrun puts its workers in sessions of their own)."""
    parents = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        parents.setdefault(int(fields[1]), []).append(int(stat.parent.name))
    found, todo = [], [pid]
    while todo:
        children = parents.get(todo.pop(), [])
        found += children
        todo += children
    return found


def _torchrun(script: list[str], cwd: Path, timeout: float = TIMEOUT_S) -> subprocess.CompletedProcess:
    """Run ``torchrun --standalone --nproc_per_node 2 SCRIPT...``; on timeout kill it and its workers."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    env.pop("WORLD_SIZE", None)
    cmd = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2", *script]
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        for pid in [*_descendants(proc.pid), proc.pid]:  # only the processes this test started
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        out, _ = proc.communicate()
        pytest.fail(f"torchrun did not finish in {timeout} s (a rank waits for the other):\n{out[-3000:]}")
    return subprocess.CompletedProcess(cmd, proc.returncode, out, None)


def _fresh_copy(tiny_data: Path, tmp_path: Path) -> Path:
    """The tiny dataset without its cache, so both ranks meet a folder with no cache yet, as in a first run."""
    data = tmp_path / "data"
    shutil.copytree(tiny_data, data, ignore=shutil.ignore_patterns("cues-cache-*"))
    return data


def _train_args(data: Path, out: Path, config: Path, *extra: str) -> list[str]:
    args = ["train", "cues", "--input", "rgbd", "--data", str(data), "--out", str(out), "--config", str(config)]
    return [*args, "--threads", "1", "--no-progress", *extra]


@pytest.mark.slow
def test_two_processes_train_and_rank_0_alone_writes(tiny_data, tiny_config_file, tmp_path):
    out = tmp_path / "run"
    args = _train_args(_fresh_copy(tiny_data, tmp_path), out, tiny_config_file, "--steps", "3")
    result = _torchrun(["-m", "footmesh", *args], tmp_path)
    assert result.returncode == 0, result.stdout[-3000:]
    assert torch.load(out / CHECKPOINT, weights_only=False)["step"] == 3
    assert (out / "weights.pt").is_file()
    assert sorted(p.name for p in out.iterdir() if p.name != "tensorboard") == [CHECKPOINT, LOG_CSV, "weights.pt"]
    text = (out / LOG_CSV).read_text()
    assert text.count("step,elapsed_s,name,value") == 1  # one header: one writer
    rows = list(csv.DictReader(text.splitlines()))
    counts = Counter((r["step"], r["name"]) for r in rows)
    assert set(counts.values()) == {1}, counts  # no row twice
    assert sorted(int(s) for s, name in counts if name == "loss") == [1, 2, 3]
    assert ("3", "val_joint_px224") in counts


@pytest.mark.slow
def test_time_budget_stops_every_rank_at_the_same_step(tiny_data, tiny_config_file, tmp_path):
    # rank 0 starts its clock 3 s after rank 1 (as a slow TensorBoard start or file system could make it):
    # both must still stop together
    driver = tmp_path / "driver.py"
    driver.write_text(
        textwrap.dedent(
            """
            import sys, time
            from footmesh.train import loop

            original = loop._Logger.__init__

            def delayed(self, out, enabled):
                original(self, out, enabled)
                if enabled:
                    time.sleep(3.0)

            loop._Logger.__init__ = delayed
            from footmesh.cli import main

            sys.exit(main(sys.argv[1:]))
            """
        )
    )
    out = tmp_path / "run"
    args = _train_args(_fresh_copy(tiny_data, tmp_path), out, tiny_config_file, "--steps", "100000")
    result = _torchrun([str(driver), *args, "--max-minutes", "0.1"], tmp_path, timeout=60)
    assert result.returncode == 0, result.stdout[-3000:]
    assert 1 <= torch.load(out / CHECKPOINT, weights_only=False)["step"] < 100000
