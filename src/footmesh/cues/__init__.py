"""2D cues of a foot photo: silhouette, 18 joints with confidences (``net``, ``predict``) and reference objects."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Cues:
    """What the cues stage hands on, in the pixels of the photo it was given (centre of the top-left pixel = (0, 0)).

    ``silhouette``: (H, W) float32 probability that the pixel shows the foot (not the leg);
    ``joints2d_px``: (18, 2) float32 joint positions (DESIGN.md joint order), may lie outside the image;
    ``joint_confidence``: (18,) float32 in [0, 1], the predicted probability that the joint is visible;
    ``input``: which network produced them (``"rgb"``, ``"rgbd"``, ``"depth"``);
    ``right_probability``: the network's probability that the foot it was shown is a right foot (None for networks
    without a left/right head).
    """

    silhouette: np.ndarray
    joints2d_px: np.ndarray
    joint_confidence: np.ndarray
    input: str
    right_probability: float | None = None

    def __post_init__(self) -> None:
        if self.silhouette.ndim != 2:
            raise ValueError(f"silhouette must be (H, W), got {self.silhouette.shape}")
        if self.joints2d_px.shape != (18, 2) or self.joint_confidence.shape != (18,):
            raise ValueError(
                f"joints2d_px must be (18, 2) and joint_confidence (18,), got "
                f"{self.joints2d_px.shape} and {self.joint_confidence.shape}"
            )

    @property
    def mask(self) -> np.ndarray:
        """(H, W) bool: the silhouette thresholded at 0.5."""
        return self.silhouette >= 0.5
