"""How good the fit is with perfect cues (plus noise): the fit stage alone on synthetic scenes with known truth.

``python -m footmesh.eval.fit_check --check N [--modes depth floor none] [--views front] [--hold standing]`` prints
one line per mode (docs/fit.md).
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
import torch

from footmesh.cues import Cues
from footmesh.fit import SIDES, FitConfig, FootFit, canonical_measures, fit_foot
from footmesh.model.layer import FootModel, default_model

log = logging.getLogger(__name__)

MODES = ("depth", "floor", "none")
"""Evidence of ``evaluate_on_synthetic``: depth map + intrinsics, floor plane + RGB cues, RGB cues only."""


def synthetic_cues(
    sample: dict[str, np.ndarray],
    joint_noise_px: float = 3.0,
    rng: np.random.Generator | int | None = None,
    visible_confidence: float = 0.9,
    hidden_confidence: float = 0.3,
) -> Cues:
    """Cues from a synthetic sample's ground truth (``synth.render.Renderer.render``): its silhouette, its 2D
    joints plus Gaussian noise of ``joint_noise_px`` (per coordinate), confidence from the joints' visibility."""
    rng = np.random.default_rng(rng)
    joints = sample["joints2d"] + rng.normal(0.0, joint_noise_px, sample["joints2d"].shape)
    confidence = np.where(sample["joints_visible"], visible_confidence, hidden_confidence)
    return Cues(
        silhouette=sample["silhouette"].astype(np.float32),
        joints2d_px=joints.astype(np.float32),
        joint_confidence=confidence.astype(np.float32),
        input="rgb",
    )


@dataclass(frozen=True)
class SyntheticCheck:
    """Errors of ``fit_foot`` on synthetic scenes of one mode (fitted - true, mm unless stated)."""

    mode: str
    scenes: int
    length_mae_mm: float
    width_mae_mm: float
    ratio_mae: float  # |width/length fitted - true|
    vertex_error_mm: float  # mean vertex distance in the camera frame (meaningless unscaled)
    side_accuracy: float
    length_z_rms: float  # RMS of length error / the covariance's predicted SD (1 = calibrated)
    seconds_median: float
    length_errors: np.ndarray = field(repr=False)
    width_errors: np.ndarray = field(repr=False)
    natural: np.ndarray = field(repr=False)  # (n,) bool: the scene's pose is an everyday one, not a thesis "ik" one

    def line(self) -> str:
        nat = self.natural
        return (
            f"{self.mode:6s} n={self.scenes:3d}  length MAE {self.length_mae_mm:5.2f} mm  ball width MAE "
            f"{self.width_mae_mm:5.2f} mm  (everyday poses, n={int(nat.sum())}: "
            f"{np.abs(self.length_errors[nat]).mean():5.2f} / {np.abs(self.width_errors[nat]).mean():4.2f} mm)"
            f"  width/length MAE {self.ratio_mae:.4f}  vertex {self.vertex_error_mm:6.2f} mm"
            f"  side {100 * self.side_accuracy:5.1f} %  length z-RMS {self.length_z_rms:5.2f}"
            f"  {1000 * self.seconds_median:5.0f} ms/fit"
        )


def evaluate_on_synthetic(
    n: int = 50,
    mode: str = "depth",
    seed: int = 1234,
    size: int = 320,
    joint_noise_px: float = 3.0,
    side: str = "auto",
    config: FitConfig | None = None,
    standing_only: bool | None = None,
    views: str | None = None,
    hold: Literal["upright", "standing"] | None = None,
) -> SyntheticCheck:
    """Fit ``n`` synthetic scenes with true cues + noise and report the length / ball-width errors.

    ``mode``: "depth" (the noisy depth map), "floor" (the true floor plane, RGB cues only) or "none".
    ``side``: "auto" (the fit picks), "given" (the true side is declared), "left" or "right".
    ``standing_only`` (default: True for "floor") skips lifted feet, which the floor contact term assumes away.
    ``views``: a ``synth.scene.VIEW_PRESETS`` name (e.g. "front"), or None for the renderer's default views.
    ``hold``: the fit held on the floor as the pipeline holds it (``MeasureConfig.held_fit``), or None (free).
    """
    from footmesh.config import MeasureConfig
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig, view_config

    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    standing_only = (mode == "floor") if standing_only is None else standing_only
    config = MeasureConfig().held_fit(config if config is not None else FitConfig(), hold)
    scenes = SynthConfig(size=size, reference="a4") if views is None else view_config(views, size=size, reference="a4")
    renderer = Renderer(scenes)
    model = default_model()
    rows = []
    index = 0
    while len(rows) < n:
        sample = renderer.render(seed, index)
        index += 1
        if standing_only and bool(sample["lifted"]):
            continue
        cues = synthetic_cues(sample, joint_noise_px, rng=[seed, index])
        depth = sample["depth"].astype(np.float32) if mode == "depth" else None
        floor = sample["cam_from_scene"] if mode == "floor" else None
        true_side = SIDES[int(sample["side"])]
        fit_side = true_side if side == "given" else side
        fit = fit_foot(cues, sample["K"], depth, floor, side=fit_side, config=config, model=model)
        length, width = canonical_measures(sample["shape"], model)
        fit_length, fit_width = canonical_measures(fit.shape, model)
        sd = _length_sd(fit, model)
        rows.append(
            (
                fit_length - length,
                fit_width - width,
                fit_width / fit_length - width / length,
                float(np.linalg.norm(fit.vertices_cam - sample["vertices"], axis=1).mean()),
                fit.side == true_side,
                (fit_length - length) / sd if sd > 0 else np.nan,
                fit.seconds,
                renderer.scene(seed, index - 1).pose_method == "natural",
            )
        )
        log.info("scene %d: length %+.2f mm, width %+.2f mm, %.2f s", index - 1, rows[-1][0], rows[-1][1], fit.seconds)
    a = np.array(rows, dtype=np.float64)
    return SyntheticCheck(
        mode=mode,
        scenes=n,
        length_mae_mm=float(np.abs(a[:, 0]).mean()),
        width_mae_mm=float(np.abs(a[:, 1]).mean()),
        ratio_mae=float(np.abs(a[:, 2]).mean()),
        vertex_error_mm=float(a[:, 3].mean()),
        side_accuracy=float(a[:, 4].mean()),
        length_z_rms=float(np.sqrt(np.nanmean(a[:, 5] ** 2))) if mode != "none" else float("nan"),
        seconds_median=float(np.median(a[:, 6])),
        length_errors=a[:, 0],
        width_errors=a[:, 1],
        natural=a[:, 7].astype(bool),
    )


def _length_sd(fit: FootFit, model: FootModel, samples: int = 64) -> float:
    """SD of the canonical stick length under ``fit.shape_covariance`` (mm), by sampling."""
    from footmesh.model.anatomy import stick_length_mm

    shapes = fit.sample_shapes(samples, rng=0)
    with torch.no_grad():
        v = model(torch.as_tensor(shapes, dtype=torch.float32)).vertices.double().numpy()
    return float(np.std([stick_length_mm(x) for x in v]))


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m footmesh.eval.fit_check --check N [--modes depth floor none]``: one line per mode."""
    from footmesh.synth.scene import VIEW_PRESETS

    parser = argparse.ArgumentParser(prog="python -m footmesh.eval.fit_check", description=main.__doc__)
    parser.add_argument("--check", type=int, default=50, metavar="N", help="scenes per mode (default 50)")
    parser.add_argument("--modes", nargs="+", choices=MODES, default=list(MODES))
    parser.add_argument("--seed", type=int, default=1234)
    parser.add_argument("--size", type=int, default=320, help="image size, px (default 320)")
    parser.add_argument("--noise", type=float, default=3.0, help="joint noise, px (default 3)")
    parser.add_argument("--side", choices=("auto", "given"), default="auto", help="auto, or the true side given")
    parser.add_argument(
        "--views", choices=tuple(VIEW_PRESETS), default=None, help="a named set of views (default: random)"
    )
    parser.add_argument(
        "--hold", choices=("upright", "standing"), default=None, help="the fit held on the floor, as the pipeline may"
    )
    parser.add_argument("--threads", type=int, default=2, help="torch threads (default 2)")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    torch.set_num_threads(args.threads)
    for mode in args.modes:
        check = evaluate_on_synthetic(
            args.check, mode, args.seed, args.size, args.noise, args.side, views=args.views, hold=args.hold
        )
        print(check.line(), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
