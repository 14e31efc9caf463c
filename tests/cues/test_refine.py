"""Silhouette refinement: a blurred, shrunken foot outline snaps back to the rendered foot's edges."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from footmesh.cues.refine import RefineConfig, clear_paper, height_image, refine_silhouette
from footmesh.synth.render import Renderer
from footmesh.synth.scene import guided_view_config


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


@pytest.fixture(scope="module")
def photos() -> list[dict]:
    renderer = Renderer(guided_view_config(size=256, reference="none"))
    return [renderer.render(31, i) for i in range(4)]


def network_like(silhouette: np.ndarray, shrink_px: int = 2, blur_px: float = 3.0) -> np.ndarray:
    """What a low-resolution network gives: the outline smoothed and a little inside the true one."""
    eroded = cv2.erode(silhouette.astype(np.uint8), np.ones((2 * shrink_px + 1,) * 2, np.uint8))
    return cv2.GaussianBlur(eroded.astype(np.float32), (0, 0), blur_px)


def test_a_smoothed_shrunken_outline_snaps_to_the_photos_edges(photos):
    before, after = [], []
    for s in photos:
        truth = s["silhouette"].astype(bool)
        coarse = network_like(truth)
        refined = refine_silhouette(s["rgb"], coarse)
        assert refined.shape == truth.shape and refined.dtype == np.float32
        assert 0.0 <= refined.min() and refined.max() <= 1.0
        before.append(iou(coarse >= 0.5, truth))
        after.append(iou(refined >= 0.5, truth))
    assert np.mean(after) > np.mean(before) + 0.05, (before, after)
    # never worse; a cut that would change the area by more than 30 % is not trusted (the small feet here)
    assert all(a >= b - 0.01 for a, b in zip(after, before, strict=True)), (before, after)
    assert max(after) > 0.98, after


def test_the_same_photo_is_refined_the_same_whatever_came_before(photos):
    # GrabCut's colour models start from k-means on OpenCV's random generator, whose state other calls advance
    coarse = [network_like(s["silhouette"].astype(bool)) for s in photos]
    first = [refine_silhouette(s["rgb"], c) for s, c in zip(photos, coarse, strict=True)]
    for s, c, f in zip(photos[::-1], coarse[::-1], first[::-1], strict=True):
        np.testing.assert_array_equal(refine_silhouette(s["rgb"], c), f)


def test_untrusted_cuts_and_empty_silhouettes_are_left_alone(photos):
    s = photos[0]
    coarse = network_like(s["silhouette"].astype(bool))
    flat = np.full_like(s["rgb"], 128)  # no edges, no colours: nothing to cut along
    out = refine_silhouette(flat, coarse, RefineConfig(max_area_change=0.0))
    assert out is coarse
    empty = np.zeros_like(coarse)
    assert refine_silhouette(s["rgb"], empty) is empty
    with pytest.raises(ValueError, match="uint8"):
        refine_silhouette(s["rgb"].astype(np.float32), coarse)


def test_a_depth_map_alone_refines_on_the_height_above_the_floor(photos):
    before, after = [], []
    for s in photos:
        truth = s["silhouette"].astype(bool)
        coarse = network_like(truth)
        image = height_image(s["depth"].astype(np.float32), s["K"], coarse >= 0.5)
        assert image is not None and image.dtype == np.uint8 and image.shape == (*truth.shape, 3)
        floor = (s["labels"] == 0) & (s["depth"] > 0)  # label 0: floor / background
        assert np.median(image[..., 0][floor]) <= 12  # within 2 mm of the fitted plane
        assert np.median(image[..., 0][truth & (s["depth"] > 0)]) > 60  # the foot stands > 10 mm above it
        before.append(iou(coarse >= 0.5, truth))
        after.append(iou(refine_silhouette(image, coarse) >= 0.5, truth))
    assert np.mean(after) > np.mean(before) + 0.03, (before, after)
    no_floor = np.where(photos[0]["silhouette"], photos[0]["depth"], 0).astype(np.float32)
    assert height_image(no_floor, photos[0]["K"], photos[0]["silhouette"].astype(bool)) is None


def test_missing_depth_on_the_foots_outline_is_not_read_as_floor(photos):
    """Sensors drop the pixels of depth edges (the foot's outline): they take the nearest measured height, so a
    refinement on the height image no longer shaves the outline off."""
    for s in photos[:2]:
        truth = s["silhouette"].astype(bool)
        rim = truth & ~cv2.erode(truth.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        depth = np.where(rim, 0, s["depth_clean"]).astype(np.float32)  # a 3-px band of the foot's rim missing
        image = height_image(depth, s["K"], truth)
        assert image is not None
        height = image[..., 0].astype(float)
        assert np.median(height[rim]) > 24  # > 4 mm above the floor, as the foot pixels beside them
        coarse = network_like(truth)
        assert iou(refine_silhouette(image, coarse) >= 0.5, truth) >= iou(coarse >= 0.5, truth)


def _foot_on_paper(skin=(196, 140, 112), shadow_level=0.55, seed=0):
    """A drawn photo: carpet, a white sheet, a skin-coloured foot on it and the foot's grey shadow on the paper
    beside it (where a network's silhouette spills); (rgb, the sheet's corners, the foot's mask, the shadow's)."""
    rng = np.random.default_rng(seed)
    h, w = 400, 300
    rgb = np.full((h, w, 3), (110, 104, 98), np.float64)  # carpet
    sheet = np.array([[30, 20], [270, 20], [270, 380], [30, 380]], np.float64)
    on_sheet = np.zeros((h, w), np.uint8)
    cv2.fillConvexPoly(on_sheet, sheet.astype(np.int32), 1)
    rgb[on_sheet > 0] = (236, 234, 226)
    foot = np.zeros((h, w), np.uint8)
    cv2.ellipse(foot, (150, 190), (50, 140), 0, 0, 360, 1, -1)
    shadow = np.zeros((h, w), np.uint8)
    cv2.ellipse(shadow, (95, 200), (35, 120), 0, 0, 360, 1, -1)
    shadow = (shadow > 0) & (foot == 0) & (on_sheet > 0)
    rgb[shadow] *= shadow_level
    rgb[foot > 0] = skin
    rgb += rng.normal(0, 3.0, rgb.shape)
    return np.clip(rgb, 0, 255).astype(np.uint8), sheet, foot > 0, shadow


def _iou(a, b):
    return float((a & b).sum() / (a | b).sum())


def test_the_shadow_on_the_sheet_is_taken_out_of_the_silhouette_and_the_foot_kept():
    rgb, sheet, foot, shadow = _foot_on_paper()
    spilled = (foot | shadow).astype(np.float32)
    assert _iou(spilled >= 0.5, foot) < 0.8
    cleared = clear_paper(rgb, spilled, sheet) >= 0.5
    assert _iou(cleared, foot) > 0.97
    assert not (cleared & shadow).any() or (cleared & shadow).sum() < 0.02 * shadow.sum()


def test_dark_skin_and_deep_shadow_are_told_apart_too():
    rgb, sheet, foot, shadow = _foot_on_paper(skin=(96, 62, 44), shadow_level=0.35, seed=1)
    cleared = clear_paper(rgb, (foot | shadow).astype(np.float32), sheet) >= 0.5
    assert _iou(cleared, foot) > 0.95


def test_a_foot_the_colour_of_the_paper_or_off_the_sheet_is_left_alone():
    rgb, sheet, foot, shadow = _foot_on_paper(skin=(180, 178, 172))  # grey: chromatically the paper's
    spilled = (foot | shadow).astype(np.float32)
    assert np.array_equal(clear_paper(rgb, spilled, sheet), spilled)
    rgb, sheet, foot, shadow = _foot_on_paper()
    elsewhere = sheet + [400.0, 0.0]  # a sheet found elsewhere: nothing of the silhouette lies on it
    assert np.array_equal(
        clear_paper(np.pad(rgb, ((0, 0), (0, 500), (0, 0))), np.pad(spilled, ((0, 0), (0, 500))), elsewhere),
        np.pad(spilled, ((0, 0), (0, 500))),
    )
