"""The file formats footmesh accepts, in one table: the loader, the CLI's help and the web's uploads all read it.

Adding a photo or depth format = one ``FileFormat`` entry here (and, if Pillow cannot open it, a reader in
``footmesh.formats``).
"""

from __future__ import annotations

from dataclasses import dataclass

from footmesh.formats.heif import HEIF_BRANDS


@dataclass(frozen=True)
class FileFormat:
    """One accepted file format."""

    name: str
    """What people call it (messages and help)."""
    pillow: tuple[str, ...]
    """Pillow's plugins that open it (``Image.open(formats=...)``); empty for formats Pillow does not open."""
    suffix: str
    """The suffix a web upload of it is saved with."""
    signatures: tuple[tuple[int, bytes], ...]
    """(offset, bytes) its files start with: a file that starts so but does not open is corrupt, not foreign."""
    opened_as: tuple[str, ...] = ()
    """Further ``Image.format`` names its files may open as (a plugin's variants)."""

    @property
    def image_formats(self) -> tuple[str, ...]:
        """Every ``Image.format`` a file of this format opens as."""
        return self.pillow + self.opened_as


JPEG = FileFormat("JPEG", ("JPEG",), ".jpg", ((0, b"\xff\xd8\xff"),), opened_as=("MPO",))
"""MPO: phones' JPEGs with a multi-picture index (Android depth photos, Samsung) open as Pillow's MPO."""
PNG = FileFormat("PNG", ("PNG",), ".png", ((0, b"\x89PNG\r\n\x1a\n"),))
WEBP = FileFormat("WebP", ("WEBP",), ".webp", ((0, b"RIFF"),))
TIFF = FileFormat("TIFF", ("TIFF",), ".tiff", ((0, b"II*\x00"), (0, b"MM\x00*")))
HEIC = FileFormat("HEIC", ("HEIF",), ".heic", tuple((4, b"ftyp" + brand) for brand in HEIF_BRANDS))
BMP = FileFormat("BMP", ("BMP",), ".bmp", ((0, b"BM"),))
NPY = FileFormat(".npy", (), ".npy", ((0, b"\x93NUMPY"),))

PHOTO_FORMATS: tuple[FileFormat, ...] = (JPEG, PNG, WEBP, TIFF, HEIC, BMP)
"""Photos (EXIF orientation honoured; HEIC and Android JPEGs may carry a depth map: ``footmesh.formats``)."""
DEPTH_IMAGE_FORMATS: tuple[FileFormat, ...] = (PNG, TIFF)
"""Depth maps as single-channel 16-bit (mm) or float images."""
DEPTH_FORMATS: tuple[FileFormat, ...] = (*DEPTH_IMAGE_FORMATS, NPY)
"""Depth maps: 16-bit PNG / TIFF in mm, or a 2D ``.npy`` array (integer mm, or float in the declared unit)."""


def pillow_names(formats: tuple[FileFormat, ...]) -> tuple[str, ...]:
    """The Pillow plugins that open ``formats`` (for ``Image.open(formats=...)``)."""
    return tuple(name for f in formats for name in f.pillow)


def format_of(image_format: str | None, formats: tuple[FileFormat, ...]) -> FileFormat | None:
    """The entry of ``formats`` that an opened image's ``Image.format`` belongs to, or None."""
    return next((f for f in formats if image_format in f.image_formats), None)


def started_like(head: bytes, formats: tuple[FileFormat, ...]) -> FileFormat | None:
    """The entry of ``formats`` whose signature ``head`` (a file's first bytes) starts with, or None."""
    for f in formats:
        for offset, magic in f.signatures:
            if head[offset : offset + len(magic)] == magic and (f is not WEBP or head[8:12] == b"WEBP"):
                return f
    return None


def listed(formats: tuple[FileFormat, ...], what: str) -> str:
    """``"a JPEG, PNG or WebP photo"``: the formats in words."""
    names = [f.name for f in formats]
    words = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} or {names[-1]}"
    return f"a {words} {what}"


PHOTO_HELP = listed(PHOTO_FORMATS, "photo")
DEPTH_HELP = "a 16-bit PNG or TIFF depth map in mm, or a 2D .npy array (integer mm, or float in the declared unit)"
