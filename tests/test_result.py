"""The typed result and its JSON Schema (footmesh.result): what result.json holds, and what the web publishes."""

from __future__ import annotations

import jsonschema
import pytest

from footmesh.result import RESULT_FORMAT, FootEntry, MeasureResult, json_schema


def _result(**changes) -> MeasureResult:
    values = dict(
        input_sha256={"image": "ab"},
        image={"width": 640, "height": 480},
        intrinsics={"fx": 500.0},
        depth=None,
        input="rgb",
        side="left",
        side_losses={"left": 1.0},
        side_source="fit",
        scale_source="a4",
        scaled=True,
        reference={"kind": "a4"},
        measurements={"stick_length": {"value_mm": 250.0, "uncertainty_mm": 3.0}},
        ratios={"ball_width/stick_length": 0.4},
        sizes={"eu": None},
        joints2d_px=[[1.0, 2.0]] * 18,
        joint_confidence=[1.0] * 18,
        joints3d_mm=None,
        angles={"mtp1": 0.1},
        shape=[0.0],
        fit={"loss": 1.0},
        timings_s={"fit_s": 1.0},
        messages=[],
        units="mm",
        files={"result_json": "result.json"},
        version="1.0",
    )
    return MeasureResult(**{**values, **changes})


def test_the_json_keeps_the_contracts_order_and_leaves_feet_out_for_one_foot():
    out = _result().to_dict()
    assert list(out)[:3] == ["format", "version", "input_sha256"] and out["format"] == RESULT_FORMAT
    assert "feet" not in out and list(out)[-2:] == ["request", "seconds"]
    jsonschema.validate(out, json_schema())


def test_two_feet_list_both_and_a_refused_one_says_only_why():
    feet = (
        FootEntry(index=0, measured=True, primary=True, side="left", scaled=True, files={"mask_png": "mask.png"}),
        FootEntry(index=1, measured=False, error="cut off"),
    )
    out = _result(feet=feet).with_message("two feet in view").to_dict()
    assert out["feet"][1] == {"index": 1, "measured": False, "error": "cut off"}
    assert out["feet"][0]["side"] == "left" and "error" not in out["feet"][0]
    assert out["messages"] == ["two feet in view"]
    jsonschema.validate(out, json_schema())


def test_the_schema_catches_a_wrong_type_or_a_missing_key():
    schema = json_schema()
    with pytest.raises(jsonschema.ValidationError, match="'yes' is not of type 'boolean'"):
        jsonschema.validate({**_result().to_dict(), "scaled": "yes"}, schema)
    missing = _result().to_dict()
    del missing["measurements"]
    with pytest.raises(jsonschema.ValidationError, match="'measurements' is a required property"):
        jsonschema.validate(missing, schema)
    assert all("description" in p for p in schema["properties"].values())
