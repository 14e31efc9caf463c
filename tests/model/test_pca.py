"""PCA: synthetic recovery, determinism, and the held-out reconstruction of FIND feet by the packaged model."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from footmesh.model.pca import fit_pca, mean_vertex_error, project, reconstruct

FIND_DIR = Path(__file__).resolve().parents[2] / ".." / "shared" / "find"


def _low_rank(rng: np.random.Generator, n: int = 200, v: int = 50, rank: int = 3, noise: float = 0.0):
    basis, _ = np.linalg.qr(rng.standard_normal((v * 3, rank)))  # (3V, rank) orthonormal
    sd = np.array([5.0, 2.0, 0.5])[:rank]
    coeffs = rng.standard_normal((n, rank)) * sd
    mean = rng.standard_normal((v, 3)) * 10
    x = mean + (coeffs @ basis.T).reshape(n, v, 3) + noise * rng.standard_normal((n, v, 3))
    return x, mean, basis, sd


def test_fit_pca_recovers_low_rank_data():
    x, mean, basis, sd = _low_rank(np.random.default_rng(0))
    m, comps, s, ratio = fit_pca(x, variance=0.999999)
    assert comps.shape == (3, 50, 3)
    np.testing.assert_allclose(m, x.mean(axis=0))
    flat = comps.reshape(3, -1)
    np.testing.assert_allclose(flat @ flat.T, np.eye(3), atol=1e-10)
    # same subspace: projecting the true basis onto the fitted one loses nothing
    np.testing.assert_allclose(np.linalg.norm(flat @ basis, axis=0), 1.0, atol=1e-8)
    np.testing.assert_allclose(s, sd, rtol=0.2)  # sample SDs of 200 draws
    assert ratio.sum() == pytest.approx(1.0)
    assert mean_vertex_error(x, m, comps) < 1e-9


def test_fit_pca_variance_threshold_and_bounds():
    x, *_ = _low_rank(np.random.default_rng(1), noise=0.01)
    _, comps, _, ratio = fit_pca(x, variance=0.5)
    assert comps.shape[0] == 1 and ratio[0] >= 0.5
    _, comps, _, _ = fit_pca(x, variance=0.5, min_components=4)
    assert comps.shape[0] == 4
    _, comps, _, _ = fit_pca(x, variance=1.0, max_components=2)
    assert comps.shape[0] == 2


def test_fit_pca_is_deterministic_and_sign_fixed():
    x, *_ = _low_rank(np.random.default_rng(2), noise=0.01)
    a = fit_pca(x, variance=0.99)
    b = fit_pca(x[::-1].copy(), variance=0.99)  # another sample order: same components, same signs
    np.testing.assert_allclose(a[1], b[1], atol=1e-8)
    flat = a[1].reshape(len(a[2]), -1)
    assert (flat[np.arange(len(flat)), np.abs(flat).argmax(axis=1)] > 0).all()


def test_project_reconstruct_round_trip():
    x, *_ = _low_rank(np.random.default_rng(3))
    m, comps, _, _ = fit_pca(x, variance=0.999999)
    np.testing.assert_allclose(reconstruct(project(x, m, comps), m, comps), x, atol=1e-9)


@pytest.mark.parametrize("bad", [np.zeros((1, 4, 3)), np.zeros((5, 4, 2)), np.zeros((5, 12))])
def test_fit_pca_rejects_bad_shapes(bad):
    with pytest.raises(ValueError):
        fit_pca(bad)


def test_packaged_model_reconstructs_heldout_find_feet():
    """Full build: 200 held-out feet, error reported by the build; here 20 fresh ones to stay fast."""
    if not FIND_DIR.is_dir():
        pytest.skip(f"FIND not found at {FIND_DIR}")
    pytest.importorskip("onnxruntime")
    from footmesh.model.assets import load_asset
    from footmesh.model.build_find import sample_population

    asset = load_asset()
    feet, _ = sample_population(FIND_DIR, 20, seed=12345)
    error = mean_vertex_error(feet, asset.mean_vertices, asset.components)
    assert error < 0.5
