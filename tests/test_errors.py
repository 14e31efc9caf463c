"""Whose fault an error is (footmesh.errors), as the CLI and the batch runner report it."""

from __future__ import annotations

import json

import numpy as np
import pytest

from footmesh.cli import main
from footmesh.errors import InputError, InternalError, Refusal, is_users_fault
from footmesh.examples import examples


def test_only_input_errors_and_refusals_are_the_users():
    assert is_users_fault(InputError("depth map d.png is 8-bit"))
    assert is_users_fault(Refusal("no foot found", "photograph one foot"))
    for ours in (ValueError("broadcast"), np.linalg.LinAlgError("SVD"), IndexError(3), InternalError("x")):
        assert not is_users_fault(ours)
    assert isinstance(Refusal("x"), ValueError) and isinstance(InputError("x"), ValueError)  # old callers


@pytest.fixture
def broken_pipeline(monkeypatch):
    """The pipeline fails on the photo named ``broken.png`` as a stage breaking its contract would."""
    import footmesh.pipeline as pipeline

    measure = pipeline.measure_loaded_photo

    def failing(photo, out_dir, request, config=None, started=None):
        if photo.info.path.name == "broken.png":
            raise ValueError("operands could not be broadcast together with shapes (3,) (4,)")
        return measure(photo, out_dir, request, config, started)

    monkeypatch.setattr(pipeline, "measure_loaded_photo", failing)


@pytest.mark.slow
def test_an_internal_failure_is_reported_as_ours_and_the_batch_goes_on(tmp_path, capsys, broken_pipeline):
    ex = next(e for e in examples() if e.name == "a4_left")
    broken = tmp_path / "broken.png"
    broken.write_bytes(ex.image.read_bytes())
    out = tmp_path / "out"
    assert main(["measure", str(broken), str(ex.image), "--out", str(out), "--json"]) == 1
    err = capsys.readouterr()
    assert "internal error (a fault of footmesh, not of your input): ValueError: operands" in err.err
    log = err.err.split("details in ")[1].split()[0]
    assert "Traceback" in open(log).read()
    results = json.loads(err.out)
    assert "internal error" in results[0]["error"] and results[1]["scale_source"] == "a4"  # the other was measured


def test_a_refusal_and_an_input_error_exit_2_with_one_line(tmp_path, capsys):
    blank = tmp_path / "floor.png"
    import cv2

    cv2.imwrite(str(blank), np.full((240, 320, 3), 128, np.uint8))
    assert main(["measure", str(blank), "--out", str(tmp_path / "a")]) == 2
    assert "no foot found in the photo; photograph one bare foot" in capsys.readouterr().err
    assert main(["measure", str(blank), "--depth", str(blank), "--out", str(tmp_path / "b")]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("footmesh: error: depth map") and "\n" not in line
