"""Cut a foot silhouette to where its own 18 joints say the foot can be: the shin and the floor beyond it are not.

Why: on real photos the networks take bare shins for feet (``../shared/real/rafiansyah``: the crop silhouette runs
up the leg to the photo's edge), while their joints stay on the foot (toes on the toes, the heel and ankle where
they are). The joints bound the foot's image: a box along the heel -> toes axis, from ``behind_heel`` behind the
heel joint to ``past_toes`` past the farthest toe tip, ``across`` to either side, each a fraction of the foot's
image size S = max(L, ``width_to_length`` W) (L: heel to farthest toe tip along the axis; W: the big toe's to the
little toe's first joint, which a view from in front of the toes does not foreshorten as it does L).

The fractions are the largest that the foot model's own projection reaches on renders (``TrimConfig``), so the
cut never removes what the fit could place there: it only removes what lies beyond any foot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from footmesh.model import skeleton as sk

_HEEL = sk.HEEL_BRANCH[1]
_BIG_TOE_MTP, _LITTLE_TOE_MTP = sk.TOE_BRANCHES[0][0], sk.TOE_BRANCHES[-1][0]


@dataclass(frozen=True)
class TrimConfig:
    """How far past its joints a foot's image can reach, as fractions of its image size S (module docstring).

    Measured on renders (every vertex of the foot model, leg cap included, projected, in the frame of the true
    joints; ``benchmarks/bench_trim.py``, 200 photos per view set guided, front, ood, tele, front_tele): the most
    any reached, plus about 0.1 for the networks' joint error.
    """

    behind_heel: float = 0.8
    """Behind the heel joint, along the axis (the leg cap of a foot seen from in front of its toes reaches 0.58,
    a lifted and posed foot seen from close 0.72)."""
    past_toes: float = 0.6
    """Past the farthest toe tip, along the axis (0.07 in the guided views; toes curled up seen from close 0.49)."""
    across: float = 1.0
    """To either side of the axis (the ankle cap of a foot seen from its side: 0.73; lifted feet 0.84)."""
    width_to_length: float = 2.5
    """S = max(L, this x W): the foot's length in the image is at least 3.3 W in the guided views (median 4.3) and
    at least 2.4 W in the front views, where L shortens and W does not."""
    min_size_px: float = 8.0
    """Joints spread over less than this (px) say nothing about where the foot ends: no cut."""


@dataclass(frozen=True)
class FootAxes:
    """A foot's image frame from its joints: ``heel`` (2,) px, unit ``axis`` (2,) heel -> toes, ``length`` px
    (heel to farthest toe tip along the axis) and ``size`` px (S, the unit of ``TrimConfig``)."""

    heel: np.ndarray
    axis: np.ndarray
    length: float
    size: float

    def coordinates(self, x_px: np.ndarray, y_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(along, across) of the points (x_px, y_px) (arrays that broadcast together), in units of ``size``: along
        the axis from the heel, and the unsigned distance from the axis."""
        dx = (np.asarray(x_px, dtype=np.float32) - np.float32(self.heel[0])) / np.float32(self.size)
        dy = (np.asarray(y_px, dtype=np.float32) - np.float32(self.heel[1])) / np.float32(self.size)
        ax, ay = np.float32(self.axis[0]), np.float32(self.axis[1])
        return dx * ax + dy * ay, np.abs(dy * ax - dx * ay)


def foot_axes(joints2d_px: np.ndarray, config: TrimConfig | None = None) -> FootAxes | None:
    """The image frame of the foot with joints (18, 2) px; None when they are too close together (or not finite)
    to tell."""
    config = config if config is not None else TrimConfig()
    joints = np.asarray(joints2d_px, dtype=np.float64)
    heel = joints[_HEEL]
    axis = joints[list(sk.TOE_TIPS)].mean(axis=0) - heel
    norm = float(np.linalg.norm(axis))
    if not np.all(np.isfinite(joints)) or norm < config.min_size_px:
        return None
    axis /= norm
    length = float(((joints[list(sk.TOE_TIPS)] - heel) @ axis).max())
    width = float(np.linalg.norm(joints[_BIG_TOE_MTP] - joints[_LITTLE_TOE_MTP]))
    return FootAxes(heel, axis, length, max(length, config.width_to_length * width))


def foot_region(shape: tuple[int, int], joints2d_px: np.ndarray, config: TrimConfig | None = None) -> np.ndarray:
    """(H, W) bool: the pixels of an image of ``shape`` (H, W) where the foot with joints (18, 2) px can be; all
    True when the joints are too close together to tell."""
    config = config if config is not None else TrimConfig()
    axes = foot_axes(joints2d_px, config)
    if axes is None:
        return np.ones(shape, dtype=bool)
    along, across = axes.coordinates(np.arange(shape[1])[None, :], np.arange(shape[0])[:, None])
    toes = axes.length / axes.size
    return (along >= -config.behind_heel) & (along <= toes + config.past_toes) & (across <= config.across)


def trim_silhouette(silhouette: np.ndarray, joints2d_px: np.ndarray, config: TrimConfig | None = None) -> np.ndarray:
    """(H, W) float32: the foot probability ``silhouette`` (H, W) set to 0 where its joints (18, 2) px say no foot
    can be (``foot_region``)."""
    keep = foot_region(silhouette.shape, joints2d_px, config)
    return np.where(keep, silhouette, 0.0).astype(np.float32)
