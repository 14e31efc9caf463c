"""HEIC / HEIF photos through pillow-heif (libheif): the primary image, and the depth image iPhones store beside it.

The primary image opens through Pillow once :func:`register` has run (libheif applies the file's rotation and
mirror, so the pixels come upright and ``info["original_orientation"]`` keeps the EXIF orientation that says
so). :func:`read_heif_depth` reads the first depth image of the primary (an auxiliary image of type
``urn:mpeg:hevc:2015:auxid:2``) with the representation libheif decodes from its depth representation SEI
(ISO/IEC 23008-2 D.3.37: uniform inverse Z, uniform disparity, uniform Z, non-uniform disparity; z_near, z_far,
d_min, d_max) and an auxiliary confidence image where the file has one (its type names "confidence").
"""

from __future__ import annotations

import io

import numpy as np

from footmesh.formats.embedded import EmbeddedDepth, Representation

HEIF_BRANDS = (b"heic", b"heix", b"hevc", b"hevx", b"heim", b"heis", b"mif1", b"msf1", b"hevm", b"hevs")
"""ISO-BMFF major brands of HEIF image files (AVIF is read by Pillow itself)."""
REPRESENTATIONS: dict[int, Representation] = {
    0: "uniform_inverse_z",
    1: "uniform_disparity",
    2: "uniform_z",
    3: "nonuniform_disparity",
}
"""libheif's heif_depth_representation_type -> ours."""
CONTAINER = "HEIF depth image"

_registered = False


def is_heif(data: bytes) -> bool:
    """Whether ``data`` starts like a HEIF image file (an ISO-BMFF ``ftyp`` box with a HEIF brand)."""
    return data[4:8] == b"ftyp" and data[8:12] in HEIF_BRANDS


def register() -> None:
    """Let ``PIL.Image.open`` read HEIC/HEIF (idempotent)."""
    global _registered
    if not _registered:
        import pillow_heif

        # pillow-heif's options are process-wide: depth and auxiliary images stay on for read_heif_depth
        pillow_heif.register_heif_opener(thumbnails=False)
        _registered = True


def _stored_bits(samples: np.ndarray) -> int:
    """Bits per sample of a decoded grey image: libheif widens 10 and 12 bits to 16 by shifting them up."""
    if samples.dtype == np.uint8:
        return 8
    used = int(np.bitwise_or.reduce(samples.ravel().astype(np.uint16)))
    shift = (used & -used).bit_length() - 1 if used else 0
    return max(8, 16 - min(shift, 8))


def _scaled(samples: np.ndarray, bits: int = 0) -> tuple[np.ndarray, int]:
    """(samples scaled to 0..1, bits per sample) of an 8- or 16-bit grey image (``bits``: 0 = infer them)."""
    bits = bits if 8 <= bits <= samples.dtype.itemsize * 8 else _stored_bits(samples)
    full = float(((1 << bits) - 1) << (samples.dtype.itemsize * 8 - bits))
    return (samples.astype(np.float32) / full).clip(0.0, 1.0), bits


def read_heif_depth(data: bytes) -> tuple[EmbeddedDepth | None, list[str]]:
    """The depth image of a HEIF photo's primary image with its meaning, and notes; (None, notes) when absent."""
    import pillow_heif

    try:
        heif = pillow_heif.open_heif(io.BytesIO(data), convert_hdr_to_8bit=False)
        depth_images = heif.info["depth_images"]
        if not depth_images:
            return None, []
        depth = depth_images[0]
        grey = np.asarray(depth.to_pillow())
        metadata = depth.info["metadata"]
        confidence = None
        for aux_type, ids in heif.info["aux"].items():
            if "confidence" in aux_type.lower():
                confidence, _ = _scaled(np.asarray(heif.get_aux_image(ids[0]).to_pillow().convert("L")))
                break
    except (ValueError, RuntimeError, OSError, EOFError, KeyError) as exc:  # libheif: a broken auxiliary image
        return None, [f"its HEIF depth image cannot be decoded ({exc}), so it was not used"]
    if grey.ndim != 2:
        return None, [f"its HEIF depth image has {grey.shape[2]} channels instead of one, so it was not used"]
    # pillow-heif gives the stored bit depth of a depth image only on its libheif handle; else infer it
    samples, bits = _scaled(grey, int(getattr(getattr(depth, "_c_image", None), "bit_depth", 0) or 0))
    kind = metadata["representation_type"] if "representation_type" in metadata else None
    if kind not in REPRESENTATIONS:
        return None, [f"its HEIF depth image has an unknown representation ({kind!r}), so it was not used"]
    return (
        EmbeddedDepth(
            samples=samples,
            representation=REPRESENTATIONS[kind],
            # libheif omits the keys the SEI does not carry
            near_m=float(metadata["z_near"]) if "z_near" in metadata else None,
            far_m=float(metadata["z_far"]) if "z_far" in metadata else None,
            container=CONTAINER,
            bits=bits,
            confidence=confidence,
        ),
        [],
    )
