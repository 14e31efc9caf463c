"""``footmesh eval recon`` (``footmesh.eval.recon``): the metrics, Tables 4.4-4.6 and the command."""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
import torch

from footmesh.eval import thesis
from footmesh.eval.recon import (
    PARAMETER_GROUPS,
    _parameter_parts,
    chamfer_mm,
    evaluate,
    evaluate_pipeline,
    format_tables,
    run_eval,
    scale_aligned_joint_error,
    vertex_errors,
    view_table,
)
from footmesh.recon.decoder import DecoderConfig
from footmesh.recon.edgeconv import EdgeConvConfig, chamfer_distance
from footmesh.recon.joints import joints_from_vertices, midfoot_aligned_error
from footmesh.recon.model import ReconConfig, ReconNet
from footmesh.recon.weights import save_weights
from footmesh.synth.dataset import SynthDataset, generate
from footmesh.synth.scene import NUM_THESIS_VIEWS, SynthConfig, guided_view_config

SIZE = 64
TINY = ReconConfig.for_widths((8, 8, 16, 16), 16, image_size=SIZE, decoder=DecoderConfig(channels=(8,) * 5))


@pytest.fixture(scope="module")
def views_data(tmp_path_factory):
    """One 64 px sample per thesis viewpoint (22)."""
    folder = tmp_path_factory.mktemp("recon-views")
    generate(folder, NUM_THESIS_VIEWS, seed=7, config=SynthConfig(size=SIZE, views="thesis"), progress=False)
    return folder


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """Weights files of untrained tiny networks: {"rgb": path, "rgbd": path, "edgeconv": path, "model": path}."""
    from footmesh.recon.hierarchy import template_hierarchy

    folder = tmp_path_factory.mktemp("recon-weights")
    hierarchy = template_hierarchy()
    edge = EdgeConvConfig(in_features=16, seed_points=32, channels=(8, 8, 8), up_factors=(2, 2))
    configs = {
        "rgb": replace(TINY, input="rgb"),
        "rgbd": TINY,
        "edgeconv": replace(TINY, kind="edgeconv", loss="chamfer", edgeconv=edge),
        "model": replace(TINY, kind="model", loss="structure"),
    }
    out = {}
    for name, config in configs.items():
        torch.manual_seed(0)
        out[name] = folder / f"{name}.pt"
        save_weights(out[name], ReconNet(config, hierarchy), config, {}, hierarchy)
    return out


@pytest.fixture(scope="module")
def foot() -> tuple[torch.Tensor, torch.Tensor]:
    """(2, V, 3) meshes and their (2, 18, 3) joints, mm, placed in front of a camera."""
    from footmesh.model.layer import default_model

    model = default_model()
    shape = torch.randn(2, model.num_components, generator=torch.Generator().manual_seed(1))
    out = model(shape)
    v = out.vertices.detach() + torch.tensor([10.0, -20.0, 450.0])
    return v, joints_from_vertices(v)


def test_vertex_errors_separate_placement_size_and_shape(foot):
    true, _ = foot
    centre = true.mean(1, keepdim=True)
    pred = centre + 0.8 * (true - centre) + torch.tensor([3.0, 4.0, 0.0])  # 20 % small, 5 mm off
    e = vertex_errors(pred, true)
    expected_raw = (pred - true).norm(dim=-1).mean(1)
    assert torch.allclose(e["raw"], expected_raw)
    assert torch.allclose(e["centred"], 0.2 * (true - centre).norm(dim=-1).mean(1), rtol=1e-4)
    assert torch.allclose(e["scaled"], torch.zeros(2), atol=1e-3) and torch.allclose(e["scale"], torch.tensor(1.25))
    noisy = true + torch.randn(true.shape, generator=torch.Generator().manual_seed(0))
    assert torch.all(vertex_errors(noisy, true)["scaled"] > 1.0)  # shape errors stay


def test_joint_errors_after_midfoot_and_scale_alignment(foot):
    _, joints = foot
    mid = joints[:, :1]
    pred = mid + 1.1 * (joints - mid) + torch.tensor([0.0, 0.0, 30.0])
    assert torch.allclose(scale_aligned_joint_error(pred, joints), torch.zeros(2, 18), atol=1e-3)
    plain = midfoot_aligned_error(pred, joints)
    assert torch.allclose(plain, 0.1 * (joints - mid).norm(dim=-1), atol=1e-3)


def test_chamfer_matches_the_training_definition(foot):
    true, _ = foot
    g = torch.Generator().manual_seed(2)
    points = true[:, torch.randperm(true.shape[1], generator=g)[:500]] + torch.randn(2, 500, 3, generator=g)
    assert torch.allclose(chamfer_mm(points, true), chamfer_distance(points, true), atol=1e-3)
    assert torch.allclose(chamfer_mm(true, true), torch.zeros(2), atol=1e-3)


def test_evaluate_scores_every_sample_and_viewpoint(views_data, weights):
    scores = evaluate(views_data, "rgbd", weights["rgbd"])
    assert scores.samples == NUM_THESIS_VIEWS and scores.kind == "ism"
    s = scores.summary()
    assert s["vertex_mm"] > s["vertex_mm_centroid_aligned"] >= s["vertex_mm_scale_aligned"] > 0
    assert set(s["latency_ms_batch1"]) == {"network", "decoder"}
    # the regressor's own error on the true posed meshes is small, and exactly what we recompute here
    dataset = SynthDataset(views_data, keys=["vertices", "joints3d"])
    v = torch.from_numpy(np.stack([dataset[i]["vertices"] for i in range(3)]))
    j = torch.from_numpy(np.stack([dataset[i]["joints3d"] for i in range(3)]))
    floor = midfoot_aligned_error(joints_from_vertices(v), j).numpy()
    np.testing.assert_allclose(np.array(scores.joint_floor[:3]), floor, atol=1e-4)
    assert 0 < s["joint_mm_floor_mean"] < 10
    table = view_table(scores)
    assert set(table) == set(thesis.JOINT_MM_BY_VIEW) and all(n == 1 for _, _, n in table.values())
    x0 = np.array(scores.joint)[np.array(scores.view_id) == 0][0, 1:]
    assert table[("X", 0)][:2] == pytest.approx((x0.mean(), x0.std()))


def test_samples_without_any_depth_are_left_out_and_counted(views_data, weights, monkeypatch):
    """A view from below the one-sided floor can leave a depth map empty: depth inputs skip it and say so."""
    read = SynthDataset.__getitem__

    def blind(self, i):
        sample = read(self, i)
        return {**sample, "depth": np.zeros_like(sample["depth"])} if i == 3 else sample

    monkeypatch.setattr(SynthDataset, "__getitem__", blind)
    scores = evaluate(views_data, "rgbd", weights["rgbd"])
    assert scores.samples == NUM_THESIS_VIEWS - 1 and scores.no_depth == 1
    assert scores.summary()["left_out_no_depth"] == 1
    rgb = evaluate(views_data, "rgb", weights["rgb"])
    assert rgb.samples == NUM_THESIS_VIEWS and rgb.no_depth == 0
    text = format_tables({"rgbd": scores}, {"rgbd": scores})
    assert "1 without any depth pixel left out for rgbd" in text


def test_tables_put_ours_beside_the_thesis_and_label_rgb(views_data, weights, tmp_path):
    out = tmp_path / "r.json"
    text = run_eval(
        views_data,
        ["rgb", "rgbd"],
        views_data,
        {"rgb": str(weights["rgb"]), "rgbd": str(weights["rgbd"])},
        out,
        edgeconv_weights=weights["edgeconv"],
        limit=4,
    )
    for needle in ("Table 4.4", "Table 4.5", "Table 4.6", "9.89", "107.92", "11.38", "11.08", "95.19", "EdgeConv"):
        assert needle in text, needle
    assert "as predicted (raw)" in text and "after aligning scale (scale-aligned)" in text
    assert "| rgb scale-aligned |" in text.replace(" | floor |", " |")
    assert text.count("| X |") == 4  # --limit 4: views X 0..90
    data = json.loads(out.read_text())
    assert data["rgb"]["samples"] == 4 and data["edgeconv"]["chamfer_mm"] > 0 and "vertex_mm" not in data["edgeconv"]
    assert len(data["by_view"]["rgbd"]) == 4
    with pytest.raises(ValueError, match="edgeconv-weights"):
        run_eval(views_data, ["rgbd"], weights={"rgbd": str(weights["edgeconv"])}, limit=1)
    with pytest.raises(ValueError, match="not 'rgb'"):
        evaluate(views_data, "rgb", weights["rgbd"], limit=1)


def test_the_model_based_network_has_its_own_row_and_column(views_data, weights, tmp_path):
    out = tmp_path / "m.json"
    text = run_eval(
        views_data, ["rgbd"], views_data, {"rgbd": str(weights["rgbd"])}, out, model_weights=weights["model"], limit=3
    )
    assert "| ISM, rgbd |" in text and "| model-based + ISM residual, rgbd |" in text
    # the thesis' RGB-D cell beside both (a whole number 9.89, not the digits inside a measured one like 99.89)
    assert len(re.findall(r"(?<![\d.])9\.89(?![\d])", text)) == 2
    assert "model ours | model thesis" in text
    data = json.loads(out.read_text())
    assert data["model"]["kind"] == "model" and data["model"]["samples"] == 3
    assert set(data["model"]["model_mesh_centred_mm"]) == set(PARAMETER_GROUPS)
    assert "| ... the foot model's mesh (true side), true shape and angles |" in text
    with pytest.raises(ValueError, match="--model-weights"):
        run_eval(views_data, ["rgbd"], weights={"rgbd": str(weights["model"])}, limit=1)
    with pytest.raises(ValueError, match="not a model-based one"):
        run_eval(views_data, ["rgbd"], weights={"rgbd": str(weights["rgbd"])}, model_weights=weights["rgbd"])


def test_the_parameter_breakdown_finds_the_parameter_that_was_wrong(views_data):
    """True parameters give the true mesh in every row; a wrong rotation alone is undone by its own row only."""
    from footmesh.recon.parametric import NUM_SHAPE, FootParameters

    samples = [
        SynthDataset(views_data, keys=["vertices", "shape", "angles", "cam_from_foot", "side"])[i] for i in (0, 5)
    ]
    true_v = torch.from_numpy(np.stack([s["vertices"] for s in samples]).astype(np.float32))

    def stacked(key):
        return torch.from_numpy(np.stack([s[key] for s in samples]).astype(np.float32))

    rotation = stacked("cam_from_foot")[:, :3, :3]
    exact = FootParameters(stacked("shape")[:, :NUM_SHAPE], stacked("angles"), rotation, torch.zeros(2))
    assert max(max(v) for v in _parameter_parts(exact, samples, true_v).values()) < 0.05
    turn = torch.tensor([[1.0, 0, 0], [0, 0.94, -0.342], [0, 0.342, 0.94]])  # 20 deg about x
    parts = _parameter_parts(replace(exact, rotation=turn @ rotation), samples, true_v)
    assert min(parts["as predicted"]) > 10 and min(parts["true shape and angles"]) > 10
    assert max(parts["true rotation"]) < 0.05


def test_tables_without_views_or_edgeconv(views_data, weights):
    text = format_tables({"rgbd": evaluate(views_data, "rgbd", weights["rgbd"], limit=2)})
    assert "not evaluated" in text and "Table 4.6" not in text and "scale-aligned)" not in text


def _has_eval_recon() -> bool:
    from footmesh.cli import build_parser

    try:
        build_parser().parse_args(["eval", "recon", "--data", "x"])
    except SystemExit:
        return False
    return True


@pytest.mark.skipif(not _has_eval_recon(), reason="`footmesh eval recon` is not in footmesh.cli yet")
def test_cli_prints_the_tables(views_data, weights, tmp_path, capsys):
    from footmesh.cli import main

    args = ["eval", "recon", "--input", "rgbd", "--data", str(views_data), "--weights", str(weights["rgbd"])]
    assert main([*args, "--limit", "2", "--json", str(tmp_path / "e.json")]) == 0
    assert "Table 4.4" in capsys.readouterr().out and (tmp_path / "e.json").is_file()
    assert main(["eval", "recon", "--data", str(views_data), "--weights", str(weights["rgbd"])]) == 2
    assert "single --input" in capsys.readouterr().err


@pytest.mark.slow
def test_the_whole_pipelines_mesh_is_scored_against_the_rendered_foot(tmp_path, weights, monkeypatch):
    data = tmp_path / "guided"
    generate(data, 2, seed=4242, config=guided_view_config(size=320, reference="none"), progress=False)
    scores = evaluate_pipeline(data, "rgbd")
    assert scores.samples == 2 and scores.refused == 0 and scores.index == [0, 1]
    assert max(scores.vertex) < 10.0  # the fit to the depth lands within millimetres of the rendered foot
    assert len(scores.joint) == 2 and scores.seconds > 0
    text = format_tables({"rgbd": evaluate(data, "rgbd", weights["rgbd"])}, pipeline={"rgbd": scores})
    assert "| whole pipeline (decoder start + fit), rgbd (2 of 2 photos measured) |" in text
    assert "| ... ISM, rgbd, on the same photos |" in text and "mean 3D joint error" in text

    from footmesh import pipeline
    from footmesh.errors import Refusal

    def refuse(*args, **kwargs):
        raise Refusal("the foot is cut off by the photo's edge")

    monkeypatch.setattr(pipeline, "measure_photo", refuse)
    refused = evaluate_pipeline(data, "rgbd", limit=1)
    assert refused.samples == 0 and refused.refused == 1
    assert "none of 1 photos measured" in format_tables({}, pipeline={"rgbd": refused})
