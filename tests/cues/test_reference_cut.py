"""A sheet with one side beyond the photo's edge (``footmesh.cues.reference.cut``), or one corner
(``finish.finish_beyond``): front views of the eval rendered with a known sheet, cropped so that the photo's edge
cuts across the sheet, searched as the pipeline does (the foot and leg masked out)."""

from __future__ import annotations

import functools

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from footmesh.cues.reference import search_reference
from footmesh.cues.reference.params import BORDER_MARGIN_PX
from footmesh.cues.reference.search import _area_in_photo
from footmesh.cues.reference.sides import side_in_view
from footmesh.geometry.camera import pixel_rays
from footmesh.synth.render import Renderer
from footmesh.synth.scene import view_config

SEED = 4242  # eval measure's rgb_ref photos of the front views (its first mode)
CUT_DEPTH = 0.3
"""The photo's edge crosses the sheet this far from its cut-off corners towards the others (of their gap)."""


@functools.cache
def _front(index: int) -> dict:
    return Renderer(view_config("front", size=640, reference="a4")).render(SEED, index)


def _cut(sample: dict, edge: str, corners_cut: int = 2) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The photo cropped so that its ``edge`` ("top", "left") cuts off the ``corners_cut`` sheet corners nearest to
    it: (rgb, K, feet mask, the sheet's true corners (4, 2) in the crop's px)."""
    corners = sample["ref_corners2d"].astype(np.float64)
    axis = 1 if edge == "top" else 0
    first, second = np.sort(corners[:, axis])[corners_cut - 1 : corners_cut + 1]
    start = int(round(first + CUT_DEPTH * (second - first)))
    offset = np.array([0, start] if axis else [start, 0])
    rgb = np.ascontiguousarray(sample["rgb"][start:] if axis else sample["rgb"][:, start:])
    K = sample["K"].astype(np.float64).copy()
    K[:2, 2] -= offset
    feet = sample["silhouette"][start:] if axis else sample["silhouette"][:, start:]
    mask = cv2.dilate(feet.astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    assert np.sum(np.all((corners - offset >= 0), axis=1)) == 4 - corners_cut, "the crop cuts off other corners"
    return rgb, K, mask, corners - offset


def _floor(points_px: np.ndarray, K: np.ndarray, normal: np.ndarray, point: np.ndarray) -> np.ndarray:
    """(N, 3) mm where the pixels' rays meet the plane through ``point`` (3,) with ``normal`` (3,), camera frame."""
    rays = pixel_rays(points_px, K)
    return rays * ((normal @ point) / (rays @ normal))[:, None]


@pytest.mark.parametrize("index", [3, 11])
def test_a_sheet_cut_by_the_photos_edge_is_placed_from_its_three_sides(index):
    """The sheet's far corners, beyond the photo, land where the sheet's are; every length across the part in
    view, measured through its floor plane, is the true one within 1 % and within three of its SD."""
    sample = _front(index)
    rgb, K, mask, truth = _cut(sample, "top")
    found = search_reference(rgb, K, exclude_mask=mask).found
    assert found is not None and found.kind == "a4" and found.beyond_edge
    h, w = rgb.shape[:2]
    outside = (found.corners_px[:, 1] < 0).sum()
    assert outside == 2, f"corners {found.corners_px.round(1)}"
    errors = min(
        (np.linalg.norm(np.roll(found.corners_px, s, axis=0)[::d] - truth, axis=1) for s in range(4) for d in (1, -1)),
        key=np.max,
    )
    assert errors.max() < 4.0, f"corner errors {errors.round(2)} px"
    # the part of the sheet in view: its two corners and where its sides leave the photo
    _, shown = cv2.intersectConvexConvex(
        truth.astype(np.float32), np.float32([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]])
    )
    shown = shown.reshape(-1, 2).astype(np.float64)
    corners3d = sample["ref_corners3d"].astype(np.float64)
    true_normal = np.cross(corners3d[1] - corners3d[0], corners3d[3] - corners3d[0])
    measured = _floor(shown, K, found.floor_normal, found.cam_from_floor[:3, 3])
    actual = _floor(shown, K, true_normal, corners3d[0])
    i, j = np.triu_indices(len(shown), 1)
    rel = np.linalg.norm(measured[i] - measured[j], axis=1) / np.linalg.norm(actual[i] - actual[j], axis=1) - 1.0
    assert np.abs(rel).max() < min(0.01, 3 * found.scale_rel_sd), f"length errors {100 * rel.round(4)} %"
    assert found.scale_rel_sd < 0.03


@pytest.mark.parametrize(("index", "edge"), [(6, "top"), (10, "left")])
def test_a_sheet_with_one_corner_beyond_the_photos_edge_is_placed_where_its_sides_meet(index, edge):
    """Three corners in view and the fourth beyond the edge: the four sides' lines place it and show the sheet's
    proportions, so the sheet is named (not assumed) and every corner lands where the sheet's is; lengths across
    the part in view, measured through its floor plane, are the true ones within 1 % and three of their SD."""
    sample = _front(index)
    rgb, K, mask, truth = _cut(sample, edge, corners_cut=1)
    found = search_reference(rgb, K, exclude_mask=mask).found
    assert found is not None and found.kind == "a4" and found.corner_beyond_edge
    assert not found.beyond_edge and not found.kind_assumed
    h, w = rgb.shape[:2]
    inside = (found.corners_px >= 0).all(axis=1) & (found.corners_px <= [w - 1, h - 1]).all(axis=1)
    assert inside.sum() == 3, f"corners {found.corners_px.round(1)}"
    errors = min(
        (np.linalg.norm(np.roll(found.corners_px, s, axis=0)[::d] - truth, axis=1) for s in range(4) for d in (1, -1)),
        key=np.max,
    )
    assert errors.max() < 2.0, f"corner errors {errors.round(2)} px"
    corners3d = sample["ref_corners3d"].astype(np.float64)
    true_normal = np.cross(corners3d[1] - corners3d[0], corners3d[3] - corners3d[0])
    in_view = truth[(truth >= 0).all(axis=1) & (truth <= [w - 1, h - 1]).all(axis=1)]
    measured = _floor(in_view, K, found.floor_normal, found.cam_from_floor[:3, 3])
    actual = _floor(in_view, K, true_normal, corners3d[0])
    i, j = np.triu_indices(len(in_view), 1)
    rel = np.linalg.norm(measured[i] - measured[j], axis=1) / np.linalg.norm(actual[i] - actual[j], axis=1) - 1.0
    assert np.abs(rel).max() < min(0.01, 3 * found.scale_rel_sd), f"length errors {100 * rel.round(4)} %"


def test_a_sheet_cut_along_its_length_says_which_side_cannot_be_told():
    """Cut along a long side, with less than half of the short sides in view: the side in view whole may be
    either of the sheet's (the other, 1.41x longer, fits too); no scale is taken from it, and the search says
    why."""
    rgb, K, mask, _ = _cut(_front(5), "left")
    searched = search_reference(rgb, K, exclude_mask=mask)
    assert searched.found is None
    assert "runs off the photo's edge and which of its sides is cut cannot be told" in searched.rejected
    assert 0.1 < searched.rejected_area <= 1.0  # its share of the photo: the part in view


def test_an_uncertain_focal_length_widens_a_cut_sheets_scale_sd_and_a_guessed_one_refuses_it():
    """The cut sides' scale rests on the focal length where the sheet is seen at an angle: known to 2 %, the sheet
    is placed as with it known exactly (at the caller's focal length) and the scale's SD grows by what 2 % changes
    along the cut sides; known only to 10 % (EXIF), the change passes ``MAX_SCALE_REL_SD`` and the search says
    what to do."""
    rgb, K, mask, _ = _cut(_front(5), "top")
    held = search_reference(rgb, K, exclude_mask=mask).found
    guessed = search_reference(rgb, K, exclude_mask=mask, focal_prior_log_sd=0.02).found
    assert held is not None and guessed is not None and held.beyond_edge and guessed.beyond_edge
    np.testing.assert_allclose(guessed.K, K)
    np.testing.assert_allclose(guessed.corners_px, held.corners_px, atol=1e-6)
    assert guessed.focal_log_sd == 0.02
    assert guessed.scale_rel_sd > held.scale_rel_sd + 1e-3
    rgb, K, mask, _ = _cut(_front(2), "top")
    assert search_reference(rgb, K, exclude_mask=mask).found is not None
    searched = search_reference(rgb, K, exclude_mask=mask, focal_prior_log_sd=0.1)
    assert searched.found is None
    assert "depends on the focal length" in searched.rejected and "--intrinsics" in searched.rejected


def test_a_rejected_cut_sheets_share_of_the_photo_is_the_part_in_view():
    """A cut sheet's rough quad reaches past the photo (its side along the edge runs on beyond the photo's corner):
    the message's "N % of the photo" counts only the part inside (a cropped real photo once read 132 %)."""
    quad = np.array([[-238.0, 0.0], [526.0, 0.0], [525.0, 472.0], [82.0, 472.0]])
    # its left side crosses x = 0 at y = 472 * 238 / 320
    x, y = np.array([[0.0, 0.0], [526.0, 0.0], [525.0, 472.0], [82.0, 472.0], [0.0, 472.0 * 238.0 / 320.0]]).T
    inside = 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))
    assert _area_in_photo(quad, 585, 640) == pytest.approx(inside, rel=1e-4)


@given(
    st.tuples(*[st.floats(-200.0, 800.0) for _ in range(4)]),
    st.integers(20, 600),
    st.integers(20, 600),
)
def test_a_side_in_view_is_the_part_of_it_inside_the_photo_in_its_own_direction(ends, h, w):
    """``side_in_view``: the clipped segment lies inside the photo (``BORDER_MARGIN_PX`` in), on the side's line,
    pointing the same way; None only where no point of the side is inside."""
    p, q = np.array(ends[:2]), np.array(ends[2:])
    seen = side_in_view(p, q, h, w)
    lo, hi = BORDER_MARGIN_PX, np.array([w - 1.0, h - 1.0]) - BORDER_MARGIN_PX
    samples = p + np.linspace(0.0, 1.0, 201)[:, None] * (q - p)
    any_inside = bool(np.all((samples >= lo - 1e-9) & (samples <= hi + 1e-9), axis=1).any())
    if seen is None:
        assert not any_inside or np.linalg.norm(q - p) < 1e-6
        return
    a, b = seen
    for point in (a, b):
        assert np.all(point >= lo - 1e-6) and np.all(point <= hi + 1e-6)
        offset = point - p
        assert abs(offset[0] * (q - p)[1] - offset[1] * (q - p)[0]) <= 1e-6 * (1.0 + np.linalg.norm(q - p) ** 2)
    assert (b - a) @ (q - p) >= 0.0
