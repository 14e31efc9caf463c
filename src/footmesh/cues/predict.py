"""Running the 2D-cues network on images of any size and mapping its outputs back to their pixels."""

from __future__ import annotations

import os
from dataclasses import replace

import cv2
import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

from footmesh.config import CuesNetConfig
from footmesh.cues import Cues
from footmesh.cues.inputs import network_input
from footmesh.cues.weights import network_for
from footmesh.geometry.camera import rescale_pixels, turned_pixels

MIRROR_AVERAGED_INPUTS: tuple[str, ...] = ("rgb", "depth")
"""Inputs whose network sees each image and its mirror image, and answers their average (``predict_batch``'s
``mirror_average``). A mirrored left foot is a right foot with the same joints, and the networks were trained on
both (their flip augmentation), so averaging holds their answer to that symmetry. RGB: on the real photos of
``../shared/real/rafiansyah`` the side came out right on 87.9 % of feet instead of 80.5 % (crop IoU 0.587 -> 0.599),
and ``eval measure --modes rgb_ref`` (60 photos each) went from 3.54 / 2.49 to 3.50 / 2.28 mm length / width on guided
seed 4242, 4.51 / 3.06 to 4.01 / 2.76 on seed 777 and 8.04 / 1.20 to 6.81 / 1.27 on the front views (one photo
fewer measured), for one more image in the network's batch. Depth, on depth-alone photos (``--modes depth``): guided
4242 / 777 length 1.96 / 1.97 -> 1.66 / 1.76 mm, front 30 photos 4.06 -> 3.95. Not RGB-D: RGB-D photos, whose cues
average the RGB-D and depth networks', lost with either averaged (guided 4242 1.21 -> 1.31 mm with the depth network
averaged, 1.52 with both), so the pipeline asks the depth network for its plain answer there
(``predict_cues(mirror_average=False)``)."""


def resize_inputs(
    rgb: np.ndarray | None, depth_mm: np.ndarray | None, size: int
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Resize an (H, W, 3) uint8 image and an (H, W) mm depth map to ``size`` x ``size`` as in training
    (``footmesh.train.data.resize_sample``: area averaging for colour, nearest neighbour for depth)."""
    rgb_s = None if rgb is None else cv2.resize(rgb, (size, size), interpolation=cv2.INTER_AREA)
    depth_s = None
    if depth_mm is not None:
        depth_s = cv2.resize(np.asarray(depth_mm, np.float32), (size, size), interpolation=cv2.INTER_NEAREST)
    return rgb_s, depth_s


def joints_to_image(joints: np.ndarray, size: int, width: int, height: int) -> np.ndarray:
    """Network-input pixels (side ``size``) -> pixels of the ``width`` x ``height`` image it was resized from."""
    scale = np.array([width / size, height / size])
    return rescale_pixels(joints, scale).astype(np.float32)


@torch.no_grad()
def predict_batch(
    model: nn.Module,
    config: CuesNetConfig,
    rgb: np.ndarray | None,
    depth_mm: np.ndarray | None,
    out_size: tuple[int, int] | None = None,
    mirror_average: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Cues of a batch already at the network's side: ``rgb`` (B, S, S, 3) uint8, ``depth_mm`` (B, S, S).

    Returns the silhouette probability (B, H, W) at ``out_size`` = (W, H) (default S x S), the joints (B, 18, 2)
    in those pixels, each joint's confidence (B, 18), and the probability of a right foot (B,) (None for networks
    without a side head). ``mirror_average``: the average of the answers for each image and its mirror image
    (mapped back; a mirrored right foot is a left one), from one batch of 2B (``MIRROR_AVERAGED_INPUTS``).
    """
    t_rgb = None if rgb is None else torch.from_numpy(np.ascontiguousarray(rgb)).permute(0, 3, 1, 2).float() / 255
    t_depth = None if depth_mm is None else torch.from_numpy(np.asarray(depth_mm, np.float32))[:, None]
    x = network_input(config.input, t_rgb, t_depth)
    if mirror_average:
        x = torch.cat([x, x.flip(-1)])
    out = model(x)[-1]
    size = config.image_size
    width, height = out_size or (size, size)
    sil = torch.sigmoid(F.interpolate(out.silhouette_logits, size=(height, width), mode="bilinear"))[:, 0].numpy()
    joints = joints_to_image(out.joints.numpy(), size, width, height)
    conf = torch.sigmoid(out.visibility_logits).numpy()
    right = None if out.side_logits is None else torch.sigmoid(out.side_logits).numpy().astype(np.float64)
    if mirror_average:
        b = len(x) // 2
        sil = 0.5 * (sil[:b] + sil[b:, :, ::-1])
        mirrored = joints[b:].copy()
        mirrored[..., 0] = width - 1 - mirrored[..., 0]  # pixel centres: x -> W - 1 - x
        joints = 0.5 * (joints[:b] + mirrored)
        conf = 0.5 * (conf[:b] + conf[b:])
        right = None if right is None else 0.5 * (right[:b] + 1.0 - right[b:])
    return sil.astype(np.float32), joints.astype(np.float32), conf.astype(np.float32), right


def predict_cues(
    input_kind: str,
    rgb: np.ndarray | None = None,
    depth_mm: np.ndarray | None = None,
    weights: str | os.PathLike | None = None,
    image_size: int | None = None,
    mirror_average: bool | None = None,
) -> Cues:
    """Silhouette and joints of one image (H, W, 3) uint8 and/or depth map (H, W) mm, in its own pixels.

    The image should be framed on the foot (the networks were trained on views centred near the foot);
    the whole-photo pipeline crops around the foot first. ``image_size``: the side the image is resized to for
    the network (default the side it was trained at; a multiple of 32): a larger side for a photo in which the
    foot is smaller than in the training views keeps the foot's size in network pixels.
    """
    model, config = network_for(input_kind, weights)
    if image_size is not None:
        if image_size % 32 or image_size < 64:
            raise ValueError(f"image_size must be a multiple of 32 and at least 64, got {image_size}")
        config = replace(config, image_size=image_size)
    ref = rgb if rgb is not None else depth_mm
    if ref is None:
        raise ValueError("predict_cues needs an image, a depth map, or both")
    height, width = ref.shape[:2]
    if rgb is not None and depth_mm is not None and rgb.shape[:2] != depth_mm.shape[:2]:
        raise ValueError(f"image {rgb.shape[1]}x{rgb.shape[0]} and depth {depth_mm.shape[1]}x{depth_mm.shape[0]}")
    rgb_s, depth_s = resize_inputs(
        rgb if input_kind != "depth" else None, depth_mm if input_kind != "rgb" else None, config.image_size
    )
    sil, joints, conf, right = predict_batch(
        model,
        config,
        None if rgb_s is None else rgb_s[None],
        None if depth_s is None else depth_s[None],
        out_size=(width, height),
        mirror_average=input_kind in MIRROR_AVERAGED_INPUTS if mirror_average is None else mirror_average,
    )
    return Cues(
        silhouette=sil[0],
        joints2d_px=joints[0],
        joint_confidence=conf[0],
        input=input_kind,
        right_probability=None if right is None else float(right[0]),
    )


def right_probabilities(
    input_kind: str, rgbs: list[np.ndarray] | None = None, depths_mm: list[np.ndarray] | None = None
) -> np.ndarray | None:
    """The shipped ``input_kind`` network's probability that each image (H, W, 3) uint8 and/or depth map (H, W) mm
    shows a right foot (N,), from one batch; None for a network without a left/right head."""
    model, config = network_for(input_kind, None)
    count = len(rgbs if rgbs is not None else depths_mm)
    resized = [
        resize_inputs(
            None if rgbs is None or input_kind == "depth" else rgbs[i],
            None if depths_mm is None or input_kind == "rgb" else depths_mm[i],
            config.image_size,
        )
        for i in range(count)
    ]
    rgb_s = None if resized[0][0] is None else np.stack([r[0] for r in resized])
    depth_s = None if resized[0][1] is None else np.stack([r[1] for r in resized])
    return predict_batch(model, config, rgb_s, depth_s, mirror_average=input_kind in MIRROR_AVERAGED_INPUTS)[3]


def average_cues(cues: list[Cues]) -> Cues:
    """One ``Cues`` from several networks' cues of the same image: silhouette probabilities averaged, each joint
    averaged with its confidences as weights, confidences and side probabilities averaged; ``input`` names them
    all ("rgbd+depth")."""
    if not cues:
        raise ValueError("average_cues needs at least one Cues")
    shapes = {c.silhouette.shape for c in cues}
    if len(shapes) != 1:
        raise ValueError(f"cues of different image sizes cannot be averaged: {sorted(shapes)}")
    silhouette = np.mean([c.silhouette for c in cues], axis=0).astype(np.float32)
    conf = np.stack([c.joint_confidence for c in cues]).astype(np.float64)  # (N, 18)
    weights = conf + 1e-3  # joints no network is sure of: the plain mean
    joints = (weights[..., None] * np.stack([c.joints2d_px for c in cues])).sum(0) / weights.sum(0)[:, None]
    sides = [c.right_probability for c in cues if c.right_probability is not None]
    return Cues(
        silhouette=silhouette,
        joints2d_px=joints.astype(np.float32),
        joint_confidence=conf.mean(0).astype(np.float32),
        input="+".join(c.input for c in cues),
        right_probability=float(np.mean(sides)) if sides else None,
    )


def turned(image: np.ndarray | None, quarter_turns: int) -> np.ndarray | None:
    """An (H, W[, C]) image turned ``quarter_turns`` x 90 deg counter-clockwise (``np.rot90``), contiguous."""
    return None if image is None else np.ascontiguousarray(np.rot90(image, quarter_turns))


def turned_back(cues: Cues, quarter_turns: int) -> Cues:
    """Cues of an image turned ``quarter_turns`` x 90 deg counter-clockwise (``turned``) -> the same cues in the
    pixels of the image before the turn: the networks were trained with the leg rising towards the top of the
    image, and a photo held sideways shows them the leg across it."""
    silhouette = np.ascontiguousarray(np.rot90(cues.silhouette, -quarter_turns))
    height, width = silhouette.shape  # the image's before the turn
    back = np.linalg.inv(turned_pixels(width, height, quarter_turns))
    joints = cues.joints2d_px.astype(np.float64) @ back[:2, :2].T + back[:2, 2]
    return replace(cues, silhouette=silhouette, joints2d_px=joints.astype(np.float32))
