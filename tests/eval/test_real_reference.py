"""The reference detector on real phone photos of a foot on an A4 sheet, against corners marked by hand.

The photos (``../shared/real/a4/photos``, licences in its README) are for evaluation only; the marked corners
(``tests/data/real_a4_corners.json``) are the ground truth. The bounds are what the detector achieves (issue 19,
docs/reference.md), with a little room: a change that loses a sheet or moves a corner fails here.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from footmesh.eval.real_reference import (
    matched_corner_errors,
    read_corners,
    score_cropped,
    score_set,
    score_turned,
    sheet_centre_distance_mm,
)

ROOT = Path(__file__).resolve().parents[2]
PHOTOS = ROOT / ".." / "shared" / "real" / "a4" / "photos"
CORNERS = ROOT / "tests" / "data" / "real_a4_corners.json"


def test_the_ground_truth_names_every_photo_of_the_set():
    marked = read_corners(CORNERS)
    assert PHOTOS.is_dir(), f"{PHOTOS} is missing: the real photos live beside the project (../shared)"
    assert sorted(marked) == sorted(p.name for p in PHOTOS.glob("*.jpg"))
    for corners in marked.values():
        assert corners.shape == (4, 2) and np.isfinite(corners).all()


def test_corner_errors_are_matched_over_the_detectors_start_and_direction():
    marked = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 7.0], [0.0, 7.0]])
    found = np.roll(marked[::-1], 1, axis=0) + [0.5, 0.0]
    assert np.allclose(matched_corner_errors(found, marked), 0.5)


def test_thesheet_centre_distance_mm_of_a_sheet_seen_square_on():
    """An A4 sheet 500 mm straight below the camera: its corners give that distance, whichever corner starts."""
    K = np.array([[800.0, 0, 320], [0, 800.0, 240], [0, 0, 1]])
    half = np.array([[-148.5, -105.0], [148.5, -105.0], [148.5, 105.0], [-148.5, 105.0]])
    corners = half * 800.0 / 500.0 + [320.0, 240.0]
    for start in range(4):
        assert sheet_centre_distance_mm(np.roll(corners, start, axis=0), K) == pytest.approx(500.0, rel=1e-6)


@pytest.mark.slow
def test_every_real_sheet_is_found_with_its_corners_and_scale():
    scores = score_set(PHOTOS, CORNERS)
    assert len(scores) == 7
    for score in scores:
        assert score.found, f"{score.photo}: no sheet ({score.rejected})"
        errors = np.array(score.corner_errors_px)
        # px at 1600 on the longer side; the search runs at 640 (1 px there is 2.5 here)
        assert np.median(errors) <= 6.0 and errors.max() <= 14.0, f"{score.photo}: corners off by {errors}"
        assert abs(score.centre_distance_error) <= 0.006, f"{score.photo}: scale {score.centre_distance_error:+.2%}"
        # the detector's own uncertainty covers its error
        assert abs(score.centre_distance_error) <= 3.0 * score.scale_rel_sd
    assert np.median([np.max(s.corner_errors_px) for s in scores]) <= 6.0


def test_a_real_sheet_turned_sideways_is_found_as_upright(tmp_path):
    """The photo whose sheet corner the feet's mask once moved 23 px when turned 90 deg (docs/reference.md): the
    search must not care which way up the phone was held."""
    name = "arshoe_barefeet_1.jpg"
    marked = read_corners(CORNERS)[name]
    upright = score_turned(PHOTOS / name, marked, 0, tmp_path)
    turned = score_turned(PHOTOS / name, marked, 1, tmp_path)
    assert upright.found and turned.found
    assert max(turned.corner_errors_px) <= 14.0
    # the detector's own uncertainty covers its error, turned as upright
    for score in (upright, turned):
        assert abs(score.centre_distance_error) <= 3.0 * score.scale_rel_sd


@pytest.mark.parametrize(
    ("name", "max_corner_px"),
    [
        # the end of the sheet beyond the heel leaves the picture
        ("arshoe_barefeet_2.jpg", 22.0),
        # the foot fills the picture and the networks' mask covers little more than its toes, so the instep and the
        # toes' tips show beside it as pieces (one object with the mask, not blobs of a pattern), and the paper
        # reads 0.67 to 0.93 along the three sides in view (a side's edge is read again with its own paper colour
        # where the sides' median finds too little of it); both refused it before
        ("arshoe_barefeet_3.jpg", 40.0),
    ],
)
def test_a_real_sheet_cut_by_the_photos_edge_is_placed_from_its_other_sides(tmp_path, name, max_corner_px):
    """A real photo cropped at the top, 25 % into its sheet (the focal length the whole sheet gave, the principal
    point kept): the far corners are placed from the three sides in view within ``max_corner_px`` (of 1600; they
    are extrapolated), and the scale is within 3 of its own SD."""
    score = score_cropped(PHOTOS / name, read_corners(CORNERS)[name], "top", 0.25, tmp_path)
    assert score.found, score.rejected
    assert max(score.corner_errors_px) <= max_corner_px, score.corner_errors_px
    assert abs(score.centre_distance_error) <= 3.0 * score.scale_rel_sd


@pytest.mark.parametrize(("name", "edge"), [("arshoe_barefeet_4.jpg", "left"), ("wildoctopus_barefeet1.jpg", "left")])
def test_a_real_sheet_with_one_corner_beyond_the_photos_edge_is_placed_where_its_sides_meet(tmp_path, name, edge):
    """A real photo cropped so that its edge cuts off one corner of the sheet (a quarter of the way from that corner
    to the next along the edge): that corner is placed where the two sides running to it meet, within 12 px (of
    1600: extrapolated along real, slightly bowed sides), the others where they were marked, and the scale is
    within 3 of its own SD. Both were refused before ("a corner lies on or beyond the edge of the photo")."""
    score = score_cropped(PHOTOS / name, read_corners(CORNERS)[name], edge, 0.25, tmp_path, corners_cut=1)
    assert score.found, score.rejected
    assert max(score.corner_errors_px) <= 12.0, score.corner_errors_px
    assert sorted(score.corner_errors_px)[2] <= 6.0, score.corner_errors_px
    assert abs(score.centre_distance_error) <= 3.0 * score.scale_rel_sd


def test_a_sheet_barely_cut_is_not_rebuilt_from_the_foots_outline(tmp_path):
    """The photo's edge just inside the sheet's near corners, the foot standing on it: the search once took the
    sheet's two far sides, the foot's outline and the paper's shading for a whole sheet completed across a hidden
    corner (a foot of 316 mm against 221 uncropped). Whatever it takes must be the sheet."""
    name = "arshoe_barefeet_1.jpg"
    score = score_cropped(PHOTOS / name, read_corners(CORNERS)[name], "bottom", 0.01, tmp_path)
    if score.found:
        assert max(score.corner_errors_px) <= 22.0, score.corner_errors_px
