"""Sampling the FIND foot model (Boyne, Charles, Cipolla, BMVC 2022; MIT) on the footmesh template.

FIND is an implicit displacement field: ``model.onnx`` maps template points plus a shape, pose and texture latent
(100-d each) to a displacement (metres) and a colour (RGB 0..1) per point. ``latents.json`` gives, for each
latent, a mean and 3 principal directions with their SDs: a latent is ``mean + sum_i c_i stddev_i V_i``.

Needs ``onnxruntime`` (the ``build`` extra); only model building uses this module.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from footmesh.model.template import FIND_NUM_VERTICES, subdivided_template

FIND_FILES = ("template.obj", "model.onnx", "latents.json")
ORT_THREADS = 2
NEUTRAL_POSE_TAG = "T-Pose"


@dataclass(frozen=True)
class Latents:
    """One of FIND's latent spaces: ``mean`` (100,), ``directions`` (3, 100) unit rows, ``sd`` (3,)."""

    mean: np.ndarray
    directions: np.ndarray
    sd: np.ndarray

    def latent(self, coefficients: np.ndarray) -> np.ndarray:
        """(..., 3) standard-normal coefficients -> (..., 100) latents ``mean + sum_i c_i sd_i V_i``."""
        return self.mean + (np.asarray(coefficients) * self.sd) @ self.directions


def check_find_dir(find_dir: str | Path) -> Path:
    """Return ``find_dir`` as a Path, raising FileNotFoundError naming the first missing file."""
    d = Path(find_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"FIND folder not found: {d} (it holds {', '.join(FIND_FILES)})")
    for name in FIND_FILES:
        if not (d / name).is_file():
            raise FileNotFoundError(f"FIND file not found: {d / name}")
    return d


class FindModel:
    """FIND's field evaluated on the footmesh template (4,002 Loop-subdivided points), CPU, deterministic."""

    def __init__(self, find_dir: str | Path, threads: int = ORT_THREADS) -> None:
        import onnxruntime as ort

        d = check_find_dir(find_dir)
        raw = json.loads((d / "latents.json").read_text())
        self.shape = _latents(raw["shape"])
        self.pose = _latents(raw["pose"])
        self.tex = _latents(raw["tex"])
        self.pose_examples: list[tuple[tuple[str, ...], np.ndarray]] = [
            (tuple(e["pose"]), np.asarray(e["pca"], dtype=np.float64)) for e in raw["pose_examples"]
        ]
        self.points, self.faces = subdivided_template(d)  # (V, 3) metres, (F, 3)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        self._session = ort.InferenceSession(str(d / "model.onnx"), opts, providers=["CPUExecutionProvider"])

    def neutral_pose_coefficients(self) -> np.ndarray:
        """(3,) pose coefficients of the neutral standing pose: the mean of FIND's "T-Pose" examples.

        Chosen over the latent mean (c = 0), which is the average over all of FIND's training poses (flexed,
        inverted, dorsiflexed ... included): the T-Pose mean has the toes flatter and the leg more upright.
        """
        tposes = [c for tags, c in self.pose_examples if NEUTRAL_POSE_TAG in tags]
        return np.mean(tposes, axis=0)

    def evaluate(
        self, shape: np.ndarray, pose: np.ndarray, tex: np.ndarray, points: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Deformed points and colours for one set of latents.

        Args:
            shape, pose, tex: (100,) latents.
            points: (P, 3) metres in FIND's frame; the template's points by default.

        Returns:
            vertices (P, 3) float64 metres (points + displacement), colours (P, 3) float64 RGB in 0..1.
        """
        pts = self.points if points is None else np.asarray(points, dtype=np.float64)
        n = FIND_NUM_VERTICES  # model.onnx takes exactly 1002 points per call: chunks, last one padded
        feeds = {
            name: np.ascontiguousarray(np.broadcast_to(np.asarray(z, np.float32), (n, 100)))
            for name, z in (("shapevec", shape), ("posevec", pose), ("texvec", tex))
        }
        disp = np.empty_like(pts)
        col = np.empty_like(pts)
        for start in range(0, len(pts), n):
            chunk = pts[start : start + n]
            k = len(chunk)
            padded = np.empty((n, 3), np.float32)
            padded[:k] = chunk
            padded[k:] = chunk[-1]
            d, c = self._session.run(["disp", "col"], {"points": padded, **feeds})
            disp[start : start + k] = d[:k]
            col[start : start + k] = c[:k]
        return pts + disp, col


def _latents(entry: dict) -> Latents:
    return Latents(
        mean=np.asarray(entry["mean"], dtype=np.float64),
        directions=np.asarray(entry["V"], dtype=np.float64),
        sd=np.asarray(entry["stddev"], dtype=np.float64),
    )


def sample_find_shapes(find_dir: str | Path | FindModel, n: int, seed: int, progress=None) -> np.ndarray:
    """Random FIND feet on the footmesh template, in FIND's frame.

    Shape latent = mean + sum_i c_i stddev_i V_i with c ~ N(0, 1) from ``numpy.random.default_rng(seed)``; pose =
    the neutral pose (:meth:`FindModel.neutral_pose_coefficients`); texture = its latent mean.

    Args:
        find_dir: folder with FIND's files, or an already opened :class:`FindModel`.
        n: number of feet.
        seed: random seed.
        progress: optional callable(k) called after each foot (e.g. ``tqdm.update``).

    Returns:
        (n, 4002, 3) float64 **millimetres**, FIND's frame (x heel->toe, z roughly up, not standing).
    """
    model = find_dir if isinstance(find_dir, FindModel) else FindModel(find_dir)
    rng = np.random.default_rng(seed)
    coeffs = rng.standard_normal((n, 3))
    pose = model.pose.latent(model.neutral_pose_coefficients())
    tex = model.tex.mean
    out = np.empty((n, len(model.points), 3))
    for i in range(n):
        out[i], _ = model.evaluate(model.shape.latent(coeffs[i]), pose, tex)
        if progress is not None:
            progress(1)
    return out * 1000.0


def sample_find_colours(find_dir: str | Path | FindModel, n: int, seed: int) -> np.ndarray:
    """Random FIND skin colours on the footmesh template: tex = mean + sum_i c_i sd_i V_i, shape/pose neutral.

    Returns:
        (n, 4002, 3) float64 RGB in 0..1.
    """
    model = find_dir if isinstance(find_dir, FindModel) else FindModel(find_dir)
    rng = np.random.default_rng(seed)
    coeffs = rng.standard_normal((n, 3))
    pose = model.pose.latent(model.neutral_pose_coefficients())
    out = np.empty((n, len(model.points), 3))
    for i in range(n):
        _, out[i] = model.evaluate(model.shape.mean, pose, model.tex.latent(coeffs[i]))
    return np.clip(out, 0.0, 1.0)
