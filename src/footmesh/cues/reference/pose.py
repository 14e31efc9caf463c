"""Step 6's pose: the known rectangle's planar PnP, its camera distance, the shape's SD from the corners' noise."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np

from footmesh.cues.reference.objects import ReferenceObject
from footmesh.cues.reference.params import DISTANCE_RANGE_MM, SIZES_MM
from footmesh.cues.reference.quads import _parallelogram


def _object_points(kind: str) -> np.ndarray:
    """(4, 3) corners of the object's rectangle in the floor frame (mm), in local order."""
    length, width = SIZES_MM[kind]
    return np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]], dtype=np.float64)


def rectangle_pose(corners: np.ndarray, kind: str, K: np.ndarray) -> tuple[np.ndarray, float] | None:
    """``cam_from_floor`` (4, 4) mm and RMS reprojection (px) of the ``kind`` object's rectangle from its (4, 2) px
    corners in local order (IPPE, K (3, 3)); None when no pose puts it in front of the camera, facing it."""
    obj = _object_points(kind)
    ok, rvec, tvec = cv2.solvePnP(obj, corners.reshape(4, 1, 2), K, None, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        return None
    rot, _ = cv2.Rodrigues(rvec)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, tvec.ravel()
    # the floor's z must face the camera (the corners' order sees to it) and every corner lie in front of it
    if -(rot[:, 2] @ pose[:3, 3]) <= 0 or np.any((obj @ rot.T + pose[:3, 3])[:, 2] <= 0):
        return None
    proj, _ = cv2.projectPoints(obj, rvec, tvec, K, None)
    reproj = float(np.sqrt(np.mean(np.sum((proj.reshape(4, 2) - corners) ** 2, axis=1))))
    return pose, reproj


def placed(corners: np.ndarray, kind: str, K: np.ndarray) -> tuple[np.ndarray, float, float] | str:
    """The ``kind`` object's pose from its (4, 2) px corners in local order: (``cam_from_floor`` (4, 4), RMS
    reprojection px, camera-to-centre distance mm), or why there is none (in words): no pose, or one outside
    ``DISTANCE_RANGE_MM``."""
    solved = rectangle_pose(corners, kind, K)
    if solved is None:
        return "no pose of the object fits its corners"
    pose, reprojection = solved
    length, width = SIZES_MM[kind]
    distance = float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0.0] + pose[:3, 3]))
    if not DISTANCE_RANGE_MM[0] <= distance <= DISTANCE_RANGE_MM[1]:
        return f"it would lie {distance / 1000:.2f} m from the camera"
    return pose, reprojection, distance


def seen_with(found: ReferenceObject, K: np.ndarray, focal_log_sd: float) -> ReferenceObject | None:
    """``found`` as its corners give it through a camera of intrinsics K (3, 3) (another focal length): its pose
    solved again, ``focal_log_sd`` the new focal length's SD; None when no pose fits."""
    solved = rectangle_pose(found.corners_px, found.kind, K)
    if solved is None:
        return None
    pose, reprojection = solved
    return replace(
        found,
        K=np.array(K, dtype=np.float64),
        cam_from_floor=pose,
        reprojection_px=reprojection,
        focal_log_sd=focal_log_sd,
    )


def _distance(corners: np.ndarray, kind: str, K: np.ndarray) -> float:
    """Camera-to-object-centre distance (mm) implied by the corners (NaN when there is no pose)."""
    found = rectangle_pose(corners, kind, K)
    if found is None:
        return float("nan")
    pose = found[0]
    length, width = SIZES_MM[kind]
    return float(np.linalg.norm(pose[:3, :3] @ [length / 2, width / 2, 0.0] + pose[:3, 3]))


def _shape_sd(corners: np.ndarray, perturbed: list[np.ndarray], K: np.ndarray) -> tuple[float, float]:
    """SD of the log side ratio and of the corner angle (deg) of ``_parallelogram``, from the perturbed corners."""
    ratio, angle, _ = _parallelogram(corners, K)
    var_r = var_a = 0.0
    for trial in perturbed:
        shape = _parallelogram(trial, K)
        if shape is None:
            return float("inf"), float("inf")
        var_r += math.log(shape[0] / ratio) ** 2
        var_a += (shape[1] - angle) ** 2
    return math.sqrt(var_r), math.sqrt(var_a)
