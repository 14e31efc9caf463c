"""Each refusal on its own: evidence that must be refused is, evidence that must not be is not (footmesh.refusals)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from footmesh import refusals
from footmesh.config import MeasureConfig
from footmesh.errors import Refusal
from footmesh.fit import FitQuality

CONFIG = MeasureConfig()
GOOD = FitQuality(contour_within_2px=0.95, vertices_outside_2px=0.01, joint_error_px=2.0, foot_shown=0.97)


def _foot_joints() -> np.ndarray:
    """(18, 2) joints of a foot lying left (toes, x = 20) to right (heel, x = 78) across a 100 x 100 photo."""
    joints = np.full((18, 2), 50.0)
    joints[[3, 6, 9, 12, 15], 0] = 20.0  # toe tips
    joints[[3, 6, 9, 12, 15], 1] = [36.0, 42.0, 47.0, 52.0, 56.0]
    joints[17] = [78.0, 45.0]  # heel
    joints[16] = [70.0, 40.0]  # ankle
    return joints


def _foot_mask() -> np.ndarray:
    mask = np.zeros((100, 100), bool)
    mask[30:60, 18:80] = True
    return mask


def test_a_foot_cut_off_by_the_edge_is_refused():
    mask, joints = _foot_mask(), _foot_joints()
    assert refusals.cut_off(mask, joints, 100, 100, CONFIG) is None  # well inside: fine
    cut, at_edge = mask.copy(), joints.copy()
    cut[30:60, 0:80] = True  # the toes run into the left edge: their tips (as the network puts them) on it
    at_edge[[3, 6, 9, 12, 15], 0] = 3.0
    refusal = refusals.cut_off(cut, at_edge, 100, 100, CONFIG)
    assert isinstance(refusal, Refusal) and "cut off" in refusal.why and "whole foot" in refusal.retake
    assert refusals.cut_off(cut, joints, 100, 100, CONFIG) is None  # silhouette far beyond the tips: not the foot
    outside = joints.copy()
    outside[17] = [-20.0, 50.0]  # heel beyond the left edge
    assert "cut off" in str(refusals.cut_off(mask, outside, 100, 100, CONFIG))


def test_the_leg_leaving_the_frame_is_normal():
    mask = _foot_mask()
    mask[40:100, 66:76] = True  # the leg, from the ankle down to the bottom edge, far from the foot's joints
    assert refusals.cut_off(mask, _foot_joints(), 100, 100, CONFIG) is None


def test_no_foot_needs_a_region_of_the_configured_share():
    photo = 1000.0 * 1000.0
    assert refusals.no_foot(CONFIG.min_foot_fraction * photo, photo, CONFIG) is None
    refusal = refusals.no_foot(0.5 * CONFIG.min_foot_fraction * photo, photo, CONFIG)
    assert "no foot found" in refusal.why and "bare foot" in refusal.retake
    assert refusals.no_foot(0.0, photo, CONFIG) is not None


def test_an_implausible_length_is_refused_only_when_scaled():
    low, high = CONFIG.plausible_length_mm
    assert refusals.implausible_length(None, CONFIG) is None  # unscaled: no length to judge
    assert refusals.implausible_length(0.5 * (low + high), CONFIG) is None
    assert "133 mm long" in str(refusals.implausible_length(133.0, CONFIG))
    assert refusals.implausible_length(high + 1, CONFIG) is not None


def test_a_reference_is_contradicted_by_an_impossible_foot_or_floor():
    low, high = CONFIG.plausible_length_mm
    assert refusals.contradicted_reference("card", 0.5 * (low + high), GOOD, CONFIG) is None
    assert "bank card would make the foot 133 mm" in refusals.contradicted_reference("card", 133.0, GOOD, CONFIG)
    missed = FitQuality(0.9, CONFIG.max_model_outside + 0.2, 2.0, 0.9)
    note = refusals.contradicted_reference("a4", 250.0, missed, CONFIG)
    assert "A4 sheet implies a floor no fitted foot stands on" in note and "ignored" in note


def test_a_reference_far_from_the_foot_is_not_the_one_put_beside_it():
    beside = refusals.contradicted_reference("a4", 250.0, GOOD, CONFIG, separation_mm=300.0)
    assert beside is None
    far = refusals.contradicted_reference("card", 250.0, GOOD, CONFIG, separation_mm=1200.0)
    assert "bank card lies 1.2 m from the foot" in far and "ignored" in far
    assert refusals.contradicted_reference("card", None, GOOD, CONFIG, separation_mm=5000.0) is None  # no scale


@pytest.mark.parametrize("kind", ["rgb", "rgbd", "depth"])
def test_end_on_limits_per_input(kind):
    limit = {"rgb": CONFIG.max_rgb_end_on, "rgbd": CONFIG.max_rgbd_end_on, "depth": CONFIG.max_depth_end_on}[kind]
    assert refusals.seen_end_on(limit - 0.01, kind, CONFIG) is None
    refusal = refusals.seen_end_on(min(limit + 0.01, 1.0), kind, CONFIG)
    assert "seen end-on" in refusal.why and refusal.retake == refusals.FROM_THE_SIDE
    assert ("far end of the foot is hidden" in refusal.why) == (kind != "rgb")


def test_a_lifted_fit_on_a_reference_floor_seen_from_above_is_the_heel_hidden():
    steep = min(CONFIG.max_rgb_end_on + 0.1, 1.0)
    from_above = 0.5 * CONFIG.max_rgb_end_on  # on that floor no foot can be seen more end-on than this
    refusal = refusals.heel_hidden(steep, from_above, "a4", CONFIG)
    assert "lying on the floor that an A4 sheet" in refusal.why and "heel" in refusal.retake
    assert refusals.heel_hidden(steep, steep, "a4", CONFIG) is None  # a floor seen low: the view may be end-on
    assert refusals.heel_hidden(from_above, from_above, "a4", CONFIG) is None  # not end-on at all
    # the composite: with the floor the heel-hidden reason wins; without it the plain end-on one
    assert "heel" in str(refusals.fitted_foot(GOOD, steep, "rgb", CONFIG, ("a4", from_above)))
    assert "plain photo" in str(refusals.fitted_foot(GOOD, steep, "rgb", CONFIG, None))


def test_a_fit_off_the_silhouette_is_refused_for_every_input():
    off = FitQuality(0.9, CONFIG.max_model_outside + 0.01, 2.0, 0.9)
    for kind in ("rgb", "rgbd", "depth"):
        assert refusals.model_outside(GOOD, CONFIG) is None
        assert "falls outside the foot" in str(refusals.fitted_foot(off, 0.0, kind, CONFIG))


def test_the_outline_is_judged_only_with_depth_and_a_hidden_foot_more_strictly_with_it():
    loose = FitQuality(CONFIG.min_depth_contour_followed - 0.05, 0.0, 2.0, 1.0)
    hidden = FitQuality(1.0, 0.0, 2.0, CONFIG.min_depth_foot_shown - 0.05)
    assert refusals.outline_not_followed(loose, "rgb", CONFIG) is None
    assert "outline" in str(refusals.outline_not_followed(loose, "rgbd", CONFIG))
    assert refusals.foot_hidden(hidden, "rgb", CONFIG) is None  # without depth the fit shrinks into what shows
    off_the_foot = FitQuality(1.0, 0.0, 2.0, CONFIG.min_rgb_foot_shown - 0.05)
    assert "hides the rest" in str(refusals.foot_hidden(off_the_foot, "rgb", CONFIG))
    assert "hides the rest" in str(refusals.foot_hidden(hidden, "depth", CONFIG))
    assert refusals.fitted_foot(GOOD, 0.0, "rgbd", CONFIG) is None


def test_a_refusal_keeps_why_and_retake_through_pickling():
    import pickle

    refusal = refusals.unmeasurable("no ball line")
    again = pickle.loads(pickle.dumps(refusal))
    assert (again.why, again.retake, str(again)) == (refusal.why, refusal.retake, str(refusal))
    assert str(refusal).startswith("the fitted foot could not be measured (no ball line); retake")
    assert math.isfinite(GOOD.joint_error_px) and "depth_median_mm" not in GOOD.to_dict()
