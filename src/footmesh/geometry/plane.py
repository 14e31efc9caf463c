"""Planes: a robust least-squares plane through 3D points, and the floor frame of a plane seen by a camera.

Written by hand: a trimmed least-squares refit is a few lines of NumPy, where a RANSAC library would bring a
dependency for the same answer on the mostly-floor point sets it is given here.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Plane:
    """A plane through ``centre`` (3,) with unit ``normal`` (3,); ``inliers`` (N,) bool marks the points it fits."""

    centre: np.ndarray
    normal: np.ndarray
    inliers: np.ndarray

    def height(self, points: np.ndarray) -> np.ndarray:
        """Signed distances (...,) of ``points`` (..., 3) along the normal, in the points' units."""
        return (points - self.centre) @ self.normal


def robust_plane(
    points: np.ndarray, rounds: int = 5, min_tolerance: float = 2.0, min_inliers: int = 100
) -> Plane | None:
    """The plane of most of ``points`` (N, 3): least squares, then ``rounds`` refits on the points within 3 robust
    SDs (median absolute deviation, at least ``min_tolerance``) of the last plane, so that the points of other
    things (a leg, a chair) drop out. None when fewer than ``min_inliers`` points stay."""
    if rounds < 1:
        raise ValueError(f"rounds must be at least 1, got {rounds}")
    if len(points) < min_inliers:
        return None
    keep = np.ones(len(points), bool)
    for _ in range(rounds):
        centre = points[keep].mean(axis=0)
        normal = np.linalg.svd(points[keep] - centre, full_matrices=False)[2][2]
        distance = (points - centre) @ normal
        keep = np.abs(distance) < max(3.0 * 1.4826 * float(np.median(np.abs(distance[keep]))), min_tolerance)
        if keep.sum() < min_inliers:
            return None
    return Plane(centre, normal, keep)


def cam_from_plane(plane: Plane) -> np.ndarray:
    """(4, 4) rigid transform from a frame on ``plane`` (origin at its centre, z along the normal turned towards
    the camera at the origin, x and y in the plane) to the camera frame."""
    z = plane.normal if float(plane.centre @ plane.normal) < 0 else -plane.normal
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    pose[:3, 3] = plane.centre
    return pose
