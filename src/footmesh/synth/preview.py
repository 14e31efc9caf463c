"""Contact sheet of synthetic samples: the image with its silhouette outline, joints and reference corners."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence

import numpy as np

from footmesh.model import skeleton as sk

BRANCH_COLOURS = ((230, 25, 75), (245, 130, 48), (255, 225, 25), (60, 180, 75), (0, 130, 200), (145, 30, 180))
"""Toes 1-5 and the heel branch (``skeleton.BRANCHES`` order); the midfoot is white."""
OUTLINE = (0, 255, 255)
REFERENCE = (255, 0, 255)


def draw_sample(sample: dict[str, np.ndarray], scale: int = 2) -> np.ndarray:
    """(S*scale, S*scale, 3) uint8 picture of one sample with its labels drawn (occluded joints hollow)."""
    from PIL import Image, ImageDraw

    rgb = sample["rgb"]
    size = rgb.shape[0]
    img = Image.fromarray(rgb).resize((size * scale, size * scale), Image.Resampling.NEAREST)
    sil = sample["silhouette"]
    edge = sil & ~(
        np.pad(sil, 1)[:-2, 1:-1] & np.pad(sil, 1)[2:, 1:-1] & np.pad(sil, 1)[1:-1, :-2] & np.pad(sil, 1)[1:-1, 2:]
    )
    arr = np.asarray(img).copy()
    arr[np.kron(edge, np.ones((scale, scale), dtype=bool))] = OUTLINE
    img = Image.fromarray(arr)
    draw = ImageDraw.Draw(img)

    def px(p: np.ndarray) -> tuple[float, float]:  # pixel centre coordinates -> picture coordinates
        return ((p[0] + 0.5) * scale, (p[1] + 0.5) * scale)

    j2d, vis = sample["joints2d"], sample["joints_visible"]
    for colour, chain in zip(BRANCH_COLOURS, sk.BRANCHES, strict=True):
        points = [px(j2d[0])] + [px(j2d[j]) for j in chain]
        draw.line(points, fill=colour, width=max(1, scale // 2))
        for j in chain:
            x, y = px(j2d[j])
            r = 1.5 * scale
            draw.ellipse((x - r, y - r, x + r, y + r), outline=colour, fill=colour if vis[j] else None)
    x, y = px(j2d[0])
    draw.ellipse((x - 2 * scale, y - 2 * scale, x + 2 * scale, y + 2 * scale), outline=(255, 255, 255))
    if int(sample["ref_type"]) > 0:
        corners = sample["ref_corners2d"]
        if np.all(np.isfinite(corners)):
            pts = [px(c) for c in corners]
            draw.line([*pts, pts[0]], fill=REFERENCE, width=1)
            for c, v in zip(pts, sample["ref_corners_visible"], strict=True):
                r = 2 * scale
                draw.rectangle(
                    (c[0] - r, c[1] - r, c[0] + r, c[1] + r), outline=REFERENCE, fill=REFERENCE if v else None
                )
    return np.asarray(img)


def contact_sheet(samples: Sequence[dict[str, np.ndarray]], columns: int | None = None, scale: int = 1) -> np.ndarray:
    """Tile drawn samples into one (rows*H, cols*W, 3) uint8 image, with a 2-pixel gap."""
    from footmesh.viz import tile_images

    tiles = [draw_sample(s, scale) for s in samples]
    if not tiles:
        raise ValueError("contact sheet: no samples")
    return tile_images(tiles, columns or math.ceil(math.sqrt(len(tiles))))


def write_preview(path: str | os.PathLike, samples: Sequence[dict[str, np.ndarray]], scale: int = 2) -> None:
    """Write a contact sheet PNG atomically."""
    from PIL import Image

    from footmesh.report import atomic_path

    with atomic_path(path) as tmp:
        Image.fromarray(contact_sheet(samples, scale=scale)).save(tmp, format="PNG")
