"""The floor a depth map shows: found where the renders put it, refused where the depth shows no floor."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.cues.floor import depth_floor
from footmesh.synth.render import Renderer
from footmesh.synth.scene import view_config


@pytest.fixture(scope="module")
def photos() -> list[dict]:
    renderer = Renderer(view_config("front", size=256, reference="none"))
    return [renderer.render(41, i) for i in range(3)]


def test_the_floor_of_a_depth_map_is_the_scenes_floor(photos):
    for s in photos:
        pose = depth_floor(s["depth"].astype(np.float32), s["K"], s["silhouette"].astype(bool))
        assert pose is not None
        np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-9)
        truth = np.asarray(s["cam_from_scene"], dtype=np.float64)  # the scene's z = 0 is the floor, z up
        angle = np.degrees(np.arccos(np.clip(pose[:3, 2] @ truth[:3, 2], -1, 1)))
        assert angle < 1.0
        # the floor frame's origin lies on the true floor, and the camera stands as high above both
        floor_from_cam = np.linalg.inv(truth)
        assert abs(floor_from_cam[2, :3] @ pose[:3, 3] + floor_from_cam[2, 3]) < 2.0
        assert abs(np.linalg.inv(pose)[2, 3] - floor_from_cam[2, 3]) < 3.0


def test_no_floor_is_made_up(photos):
    s = photos[0]
    mask, depth, K = s["silhouette"].astype(bool), s["depth"].astype(np.float32), s["K"]
    assert depth_floor(np.where(mask, depth, 0), K, mask) is None  # the foot alone
    rng = np.random.default_rng(0)
    clutter = np.where(mask, depth, rng.uniform(200, 2000, depth.shape)).astype(np.float32)
    assert depth_floor(clutter, K, mask) is None  # no plane holds most of what is around the foot
    # the camera under the "floor" (a ceiling, or a depth map in the wrong units) is no floor to stand on
    assert depth_floor(depth / 1000.0, K, mask) is None
