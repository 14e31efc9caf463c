"""The fit stage: the foot model fitted to cues made from rendered scenes with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.fit import canonical_measures, fit_foot, synthetic_cues
from footmesh.model import skeleton as sk
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig


@pytest.fixture(scope="module")
def scene():
    """A standing foot (the floor test needs one), rendered at 320 px with its ground truth."""
    renderer = Renderer(SynthConfig(size=320, reference="none"))
    index = 0
    while bool((sample := renderer.render(7, index))["lifted"]):
        index += 1
    return sample


def _truth(sample):
    return canonical_measures(sample["shape"]), "right" if int(sample["side"]) else "left"


@pytest.mark.slow
def test_fit_with_depth_recovers_length_and_side(scene):
    (length, width), side = _truth(scene)
    cues = synthetic_cues(scene, joint_noise_px=2.0, rng=0)
    fit = fit_foot(cues, scene["K"], depth_mm=scene["depth"].astype(np.float32), side="auto")
    assert fit.scaled and fit.scale_source == "depth"
    assert fit.side == side
    got_length, got_width = canonical_measures(fit.shape)
    assert abs(got_length - length) < 4.0
    assert abs(got_width - width) < 4.0
    assert np.all(fit.angles >= np.asarray(sk.DOF_LOWER) - 1e-9)
    assert np.all(fit.angles <= np.asarray(sk.DOF_UPPER) + 1e-9)
    assert np.mean(np.linalg.norm(fit.vertices_cam - scene["vertices"], axis=1)) < 8.0


@pytest.mark.slow
def test_fit_on_the_floor_plane_is_scaled_and_without_evidence_is_not(scene):
    (length, _), side = _truth(scene)
    cues = synthetic_cues(scene, joint_noise_px=2.0, rng=1)
    floor = fit_foot(cues, scene["K"], cam_from_floor=scene["cam_from_scene"], side=side)
    assert floor.scaled and floor.scale_source == "floor"
    assert abs(canonical_measures(floor.shape)[0] - length) < 10.0
    bare = fit_foot(cues, scene["K"], side=side)
    assert not bare.scaled and bare.scale_source == "none"


def test_bad_inputs_are_refused(scene):
    cues = synthetic_cues(scene, rng=0)
    with pytest.raises(ValueError):
        fit_foot(cues, np.eye(2), side="left")
    with pytest.raises(ValueError):
        fit_foot(cues, scene["K"], side="both")
    with pytest.raises(ValueError):
        fit_foot(cues, scene["K"], depth_mm=np.zeros((5, 5), np.float32), side="left")
