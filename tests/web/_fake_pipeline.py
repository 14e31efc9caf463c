"""Test scaffolding: a stand-in for ``footmesh.pipeline.measure_photo`` with the same signature and files.

It writes real files (``mesh.obj``, ``mesh.glb``, ``overlay.png``, ``result.json``) and a result dict of the
contract's shape, with numbers measured by ``footmesh.measure.measure_foot`` on the packaged model's mean foot,
placed in the camera frame of a camera above the photo's centre. It refuses a photo without a foot the way the
real pipeline does (``ValueError`` with one line): here, a photo with (almost) no contrast counts as one.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from PIL import Image, ImageDraw, ImageOps

from footmesh import __version__, report
from footmesh.errors import InputError, Refusal
from footmesh.measure import FootLandmarks, measure_foot
from footmesh.model import skeleton as sk
from footmesh.model.layer import default_model
from footmesh.sizes import shoe_sizes

NO_FOOT_GREY_SD = 6.0
"""A photo whose grey levels vary less than this (0-255 scale) has nothing in it: "no foot"."""
CAMERA_FROM_FOOT = np.array([[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]).T
"""Rotation, foot frame -> camera frame, for a camera looking straight down: toes up, foot's up to the camera."""
FOOT_CENTRE_DEPTH_MM = 600.0
UNCERTAINTY_MM = 1.5
FILES = {"mesh_obj": "mesh.obj", "mesh_glb": "mesh.glb", "overlay_png": "overlay.png", "result_json": "result.json"}


@dataclass(frozen=True)
class FakeMeasure:
    """``fake_measure`` with options, picklable (process isolation): a delay and the scale source to claim."""

    delay_s: float = 0.0
    scale_source: str = "a4"

    def __call__(self, image: Path, out_dir: Path, **options) -> dict:
        return fake_measure(image, out_dir, delay_s=self.delay_s, scale_source=self.scale_source, **options)


def fake_measure(
    image: Path,
    out_dir: Path,
    *,
    depth: Path | None = None,
    depth_unit: str = "mm",
    intrinsics: Path | None = None,
    side: str = "auto",
    reference: str = "auto",
    delay_s: float = 0.0,
    scale_source: str = "a4",
) -> dict:
    """Measure the mean foot "seen" in ``image``; write the four result files into ``out_dir``; return the dict."""
    data = Path(image).read_bytes()
    with Image.open(image) as img:
        rgb = ImageOps.exif_transpose(img).convert("RGB")
    if np.asarray(rgb.convert("L"), dtype=np.float64).std() < NO_FOOT_GREY_SD:
        raise Refusal("no foot found in the photo", "take it from above with the whole foot in the picture")
    if depth_unit not in ("mm", "m"):
        raise InputError(f"depth_unit must be 'mm' or 'm', got {depth_unit!r}")
    time.sleep(delay_s)
    side_used = "left" if side == "auto" else side
    if depth is not None:
        scale_source = "depth"

    model = default_model()
    shape = torch.zeros(1, model.num_components)
    rotation = torch.from_numpy(CAMERA_FROM_FOOT).float()[None]
    with torch.no_grad():
        rest = model(shape)
        length = float(rest.rest_vertices[0, :, 0].max())
        translation = torch.tensor([[0.0, length / 2, FOOT_CENTRE_DEPTH_MM]])
        posed = model(shape, side=side_used, rotation=rotation, translation=translation)
    faces = model.faces("left").numpy()
    measured = measure_foot(rest.vertices[0].numpy(), faces, FootLandmarks.from_joints(rest.joints[0].numpy()))
    measured = measured.with_uncertainties(dict.fromkeys(measured.values_mm(), UNCERTAINTY_MM))
    if scale_source == "none":
        measured = measured.as_unscaled()
    values = measured.values_mm()
    sizes = shoe_sizes(values["stick_length"], values["ball_width"])

    width, height = rgb.size
    focal = 1.1 * max(width, height)
    joints3d = posed.joints[0].numpy().astype(np.float64)
    joints2d = focal * joints3d[:, :2] / joints3d[:, 2:] + np.array([width / 2, height / 2])

    out = Path(out_dir)
    report.write_mesh(out / FILES["mesh_obj"], posed.vertices[0].numpy(), model.faces(side_used).numpy())
    report.write_mesh(out / FILES["mesh_glb"], posed.vertices[0].numpy(), model.faces(side_used).numpy())
    draw = ImageDraw.Draw(rgb)
    for child, parent in enumerate(sk.PARENTS):
        if parent >= 0:
            draw.line([tuple(joints2d[parent]), tuple(joints2d[child])], fill=(30, 90, 200), width=3)
    for x, y in joints2d:
        draw.ellipse([x - 4, y - 4, x + 4, y + 4], fill=(255, 210, 0), outline=(0, 0, 0))
    with report.atomic_path(out / FILES["overlay_png"]) as tmp:
        rgb.save(tmp, format="PNG")
    messages = ["fake pipeline (tests/web): the packaged model's mean foot, not the photo's"]
    if not measured.scaled:
        messages.append("no scale reference found: put an A4 sheet or a bank card in the photo to get millimetres")
    result = {
        "version": __version__,
        "input_sha256": hashlib.sha256(data).hexdigest(),
        "side": side_used,
        "scale_source": scale_source,
        "measurements": measured.to_dict(),
        "ratios": measured.ratios(),
        "sizes": sizes.to_dict(),
        "joints2d_px": joints2d.tolist(),
        "joints3d_mm": joints3d.tolist(),
        "angles": dict.fromkeys(sk.DOF_NAMES, 0.0),
        "files": dict(FILES),
        "messages": messages,
    }
    report.write_json(out / FILES["result_json"], result)
    return result
