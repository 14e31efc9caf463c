"""The FIND-derived model: packaged asset, foot frame, sizing, landmarks, reproducible builds, CLI errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from footmesh.measure import ball_width_mm, stick_length_mm
from footmesh.model import vertex_ids
from footmesh.model.template import NUM_FACES, NUM_VERTICES, to_foot_frame

FIND_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "find"


def _needs_find():
    if not FIND_DIR.is_dir():
        pytest.skip(f"FIND not found at {FIND_DIR}")
    pytest.importorskip("onnxruntime")


@pytest.fixture(scope="module")
def asset():
    from footmesh.model.assets import load_asset

    return load_asset()


def _random_rigid(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    q = rng.standard_normal(4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    rot = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    return rot, rng.uniform(-500, 500, 3)


def test_packaged_asset(asset):
    import trimesh

    assert asset.num_vertices == NUM_VERTICES and len(asset.faces) == NUM_FACES
    assert asset.landmarks() == vertex_ids.LANDMARKS
    mesh = trimesh.Trimesh(asset.mean_vertices, asset.faces, process=False)
    assert mesh.is_watertight and mesh.volume > 0  # counter-clockwise seen from outside
    length = stick_length_mm(asset.mean_vertices)
    assert 235 < length < 280
    assert 0.35 < ball_width_mm(asset.mean_vertices) / length < 0.42
    assert "Boyne" in asset.provenance and "MIT" in asset.provenance
    np.testing.assert_allclose(asset.joint_regressor.sum(axis=1), 1, atol=1e-5)
    np.testing.assert_allclose(asset.skin_weights.sum(axis=1), 1, atol=1e-5)
    flat = asset.components.reshape(asset.num_components, -1).astype(np.float64)
    np.testing.assert_allclose(flat @ flat.T, np.eye(asset.num_components), atol=1e-4)


def _check_frame(v: np.ndarray) -> None:
    lm = vertex_ids.LANDMARKS
    assert abs(v[:, 2].min()) < 0.5  # sole on the floor
    low = v[:, 2] <= 0.25 * np.ptp(v[:, 0])
    assert v[low, 0].min() == pytest.approx(0.0, abs=1e-9)  # heel at x = 0
    assert v[lm["heel"], 1] == pytest.approx(0.0, abs=1e-9)
    assert v[lm["toe2_tip"], 1] == pytest.approx(0.0, abs=1e-6)  # the foot axis is +x
    assert v[lm["toe2_tip"], 0] > 200
    assert v[lm["malleolus_lateral"], 2] > 40 and v[lm["toe1_tip"], 1] < v[lm["toe5_tip"], 1]  # left foot


def test_to_foot_frame_stands_the_foot_and_ignores_rigid_motion(asset):
    rng = np.random.default_rng(0)
    sample = asset.mean_vertices + np.einsum("k,kvc->vc", 2 * asset.component_sd, asset.components)
    for shape in (asset.mean_vertices.astype(np.float64), sample.astype(np.float64)):
        ref = to_foot_frame(shape)
        _check_frame(ref)
        for _ in range(3):
            rot, t = _random_rigid(rng)
            np.testing.assert_allclose(to_foot_frame(shape @ rot.T + t), ref, atol=1e-6)


def test_to_foot_frame_rejects_bad_input():
    with pytest.raises(ValueError):
        to_foot_frame(np.zeros((10, 2)))
    with pytest.raises(ValueError):
        to_foot_frame(np.zeros((10, 3)))  # too few vertices for the landmarks


def test_scale_to_size_hits_targets(asset):
    from footmesh.model.build_find import scale_to_size

    v = scale_to_size(asset.mean_vertices, 250.0, 97.0)
    assert stick_length_mm(v) == pytest.approx(250.0, abs=0.2)
    assert ball_width_mm(v) == pytest.approx(97.0, abs=0.2)
    np.testing.assert_allclose(to_foot_frame(v), v, atol=1e-6)  # scaling keeps the frame


def test_sample_sizes_follow_ansur():
    from footmesh.model.build_find import MEN, WOMEN, sample_sizes

    s = sample_sizes(np.random.default_rng(0), 20000)
    assert s.male.mean() == pytest.approx(0.5, abs=0.02)
    assert s.length[s.male].mean() == pytest.approx(MEN.length_mean, abs=0.5)
    assert s.length[~s.male].std() == pytest.approx(WOMEN.length_sd, abs=0.5)
    assert s.width[s.male].mean() == pytest.approx(101.8, abs=0.5)  # ANSUR men 101.9 +- 5.2
    assert s.width[~s.male].mean() == pytest.approx(92.6, abs=0.5)  # ANSUR women 92.7 +- 4.8


def test_landmark_ids_rederive_from_find():
    _needs_find()
    if not (FIND_DIR / "hires" / "keypoints.csv").is_file():
        pytest.skip("FOCUS keypoints not found")
    from footmesh.model.build_find import derive_landmarks

    assert derive_landmarks(FIND_DIR) == vertex_ids.LANDMARKS


def test_subdivided_template_is_watertight_and_outward():
    _needs_find()
    import trimesh

    from footmesh.model.template import subdivided_template

    v, f = subdivided_template(FIND_DIR)
    mesh = trimesh.Trimesh(v, f, process=False)
    assert v.shape == (NUM_VERTICES, 3) and mesh.is_watertight and mesh.volume > 0


def test_build_is_bit_for_bit_reproducible(tmp_path):
    _needs_find()
    from footmesh.model.assets import load_asset
    from footmesh.model.build_find import build_from_find

    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    build_from_find(FIND_DIR, a, n_samples=20, seed=3, n_test=0)
    build_from_find(FIND_DIR, b, n_samples=20, seed=3, n_test=0)
    assert a.read_bytes() == b.read_bytes()
    small = load_asset(a)
    assert small.num_vertices == NUM_VERTICES and "n_samples=20, seed=3" in small.provenance


def test_skin_colours():
    from footmesh.model.skin import load_skin_colours, sample_skin_colours

    model = load_skin_colours()
    assert model.mean.shape == (NUM_VERTICES, 3)
    c = sample_skin_colours(np.random.default_rng(0), 4, model)
    assert c.shape == (4, NUM_VERTICES, 3) and c.min() >= 0 and c.max() <= 1
    np.testing.assert_array_equal(c, sample_skin_colours(np.random.default_rng(0), 4, model))


def test_cli_missing_find_folder(tmp_path, capsys):
    from footmesh.cli import main

    missing = tmp_path / "nope"
    assert main(["model", "build-from-find", "--find", str(missing), "--out", str(tmp_path / "m.npz")]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and err.count("\n") == 1


def test_cli_missing_find_file(tmp_path, capsys):
    from footmesh.cli import main

    (tmp_path / "template.obj").write_text("")
    assert main(["model", "build-from-find", "--find", str(tmp_path), "--out", str(tmp_path / "m.npz")]) == 2
    assert "model.onnx" in capsys.readouterr().err
