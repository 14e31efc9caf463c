"""Principal component analysis of registered meshes (same topology), pure numpy.

Used for the FIND-derived model (:mod:`footmesh.model.build_find`) and for models rebuilt from registered scans.
"""

from __future__ import annotations

import numpy as np


def fit_pca(
    samples: np.ndarray, variance: float = 0.995, max_components: int | None = None, min_components: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """PCA of meshes by SVD of the centred data matrix.

    Keeps the fewest components whose cumulative explained variance reaches ``variance`` (then at least
    ``min_components`` and at most ``max_components``). Signs are fixed deterministically: each component's
    largest-magnitude coordinate is positive.

    Args:
        samples: (N, V, 3) vertices, any units (mm for footmesh); N >= 2.
        variance: fraction of the total variance to keep, in (0, 1].
        max_components: upper bound on the number kept (default: no bound besides N - 1).
        min_components: lower bound on the number kept.

    Returns:
        mean (V, 3), components (K, V, 3) orthonormal as flattened (V*3,) vectors, sd (K,) standard deviation
        of each component's coefficient (same units as ``samples``, ddof = 1), explained_ratio (K,) fraction of
        the total variance each explains. All float64.
    """
    x = np.asarray(samples, dtype=np.float64)
    if x.ndim != 3 or x.shape[2] != 3 or x.shape[0] < 2:
        raise ValueError(f"expected samples of shape (N, V, 3) with N >= 2, got {x.shape}")
    if not 0.0 < variance <= 1.0:
        raise ValueError(f"variance must be in (0, 1], got {variance}")
    n, v, _ = x.shape
    mean = x.mean(axis=0)
    centred = (x - mean).reshape(n, v * 3)  # (N, 3V)
    _, s, vt = np.linalg.svd(centred, full_matrices=False)  # vt: (min(N, 3V), 3V)
    var = s**2 / (n - 1)
    total = var.sum()
    if total <= 0:
        raise ValueError("samples have no variance")
    ratio = var / total
    k = int(np.searchsorted(np.cumsum(ratio), variance - 1e-12) + 1)
    k = max(k, min_components)
    k = min(k, len(s) if max_components is None else max_components, len(s))
    comps = vt[:k]
    signs = np.sign(comps[np.arange(k), np.argmax(np.abs(comps), axis=1)])
    comps = comps * signs[:, None]
    return mean, comps.reshape(k, v, 3), np.sqrt(var[:k]), ratio[:k]


def project(samples: np.ndarray, mean: np.ndarray, components: np.ndarray) -> np.ndarray:
    """Coefficients (N, K) of meshes (N, V, 3) in the basis (orthonormal projection; same units as the data)."""
    x = np.asarray(samples, dtype=np.float64)
    k = components.shape[0]
    return (x - mean).reshape(len(x), -1) @ np.asarray(components, dtype=np.float64).reshape(k, -1).T


def reconstruct(coefficients: np.ndarray, mean: np.ndarray, components: np.ndarray) -> np.ndarray:
    """Meshes (N, V, 3) from coefficients (N, K): ``mean + coefficients @ components``."""
    c = np.asarray(coefficients, dtype=np.float64)
    k = components.shape[0]
    flat = c @ np.asarray(components, dtype=np.float64).reshape(k, -1)
    return np.asarray(mean, dtype=np.float64) + flat.reshape(len(c), *mean.shape)


def mean_vertex_error(samples: np.ndarray, mean: np.ndarray, components: np.ndarray) -> float:
    """Mean Euclidean vertex error of reconstructing ``samples`` (N, V, 3) by projection onto the basis."""
    x = np.asarray(samples, dtype=np.float64)
    rec = reconstruct(project(x, mean, components), mean, components)
    return float(np.linalg.norm(rec - x, axis=-1).mean())
