"""Build the packaged PCA foot model from FIND (Boyne, Charles, Cipolla, BMVC 2022; MIT licence).

Steps (``build_from_find``):

1. Sample FIND feet on the footmesh template (:func:`footmesh.model.find.sample_find_shapes`: random shape
   latent, neutral pose, mean texture), mm.
2. Stand each in the foot frame (:func:`footmesh.model.template.to_foot_frame`).
3. Give each a size and proportions drawn from ANSUR II (DESIGN.md "Anthropometrics"): sex ~ Bernoulli(0.5),
   foot length L ~ N(271.2, 13.1) (men) / N(246.3, 12.4) (women), ball width
   W = 38.09 + 0.235 L (men) / 40.16 + 0.213 L (women) + N(0, 4.0). FIND's shapes are normalised (their length
   varies by ~8 mm over +-2 SD), so this adds the real variation of adult feet. Scale anisotropically about the
   heel origin: x by s_x so that :func:`footmesh.model.anatomy.stick_length_mm` = L, y by s_y so that
   :func:`footmesh.model.anatomy.ball_width_mm` = W, z by sqrt(s_x s_y) (heights follow the geometric mean of the
   two plan scales: taller with bigger feet, without inventing a height statistic that ANSUR does not give);
   iterated three times because the measurements' vertex selections depend slightly on the scales.
4. PCA (:func:`footmesh.model.pca.fit_pca`), keeping enough components for ``variance`` of the variance and a
   held-out reconstruction error under ``max_error_mm``.
5. Rig the mean (:func:`footmesh.model.rig.build_rig`) and write the asset
   (:func:`footmesh.model.assets.save_asset`, whose bytes depend only on the arrays).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from footmesh.model import vertex_ids
from footmesh.model.anatomy import ball_width_mm, stick_length_mm
from footmesh.model.template import to_foot_frame

log = logging.getLogger(__name__)

TEST_SEED_OFFSET = 1_000_003
"""Held-out samples use seed + this, so they never share a random stream with the training samples."""
SIZE_STREAM = 1
"""Sizes are drawn from ``default_rng([seed, SIZE_STREAM])``, shapes from ``default_rng(seed)``."""
SCALE_ITERATIONS = 3


@dataclass(frozen=True)
class SexStats:
    """ANSUR II (Gordon et al. 2014, US Army 2012 survey) foot size statistics of one sex, mm."""

    length_mean: float
    length_sd: float
    width_intercept: float
    width_slope: float
    width_residual_sd: float = 4.0


MEN = SexStats(271.2, 13.1, 38.09, 0.235)
WOMEN = SexStats(246.3, 12.4, 40.16, 0.213)
P_MALE = 0.5


@dataclass(frozen=True)
class Sizes:
    """Per-sample target sizes: ``male`` (N,) bool, ``length`` (N,) mm, ``width`` (N,) mm."""

    male: np.ndarray
    length: np.ndarray
    width: np.ndarray


def sample_sizes(rng: np.random.Generator, n: int) -> Sizes:
    """Draw sex, foot length and ball width per sample from the ANSUR II mixture (DESIGN.md)."""
    male = rng.random(n) < P_MALE
    z_len = rng.standard_normal(n)
    z_width = rng.standard_normal(n)
    length = np.where(male, MEN.length_mean + MEN.length_sd * z_len, WOMEN.length_mean + WOMEN.length_sd * z_len)
    width = np.where(
        male,
        MEN.width_intercept + MEN.width_slope * length + MEN.width_residual_sd * z_width,
        WOMEN.width_intercept + WOMEN.width_slope * length + WOMEN.width_residual_sd * z_width,
    )
    return Sizes(male, length, width)


def scale_to_size(vertices: np.ndarray, length: float, width: float) -> np.ndarray:
    """Scale a foot-frame foot so that its stick length is ``length`` and its ball width ``width`` (mm).

    x *= s_x, y *= s_y, z *= sqrt(s_x s_y) about the origin (heel on the floor), so the floor, the heel and
    the foot axis stay where they are; iterated ``SCALE_ITERATIONS`` times.

    Args:
        vertices: (V, 3) mm, foot frame.

    Returns:
        (V, 3) mm, foot frame.
    """
    v0 = np.asarray(vertices, dtype=np.float64)
    sx = sy = 1.0
    v = v0
    for _ in range(SCALE_ITERATIONS):
        sx *= length / stick_length_mm(v)
        sy *= width / ball_width_mm(v)
        v = v0 * np.array([sx, sy, np.sqrt(sx * sy)])
    return v


def sample_population(
    find_dir, n: int, seed: int, progress: Callable[[int], object] | None = None
) -> tuple[np.ndarray, Sizes]:
    """Random adult feet: FIND shapes stood in the foot frame and sized by ANSUR II.

    Args:
        find_dir: FIND folder or an open :class:`footmesh.model.find.FindModel`.
        n: number of feet.
        seed: seed of the shape stream (sizes use ``[seed, SIZE_STREAM]``).
        progress: optional callable(k) after each foot.

    Returns:
        vertices (n, V, 3) float64 mm in the foot frame, and the target :class:`Sizes`.
    """
    from footmesh.model.find import FindModel, sample_find_shapes

    model = find_dir if isinstance(find_dir, FindModel) else FindModel(find_dir)
    sizes = sample_sizes(np.random.default_rng([seed, SIZE_STREAM]), n)
    raw = sample_find_shapes(model, n, seed, progress=progress)  # (n, V, 3) mm, FIND frame
    out = np.empty_like(raw)
    for i in range(n):
        standing = to_foot_frame(raw[i])
        out[i] = to_foot_frame(scale_to_size(standing, sizes.length[i], sizes.width[i]))
    return out, sizes


def population_stats(vertices: np.ndarray, male: np.ndarray) -> dict[str, dict[str, float]]:
    """Mean and SD of length, ball width and width/length per sex, measured on (N, V, 3) foot-frame samples."""
    length = np.array([stick_length_mm(v) for v in vertices])
    width = np.array([ball_width_mm(v) for v in vertices])
    stats = {}
    for name, mask in (("men", male), ("women", ~male)):
        if not mask.any():
            continue
        ratio = width[mask] / length[mask]
        stats[name] = {
            "n": int(mask.sum()),
            "length_mean": float(length[mask].mean()),
            "length_sd": float(length[mask].std(ddof=1)) if mask.sum() > 1 else 0.0,
            "width_mean": float(width[mask].mean()),
            "width_sd": float(width[mask].std(ddof=1)) if mask.sum() > 1 else 0.0,
            "ratio_mean": float(ratio.mean()),
            "ratio_sd": float(ratio.std(ddof=1)) if mask.sum() > 1 else 0.0,
        }
    return stats


def derive_landmarks(find_dir, icp_iterations: int = 30) -> dict[str, int]:
    """Re-derive :data:`footmesh.model.vertex_ids.LANDMARKS` from FIND's files (the rule in that module).

    Needs ``hires/template.obj`` and ``hires/keypoints.csv`` (from FOCUS) beside FIND's files.
    """
    import csv

    import trimesh
    from scipy.spatial import cKDTree

    from footmesh.model.find import FindModel

    d = Path(find_dir)
    hires_path, csv_path = d / "hires" / "template.obj", d / "hires" / "keypoints.csv"
    for p in (hires_path, csv_path):
        if not p.is_file():
            raise FileNotFoundError(f"FOCUS file not found: {p}")
    model = FindModel(d)
    sub = model.points  # (V, 3) metres, FIND frame
    hires = np.asarray(trimesh.load(hires_path, process=False, force="mesh").vertices)
    with csv_path.open() as fh:
        rows = {r[0]: r[1:] for r in csv.reader(fh) if r}
    names, ids = rows["model"], [int(x) for x in rows["FIND"]]

    # affine ICP of the high-resolution template onto ours (below the leg cap), nearest vertices both ways
    src = hires[::5]
    src = src[src[:, 2] < 0.06]
    dst = sub[sub[:, 2] < 0.06]
    dst_tree = cKDTree(dst)
    affine = np.vstack([np.eye(3), np.zeros((1, 3))])  # (4, 3): [A^T; b]
    for _ in range(icp_iterations):
        moved = src @ affine[:3] + affine[3]
        _, fwd = dst_tree.query(moved)
        _, back = cKDTree(moved).query(dst)
        a = np.vstack([src, src[back]])
        b = np.vstack([dst[fwd], dst])
        affine, *_ = np.linalg.lstsq(np.hstack([a, np.ones((len(a), 1))]), b, rcond=None)
    keypoints = hires[ids] @ affine[:3] + affine[3]
    _, nearest = cKDTree(sub).query(keypoints)
    landmarks = {vertex_ids.FIND_KEYPOINT_NAMES[n]: int(j) for n, j in zip(names, nearest, strict=True)}

    # malleoli on the neutral mean foot in the foot frame (fixed point: the frame uses them only for "up")
    mean, _ = model.evaluate(model.shape.mean, model.pose.latent(model.neutral_pose_coefficients()), model.tex.mean)
    mall = {**landmarks, "malleolus_lateral": vertex_ids.LANDMARKS["malleolus_lateral"]}
    mall["malleolus_medial"] = vertex_ids.LANDMARKS["malleolus_medial"]
    for _ in range(2):
        w = to_foot_frame(mean * 1000.0, mall)
        length = np.ptp(w[:, 0])
        for name, height, sign in (
            ("malleolus_lateral", 72.9 / 271.2, 1.0),
            ("malleolus_medial", 82.9 / 271.2, -1.0),
        ):
            band = (np.abs(w[:, 2] - height * length) < 3.0) & (w[:, 0] < 0.45 * length)
            xc = 0.5 * (w[band, 0].min() + w[band, 0].max())
            cand = np.flatnonzero(band & (np.abs(w[:, 0] - xc) < 8.0))
            mall[name] = int(cand[np.argmax(sign * w[cand, 1])])
    return {name: mall[name] for name in vertex_ids.LANDMARK_NAMES}


@dataclass
class BuildReport:
    """What a build produced (for the log and the CLI)."""

    path: Path
    num_components: int
    explained_variance: float
    heldout_error_mm: float
    stats: dict
    seconds: float
    size_bytes: int


def provenance_text(n_samples: int, seed: int, num_components: int, variance: float, error: float) -> str:
    return (
        "footmesh foot model derived from FIND: An Unsupervised Implicit 3D Model of Articulated Human Feet "
        "(O. Boyne, J. Charles, R. Cipolla, BMVC 2022), demo export (template.obj, model.onnx, latents.json), "
        "MIT licence, Copyright (c) 2022 Ollie Boyne (see LICENSE-FIND). Template: FIND's 1,002-vertex template "
        "subdivided once (Loop). Landmarks transferred from FOCUS keypoints (MIT, Copyright (c) 2024 Ollie "
        f"Boyne). Built by footmesh.model.build_find with n_samples={n_samples}, seed={seed}: FIND shape latents "
        "~ N(0, 1) on its 3 principal directions, pose = mean of FIND's T-Pose examples, stood on the sole's "
        "support plane, sized by ANSUR II 2012 (sex p=0.5; length N(271.2,13.1) men / N(246.3,12.4) women; "
        "ball width 38.09+0.235L / 40.16+0.213L + N(0,4.0); z scaled by sqrt(sx*sy)). PCA: "
        f"{num_components} components, {100 * variance:.3f}% of the variance, held-out mean vertex error "
        f"{error:.3f} mm. Rig: footmesh.model.rig.build_rig on the mean."
    )


def build_from_find(
    find_dir: str | os.PathLike,
    out_path: str | os.PathLike,
    n_samples: int = 2000,
    seed: int = 0,
    n_test: int = 200,
    variance: float = 0.995,
    max_error_mm: float = 0.35,
    progress: bool = False,
) -> BuildReport:
    """Build the foot model asset from FIND and write it to ``out_path`` (see the module docstring).

    The result is bit-for-bit reproducible from (FIND's files, n_samples, seed, n_test, variance, max_error_mm).

    Args:
        find_dir: folder with FIND's ``template.obj``, ``model.onnx``, ``latents.json``.
        out_path: the ``.npz`` to write.
        n_samples: training feet for the PCA.
        seed: random seed (held-out feet use ``seed + TEST_SEED_OFFSET``).
        n_test: held-out feet for choosing the number of components (0: variance only).
        variance: fraction of the variance to keep, at least.
        max_error_mm: the held-out mean vertex error must be under this (more components are kept if needed);
            the default leaves a margin under the 0.5 mm requirement for feet beyond the held-out set.
        progress: show a tqdm progress bar.
    """
    from footmesh.model.assets import FootModelAsset, save_asset
    from footmesh.model.find import FindModel, check_find_dir
    from footmesh.model.pca import fit_pca, mean_vertex_error
    from footmesh.model.rig import build_rig

    t0 = time.perf_counter()
    check_find_dir(find_dir)
    model = FindModel(find_dir)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_samples + n_test, desc="sampling FIND", unit="foot")
    update = bar.update if bar is not None else None
    try:
        train, sizes = sample_population(model, n_samples, seed, progress=update)
        test, _ = sample_population(model, n_test, seed + TEST_SEED_OFFSET, progress=update) if n_test else (None, None)
    finally:
        if bar is not None:
            bar.close()
    mean, comps, sd, ratio = fit_pca(train, variance=1.0)
    k = int(np.searchsorted(np.cumsum(ratio), variance - 1e-12) + 1)
    error = mean_vertex_error(test, mean, comps[:k]) if test is not None else float("nan")
    while test is not None and error >= max_error_mm and k < len(sd):
        k += 1
        error = mean_vertex_error(test, mean, comps[:k])
    comps, sd, ratio = comps[:k], sd[:k], ratio[:k]
    if test is not None and error >= max_error_mm:
        raise ValueError(f"PCA cannot reach {max_error_mm} mm held-out error (got {error:.3f} mm)")
    log.info("PCA: %d components, %.4f of the variance, held-out error %.3f mm", k, ratio.sum(), error)

    # the mean of stood feet is nearly stood already; re-stand it and turn the components by the same rotation
    mean_standing = to_foot_frame(mean)
    rot = _kabsch_rotation(mean, mean_standing)
    comps = comps @ rot.T
    log.info("re-standing the mean moved it by %.3f mm at most", np.abs(mean_standing - mean).max())
    landmarks = dict(vertex_ids.LANDMARKS)
    rig = build_rig(mean_standing, model.faces, landmarks)
    asset = FootModelAsset(
        mean_vertices=mean_standing.astype(np.float32),
        components=comps.astype(np.float32),
        component_sd=sd.astype(np.float32),
        explained_variance_ratio=ratio.astype(np.float32),
        faces=model.faces.astype(np.int32),
        landmark_names=np.array(vertex_ids.LANDMARK_NAMES),
        landmark_vertices=np.array([landmarks[n] for n in vertex_ids.LANDMARK_NAMES], dtype=np.int32),
        joint_regressor=np.asarray(rig.joint_regressor, dtype=np.float32),
        skin_weights=np.asarray(rig.skin_weights, dtype=np.float32),
        provenance=provenance_text(n_samples, seed, k, float(ratio.sum()), error),
    )
    out = Path(out_path)
    save_asset(asset, out)
    stats = population_stats(train, sizes.male)
    return BuildReport(out, k, float(ratio.sum()), error, stats, time.perf_counter() - t0, out.stat().st_size)


def _kabsch_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation R (3, 3) minimising ||(a - mean a) R^T - (b - mean b)|| for (V, 3) point sets (Kabsch)."""
    a0, b0 = a - a.mean(axis=0), b - b.mean(axis=0)
    u, _, vt = np.linalg.svd(b0.T @ a0)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


SKIN_COMPONENTS = 8
"""FIND's colours vary non-linearly over its 3 texture directions: 8 linear components explain about 96 % of
the variance (RMS colour error about 0.007)."""


def build_skin_colours(
    find_dir: str | os.PathLike,
    out_path: str | os.PathLike,
    n_samples: int = 300,
    seed: int = 0,
    num_components: int = SKIN_COMPONENTS,
) -> Path:
    """Fit the skin colour model (:mod:`footmesh.model.skin`) to FIND's colours and write it (reproducible bytes).

    Colours: FIND's ``col`` output for texture latents ``mean + sum_i c_i sd_i V_i`` (c ~ N(0, 1)), shape latent
    mean, neutral pose, on the footmesh template.
    """
    from footmesh.model.find import check_find_dir, sample_find_colours
    from footmesh.model.pca import fit_pca
    from footmesh.model.skin import SkinColours, save_skin_colours

    check_find_dir(find_dir)
    colours = sample_find_colours(find_dir, n_samples, seed)  # (n, V, 3) RGB 0..1
    mean, comps, sd, ratio = fit_pca(colours, variance=1.0, max_components=num_components)
    provenance = (
        "footmesh skin colours from FIND (O. Boyne, J. Charles, R. Cipolla, BMVC 2022; MIT, Copyright (c) 2022 "
        f"Ollie Boyne): PCA of the per-vertex colour output over {n_samples} texture latents (seed {seed}), "
        f"{len(sd)} components, {100 * ratio.sum():.1f}% of the variance."
    )
    out = Path(out_path)
    save_skin_colours(SkinColours(mean, comps, sd, provenance), out)
    return out
