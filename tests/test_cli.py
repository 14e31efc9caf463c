"""The command line: ``main(argv) -> exit code``; real runs, and one clear line for bad input."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from footmesh.cli import main


def test_demo_writes_meshes_json_and_picture(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--model", "--out", str(out), "--seed", "3", "--side", "right"]) == 0
    result = json.loads((out / "result.json").read_text())
    assert result["side"] == "right"
    measured = {k: v["value_mm"] for k, v in result["measurements"].items()}
    for name, expected in result["expected_measurements_mm"].items():
        assert measured[name] == pytest.approx(expected, abs=0.5), name
    assert 200 < measured["stick_length"] < 320
    assert result["sizes"]["eu"]["label"].startswith("EU ")
    posed = trimesh.load(out / "posed.obj", process=False)
    canonical = trimesh.load(out / "canonical.obj", process=False)
    assert posed.is_watertight and canonical.is_watertight
    assert posed.volume > 0 and canonical.volume > 0  # right foot re-wound: normals still outwards
    assert np.asarray(result["joints3d_mm"]).shape == (18, 3)
    assert (out / "foot.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "stick_length" in capsys.readouterr().out
    assert not list(out.glob(".*"))  # no temporary files left behind


def test_missing_find_folder_is_one_clear_line(tmp_path, capsys):
    code = main(["model", "build-from-find", "--find", str(tmp_path / "nowhere"), "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err
    assert code == 2
    assert "nowhere" in err and "Traceback" not in err
    assert not (tmp_path / "m.npz").exists()


def test_unknown_command_exits_non_zero():
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code != 0


def test_eval_real_on_a_folder_that_is_no_set_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["eval", "real", "--set", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert "no labels.json" in err and len(err.splitlines()) == 1


@pytest.mark.parametrize(
    "failure",
    [TypeError("'NoneType' object is not subscriptable"), np.linalg.LinAlgError("SVD did not converge")],
)
def test_an_internal_failure_is_one_line_exit_1_and_a_log_file(monkeypatch, capsys, failure):
    def broken(args):
        raise failure

    monkeypatch.setattr("footmesh.batch.measure_batch", lambda *a, **k: broken(None))
    assert main(["measure", "photo.jpg"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("footmesh: internal error (a fault of footmesh, not of your input)")
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1
    log = Path(err.rsplit("details in ", 1)[1].strip())
    assert type(failure).__name__ in log.read_text() and "Traceback" in log.read_text()
    log.unlink()


def test_a_bad_input_is_refused_before_the_pipeline_loads(tmp_path):
    """A corrupt photo is refused from its bytes alone: torch and the networks are not imported for it (they take
    seconds; issue 23 row 17)."""
    import subprocess
    import sys

    bad = tmp_path / "photo.jpg"
    bad.write_bytes(b"not a photo at all")
    code = (
        "import sys\n"
        "from footmesh.cli import main\n"
        f"rc = main(['measure', {str(bad)!r}, '--out', {str(tmp_path / 'out')!r}])\n"
        "print('RC', rc, 'TORCH', 'torch' in sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert "RC 2 TORCH False" in done.stdout, done.stdout + done.stderr
    assert done.stderr.count(str(bad)) == 1 and "not an image" in done.stderr
