"""Depth maps inside Android camera JPEGs: Dynamic Depth 1.0 and the older GDepth XMP.

Both live in the JPEG's XMP (Adobe XMP Specification Part 3, 1.1.3: the standard XMP in one APP1 segment, and
the extended XMP split over further APP1 segments, named by ``xmpNote:HasExtendedXMP``):

- Dynamic Depth 1.0 (Google, 2019; Pixel phones and the Android camera service): the standard XMP's
  ``Container:Directory`` lists items (``Item:Mime``, ``Item:Length``, ``Item:Padding``, ``Item:DataURI``,
  ``Item:Semantic``) whose bytes follow the primary JPEG's EOI in directory order, the primary image first; the
  first camera's ``Camera:DepthMap`` (``Format``, ``Near``, ``Far``, ``Units``, ``MeasureType``, ``DepthURI``,
  ``ConfidenceURI``) says what the depth item holds.
- GDepth (Google's "depthmap metadata", Google Camera lens blur and portrait): ``GDepth:Format``, ``Near``,
  ``Far``, ``Units``, ``MeasureType``, ``Mime`` in the standard XMP, the base64 depth image ``GDepth:Data`` (and
  ``ConfidenceData``) normally in the extended XMP.

Either stores an 8- or 16-bit grey PNG or an 8-bit JPEG of samples v in 0..1: RangeLinear d = near + v (far -
near), RangeInverse d = far near / (far - v (far - near)), d along the optical axis or along each pixel's ray.
:func:`read_android_depth` returns them as an :class:`~footmesh.formats.embedded.EmbeddedDepth`; a broken
container gives a note, never an exception, since the photo itself is still good.
"""

from __future__ import annotations

import base64
import binascii
import io
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from typing import Literal

import numpy as np
from PIL import Image

from footmesh.formats.embedded import EmbeddedDepth, Representation

XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
"""How the APP1 segment of the standard XMP starts."""
EXTENDED_XMP_HEADER = b"http://ns.adobe.com/xmp/extension/\x00"
"""How each APP1 segment of the extended XMP starts (then a 32-byte GUID, full length, offset, chunk)."""
XMP_NOTE_NS = "http://ns.adobe.com/xmp/note/"
"""Namespace of ``xmpNote:HasExtendedXMP``, the GUID of the extended XMP that belongs to the standard one."""
GDEPTH_NS = "http://ns.google.com/photos/1.0/depthmap/"
"""Namespace of the GDepth properties."""
DD_CONTAINER_NS = "http://ns.google.com/photos/dd/1.0/container/"
"""Namespace of Dynamic Depth's ``Container:Directory``."""
DD_ITEM_NS = "http://ns.google.com/photos/dd/1.0/item/"
"""Namespace of Dynamic Depth's ``Item:*`` properties of each container item."""
DD_DEPTHMAP_NS = "http://ns.google.com/photos/dd/1.0/depthmap/"
"""Namespace of Dynamic Depth's ``DepthMap:*`` properties."""
MAX_XMP_BYTES = 64 << 20
"""XMP (standard or extended) larger than this (64 MiB) is refused: the file is untrusted and a real depth map
is a few MB of base64 at most."""
FORMATS: dict[str, Representation] = {"RangeLinear": "range_linear", "RangeInverse": "range_inverse"}
"""GDepth / Dynamic Depth ``Format`` -> our representation."""
MEASURES: dict[str, Literal["optical_axis", "optic_ray"]] = {"OpticalAxis": "optical_axis", "OpticRay": "optic_ray"}
"""GDepth / Dynamic Depth ``MeasureType`` -> ``EmbeddedDepth.measure``."""
UNITS_M = {"": 1.0, "m": 1.0, "meters": 1.0, "metres": 1.0, "mm": 1e-3, "millimeters": 1e-3, "millimetres": 1e-3}
"""Metres per unit of ``Near`` and ``Far`` by their ``Units`` (case-folded; missing = metres). GDepth writes
"m" or "mm", Dynamic Depth "Meters"; its "Diopters" and "None" are not metric."""
IMAGE_MIMES = ("image/png", "image/jpeg")
"""The depth and confidence image types the specs allow."""
MAX_IMAGE_PIXELS = 1 << 25
"""Embedded depth or confidence images larger than this (33.5 MP, more than a phone photo) are refused before
they are decoded: phones store depth at a megapixel or less, and a few bytes of PNG can claim any size."""
GDEPTH = "GDepth XMP"
DYNAMIC_DEPTH = "Dynamic Depth"

_STANDALONE_MARKERS = frozenset({0x01, 0xD8, *range(0xD0, 0xD8)})  # TEM, SOI, RST0-7: no length field
_SOS, _EOI, _APP1 = 0xDA, 0xD9, 0xE1
# the end of a scan's entropy-coded data: 0xFF followed by neither a stuffed 0x00, a restart marker nor fill
_ENTROPY_END = re.compile(rb"\xff[^\x00\xd0-\xd7\xff]")


class _Unusable(Exception):
    """Why a container's depth map cannot be used: the end of a sentence that starts "its ... depth map"."""


def read_android_depth(data: bytes) -> tuple[EmbeddedDepth | None, list[str]]:
    """The depth map of an Android JPEG (Dynamic Depth 1.0 or GDepth) and notes; None when absent or unusable."""
    if not data.startswith(b"\xff\xd8"):
        return None, []
    standard, chunks = _xmp_segments(data)
    # most JPEGs stop here: a substring test on the raw segments, no XML parsed
    has_dd, has_gdepth = (
        any(ns.encode() in packet for packet in [standard or b"", *chunks]) for ns in (DD_DEPTHMAP_NS, GDEPTH_NS)
    )
    notes: list[str] = []
    for present, container, read in (
        (has_dd, DYNAMIC_DEPTH, lambda: _read_dynamic_depth(data, standard, chunks)),
        (has_gdepth, GDEPTH, lambda: _read_gdepth(standard, chunks)),
    ):
        if not present:
            continue
        try:
            depth, more = read()
        except _Unusable as exc:
            notes.append(f"its {container} depth map {exc}, so it was not used")
            continue
        if depth is not None:
            return depth, [*notes, *more]
    return None, notes


# --- JPEG segments ------------------------------------------------------------------------------------------------
# The markers are walked here rather than through Pillow's ``applist``: Dynamic Depth needs the byte offset of the
# primary JPEG's EOI, which Pillow does not give, and the walk reads no pixels.


def _marker_at(data: bytes, pos: int) -> tuple[int, int] | None:
    """(marker, position after it) of the marker at ``pos`` (fill bytes skipped), or None when there is none."""
    if pos >= len(data) or data[pos] != 0xFF:
        return None
    while pos + 1 < len(data) and data[pos + 1] == 0xFF:
        pos += 1
    if pos + 1 >= len(data):
        return None
    return data[pos + 1], pos + 2


def _segment_length(data: bytes, pos: int) -> int | None:
    """The length field (counting itself) of the segment whose length starts at ``pos``, or None when broken."""
    if pos + 2 > len(data):
        return None
    length = int.from_bytes(data[pos : pos + 2], "big")
    return length if length >= 2 and pos + length <= len(data) else None


def _xmp_segments(data: bytes) -> tuple[bytes | None, list[bytes]]:
    """(the standard XMP packet or None, the extended XMP chunks after their header) of the APP1s before SOS."""
    standard: bytes | None = None
    chunks: list[bytes] = []
    pos = 2
    while (found := _marker_at(data, pos)) is not None:
        marker, pos = found
        if marker in _STANDALONE_MARKERS:
            continue
        if marker in (_SOS, _EOI):
            break
        length = _segment_length(data, pos)
        if length is None:
            break
        if marker == _APP1:
            if data.startswith(XMP_HEADER, pos + 2) and standard is None:
                standard = data[pos + 2 + len(XMP_HEADER) : pos + length]
            elif data.startswith(EXTENDED_XMP_HEADER, pos + 2):
                chunks.append(data[pos + 2 + len(EXTENDED_XMP_HEADER) : pos + length])
        pos += length
    return standard, chunks


def _primary_end(data: bytes) -> int | None:
    """The offset just after the primary JPEG's EOI marker, or None when its markers are broken."""
    pos = 2
    while (found := _marker_at(data, pos)) is not None:
        marker, pos = found
        if marker == _EOI:
            return pos
        if marker in _STANDALONE_MARKERS:
            continue
        length = _segment_length(data, pos)
        if length is None:
            return None
        pos += length
        if marker == _SOS:  # progressive JPEGs have several scans, with tables between them
            end = _ENTROPY_END.search(data, pos)
            if end is None:
                return None
            pos = end.start()
    return None


# --- XMP ----------------------------------------------------------------------------------------------------------


def _parse_xmp(packet: bytes, what: str) -> ET.Element:
    """The root element of an XMP packet (the padding around the XML trimmed)."""
    if len(packet) > MAX_XMP_BYTES:
        raise _Unusable(f"cannot be read (its {what} is {len(packet) / 2**20:.0f} MiB, over {MAX_XMP_BYTES >> 20} MiB)")
    start, end = packet.find(b"<"), packet.rfind(b">")
    try:
        return ET.fromstring(packet[max(start, 0) : end + 1])
    except ET.ParseError as exc:
        raise _Unusable(f"cannot be read (its {what} is not well-formed XML: {exc})") from None


def _properties(node: ET.Element, ns: str) -> dict[str, str]:
    """The simple properties of namespace ``ns`` on one XMP node: attributes, and child elements holding text."""
    prefix = "{" + ns + "}"
    props = {key[len(prefix) :]: value.strip() for key, value in node.attrib.items() if key.startswith(prefix)}
    for child in node:
        # writers differ: DepthMap:Near="0.2" or <DepthMap:Near>0.2</DepthMap:Near>; the attribute wins a tie
        if isinstance(child.tag, str) and child.tag.startswith(prefix) and len(child) == 0:
            props.setdefault(child.tag[len(prefix) :], (child.text or "").strip())
    return props


def _nodes(roots: list[ET.Element], ns: str) -> list[dict[str, str]]:
    """The properties of namespace ``ns`` of every node that has some, in document order."""
    return [props for root in roots for node in root.iter() if (props := _properties(node, ns))]


def _with_extended(standard: bytes | None, chunks: list[bytes]) -> tuple[list[ET.Element], str | None, bool]:
    """(the parsed standard and extended XMP, the GUID the standard names, whether its extended XMP is there)."""
    roots = [] if standard is None else [_parse_xmp(standard, "XMP")]
    named = [node["HasExtendedXMP"] for node in _nodes(roots, XMP_NOTE_NS) if "HasExtendedXMP" in node]
    guid = named[0] if named else None
    extended = _extended_xmp(chunks, guid) if chunks else None
    if extended is not None:
        roots.append(_parse_xmp(extended, "extended XMP"))
    return roots, guid, extended is not None


def _extended_xmp(chunks: list[bytes], guid: str | None) -> bytes | None:
    """The extended XMP packet with GUID ``guid`` (None: the only one there is) from its chunks, by offset."""
    pieces: dict[str, tuple[int, dict[int, bytes]]] = {}
    for chunk in chunks:
        if len(chunk) < 40:
            continue
        key = chunk[:32].decode("ascii", "replace").upper()
        full, offset = int.from_bytes(chunk[32:36], "big"), int.from_bytes(chunk[36:40], "big")
        if key in pieces and pieces[key][0] != full:
            raise _Unusable("cannot be read (its extended XMP chunks disagree on the packet's length)")
        pieces.setdefault(key, (full, {}))[1][offset] = chunk[40:]
    if guid is None:
        if len(pieces) > 1:
            raise _Unusable("cannot be read (the photo has several extended XMP packets and names none)")
        guid = next(iter(pieces), None)
    if guid is None or guid.upper() not in pieces:
        return None
    full, by_offset = pieces[guid.upper()]
    if full > MAX_XMP_BYTES:
        raise _Unusable(f"cannot be read (its extended XMP is {full / 2**20:.0f} MiB, over {MAX_XMP_BYTES >> 20} MiB)")
    covered = 0
    for offset in sorted(by_offset):
        if offset != covered:
            break
        covered += len(by_offset[offset])
    if covered != full:
        raise _Unusable(f"cannot be read (its extended XMP is incomplete: {covered} of {full} bytes in order)")
    return b"".join(by_offset[offset] for offset in sorted(by_offset))


# --- values -------------------------------------------------------------------------------------------------------


def _number(props: dict[str, str], key: str) -> float | None:
    """The float property ``key`` (None when absent)."""
    if key not in props:
        return None
    try:
        return float(props[key])
    except ValueError:
        raise _Unusable(f"states {key} = {props[key]!r}, which is not a number") from None


def _meaning(
    props: dict[str, str],
) -> tuple[Representation, float | None, float | None, Literal["optical_axis", "optic_ray"]]:
    """(representation, near m, far m, measure) from the Format, Near, Far, Units and MeasureType properties."""
    if "Format" not in props:
        raise _Unusable("states no Format (RangeLinear or RangeInverse)")
    if props["Format"] not in FORMATS:
        raise _Unusable(f"has Format {props['Format']!r}, neither RangeLinear nor RangeInverse")
    units = props["Units"] if "Units" in props else ""
    if units.casefold() not in UNITS_M:
        raise _Unusable(f"is in Units {units!r}, not metres or millimetres")
    measure = props["MeasureType"] if "MeasureType" in props else "OpticalAxis"  # the specs' default
    if measure not in MEASURES:
        raise _Unusable(f"has MeasureType {measure!r}, neither OpticalAxis nor OpticRay")
    scale = UNITS_M[units.casefold()]
    near, far = _number(props, "Near"), _number(props, "Far")
    return (
        FORMATS[props["Format"]],
        None if near is None else near * scale,
        None if far is None else far * scale,
        MEASURES[measure],
    )


def _grey(blob: bytes, mime: str | None, subject: str) -> tuple[np.ndarray, int, list[str]]:
    """(samples scaled to 0..1 by the largest value of their bit depth, bits, notes) of a PNG or JPEG image.

    ``subject`` names the image in notes ("GDepth XMP depth map").
    """
    if mime is not None and mime not in IMAGE_MIMES:
        raise _Unusable(f"is a {mime!r} image, not PNG or JPEG")
    notes: list[str] = []
    try:
        with Image.open(io.BytesIO(blob), formats=["PNG", "JPEG"]) as image:
            if image.width * image.height > MAX_IMAGE_PIXELS:
                raise _Unusable(f"is refused (it claims {image.width} x {image.height} px)")
            image.load()
            mode = image.mode
            if mode in ("L", "1"):
                grey, bits = np.asarray(image.convert("L")), 8
            elif mode.startswith("I;16") or mode == "I":  # PNG grey is at most 16 bits, whatever Pillow widens to
                grey, bits = np.asarray(image), 16
                if grey.size and (grey.min() < 0 or grey.max() > 65535):
                    raise _Unusable("cannot be decoded (it has samples outside 16 bits)")
            elif mode in ("LA", "RGB", "RGBA", "P", "PA"):
                rgb = image.convert("RGBA") if mode.startswith("P") else image
                grey, bits = np.asarray(rgb.getchannel(0)), 8
                notes.append(f"its {subject} is in {mode} mode, not grey; its first channel was used")
            else:
                raise _Unusable(f"cannot be decoded (it is a {mode} image, not grey)")
    except Image.UnidentifiedImageError:
        raise _Unusable("cannot be decoded (it is not a PNG or JPEG image)") from None
    except (OSError, ValueError, SyntaxError, EOFError, Image.DecompressionBombError) as exc:
        raise _Unusable(f"cannot be decoded ({exc})") from None
    if grey.ndim != 2 or grey.size == 0:
        raise _Unusable("cannot be decoded (it is empty)")
    return (grey.astype(np.float32) / float((1 << bits) - 1)).clip(0.0, 1.0), bits, notes


def _confidence(blob: Callable[[], bytes], mime: str | None, container: str) -> tuple[np.ndarray | None, list[str]]:
    """(confidence scaled to 0..1, notes): a broken confidence map only costs the confidence, not the depth."""
    try:
        samples, _, notes = _grey(blob(), mime, f"{container} confidence map")
    except _Unusable as exc:
        return None, [f"its {container} confidence map {exc}, so the depth was used without it"]
    return samples, notes


# --- the two containers -------------------------------------------------------------------------------------------


def _read_gdepth(standard: bytes | None, chunks: list[bytes]) -> tuple[EmbeddedDepth | None, list[str]]:
    """The GDepth depth map of the standard and extended XMP."""
    roots, guid, has_extended = _with_extended(standard, chunks)
    props: dict[str, str] = {}
    for node in _nodes(roots, GDEPTH_NS):  # the standard XMP first: it wins where both say something
        props = node | props
    if not props:
        return None, []
    representation, near, far, measure = _meaning(props)
    if "Data" not in props:
        if guid is not None and not has_extended:
            raise _Unusable("is missing (the extended XMP that should hold GDepth:Data is not in the file)")
        raise _Unusable("is missing (the XMP has no GDepth:Data)")
    samples, bits, notes = _grey(_base64(props["Data"]), _optional(props, "Mime"), f"{GDEPTH} depth map")
    confidence, more = None, []
    if "ConfidenceData" in props:
        confidence, more = _confidence(
            lambda: _base64(props["ConfidenceData"]), _optional(props, "ConfidenceMime"), GDEPTH
        )
    depth = EmbeddedDepth(
        samples=samples,
        representation=representation,
        near_m=near,
        far_m=far,
        container=GDEPTH,
        bits=bits,
        measure=measure,
        confidence=confidence,
    )
    return depth, [*notes, *more]


def _optional(props: dict[str, str], key: str) -> str | None:
    """An optional property, None when absent or empty."""
    return (props[key] or None) if key in props else None


def _base64(text: str) -> bytes:
    """The bytes of a base64 XMP value (line breaks allowed)."""
    try:
        return base64.b64decode("".join(text.split()), validate=True)
    except binascii.Error as exc:
        raise _Unusable(f"cannot be decoded (its base64 is broken: {exc})") from None


def _read_dynamic_depth(
    data: bytes, standard: bytes | None, chunks: list[bytes]
) -> tuple[EmbeddedDepth | None, list[str]]:
    """The Dynamic Depth depth map of the first camera, from the items after the primary JPEG."""
    roots = [] if standard is None else [_parse_xmp(standard, "XMP")]
    depth_maps = _nodes(roots, DD_DEPTHMAP_NS)
    if not depth_maps and chunks:  # the spec puts the Device in the standard XMP; a writer may have overflowed it
        roots = _with_extended(standard, chunks)[0]
        depth_maps = _nodes(roots, DD_DEPTHMAP_NS)
    if not depth_maps:
        return None, []
    props = depth_maps[0]  # camera 0 is the one that took the primary image
    representation, near, far, measure = _meaning(props)
    directories = [node for root in roots for node in root.iter(f"{{{DD_CONTAINER_NS}}}Directory")]
    if not directories:
        raise _Unusable("cannot be found (the XMP has no Container:Directory of items)")
    items = _nodes([directories[0]], DD_ITEM_NS)
    end = _primary_end(data)
    if end is None:
        raise _Unusable("cannot be found (the primary JPEG's markers end before its EOI)")
    depth_uri = _optional(props, "DepthURI")
    depth_index = _find_item(items, depth_uri, "depth")
    if depth_index is None:
        raise _Unusable(
            f"cannot be found (its DepthURI {depth_uri!r} names no item of the container directory, and no item "
            "has the Depth semantic)"
        )
    samples, bits, notes = _grey(
        _item_bytes(data, items, depth_index, end), _optional(items[depth_index], "Mime"), f"{DYNAMIC_DEPTH} depth map"
    )
    confidence, more = None, []
    confidence_uri = _optional(props, "ConfidenceURI")
    confidence_index = _find_item(items, confidence_uri, "confidence")
    if confidence_index is not None:
        confidence, more = _confidence(
            lambda: _item_bytes(data, items, confidence_index, end),
            _optional(items[confidence_index], "Mime"),
            DYNAMIC_DEPTH,
        )
    elif confidence_uri is not None:
        more = [
            f"its {DYNAMIC_DEPTH} confidence map cannot be found (its ConfidenceURI {confidence_uri!r} names no item "
            "of the container directory), so the depth was used without it"
        ]
    depth = EmbeddedDepth(
        samples=samples,
        representation=representation,
        near_m=near,
        far_m=far,
        container=DYNAMIC_DEPTH,
        bits=bits,
        measure=measure,
        confidence=confidence,
    )
    return depth, [*notes, *more]


def _find_item(items: list[dict[str, str]], uri: str | None, semantic: str) -> int | None:
    """The index of the (non-primary) item whose DataURI is ``uri``, else of the first with ``semantic``."""
    for index, item in enumerate(items[1:], start=1):
        if uri is not None and _optional(item, "DataURI") == uri:
            return index
    for index, item in enumerate(items[1:], start=1):
        if (_optional(item, "Semantic") or "").casefold() == semantic:
            return index
    return None


def _item_int(item: dict[str, str], key: str, index: int, required: bool) -> int:
    """An item's Length or Padding (bytes); a missing optional one is 0."""
    if key not in item or not item[key]:
        if required:
            raise _Unusable(f"cannot be found (container item {index} states no {key})")
        return 0
    try:
        value = int(item[key])
    except ValueError:
        raise _Unusable(f"cannot be found (container item {index} states {key} = {item[key]!r})") from None
    if value < 0:
        raise _Unusable(f"cannot be found (container item {index} states {key} = {value})")
    return value


def _item_bytes(data: bytes, items: list[dict[str, str]], index: int, primary_end: int) -> bytes:
    """The bytes of container item ``index``: the items follow the primary JPEG in directory order."""
    # Padding: bytes after an item that are not part of it (the primary's, in practice)
    pos = primary_end + _item_int(items[0], "Padding", 0, required=False)
    for i in range(1, index):
        pos += _item_int(items[i], "Length", i, required=True) + _item_int(items[i], "Padding", i, required=False)
    length = _item_int(items[index], "Length", index, required=True)
    if pos + length > len(data):
        raise _Unusable(
            f"is truncated (container item {index} is {length} bytes at offset {pos}, the file has "
            f"{max(len(data) - pos, 0)} there)"
        )
    return data[pos : pos + length]
