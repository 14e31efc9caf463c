"""The generator's compiled inner loops (numba, ``nopython``, single-threaded): one code path, no numpy twin.

- ``rasterize_into``: the z-buffer triangle loop behind ``raster.rasterize``;
- ``compose``: per-sample mesh colour (Gouraud), the floor upsampled between pixel centres, tent filter;
- ``floor_shade``: the floor along the camera rays (ray-plane intersection, procedural texture, reference object,
  cast and contact shadow maps read bilinearly, Lambert light), with the textures of ``textures`` per point
  (``floor_albedo``, ``reference_albedo``, ``value_noise``, ``lattice``);
- ``nearest_distance``: joint-to-skin distances for joint visibility;
- ``gaussians``, ``uniforms``, ``noisy_rgb_to_uint8``: the sensor noise's draws (SplitMix64 and Doornik's
  ZIGNOR ziggurat), functions of a seed alone.

Determinism: plain sequential loops, no ``fastmath`` (no reassociation, no fused multiply-add), no ``parallel``;
the same inputs give the same bits on every run, compiled afresh or loaded from numba's cache. Compilation of
all kernels takes about 5 s on first use; the result is cached on disk where possible (``_jit``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


def _jit(func):
    """``numba.njit``, cached on disk where numba finds a writable place, else compiled in memory per process.

    numba's own order: ``$NUMBA_CACHE_DIR``, ``__pycache__`` beside this file, the user's cache folder
    (``~/.cache/numba``). Where none is writable (a read-only install and home), numba refuses ``cache=True``
    when decorating; the kernel is then compiled on first use in every process (about 5 s for all of them).
    """
    try:
        return njit(cache=True, nogil=True)(func)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return njit(nogil=True)(func)


def _jit_inline(func):
    """``_jit`` for the small per-point helpers of the kernels, inlined into their callers by numba: a call with
    array arguments costs more than a texture lookup (references counted). The arithmetic is the same, in the same
    order, so the bits are too."""
    try:
        return njit(cache=True, nogil=True, inline="always")(func)
    except RuntimeError:
        return njit(nogil=True, inline="always")(func)


EDGE_TOLERANCE = 1e-9
"""Barycentric slack (dimensionless) that keeps samples on a shared edge from falling between two triangles."""


@_jit
def rasterize_into(xy, z, faces, perspective, cull_back, face_out, depth_out, bary_out):  # pragma: no cover
    """Rasterise ``faces`` in order into the (H, W) buffers; a later triangle wins ties in depth.

    The arithmetic is that of the former vectorised numpy rasteriser (same expressions, same order), so the
    results are the same bits.
    """
    height, width = depth_out.shape
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        x0, y0 = xy[i0, 0], xy[i0, 1]
        x1, y1 = xy[i1, 0], xy[i1, 1]
        x2, y2 = xy[i2, 0], xy[i2, 1]
        area = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        if cull_back:
            if not area < 0:
                continue
        elif area == 0:
            continue
        z0, z1, z2 = z[i0], z[i1], z[i2]
        if perspective and not (z0 > 0 and z1 > 0 and z2 > 0):
            continue
        lo_x = max(np.ceil(min(min(x0, x1), x2)), 0.0)  # bounding box in whole samples
        lo_y = max(np.ceil(min(min(y0, y1), y2)), 0.0)
        hi_x = min(np.floor(max(max(x0, x1), x2)), width - 1.0)
        hi_y = min(np.floor(max(max(y0, y1), y2)), height - 1.0)
        if not (hi_x >= lo_x and hi_y >= lo_y):
            continue
        inv = 1.0 / area
        a0, b0, c0 = (y1 - y2) * inv, (x2 - x1) * inv, (x1 * y2 - x2 * y1) * inv
        a1, b1, c1 = (y2 - y0) * inv, (x0 - x2) * inv, (x2 * y0 - x0 * y2) * inv
        for py in range(int(lo_y), int(hi_y) + 1):
            fy = float(py)
            for px in range(int(lo_x), int(hi_x) + 1):
                fx = float(px)
                w0 = a0 * fx + b0 * fy + c0
                if not w0 >= -EDGE_TOLERANCE:
                    continue
                w1 = a1 * fx + b1 * fy + c1
                w2 = 1.0 - w0 - w1
                if not (w1 >= -EDGE_TOLERANCE and w2 >= -EDGE_TOLERANCE):
                    continue
                if perspective:
                    q0, q1, q2 = w0 / z0, w1 / z1, w2 / z2
                    depth = 1.0 / (q0 + q1 + q2)
                    q0, q1, q2 = q0 * depth, q1 * depth, q2 * depth
                else:
                    depth = w0 * z0 + w1 * z1 + w2 * z2
                    q0, q1, q2 = w0, w1, w2
                if depth <= depth_out[py, px]:
                    depth_out[py, px] = depth
                    face_out[py, px] = f
                    bary_out[py, px, 0] = q0
                    bary_out[py, px, 1] = q1
                    bary_out[py, px, 2] = q2


@_jit
def rasterize(xy, z, faces, height, width, perspective, cull_back):  # pragma: no cover
    """``rasterize_into`` fresh buffers: face (H, W) int64 = -1, depth (H, W) = inf, bary (H, W, 3) = 0 (made here,
    without the GIL, so that other threads run while they are filled)."""
    face = np.full((height, width), -1, dtype=np.int64)
    depth = np.full((height, width), np.inf)
    bary = np.zeros((height, width, 3))
    if faces.shape[0]:
        rasterize_into(xy, z, faces, perspective, cull_back, face, depth, bary)
    return face, depth, bary


@_jit
def floor_needed(face):  # pragma: no cover
    """(S, S) bool: the pixel centres whose floor colour ``compose`` reads (a sample near them misses the mesh)."""
    size = (face.shape[0] - 1) // 2
    out = np.zeros((size, size), dtype=np.bool_)
    for i in range(size):
        for j in range(size):
            for r in range(2 * i, 2 * i + 3):
                for s in range(2 * j, 2 * j + 3):
                    if face[r, s] < 0:
                        out[i, j] = True
    return out


@_jit_inline
def _sample_row(face, bary, faces, v_colour, floor_rgb, r, out):  # pragma: no cover
    """Colour of the supersampled row ``r`` into ``out`` (n, 3): ``compose``'s samples, one row at a time."""
    n = face.shape[1]
    size = floor_rgb.shape[0]
    # the floor's pixel rows around sample row r (the same one twice at a pixel centre)
    if r % 2 == 1:
        ra = rb = (r - 1) // 2
    else:
        ra, rb = max(r // 2 - 1, 0), min(r // 2, size - 1)
    for s in range(n):
        f = face[r, s]
        if f >= 0:
            t0, t1, t2 = faces[f, 0], faces[f, 1], faces[f, 2]
            w0, w1, w2 = bary[r, s, 0], bary[r, s, 1], bary[r, s, 2]
            for c in range(3):
                out[s, c] = w0 * v_colour[t0, c] + w1 * v_colour[t1, c] + w2 * v_colour[t2, c]
            continue
        if s % 2 == 1:
            ca = cb = (s - 1) // 2
        else:
            ca, cb = max(s // 2 - 1, 0), min(s // 2, size - 1)
        for c in range(3):
            if ra == rb:
                left, right = floor_rgb[ra, ca, c], floor_rgb[ra, cb, c]
            else:
                left = 0.5 * (floor_rgb[ra, ca, c] + floor_rgb[rb, ca, c])
                right = 0.5 * (floor_rgb[ra, cb, c] + floor_rgb[rb, cb, c])
            out[s, c] = left if ca == cb else 0.5 * (left + right)


@_jit
def compose(face, bary, faces, v_colour, floor_rgb):  # pragma: no cover
    """Anti-aliased (S, S, 3) colour from the (2S+1)^2 supersampled mesh fragments and the floor at pixel centres.

    A sample covered by the mesh takes its barycentric blend of ``v_colour``; any other sample the floor's
    colour, bilinear between the pixel centres (edges replicated); then the tent ``[1, 2, 1] / 4`` along rows
    and columns. Sample rows are made as the filter reaches them (three at a time; the last is the next pixel
    row's first).
    """
    n = face.shape[0]
    size = floor_rgb.shape[0]
    top = np.empty((n, 3))
    middle = np.empty((n, 3))
    bottom = np.empty((n, 3))
    _sample_row(face, bary, faces, v_colour, floor_rgb, 0, bottom)
    out = np.empty((size, size, 3))
    rows = np.empty((n, 3))
    for i in range(size):
        top, bottom = bottom, top  # sample row 2i: the previous pixel row's last
        _sample_row(face, bary, faces, v_colour, floor_rgb, 2 * i + 1, middle)
        _sample_row(face, bary, faces, v_colour, floor_rgb, 2 * i + 2, bottom)
        for s in range(n):
            for c in range(3):
                rows[s, c] = 0.25 * top[s, c] + 0.5 * middle[s, c] + 0.25 * bottom[s, c]
        for j in range(size):
            for c in range(3):
                out[i, j, c] = 0.25 * rows[2 * j, c] + 0.5 * rows[2 * j + 1, c] + 0.25 * rows[2 * j + 2, c]
    return out


@_jit_inline
def bilinear_at(img, gx, gy):  # pragma: no cover
    """Bilinear lookup of a 2D map at (column, row) coordinates; 0 outside the map (one texel of zeros around it)."""
    h, w = img.shape
    x = min(max(gx + 1.0, 0.0), w + 0.999)  # coordinates in the map padded with one texel of zeros
    y = min(max(gy + 1.0, 0.0), h + 0.999)
    x0, y0 = int(x), int(y)
    fx, fy = x - x0, y - y0
    v00 = img[y0 - 1, x0 - 1] if 1 <= y0 <= h and 1 <= x0 <= w else 0.0
    v01 = img[y0 - 1, x0] if 1 <= y0 <= h and x0 < w else 0.0
    v10 = img[y0, x0 - 1] if y0 < h and 1 <= x0 <= w else 0.0
    v11 = img[y0, x0] if y0 < h and x0 < w else 0.0
    top = v00 * (1 - fx) + v01 * fx
    bottom = v10 * (1 - fx) + v11 * fx
    return top * (1 - fy) + bottom * fy


# --- procedural textures ----------------------------------------------------------------------------------


@_jit_inline
def lattice(table, a, b, salt):  # pragma: no cover
    """``table`` value of the integer-valued cell (a, b) shifted by the salt (``textures._hash``, one point)."""
    n = table.shape[0] - 1
    s = np.int64(salt * 1000.0)
    ia = (np.int64(a) + s) & n
    ib = (np.int64(b) + 7 * s + (s >> 8)) & n
    return table[ia, ib]


@_jit_inline
def value_noise(table, x, y, cell, salt):  # pragma: no cover
    """Smooth value noise in [0, 1) at one point: hashed lattice values, smoothstep blend."""
    gx, gy = x / cell, y / cell
    ix, iy = np.floor(gx), np.floor(gy)
    fx, fy = gx - ix, gy - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    v00, v10 = lattice(table, ix, iy, salt), lattice(table, ix + 1, iy, salt)
    v01, v11 = lattice(table, ix, iy + 1, salt), lattice(table, ix + 1, iy + 1, salt)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy


@_jit
def value_noise_many(table, x, y, cell, salt):  # pragma: no cover
    out = np.empty(x.shape[0])
    for k in range(x.shape[0]):
        out[k] = value_noise(table, x[k], y[k], cell, salt)
    return out


@_jit_inline
def floor_albedo(table, kind, base, size, angle, salt, contrast, x, y, out):  # pragma: no cover
    """Albedo (3,) into ``out`` of floor ``kind`` (0 wood, 1 tiles, 2 carpet, 3 plain) at the floor point x, y."""
    ca, sa = math.cos(angle), math.sin(angle)
    u, v = ca * x + sa * y, -sa * x + ca * y  # u along the planks / tile rows
    if kind == 0:  # wood
        plank_len = 5.0 * size + 400.0
        row = np.floor(v / size)
        shift = lattice(table, row, 0.0, salt)
        col = np.floor(u / plank_len + shift)
        tone = 1.0 + contrast * 0.35 * (lattice(table, row, col, salt + 1) - 0.5)
        wobble = value_noise(table, u * 0.05, v, 4.0, salt + 2) * 6.0
        grain = 0.5 + 0.5 * math.sin(2 * math.pi * (v + wobble) / (2.5 + 2 * lattice(table, row, col, salt + 3)))
        fine = value_noise(table, u, v * 4.0, 30.0, salt + 4)
        shade = tone * (0.88 + 0.12 * contrast * grain) * (0.93 + 0.14 * fine)
        fv = v / size - row
        fu = u / plank_len + shift - col
        if fv * size < 1.5 or fu * plank_len < 1.5:  # the gaps between planks
            shade = 0.45
    elif kind == 1:  # tiles
        grout_mm = 2.0 + 4.0 * lattice(table, salt, 1.0, 0.0)
        gu, gv = u / size, v / size
        iu, iv = np.floor(gu), np.floor(gv)
        du = min(gu - iu, 1 - (gu - iu)) * size
        dv = min(gv - iv, 1 - (gv - iv)) * size
        if min(du, dv) < grout_mm / 2:
            grout = 0.55 if (base[0] + base[1] + base[2]) / 3.0 > 0.5 else 0.8
            out[0] = min(max(grout * 1.0, 0.0), 1.0)
            out[1] = min(max(grout * 0.98, 0.0), 1.0)
            out[2] = min(max(grout * 0.95, 0.0), 1.0)
            return
        marble = value_noise(table, u, v, 60.0, salt) * 0.6 + value_noise(table, u, v, 15.0, salt + 1) * 0.4
        shade = (1.0 + contrast * 0.12 * (lattice(table, iu, iv, salt) - 0.5)) * (0.92 + 0.16 * contrast * marble)
    elif kind == 2:  # carpet
        fibre = lattice(table, np.floor(u / size), np.floor(v / size), salt)
        blotch = value_noise(table, u, v, 80.0, salt + 1)
        shade = (0.8 + 0.3 * contrast * fibre) * (0.9 + 0.2 * blotch)
    else:  # plain: concrete, vinyl, painted floor
        shade = (
            0.92 + 0.12 * contrast * value_noise(table, u, v, size, salt) + 0.04 * value_noise(table, u, v, 8.0, salt)
        )
    for c in range(3):
        out[c] = min(max(base[c] * shade, 0.0), 1.0)


@_jit
def floor_texture(table, kind, base, size, angle, salt, contrast, x, y):  # pragma: no cover
    """(N, 3) albedo of floor ``kind`` at floor points x, y (N,) mm."""
    out = np.empty((x.shape[0], 3))
    for k in range(x.shape[0]):
        floor_albedo(table, kind, base, size, angle, salt, contrast, x[k], y[k], out[k])
    return out


@_jit_inline
def reference_albedo(table, bits, kind, length, width, margin, card, tint, salt, u, v, out):  # pragma: no cover
    """Whether reference object ``kind`` (1 A4, 2 card, 3 marker) covers local point u, v (mm); its albedo into out.

    ``length`` x ``width``: the stored rectangle; ``margin``: white paper around it (marker); ``card``: the card's
    base colour (3,); ``bits``: the marker's cells (1 = white).
    """
    if not (u >= -margin and u <= length + margin and v >= -margin and v <= width + margin):
        return False
    if kind == 2:  # card: rounded corners, a base colour, a chip and a stripe
        r = 3.18
        cu, cv = min(max(u, r), length - r), min(max(v, r), width - r)
        if not (u - cu) * (u - cu) + (v - cv) * (v - cv) <= r * r:
            return False
        if u > 10 and u < 22 and v > 19 and v < 29:
            out[0], out[1], out[2] = 0.80, 0.68, 0.35
        elif v > 40 and v < 44:
            for c in range(3):
                out[c] = min(max(card[c] * 1.6 + 0.2, 0.0), 1.0)
        else:
            noise = 0.9 + 0.2 * value_noise(table, u, v, 20.0, salt)
            for c in range(3):
                out[c] = card[c] * noise
        return True
    if kind == 3:  # marker: black cells on white paper
        cell = length / bits.shape[0]
        iu = int(min(max(np.floor(u / cell), 0.0), bits.shape[1] - 1.0))
        iv = int(min(max(np.floor(v / cell), 0.0), bits.shape[0] - 1.0))
        if u >= 0 and u < length and v >= 0 and v < length and not bits[iv, iu]:
            out[0], out[1], out[2] = 0.06, 0.06, 0.06
            return True
    paper = 0.97 + 0.03 * value_noise(table, u, v, 3.0, salt)
    for c in range(3):
        out[c] = tint[c] * paper
    return True


@_jit
def reference_texture(table, bits, kind, length, width, margin, card, tint, salt, u, v):  # pragma: no cover
    inside = np.zeros(u.shape[0], dtype=np.bool_)
    out = np.zeros((u.shape[0], 3))
    for k in range(u.shape[0]):
        inside[k] = reference_albedo(table, bits, kind, length, width, margin, card, tint, salt, u[k], v[k], out[k])
    return inside, out


@_jit
def floor_shade(
    rays,
    width,
    eye,
    far,
    background,
    off_gain,
    table,
    kind,
    base,
    size,
    angle,
    salt,
    contrast,
    ref_kind,
    ref_origin,
    ref_angle,
    ref_length,
    ref_width,
    ref_margin,
    card,
    tint,
    ref_salt,
    bits,
    cast,
    cast_lo,
    cast_texel,
    contact,
    contact_lo,
    contact_texel,
    ambient,
    diffuse_z,
    light_colour,
    needed,
):  # pragma: no cover
    """The floor seen from ``eye`` at the N = ``width``^2 pixel centres (row-major): pixel (column c, row r) looks
    along the scene-frame direction ``(c, r, 1) @ rays`` (``rays`` (3, 3) = ``inv(K).T @ R``; camera z = 1).

    Returns colour (N, 3), depth (N,) (the ray parameter, = camera z; inf = none) and the reference mask (N,).
    Rays that miss the floor within ``far`` mm (or any ray when the eye is under the floor) see the wall
    ``background`` (3,) scaled by its brightness along the ray, times ``off_gain``. A floor point's light is
    ``ambient (1 - 0.6 contact) + diffuse_z (1 - cast) light_colour``, with the cast shadow and the contact
    shadow read bilinearly from their maps (origin ``*_lo``, texel size ``*_texel`` mm). Where ``needed`` (N,) is
    False (the mesh hides the point and its neighbours) only depth and the reference mask are computed, and the
    colour is 0.
    """
    n = width * width
    colour = np.empty((n, 3))
    depth = np.full(n, np.inf)
    ref_hit = np.zeros(n, dtype=np.bool_)
    albedo = np.empty(3)
    rc, rs = math.cos(ref_angle), math.sin(ref_angle)
    col, row = -1.0, 0.0  # pixel k's column and row (k = row * width + col), counted without a division
    last = np.float64(width - 1)
    for k in range(n):
        if col == last:
            col, row = 0.0, row + 1.0
        else:
            col += 1.0
        rx = col * rays[0, 0] + row * rays[1, 0] + rays[2, 0]
        ry = col * rays[0, 1] + row * rays[1, 1] + rays[2, 1]
        rz = col * rays[0, 2] + row * rays[1, 2] + rays[2, 2]
        norm = math.sqrt(rx * rx + ry * ry + rz * rz)
        t = -eye[2] / rz if (rz < 0 and eye[2] > 0) else np.inf
        if not t * norm < far:
            wall = 0.85 + 0.25 * min(max(rz / norm, -1.0), 1.0)
            for c in range(3):
                colour[k, c] = min(max(background[c] * wall, 0.0), 1.0) * off_gain
            continue
        depth[k] = t
        x, y = eye[0] + t * rx, eye[1] + t * ry
        if not needed[k]:
            colour[k, 0] = colour[k, 1] = colour[k, 2] = 0.0
            if ref_kind > 0:
                dx, dy = x - ref_origin[0], y - ref_origin[1]
                u, v = rc * dx + rs * dy, -rs * dx + rc * dy
                if (
                    u >= -ref_margin
                    and u <= ref_length + ref_margin
                    and v >= -ref_margin
                    and v <= ref_width + ref_margin
                ):
                    ref_hit[k] = reference_albedo(
                        table, bits, ref_kind, ref_length, ref_width, ref_margin, card, tint, ref_salt, u, v, albedo
                    )
            continue
        floor_albedo(table, kind, base, size, angle, salt, contrast, x, y, albedo)
        if ref_kind > 0:
            dx, dy = x - ref_origin[0], y - ref_origin[1]
            u, v = rc * dx + rs * dy, -rs * dx + rc * dy
            # the object's bounds (``reference_albedo``'s first test) checked here: most points are outside
            if u >= -ref_margin and u <= ref_length + ref_margin and v >= -ref_margin and v <= ref_width + ref_margin:
                if reference_albedo(
                    table, bits, ref_kind, ref_length, ref_width, ref_margin, card, tint, ref_salt, u, v, albedo
                ):
                    ref_hit[k] = True
        shadow = bilinear_at(cast, (x - cast_lo[0]) / cast_texel, (y - cast_lo[1]) / cast_texel)
        occ = 0.6 * bilinear_at(contact, (x - contact_lo[0]) / contact_texel, (y - contact_lo[1]) / contact_texel)
        for c in range(3):
            colour[k, c] = albedo[c] * (ambient * (1.0 - occ) + diffuse_z * (1.0 - shadow) * light_colour[c])
    return colour, depth, ref_hit


@_jit
def nearest_distance(points, vertices):  # pragma: no cover
    """(P,) distance from each point (P, 3) to the nearest of ``vertices`` (V, 3)."""
    out = np.empty(points.shape[0])
    for p in range(points.shape[0]):
        best = np.inf
        for v in range(vertices.shape[0]):
            dx = points[p, 0] - vertices[v, 0]
            dy = points[p, 1] - vertices[v, 1]
            dz = points[p, 2] - vertices[v, 2]
            best = min(best, dx * dx + dy * dy + dz * dz)
        out[p] = math.sqrt(best)
    return out


# --- normals and sensor noise (numpy's expressions, in numpy's order) -----------------------------------------


@_jit
def area_normals(vertices, faces):  # pragma: no cover
    """(F, 3) ``cross(v1 - v0, v2 - v0)`` of each face (``geometry.mesh.face_normals(unit=False)``)."""
    out = np.empty((faces.shape[0], 3))
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        a0, a1, a2 = (
            vertices[i1, 0] - vertices[i0, 0],
            vertices[i1, 1] - vertices[i0, 1],
            vertices[i1, 2] - vertices[i0, 2],
        )
        b0, b1, b2 = (
            vertices[i2, 0] - vertices[i0, 0],
            vertices[i2, 1] - vertices[i0, 1],
            vertices[i2, 2] - vertices[i0, 2],
        )
        out[f, 0] = a1 * b2 - a2 * b1
        out[f, 1] = a2 * b0 - a0 * b2
        out[f, 2] = a0 * b1 - a1 * b0
    return out


@_jit
def csr_rows(indptr, indices, data, x):  # pragma: no cover
    """(R, 3) ``A @ x`` of a CSR matrix A (R, F) and (F, 3) ``x``, summed in scipy's order (``csr_matvecs``)."""
    out = np.zeros((indptr.shape[0] - 1, 3))
    for r in range(indptr.shape[0] - 1):
        for jj in range(indptr[r], indptr[r + 1]):
            j, a = indices[jj], data[jj]
            for c in range(3):
                out[r, c] += a * x[j, c]
    return out


@_jit
def scatter_faces(faces, values, n):  # pragma: no cover
    """(n, 3) sums of each face's ``values`` (F, 3) at its three vertices (``np.add.at`` per corner, in order)."""
    out = np.zeros((n, 3))
    for k in range(3):
        for f in range(faces.shape[0]):
            v = faces[f, k]
            for c in range(3):
                out[v, c] += values[f, c]
    return out


@_jit
def unit_rows(x, eps):  # pragma: no cover
    """(N, 3) rows divided by ``max(|row|, eps)``: ``x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), eps)``
    (numpy sums the three squares in order)."""
    out = np.empty_like(x)
    for r in range(x.shape[0]):
        norm = max(math.sqrt(x[r, 0] * x[r, 0] + x[r, 1] * x[r, 1] + x[r, 2] * x[r, 2]), eps)
        for c in range(3):
            out[r, c] = x[r, c] / norm
    return out


@_jit
def rgb_to_uint8(rgb, noise):  # pragma: no cover
    """``clip(round((rgb + noise) * 255), 0, 255)`` as uint8 (rounding half to even, as ``np.round``)."""
    out = np.empty(rgb.shape, dtype=np.uint8)
    flat_in, flat_noise, flat_out = rgb.reshape(-1), noise.reshape(-1), out.reshape(-1)
    for k in range(flat_in.shape[0]):
        flat_out[k] = np.uint8(min(max(np.rint((flat_in[k] + flat_noise[k]) * 255.0), 0.0), 255.0))
    return out


# --- Gaussian and uniform draws (SplitMix64 and Doornik's ZIGNOR ziggurat) ---------------------------------------

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_LOW7 = np.uint64(127)
_ONE = np.uint64(1)
_TWO_M53 = 2.0**-53
ZIG_R = 3.442619855899
"""ZIGNOR's start of the tail (128 blocks; Doornik 2005, "An improved ziggurat method to generate normal random
samples")."""
ZIG_V = 9.91256303526217e-3
"""ZIGNOR's block area (128 blocks)."""


def _ziggurat_tables(blocks: int = 128, r: float = ZIG_R, v: float = ZIG_V) -> tuple[np.ndarray, np.ndarray]:
    """ZIGNOR's block edges x (blocks + 1,) and ratios x[i + 1] / x[i] (blocks,), as Doornik's ``zigNorInit``."""
    x = np.zeros(blocks + 1)
    f = math.exp(-0.5 * r * r)
    x[0], x[1] = v / f, r
    for i in range(2, blocks):
        x[i] = math.sqrt(-2.0 * math.log(v / x[i - 1] + f))
        f = math.exp(-0.5 * x[i] * x[i])
    return x, x[1:] / x[:-1]


_ZIG_X, _ZIG_RATIO = _ziggurat_tables()


@_jit_inline
def _splitmix64(state):  # pragma: no cover
    """SplitMix64 (Steele, Lea, Flood 2014; Vigna's constants): (next state, 64 random bits)."""
    state = state + _GOLDEN
    z = state
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return state, z ^ (z >> _S31)


@_jit_inline
def _gauss(state):  # pragma: no cover
    """(next state, one standard normal draw): ZIGNOR, its uniform from the upper 53 bits of a SplitMix64 output
    and its block from the lowest 7 (disjoint bits), the tail by Marsaglia's exponential rejection."""
    while True:
        state, bits = _splitmix64(state)
        u = 2.0 * (np.float64(np.int64(bits >> _S11)) * _TWO_M53) - 1.0
        i = np.int64(bits & _LOW7)
        if abs(u) < _ZIG_RATIO[i]:
            return state, u * _ZIG_X[i]
        if i == 0:  # the bottom block's overhang: the tail beyond ZIG_R
            while True:
                state, b1 = _splitmix64(state)
                state, b2 = _splitmix64(state)
                x = math.log(np.float64(np.int64((b1 >> _S11) + _ONE)) * _TWO_M53) / ZIG_R  # log of (0, 1]
                y = math.log(np.float64(np.int64((b2 >> _S11) + _ONE)) * _TWO_M53)
                if -2.0 * y >= x * x:
                    return state, (x - ZIG_R) if u < 0 else (ZIG_R - x)
        x = u * _ZIG_X[i]
        f0 = math.exp(-0.5 * (_ZIG_X[i] * _ZIG_X[i] - x * x))
        f1 = math.exp(-0.5 * (_ZIG_X[i + 1] * _ZIG_X[i + 1] - x * x))
        state, b = _splitmix64(state)
        if f1 + np.float64(np.int64(b >> _S11)) * _TWO_M53 * (f0 - f1) < 1.0:
            return state, x


@_jit
def gaussians(seed, n, scale):  # pragma: no cover
    """(n,) ``scale`` times standard normal draws, a function of ``seed`` (0 <= seed < 2**63) alone."""
    out = np.empty(n)
    state = np.uint64(seed)
    for k in range(n):
        state, z = _gauss(state)
        out[k] = scale * z
    return out


@_jit
def uniforms(seed, n):  # pragma: no cover
    """(n,) uniform draws on [0, 1) (multiples of 2**-53), a function of ``seed`` (0 <= seed < 2**63) alone."""
    out = np.empty(n)
    state = np.uint64(seed)
    for k in range(n):
        state, bits = _splitmix64(state)
        out[k] = np.float64(np.int64(bits >> _S11)) * _TWO_M53
    return out


@_jit
def noisy_rgb_to_uint8(rgb, sd, seed):  # pragma: no cover
    """``rgb_to_uint8(rgb, gaussians(seed, rgb.size, sd).reshape(rgb.shape))`` without the noise array."""
    out = np.empty(rgb.shape, dtype=np.uint8)
    flat_in, flat_out = rgb.reshape(-1), out.reshape(-1)
    state = np.uint64(seed)
    for k in range(flat_in.shape[0]):
        state, z = _gauss(state)
        flat_out[k] = np.uint8(min(max(np.rint((flat_in[k] + sd * z) * 255.0), 0.0), 255.0))
    return out


@_jit
def depth_sensor(z, normal, u, a, b, jump_min, jump_frac, edge_dropout, keep_below, near, far):  # pragma: no cover
    """``render.depth_noise`` after its draws: (S, S) uint16 mm from exact depth ``z``, the standard normals and
    the uniforms (S, S each); the same expressions in the same order, so the same bits."""
    h, w = z.shape
    out = np.empty((h, w), dtype=np.uint16)
    for i in range(h):
        for j in range(w):
            zij = z[i, j]
            limit = max(jump_min, jump_frac * zij)
            jump = False
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                ni, nj = i + di, j + dj
                if 0 <= ni < h and 0 <= nj < w:
                    zn = z[ni, nj]
                    # |z_lo - z_hi| of the pair in ``np.diff`` order against the smaller limit of the two
                    d = abs(zn - zij) if (di > 0 or dj > 0) else abs(zij - zn)
                    if d > min(limit, max(jump_min, jump_frac * zn)):
                        jump = True
            uij = u[i, j]
            drop = (jump and uij < edge_dropout) or uij > keep_below or zij < near or zij > far
            if drop:
                out[i, j] = 0
            else:
                sigma = a + b * zij * zij
                noisy = zij + normal[i, j] * sigma
                out[i, j] = np.uint16(min(max(np.rint(noisy), 0.0), 65535.0))
    return out


@_jit
def visible(uv, z, mask, depth, tolerance):  # pragma: no cover
    """(P,) points whose projection lies in the image and, within one pixel, on ``mask`` (H, W) with
    ``depth >= z - tolerance`` (``render._visible``; the pixel is the rounded projection, half to even)."""
    h, w = mask.shape
    out = np.zeros(uv.shape[0], dtype=np.bool_)
    for i in range(uv.shape[0]):
        u, v, zi = uv[i, 0], uv[i, 1], z[i]
        if not (zi > 0 and -0.5 <= u < w - 0.5 and -0.5 <= v < h - 0.5):
            continue
        c, r = int(np.rint(u)), int(np.rint(v))
        limit = zi - tolerance[i]
        for rr in range(max(r - 1, 0), min(r + 2, h)):
            for cc in range(max(c - 1, 0), min(c + 2, w)):
                if mask[rr, cc] and depth[rr, cc] >= limit:
                    out[i] = True
    return out


@_jit
def gaussian_blur(x, weights):  # pragma: no cover
    """``scipy.ndimage.gaussian_filter(x, sigma, mode="constant")`` of a 2D map with the symmetric 1D ``weights``
    (2r + 1,) of that sigma: along axis 0, then axis 1, each output the centre times its weight plus the pairs
    around it from the farthest in (scipy's ``correlate1d`` for symmetric weights; zeros outside)."""
    return _blur_axis(_blur_axis(x, weights, True), weights, False)


@_jit_inline
def _blur_axis(x, w, along_rows):  # pragma: no cover
    h, wd = x.shape
    r = w.shape[0] // 2
    out = np.empty_like(x)
    for i in range(h):
        for j in range(wd):
            acc = x[i, j] * w[r]
            for k in range(r, 0, -1):
                if along_rows:
                    a = x[i - k, j] if i - k >= 0 else 0.0
                    b = x[i + k, j] if i + k < h else 0.0
                else:
                    a = x[i, j - k] if j - k >= 0 else 0.0
                    b = x[i, j + k] if j + k < wd else 0.0
                acc += (a + b) * w[r - k]
            out[i, j] = acc
    return out
