"""Depth maps in Android JPEGs (Dynamic Depth 1.0 and GDepth XMP), on JPEG files the tests write.

The photos are Pillow JPEGs with APP1 segments inserted after SOI: a GDepth file carries its GDepth properties in
the standard XMP and the base64 depth PNG in extended XMP chunks; a Dynamic Depth file carries the container
directory and depth map properties in the standard XMP and the depth and confidence images after the EOI.
"""

from __future__ import annotations

import base64
import hashlib
import io
import xml.etree.ElementTree as ET
import zlib
from collections.abc import Callable

import numpy as np
import pytest
from PIL import Image

from footmesh.formats.android import read_android_depth
from footmesh.formats.embedded import EmbeddedDepth, align_depth
from footmesh.load import load_photo

W, H = 96, 72  # the photo, px (the loader takes 64 px and more)
DW, DH = 32, 24  # the depth map as stored
NEAR_M, FAR_M = 0.3, 1.2
XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
EXTENDED_XMP_HEADER = b"http://ns.adobe.com/xmp/extension/\x00"
RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
DD = "http://ns.google.com/photos/dd/1.0/"


# --- writing the files ---------------------------------------------------------------------------------------------


def photo_jpeg(w: int = W, h: int = H) -> bytes:
    """A plain Pillow JPEG: a colour gradient."""
    x, y = np.meshgrid(np.linspace(0, 255, w), np.linspace(0, 255, h))
    rgb = np.stack([x, y, 255 - x], axis=-1).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "JPEG", quality=90)
    return buf.getvalue()


def depth_ramp() -> np.ndarray:
    """(DH, DW) metres: every depth from NEAR_M to FAR_M, row by row."""
    return np.linspace(NEAR_M, FAR_M, DW * DH).reshape(DH, DW)


def depth_quadrants() -> np.ndarray:
    """(DH, DW) metres: 0.4, 0.6 / 0.8, 1.0 m quadrants."""
    z = np.empty((DH, DW))
    z[: DH // 2, : DW // 2], z[: DH // 2, DW // 2 :] = 0.4, 0.6
    z[DH // 2 :, : DW // 2], z[DH // 2 :, DW // 2 :] = 0.8, 1.0
    return z


def encode(z_m: np.ndarray, fmt: str, bits: int, near: float = NEAR_M, far: float = FAR_M) -> np.ndarray:
    """Samples of depth ``z_m`` as the GDepth / Dynamic Depth encoding stores them (uint8 or uint16)."""
    if fmt == "RangeLinear":
        v = (z_m - near) / (far - near)
    else:  # RangeInverse: v = 0 at near, 1 at far
        v = far * (z_m - near) / (z_m * (far - near))
    full = (1 << bits) - 1
    return np.round(np.clip(v, 0, 1) * full).astype(np.uint8 if bits == 8 else np.uint16)


def half_step_m(fmt: str, bits: int) -> float:
    """The largest depth error of rounding a sample (half a quantisation step), metres, over NEAR_M..FAR_M."""
    full = (1 << bits) - 1
    # dz/dv: far - near for RangeLinear; far near (far - near) / (far - v (far - near))^2, largest at v = 1
    slope = FAR_M - NEAR_M if fmt == "RangeLinear" else FAR_M * (FAR_M - NEAR_M) / NEAR_M
    return 0.5 * slope / full + 1e-6


def png(samples: np.ndarray) -> bytes:
    """An 8-bit (uint8) or 16-bit (uint16) grey PNG, or a colour one for (h, w, 3)."""
    buf = io.BytesIO()
    Image.fromarray(samples).save(buf, "PNG")
    return buf.getvalue()


def grey_jpeg(samples: np.ndarray) -> bytes:
    """An 8-bit grey JPEG, as the Android camera service writes depth and confidence."""
    buf = io.BytesIO()
    Image.fromarray(samples).save(buf, "JPEG", quality=95)
    return buf.getvalue()


def app1(payload: bytes) -> bytes:
    """One APP1 segment: marker, 2-byte length counting itself, payload."""
    assert len(payload) + 2 <= 0xFFFF
    return b"\xff\xe1" + (len(payload) + 2).to_bytes(2, "big") + payload


def with_segments(jpeg: bytes, segments: list[bytes]) -> bytes:
    """``jpeg`` with ``segments`` inserted right after SOI."""
    return jpeg[:2] + b"".join(segments) + jpeg[2:]


def xmp_packet(namespaces: dict[str, str], attributes: dict[str, str | None], body: str = "") -> bytes:
    """A serialised XMP packet (xpacket wrapper and trailing padding, as cameras write) with one rdf:Description."""
    xmlns = " ".join(f'xmlns:{prefix}="{uri}"' for prefix, uri in namespaces.items())
    attrs = " ".join(f'{key}="{value}"' for key, value in attributes.items() if value is not None)
    return (
        '<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>'
        f'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="{RDF}">'
        f'<rdf:Description rdf:about="" {xmlns} {attrs}>{body}</rdf:Description>'
        "</rdf:RDF></x:xmpmeta>" + " " * 200 + '<?xpacket end="w"?>'
    ).encode()


def gdepth_jpeg(
    depth_image: bytes,
    *,
    fmt: str = "RangeLinear",
    near: float | None = NEAR_M,
    far: float | None = FAR_M,
    units: str | None = "m",
    measure: str | None = None,
    mime: str = "image/png",
    confidence: bytes | None = None,
    data_text: str | None = None,
    chunk_size: int = 65000,
    reorder: Callable[[list[bytes]], list[bytes]] = lambda segments: segments,
    named_guid: str | None = "md5",
) -> bytes:
    """A GDepth JPEG: GDepth properties and xmpNote:HasExtendedXMP in the standard XMP, the base64 depth image
    (``data_text`` overrides it) and confidence in extended XMP chunks of at most ``chunk_size`` bytes.

    ``named_guid``: what HasExtendedXMP names ("md5": the chunks' GUID, as the XMP spec says; None: nothing).
    """
    namespaces = {"GDepth": "http://ns.google.com/photos/1.0/depthmap/"}
    extended = xmp_packet(
        namespaces,
        {
            "GDepth:Data": base64.b64encode(depth_image).decode() if data_text is None else data_text,
            "GDepth:ConfidenceData": None if confidence is None else base64.b64encode(confidence).decode(),
        },
    )
    guid = hashlib.md5(extended).hexdigest().upper().encode()
    standard = xmp_packet(
        namespaces | {"xmpNote": "http://ns.adobe.com/xmp/note/"},
        {
            "GDepth:Format": fmt,
            "GDepth:Near": None if near is None else f"{near:g}",
            "GDepth:Far": None if far is None else f"{far:g}",
            "GDepth:Units": units,
            "GDepth:MeasureType": measure,
            "GDepth:Mime": mime,
            "GDepth:ConfidenceMime": None if confidence is None else "image/png",
            "xmpNote:HasExtendedXMP": guid.decode() if named_guid == "md5" else named_guid,
        },
    )
    chunks = [
        EXTENDED_XMP_HEADER
        + guid
        + len(extended).to_bytes(4, "big")
        + offset.to_bytes(4, "big")
        + extended[offset : offset + chunk_size]
        for offset in range(0, len(extended), chunk_size)
    ]
    return with_segments(photo_jpeg(), [app1(XMP_HEADER + standard), *map(app1, reorder(chunks))])


def dd_item(properties: dict[str, str], elements: bool) -> str:
    """One rdf:li of the container directory, its Item properties as attributes or as elements."""
    if elements:
        inner = "".join(f"<Item:{key}>{value}</Item:{key}>" for key, value in properties.items())
        item = f'<Container:Item rdf:parseType="Resource">{inner}</Container:Item>'
    else:
        item = "<Container:Item " + " ".join(f'Item:{key}="{value}"' for key, value in properties.items()) + "/>"
    return f'<rdf:li rdf:parseType="Resource">{item}</rdf:li>'


def dynamic_depth_jpeg(
    depth_image: bytes,
    *,
    fmt: str = "RangeInverse",
    near: float = NEAR_M,
    far: float = FAR_M,
    units: str | None = "Meters",
    measure: str | None = None,
    depth_mime: str = "image/png",
    confidence: bytes | None = None,
    confidence_mime: str = "image/png",
    depth_uri: str = "android/depthmap",
    depth_semantic: str = "Depth",
    before_depth: tuple[tuple[str, bytes], ...] = (),
    elements: bool = False,
    cut_tail: int = 0,
) -> bytes:
    """A Dynamic Depth JPEG: container directory and first camera's DepthMap in the standard XMP, then after the
    primary's EOI the items ``before_depth`` ((DataURI, bytes)), the depth image and the confidence image; the last
    ``cut_tail`` bytes dropped."""
    items = [{"Mime": "image/jpeg", "Semantic": "Primary", "Length": "0", "DataURI": "primary_image"}]
    payloads = []
    for uri, blob in before_depth:
        items.append({"Mime": "image/jpeg", "Semantic": "Original", "Length": str(len(blob)), "DataURI": uri})
        payloads.append(blob)
    items.append(
        {"Mime": depth_mime, "Semantic": depth_semantic, "Length": str(len(depth_image)), "DataURI": "android/depthmap"}
    )
    payloads.append(depth_image)
    if confidence is not None:
        items.append(
            {
                "Mime": confidence_mime,
                "Semantic": "Confidence",
                "Length": str(len(confidence)),
                "DataURI": "android/confidencemap",
            }
        )
        payloads.append(confidence)
    depth_map = {
        "Format": fmt,
        "Near": f"{near:g}",
        "Far": f"{far:g}",
        "Units": units,
        "MeasureType": measure,
        "DepthURI": depth_uri,
        "ConfidenceURI": None if confidence is None else "android/confidencemap",
    }
    depth_map = {key: value for key, value in depth_map.items() if value is not None}
    if elements:
        inner = "".join(f"<DepthMap:{key}>{value}</DepthMap:{key}>" for key, value in depth_map.items())
        camera_depth = f'<Camera:DepthMap rdf:parseType="Resource">{inner}</Camera:DepthMap>'
    else:
        camera_depth = "<Camera:DepthMap " + " ".join(f'DepthMap:{k}="{v}"' for k, v in depth_map.items()) + "/>"
    body = (
        "<Device:Container><Container:Directory><rdf:Seq>"
        + "".join(dd_item(item, elements) for item in items)
        + "</rdf:Seq></Container:Directory></Device:Container>"
        '<Device:Cameras><rdf:Seq><rdf:li rdf:parseType="Resource"><Device:Camera Camera:Trait="Physical">'
        f"{camera_depth}</Device:Camera></rdf:li></rdf:Seq></Device:Cameras>"
    )
    namespaces = {name: f"{DD}{name.lower()}/" for name in ("Device", "Container", "Item", "Camera", "DepthMap")}
    standard = xmp_packet(namespaces, {}, body)
    data = with_segments(photo_jpeg(), [app1(XMP_HEADER + standard)]) + b"".join(payloads)
    return data[: len(data) - cut_tail]


def read_ok(data: bytes) -> EmbeddedDepth:
    depth, notes = read_android_depth(data)
    assert depth is not None, notes
    return depth


# --- depth that decodes --------------------------------------------------------------------------------------------


@pytest.mark.parametrize("bits", [8, 16])
@pytest.mark.parametrize("fmt", ["RangeLinear", "RangeInverse"])
def test_gdepth_samples_decode_to_the_depths_encoded(fmt, bits):
    z = depth_ramp()
    depth, notes = read_android_depth(gdepth_jpeg(png(encode(z, fmt, bits)), fmt=fmt))
    assert notes == []
    assert depth.container == "GDepth XMP" and depth.bits == bits
    assert depth.representation == {"RangeLinear": "range_linear", "RangeInverse": "range_inverse"}[fmt]
    assert (depth.near_m, depth.far_m, depth.measure, depth.confidence) == (NEAR_M, FAR_M, "optical_axis", None)
    assert depth.size == (DW, DH) and not depth.upright
    assert depth.why_not_metric() is None
    np.testing.assert_allclose(depth.metres(), z, atol=half_step_m(fmt, bits), rtol=0)


@pytest.mark.parametrize("elements", [False, True], ids=["attributes", "elements"])
@pytest.mark.parametrize("fmt", ["RangeLinear", "RangeInverse"])
def test_dynamic_depth_samples_and_confidence_decode_from_the_items_after_the_photo(fmt, elements):
    z = depth_ramp()
    confidence = np.tile(np.linspace(0, 255, DW).astype(np.uint8), (DH, 1))
    data = dynamic_depth_jpeg(png(encode(z, fmt, 16)), fmt=fmt, confidence=png(confidence), elements=elements)
    depth, notes = read_android_depth(data)
    assert notes == []
    assert depth.container == "Dynamic Depth" and depth.bits == 16 and depth.measure == "optical_axis"
    assert (depth.near_m, depth.far_m) == (NEAR_M, FAR_M)
    np.testing.assert_allclose(depth.metres(), z, atol=half_step_m(fmt, 16), rtol=0)
    np.testing.assert_allclose(depth.confidence, confidence / 255.0, atol=1e-6)


def test_dynamic_depth_8bit_jpeg_items_as_the_android_camera_service_writes_them():
    z = depth_quadrants()
    conf = np.full((DH, DW), 255, np.uint8)
    conf[:, : DW // 4] = 0
    data = dynamic_depth_jpeg(
        grey_jpeg(encode(z, "RangeInverse", 8)),
        depth_mime="image/jpeg",
        confidence=grey_jpeg(conf),
        confidence_mime="image/jpeg",
    )
    depth = read_ok(data)
    assert depth.bits == 8
    metres = depth.metres()
    for rows, cols in [(slice(2, 10), slice(2, 14)), (slice(14, 22), slice(18, 30))]:  # quadrant interiors
        assert abs(np.median(metres[rows, cols]) - z[rows, cols][0, 0]) < 2 * half_step_m("RangeInverse", 8)
    assert depth.confidence[:, 2:6].max() < 0.1 and depth.confidence[:, 12:].min() > 0.9


def test_gdepth_confidence_is_read():
    conf = np.tile(np.linspace(0, 255, DH).astype(np.uint8)[:, None], (1, DW))
    depth = read_ok(gdepth_jpeg(png(encode(depth_ramp(), "RangeLinear", 8)), confidence=png(conf)))
    np.testing.assert_allclose(depth.confidence, conf / 255.0, atol=1e-6)


@pytest.mark.parametrize("container", ["GDepth", "Dynamic Depth"])
def test_optic_ray_measure_type_is_passed_through(container):
    image = png(encode(depth_ramp(), "RangeLinear", 8))
    write = gdepth_jpeg if container == "GDepth" else dynamic_depth_jpeg
    assert read_ok(write(image, fmt="RangeLinear", measure="OpticRay")).measure == "optic_ray"


def test_gdepth_near_and_far_in_millimetres_become_metres():
    z = depth_ramp()
    depth = read_ok(gdepth_jpeg(png(encode(z, "RangeLinear", 16)), near=300, far=1200, units="mm"))
    assert depth.near_m == pytest.approx(NEAR_M) and depth.far_m == pytest.approx(FAR_M)
    np.testing.assert_allclose(depth.metres(), z, atol=half_step_m("RangeLinear", 16), rtol=0)


def test_gdepth_without_units_is_in_metres():
    depth = read_ok(gdepth_jpeg(png(encode(depth_ramp(), "RangeLinear", 8)), units=None))
    assert (depth.near_m, depth.far_m) == (NEAR_M, FAR_M)


def test_gdepth_without_near_and_far_says_so_rather_than_guessing():
    depth = read_ok(gdepth_jpeg(png(encode(depth_ramp(), "RangeLinear", 8)), near=None, far=None))
    assert depth.near_m is None and depth.far_m is None
    assert "does not state its near and far range" in depth.why_not_metric()


def test_extended_xmp_chunks_out_of_order_still_decode():
    rng = np.random.default_rng(1)
    samples = rng.integers(0, 65536, (DH, DW), dtype=np.uint16)  # noise: a PNG that spans several chunks
    order = rng.permutation(64)

    def shuffle(chunks: list[bytes]) -> list[bytes]:
        assert len(chunks) >= 4
        return [chunks[i] for i in order if i < len(chunks)]

    depth = read_ok(gdepth_jpeg(png(samples), chunk_size=600, reorder=shuffle))
    np.testing.assert_array_equal(np.round(depth.samples * 65535).astype(np.uint16), samples)


def test_gdepth_extended_xmp_is_found_when_the_standard_xmp_names_none():
    z = depth_ramp()
    depth = read_ok(gdepth_jpeg(png(encode(z, "RangeLinear", 16)), named_guid=None, chunk_size=100))
    np.testing.assert_allclose(depth.metres(), z, atol=half_step_m("RangeLinear", 16), rtol=0)


def test_dynamic_depth_item_is_found_after_other_items():
    z = depth_ramp()
    data = dynamic_depth_jpeg(
        png(encode(z, "RangeInverse", 16)), before_depth=(("android/originalimage", photo_jpeg()),)
    )
    np.testing.assert_allclose(read_ok(data).metres(), z, atol=half_step_m("RangeInverse", 16), rtol=0)


def test_dynamic_depth_item_is_found_by_its_semantic_when_the_depth_uri_names_none():
    data = dynamic_depth_jpeg(png(encode(depth_ramp(), "RangeInverse", 8)), depth_uri="android/elsewhere")
    assert read_ok(data).bits == 8


def test_colour_depth_image_uses_its_first_channel_with_a_note():
    grey = encode(depth_ramp(), "RangeLinear", 8)
    depth, notes = read_android_depth(gdepth_jpeg(png(np.stack([grey, grey // 2, grey // 3], axis=-1))))
    np.testing.assert_allclose(depth.samples, grey / 255.0, atol=1e-6)
    assert notes == ["its GDepth XMP depth map is in RGB mode, not grey; its first channel was used"]


def test_embedded_depth_aligns_to_millimetres_of_the_photo():
    z = depth_quadrants()
    depth = read_ok(dynamic_depth_jpeg(png(encode(z, "RangeLinear", 16)), fmt="RangeLinear"))
    mm, source, why = align_depth(depth, 1, (W, H), 50.0, 50.0, (W - 1) / 2, (H - 1) / 2)
    assert why is None and mm.shape == (H, W) and source.container == "Dynamic Depth"
    assert mm[5, 5] == pytest.approx(400, abs=0.1) and mm[H - 5, W - 5] == pytest.approx(1000, abs=0.1)


@pytest.mark.parametrize("container", ["GDepth XMP", "Dynamic Depth"])
def test_an_android_depth_photo_loads_as_rgbd_without_flags(tmp_path, container):
    samples = png(encode(depth_quadrants(), "RangeInverse", 16))
    data = gdepth_jpeg(samples, fmt="RangeInverse") if container == "GDepth XMP" else dynamic_depth_jpeg(samples)
    path = tmp_path / "PXL_0001.jpg"
    path.write_bytes(data)
    photo = load_photo(path)
    assert photo.depth_source.container == container and photo.depth_source.representation == "range_inverse"
    assert photo.depth_mm.shape == (H, W) and photo.depth_mm[5, 5] == pytest.approx(400, abs=1.0)
    assert load_photo(path, embedded_depth=False).depth_mm is None


# --- no depth, or depth that cannot be used ------------------------------------------------------------------------


def test_plain_jpeg_has_no_depth_and_no_notes():
    assert read_android_depth(photo_jpeg()) == (None, [])
    assert read_android_depth(b"") == (None, [])


def test_jpeg_with_other_xmp_has_no_depth_and_its_xml_is_not_parsed(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("XML parsed for a JPEG without depth metadata")

    monkeypatch.setattr(ET, "fromstring", refuse)
    xmp = xmp_packet({"xmp": "http://ns.adobe.com/xap/1.0/"}, {"xmp:CreatorTool": "a camera"})
    exif = Image.Exif()
    exif[0x0112] = 6
    data = with_segments(photo_jpeg(), [app1(b"Exif\x00\x00" + exif.tobytes()), app1(XMP_HEADER + xmp)])
    assert read_android_depth(data) == (None, [])


def _png_ramp() -> bytes:
    return png(encode(depth_ramp(), "RangeLinear", 16))


def _flipped(blob: bytes) -> bytes:
    """``blob`` with the middle of its compressed data overwritten."""
    middle = len(blob) // 2
    return blob[:middle] + bytes(64) + blob[middle + 64 :]


def _without_chunk(chunks: list[bytes]) -> list[bytes]:
    return chunks[:1] + chunks[2:]


def _png_claiming(width: int, height: int) -> bytes:
    """A 1 x 1 grey PNG whose header claims ``width`` x ``height`` px (a decompression bomb's first bytes)."""
    blob = bytearray(png(np.zeros((1, 1), np.uint8)))
    blob[16:24] = width.to_bytes(4, "big") + height.to_bytes(4, "big")  # IHDR data starts at byte 16
    blob[29:33] = zlib.crc32(bytes(blob[12:29])).to_bytes(4, "big")  # CRC of "IHDR" and its 13 bytes
    return bytes(blob)


BROKEN = {
    "gdepth truncated base64": (
        lambda: gdepth_jpeg(b"", data_text=base64.b64encode(_png_ramp()).decode()[:-3]),
        "base64",
    ),
    "gdepth truncated png": (lambda: gdepth_jpeg(_png_ramp()[: len(_png_ramp()) // 2]), "cannot be decoded"),
    "gdepth corrupt png": (lambda: gdepth_jpeg(_flipped(_png_ramp())), "cannot be decoded"),
    "gdepth not an image": (lambda: gdepth_jpeg(b"not an image at all"), "not a PNG or JPEG"),
    "gdepth extended xmp chunk missing": (
        lambda: gdepth_jpeg(_png_ramp(), chunk_size=500, reorder=_without_chunk),
        "incomplete",
    ),
    "gdepth extended xmp named is absent": (
        lambda: gdepth_jpeg(_png_ramp(), named_guid="0" * 32),
        "the extended XMP that should hold GDepth:Data is not in the file",
    ),
    "gdepth png claiming 49 MP": (lambda: gdepth_jpeg(_png_claiming(7000, 7000)), "7000 x 7000"),
    "gdepth unknown format": (lambda: gdepth_jpeg(_png_ramp(), fmt="RangeCubic"), "RangeCubic"),
    "gdepth unknown units": (lambda: gdepth_jpeg(_png_ramp(), units="furlong"), "furlong"),
    "dd depth item missing": (
        lambda: dynamic_depth_jpeg(_png_ramp(), depth_uri="android/none", depth_semantic="X"),
        "android/none",
    ),
    "dd file truncated": (lambda: dynamic_depth_jpeg(_png_ramp(), cut_tail=100), "truncated"),
    "dd corrupt png": (lambda: dynamic_depth_jpeg(_flipped(_png_ramp())), "cannot be decoded"),
    "dd diopters": (lambda: dynamic_depth_jpeg(_png_ramp(), units="Diopters"), "Diopters"),
    "dd broken xml": (
        lambda: dynamic_depth_jpeg(_png_ramp()).replace(b"</Container:Directory>", b"</Container:Directorz>"),
        "not well-formed XML",
    ),
}


@pytest.mark.parametrize("case", BROKEN, ids=list(BROKEN))
def test_broken_embedded_depth_gives_one_note_and_no_depth(case):
    write, says = BROKEN[case]
    depth, notes = read_android_depth(write())
    assert depth is None
    assert len(notes) == 1 and says in notes[0], notes
    assert notes[0].startswith("its ") and notes[0].endswith("so it was not used")


def test_extended_xmp_declaring_more_than_the_cap_is_refused():
    standard = xmp_packet({"GDepth": "http://ns.google.com/photos/1.0/depthmap/"}, {"GDepth:Format": "RangeLinear"})
    chunk = EXTENDED_XMP_HEADER + b"0" * 32 + (1 << 31).to_bytes(4, "big") + bytes(4) + b"<x:xmpmeta"
    depth, notes = read_android_depth(with_segments(photo_jpeg(), [app1(XMP_HEADER + standard), app1(chunk)]))
    assert depth is None and len(notes) == 1 and "MiB" in notes[0]


def test_broken_confidence_costs_only_the_confidence():
    z = depth_ramp()
    depth, notes = read_android_depth(dynamic_depth_jpeg(png(encode(z, "RangeInverse", 16)), confidence=b"junk"))
    assert depth is not None and depth.confidence is None
    assert len(notes) == 1 and notes[0].startswith("its Dynamic Depth confidence map cannot be decoded")


@pytest.mark.parametrize("write", [gdepth_jpeg, dynamic_depth_jpeg], ids=["GDepth", "Dynamic Depth"])
def test_damaged_files_never_raise(write):
    data = write(png(encode(depth_ramp(), "RangeLinear", 8)), fmt="RangeLinear")
    rng = np.random.default_rng(2)
    for cut in rng.integers(0, len(data), 40):
        depth, notes = read_android_depth(data[:cut])
        assert depth is None or isinstance(depth, EmbeddedDepth)
        assert all(isinstance(note, str) for note in notes)
    for at in rng.integers(2, len(data) - 8, 40):
        damaged = data[:at] + bytes(rng.integers(0, 256, 8, dtype=np.uint8)) + data[at + 8 :]
        depth, notes = read_android_depth(damaged)
        assert depth is None or isinstance(depth, EmbeddedDepth)
