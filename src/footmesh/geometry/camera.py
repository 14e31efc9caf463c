"""Pinhole cameras in pixels: the centre of the top-left pixel is (0, 0), an image spans -0.5 .. W - 0.5.

``Camera`` is one image's camera (K and the image size) with its crops, resizes and projections; the functions
under it work on ``K``, the (..., 3, 3) intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` of an image,
as a NumPy array or a torch tensor; each function returns the same kind it is given.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def rescale_pixels(points_px: Any, factor: Any) -> Any:
    """Pixel coordinates (..., 2) of an image after resizing it by ``factor`` (a number, or (sx, sy)):
    ``p' + 0.5 = (p + 0.5) * factor``, as the image's extent scales, not its first pixel's centre."""
    return (points_px + 0.5) * factor - 0.5


def resize_intrinsics(K: Any, sx: float, sy: float | None = None) -> Any:  # noqa: N803
    """Intrinsics of an image resized by ``sx`` horizontally and ``sy`` (default ``sx``) vertically."""
    sy = sx if sy is None else sy
    k = K.clone() if hasattr(K, "clone") else np.array(K, dtype=np.float64, copy=True)
    k[..., 0, 0] *= sx
    k[..., 0, 1] *= sx
    k[..., 1, 1] *= sy
    k[..., 0, 2] = rescale_pixels(k[..., 0, 2], sx)
    k[..., 1, 2] = rescale_pixels(k[..., 1, 2], sy)
    return k


def crop_intrinsics(K: Any, x0: float, y0: float) -> Any:  # noqa: N803
    """Intrinsics of the crop whose top-left pixel is ``(x0, y0)``: the same camera, its principal point moved."""
    k = K.clone() if hasattr(K, "clone") else np.array(K, dtype=np.float64, copy=True)
    k[..., 0, 2] -= x0
    k[..., 1, 2] -= y0
    return k


def project(points: Any, K: Any, min_depth: float | None = None) -> tuple[Any, Any]:  # noqa: N803
    """Camera-frame points (..., N, 3) mm -> pixels (..., N, 2) and depths z (..., N) mm, for K (3, 3) or
    (..., 3, 3); ``min_depth``: divide by at least this (points behind the camera stay finite)."""
    h = points @ K.swapaxes(-1, -2)
    z = h[..., 2]
    divisor = z if min_depth is None else z.clip(min_depth, None)
    return h[..., :2] / divisor[..., None], z


def pixel_rays(points_px: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Rays (..., 3) through pixels (..., 2) of a camera K (3, 3), scaled to z = 1 (camera frame)."""
    points_px = np.asarray(points_px, dtype=np.float64)
    homogeneous = np.concatenate([points_px, np.ones(points_px.shape[:-1] + (1,))], axis=-1)
    rays = homogeneous @ np.linalg.inv(np.asarray(K, dtype=np.float64)).T
    return rays / rays[..., 2:3]


def unproject(points_px: np.ndarray, depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Camera-frame points (..., 3) of pixels (..., 2) at camera depths z (...,) (mm)."""
    return pixel_rays(points_px, K) * np.asarray(depth, dtype=np.float64)[..., None]


def turned_pixels(width: int, height: int, quarter_turns: int) -> np.ndarray:
    """(3, 3) map of homogeneous pixels of a ``width`` x ``height`` image to those of the image turned
    ``quarter_turns`` x 90 deg counter-clockwise (``np.rot90``): (x, y) -> (y, W - 1 - x) per turn."""
    pixels = np.eye(3)
    for _ in range(quarter_turns % 4):
        pixels = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, width - 1.0], [0.0, 0.0, 1.0]]) @ pixels
        width, height = height, width
    return pixels


def turned_frame(quarter_turns: int) -> np.ndarray:
    """(3, 3) rotation from a camera's frame to that of its image turned ``quarter_turns`` x 90 deg
    counter-clockwise (``Camera.turned``): x' = y, y' = -x per turn; points (N, 3) go back with ``p @ R``."""
    return np.linalg.matrix_power(np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), quarter_turns % 4)


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera of one image: intrinsics ``K`` (3, 3) px and the image's ``width`` x ``height`` px."""

    K: np.ndarray
    width: int
    height: int

    def resized(self, width: int, height: int) -> Camera:
        """The camera of this image resized to ``width`` x ``height`` px (each axis scaled on its own)."""
        return Camera(resize_intrinsics(self.K, width / self.width, height / self.height), int(width), int(height))

    def cropped(self, x0: float, y0: float, width: int, height: int) -> Camera:
        """The camera of the ``width`` x ``height`` crop whose top-left pixel is ``(x0, y0)`` (may reach past the
        image: a padded crop)."""
        return Camera(crop_intrinsics(self.K, x0, y0), int(width), int(height))

    def turned(self, quarter_turns: int) -> Camera:
        """The camera of this image turned ``quarter_turns`` x 90 deg counter-clockwise (``np.rot90``): pixel
        (x, y) goes to (y, W - 1 - x) per turn, and the camera frame with it (``turned_frame``)."""
        K = turned_pixels(self.width, self.height, quarter_turns) @ self.K @ turned_frame(quarter_turns).T
        width, height = (self.height, self.width) if quarter_turns % 2 else (self.width, self.height)
        return Camera(K, width, height)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Camera-frame points (..., 3) mm -> pixels (..., 2) and depths (...,) mm."""
        return project(np.asarray(points, dtype=np.float64), self.K)

    def rays(self, points_px: np.ndarray) -> np.ndarray:
        """Rays (..., 3) through pixels (..., 2), z = 1."""
        return pixel_rays(points_px, self.K)

    def unproject(self, points_px: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Camera-frame points (..., 3) of pixels (..., 2) at depths (...,) mm."""
        return unproject(points_px, depth, self.K)
