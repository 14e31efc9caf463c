"""Shared fixtures: one renderer at a small image size and a few rendered samples."""

from __future__ import annotations

import pytest

from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig

SIZE = 96


@pytest.fixture(scope="session")
def renderer() -> Renderer:
    return Renderer(SynthConfig(size=SIZE))


@pytest.fixture(scope="session")
def samples(renderer: Renderer) -> list[dict]:
    return [renderer.render(7, i) for i in range(6)]
