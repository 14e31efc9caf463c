"""Geometry consistency of rendered samples: joints, depth, silhouette and reference corners agree with K."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from footmesh.geometry.camera import project
from footmesh.synth import raster
from footmesh.synth.render import LABEL_LEG
from footmesh.synth.textures import reference_size


def _project(points: np.ndarray, k: np.ndarray) -> np.ndarray:
    p = points.astype(np.float64) @ k.T
    return p[:, :2] / p[:, 2:3]


def test_joints_project_to_stored_2d(samples):
    for s in samples:
        err = np.abs(_project(s["joints3d"], s["K"]) - s["joints2d"]).max()
        assert err < 0.5, err
        assert s["joints_visible"].dtype == bool and s["joints_visible"].any()


def test_clean_depth_in_silhouette_lies_on_the_mesh(samples, renderer):
    worst = 0.0
    for s in samples[:3]:
        k, sil, depth = s["K"], s["silhouette"], s["depth_clean"].astype(np.float64)
        rows, cols = np.nonzero(sil)
        z = depth[rows, cols]
        pts = np.stack([(cols - k[0, 2]) * z / k[0, 0], (rows - k[1, 2]) * z / k[1, 1], z], axis=1)
        side = "right" if int(s["side"]) else "left"
        mesh = trimesh.Trimesh(s["vertices"].astype(np.float64), renderer._faces[side], process=False)
        _, dist, _ = trimesh.proximity.closest_point(mesh, pts)
        worst = max(worst, float(dist.max()))
    assert worst < 1.0, worst


def test_silhouette_is_the_foots_own_pixels(samples, renderer):
    """Render the foot alone: the silhouette is exactly its pixels except where the leg hides them."""
    for s in samples:
        side = "right" if int(s["side"]) else "left"
        xy, z = project(s["vertices"].astype(np.float64), s["K"])
        size = s["rgb"].shape[0]
        alone = raster.rasterize(xy, z, renderer._faces[side], size, size).face >= 0
        sil = s["silhouette"]
        assert not (sil & ~alone).any()
        hidden = alone & ~sil
        assert (s["labels"][hidden] == LABEL_LEG).all()


def test_reference_corners(samples):
    seen = 0
    for s in samples:
        if int(s["ref_type"]) == 0:
            assert np.isnan(s["ref_corners3d"]).all()
            continue
        seen += 1
        corners = s["ref_corners3d"].astype(np.float64)
        assert np.abs(_project(corners, s["K"]) - s["ref_corners2d"]).max() < 0.5
        scene_from_cam = np.linalg.inv(s["cam_from_scene"])
        on_floor = corners @ scene_from_cam[:3, :3].T + scene_from_cam[:3, 3]
        assert np.abs(on_floor[:, 2]).max() < 1e-2  # lying on the floor
        kind = ("none", "a4", "card", "marker")[int(s["ref_type"])]
        length, width = reference_size(kind)
        sides = np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)
        np.testing.assert_allclose(sides, [length, width, length, width], atol=1e-2)
    assert seen > 0


def test_cam_from_foot_places_the_model(samples, renderer):
    import torch

    s = samples[0]
    side = "right" if int(s["side"]) else "left"
    pose = torch.from_numpy(s["cam_from_foot"])
    out = renderer.model(
        torch.from_numpy(s["shape"].astype(np.float64))[None],
        torch.from_numpy(s["angles"].astype(np.float64))[None],
        side=side,
        rotation=pose[None, :3, :3],
        translation=pose[None, :3, 3],
    )
    # angles are stored as float32: a few hundredths of a mm at most
    assert np.abs(out.vertices[0].numpy() - s["vertices"]).max() < 0.05


def test_rasteriser_matches_a_naive_loop():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-2, 18, (12, 2))
    z = rng.uniform(100, 200, 12)
    faces = rng.integers(0, 12, (10, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    frag = raster.rasterize(xy, z, faces, 16, 16, cull_back=False)
    for i in range(16):
        for j in range(16):
            best = np.inf
            for f in faces:
                a, b, c = xy[f]
                m = np.array([[b[0] - a[0], c[0] - a[0]], [b[1] - a[1], c[1] - a[1]]])
                if abs(np.linalg.det(m)) < 1e-12:
                    continue
                u, v = np.linalg.solve(m, [j - a[0], i - a[1]])
                w = np.array([1 - u - v, u, v])
                if (w >= -1e-9).all():
                    best = min(best, 1.0 / (w / z[f]).sum())
            assert np.isclose(frag.depth[i, j], best) or (np.isinf(best) and np.isinf(frag.depth[i, j]))


def test_random_views_frame_the_reference_object_as_the_photo_guide_asks():
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    for kind in ("a4", "card"):
        framed = Renderer(SynthConfig(size=48, reference=kind, frame_reference=True))
        foot_only = Renderer(SynthConfig(size=48, reference=kind, frame_reference=False))
        inside = {True: 0, False: 0}
        for i in range(8):
            for frames, r in ((True, framed), (False, foot_only)):
                s = r.render(11, i)
                corners = _project(s["ref_corners3d"].astype(np.float64), s["K"])
                inside[frames] += bool(((corners >= 0) & (corners <= 48)).all())
        assert inside[True] == 8, inside  # every corner in the photo
        assert inside[False] < 8, inside  # framing on the foot alone cuts some objects off


def test_guided_views_see_the_foot_from_the_side_and_flat_on_the_floor():
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig, guided_view_config

    renderer = Renderer(guided_view_config(size=32, reference="card"))
    for i in range(10):
        s = renderer.render(5, i)
        # the foot's long axis (foot x) lies across the view: within 30 deg of the image plane, plus the tilt
        assert abs(s["cam_from_foot"][2, 0]) < 0.6, i
        assert not bool(s["lifted"])
    with pytest.raises(ValueError, match="azimuths"):
        SynthConfig(min_azimuth_deg=150.0, max_azimuth_deg=140.0)


def test_ood_views_are_unlike_the_training_ones():
    """The out-of-distribution eval's scenes (``view_config("ood")``): lifted feet, short leg stumps, every skin
    re-toned, and four times the sensor noise on a flat floor patch."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig, view_config

    config = view_config("ood", size=48, reference="none")
    scenes = [Renderer(config).scene(7, i) for i in range(40)]
    assert 0.2 < np.mean([s.lifted for s in scenes]) < 0.8
    assert all(s.skin_tone is not None for s in scenes)
    assert max(s.leg_top_mm for s in scenes) <= 260.0
    assert min(s.fov_deg for s in scenes) < 50.0 < 90.0 < max(s.fov_deg for s in scenes)
    # the same scene with the training noise and with the eval's: the difference is the added noise
    plain = Renderer(SynthConfig(size=48, reference="none", rgb_noise_sd=0.0)).render(7, 0)["rgb"]
    for noise, lo, hi in ((1.5 / 255, 0.5, 3.0), (6.0 / 255, 4.0, 8.0)):
        noisy = Renderer(SynthConfig(size=48, reference="none", rgb_noise_sd=noise)).render(7, 0)["rgb"]
        sd = float(np.std(noisy.astype(np.float64) - plain))
        assert lo < sd < hi, (noise * 255, sd)
    with pytest.raises(ValueError, match="rgb_noise_sd"):
        SynthConfig(rgb_noise_sd=-0.1)


def test_weight_bearing_feet_stand_on_heel_and_ball_and_keep_their_toes_out_of_the_floor():
    """``SynthConfig.weight_bearing`` (the ``front`` views): the heel's and the ball's lowest points on the floor
    (within the 0.024 rad grid of the hindfoot angle: about 2 mm), no toe through the floor below the ball (1 mm
    allowed, and the hindfoot's angle moves the ball's back edge by about as much again); without it the same seed
    keeps the everyday pose as drawn, one of the two often well off the floor."""
    from dataclasses import replace

    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import view_config

    bearing = view_config("front", size=32, reference="none")
    assert bearing.weight_bearing
    renderers = {flag: Renderer(replace(bearing, weight_bearing=flag)) for flag in (True, False)}
    gaps = {True: [], False: []}
    for flag, renderer in renderers.items():
        for i in range(12):
            s = renderer.render(9, i)
            scene_from_cam = np.linalg.inv(s["cam_from_scene"])
            z = (s["vertices"] @ scene_from_cam[:3, :3].T + scene_from_cam[:3, 3])[:, 2]
            heel, ball, toes = (z[renderer._heel].min(), z[renderer._ball].min(), z[renderer._toes].min())
            assert min(heel, ball, toes) == pytest.approx(0.0, abs=1e-3)  # standing: the lowest point on the floor
            gaps[flag].append(max(heel, ball))
            if flag:
                assert toes >= ball - 2.5, i
    assert max(gaps[True]) < 2.5, gaps[True]
    assert max(gaps[False]) > 10.0, gaps[False]  # at rest: the heel or the ball lifted
