"""The image -> mesh network (``footmesh.recon.model``): the normalised camera frame, inputs, outputs, weights."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from footmesh.geometry.camera import resize_intrinsics
from footmesh.recon.decoder import DecoderConfig, DecoderOutput
from footmesh.recon.edgeconv import EdgeConvConfig, PointCloudOutput
from footmesh.recon.model import (
    DEPTH_GAIN,
    FOCAL_REF,
    ReconConfig,
    ReconNet,
    _coordinates,
    from_camera,
    recon_input,
    to_camera,
)
from footmesh.recon.weights import load_network, network_for, read_weights, save_weights

SIZE = 64
TINY = ReconConfig.for_widths((8, 8, 16, 16), 16, image_size=SIZE, decoder=DecoderConfig(channels=(8,) * 5))
TINY_EDGE = replace(
    TINY,
    kind="edgeconv",
    loss="chamfer",
    edgeconv=EdgeConvConfig(in_features=16, seed_points=32, channels=(8, 8, 8), up_factors=(2, 2)),
)


def camera(f: float = 70.0, cx: float = 35.0, cy: float = 28.0, b: int = 1) -> torch.Tensor:
    """(b, 3, 3) intrinsics of a SIZE-px image, principal point off the centre (31.5, 31.5) unless given."""
    return torch.tensor([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]]).expand(b, 3, 3).clone()


def scene(b: int = 2, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """Random images (b, 3, S, S) in [0, 1] and depth maps (b, 1, S, S) mm with some holes."""
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(b, 3, SIZE, SIZE, generator=g)
    depth = 350 + 200 * torch.rand(b, 1, SIZE, SIZE, generator=g)
    depth[torch.rand(depth.shape, generator=g) < 0.1] = 0
    return rgb, depth


def test_normalised_frame_is_what_the_image_shows(foot_target):
    """C = Z / s, and (A, B) / C x f_ref + image centre = the pixel the vertex projects to; exactly invertible."""
    K = camera(b=1)  # noqa: N806
    s = torch.tensor([0.8])
    p = from_camera(foot_target, K, s, SIZE)
    x, y, z = foot_target.unbind(-1)
    c0, f_ref = (SIZE - 1) / 2, FOCAL_REF * SIZE
    assert torch.allclose(p[..., 2], z / 0.8)
    assert torch.allclose(p[..., 0] / p[..., 2] * f_ref + c0, 70 * x / z + 35.0, atol=1e-3)
    assert torch.allclose(p[..., 1] / p[..., 2] * f_ref + c0, 70 * y / z + 28.0, atol=1e-3)
    assert torch.allclose(to_camera(p, K, s, SIZE), foot_target, atol=1e-3)


def test_resized_intrinsics_project_like_resized_pixels():
    K = camera(f=120.0, cx=111.5, cy=111.5)[0].numpy().astype(np.float64)  # noqa: N806
    point = np.array([40.0, -25.0, 430.0])
    uv = (K @ point)[:2] / point[2]
    k = resize_intrinsics(K, 128 / 224)
    np.testing.assert_allclose((k @ point)[:2] / point[2], (uv + 0.5) * 128 / 224 - 0.5, atol=1e-9)
    assert k[0, 2] == pytest.approx(63.5)
    assert torch.allclose(resize_intrinsics(torch.from_numpy(K), 128 / 224), torch.from_numpy(k))


def test_input_is_relative_depth_and_carries_the_scale_separately():
    rgb, depth = scene()
    x, ref = recon_input("rgbd", rgb, depth)
    assert x.shape == (2, 4, SIZE, SIZE)
    valid = depth > 0
    assert torch.allclose(ref, torch.tensor([depth[i][valid[i]].median() for i in range(2)]))
    assert torch.all(x[:, 3:][~valid] == 0)
    # 1 % deeper than the median reads as DEPTH_GAIN / 100
    flat = torch.full((1, 1, SIZE, SIZE), 500.0)
    flat[0, 0, 3, 4] = 505.0
    assert recon_input("depth", None, flat)[0][0, 0, 3, 4] == pytest.approx(DEPTH_GAIN / 100)
    # the whole scene scaled: the same input, the scale in ref
    x2, ref2 = recon_input("rgbd", rgb, 1.3 * depth)
    assert torch.allclose(x2, x, atol=1e-5) and torch.allclose(ref2, 1.3 * ref)
    x_rgb, ref_rgb = recon_input("rgb", rgb, None)
    assert x_rgb.shape == (2, 3, SIZE, SIZE) and ref_rgb is None
    with pytest.raises(ValueError, match="no valid"):
        recon_input("depth", None, torch.where(torch.arange(2).view(2, 1, 1, 1) == 1, 0.0, depth))
    with pytest.raises(ValueError, match="RGB"):
        recon_input("rgbd", None, depth)
    with pytest.raises(ValueError, match="depth"):
        recon_input("depth", rgb, None)


def test_coordinate_channels_span_the_image():
    c = _coordinates(torch.zeros(2, 1, 4, 8))
    assert c.shape == (2, 2, 4, 8)
    assert torch.allclose(c[0, 0, 0], torch.linspace(-7 / 8, 7 / 8, 8)) and torch.allclose(c[0, 1, :, 0], c[0, 1, :, 3])
    assert torch.allclose(c[0, 1, :, 0], torch.linspace(-3 / 4, 3 / 4, 4))


def test_scaling_the_scene_scales_the_mesh_exactly():
    """Depth inputs: the scene k times larger (depth k times) gives the mesh k times larger, same image."""
    torch.manual_seed(0)
    net = ReconNet(TINY).eval()
    rgb, depth = scene()
    K = camera(b=2)  # noqa: N806
    with torch.no_grad():
        a = run(net, rgb, depth, K)
        b = run(net, rgb, 1.25 * depth, K)
    assert isinstance(a, DecoderOutput) and a.vertices.shape == (2, 4002, 3) and a.centre.shape == (2, 3)
    assert torch.allclose(b.vertices, 1.25 * a.vertices, rtol=1e-4, atol=1e-3)
    assert [lv.shape[1] for lv in a.levels] == [4002, 2002, 1002, 502, 252] and a.levels[0] is a.vertices
    assert torch.allclose(a.vertices.mean(1), a.centre, atol=1e-2)


def test_spatial_centroid_lies_on_the_ray_of_its_soft_argmax_pixel():
    """The centroid projects onto the soft-argmax pixel of the centre map, whatever the intrinsics."""
    torch.manual_seed(3)
    net = ReconNet(replace(TINY, centre_head="spatial")).eval()
    assert net.centre_map is not None and net.surface_map is None
    with torch.no_grad():
        net.centre_map.weight.normal_(0.0, 3.0)  # a peaked map somewhere off the image centre
    rgb, depth = scene()
    x, ref = recon_input("rgbd", rgb, depth)
    captured = {}
    net.encoder.stages[1].register_forward_hook(lambda _m, _i, out: captured.update(feature=out))
    K = camera(b=2)  # noqa: N806
    with torch.no_grad():
        out = net(x, K, ref)
        feature = captured["feature"]
        prob = net.centre_map(feature).flatten(1).softmax(1).view(2, *feature.shape[2:])
    stride = SIZE / feature.shape[-1]
    grid = (torch.arange(feature.shape[-1]) + 0.5) * stride - 0.5
    want = torch.stack([(prob.sum(1) * grid).sum(1), (prob.sum(2) * grid).sum(1)], -1)
    seen = (out.centre @ K[0].T)[:, :2] / out.centre[:, 2:]
    assert torch.allclose(seen, want, atol=1e-3), (seen, want)
    assert (want - (SIZE - 1) / 2).abs().max() > 1.0  # really off the centre: the test can fail
    glob = ReconNet(replace(TINY, centre_head="global"))
    assert glob.centre_map is None
    with pytest.raises(ValueError, match="centre_head"):
        replace(TINY, centre_head="middle")


@pytest.mark.parametrize("kind", ["rgbd", "depth"])
def test_anchored_centroid_reads_its_depth_off_the_depth_map(kind):
    """At the start (uniform surface map, zero offset) the centroid's depth is the mean over the stride-8 cells
    with measured depth of each cell's mean depth, in mm, whatever the encoder computes."""
    torch.manual_seed(5)
    net = ReconNet(replace(TINY, input=kind)).eval()
    assert TINY.centre_head == "anchored" and net.surface_map is not None
    rgb, depth = scene()
    depth[:, :, :24] = 0.0  # a third of the map missing: those cells do not count
    x, ref = recon_input(kind, rgb, depth)
    with torch.no_grad():
        out = net(x, camera(b=2), ref)
    cells = SIZE // 8
    for b in range(2):
        d = depth[b, 0]
        valid = (d > 0) & (d != ref[b])  # (a pixel at exactly the median reads as missing: relative depth 0)
        total = torch.where(valid, d, 0.0).view(cells, 8, cells, 8).sum((1, 3))
        count = valid.view(cells, 8, cells, 8).sum((1, 3))
        want = (total[count > 0] / count[count > 0]).mean()
        assert torch.allclose(out.centre[b, 2], want, rtol=1e-4), (out.centre[b, 2], want)
    assert ReconNet(replace(TINY, input="rgb")).surface_map is None


def test_a_centre_pixel_head_starts_as_the_network_without_it_and_moves_the_centroid_on_its_ray():
    """Given the weights of a network without it, a network with ``centre_refine`` answers the same (its last layer
    starts at zero); once it has learnt, the centroid moves to the pixel its offsets and heat map point at, the
    depth still read off the depth map."""
    torch.manual_seed(4)
    plain = ReconNet(TINY).eval()
    refined = ReconNet(replace(TINY, centre_refine=True)).eval()
    missing, unexpected = refined.load_state_dict(plain.state_dict(), strict=False)
    assert missing and all(k.startswith("centre_refiner.") for k in missing) and not unexpected
    rgb, depth = scene()
    x, ref = recon_input("rgbd", rgb, depth)
    K = camera(b=2)  # noqa: N806
    with torch.no_grad():
        before = plain(x, K, ref)
        same = refined(x, K, ref)
        assert torch.allclose(same.vertices, before.vertices, atol=1e-4)
        refined.centre_refiner.out.bias.copy_(torch.tensor([0.0, 1.5, -1.0]))  # every cell 1.5 right, 1 up
        moved = refined(x, K, ref)
    pixel = lambda c: (c @ K[0].T)[:, :2] / c[:, 2:]  # noqa: E731
    shift = pixel(moved.centre) - pixel(before.centre)
    stride = SIZE / (SIZE // 8)
    assert torch.allclose(shift, torch.tensor([1.5 * stride, -stride]).expand(2, 2), atol=1e-3), shift
    assert torch.allclose(moved.centre[:, 2], before.centre[:, 2], rtol=1e-5)
    assert ReconNet(replace(TINY, centre_head="global", centre_refine=True)).centre_refiner is None


def test_train_only_freezes_the_rest_and_its_batch_norm_statistics():
    """With ``train_only``, a training step changes the named submodule alone: the rest gets no gradient and its
    batch-norm statistics stay as loaded, although the network is in training mode."""
    torch.manual_seed(6)
    net = ReconNet(replace(TINY, centre_refine=True))
    net.train_only(("centre_refiner",))
    net.train()
    assert net.centre_refiner.training and not net.encoder.training and net.training
    state = {k: v.clone() for k, v in net.state_dict().items()}
    with torch.no_grad():
        net.centre_refiner.out.weight.normal_(0.0, 0.1)  # past the zero start, where gradients reach the map
    rgb, depth = scene()
    x, ref = recon_input("rgbd", rgb, depth)
    optimiser = torch.optim.SGD([p for p in net.parameters() if p.requires_grad], lr=0.1)
    (net(x, camera(b=2), ref).vertices - torch.tensor([5.0, -3.0, 420.0])).abs().mean().backward()
    optimiser.step()
    changed = {k for k, v in net.state_dict().items() if not torch.equal(v, state[k])}
    assert changed and all(k.startswith("centre_refiner.") for k in changed), changed
    assert all(p.grad is None for n, p in net.named_parameters() if not n.startswith("centre_refiner."))
    with pytest.raises(ValueError, match="centre_refiner"):
        ReconNet(TINY).train_only(("centre_refiner",))  # a network without one


def test_rgb_focal_length_sets_the_depth():
    """RGB: the same image taken with a k times longer lens shows the same objects k times farther away."""
    torch.manual_seed(1)
    net = ReconNet(replace(TINY, input="rgb")).eval()
    rgb, _ = scene()
    x, _ = recon_input("rgb", rgb, None)
    centred = camera(f=60.0, cx=31.5, cy=31.5, b=2)
    with torch.no_grad():
        a = net(x, centred).vertices
        b = net(x, camera(f=90.0, cx=31.5, cy=31.5, b=2)).vertices
    assert torch.allclose(b[..., 2], 1.5 * a[..., 2], rtol=1e-5)
    assert torch.allclose(b[..., :2], a[..., :2], atol=1e-3)


def test_edgeconv_kind_outputs_points():
    torch.manual_seed(2)
    net = ReconNet(TINY_EDGE).eval()
    rgb, depth = scene()
    with torch.no_grad():
        out = run(net, rgb, depth, camera(b=2))
    assert isinstance(out, PointCloudOutput) and out.points.shape == (2, 128, 3)
    assert torch.allclose(out.points.mean(1), out.centre, atol=1e-2)
    with pytest.raises(ValueError, match="point cloud"):
        _ = net.faces


def test_every_parameter_learns_and_bad_inputs_fail():
    torch.manual_seed(3)
    net = ReconNet(TINY)
    rgb, depth = scene()
    x, ref = recon_input("rgbd", rgb, depth)
    out = net(x, camera(b=2), ref)
    (out.vertices - torch.tensor([5.0, -3.0, 420.0])).abs().mean().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        if not name.startswith("decoder.blocks"):  # (a tiny decoder's ISM may start with a channel ReLU-dead)
            assert p.grad.abs().sum() > 0, name
    with pytest.raises(ValueError, match="input must be"):
        net(x[:, :3], camera(b=2), ref)
    with pytest.raises(ValueError, match="K must be"):
        net(x, camera(b=1), ref)
    with pytest.raises(ValueError, match="medians"):
        net(x, camera(b=2))


def test_configuration_is_checked():
    with pytest.raises(ValueError, match="skip_in_channels"):
        replace(TINY, widths=(8, 8, 8, 8))
    with pytest.raises(ValueError, match="chamfer"):
        replace(TINY, kind="edgeconv")
    with pytest.raises(ValueError, match="thesis or structure"):
        replace(TINY, loss="chamfer")
    with pytest.raises(ValueError, match="input"):
        replace(TINY, input="ir")
    with pytest.raises(ValueError, match="edgeconv.in_features"):
        ReconConfig(decoder=replace(ReconConfig().decoder, in_features=64))
    assert replace(TINY, decoder=replace(TINY.decoder, skip_in_channels=())).decoder.skip_in_channels == ()
    assert ReconConfig().in_channels == 6 and replace(TINY, input="depth", coord_channels=False).in_channels == 1


def test_default_network_weights_are_small_and_round_trip(hierarchy, tmp_path):
    torch.manual_seed(4)
    net = ReconNet(ReconConfig(), hierarchy).eval()
    path = tmp_path / "w.pt"
    save_weights(path, net, net.config, {"validation": {"val_vertex_mm": 1.0}}, hierarchy)
    assert path.stat().st_size <= 25e6
    loaded, config, info = load_network(path)
    assert config == net.config and info["validation"]["val_vertex_mm"] == 1.0
    # the same network up to float16 storage of the weights
    net.load_state_dict({k: v.half().float() if v.is_floating_point() else v for k, v in net.state_dict().items()})
    rgb, depth = scene(1)
    rgb = torch.nn.functional.interpolate(rgb, size=128)
    depth = torch.nn.functional.interpolate(depth, size=128)
    with torch.no_grad():
        a = run(net, rgb, depth, camera(f=96.0, cx=63.5, cy=63.5))
        b = run(loaded, rgb, depth, camera(f=96.0, cx=63.5, cy=63.5))
    assert torch.allclose(a.vertices, b.vertices, atol=1e-3)
    assert torch.equal(loaded.faces, net.faces)
    state, cfg, _ = read_weights(path)
    assert cfg == config and state.keys() == net.state_dict().keys()
    with pytest.raises(ValueError, match="holds a network for 'rgbd'"):
        network_for("rgb", path)
    with pytest.raises(ValueError, match="hierarchy"):
        save_weights(tmp_path / "x.pt", net, net.config, {})
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(ValueError, match="not a footmesh reconstruction weights file"):
        load_network(tmp_path / "other.pt")
    with pytest.raises(FileNotFoundError):
        load_network(tmp_path / "missing.pt")


def run(net: ReconNet, rgb: torch.Tensor, depth: torch.Tensor | None, K: torch.Tensor):  # noqa: N803
    """The network's output for images and depth maps (its input kind picks what it uses)."""
    x, ref = recon_input(net.config.input, rgb, depth)
    return net(x, K, ref)
