"""Test scaffolding for process isolation: a measure function without torch, so that the forkserver and each job
start in a moment. Writes only ``result.json``; refuses a photo with no contrast like ``_fake_pipeline``."""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

from PIL import Image, ImageStat

from footmesh.errors import Refusal

NO_FOOT_GREY_SD = 6.0


@dataclass(frozen=True)
class StubMeasure:
    """Picklable ``measure(image, out_dir, **options)`` that sleeps ``delay_s`` first; its result names the process
    that measured (``pid``); ``crash``: the process dies instead (as a segfault would take it)."""

    delay_s: float = 0.0
    crash: bool = False

    def __call__(self, image: Path, out_dir: Path, **options) -> dict:
        with Image.open(image) as img:
            if ImageStat.Stat(img.convert("L")).stddev[0] < NO_FOOT_GREY_SD:
                raise Refusal("no foot found in the photo")
        time.sleep(self.delay_s)
        if self.crash:
            os._exit(3)
        result = {"side": options.get("side", "auto"), "scale_source": "none", "files": {"result_json": "result.json"}}
        result["pid"] = os.getpid()
        (Path(out_dir) / "result.json").write_text(json.dumps(result))
        return result
