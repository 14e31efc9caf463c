"""Training the reconstruction network (``footmesh.train.recon``): 3D-target cache, camera-exact augmentation,
training, resuming, weights, and the ``footmesh train recon`` command."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
from _tiny_cues import SIZE

from footmesh.config import TrainConfig
from footmesh.recon.decoder import DecoderConfig
from footmesh.recon.model import ReconConfig, ReconNet, recon_input
from footmesh.recon.weights import load_network
from footmesh.synth.dataset import SynthDataset
from footmesh.train.loop import CHECKPOINT
from footmesh.train.recon import (
    MODEL_CARD,
    WEIGHTS,
    ReconAugment,
    ReconBatch,
    ReconTrainingConfig,
    augment_recon,
    copy_matching,
    evaluate_arrays,
    keep_with_depth,
    load_recon_arrays,
    make_recon_batch,
    train_recon,
)

TINY_MODEL = ReconConfig.for_widths((8, 8, 16, 16), 16, image_size=SIZE, decoder=DecoderConfig(channels=(8,) * 5))
TINY_TRAIN = TrainConfig(steps=2, batch_size=4, warmup_steps=1, val_every=1000, threads=1, seed=3)
STEPS = 30
NO_PHOTOMETRIC = {
    "brightness": (1.0, 1.0),
    "contrast": (1.0, 1.0),
    "saturation": (1.0, 1.0),
    "white_balance": 0.0,
    "noise_sd": (0.0, 0.0),
    "blur_p": 0.0,
    "jpeg_p": 0.0,
    "depth_noise_mm": (0.0, 0.0),
    "depth_dropout_p": 0.0,
}


def tiny_config(**model: object) -> ReconTrainingConfig:
    return ReconTrainingConfig(model=replace(TINY_MODEL, **model), train=TINY_TRAIN)


def project(points: torch.Tensor, K: torch.Tensor) -> torch.Tensor:  # noqa: N803
    """(B, N, 3) mm camera frame -> (B, N, 2) px."""
    uvw = points @ K.transpose(1, 2)
    return uvw[..., :2] / uvw[..., 2:]


def test_arrays_hold_the_samples_3d_targets_and_intrinsics(tiny_data):
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    dataset = SynthDataset(tiny_data, keys=["vertices", "joints3d", "K", "joints2d"])
    assert len(arrays) == len(dataset) == 24
    for i in (0, 17):
        s = dataset[i]
        np.testing.assert_array_equal(arrays.vertices[i], s["vertices"])
        np.testing.assert_array_equal(arrays.joints3d[i], s["joints3d"])
        np.testing.assert_allclose(arrays.K[i], s["K"], rtol=1e-6)  # same side: unchanged
    # a second call reuses the cache; at another side K is resized so that the joints project where they should
    stamp = (tiny_data / f"recon-cache-{SIZE}" / "vertices.npy").stat().st_mtime_ns
    load_recon_arrays(tiny_data, SIZE, progress=False)
    assert (tiny_data / f"recon-cache-{SIZE}" / "vertices.npy").stat().st_mtime_ns == stamp
    batch = make_recon_batch(arrays, np.arange(4))
    assert batch.rgb.shape == (4, 3, SIZE, SIZE) and batch.depth.shape == (4, 1, SIZE, SIZE)
    assert batch.vertices.shape == (4, 4002, 3) and batch.joints3d.shape == (4, 18, 3)
    truth = torch.from_numpy(np.stack([dataset[i]["joints2d"] for i in range(4)]))
    assert torch.allclose(project(batch.joints3d, batch.K), truth, atol=1e-2)


def _blob_batch(arrays, rows: np.ndarray, joint: int) -> ReconBatch:
    """A batch whose images are black but for a Gaussian blob (SD 1.2 px) centred where ``joint`` projects."""
    batch = make_recon_batch(arrays, rows)
    uv = project(batch.joints3d, batch.K)[:, joint]  # (B, 2)
    px = torch.arange(SIZE, dtype=torch.float32)
    gx = torch.exp(-((px - uv[:, :1]) ** 2) / (2 * 1.2**2))  # (B, S)
    gy = torch.exp(-((px - uv[:, 1:]) ** 2) / (2 * 1.2**2))
    rgb = (gy[:, :, None] * gx[:, None, :]).unsqueeze(1).expand(-1, 3, -1, -1).contiguous()
    return replace(batch, rgb=rgb, depth=torch.full_like(batch.depth, 400.0))


def _centroid(rgb: torch.Tensor) -> torch.Tensor:
    """Brightness-weighted centre (B, 2) px of each image."""
    w = rgb.mean(1)  # (B, S, S)
    px = torch.arange(w.shape[-1], dtype=w.dtype)
    total = w.sum((1, 2))
    return torch.stack([(w.sum(1) * px).sum(-1) / total, (w.sum(2) * px).sum(-1) / total], -1)


def test_augmentation_moves_image_targets_and_intrinsics_together(tiny_data):
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    # the midfoot: inside the image in every sample (the camera looks at the foot's centre)
    batch = _blob_batch(arrays, np.arange(12), joint=0)
    assert torch.allclose(_centroid(batch.rgb), project(batch.joints3d, batch.K)[:, 0], atol=0.05)
    # the image's blob must go where the turned targets project with the new K
    aug = ReconAugment(rotate_deg=30.0, flip=0.5, zoom=(0.85, 1.15), **NO_PHOTOMETRIC)
    out = augment_recon(batch, aug, torch.Generator().manual_seed(5))
    moved = project(out.joints3d, out.K)[:, 0]
    inside = ((moved > 5) & (moved < SIZE - 6)).all(-1)
    assert inside.sum() >= 8
    assert torch.allclose(_centroid(out.rgb)[inside], moved[inside], atol=0.1)
    # the targets moved rigidly or mirrored: depth kept, distances kept, some samples mirrored
    assert torch.allclose(out.vertices[..., 2], batch.vertices[..., 2])
    d_before = (batch.vertices[:, :50, None] - batch.vertices[:, None, :50]).norm(dim=-1)
    d_after = (out.vertices[:, :50, None] - out.vertices[:, None, :50]).norm(dim=-1)
    assert torch.allclose(d_before, d_after, atol=1e-2)
    det = torch.linalg.det(torch.linalg.lstsq(batch.vertices[..., :2], out.vertices[..., :2]).solution)
    assert torch.allclose(det.abs(), torch.ones_like(det), atol=1e-4)
    assert (det < 0).any() and (det > 0).any()
    assert torch.allclose(out.K[:, 0, 0], out.K[:, 1, 1]) and not torch.allclose(out.K, batch.K)
    assert torch.equal(out.K[:, :2, 2], batch.K[:, :2, 2])  # the principal point stays


def test_augmented_foot_model_parameters_still_build_the_augmented_mesh(tiny_data):
    """Rotation, mirror and zoom keep the parameters' targets consistent: the foot model of the turned rotation
    and the swapped side is the turned (mirrored) mesh, so the model-based head learns from exact targets."""
    from footmesh.model.layer import default_model

    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    batch = make_recon_batch(arrays, np.arange(12))
    aug = ReconAugment(rotate_deg=40.0, flip=0.5, zoom=(0.85, 1.15), **NO_PHOTOMETRIC)
    out = augment_recon(batch, aug, torch.Generator().manual_seed(2))
    assert (out.right != batch.right).any() and (out.right == batch.right).any()
    eye = torch.eye(3).expand(12, 3, 3)
    assert torch.allclose(out.rotation @ out.rotation.transpose(1, 2), eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(out.rotation), torch.ones(12), atol=1e-5)
    for b in (batch, out):
        sides = ["right" if r > 0.5 else "left" for r in b.right.tolist()]
        built = default_model()(b.shape, b.angles, side=sides, rotation=b.rotation).vertices
        target = b.vertices
        err = (built - built.mean(1, keepdim=True)) - (target - target.mean(1, keepdim=True))
        assert err.norm(dim=-1).max() < 0.05  # mm


def test_identity_augmentation_changes_nothing_and_non_square_pixels_are_refused(tiny_data):
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    batch = make_recon_batch(arrays, np.arange(3))
    still = ReconAugment(rotate_deg=0.0, flip=0.0, zoom=(1.0, 1.0), **NO_PHOTOMETRIC)
    out = augment_recon(batch, still, torch.Generator().manual_seed(0))
    assert torch.allclose(out.rgb, batch.rgb, atol=1e-5) and torch.equal(out.depth, batch.depth)
    assert torch.allclose(out.vertices, batch.vertices) and torch.allclose(out.K, batch.K)
    k = batch.K.clone()
    k[:, 1, 1] *= 1.1
    with pytest.raises(ValueError, match="square pixels"):
        augment_recon(replace(batch, K=k), still, torch.Generator())


def test_samples_whose_depth_map_was_emptied_leave_the_batch(tiny_data):
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    batch = make_recon_batch(arrays, np.arange(3))
    depth = batch.depth.clone()
    depth[1] = 0.0  # e.g. a zoom that cropped away a small foot's few depth pixels
    kept = keep_with_depth(replace(batch, depth=depth))
    assert kept.depth.shape[0] == 2 and torch.equal(kept.vertices, batch.vertices[[0, 2]])
    x, ref = recon_input("rgbd", kept.rgb, kept.depth)
    assert torch.isfinite(x).all() and (ref > 0).all()
    assert keep_with_depth(batch) is batch


def test_train_two_steps_writes_weights_and_card_then_resumes(tiny_data, tmp_path):
    out = tmp_path / "run"
    config = tiny_config()
    result = train_recon(tiny_data, out, config, progress=False)
    assert result.finished and result.steps_done == 2
    assert set(result.metrics) == {"val_vertex_mm", "val_joint_mm"}
    model, net, info = load_network(out / WEIGHTS)
    assert net == config.model and info["steps_done"] == 2 and info["data"]["samples"] == 24
    assert "rgbd input" in (out / MODEL_CARD).read_text()
    # stopped by its time budget after one step, then resumed by the same command to the end
    run2 = tmp_path / "run2"
    budget = replace(config, train=replace(config.train, steps=3, max_minutes=1e-6))
    first = train_recon(tiny_data, run2, budget, progress=False)
    assert not first.finished and first.steps_done == 1
    again = train_recon(tiny_data, run2, replace(budget, train=replace(budget.train, max_minutes=None)), False)
    assert again.finished and torch.load(run2 / CHECKPOINT, weights_only=False)["step"] == 3
    log = (run2 / "log.csv").read_text()
    assert "vertex_mm" in log and "edge" in log
    with pytest.raises(ValueError, match="another configuration"):
        train_recon(tiny_data, run2, tiny_config(loss="structure"), progress=False)


@pytest.mark.parametrize("residual", [False, True])
def test_model_based_head_trains_and_its_weights_load(tiny_data, tmp_path, residual):
    config = tiny_config(kind="model", loss="structure", residual=residual)
    result = train_recon(tiny_data, tmp_path / "model", config, progress=False)
    assert result.finished and 0 < result.metrics["val_vertex_mm"] < 500
    log = (tmp_path / "model" / "log.csv").read_text()
    assert all(term in log for term in ("model_mesh", "shape", "angles", "rotation", "side", "centre"))
    model, net, _ = load_network(tmp_path / "model" / WEIGHTS)
    assert net == config.model and (model.decoder is not None) == residual
    assert "model-based head" in (tmp_path / "model" / MODEL_CARD).read_text()
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False)
    batch = make_recon_batch(arrays, np.arange(2))
    x, ref = recon_input("rgbd", batch.rgb, batch.depth)
    given = torch.tensor([True, False])
    out = model(x, batch.K, ref, given)
    assert torch.equal(out.right, given) and out.vertices.shape == (2, 4002, 3)
    # the side given decides the mirror: the other side's mesh is a different one
    other = model(x, batch.K, ref, ~given)
    assert (other.model_vertices - out.model_vertices).norm(dim=-1).mean() > 1.0


def test_the_residual_decoder_starts_from_an_ism_networks_spiral_layers(tiny_data, tmp_path):
    """A model-based run without the residual, continued with it: the foot model's head from that run, the residual
    decoder's spiral layers from an ISM run (``residual_from``), its heads at zero."""
    frozen = replace(TINY_TRAIN, lr=1e-12, steps=1)  # the copied tensors are still the sources' after one step
    # another seed: the ISM's spiral layers are not the ones the residual decoder would draw anyway
    train_recon(tiny_data, tmp_path / "ism", replace(tiny_config(), train=replace(frozen, seed=7)), progress=False)
    plain = tiny_config(kind="model", loss="structure", residual=False)  # trained: its zero-started heads move
    train_recon(tiny_data, tmp_path / "plain", plain, progress=False)
    both = replace(
        tiny_config(kind="model", loss="structure"),
        train=replace(frozen, init_from=str(tmp_path / "plain" / WEIGHTS)),
        residual_from=str(tmp_path / "ism" / WEIGHTS),
    )
    train_recon(tiny_data, tmp_path / "both", both, progress=False)
    ism, _, _ = load_network(tmp_path / "ism" / WEIGHTS)
    head, _, _ = load_network(tmp_path / "plain" / WEIGHTS)
    model, _, _ = load_network(tmp_path / "both" / WEIGHTS)
    close = dict(atol=1e-3, rtol=1e-3)
    assert torch.allclose(model.decoder.blocks[0].filter_full.weight, ism.decoder.blocks[0].filter_full.weight, **close)
    assert torch.allclose(model.parametric.linear.weight, head.parametric.linear.weight, **close)
    assert torch.allclose(model.placement.centre_head.weight, head.placement.centre_head.weight, **close)
    assert float(head.parametric.linear.weight.detach().abs().max()) > 1e-4
    assert all(float(h.linear.weight.detach().abs().max()) < 1e-6 for h in model.decoder.heads)
    with pytest.raises(ValueError, match="residual_from"):
        replace(tiny_config(), residual_from=str(tmp_path / "ism" / WEIGHTS))


def test_edgeconv_baseline_trains_with_chamfer(tiny_data, tmp_path):
    from footmesh.recon.edgeconv import EdgeConvConfig

    edge = EdgeConvConfig(in_features=16, seed_points=32, channels=(8, 8, 8), up_factors=(2, 2))
    config = replace(tiny_config(kind="edgeconv", loss="chamfer", edgeconv=edge), chamfer_points=256)
    result = train_recon(tiny_data, tmp_path / "ec", replace(config, train=replace(config.train, steps=1)), False)
    assert set(result.metrics) == {"val_chamfer_mm"} and 0 < result.metrics["val_chamfer_mm"] < 500
    model, net, _ = load_network(tmp_path / "ec" / WEIGHTS)
    assert net.kind == "edgeconv" and model.decoder is None


def test_a_tiny_network_learns_a_few_feet(tiny_data, hierarchy_cache):
    """Without augmentation, 30 steps on 4 samples bring the mean vertex error far below the first guess."""
    torch.manual_seed(0)
    torch.set_num_threads(1)
    arrays = load_recon_arrays(tiny_data, SIZE, progress=False).subset(np.arange(4))
    model = ReconNet(replace(TINY_MODEL, input="depth"), hierarchy_cache)
    batch = make_recon_batch(arrays, np.arange(4))
    x, ref = recon_input("depth", batch.rgb, batch.depth)
    start = evaluate_arrays(model.eval(), arrays)["vertex_mm"]
    model.train()
    from footmesh.recon.losses import LossWeights, mesh_loss

    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    for _ in range(STEPS):
        loss = mesh_loss(model(x, batch.K, ref).vertices, batch.vertices, model.faces, LossWeights.thesis()).total
        opt.zero_grad()
        loss.backward()
        opt.step()
    end = evaluate_arrays(model.eval(), arrays)["vertex_mm"]
    assert start > 40 and end < 0.5 * start, (start, end)


def test_copy_matching_adapts_the_first_convolution():
    torch.manual_seed(0)
    rgbd = ReconNet(replace(TINY_MODEL, kind="edgeconv", loss="chamfer"))
    rgb = ReconNet(replace(TINY_MODEL, input="rgb", kind="edgeconv", loss="chamfer"))
    copied = copy_matching(rgb, rgbd.state_dict(), rgbd.config)
    assert copied == len(rgbd.state_dict())
    w_src, w_dst = rgbd.state_dict()["encoder.stem.0.0.weight"], rgb.state_dict()["encoder.stem.0.0.weight"]
    assert torch.equal(w_dst[:, :3], w_src[:, :3]) and torch.equal(w_dst[:, 3:], w_src[:, 4:])  # r g b | x y


def test_an_ism_network_starts_the_model_based_head_where_it_places_the_foot(hierarchy_cache):
    """From an ISM network's weights the model-based network reads the same latent and puts the foot model's
    mesh at the ISM's centroid; the residual starts at zero; and the copied parts, not the new head, count as
    pretrained (their learning rate scaled)."""
    from footmesh.train.loop import param_groups

    torch.manual_seed(0)
    ism = ReconNet(TINY_MODEL, hierarchy_cache)
    with torch.no_grad():  # a trained network's heads are not the zero start
        for p in ism.parameters():
            p.add_(0.05 * torch.randn_like(p))
    model = ReconNet(replace(TINY_MODEL, kind="model", loss="structure"), hierarchy_cache)
    copy_matching(model, ism.state_dict(), ism.config)
    g = torch.Generator().manual_seed(1)
    rgb, depth = torch.rand(2, 3, SIZE, SIZE, generator=g), 400 + 100 * torch.rand(2, 1, SIZE, SIZE, generator=g)
    x, ref = recon_input("rgbd", rgb, depth)
    K = torch.tensor([[60.0, 0, 31.5], [0, 60.0, 31.5], [0, 0, 1]]).expand(2, 3, 3)  # noqa: N806
    with torch.no_grad():
        out, ism_out = model(x, K, ref), ism(x, K, ref)
    assert torch.allclose(out.centre, ism_out.centre, atol=1e-4)
    assert torch.allclose(out.vertices, out.model_vertices)  # the ISM's coordinate heads were not copied
    assert all(not head.linear.weight.detach().any() for head in model.decoder.heads)
    assert torch.equal(model.decoder.blocks[0].filter_full.weight, ism.decoder.blocks[0].filter_full.weight)

    model.initialised_from_network = True
    groups = param_groups(model, replace(TINY_TRAIN, pretrained_lr_scale=0.2))
    new = {id(p) for p in groups[0]["params"]}
    scaled = {id(p) for p in groups[1]["params"]}
    assert groups[1]["lr_scale"] == 0.2 and {id(p) for p in model.encoder.parameters()} <= scaled
    assert {id(p) for p in model.parametric.parameters()} <= new
    assert {id(p) for p in model.decoder.heads.parameters()} <= new


def test_config_from_partial_dict_keeps_this_modules_defaults():
    config = ReconTrainingConfig.from_dict({"model": {"decoder": {"channels": [8, 8, 8, 8, 8]}}, "chamfer_points": 9})
    assert config.model.decoder.in_features == ReconConfig().decoder.in_features
    assert config.model.decoder.skip_in_channels == (256, 128, 64, 32) and config.chamfer_points == 9
    with pytest.raises(ValueError, match="stackz"):
        ReconTrainingConfig.from_dict({"model": {"stackz": 1}})
    with pytest.raises(ValueError, match="skip_in_channels"):
        ReconTrainingConfig.from_dict({"model": {"widths": [8, 8, 8, 8]}})
    with pytest.raises(ValueError, match="chamfer"):
        ReconTrainingConfig.from_dict({"model": {"kind": "edgeconv"}})
    assert json.loads(json.dumps(ReconTrainingConfig().to_dict()))["model"]["loss"] == "thesis"
    assert ReconTrainingConfig.from_dict({"train_only": ["centre_refiner"]}).train_only == ("centre_refiner",)
    with pytest.raises(ValueError, match="list of strings"):
        ReconTrainingConfig.from_dict({"train_only": [1]})


# --- the command line (footmesh.cli; skipped until the subcommand is part of cli.py) ------------------------------


def _has_recon_command() -> bool:
    from footmesh.cli import build_parser

    try:
        build_parser().parse_args(["train", "recon", "--input", "rgb", "--data", "x"])
    except SystemExit:
        return False
    return True


cli = pytest.mark.skipif(not _has_recon_command(), reason="`footmesh train recon` is not in footmesh.cli yet")


@cli
def test_cli_trains_two_steps_and_resumes(tiny_data, tmp_path):
    from footmesh.cli import main

    config = tmp_path / "tiny.json"
    config.write_text(json.dumps({"model": ReconTrainingConfig(model=TINY_MODEL).to_dict()["model"]}))
    out = tmp_path / "run"
    args = ["train", "recon", "--input", "depth", "--data", str(tiny_data), "--out", str(out), "--no-progress"]
    args += ["--config", str(config), "--batch-size", "4", "--threads", "1", "--loss", "structure"]
    assert main([*args, "--steps", "2"]) == 0
    _, net, info = load_network(out / WEIGHTS)
    assert net.input == "depth" and net.loss == "structure" and net.widths == (8, 8, 16, 16)
    assert info["training"]["train"]["steps"] == 2 and info["training"]["train"]["batch_size"] == 4
    assert main([*args, "--steps", "2"]) == 0  # finished: nothing to do
    assert torch.load(out / CHECKPOINT, weights_only=False)["step"] == 2


@cli
def test_cli_refuses_bad_settings_with_one_line(tiny_data, tmp_path, capsys):
    from footmesh.cli import main

    base = ["train", "recon", "--input", "rgb", "--data", str(tiny_data), "--out", str(tmp_path / "r"), "--no-progress"]
    for extra, message in (
        (["--kind", "edgeconv", "--loss", "structure"], "chamfer"),
        (["--steps", "0"], "--steps"),
        (["--data", str(tmp_path / "nowhere")], "nowhere"),
    ):
        assert main([*base, *extra]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("footmesh: error: ") and message in err[0], err
    assert not (tmp_path / "r").exists()


@pytest.fixture(scope="module")
def hierarchy_cache():
    from footmesh.recon.hierarchy import template_hierarchy

    return template_hierarchy()
