"""``footmesh eval measure``: the whole pipeline on synthetic photos, thesis Tables 4.7, 4.8 and 4.9.

Each test photo is rendered like a phone photo (``--size`` px, a phone-like field of view, floors, a reference
object on the floor), written to disk as PNG (+ 16-bit depth PNG, K.json) and measured by the same
``measure_photo`` the command runs. The truth is the measurement of the true shape in the zero pose. Modes:

- ``rgb_ref``: RGB with an A4 sheet, a card or a marker (scale from the reference object);
- ``rgbd``: RGB + depth; ``depth``: the depth map alone;
- ``rgb``: RGB without any reference: unscaled, so only the ratios (width / length) are compared;
- ``rgbd_heic``: the ``rgbd`` photos written as an iPhone writes a LiDAR photo: one HEIC stored sideways with
  EXIF orientation 6, its depth image inside at 256 px, 8-bit uniform Z over the scene's range, measured with no
  depth flag (the embedded depth path of issue 20).
"""

from __future__ import annotations

import json
import math
import re
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import torch

from footmesh.config import MeasureConfig
from footmesh.errors import Refusal
from footmesh.eval import thesis
from footmesh.measure import FootLandmarks, measure_foot
from footmesh.model.layer import default_model

MODES = ("rgb_ref", "rgbd", "depth", "rgb", "rgbd_heic")
INTERNAL = "internal error"
"""How a photo that failed by footmesh's own fault (not a refusal) is marked in the records and the tables."""
REFERENCES = ("a4", "card", "marker")
"""The objects the ``rgb_ref`` photos cycle through, the ones every table of this eval was measured with (the US
letter sheet, told apart from A4 by its proportions, has its own table: ``benchmarks/bench_reference.py``)."""
EVAL_SEED = 4242
"""Seed of the test photos (training used seeds 1-3)."""
SEED_MODE = {"rgbd_heic": "rgbd"}
"""Modes that measure another mode's photos (written differently)."""
HEIC_DEPTH_SIDE_PX = 256
"""Longer side of the depth image in ``rgbd_heic`` photos (an iPhone's LiDAR depth: 256 x 192)."""
BASELINE_MM = {"length": 14.2, "width": 5.3}
"""DESIGN.md: always answering the population's mean foot."""


@dataclass
class Record:
    index: int
    view: tuple[str, int] | None
    ok: bool
    error: str = ""
    length_err: float = math.nan
    width_err: float = math.nan
    length_u: float = math.nan
    width_u: float = math.nan
    ratio_err: float = math.nan
    side_ok: bool = False
    scale_source: str = ""
    seconds: float = math.nan
    stage_seconds: dict[str, float] = field(default_factory=dict)
    """The pipeline's own timings (result.json ``timings_s``): cues, reference, fit, measure."""
    fit_loss: float = math.nan
    """The fit's final cost (result.json ``fit.loss``): how well the model explains the photo."""
    fit_quality: dict[str, float] = field(default_factory=dict)
    """result.json ``fit.quality``: contour within 2 px, model outside, joint error, depth residual."""
    view_angle_deg: float = math.nan
    """The true angle between the foot's heel-to-toe axis and the line of sight to its middle (0: end-on, 90: seen
    from the side or from above), from the render."""


@dataclass
class ModeResult:
    mode: str
    records: list[Record] = field(default_factory=list)

    def ok(self) -> list[Record]:
        return [r for r in self.records if r.ok]

    def summary(self) -> dict:
        ok = self.ok()
        le = np.array([r.length_err for r in ok])
        we = np.array([r.width_err for r in ok])
        lu = np.array([r.length_u for r in ok])
        wu = np.array([r.width_u for r in ok])
        scaled = np.isfinite(le)
        out = {
            "photos": len(self.records),
            "measured": len(ok),
            "failed": {r.index: r.error for r in self.records if not r.ok},
            "side_accuracy": float(np.mean([r.side_ok for r in ok])) if ok else math.nan,
            "seconds_median": float(np.median([r.seconds for r in ok])) if ok else math.nan,
            "seconds_p90": float(np.percentile([r.seconds for r in ok], 90)) if ok else math.nan,
            "stage_seconds_median": (
                {k: float(np.median([r.stage_seconds[k] for r in ok])) for k in ok[0].stage_seconds} if ok else {}
            ),
            "ratio_mae": float(np.nanmean([abs(r.ratio_err) for r in ok])) if ok else math.nan,
        }
        if scaled.any():
            out.update(
                {
                    "length_mae_mm": float(np.mean(np.abs(le[scaled]))),
                    "length_sd_mm": float(np.std(np.abs(le[scaled]))),
                    "length_bias_mm": float(np.mean(le[scaled])),
                    "width_mae_mm": float(np.mean(np.abs(we[scaled]))),
                    "width_sd_mm": float(np.std(np.abs(we[scaled]))),
                    "width_bias_mm": float(np.mean(we[scaled])),
                    "within_half_size": float(np.mean(np.abs(le[scaled]) <= 4.23)),
                    "length_within_1u": float(np.mean(np.abs(le[scaled]) <= lu[scaled])),
                    "width_within_1u": float(np.mean(np.abs(we[scaled]) <= wu[scaled])),
                    "scale_sources": {s: sum(r.scale_source == s for r in ok) for s in {r.scale_source for r in ok}},
                }
            )
        return out


def true_measurements(shape: np.ndarray, side: str) -> dict[str, float]:
    """The eight measurements of the true shape in the zero pose, mm."""
    model = default_model()
    with torch.no_grad():
        out = model(torch.as_tensor(shape, dtype=torch.float32)[None], side=side)
    v, j = out.vertices[0].double().numpy(), out.joints[0].double().numpy()
    return measure_foot(v, model.faces(side).numpy(), FootLandmarks.from_joints(j), side=side).values_mm()


def write_inputs(sample: dict, folder: Path, with_depth: bool) -> dict:
    """A synthetic sample as the files a user gives: photo.png, K.json and (``with_depth``) depth.png in mm."""
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "photo.png"), sample["rgb"][..., ::-1])
    K = sample["K"]
    h, w = sample["rgb"].shape[:2]
    k_json = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": w, "height": h}
    (folder / "K.json").write_text(json.dumps({k: float(v) for k, v in k_json.items()}))
    paths = {"image": folder / "photo.png", "intrinsics": folder / "K.json"}
    if with_depth:
        cv2.imwrite(str(folder / "depth.png"), sample["depth"])
        paths["depth"] = folder / "depth.png"
    return paths


def turned_sample(sample: dict, quarter_turns: int) -> dict:
    """A synthetic sample's photo (and depth) turned ``quarter_turns`` x 90 deg counter-clockwise, with its K: the
    same scene photographed another way up, for ``write_inputs``."""
    from footmesh.cues.predict import turned
    from footmesh.geometry.camera import Camera

    h, w = sample["rgb"].shape[:2]
    out = {**sample, "rgb": turned(sample["rgb"], quarter_turns)}
    out["K"] = Camera(np.asarray(sample["K"], np.float64), w, h).turned(quarter_turns).K
    if "depth" in sample:
        out["depth"] = turned(sample["depth"], quarter_turns)
    return out


def _write_heic_inputs(sample: dict, folder: Path) -> dict:
    """The photo as an iPhone-like HEIC with its depth inside (see ``rgbd_heic``), and K.json."""
    from PIL import Image

    from footmesh.formats.heif_writer import write_heic

    paths = write_inputs(sample, folder, with_depth=False)
    depth_mm = sample["depth"].astype(np.float64)
    valid = depth_mm > 0
    near_m, far_m = math.floor(depth_mm[valid].min() / 10) / 100, math.ceil(depth_mm[valid].max() / 10) / 100
    h, w = depth_mm.shape
    scale = HEIC_DEPTH_SIDE_PX / max(h, w)
    small = cv2.resize(depth_mm, (round(w * scale), round(h * scale)), interpolation=cv2.INTER_NEAREST) / 1000.0
    codes = np.clip(np.round((small - near_m) / (far_m - near_m) * 255), 1, 254)
    codes[small <= 0] = 255  # missing: the far clip code, which the reader drops
    exif = Image.Exif()
    exif[0x0112] = 6  # stored as the sensor saw it; the viewer turns it a quarter clockwise
    data = write_heic(
        np.ascontiguousarray(np.rot90(sample["rgb"], 1)),
        exif=exif.tobytes(),
        depth_samples=np.ascontiguousarray(np.rot90(codes, 1)).astype(np.uint8),
        z_near=near_m,
        z_far=far_m,
    )
    (folder / "photo.heic").write_bytes(data)
    return {**paths, "image": folder / "photo.heic"}


def view_angle_deg(cam_from_foot: np.ndarray, length_mm: float = 260.0) -> float:
    """Angle (deg) between a foot's heel-to-toe axis and the line of sight to its middle, from its (4, 4) pose
    (foot frame: heel at the origin, toes along +x): 0 end-on, 90 seen square to its length."""
    axis = cam_from_foot[:3, 0]
    middle = cam_from_foot[:3, :3] @ [length_mm / 2, 0.0, 0.0] + cam_from_foot[:3, 3]
    cos = abs(float(axis @ middle)) / float(np.linalg.norm(middle))
    return math.degrees(math.acos(min(cos, 1.0)))


def evaluate_mode(
    mode: str,
    n: int,
    size: int,
    views: str = "random",
    progress: bool = True,
    seed: int = EVAL_SEED,
    config: MeasureConfig | None = None,
    withhold_intrinsics: bool = False,
) -> ModeResult:
    """Measure ``n`` synthetic photos of ``mode`` with the full pipeline (``config``: its settings; default ones).
    ``withhold_intrinsics``: RGB photos are measured without their K.json, as a photo without EXIF is (the
    pipeline assumes a focal length; with a reference its perspective may correct it)."""
    from tqdm import tqdm

    from footmesh.pipeline import measure_photo
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import VIEW_PRESETS, SynthConfig, thesis_view, view_config

    renderers = {}

    def renderer(reference: str) -> Renderer:
        if reference not in renderers:
            if views in VIEW_PRESETS:
                config = view_config(views, size=size, reference=reference)
            else:
                config = SynthConfig(size=size, reference=reference, views=views, frame_reference=True)
            renderers[reference] = Renderer(config)
        return renderers[reference]

    result = ModeResult(mode)
    with tempfile.TemporaryDirectory(prefix="footmesh-eval-") as tmp:
        for i in tqdm(range(n), desc=f"eval measure {mode}", disable=not progress):
            reference = REFERENCES[i % len(REFERENCES)] if mode == "rgb_ref" else "none"
            sample = renderer(reference).render(seed + MODES.index(SEED_MODE.get(mode, mode)), i)
            side = "right" if int(sample["side"]) else "left"
            view = None
            if int(sample["view_id"]) >= 0:
                _, _, axis, deg = thesis_view(int(sample["view_id"]), side)
                view = (axis, deg)
            if mode == "rgbd_heic":
                paths = _write_heic_inputs(sample, Path(tmp) / f"{i}")
            else:
                paths = write_inputs(sample, Path(tmp) / f"{i}", with_depth=mode in ("rgbd", "depth"))
            truth = true_measurements(sample["shape"], side)
            angle = view_angle_deg(np.asarray(sample["cam_from_foot"], dtype=np.float64), truth["stick_length"])
            t0 = time.perf_counter()
            try:
                res = measure_photo(
                    paths["image"],
                    Path(tmp) / f"{i}" / "out",
                    depth=paths.get("depth"),
                    intrinsics=None if withhold_intrinsics and mode in ("rgb_ref", "rgb") else paths["intrinsics"],
                    input={"rgb_ref": "rgb", "rgb": "rgb", "rgbd_heic": "rgbd"}.get(mode, mode),
                    config=config,
                )
            except ValueError as exc:  # a refusal costs time too (issue 21 times every photo tried)
                seconds = time.perf_counter() - t0
                # any other ValueError is footmesh's own fault (the CLI reports it as internal): never a refusal
                error = str(exc) if isinstance(exc, Refusal) else f"{INTERNAL} {type(exc).__name__}: {exc}"
                result.records.append(Record(i, view, False, error, seconds=seconds, view_angle_deg=angle))
                continue
            rec = Record(
                i,
                view,
                True,
                seconds=time.perf_counter() - t0,
                scale_source=res["scale_source"],
                stage_seconds=dict(res["timings_s"]),
                fit_loss=float(res["fit"]["loss"]),
                fit_quality=dict(res["fit"]["quality"]),
                view_angle_deg=angle,
            )
            rec.side_ok = res["side"] == side
            m = res["measurements"]
            length, width = m["stick_length"]["value_mm"], m["ball_width"]["value_mm"]
            if length is not None:
                rec.length_err = length - truth["stick_length"]
                rec.width_err = width - truth["ball_width"]
                rec.length_u = m["stick_length"]["uncertainty_mm"] or math.nan
                rec.width_u = m["ball_width"]["uncertainty_mm"] or math.nan
            ratio = res["ratios"].get("ball_width/stick_length")
            if ratio is not None:
                rec.ratio_err = ratio - truth["ball_width"] / truth["stick_length"]
            result.records.append(rec)
    return result


def format_tables(results: dict[str, ModeResult]) -> str:
    """Table 4.7 (and 4.8/4.9 for thesis viewpoints) in Markdown, ours beside the thesis'."""
    thesis_key = {"rgb_ref": "rgb", "rgbd": "rgbd", "depth": "depth", "rgb": "rgb", "rgbd_heic": "rgbd"}
    lines = [
        "Table 4.7: foot length and ball width error, mm: mean absolute (SD); thesis: ISM, same input",
        "",
        "| input | photos | measured | length ours | length thesis | width ours | width thesis | within half a "
        "size | length within 1 u | width within 1 u | s / photo |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for mode, res in results.items():
        s = res.summary()
        t = thesis.MEASURE_MM[thesis_key[mode]]
        tl, tw = f"{t['length'][0]:.1f} ({t['length'][1]:.1f})", f"{t['width'][0]:.1f} ({t['width'][1]:.1f})"
        if "length_mae_mm" in s:
            lines.append(
                f"| {mode} | {s['photos']} | {s['measured']} | **{s['length_mae_mm']:.2f}** ({s['length_sd_mm']:.2f}) "
                f"| {tl} | **{s['width_mae_mm']:.2f}** ({s['width_sd_mm']:.2f}) | {tw} | "
                f"{100 * s['within_half_size']:.0f} % | {100 * s['length_within_1u']:.0f} % | "
                f"{100 * s['width_within_1u']:.0f} % | {s['seconds_median']:.2f} |"
            )
        else:
            lines.append(
                f"| {mode} (unscaled: width/length MAE {s['ratio_mae']:.4f}) | {s['photos']} | {s['measured']} | "
                f"- | {tl} | - | {tw} | - | - | - | {s['seconds_median']:.2f} |"
            )
    lines.append(
        f"| population mean foot (DESIGN.md baseline) | | | {BASELINE_MM['length']:.1f} | | {BASELINE_MM['width']:.1f} "
        "| | | | | |"
    )
    for mode, res in results.items():
        failed = res.summary()["failed"]
        refused = {i: msg for i, msg in failed.items() if not msg.startswith(INTERNAL)}
        if refused:
            reasons: dict[str, int] = {}
            for msg in refused.values():
                reason = re.sub(r"\d+", "N", msg.split(";")[0])[:90]  # "55 deg", "83 %": one reason, counted
                reasons[reason] = reasons.get(reason, 0) + 1
            lines.append("")
            lines.append(
                f"{mode}: {len(refused)} photo(s) refused: " + "; ".join(f"{k} ({v})" for k, v in reasons.items())
            )
        internal = {i: msg for i, msg in failed.items() if msg.startswith(INTERNAL)}
        if internal:
            lines.append("")
            lines.append(
                f"{mode}: {len(internal)} {INTERNAL}s: " + "; ".join(f"photo {i}: {m}" for i, m in internal.items())
            )
    by_view = {m: r for m, r in results.items() if any(rec.view for rec in r.records)}
    if by_view:
        for what, table, attr in (
            ("4.8", thesis.LENGTH_MM_BY_VIEW, "length_err"),
            ("4.9", thesis.WIDTH_MM_BY_VIEW, "width_err"),
        ):
            name = "length" if attr == "length_err" else "width"
            lines += ["", f"Table {what}: {name} error per thesis viewpoint, mean abs (SD) mm, ours | thesis", ""]
            lines.append("| axis | deg | " + " | ".join(f"{m} ours | thesis" for m in by_view) + " |")
            lines.append("|---|---:|" + "---:|---:|" * len(by_view))
            for key in sorted(table, key=lambda a: (a[0], a[1])):
                cells = []
                for mode, res in by_view.items():
                    errs = np.abs([getattr(r, attr) for r in res.ok() if r.view == key])
                    errs = errs[np.isfinite(errs)]
                    total = sum(r.view == key for r in res.records)
                    ours = (
                        f"{errs.mean():.1f} ({errs.std():.1f}) [{len(errs)}/{total}]" if len(errs) else f"- [0/{total}]"
                    )
                    t = table[key][thesis_key[mode]]
                    cells.append(f"{ours} | {t[0]:.1f} ({t[1]:.1f})")
                lines.append(f"| {key[0]} | {key[1]} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_eval(
    modes: list[str],
    n: int,
    size: int,
    views: str,
    json_out: str | None = None,
    progress: bool = True,
    seed: int = EVAL_SEED,
    withhold_intrinsics: bool = False,
    config: MeasureConfig | None = None,
) -> str:
    """Evaluate the modes and return the tables (and write per-photo records as JSON)."""
    torch.set_num_threads(max(1, torch.get_num_threads()))
    results = {m: evaluate_mode(m, n, size, views, progress, seed, config, withhold_intrinsics) for m in modes}
    text = format_tables(results)
    print(text, flush=True)  # before anything that could fail: the numbers took minutes
    if json_out:
        from dataclasses import asdict

        from footmesh.report import write_json

        payload = {m: {"summary": r.summary(), "records": [asdict(x) for x in r.records]} for m, r in results.items()}
        write_json(Path(json_out), _finite(json.loads(json.dumps(payload, default=str))))
    return text


def _finite(value):
    """NaN (a photo not measured, an unscaled length) as JSON null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_finite(v) for v in value]
    return value
