"""``footmesh eval measure``: the tables from per-photo records, and one photo end to end."""

from __future__ import annotations

import math

import pytest

from footmesh.eval.measure import ModeResult, Record, _finite, evaluate_mode, format_tables


def _result() -> ModeResult:
    res = ModeResult("rgbd")
    res.records = [
        Record(0, None, True, length_err=2.0, width_err=-1.0, length_u=3.0, width_u=0.5, ratio_err=0.01, seconds=1.0),
        Record(1, None, True, length_err=-4.0, width_err=2.0, length_u=1.0, width_u=3.0, ratio_err=-0.01, seconds=3.0),
        Record(2, None, False, error="no foot found in the photo; ..."),
    ]
    return res


def test_summary_counts_errors_coverage_and_refusals():
    s = _result().summary()
    assert s["photos"] == 3 and s["measured"] == 2
    assert s["length_mae_mm"] == pytest.approx(3.0)
    assert s["width_mae_mm"] == pytest.approx(1.5)
    assert s["length_within_1u"] == pytest.approx(0.5)  # |2| <= 3 yes, |-4| <= 1 no
    assert s["within_half_size"] == pytest.approx(1.0)
    assert s["failed"] == {2: "no foot found in the photo; ..."}


def test_tables_show_ours_beside_the_thesis_and_the_baseline():
    text = format_tables({"rgbd": _result()})
    assert "13.0 (9.0)" in text  # thesis Table 4.7, ISM with RGB-D, length
    assert "14.2" in text and "no foot found" in text


def test_json_gets_null_for_nan():
    assert _finite({"a": [math.nan, 1.0], "b": {"c": math.inf}}) == {"a": [None, 1.0], "b": {"c": None}}


@pytest.mark.slow
def test_one_rgbd_photo_end_to_end():
    res = evaluate_mode("rgbd", n=1, size=320, progress=False)
    assert len(res.records) == 1
    rec = res.records[0]
    if rec.ok:
        assert rec.scale_source == "depth"
        assert abs(rec.length_err) < 30.0
    else:
        assert rec.error  # refused with a message, never a crash


def test_a_fault_of_footmesh_is_counted_apart_from_the_refusals(monkeypatch):
    """A refusal is the photo's; any other error is footmesh's own (the CLI calls it internal): the eval must not
    hide it among the refusals."""
    from footmesh.errors import Refusal
    from footmesh.eval.measure import INTERNAL

    outcomes = iter([Refusal("no foot found in the photo", "retake it"), ValueError("cues: 7 foot pixels")])

    def failing(*args, **kwargs):
        raise next(outcomes)

    monkeypatch.setattr("footmesh.pipeline.measure_photo", failing)
    res = evaluate_mode("rgbd", n=2, size=128, progress=False)
    assert [r.error.startswith(INTERNAL) for r in res.records] == [False, True]
    text = format_tables({"rgbd": res})
    assert "rgbd: 1 photo(s) refused: no foot found in the photo (1)" in text
    assert "rgbd: 1 internal errors: photo 1: internal error ValueError: cues: 7 foot pixels" in text
