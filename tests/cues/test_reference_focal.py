"""The focal length a rectangle's perspective gives (``cues.reference.focal``), and a sheet found through a lens
other than the one assumed (issue 19)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest

from footmesh.cues.reference import focal as focal_mod
from footmesh.cues.reference import search_reference
from footmesh.cues.reference.quads import _corner_points_many
from footmesh.synth.render import Renderer
from footmesh.synth.scene import view_config

A4 = (297.0, 210.0)


def _seen_rectangle(focal_px: float, elevation_deg: float, size: int = 1000) -> np.ndarray:
    """(4, 2) px corners of an A4 sheet seen from ``elevation_deg`` above the floor through a lens of ``focal_px``,
    the camera backed off so that the sheet spans about half the image."""
    length, width = A4
    corners = np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]]) - [length / 2, width / 2, 0]
    e, a = math.radians(elevation_deg), math.radians(25.0)
    distance = 0.5 * focal_px * 2 * length / size + 200.0
    centre = distance * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    z = -centre / np.linalg.norm(centre)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    rotation = np.stack([x, np.cross(z, x), z])
    points = (corners - centre) @ rotation.T
    return points[:, :2] / points[:, 2:] * focal_px + (size - 1) / 2


def _K(focal_px: float, size: int = 1000) -> np.ndarray:
    return np.array([[focal_px, 0, (size - 1) / 2], [0, focal_px, (size - 1) / 2], [0, 0, 1.0]])


@pytest.mark.parametrize("factor", [0.6, 1.0, 2.0, 3.5])
def test_the_right_angle_gives_the_focal_length_whatever_the_one_assumed(factor):
    assumed = 800.0
    corners = _seen_rectangle(assumed * factor, elevation_deg=40.0)
    points, good = _corner_points_many(corners[None], _K(assumed))
    assert good.all()
    assert focal_mod.right_angle_scale(points)[0] == pytest.approx(factor, rel=1e-6)
    # the angle at that focal length is a right angle, at the assumed one it is not (unless it is the true one)
    assert focal_mod.corner_angle_deg(points, np.array([factor]))[0] == pytest.approx(90.0, abs=1e-6)


def test_an_oblique_sheet_moves_the_focal_length_a_sheet_seen_straight_on_does_not():
    assumed = 800.0
    for elevation, moved in ((40.0, True), (89.0, False)):
        corners = _seen_rectangle(assumed * 2.5, elevation)
        # the corners' noise: each corner moved by half a pixel, one at a time, either way
        shifts = [np.eye(8)[i].reshape(4, 2) * 0.5 * s for i in range(8) for s in (1, -1)]
        points, _ = _corner_points_many(np.stack([corners, *[corners + d for d in shifts]]), _K(assumed))
        scale, log_sd = focal_mod.focal_estimate(points[0], points[1:], prior_log_sd=0.7)
        if moved:
            assert scale == pytest.approx(2.5, rel=0.1) and log_sd < 0.2
        else:  # straight down the corner angle hardly depends on the focal length: the assumed one is kept
            assert abs(math.log(scale)) < 0.1 and log_sd > 0.6
        # a known focal length is never moved
        assert focal_mod.focal_estimate(points[0], points[1:], prior_log_sd=0.0) == (1.0, 0.0)


@functools.cache
def _tele_sample(index: int) -> dict:
    config = view_config("tele", size=640, reference="a4", elevation_deg=(35.0, 50.0))
    return Renderer(config).render(7, index)


@pytest.mark.parametrize("index", [0, 1])
def test_a_sheet_seen_through_a_tele_lens_is_found_without_its_focal_length(index):
    sample = _tele_sample(index)
    K_true = np.asarray(sample["K"], dtype=np.float64)
    assumed = focal_mod.with_focal_scale(K_true, 1.0 / 2.6)  # a main camera's focal length, as a photo without EXIF
    held = search_reference(sample["rgb"], assumed, exclude_mask=(sample["labels"] == 1) | (sample["labels"] == 2))
    assert held.found is None, "at the assumed focal length the oblique sheet is no rectangle"
    found = search_reference(
        sample["rgb"], assumed, exclude_mask=(sample["labels"] == 1) | (sample["labels"] == 2), focal_prior_log_sd=0.7
    ).found
    assert found is not None and found.kind == "a4"
    assert found.K[0, 0] == pytest.approx(K_true[0, 0], rel=0.1)
    cam = sample["cam_from_scene"]
    assert found.floor_distance_mm == pytest.approx(float(-cam[:3, 2] @ cam[:3, 3]), rel=0.1)


def test_a_prior_on_the_camera_distance_weighs_by_how_well_the_focal_length_is_known():
    # a well-measured focal length hardly moves; a guessed one moves most of the way to the prior's distance
    assert focal_mod.distance_prior_scale(0.02, 300.0, 600.0, 0.5)[0] == pytest.approx(1.0, abs=0.005)
    factor, log_sd = focal_mod.distance_prior_scale(0.7, 300.0, 600.0, 0.5)
    expected = math.exp(math.log(2.0) * (1 / 0.5**2) / (1 / 0.7**2 + 1 / 0.5**2))
    assert factor == pytest.approx(expected) and 1.4 < factor < 2.0
    assert log_sd < 0.5 and log_sd == pytest.approx((1 / 0.7**2 + 1 / 0.5**2) ** -0.5)
    # at the prior's own distance, or with the focal length held, nothing moves
    assert focal_mod.distance_prior_scale(0.7, 600.0, 600.0, 0.5) == (pytest.approx(1.0), pytest.approx(log_sd))
    assert focal_mod.distance_prior_scale(0.0, 300.0, 600.0, 0.5) == (1.0, 0.0)


def test_a_sheet_seen_straight_down_through_a_tele_lens_takes_its_focal_length_from_the_camera_distance():
    # a 2x lens (36 deg) held 0.6-0.8 m over the sheet, straight down
    config = view_config(
        "front_tele",
        size=640,
        reference="a4",
        elevation_deg=(84.0, 88.0),
        fov_deg=(36.0, 36.0),
        distance_mm=(600.0, 600.0),
    )
    sample = Renderer(config).render(7, 0)
    K_true = np.asarray(sample["K"], dtype=np.float64)
    assumed = focal_mod.with_focal_scale(K_true, 1.0 / 2.5)
    exclude = (sample["labels"] == 1) | (sample["labels"] == 2)
    perspective = search_reference(sample["rgb"], assumed, exclude_mask=exclude, focal_prior_log_sd=0.7).found
    both = search_reference(
        sample["rgb"], assumed, exclude_mask=exclude, focal_prior_log_sd=0.7, distance_prior=(550.0, 0.5)
    ).found
    assert perspective is not None and both is not None and both.kind == "a4"
    # straight down the perspective keeps the guess, 2.5x short; the distance prior takes it a good part of the way
    # (the camera stands 0.78 m away, farther than the prior's median: not all of it)
    assert perspective.K[0, 0] / K_true[0, 0] < 0.5
    assert abs(math.log(both.K[0, 0] / K_true[0, 0])) < 0.7 * abs(math.log(perspective.K[0, 0] / K_true[0, 0]))
    assert both.focal_log_sd < perspective.focal_log_sd
    # the floor moves with it: the camera stands farther, nearer the truth
    cam = sample["cam_from_scene"]
    true_height = float(-cam[:3, 2] @ cam[:3, 3])
    assert abs(both.floor_distance_mm - true_height) < abs(perspective.floor_distance_mm - true_height)
