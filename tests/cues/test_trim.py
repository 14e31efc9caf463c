"""Cutting a silhouette to its joints: a rendered foot loses nothing, a shin beyond it is cut away."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.cues.trim import TrimConfig, foot_axes, foot_region, trim_silhouette
from footmesh.fit import projected_mask
from footmesh.model.layer import default_model
from footmesh.synth.render import Renderer
from footmesh.synth.scene import view_config


@pytest.mark.parametrize("views", ["guided", "front", "ood"])
def test_a_rendered_foot_with_its_true_joints_loses_no_pixel(views):
    renderer = Renderer(view_config(views, size=256, reference="none"))
    for i in range(8):
        sample = renderer.render(43, i)
        # this foot's pixels: the ood views' other foot is foot in the silhouette too
        faces = default_model().faces("right" if int(sample["side"]) else "left").numpy()
        own = projected_mask(sample["vertices"].astype(np.float64), faces, sample["K"], sample["silhouette"].shape)
        silhouette = (sample["silhouette"] & own).astype(np.float32)
        trimmed = trim_silhouette(silhouette, sample["joints2d"])
        assert trimmed.dtype == np.float32 and trimmed.shape == silhouette.shape
        np.testing.assert_array_equal(trimmed, silhouette)


def _foot_with_a_shin(h: int = 400, w: int = 200) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A foot seen from above, toes up (heel at y 200, toe tips at y 60, 60 px wide), the shin a strip from its
    heel down to the image's edge; and its joints."""
    joints = np.zeros((18, 2), np.float32)
    tips_x = np.linspace(75, 125, 5)
    for k in range(5):
        joints[1 + 3 * k] = (tips_x[k], 110)  # first joints, 50 px apart
        joints[2 + 3 * k] = (tips_x[k], 85)
        joints[3 + 3 * k] = (tips_x[k], 60 + 4 * abs(k - 1))
    joints[0], joints[16], joints[17] = (100, 150), (100, 185), (100, 200)
    foot = np.zeros((h, w), np.float32)
    foot[55:210, 70:131] = 1.0
    shin = np.zeros_like(foot)
    shin[180:, 80:121] = 1.0
    return foot, np.maximum(foot, shin), joints


def test_a_shin_running_off_the_photo_is_cut_and_the_foot_kept():
    foot, with_shin, joints = _foot_with_a_shin()
    trimmed = trim_silhouette(with_shin, joints)
    assert np.all(trimmed[foot > 0] == 1.0)  # the foot kept whole
    axes = foot_axes(joints)
    config = TrimConfig()
    # the cut lies config.behind_heel x S behind the heel: the shin beyond it is gone
    cut_y = 200 + config.behind_heel * axes.size
    assert axes.size == pytest.approx(max(140, config.width_to_length * 50))
    assert trimmed[int(np.ceil(cut_y)) + 1 :].sum() == 0
    assert trimmed[: int(cut_y)].sum() == with_shin[: int(cut_y)].sum()


def test_joints_too_close_together_cut_nothing():
    silhouette = np.ones((40, 50), np.float32)
    joints = np.full((18, 2), 20.0, np.float32)
    assert foot_axes(joints) is None
    assert foot_region(silhouette.shape, joints).all()
    np.testing.assert_array_equal(trim_silhouette(silhouette, joints), silhouette)
    joints[3] = np.nan
    np.testing.assert_array_equal(trim_silhouette(silhouette, joints), silhouette)
