"""``footmesh.report``: result files written atomically, and never with a NaN in them."""

from __future__ import annotations

import json

import pytest

from footmesh.errors import InternalError
from footmesh.report import write_json


def test_json_with_a_nan_is_an_internal_error_naming_the_key(tmp_path):
    """A NaN in a result is the program's fault: InternalError (reported as internal), not ValueError (reported
    as bad input), naming where it is; nothing is written."""
    path = tmp_path / "result.json"
    with pytest.raises(InternalError, match=r"fit\.quality\.contour_within_2px"):
        write_json(path, {"fit": {"quality": {"contour_within_2px": float("nan")}}, "ok": [1.0]})
    assert not path.exists()
    write_json(path, {"fit": {"quality": {"contour_within_2px": None}}, "list": [1.5, {"x": 2}]})
    assert json.loads(path.read_text())["list"][1]["x"] == 2
