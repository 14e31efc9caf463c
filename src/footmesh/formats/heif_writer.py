"""HEIC files with an embedded depth image, as iPhones write them: for the tests and ``footmesh eval measure``.

pillow-heif (libheif) writes HEIF photos but cannot attach a depth image (libheif has no API for it), so this
module writes the container itself (written by hand because no maintained Python library writes HEIF auxiliary
images): it encodes the photo and the depth (and an optional confidence map) with
pillow-heif, reads back their HEVC streams and properties, and assembles one ISO-BMFF file (ISO/IEC 14496-12,
23008-12) where the depth is an auxiliary image (``auxC`` = ``urn:mpeg:hevc:2015:auxid:2``, ``auxl`` reference)
whose representation (type, z_near, z_far, d_min, d_max) sits in the ``auxC`` subtype as the HEVC depth
representation information SEI (payload 177), where iPhones and libheif put it.
"""

from __future__ import annotations

import io
import math
import struct
from dataclasses import dataclass, field

import numpy as np
import pillow_heif
from PIL import Image

DEPTH_URN = "urn:mpeg:hevc:2015:auxid:2"
CONFIDENCE_URN = "urn:com:apple:photo:2020:aux:depthconfidence"  # no standard URN; the reader matches "confidence"
REPRESENTATION_TYPE = {"uniform_inverse_z": 0, "uniform_disparity": 1, "uniform_z": 2, "nonuniform_disparity": 3}


def box(kind: bytes, payload: bytes) -> bytes:
    """A plain box."""
    return struct.pack(">I", 8 + len(payload)) + kind + payload


def full_box(kind: bytes, version: int, flags: int, payload: bytes) -> bytes:
    """A full box (version and flags)."""
    return box(kind, struct.pack(">I", (version << 24) | flags) + payload)


def children(data: bytes, start: int, end: int) -> list[tuple[bytes, int, int]]:
    """(type, payload start, box end) of the boxes in data[start:end]."""
    out = []
    while start < end:
        size, kind = struct.unpack(">I4s", data[start : start + 8])
        header = 8
        if size == 1:
            size = struct.unpack(">Q", data[start + 8 : start + 16])[0]
            header = 16
        out.append((kind, start + header, start + size))
        start += size
    return out


@dataclass
class _Item:
    item_id: int
    infe: bytes  # the whole infe box
    properties: list[tuple[bytes, bool]]  # (property box, essential)
    data: bytes


@dataclass
class _Heif:
    ftyp: bytes
    hdlr: bytes
    primary_id: int
    items: dict[int, _Item]
    refs: list[tuple[bytes, int, list[int]]] = field(default_factory=list)  # (type, from, to)


def _uint(data: bytes, offset: int, size: int) -> int:
    return int.from_bytes(data[offset : offset + size], "big") if size else 0


def parse(data: bytes) -> _Heif:
    """The items of a single-layer HEIF as pillow-heif writes it (iloc with construction method 0)."""
    top = {kind: (s, e) for kind, s, e in children(data, 0, len(data))}
    ftyp = data[top[b"ftyp"][0] - 8 : top[b"ftyp"][1]]
    ms, me = top[b"meta"]
    meta = {kind: (s, e) for kind, s, e in children(data, ms + 4, me)}
    hdlr = data[meta[b"hdlr"][0] - 8 : meta[b"hdlr"][1]]
    s, _ = meta[b"pitm"]
    version = data[s]
    primary = _uint(data, s + 4, 2 if version == 0 else 4)
    # iinf
    s, e = meta[b"iinf"]
    version = data[s]
    first = s + 4 + (2 if version == 0 else 4)
    infes = {}
    for _kind, bs, be in children(data, first, e):
        v = data[bs]
        item_id = _uint(data, bs + 4, 2 if v < 3 else 4)
        infes[item_id] = data[bs - 8 : be]
    # iloc
    s, e = meta[b"iloc"]
    version = data[s]
    p = s + 4
    offset_size, length_size = data[p] >> 4, data[p] & 15
    base_size, index_size = data[p + 1] >> 4, (data[p + 1] & 15) if version in (1, 2) else 0
    p += 2
    count = _uint(data, p, 2 if version < 2 else 4)
    p += 2 if version < 2 else 4
    blobs = {}
    for _ in range(count):
        item_id = _uint(data, p, 2 if version < 2 else 4)
        p += 2 if version < 2 else 4
        if version in (1, 2):
            assert _uint(data, p, 2) & 15 == 0, "construction method 0 only"
            p += 2
        p += 2  # data reference index
        base = _uint(data, p, base_size)
        p += base_size
        extents = _uint(data, p, 2)
        p += 2
        chunk = b""
        for _ in range(extents):
            p += index_size
            off = _uint(data, p, offset_size)
            p += offset_size
            length = _uint(data, p, length_size)
            p += length_size
            chunk += data[base + off : base + off + length]
        blobs[item_id] = chunk
    # iprp
    s, e = meta[b"iprp"]
    iprp = {kind: (bs, be) for kind, bs, be in children(data, s, e)}
    cs, ce = iprp[b"ipco"]
    props = [data[bs - 8 : be] for _kind, bs, be in children(data, cs, ce)]
    s, _ = iprp[b"ipma"]
    version, flags = data[s], _uint(data, s + 1, 3)
    p = s + 4
    entries = _uint(data, p, 4)
    p += 4
    assoc: dict[int, list[tuple[bytes, bool]]] = {}
    for _ in range(entries):
        item_id = _uint(data, p, 2 if version < 1 else 4)
        p += 2 if version < 1 else 4
        n = data[p]
        p += 1
        assoc[item_id] = []
        for _ in range(n):
            if flags & 1:
                value, p = _uint(data, p, 2), p + 2
                essential, index = bool(value >> 15), value & 0x7FFF
            else:
                value, p = data[p], p + 1
                essential, index = bool(value >> 7), value & 0x7F
            assoc[item_id].append((props[index - 1], essential))
    refs = []
    if b"iref" in meta:
        s, e = meta[b"iref"]
        version = data[s]
        width = 2 if version == 0 else 4
        for kind, bs, _be in children(data, s + 4, e):
            src = _uint(data, bs, width)
            n = _uint(data, bs + width, 2)
            to = [_uint(data, bs + width + 2 + i * width, width) for i in range(n)]
            refs.append((kind, src, to))
    items = {i: _Item(i, infes[i], assoc.get(i, []), blobs[i]) for i in infes}
    return _Heif(ftyp, hdlr, primary, items, refs)


def _depth_element(value: float) -> str:
    """One number of the depth representation SEI as bits: sign, 7-bit exponent, mantissa length - 1, mantissa."""
    sign = "1" if value < 0 else "0"
    value = abs(value)
    mantissa_len = 24
    if value == 0:
        return sign + "0" * 7 + format(mantissa_len - 1, "05b") + "0" * mantissa_len
    exponent = math.floor(math.log2(value)) + 31
    assert 0 < exponent < 127
    mantissa = round((value / 2.0 ** (exponent - 31) - 1.0) * 2**mantissa_len)
    mantissa = min(mantissa, 2**mantissa_len - 1)
    return sign + format(exponent, "07b") + format(mantissa_len - 1, "05b") + format(mantissa, f"0{mantissa_len}b")


def _uvlc(value: int) -> str:
    code = format(value + 1, "b")
    return "0" * (len(code) - 1) + code


def depth_sei(representation: str, z_near=None, z_far=None, d_min=None, d_max=None) -> bytes:
    """The auxC subtype of a depth image: one prefix-SEI NAL with depth_representation_info (payload 177)."""
    bits = "".join("1" if v is not None else "0" for v in (z_near, z_far, d_min, d_max))
    bits += _uvlc(REPRESENTATION_TYPE[representation])
    if d_min is not None or d_max is not None:
        bits += _uvlc(0)  # disparity_reference_view
    for v in (z_near, z_far, d_min, d_max):
        if v is not None:
            bits += _depth_element(float(v))
    bits += "1"  # rbsp stop bit
    bits += "0" * (-len(bits) % 8)
    payload = int(bits, 2).to_bytes(len(bits) // 8, "big")
    nal = bytes([39 << 1, 1]) + bytes([177, len(payload)]) + payload
    body = struct.pack(">I", len(nal)) + nal
    return struct.pack(">I", len(body)) + body


def _encode_grey(samples: np.ndarray) -> _Heif:
    """A pillow-heif HEIF of a grey image (uint8 -> 8 bits, uint16 -> 10 bits), parsed."""
    h, w = samples.shape
    if samples.dtype == np.uint16:  # 10-bit samples, given to pillow-heif scaled to 16 bits
        heif = pillow_heif.from_bytes("L;16", (w, h), (samples.astype(np.uint16) << 6).tobytes())
    else:
        heif = pillow_heif.from_pillow(Image.fromarray(samples.astype(np.uint8), mode="L"))
    buf = io.BytesIO()
    heif.save(buf, quality=-1)  # lossless: the depth samples must survive exactly
    return parse(buf.getvalue())


def write_heic(
    rgb: np.ndarray,
    *,
    exif: bytes | None = None,
    depth_samples: np.ndarray | None = None,
    depth_urn: str = DEPTH_URN,
    representation: str = "uniform_z",
    z_near: float | None = None,
    z_far: float | None = None,
    d_min: float | None = None,
    d_max: float | None = None,
    confidence: np.ndarray | None = None,
    bit_depth: int = 8,
) -> bytes:
    """A HEIC photo of ``rgb`` (as stored, turned by ``exif``'s orientation on display) with an optional depth
    image (``depth_samples``: uint8 or uint16 as stored) and confidence image, each an auxiliary image of the photo."""
    buf = io.BytesIO()
    kwargs = {"exif": exif} if exif is not None else {}
    if bit_depth == 8:
        pillow_heif.from_pillow(Image.fromarray(rgb)).save(buf, quality=95, **kwargs)
    else:
        heif = pillow_heif.from_bytes("RGB;16", (rgb.shape[1], rgb.shape[0]), (rgb.astype(np.uint16) * 257).tobytes())
        heif.save(buf, quality=95, **kwargs)
    if depth_samples is None and confidence is None:
        return buf.getvalue()
    photo = parse(buf.getvalue())
    extras: list[tuple[_Heif, str, bytes]] = []
    if depth_samples is not None:
        extras.append((_encode_grey(depth_samples), depth_urn, depth_sei(representation, z_near, z_far, d_min, d_max)))
    if confidence is not None:
        extras.append((_encode_grey(confidence), CONFIDENCE_URN, b""))
    next_id = max(photo.items) + 1
    for grey, urn, subtype in extras:
        item = grey.items[grey.primary_id]
        auxc = full_box(b"auxC", 0, 0, urn.encode() + b"\x00" + subtype)
        infe = full_box(b"infe", 2, 1, struct.pack(">HH4s", next_id, 0, b"hvc1") + b"\x00")  # flags 1: hidden
        photo.items[next_id] = _Item(next_id, infe, [*item.properties, (auxc, True)], item.data)
        photo.refs.append((b"auxl", next_id, [photo.primary_id]))
        next_id += 1
    return assemble(photo)


def assemble(heif: _Heif) -> bytes:
    """The bytes of ``heif``: ftyp, meta, then one mdat with every item's data."""
    ids = sorted(heif.items)
    props: list[bytes] = []
    assoc = {}
    for i in ids:
        entry = []
        for prop, essential in heif.items[i].properties:
            if prop not in props:
                props.append(prop)
            entry.append((props.index(prop) + 1, essential))
        assoc[i] = entry
    ipco = box(b"ipco", b"".join(props))
    ipma_body = struct.pack(">I", len(ids))
    for i in ids:
        ipma_body += struct.pack(">HB", i, len(assoc[i]))
        ipma_body += b"".join(bytes([(0x80 if e else 0) | index]) for index, e in assoc[i])
    iprp = box(b"iprp", ipco + full_box(b"ipma", 0, 0, ipma_body))
    iinf = full_box(b"iinf", 0, 0, struct.pack(">H", len(ids)) + b"".join(heif.items[i].infe for i in ids))
    pitm = full_box(b"pitm", 0, 0, struct.pack(">H", heif.primary_id))
    iref = full_box(
        b"iref",
        0,
        0,
        b"".join(
            box(k, struct.pack(">HH", s, len(to)) + b"".join(struct.pack(">H", t) for t in to))
            for k, s, to in heif.refs
        ),
    )

    def meta_with(offsets: dict[int, int]) -> bytes:
        iloc_body = bytes([0x44, 0x00]) + struct.pack(">H", len(ids))
        for i in ids:
            iloc_body += struct.pack(">HHHII", i, 0, 1, offsets[i], len(heif.items[i].data))
        iloc = full_box(b"iloc", 0, 0, iloc_body)
        return full_box(b"meta", 0, 0, heif.hdlr + pitm + iloc + iinf + iprp + iref)

    head = len(heif.ftyp) + len(meta_with(dict.fromkeys(ids, 0))) + 8
    offsets, at = {}, head
    for i in ids:
        offsets[i] = at
        at += len(heif.items[i].data)
    mdat = box(b"mdat", b"".join(heif.items[i].data for i in ids))
    return heif.ftyp + meta_with(offsets) + mdat
