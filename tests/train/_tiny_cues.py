"""The tiny dataset and network settings the training tests share (small enough for one core)."""

from __future__ import annotations

from footmesh.config import CuesNetConfig, CuesTrainingConfig, TrainConfig

SIZE = 64
"""Side of the rendered images and of the tiny networks' input, px."""
N_SAMPLES = 24
DATA_SEED = 11
TINY_NET = {"image_size": SIZE, "widths": [8, 8, 16, 16]}
# one thread (reproducible, and the machine's cores are busy), a short warm-up so a few steps see a real rate
TINY_TRAIN = {"batch_size": 4, "warmup_steps": 2, "val_every": 1000, "threads": 1, "seed": 3}


def tiny_config(input_kind: str = "rgbd", **train: object) -> CuesTrainingConfig:
    """The tiny network and training settings as a ``CuesTrainingConfig`` (``train`` overrides fields)."""
    return CuesTrainingConfig(
        net=CuesNetConfig(input=input_kind, image_size=SIZE, widths=tuple(TINY_NET["widths"])),
        train=TrainConfig(**{**TINY_TRAIN, **train}),
    )
