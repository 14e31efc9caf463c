"""Running the 2D-cues network on images of any size (``footmesh.cues.predict``), and the shipped networks."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from footmesh.config import CuesNetConfig
from footmesh.cues import Cues
from footmesh.cues.inputs import network_input
from footmesh.cues.net import CuesNet
from footmesh.cues.predict import (
    MIRROR_AVERAGED_INPUTS,
    joints_to_image,
    predict_cues,
    resize_inputs,
    turned,
    turned_back,
)
from footmesh.cues.weights import save_weights
from footmesh.train.data import resize_joints

SIZE = 64
WIDTHS = (8, 8, 16, 16)

# Accuracy the shipped networks must reach on fresh synthetic scenes at 224 x 224 (the thesis' image side).
# The thesis reports mean joint errors of about 5-9 px (Table 4.2) for its 3-stack network; these bounds leave
# room for our one narrow stack and for 8 scenes' sampling noise, and fail clearly for an untrained or broken
# network (an untrained one is off by 40+ px, a half-pixel convention slip shows in the silhouette IoU).
MAX_JOINT_PX = {"rgbd": 12.0, "depth": 12.0, "rgb": 16.0}
"""Mean joint error, px of a 224 image, over the joints projecting inside it."""
MIN_SILHOUETTE_IOU = {"rgb": 0.75, "rgbd": 0.85, "depth": 0.85}
"""Mean intersection over union of the predicted (>= 0.5) and true silhouettes."""
ACCURACY_SCENES = 8
ACCURACY_SEED = 777
"""Not a seed any shipped network was trained on (training: 1; test folders: 2, 3)."""


@pytest.fixture(autouse=True)
def _one_thread():
    torch.set_num_threads(1)


@settings(max_examples=60, deadline=None)
@given(
    st.integers(16, 2000),
    st.integers(16, 2000),
    st.sampled_from([64, 128, 224]),
    st.lists(st.floats(-50, 2100, allow_nan=False), min_size=36, max_size=36),
)
def test_joints_to_image_inverts_the_resize_mapping(width, height, size, values):
    joints = np.asarray(values, np.float64).reshape(18, 2)
    net = np.stack([resize_joints(joints[:, 0], width, size), resize_joints(joints[:, 1], height, size)], -1)
    back = joints_to_image(net, size, width, height)
    assert back.dtype == np.float32 and back.shape == (18, 2)
    np.testing.assert_allclose(back, joints, rtol=1e-6, atol=1e-3)


def test_joints_to_image_follows_image_content_of_a_non_square_image():
    width, height, size = 300, 180, 64
    image = np.zeros((height, width, 3), np.uint8)
    dots = np.array([[40.0, 30.0], [251.0, 150.0], [150.0, 90.0]])  # (x, y) of 5x5 blocks' centres
    for x, y in dots.astype(int):
        image[y - 2 : y + 3, x - 2 : x + 3] = 255
    small, _ = resize_inputs(image, None, size)
    grey = small.astype(np.float64).mean(-1)
    ys, xs = np.mgrid[:size, :size]
    for x, y in dots:
        # where the dot lands in the network input (area-averaged), mapped back
        nx, ny = x * size / width, y * size / height
        w = grey * ((np.abs(xs - nx) < 4) & (np.abs(ys - ny) < 4))
        centroid = np.array([[(xs * w).sum(), (ys * w).sum()]]) / w.sum()
        np.testing.assert_allclose(joints_to_image(centroid, size, width, height)[0], [x, y], atol=0.5)


@pytest.fixture(scope="module")
def tiny_weights(tmp_path_factory) -> dict[str, str]:
    """Untrained tiny networks of each input kind, saved as weights files."""
    folder = tmp_path_factory.mktemp("cues-weights")
    paths = {}
    for kind in ("rgb", "rgbd", "depth"):
        config = CuesNetConfig(input=kind, image_size=SIZE, widths=WIDTHS)
        torch.manual_seed(0)
        model = CuesNet(config).eval()
        paths[kind] = str(folder / f"{kind}.pt")
        save_weights(paths[kind], model, config, {})
    return paths


def _photo(height: int, width: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    rgb = cv2.GaussianBlur(rng.integers(0, 256, (height, width, 3), dtype=np.uint8), (7, 7), 2)
    depth = rng.uniform(350, 450, (height, width)).astype(np.float32)
    depth[: height // 5] = 0  # missing
    return rgb, depth


@pytest.mark.parametrize("kind", ["rgb", "rgbd", "depth"])
def test_predict_cues_returns_cues_in_the_photos_pixels(tiny_weights, kind):
    from footmesh.cues.weights import load_network

    height, width = 90, 150
    rgb, depth = _photo(height, width)
    cues = predict_cues(
        kind, rgb if kind != "depth" else None, depth if kind != "rgb" else None, weights=tiny_weights[kind]
    )
    assert isinstance(cues, Cues) and cues.input == kind
    assert cues.silhouette.shape == (height, width) and cues.silhouette.dtype == np.float32
    assert 0 <= cues.silhouette.min() and cues.silhouette.max() <= 1
    assert cues.joints2d_px.shape == (18, 2) and cues.joints2d_px.dtype == np.float32
    assert cues.joint_confidence.shape == (18,)
    assert 0 <= cues.joint_confidence.min() and cues.joint_confidence.max() <= 1
    assert cues.mask.shape == (height, width) and cues.mask.dtype == bool
    # the joints are the network's, mapped from its square input to this photo's pixels
    model, config, _ = load_network(tiny_weights[kind])
    rgb_s, depth_s = resize_inputs(rgb, depth, SIZE)
    t_rgb = torch.from_numpy(rgb_s).permute(2, 0, 1)[None].float() / 255
    t_depth = torch.from_numpy(depth_s)[None, None]
    x = network_input(kind, t_rgb, t_depth)
    with torch.no_grad():
        alone = joints_to_image(model(x)[-1].joints[0].numpy(), SIZE, width, height)
        want = alone
        if kind in MIRROR_AVERAGED_INPUTS:  # averaged with the mirror image's, flipped back
            mirrored = joints_to_image(model(x.flip(-1))[-1].joints[0].numpy(), SIZE, width, height)
            want = 0.5 * (alone + np.stack([width - 1 - mirrored[:, 0], mirrored[:, 1]], axis=1))
    np.testing.assert_allclose(cues.joints2d_px, want, atol=1e-4)
    # asked for it, any network answers for the image alone
    plain = predict_cues(
        kind,
        rgb if kind != "depth" else None,
        depth if kind != "rgb" else None,
        weights=tiny_weights[kind],
        mirror_average=False,
    )
    np.testing.assert_allclose(plain.joints2d_px, alone, atol=1e-4)
    assert (cues.joints2d_px[:, 0] >= -0.5).all() and (cues.joints2d_px[:, 0] <= width - 0.5).all()
    assert (cues.joints2d_px[:, 1] >= -0.5).all() and (cues.joints2d_px[:, 1] <= height - 0.5).all()
    # an RGB-D call ignores what its network does not use
    if kind == "rgb":
        other = predict_cues(kind, rgb, depth, weights=tiny_weights[kind])
        np.testing.assert_array_equal(other.joints2d_px, cues.joints2d_px)


def test_predict_cues_refuses_bad_input(tiny_weights):
    rgb, depth = _photo(90, 150)
    with pytest.raises(ValueError, match="150x90"):
        predict_cues("rgbd", rgb, depth[:, :100], weights=tiny_weights["rgbd"])
    with pytest.raises(ValueError, match="image, a depth map, or both"):
        predict_cues("rgbd", weights=tiny_weights["rgbd"])
    with pytest.raises(ValueError, match="needs a depth map"):
        predict_cues("rgbd", rgb, weights=tiny_weights["rgbd"])
    with pytest.raises(ValueError, match="needs an RGB image"):
        predict_cues("rgb", None, depth, weights=tiny_weights["rgb"])
    with pytest.raises(ValueError, match="'rgbd'"):  # weights of another kind of network
        predict_cues("depth", None, depth, weights=tiny_weights["rgbd"])


# --- the shipped networks ---------------------------------------------------------------------------------------


def _shipped(kind: str) -> str:
    from footmesh.cues.weights import _read, packaged_weights

    path = packaged_weights(kind)  # shipped: a missing file fails the test, it is not skipped
    assert _read(path)["info"]["validation"], f"shipped {kind} weights were saved before their first validation"
    return str(path)


@pytest.fixture(scope="module")
def fresh_scenes() -> list[dict]:
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    renderer = Renderer(SynthConfig(size=224))
    return [renderer.render(ACCURACY_SEED, i) for i in range(ACCURACY_SCENES)]


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["rgbd", "depth", "rgb"])
def test_shipped_networks_find_silhouettes_and_joints_of_fresh_scenes(kind, request):
    path = _shipped(kind)
    scenes = request.getfixturevalue("fresh_scenes")
    errors, ious = [], []
    for scene in scenes:
        cues = predict_cues(
            kind,
            scene["rgb"] if kind != "depth" else None,
            scene["depth"].astype(np.float32) if kind != "rgb" else None,
            weights=path,
        )
        truth = scene["joints2d"]
        inside = ((truth >= -0.5) & (truth <= 223.5)).all(-1)
        errors.extend(np.linalg.norm(cues.joints2d_px - truth, axis=-1)[inside])
        sil = scene["silhouette"]
        ious.append((cues.mask & sil).sum() / max((cues.mask | sil).sum(), 1))
    mean_error, mean_iou = float(np.mean(errors)), float(np.mean(ious))
    assert mean_error <= MAX_JOINT_PX[kind], f"{kind}: mean joint error {mean_error:.2f} px"
    assert mean_iou >= MIN_SILHOUETTE_IOU[kind], f"{kind}: silhouette IoU {mean_iou:.3f}"


@pytest.mark.slow
def test_the_rgb_network_answers_a_mirrored_photo_with_the_mirror_of_its_answer(request):
    # the image and its mirror average to one answer: the symmetry the flip augmentation taught, held exactly
    assert "rgb" in MIRROR_AVERAGED_INPUTS
    path = _shipped("rgb")
    scene = request.getfixturevalue("fresh_scenes")[1]["rgb"][:, 20:]  # not square: x -> W - 1 - x is tested
    width = scene.shape[1]
    cues = predict_cues("rgb", scene, weights=path)
    mirrored = predict_cues("rgb", np.ascontiguousarray(scene[:, ::-1]), weights=path)
    np.testing.assert_allclose(mirrored.silhouette, cues.silhouette[:, ::-1], atol=1e-5)
    flipped = cues.joints2d_px.copy()
    flipped[:, 0] = width - 1 - flipped[:, 0]
    np.testing.assert_allclose(mirrored.joints2d_px, flipped, atol=1e-3)
    np.testing.assert_allclose(mirrored.joint_confidence, cues.joint_confidence, atol=1e-5)
    assert mirrored.right_probability == pytest.approx(1.0 - cues.right_probability, abs=1e-6)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 7), st.integers(3, 12), st.integers(3, 12), st.data())
def test_cues_of_a_turned_image_turned_back_land_on_the_pixels_before_the_turn(quarter_turns, height, width, data):
    y, x = data.draw(st.integers(0, height - 1)), data.draw(st.integers(0, width - 1))
    image = np.zeros((height, width), np.float32)
    image[y, x] = 1.0
    after = turned(image, quarter_turns)
    ty, tx = np.argwhere(after == 1.0)[0]  # where the turn took the pixel
    joints = np.tile(np.array([[tx, ty]], np.float32), (18, 1))
    back = turned_back(Cues(after, joints, np.ones(18, np.float32), "rgb"), quarter_turns)
    np.testing.assert_array_equal(back.silhouette, image)
    np.testing.assert_allclose(back.joints2d_px, np.tile([[x, y]], (18, 1)))
