"""Skin colours of the foot template: a small linear (PCA) model of FIND's per-vertex colours.

Asset ``skin_colours.npz`` (shipped in the package, built by :func:`footmesh.model.build_find.build_skin_colours`
from FIND's ``col`` output over its texture latents, shape and pose neutral; see ``data/PROVENANCE.md``):

    format_version ()        int
    mean (V, 3) float16      per-vertex mean RGB, 0..1, on the 4,002-vertex template
    components (K, V, 3)     float16, orthonormal as flattened (V*3,) vectors
    sd (K,) float32          SD of each component's coefficient
    provenance ()            str

FIND's scans cover light to medium skin only (per-foot mean luminance about 0.40-0.53); synthetic data that
needs darker or more varied tones must add them on top (e.g. a global tint).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

FORMAT_VERSION = 1
DEFAULT_ASSET = "skin_colours.npz"


@dataclass(frozen=True)
class SkinColours:
    """Per-vertex colour model: ``mean`` (V, 3), ``components`` (K, V, 3), ``sd`` (K,); RGB in 0..1."""

    mean: np.ndarray
    components: np.ndarray
    sd: np.ndarray
    provenance: str = ""

    def __post_init__(self) -> None:
        v, k = self.mean.shape[0], self.sd.shape[0]
        if self.mean.shape != (v, 3) or self.components.shape != (k, v, 3):
            raise ValueError(
                f"skin colours: mean {self.mean.shape}, components {self.components.shape}, sd {self.sd.shape}"
            )

    def __repr__(self) -> str:
        return f"SkinColours(V={self.mean.shape[0]}, K={self.sd.shape[0]})"


def load_skin_colours(path: str | os.PathLike | None = None) -> SkinColours:
    """Load the skin colour model (the packaged one when ``path`` is None), as float32 arrays."""
    if path is None:
        ref = resources.files("footmesh.model").joinpath("data", DEFAULT_ASSET)
        data, source = ref.read_bytes(), str(ref)
    else:
        p = Path(path)
        if not p.is_file():
            raise FileNotFoundError(f"skin colour asset not found: {p}")
        data, source = p.read_bytes(), str(p)
    with np.load(io.BytesIO(data), allow_pickle=False) as npz:
        version = int(npz["format_version"]) if "format_version" in npz else -1
        if version != FORMAT_VERSION:
            raise ValueError(f"{source}: format_version {version}, this footmesh reads {FORMAT_VERSION}")
        return SkinColours(
            mean=npz["mean"].astype(np.float32),
            components=npz["components"].astype(np.float32),
            sd=npz["sd"].astype(np.float32),
            provenance=str(npz["provenance"]),
        )


def sample_skin_colours(rng: np.random.Generator, n: int, colours: SkinColours | None = None) -> np.ndarray:
    """Random per-vertex skin colours: ``mean + sum_k c_k sd_k component_k``, c ~ N(0, 1), clipped to 0..1.

    Args:
        rng: numpy Generator (the caller owns the seed).
        n: number of feet.
        colours: the model (default: the packaged asset).

    Returns:
        (n, V, 3) float32 RGB in 0..1, on the footmesh template.
    """
    model = load_skin_colours() if colours is None else colours
    k = model.sd.shape[0]
    coeffs = rng.standard_normal((n, k)) * model.sd  # (n, K)
    flat = coeffs @ model.components.reshape(k, -1).astype(np.float64)  # (n, 3V)
    out = model.mean.astype(np.float64) + flat.reshape(n, *model.mean.shape)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def save_skin_colours(colours: SkinColours, path: str | os.PathLike) -> None:
    """Write the skin colour asset (float16 mean and components)."""
    from footmesh.report import write_npz

    write_npz(
        path,
        {
            "format_version": np.array(FORMAT_VERSION),
            "mean": colours.mean.astype(np.float16),
            "components": colours.components.astype(np.float16),
            "sd": colours.sd.astype(np.float32),
            "provenance": np.array(colours.provenance),
        },
    )
