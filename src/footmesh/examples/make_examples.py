"""Render the bundled example photos of ``footmesh demo`` (``python -m footmesh.examples.make_examples``).

Three synthetic phone photos with known truth, chosen as the first samples of fixed seeds that show what the
demo needs: a left foot beside an A4 sheet (RGB, focal length in EXIF), a right foot with a depth map (RGB-D,
K.json), and a right foot with a bank card (RGB, K.json); seen from the side, the reference object whole in view
(as the photo guide asks) and found by the detector. ``truth.json`` holds the true measurements.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from PIL import Image

from footmesh.cues.reference import detect_reference
from footmesh.eval.measure import true_measurements
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig

HERE = Path(__file__).parent
SIZE = 960
SEARCH_SIZE = 160
SEED = 20261122
EXAMPLES = (  # name, reference, side wanted, depth
    ("a4_left", "a4", "left", False),
    ("depth_right", "none", "right", True),
    ("card_right", "card", "right", False),
)


def _wanted(sample: dict, side: str, size: int) -> bool:
    # the way the photo guide asks: from the side and above, so that heel and toes are both in view
    foot_axis_z = abs(float(sample["cam_from_foot"][2, 0]))
    visible = foot_axis_z < 0.5
    margin = 0.03 * size
    inside = (sample["joints2d"] > margin).all() and (sample["joints2d"] < size - margin).all()
    ref_ok = bool(np.all(sample["ref_corners_visible"])) if int(sample["ref_type"]) else True
    return (
        (int(sample["side"]) == (side == "right"))
        and not bool(sample["lifted"])
        and visible
        and bool(inside)
        and ref_ok
    )


def main() -> None:
    truth = {}
    for k, (name, reference, side, depth) in enumerate(EXAMPLES):
        seed = SEED + k
        # search at a small size (the scene does not depend on it), render the chosen one at full size
        finder = Renderer(SynthConfig(size=SEARCH_SIZE, reference=reference, frame_reference=True))
        full = Renderer(SynthConfig(size=SIZE, reference=reference, frame_reference=True))
        index = 0
        while True:
            if _wanted(finder.render(seed, index), side, SEARCH_SIZE):
                sample = full.render(seed, index)
                # the photo guide asks for the whole object in view; the demo shows such a photo
                if reference == "none" or detect_reference(
                    sample["rgb"], sample["K"], exclude_mask=sample["labels"] == 1
                ):
                    break
            index += 1
        K = sample["K"]
        exif = Image.Exif()
        if not depth and reference == "a4":
            # 35 mm-equivalent focal length from K, so that the A4 example exercises the EXIF path
            exif_ifd = exif.get_ifd(0x8769)
            exif_ifd[0xA405] = int(round(K[0, 0] * 43.27 / math.hypot(SIZE, SIZE)))
        Image.fromarray(sample["rgb"]).save(HERE / f"{name}.jpg", quality=92, exif=exif.tobytes())
        if reference != "a4" or depth:
            k_json = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "width": SIZE, "height": SIZE}
            (HERE / f"{name}.K.json").write_text(json.dumps({k: float(v) for k, v in k_json.items()}, indent=1))
        if depth:
            Image.fromarray(sample["depth"].astype(np.uint16)).save(HERE / f"{name}.depth.png")
        values = true_measurements(sample["shape"], side)
        truth[name] = {"seed": seed, "index": index, "side": side, "reference": reference, "measurements_mm": values}
        print(name, index, {k: round(v, 1) for k, v in values.items()})
    (HERE / "truth.json").write_text(json.dumps(truth, indent=1))


if __name__ == "__main__":
    main()
