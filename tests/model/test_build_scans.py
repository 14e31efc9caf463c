"""Scan loading/validation, marker files, and building a model from a folder of scans (resumable)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from _scan_corpus import coarse_model, random_shape

from footmesh.cli import main
from footmesh.model import build_scans as bs
from footmesh.model import scans
from footmesh.model.assets import load_asset, save_asset
from footmesh.model.vertex_ids import LANDMARKS


@pytest.fixture(scope="module")
def model():
    return coarse_model()


@pytest.fixture()
def foot_mesh(model):
    return trimesh.Trimesh(model.mean_vertices, model.faces, process=False)


# --- scans ------------------------------------------------------------------------------------------------


def test_load_scan_reads_ply_obj_stl(tmp_path, foot_mesh):
    for suffix in (".ply", ".obj", ".stl"):
        path = tmp_path / f"foot{suffix}"
        foot_mesh.export(path)
        mesh, report = scans.load_scan(path)
        assert len(mesh.faces) == len(foot_mesh.faces)
        assert report.boundary_edges == 0
        assert 200 < report.diagonal_mm < 500


def test_scan_in_metres_is_reported_not_rescaled(tmp_path, foot_mesh):
    path = tmp_path / "metres.ply"
    trimesh.Trimesh(foot_mesh.vertices / 1000.0, foot_mesh.faces).export(path)
    with pytest.raises(scans.ScanError, match="--unit m"):
        scans.load_scan(path)
    mesh, _ = scans.load_scan(path, unit="m")  # told: converted
    np.testing.assert_allclose(mesh.bounds, foot_mesh.bounds, atol=1e-3)


@pytest.mark.parametrize(
    ("content", "suffix", "match"),
    [
        ("this is not a mesh\n", ".obj", "empty"),
        ("", ".ply", "cannot read|empty|not a triangle"),
        ("v 0 0 0\nv 1 0 0\n", ".obj", "empty|not a triangle"),
        ("solid x\nendsolid x\n", ".stl", "cannot read|empty"),
    ],
)
def test_bad_files_give_clear_errors(tmp_path, content, suffix, match):
    path = tmp_path / f"bad{suffix}"
    path.write_text(content)
    with pytest.raises(scans.ScanError, match=match):
        scans.load_scan(path)


def test_missing_and_unsupported_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        scans.load_scan(tmp_path / "nope.ply")
    (tmp_path / "foot.xyz").write_text("1 2 3\n")
    with pytest.raises(scans.ScanError, match="unsupported"):
        scans.load_scan(tmp_path / "foot.xyz")


def test_non_manifold_scan_is_rejected(foot_mesh):
    # a second sheet glued along every edge: each edge now has four triangles
    v = foot_mesh.vertices
    f = np.concatenate([foot_mesh.faces, foot_mesh.faces[:, ::-1]])
    with pytest.raises(scans.ScanError, match="non-manifold"):
        scans.check_scan(trimesh.Trimesh(v, f, process=False))


def test_inward_scan_is_flipped_and_loose_bits_dropped(foot_mesh):
    v = foot_mesh.vertices
    speck = trimesh.creation.icosphere(subdivisions=1, radius=1.0).apply_translation(v.max(axis=0) + 50.0)
    inward = trimesh.Trimesh(v, foot_mesh.faces[:, ::-1], process=False)
    mesh, report = scans.check_scan(trimesh.util.concatenate([inward, speck]))
    assert mesh.volume > 0
    assert len(mesh.faces) == len(foot_mesh.faces)
    assert any("flipped" in w for w in report.warnings)
    assert any("loose" in w for w in report.warnings)


def test_markers_round_trip_and_errors(tmp_path):
    path = tmp_path / "m.json"
    scans.save_markers(path, {"heel": np.array([1.0, 2.0, 3.0]), "toe1_tip": np.array([250.0, 0.0, 10.0])})
    m = scans.load_markers(path)
    np.testing.assert_allclose(m["heel"], [1.0, 2.0, 3.0])
    cm = scans.parse_markers({"units": "cm", "markers": {"heel": [1, 2, 3]}})
    np.testing.assert_allclose(cm["heel"], [10.0, 20.0, 30.0])
    bad = [
        ({"markers": {"knee": [0, 0, 0]}}, "unknown marker"),
        ({"markers": {"heel": [0, 0]}}, "three finite numbers"),
        ({"markers": {"heel": [0, "a", 0]}}, "three finite numbers"),
        ({"units": "inch", "markers": {"heel": [0, 0, 0]}}, "unknown units"),
        ([1, 2, 3], "expected an object"),
    ]
    for data, match in bad:
        with pytest.raises(scans.ScanError, match=match):
            scans.parse_markers(data)
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(scans.ScanError, match="not valid JSON"):
        scans.load_markers(tmp_path / "broken.json")


def test_markers_far_from_the_scan_are_caught(foot_mesh):
    far = {"heel": foot_mesh.vertices[0] + [0.0, 0.0, 500.0]}
    with pytest.raises(scans.ScanError, match="same frame and units"):
        scans.check_markers_on_scan(far, foot_mesh)


def test_template_markers_are_known_names_on_the_coarse_template(model):
    ids = scans.template_markers(model.num_vertices)
    assert set(ids) <= set(scans.MARKER_NAMES)
    assert len(ids) >= 12
    with pytest.raises(ValueError, match="vertices"):
        scans.template_markers(100)


def test_footmesh_landmarks_on_both_templates_and_the_markers_agree(model):
    """One definition: vertex_ids.LANDMARKS on 4,002 vertices, moved to the nearest coarse vertex on 1,002; the
    template markers of the same names are those coarse vertices."""
    fine = load_asset()
    assert scans.template_landmarks(fine.num_vertices) == LANDMARKS
    coarse = scans.template_landmarks(model.num_vertices, fine.mean_vertices)
    assert set(coarse) == set(LANDMARKS)
    v = fine.mean_vertices
    for name, i in coarse.items():
        assert i < model.num_vertices
        assert np.linalg.norm(v[i] - v[LANDMARKS[name]]) < 10.0, name
    markers = scans.template_markers(model.num_vertices)
    shared = set(markers) & set(LANDMARKS)
    assert len(shared) == 11
    assert {k: markers[k] for k in shared} == {k: coarse[k] for k in shared}
    with pytest.raises(ValueError, match="4,002"):
        scans.template_landmarks(500)


# --- building a model from a folder ------------------------------------------------------------------------


def _write_corpus(folder, model, n, with_markers=True):
    folder.mkdir()
    ids = scans.template_markers(model.num_vertices)
    for i in range(n):
        s = scans.synthetic_scan(random_shape(model, 300 + i), model.faces, ids, seed=i, target_vertices=2000)
        s.mesh.export(folder / f"foot{i:02d}.ply")
        if with_markers:
            scans.save_markers(folder / f"foot{i:02d}.markers.json", s.markers)


def test_build_model_from_scans_is_resumable_and_skips_bad_scans(tmp_path, model):
    folder = tmp_path / "scans"
    _write_corpus(folder, model, 3)
    (folder / "broken.stl").write_text("solid x\nendsolid x\n")
    out = tmp_path / "model.npz"
    summary = bs.build_model(folder, out, template=model, progress=False)
    assert summary.succeeded == 3
    assert [o.name for o in summary.outcomes if not o.ok] == ["broken.stl"]
    assert "1 failed" in summary.text()
    asset = load_asset(out)
    assert asset.mean_vertices.shape == (model.num_vertices, 3)
    assert asset.num_components >= 1
    np.testing.assert_array_equal(asset.faces, model.faces)
    assert asset.landmarks() == scans.template_landmarks(model.num_vertices)
    assert set(asset.landmarks()) == set(LANDMARKS)
    # rerun: every good scan comes from the cache
    again = bs.build_model(folder, out, template=model, progress=False)
    assert [o.cached for o in again.outcomes if o.ok] == [True, True, True]
    # a changed scan is redone
    s = scans.synthetic_scan(random_shape(model, 999), model.faces, {}, seed=9, target_vertices=2000)
    s.mesh.export(folder / "foot00.ply")
    (folder / "foot00.markers.json").unlink()
    third = bs.build_model(folder, out, template=model, progress=False)
    assert [o.cached for o in third.outcomes if o.ok] == [False, True, True]


def test_cli_register_and_build(tmp_path, model, capsys):
    template = tmp_path / "coarse.npz"
    save_asset(model, template)
    folder = tmp_path / "scans"
    _write_corpus(folder, model, 2, with_markers=False)
    out = tmp_path / "reg.ply"
    code = main(["model", "register", str(folder / "foot00.ply"), "--out", str(out), "--template", str(template)])
    assert code == 0
    assert len(trimesh.load(out, process=False).vertices) == model.num_vertices
    code = main(
        ["model", "build", "--scans", str(folder), "--out", str(tmp_path / "m.npz"), "--template", str(template)]
        + ["--no-progress"]
    )
    assert code == 0
    assert "2 of 2 scans registered" in capsys.readouterr().out
    # nothing usable: non-zero exit and a clear message
    empty = tmp_path / "bad"
    empty.mkdir()
    (empty / "a.stl").write_text("solid x\nendsolid x\n")
    code = main(
        ["model", "build", "--scans", str(empty), "--out", str(tmp_path / "x.npz"), "--template", str(template)]
    )
    assert code == 2
    assert not (tmp_path / "x.npz").exists()
    metres = tmp_path / "m.ply"
    trimesh.Trimesh(model.mean_vertices / 1000.0, model.faces).export(metres)
    assert main(["model", "register", str(metres), "--out", str(out), "--template", str(template)]) == 2
    assert "--unit m" in capsys.readouterr().err


def test_marker_file_lookup(tmp_path):
    scan = tmp_path / "a.ply"
    assert bs.markers_path(scan, None) is None
    (tmp_path / "a.json").write_text(json.dumps({"markers": {"heel": [0, 0, 0]}}))
    assert bs.markers_path(scan, None) == tmp_path / "a.json"
    (tmp_path / "a.markers.json").write_text(json.dumps({"markers": {"heel": [0, 0, 0]}}))
    assert bs.markers_path(scan, None) == tmp_path / "a.markers.json"


def test_pca_asset_reproduces_the_reference_components_from_its_own_shapes():
    """pca_asset stands every shape in the foot frame, as the FIND-built model was made (issue 3's comparison).

    A Procrustes alignment of each shape (the first version) gave principal angles of 29-73 degrees for the first
    5 components on these very shapes; no registration here, so this isolates the frame handling.
    """
    from scipy.linalg import subspace_angles
    from scipy.spatial.transform import Rotation

    from footmesh.model.template import to_foot_frame

    ref = load_asset()  # shipped: a missing asset fails the test
    rng = np.random.default_rng(7)
    n = 50
    coef = rng.standard_normal((n, ref.num_components)) * ref.component_sd
    shapes = ref.mean_vertices + np.tensordot(coef, ref.components, axes=1)
    rots = Rotation.random(n, random_state=1).as_matrix()
    posed = np.einsum("nij,nvj->nvi", rots, shapes) + rng.normal(0.0, 100.0, (n, 1, 3))  # any pose in
    built = bs.pca_asset(posed, ref, 1.0, "test")
    k = 5
    a = ref.components[:k].reshape(k, -1).astype(np.float64).T
    b = built.components[:k].reshape(k, -1).astype(np.float64).T
    angles = np.degrees(subspace_angles(a, b))
    assert angles.max() < 10.0, angles  # measured 0.1-6.0: 50 samples (components 2 and 3 have close variances)
    assert np.degrees(subspace_angles(a[:, :2], b[:, :2])).max() < 5.0  # measured 1.0, 3.2
    # the built mean is in the foot frame, and a shape of the built model still stands there
    np.testing.assert_allclose(to_foot_frame(built.mean_vertices), built.mean_vertices, atol=1e-3)
    one = built.mean_vertices + built.component_sd[0] * built.components[0]
    assert np.abs(to_foot_frame(one) - one).max() < 2.0
