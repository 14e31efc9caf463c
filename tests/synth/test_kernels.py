"""The compiled kernels against the numpy code they replaced (kept here, and only here, as the reference)."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh import references
from footmesh.synth import kernels, raster, textures
from footmesh.synth.textures import _TABLE, FloorParams


def _numpy_rasterize(xy, z, faces, height, width, perspective=True, cull_back=True):
    """The former vectorised numpy rasteriser: (face, depth, bary)."""
    face_out = np.full(height * width, -1, dtype=np.int64)
    depth_out = np.full(height * width, np.inf)
    bary_out = np.zeros((height * width, 3))
    p0, p1, p2 = xy[faces[:, 0]], xy[faces[:, 1]], xy[faces[:, 2]]
    area = (p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1]) - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0])
    keep = area < 0 if cull_back else area != 0
    lo = np.maximum(np.ceil(np.minimum(np.minimum(p0, p1), p2)), 0.0)
    hi = np.minimum(np.floor(np.maximum(np.maximum(p0, p1), p2)), [width - 1.0, height - 1.0])
    keep &= np.all(hi >= lo, axis=1)
    if perspective:
        keep &= np.all(z[faces] > 0, axis=1)
    ids = np.flatnonzero(keep)
    lo_i, hi_i = lo[ids].astype(np.int64), hi[ids].astype(np.int64)
    box_w = hi_i[:, 0] - lo_i[:, 0] + 1
    counts = box_w * (hi_i[:, 1] - lo_i[:, 1] + 1)
    cand = np.repeat(np.arange(len(ids)), counts)
    local = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    px = lo_i[cand, 0] + local % box_w[cand]
    py = lo_i[cand, 1] + local // box_w[cand]
    q0, q1, q2 = p0[ids], p1[ids], p2[ids]
    inv = 1.0 / area[ids]
    coef = [
        ((qa[:, 1] - qb[:, 1]) * inv, (qb[:, 0] - qa[:, 0]) * inv, (qa[:, 0] * qb[:, 1] - qb[:, 0] * qa[:, 1]) * inv)
        for qa, qb in ((q1, q2), (q2, q0))
    ]
    fx, fy = px.astype(np.float64), py.astype(np.float64)
    w0 = coef[0][0][cand] * fx + coef[0][1][cand] * fy + coef[0][2][cand]
    w1 = coef[1][0][cand] * fx + coef[1][1][cand] * fy + coef[1][2][cand]
    w2 = 1.0 - w0 - w1
    tol = -raster.EDGE_TOLERANCE
    inside = (w0 >= tol) & (w1 >= tol) & (w2 >= tol)
    w = np.stack([w0[inside], w1[inside], w2[inside]], axis=1)
    cand, px, py = cand[inside], px[inside], py[inside]
    zf = z[faces[ids]][cand]
    if perspective:
        wz = w / zf
        depth = 1.0 / wz.sum(axis=1)
        bary = wz * depth[:, None]
    else:
        depth, bary = (w * zf).sum(axis=1), w
    pix = py * width + px
    np.minimum.at(depth_out, pix, depth)
    win = depth == depth_out[pix]
    face_out[pix[win]] = ids[cand[win]]
    bary_out[pix[win]] = bary[win]
    return face_out.reshape(height, width), depth_out.reshape(height, width), bary_out.reshape(height, width, 3)


@pytest.mark.parametrize("perspective, cull_back", [(True, True), (True, False), (False, True)])
def test_rasteriser_matches_the_numpy_one(perspective, cull_back):
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=9.0)
    rng = np.random.default_rng(1)
    for _ in range(3):
        v = sphere.vertices @ np.linalg.qr(rng.standard_normal((3, 3)))[0].T + [12.0, 10.0, 40.0]
        xy, z = 30.0 * v[:, :2] / v[:, 2:3] + 1.0, v[:, 2]
        faces = np.asarray(sphere.faces, dtype=np.int64)
        # ties at equal depth and duplicated triangles: the later one wins in both
        faces = np.concatenate([faces, faces[:7]])
        frag = raster.rasterize(xy, z, faces, 21, 23, perspective=perspective, cull_back=cull_back)
        face, depth, bary = _numpy_rasterize(xy, z, faces, 21, 23, perspective, cull_back)
        assert (frag.face >= 0).sum() > 50
        np.testing.assert_array_equal(frag.face, face)
        np.testing.assert_array_equal(frag.depth, depth)
        np.testing.assert_array_equal(frag.bary, bary)


def _numpy_hash(a, b=0.0, salt=0.0):
    s = int(salt * 1000.0)
    ia = (np.asarray(a).astype(np.int64) + s) & 255
    ib = (np.asarray(b).astype(np.int64) + 7 * s + (s >> 8)) & 255
    return _TABLE[ia, ib]


def _numpy_noise(x, y, cell, salt):
    gx, gy = x / cell, y / cell
    ix, iy = np.floor(gx), np.floor(gy)
    fx, fy = gx - ix, gy - iy
    fx, fy = fx * fx * (3 - 2 * fx), fy * fy * (3 - 2 * fy)
    v00, v10 = _numpy_hash(ix, iy, salt), _numpy_hash(ix + 1, iy, salt)
    v01, v11 = _numpy_hash(ix, iy + 1, salt), _numpy_hash(ix + 1, iy + 1, salt)
    return (v00 * (1 - fx) + v10 * fx) * (1 - fy) + (v01 * (1 - fx) + v11 * fx) * fy


def _numpy_floor(p, x, y):
    """The former numpy ``textures.floor_colour``."""
    ca, sa = np.cos(p.angle), np.sin(p.angle)
    u, v = ca * x + sa * y, -sa * x + ca * y
    base = np.asarray(p.colour)
    if p.kind == "wood":
        row = np.floor(v / p.size_mm)
        plank_len = 5.0 * p.size_mm + 400.0
        col = np.floor(u / plank_len + _numpy_hash(row, 0.0, p.salt))
        tone = 1.0 + p.contrast * 0.35 * (_numpy_hash(row, col, p.salt + 1) - 0.5)
        wobble = _numpy_noise(u * 0.05, v, 4.0, p.salt + 2) * 6.0
        grain = 0.5 + 0.5 * np.sin(2 * np.pi * (v + wobble) / (2.5 + 2 * _numpy_hash(row, col, p.salt + 3)))
        fine = _numpy_noise(u, v * 4.0, 30.0, p.salt + 4)
        shade = tone * (0.88 + 0.12 * p.contrast * grain) * (0.93 + 0.14 * fine)
        fv = v / p.size_mm - row
        h = _numpy_hash(row, 0.0, p.salt)
        fu = u / plank_len + h - np.floor(u / plank_len + h)
        shade = np.where((fv * p.size_mm < 1.5) | (fu * plank_len < 1.5), 0.45, shade)
    elif p.kind == "tiles":
        gu, gv = u / p.size_mm, v / p.size_mm
        iu, iv = np.floor(gu), np.floor(gv)
        grout_mm = 2.0 + 4.0 * _numpy_hash(np.array(p.salt), 1.0)
        du = np.minimum(gu - iu, 1 - (gu - iu)) * p.size_mm
        dv = np.minimum(gv - iv, 1 - (gv - iv)) * p.size_mm
        marble = _numpy_noise(u, v, 60.0, p.salt) * 0.6 + _numpy_noise(u, v, 15.0, p.salt + 1) * 0.4
        shade = (1.0 + p.contrast * 0.12 * (_numpy_hash(iu, iv, p.salt) - 0.5)) * (0.92 + 0.16 * p.contrast * marble)
        out = base[None] * shade[:, None]
        out[np.minimum(du, dv) < grout_mm / 2] = np.where(base.mean() > 0.5, 0.55, 0.8) * np.array([1.0, 0.98, 0.95])
        return np.clip(out, 0, 1)
    elif p.kind == "carpet":
        fibre = _numpy_hash(np.floor(u / p.size_mm), np.floor(v / p.size_mm), p.salt)
        shade = (0.8 + 0.3 * p.contrast * fibre) * (0.9 + 0.2 * _numpy_noise(u, v, 80.0, p.salt + 1))
    else:
        shade = (
            0.92 + 0.12 * p.contrast * _numpy_noise(u, v, p.size_mm, p.salt) + 0.04 * _numpy_noise(u, v, 8.0, p.salt)
        )
    return np.clip(base[None] * shade[:, None], 0, 1)


def test_floor_textures_match_the_numpy_ones():
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-900, 900, 4000), rng.uniform(-900, 900, 4000)
    kinds = set()
    for _ in range(24):
        p = FloorParams.sample(rng)
        kinds.add(p.kind)
        np.testing.assert_allclose(textures.floor_colour(p, x, y), _numpy_floor(p, x, y), rtol=0, atol=1e-12)
    assert kinds == set(textures.FLOOR_KINDS)
    np.testing.assert_allclose(textures.value_noise(x, y, 7.0, 3.3), _numpy_noise(x, y, 7.0, 3.3), atol=1e-12)


def _numpy_reference(kind, u, v, tint, salt):
    """The former numpy ``textures.reference_colour``."""
    w, h = textures.reference_size(kind)
    margin = references.kind(kind).margin_mm
    inside = (u >= -margin) & (u <= w + margin) & (v >= -margin) & (v <= h + margin)
    paper = np.asarray(tint)[None] * (0.97 + 0.03 * _numpy_noise(u, v, 3.0, salt))[:, None]
    if kind == "a4":
        return inside, paper
    if kind == "marker":
        marker_mm = references.kind("marker").size_mm[0]
        cell = marker_mm / 6
        iu = np.clip(np.floor(u / cell), 0, 5).astype(np.int64)
        iv = np.clip(np.floor(v / cell), 0, 5).astype(np.int64)
        in_marker = (u >= 0) & (u < marker_mm) & (v >= 0) & (v < marker_mm)
        return inside, np.where((in_marker & ~textures.ARUCO_BITS[iv, iu])[:, None], 0.06, paper)
    r = textures.CARD_CORNER_MM
    cu, cv = np.clip(u, r, w - r), np.clip(v, r, h - r)
    inside &= (u - cu) ** 2 + (v - cv) ** 2 <= r * r
    base = textures._CARD[int(_numpy_hash(np.array(salt), 5.0)[()] * len(textures._CARD))]
    colour = np.broadcast_to(base, (len(u), 3)) * (0.9 + 0.2 * _numpy_noise(u, v, 20.0, salt))[:, None]
    colour = np.where(((u > 10) & (u < 22) & (v > 19) & (v < 29))[:, None], np.array([0.80, 0.68, 0.35]), colour)
    return inside, np.where(((v > 40) & (v < 44))[:, None], np.clip(base * 1.6 + 0.2, 0, 1), colour)


@pytest.mark.parametrize("kind", ["a4", "card", "marker"])
def test_reference_textures_match_the_numpy_ones(kind):
    rng = np.random.default_rng(4)
    u, v = rng.uniform(-40, 340, 20000), rng.uniform(-40, 250, 20000)
    inside, colour = textures.reference_colour(kind, u, v, (0.95, 0.93, 0.9), 41.7)
    want_inside, want = _numpy_reference(kind, u, v, (0.95, 0.93, 0.9), 41.7)
    np.testing.assert_array_equal(inside, want_inside)
    np.testing.assert_allclose(colour[inside], want[inside], rtol=0, atol=1e-12)


def test_compose_matches_upsampling_and_the_tent_filter_in_numpy():
    rng = np.random.default_rng(5)
    size = 9
    face = np.where(rng.random((2 * size + 1, 2 * size + 1)) < 0.4, rng.integers(0, 6, (2 * size + 1,) * 2), -1)
    bary = rng.dirichlet(np.ones(3), (2 * size + 1, 2 * size + 1))
    faces, v_colour, floor = rng.integers(0, 8, (6, 3)), rng.random((8, 3)), rng.random((size, size, 3))
    # reference: the former numpy path (bilinear upsampling with replicated edges, then [1, 2, 1] / 4)
    pad = np.pad(floor, ((1, 1), (1, 1), (0, 0)), mode="edge")
    up = np.empty((2 * size + 1, 2 * size + 1, 3))
    up[1::2, 1::2] = floor
    up[0::2, 1::2] = 0.5 * (pad[:-1, 1:-1] + pad[1:, 1:-1])
    odd = up[:, 1::2]
    up[:, 0::2] = 0.5 * (
        np.pad(odd, ((0, 0), (1, 0), (0, 0)), mode="edge") + np.pad(odd, ((0, 0), (0, 1), (0, 0)), mode="edge")
    )
    hit = face >= 0
    up[hit] = np.einsum("hk,hkc->hc", bary[hit], v_colour[faces[face[hit]]])
    rgb = 0.25 * up[:-1:2] + 0.5 * up[1::2] + 0.25 * up[2::2]
    rgb = 0.25 * rgb[:, :-1:2] + 0.5 * rgb[:, 1::2] + 0.25 * rgb[:, 2::2]
    np.testing.assert_allclose(kernels.compose(face, bary, faces, v_colour, floor), rgb, rtol=0, atol=1e-12)
    # the floor is read only at the pixels that ``floor_needed`` marks
    needed = kernels.floor_needed(face)
    masked = np.where(needed[..., None], floor, np.nan)
    np.testing.assert_array_equal(
        kernels.compose(face, bary, faces, v_colour, masked), kernels.compose(face, bary, faces, v_colour, floor)
    )


def test_nearest_distance_and_bilinear():
    rng = np.random.default_rng(6)
    p, v = rng.normal(size=(18, 3)) * 50, rng.normal(size=(300, 3)) * 50
    want = np.sqrt(((p[:, None] - v[None]) ** 2).sum(-1)).min(axis=1)
    np.testing.assert_array_equal(kernels.nearest_distance(p, v), want)
    img = rng.random((5, 7))
    gx, gy = rng.uniform(-2, 9, 200), rng.uniform(-2, 7, 200)
    pad = np.pad(img, 1)  # the former numpy lookup: zeros around the map
    x, y = np.clip(gx + 1.0, 0.0, 7.999), np.clip(gy + 1.0, 0.0, 5.999)
    x0, y0 = x.astype(int), y.astype(int)
    fx, fy = x - x0, y - y0
    top = pad[y0, x0] * (1 - fx) + pad[y0, x0 + 1] * fx
    bottom = pad[y0 + 1, x0] * (1 - fx) + pad[y0 + 1, x0 + 1] * fx
    got = np.array([kernels.bilinear_at(img, a, b) for a, b in zip(gx, gy, strict=True)])
    np.testing.assert_allclose(got, top * (1 - fy) + bottom * fy, rtol=0, atol=1e-15)


def _numpy_depth_noise(depth, normal, u):
    """The former numpy ``render.depth_noise`` after its draws (standard normals, then uniforms, both like
    ``depth``)."""
    from footmesh.synth import render as r

    z = depth.astype(np.float64)
    sigma = r.DEPTH_NOISE_A_MM + r.DEPTH_NOISE_B_PER_MM * z * z
    noisy = z + normal * sigma
    jump = np.zeros(z.shape, dtype=bool)
    limit = np.maximum(r.DEPTH_EDGE_JUMP[0], r.DEPTH_EDGE_JUMP[1] * z)
    dy = np.abs(np.diff(z, axis=0)) > np.minimum(limit[1:], limit[:-1])
    dx = np.abs(np.diff(z, axis=1)) > np.minimum(limit[:, 1:], limit[:, :-1])
    jump[1:] |= dy
    jump[:-1] |= dy
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    drop = (jump & (u < r.DEPTH_EDGE_DROPOUT)) | (u > 1.0 - r.DEPTH_RANDOM_DROPOUT)
    drop |= (z < r.DEPTH_RANGE_MM[0]) | (z > r.DEPTH_RANGE_MM[1])
    return np.where(drop, 0, np.clip(np.round(noisy), 0, 65535)).astype(np.uint16)


def test_depth_noise_and_rgb_quantisation_match_numpy():
    from footmesh.synth.render import depth_noise

    rng = np.random.default_rng(3)
    depth = rng.uniform(50, 3200, (40, 50))
    depth[5:20, 10:30] = 400.0 + rng.normal(0, 2, (15, 20))  # a surface with edges around it
    depth[rng.random(depth.shape) < 0.1] = 0.0
    got = depth_noise(depth, np.random.default_rng(8))
    seeds = np.random.default_rng(8).integers(2**63, size=2)
    normal = kernels.gaussians(int(seeds[0]), depth.size, 1.0).reshape(depth.shape)
    u = kernels.uniforms(int(seeds[1]), depth.size).reshape(depth.shape)
    assert got.dtype == np.uint16 and got.tobytes() == _numpy_depth_noise(depth, normal, u).tobytes()
    rgb = rng.uniform(-0.05, 1.05, (30, 20, 3))
    noise = rng.normal(0, 0.01, rgb.shape)
    rgb[0, 0, 0], noise[0, 0, 0] = 0.5 / 255.0, 0.0  # a tie: rounds half to even
    want = np.clip(np.round((rgb + noise) * 255.0), 0, 255).astype(np.uint8)
    assert kernels.rgb_to_uint8(rgb, noise).tobytes() == want.tobytes()
    fused = kernels.noisy_rgb_to_uint8(rgb, 0.01, 5)
    assert (
        fused.tobytes() == kernels.rgb_to_uint8(rgb, kernels.gaussians(5, rgb.size, 0.01).reshape(rgb.shape)).tobytes()
    )


def test_compiled_draws_are_standard_normal_and_uniform():
    from scipy import stats

    z = kernels.gaussians(123, 2_000_000, 1.0)
    assert z.tobytes() == kernels.gaussians(123, 2_000_000, 1.0).tobytes()  # a function of the seed
    assert not np.array_equal(z[:100], kernels.gaussians(124, 100, 1.0))
    assert abs(z.mean()) < 0.003 and abs(z.std() - 1.0) < 0.003
    assert stats.kstest(z, "norm").pvalue > 1e-3
    # the ziggurat's tail (beyond ZIG_R) and its wedges: the right mass beyond 3.44 and 4 (SE about 4 %, 11 %)
    for x, rtol in ((kernels.ZIG_R, 0.15), (4.0, 0.4)):
        assert abs((np.abs(z) > x).mean() / (2 * stats.norm.sf(x)) - 1.0) < rtol
    np.testing.assert_allclose(kernels.gaussians(123, 10, 2.5), 2.5 * z[:10], rtol=0, atol=0)
    u = kernels.uniforms(7, 1_000_000)
    assert u.min() >= 0.0 and u.max() < 1.0 and stats.kstest(u, "uniform").pvalue > 1e-3


def test_normals_match_geometry_mesh():
    import trimesh

    from footmesh.geometry.mesh import vertex_normals
    from footmesh.synth.render import _mesh_normals

    mesh = trimesh.creation.icosphere(subdivisions=2)
    v = mesh.vertices * np.random.default_rng(0).uniform(0.5, 2.0, (len(mesh.vertices), 1))
    assert _mesh_normals(v, mesh.faces).tobytes() == vertex_normals(v, mesh.faces).tobytes()


def test_foot_normals_match_the_sparse_incidence_product(renderer):
    from footmesh.geometry.mesh import face_normals

    verts = renderer.model.mean_vertices.numpy().astype(np.float64) * 1.01
    faces = renderer._faces["right"]
    n = renderer._incidence @ face_normals(verts, faces, unit=False)
    want = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    assert renderer._vertex_normals(verts, faces).tobytes() == want.tobytes()


def _python_visible(uv, z, mask, depth, tolerance):
    """The former Python ``render._visible``."""
    size_h, size_w = mask.shape
    out = np.zeros(len(uv), dtype=bool)
    for i, ((u, v), zi, tol) in enumerate(zip(uv, z, tolerance, strict=True)):
        if not (zi > 0 and -0.5 <= u < size_w - 0.5 and -0.5 <= v < size_h - 0.5):
            continue
        c, r = int(round(u)), int(round(v))
        rs, cs = slice(max(r - 1, 0), r + 2), slice(max(c - 1, 0), c + 2)
        out[i] = bool(np.any(mask[rs, cs] & (depth[rs, cs] >= zi - tol)))
    return out


def test_visibility_matches_the_python_loop():
    from footmesh.synth.render import _visible

    rng = np.random.default_rng(2)
    mask = rng.random((30, 40)) < 0.5
    depth = rng.uniform(100, 200, mask.shape)
    uv = rng.uniform(-2, 42, (500, 2))
    uv[:20] = np.round(uv[:20]) + 0.5  # ties: half to even
    z = rng.uniform(-10, 220, 500)
    tol = rng.uniform(0, 20, 500)
    want = _python_visible(uv, z, mask, depth, tol)
    assert want.any() and not want.all()
    assert np.array_equal(_visible(uv, z, mask, depth, tol), want)


@pytest.mark.parametrize("sigma", [4.0 / 3.0, 10.0 / 3.0, 2.7, 0.6])
def test_gaussian_blur_matches_scipy(sigma):
    from scipy import ndimage

    from footmesh.synth.render import gaussian_weights

    rng = np.random.default_rng(1)
    x = (rng.random((70, 90)) < 0.3) * rng.random((70, 90))
    want = ndimage.gaussian_filter(x, sigma, mode="constant")
    assert kernels.gaussian_blur(x, gaussian_weights(sigma)).tobytes() == want.tobytes()
