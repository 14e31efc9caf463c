"""The foot model asset: one versioned ``.npz`` shipped in the package, loaded read-only.

Keys (all lengths in mm, foot frame, left foot):
    format_version ()                 int, bumped when keys change
    mean_vertices (V, 3) float32       PCA mean shape, canonical (zero) pose
    components (K, V, 3) float32       orthonormal PCA directions (as flattened (V*3,) vectors)
    component_sd (K,) float32          standard deviation of each component, mm
    explained_variance_ratio (K,)      float32
    faces (F, 3) int32                 triangles, counter-clockwise seen from outside (left foot)
    landmark_names (L,) str            named surface landmarks (heel, toe tips, ball extrema, ...)
    landmark_vertices (L,) int32       their vertex ids
    joint_regressor (18, V) float32    rest joints = joint_regressor @ vertices (vertex groups, rows sum to 1)
    skin_weights (V, 18) float32       linear-blend-skinning weights, rows sum to 1 (column j = segment ending at j)
    provenance ()                      str, how the asset was made
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass, fields
from importlib import resources
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1
DEFAULT_ASSET = "foot_model.npz"


@dataclass(frozen=True)
class FootModelAsset:
    """Arrays of the foot model; see the module docstring for shapes and units."""

    mean_vertices: np.ndarray
    components: np.ndarray
    component_sd: np.ndarray
    explained_variance_ratio: np.ndarray
    faces: np.ndarray
    landmark_names: np.ndarray
    landmark_vertices: np.ndarray
    joint_regressor: np.ndarray
    skin_weights: np.ndarray
    provenance: str = ""

    def __post_init__(self) -> None:
        v = self.mean_vertices.shape[0]
        k = self.component_sd.shape[0]
        checks = {
            "mean_vertices": (self.mean_vertices.shape, (v, 3)),
            "components": (self.components.shape, (k, v, 3)),
            "explained_variance_ratio": (self.explained_variance_ratio.shape, (k,)),
            "joint_regressor": (self.joint_regressor.shape, (18, v)),
            "skin_weights": (self.skin_weights.shape, (v, 18)),
            "landmark_vertices": (self.landmark_vertices.shape, self.landmark_names.shape),
        }
        for name, (got, want) in checks.items():
            if got != want:
                raise ValueError(f"foot model asset: {name} has shape {got}, expected {want}")
        if self.faces.ndim != 2 or self.faces.shape[1] != 3 or self.faces.max() >= v:
            raise ValueError(f"foot model asset: faces of shape {self.faces.shape} do not index {v} vertices")

    @property
    def num_vertices(self) -> int:
        return int(self.mean_vertices.shape[0])

    @property
    def num_components(self) -> int:
        return int(self.component_sd.shape[0])

    def landmarks(self) -> dict[str, int]:
        """Landmark name -> vertex id."""
        return {str(n): int(i) for n, i in zip(self.landmark_names, self.landmark_vertices, strict=True)}

    def __repr__(self) -> str:
        return (
            f"FootModelAsset(V={self.num_vertices}, F={len(self.faces)}, K={self.num_components}, "
            f"landmarks={len(self.landmark_names)})"
        )


def load_asset(path: str | os.PathLike | None = None) -> FootModelAsset:
    """Load the foot model asset (the packaged one when ``path`` is None)."""
    if path is None:
        ref = resources.files("footmesh.model").joinpath("data", DEFAULT_ASSET)
        data = ref.read_bytes()
        source = str(ref)
    else:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"foot model asset not found: {p}")
        data = p.read_bytes()
        source = str(p)
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        version = int(npz["format_version"]) if "format_version" in npz else -1
        if version != FORMAT_VERSION:
            raise ValueError(f"{source}: format_version {version}, this footmesh reads {FORMAT_VERSION}")
        kwargs = {}
        for f in fields(FootModelAsset):
            if f.name not in npz:
                raise ValueError(f"{source}: missing key {f.name!r}; rebuild it with `make model`")
            value = npz[f.name]
            kwargs[f.name] = str(value) if f.name == "provenance" else value
    return FootModelAsset(**kwargs)


def save_asset(asset: FootModelAsset, path: str | os.PathLike) -> None:
    """Write the asset atomically; the bytes depend only on the arrays (``report.write_npz``)."""
    arrays = {f.name: getattr(asset, f.name) for f in fields(FootModelAsset)}
    arrays["provenance"] = np.array(asset.provenance)
    arrays["format_version"] = np.array(FORMAT_VERSION)
    from footmesh.report import write_npz

    write_npz(path, arrays)
