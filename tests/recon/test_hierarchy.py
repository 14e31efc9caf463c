"""Mesh hierarchy of the template: QSLIM levels, resampling matrices, spirals, determinism and the cache."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import trimesh

from footmesh.geometry.mesh import vertex_normals
from footmesh.recon import hierarchy as hier
from footmesh.recon.hierarchy import (
    MeshHierarchy,
    Resample,
    build_hierarchy,
    ordered_one_rings,
    resample,
    spiral_sequences,
    template_hierarchy,
)


def _neighbours(faces: np.ndarray, n: int) -> list[set[int]]:
    out: list[set[int]] = [set() for _ in range(n)]
    for a, b, c in faces:
        out[a] |= {b, c}
        out[b] |= {a, c}
        out[c] |= {a, b}
    return out


def _oriented_corners(faces: np.ndarray) -> set[tuple[int, int, int]]:
    """Every face as its three rotations (a, b, c), (b, c, a), (c, a, b)."""
    out = set()
    for a, b, c in faces.tolist():
        out |= {(a, b, c), (b, c, a), (c, a, b)}
    return out


def test_levels_halve_and_stay_closed_surfaces(hierarchy):
    sizes = hierarchy.num_vertices
    assert hierarchy.num_levels == 5
    assert sizes[0] == 4002 and len(hierarchy.faces[0]) == 8000
    for fine, coarse in zip(sizes, sizes[1:], strict=False):
        assert 0.45 * fine <= coarse <= 0.55 * fine
    for v, f in zip(hierarchy.vertices, hierarchy.faces, strict=True):
        mesh = trimesh.Trimesh(v.astype(np.float64), f, process=False)
        assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
        assert len(np.unique(f)) == len(v)  # no unused vertices


def test_resampling_rows_are_barycentric(hierarchy):
    for level in range(hierarchy.num_levels - 1):
        for m in (hierarchy.down[level], hierarchy.up[level]):
            assert m.is_sparse
            dense = m.to_dense()
            assert torch.allclose(dense.sum(dim=1), torch.ones(dense.shape[0]), atol=1e-6)
            assert (dense >= 0).all()
            assert ((dense > 0).sum(dim=1) <= 3).all()


def test_up_and_down_reproduce_the_meshes(hierarchy):
    for level in range(hierarchy.num_levels - 1):
        fine = torch.from_numpy(hierarchy.vertices[level]).unsqueeze(0)
        coarse = torch.from_numpy(hierarchy.vertices[level + 1]).unsqueeze(0)
        up = resample(hierarchy.up[level], coarse)
        round_trip = resample(hierarchy.down[level], up)
        # the coarse mesh lies within QSLIM's error of the fine one, so interpolation lands close to it
        assert (up - fine).norm(dim=-1).mean() < 1.0
        assert (up - fine).norm(dim=-1).max() < 5.0
        assert (round_trip - coarse).norm(dim=-1).mean() < 1.0
        assert (resample(hierarchy.down[level], fine) - coarse).norm(dim=-1).max() < 2.0
    full = torch.from_numpy(hierarchy.vertices[0]).unsqueeze(0)
    coarsest = hierarchy.downsample(full, hierarchy.num_levels - 1)
    assert coarsest.shape == (1, hierarchy.num_vertices[-1], 3)
    assert (coarsest - torch.from_numpy(hierarchy.vertices[-1])).norm(dim=-1).mean() < 2.0


def test_resample_module_matches_the_sparse_product(hierarchy):
    x = torch.randn(2, hierarchy.num_vertices[1], 5, dtype=torch.float64)
    module = Resample(hierarchy.up[0])
    assert torch.allclose(module(x), resample(hierarchy.up[0], x))
    with pytest.raises(ValueError, match="features must be"):
        module(torch.randn(2, 7, 5))


def test_spirals_start_at_the_vertex_and_walk_the_one_ring_counter_clockwise(hierarchy):
    for v, f, spirals in zip(hierarchy.vertices, hierarchy.faces, hierarchy.spirals, strict=True):
        n = len(v)
        assert spirals.shape == (n, hierarchy.spiral_length)
        assert np.array_equal(spirals[:, 0], np.arange(n))
        neighbours = _neighbours(f, n)
        corners = _oriented_corners(f)
        for i in range(n):
            s = spirals[i]
            assert len(set(s.tolist())) == len(s)  # closed meshes this size never need padding
            degree = len(neighbours[i])
            ring = s[1 : 1 + min(degree, len(s) - 1)].tolist()
            assert set(ring) <= neighbours[i]
            if degree < len(s) - 1:
                assert set(ring) == neighbours[i]
                # the ring is a cycle around i, counter-clockwise seen from outside: (i, r_k, r_k+1) are faces
                for a, b in zip(ring, ring[1:] + ring[:1], strict=True):
                    assert (i, a, b) in corners
                # the next entry starts the second ring: a neighbour of a first-ring vertex
                assert s[1 + degree] not in neighbours[i]
                assert any(s[1 + degree] in neighbours[r] for r in ring)


def test_spirals_start_towards_plus_x(sphere):
    v, f = sphere
    spirals = spiral_sequences(v, f, length=7)
    normals = vertex_normals(v, f)
    checked = 0
    for i in range(len(v)):
        if abs(normals[i, 0]) > hier.FALLBACK_COSINE:
            continue
        ref = np.array([1.0, 0.0, 0.0]) - normals[i, 0] * normals[i]
        nbrs = sorted(_neighbours(f, len(v))[i])  # ties (symmetric icosphere) go to the lowest id
        d = v[nbrs] - v[i]
        assert spirals[i, 1] == nbrs[int(np.argmax((d / np.linalg.norm(d, axis=1, keepdims=True)) @ ref))]
        checked += 1
    assert checked > 100


def test_dilation_keeps_every_other_entry(sphere):
    v, f = sphere
    plain = spiral_sequences(v, f, length=17)
    dilated = spiral_sequences(v, f, length=9, dilation=2)
    assert np.array_equal(dilated, plain[:, ::2])


def test_open_mesh_and_padding():
    grid = trimesh.creation.box().subdivide().subdivide()
    # cut the box open: drop the faces on its top
    keep = grid.triangles_center[:, 2] < 0.49
    v, f = np.asarray(grid.vertices), np.asarray(grid.faces[keep])
    used = np.unique(f)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    v, f = v[used], remap[f]
    rings = ordered_one_rings(v, f)
    neighbours = _neighbours(f, len(v))
    assert all(set(r.tolist()) == neighbours[i] for i, r in enumerate(rings))
    # a spiral longer than the mesh is padded with its own vertex
    tiny_v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    tiny_f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    s = spiral_sequences(tiny_v, tiny_f, length=6)
    assert np.array_equal(s[:, 0], np.arange(4))
    assert np.array_equal(np.sort(s[:, :4], axis=1), np.tile(np.arange(4), (4, 1)))
    assert np.array_equal(s[:, 4:], np.repeat(np.arange(4)[:, None], 2, axis=1))


def test_deterministic_and_saved_bytes_identical(hierarchy, tmp_path):
    again = build_hierarchy(hierarchy.vertices[0], hierarchy.faces[0])
    arrays = hierarchy.spirals + hierarchy.faces + hierarchy.vertices
    arrays_again = again.spirals + again.faces + again.vertices
    assert all(np.array_equal(a, b) for a, b in zip(arrays, arrays_again, strict=True))
    for a, b in zip(hierarchy.down + hierarchy.up, again.down + again.up, strict=True):
        assert torch.equal(a.to_dense(), b.to_dense())
    hierarchy.save(tmp_path / "a.npz")
    again.save(tmp_path / "b.npz")
    assert (tmp_path / "a.npz").read_bytes() == (tmp_path / "b.npz").read_bytes()
    loaded = MeshHierarchy.load(tmp_path / "a.npz")
    assert loaded.key == hierarchy.key and loaded.num_vertices == hierarchy.num_vertices
    assert all(np.array_equal(a, b) for a, b in zip(loaded.spirals, hierarchy.spirals, strict=True))
    assert all(torch.equal(a.to_dense(), b.to_dense()) for a, b in zip(loaded.up, hierarchy.up, strict=True))


def test_template_cache_is_reused_and_checked(hierarchy, tmp_path, monkeypatch):
    cache = tmp_path / "hierarchy.npz"
    hierarchy.save(cache)

    def no_build(*args, **kwargs):
        raise AssertionError("rebuilt although the cache matches")

    monkeypatch.setattr(hier, "build_hierarchy", no_build)
    assert template_hierarchy(cache=cache).key == hierarchy.key
    monkeypatch.undo()
    # other parameters: rebuilt and written over the stale file
    other = template_hierarchy(cache=cache, num_levels=2, spiral_length=7)
    assert other.num_levels == 3 and other.spiral_length == 7
    assert MeshHierarchy.load(cache).key == other.key


def test_with_spirals(hierarchy):
    assert hierarchy.with_spirals(hierarchy.spiral_length, hierarchy.dilation) is hierarchy
    other = hierarchy.with_spirals(9, 2)
    assert other.spirals[0].shape == (4002, 9) and other.key != hierarchy.key
    assert other.up is hierarchy.up


def test_bad_input(sphere, tmp_path):
    v, f = sphere
    with pytest.raises(ValueError, match=r"\(V, 3\)"):
        build_hierarchy(v[:, :2], f)
    with pytest.raises(ValueError, match="outside"):
        build_hierarchy(v, f + 1000)
    with pytest.raises(ValueError, match="faces"):
        build_hierarchy(v, f, num_levels=8)
    with pytest.raises(ValueError, match="spiral length"):
        spiral_sequences(v, f, length=0)
    with pytest.raises(FileNotFoundError, match="nowhere"):
        MeshHierarchy.load(tmp_path / "nowhere.npz")
