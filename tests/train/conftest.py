"""Shared fixtures: a tiny synthetic dataset (rendered once per session) and the tiny settings as a JSON file."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _tiny_cues import DATA_SEED, N_SAMPLES, SIZE, TINY_NET, TINY_TRAIN

from footmesh.synth.dataset import generate
from footmesh.synth.scene import SynthConfig


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 24-sample, 64 px synthetic dataset folder (do not modify; ``load_arrays`` adds its cache beside it)."""
    folder = tmp_path_factory.mktemp("tiny-synth")
    generate(folder, N_SAMPLES, seed=DATA_SEED, config=SynthConfig(size=SIZE), progress=False)
    return folder


@pytest.fixture
def tiny_config_file(tmp_path: Path) -> Path:
    """The tiny settings as a ``--config`` JSON file."""
    path = tmp_path / "tiny.json"
    path.write_text(json.dumps({"net": TINY_NET, "train": TINY_TRAIN}))
    return path
