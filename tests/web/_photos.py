"""Photos the web tests make on the fly (a rendered foot on an A4 sheet; PNG bytes of an array). A module of its own
name, not conftest: ``from conftest import ...`` takes whichever conftest.py pytest imported last."""

from __future__ import annotations

import io

import numpy as np
from PIL import Image

DEMO_SEED, DEMO_INDEX = 1, 6
"""A synthetic scene of a foot standing on an A4 sheet, seen from above (the page's demo photo)."""


def render_demo_photo(size: int = 320, quality: int = 90) -> bytes:
    """The demo photo as JPEG bytes: a synthetic foot on an A4 sheet (``footmesh.synth``), ``size`` px square."""
    from footmesh.synth.render import Renderer
    from footmesh.synth.scene import SynthConfig

    config = SynthConfig(size=size, reference="a4", lifted_fraction=0.0, elevation_deg=(55.0, 80.0))
    rgb = Renderer(config).render(DEMO_SEED, DEMO_INDEX)["rgb"]
    buffer = io.BytesIO()
    Image.fromarray(rgb).save(buffer, format="JPEG", quality=quality)
    return buffer.getvalue()


def png_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(array).save(buffer, format="PNG")
    return buffer.getvalue()
