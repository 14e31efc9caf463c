"""Reference objects on the floor: found in rendered scenes, their floor plane in millimetres."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.cues.reference import detect_reference
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig


def _scenes(kind: str, n: int, size: int = 640):
    renderer = Renderer(SynthConfig(size=size, reference=kind))
    for i in range(n):
        sample = renderer.render(555, i)
        if kind == "none" or bool(np.all(sample["ref_corners_visible"])):
            yield sample


def test_marker_gives_the_floor_distance_within_one_percent():
    found = 0
    for s in _scenes("marker", 12):  # the marker is often partly out of view; 2 of these 12 are whole
        obj = detect_reference(s["rgb"], s["K"], exclude_mask=s["labels"] == 1)
        if obj is None:
            continue
        assert obj.kind == "marker"
        found += 1
        corner0 = s["ref_corners3d"][0]
        assert np.linalg.norm(obj.cam_from_floor[:3, 3]) == pytest.approx(np.linalg.norm(corner0), rel=0.01)
        assert np.abs(obj.corners_px - s["ref_corners2d"]).max() < 2.0
        assert obj.scale_rel_sd > 0
    assert found >= 1


def test_no_object_no_reference():
    for s in _scenes("none", 3):
        assert detect_reference(s["rgb"], s["K"], exclude_mask=s["labels"] == 1) is None


def test_bad_inputs_are_refused():
    image = np.zeros((100, 100, 3), np.uint8)
    with pytest.raises(ValueError):
        detect_reference(image, np.eye(2))
    with pytest.raises(ValueError):
        detect_reference(image[..., 0], np.eye(3))
    with pytest.raises(ValueError):
        detect_reference(image, np.eye(3), kinds=("banana",))
