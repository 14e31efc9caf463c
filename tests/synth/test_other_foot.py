"""The other foot in view, first-person and front views, skin-coloured legs: drawn after everything else (old datasets
keep their values), labelled foot, never changing the first foot's ground truth."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
import torch

from footmesh.synth.render import LABEL_FOOT, LEG_SEGMENTS, Renderer
from footmesh.synth.scene import SynthConfig, sample_scene, sample_skin

SIZE = 96


def test_the_new_draws_leave_every_other_value_of_a_scene_alone():
    plain = sample_scene(3, 5, SynthConfig(), 10)
    both = sample_scene(3, 5, SynthConfig(other_foot_fraction=1.0), 10)
    assert plain.other_foot is None and both.other_foot is not None
    assert np.array_equal(plain.shape, both.shape) and plain.noise_seed == both.noise_seed
    assert replace(both, other_foot=None).azimuth == plain.azimuth


@pytest.mark.parametrize("side", ["left", "right"])
def test_the_other_foot_stands_beside_the_first_and_is_labelled_foot(side):
    renderer = Renderer(SynthConfig(size=SIZE, other_foot_fraction=1.0, lifted_fraction=0.0))
    index = next(i for i in range(50) if renderer.scene(9, i).side == side)
    scene = renderer.scene(9, index)
    geo, _ = renderer.geometry(scene)
    other = geo.other_foot.vertices
    # a person's right foot stands on the left foot's -y side (the foot frame's y points left)
    assert np.sign(other[:, 1].mean() - geo.foot_vertices[:, 1].mean()) == (-1 if side == "left" else 1)
    assert abs(other[:, 2].min()) < 1e-6  # standing on the floor
    with_other = renderer.render(9, index)
    alone = Renderer(replace(renderer.config, other_foot_fraction=0.0)).render(9, index)
    # the first foot's ground truth is untouched; the silhouette gains the other foot's pixels
    assert np.array_equal(with_other["joints2d"], alone["joints2d"])
    assert np.array_equal(with_other["vertices"], alone["vertices"])
    assert np.array_equal(with_other["silhouette"], with_other["labels"] == LABEL_FOOT)
    gained = with_other["silhouette"] & ~alone["silhouette"]
    assert gained.sum() > 0.2 * alone["silhouette"].sum()
    assert not (alone["silhouette"] & ~with_other["silhouette"]).sum() > 0.5 * alone["silhouette"].sum()


def test_first_person_views_look_down_from_behind_the_heels():
    config = SynthConfig(size=SIZE, first_person_fraction=1.0)
    renderer = Renderer(config)
    for i in range(4):
        scene = renderer.scene(2, i)
        assert scene.first_person and abs(abs(scene.azimuth) - math.pi) <= math.radians(40) + 1e-9
        assert scene.elevation >= math.radians(50)
        sample = renderer.render(2, i)
        eye = -sample["cam_from_scene"][:3, :3].T @ sample["cam_from_scene"][:3, 3]
        centre = renderer.geometry(scene)[0].foot_vertices.mean(axis=0)
        assert eye[0] < centre[0] and eye[2] > 300  # on the heel's side of the foot and well above the floor


def test_front_views_look_at_the_toes_from_above_with_the_foot_on_the_sheet():
    config = SynthConfig(size=SIZE, front_fraction=1.0, reference="a4", lifted_fraction=1.0)
    plain = SynthConfig(size=SIZE, reference="a4", lifted_fraction=1.0)
    for i in range(6):
        scene, before = sample_scene(4, i, config, 10), sample_scene(4, i, plain, 10)
        assert scene.front and abs(scene.azimuth) <= math.radians(35) + 1e-9
        assert math.radians(45) <= scene.elevation <= math.radians(85) and 500 <= scene.leg_top_mm <= 800
        assert not scene.lifted and scene.reference.under_foot
        assert np.array_equal(scene.shape, before.shape) and scene.noise_seed == before.noise_seed
    # drawn after the first-person views: those keep their view
    both = sample_scene(4, 0, SynthConfig(first_person_fraction=1.0, front_fraction=1.0), 10)
    assert both.first_person and not both.front
    renderer = Renderer(config)
    sample = renderer.render(4, 0)
    eye = -sample["cam_from_scene"][:3, :3].T @ sample["cam_from_scene"][:3, 3]
    assert eye[0] > renderer.geometry(renderer.scene(4, 0))[0].foot_vertices[:, 0].max()  # beyond the toes


def test_fractions_outside_0_1_are_refused():
    with pytest.raises(ValueError, match="other_foot_fraction"):
        SynthConfig(other_foot_fraction=1.5)
    with pytest.raises(ValueError, match="front_fraction"):
        SynthConfig(front_fraction=-0.1)


def test_a_mirrored_training_image_shows_the_other_side():
    from footmesh.train.data import Augment, Batch, augment_batch, inside_image

    b, s = 64, 32
    joints = torch.full((b, 18, 2), 16.0)
    batch = Batch(
        torch.rand(b, 3, s, s), torch.zeros(b, 1, s, s), torch.zeros(b, 1, s, s), joints,
        torch.ones(b, 18), inside_image(joints, s), torch.zeros(b),
    )  # fmt: skip
    flip_only = Augment(scale=(1, 1), rotate_deg=0, shift=0, flip=1.0)
    assert torch.equal(augment_batch(batch, flip_only, torch.Generator().manual_seed(0)).side, torch.ones(b))
    never = replace(flip_only, flip=0.0)
    assert torch.equal(augment_batch(batch, never, torch.Generator().manual_seed(0)).side, torch.zeros(b))


def test_skin_legs_continue_the_foots_skin_and_leave_the_rest_of_the_sample_alone():
    plain = Renderer(SynthConfig(size=SIZE, other_foot_fraction=1.0))
    skinned = Renderer(replace(plain.config, skin_legs=True))
    index = next(i for i in range(50) if plain.scene(4, i).leg_style == "bare")
    scene = plain.scene(4, index)
    geo_plain, geo_skin = plain.geometry(scene)[0], skinned.geometry(scene)[0]
    # one even colour before; now it varies around and along the leg, starting from the ankle cap's own colours
    assert np.ptp(geo_plain.leg_albedo, axis=0).max() == 0.0
    assert np.ptp(geo_skin.leg_albedo, axis=0).max() > 0.02
    albedo = sample_skin(scene.seed, scene.index, scene.skin_tone, plain.skin)
    cap_colours = {tuple(c) for c in np.round(albedo[plain.cap], 6)}
    assert {tuple(c) for c in np.round(geo_skin.leg_albedo[:LEG_SEGMENTS], 6)} <= cap_colours
    assert np.ptp(geo_skin.other_leg.albedo, axis=0).max() > 0.02
    # the same geometry, labels and ground truth: only the leg's colours differ
    a, b = plain.render(4, index), skinned.render(4, index)
    for key in ("labels", "joints2d", "depth_clean", "angles"):
        assert np.array_equal(a[key], b[key]), key
    assert not np.array_equal(a["rgb"], b["rgb"])
