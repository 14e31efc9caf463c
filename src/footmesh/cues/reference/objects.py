"""What the detector returns: a reference object found (and the floor it gives), or why none was taken."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from footmesh.geometry.camera import pixel_rays


@dataclass(frozen=True)
class ReferenceObject:
    """A reference object found on the floor, and the floor plane it gives.

    ``kind``: a ``references.NAMES`` entry; ``corners_px``: (4, 2) float64 px of the rectangle's corners in
    the order local (0, 0), (L, 0), (L, W), (0, W) (marker: its black square, the first corner at the bottom left
    of the pattern read upright; sheet and card: of the two possible starts, the one nearer the camera);
    ``size_mm``: (L, W); ``cam_from_floor``: (4, 4) floor frame (mm, origin at corner 0, x along L, z up out of
    the floor) -> camera frame (mm); ``reprojection_px``: RMS distance between ``corners_px`` and the rectangle
    projected with the pose; ``corner_sd_px``: estimated SD of a corner's position (from the line fits);
    ``fit_rel_sd``: relative SD of the camera-to-object distance from the corners' noise alone;
    ``scale_rel_sd``: the same with the object's size tolerance (``SIZE_REL_SD``) added, the relative SD of every
    length measured through this plane; ``K`` (3, 3): the intrinsics the pose was solved with (the caller's, or,
    where their focal length was a guess, with the focal length the rectangle's perspective gives:
    ``focal.focal_estimate``); ``focal_log_sd``: the SD of that focal length's log (0: the caller's, held; a
    sheet completed across a hidden corner keeps the caller's focal length and its SD); ``mirrored``: the marker
    was read in the mirror image; ``beyond_edge``: a sheet with one side beyond the photo's edge, its two corners
    there placed from its other sides and its size (``cut``; the focal length held, and its SD's effect on the
    scale counted in ``scale_rel_sd``); ``corner_beyond_edge``: a sheet with one corner beyond the photo's edge, placed
    where the lines of its two sides running there meet (its proportions and perspective still seen);
    ``kind_assumed``: a sheet whose proportions were not seen (completed across
    a hidden corner, or cut by the photo's edge), taken to be the most preferred sheet searched
    (``params.assumed_sheet``): a sheet of another size would give other millimetres.
    """

    kind: str
    corners_px: np.ndarray
    size_mm: tuple[float, float]
    cam_from_floor: np.ndarray
    reprojection_px: float
    corner_sd_px: float
    fit_rel_sd: float
    scale_rel_sd: float
    K: np.ndarray
    focal_log_sd: float = 0.0
    mirrored: bool = False
    beyond_edge: bool = False
    corner_beyond_edge: bool = False
    kind_assumed: bool = False

    @property
    def floor_normal(self) -> np.ndarray:
        """(3,) unit normal of the floor in the camera frame, pointing up out of the floor (towards the camera)."""
        return self.cam_from_floor[:3, 2].copy()

    @property
    def floor_distance_mm(self) -> float:
        """Distance (mm) from the camera centre to the floor plane."""
        return float(-self.floor_normal @ self.cam_from_floor[:3, 3])

    @property
    def centre_mm(self) -> np.ndarray:
        """(3,) the object's centre, camera frame, mm."""
        length, width = self.size_mm
        return self.cam_from_floor[:3, :3] @ [length / 2, width / 2, 0.0] + self.cam_from_floor[:3, 3]

    @property
    def object_distance_mm(self) -> float:
        """Distance (mm) from the camera centre to the object's centre."""
        return float(np.linalg.norm(self.centre_mm))

    def floor_points(self, points_px: np.ndarray, K: np.ndarray) -> np.ndarray:
        """(N, 2) px -> (N, 3) mm: where the pixels' rays meet the floor, in the floor frame (z = 0); NaN if never."""
        pts = np.asarray(points_px, dtype=np.float64).reshape(-1, 2)
        rays = pixel_rays(pts, K)  # camera frame, z = 1
        rot, trans = self.cam_from_floor[:3, :3], self.cam_from_floor[:3, 3]
        normal = rot[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = (normal @ trans) / (rays @ normal)
        floor = (rays * depth[:, None] - trans) @ rot  # R^T (p - t)
        floor[~(depth > 0)] = np.nan
        floor[:, 2] = np.where(np.isfinite(floor[:, 0]), 0.0, np.nan)
        return floor


@dataclass(frozen=True)
class ReferenceSearch:
    """What the search for a reference object saw: the object found (None when none is convincing) and, when none
    was, why the most sheet-like candidate was not taken (``rejected``, in words; None when nothing looked like
    a reference object) and how much of the photo it covered (``rejected_area``, a fraction)."""

    found: ReferenceObject | None
    rejected: str | None = None
    rejected_area: float = 0.0
