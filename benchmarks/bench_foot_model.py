"""Foot model on this machine: speed (forward, IK, canonicalisation, measurement) and skinning quality.

Run: ``python benchmarks/bench_foot_model.py`` (or ``python -m benchmarks bench_foot_model``).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np
import torch

from footmesh.measure import FootLandmarks, measure_foot
from footmesh.model.canonical import canonicalise
from footmesh.model.ik import angles_from_joints, sample_poses
from footmesh.model.layer import FootModel


def _time(fn, repeats: int) -> float:
    fn()  # warm-up
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args(argv)
    torch.set_num_threads(min(2, os.cpu_count() or 1))
    model = FootModel()
    b = args.batch
    rng = np.random.default_rng(0)
    shape = torch.from_numpy(rng.normal(size=(b, model.num_components))).float()
    rest = model(shape).rest_joints.double()
    angles = sample_poses(rest, rng, b, method="natural").float()

    rows = []
    with torch.no_grad():
        t = _time(lambda: model(shape, angles), args.repeats)
    rows.append((f"forward, batch {b} (no grad)", t * 1e3, t * 1e3 / b))

    def forward_backward():
        s = shape.clone().requires_grad_(True)
        a = angles.clone().requires_grad_(True)
        model(s, a).vertices.sum().backward()

    t = _time(forward_backward, args.repeats)
    rows.append((f"forward + backward, batch {b}", t * 1e3, t * 1e3 / b))

    posed = model(shape.double(), angles.double()).joints
    t = _time(lambda: angles_from_joints(posed, rest), args.repeats)
    rows.append((f"IK from joints, batch {b}", t * 1e3, t * 1e3 / b))

    dmodel = FootModel().double()
    one = dmodel(shape[:1].double(), angles[:1].double())
    t = _time(lambda: canonicalise(one.vertices, dmodel), 3)
    rows.append(("canonicalise one posed mesh", t * 1e3, t * 1e3))

    faces = model.faces().numpy()
    v0 = one.rest_vertices[0].numpy()
    lm = FootLandmarks.from_joints(one.rest_joints[0].numpy())
    t = _time(lambda: measure_foot(v0, faces, lm), 5)
    rows.append(("eight measurements of one mesh", t * 1e3, t * 1e3))

    print(
        f"machine: {platform.processor() or platform.machine()}, torch threads {torch.get_num_threads()}, "
        f"V={model.num_vertices}, K={model.num_components}"
    )
    print(f"{'operation':<36} {'ms / call':>10} {'ms / foot':>10}")
    for name, ms, per in rows:
        print(f"{name:<36} {ms:>10.2f} {per:>10.3f}")
    print("(no published number to compare with: the thesis gives no foot-model timings)")
    skinning_quality(dmodel, rng)


def skinning_quality(model: FootModel, rng: np.random.Generator, n: int = 500) -> None:
    """How posing deforms the mesh: edge stretch and folded faces over random shapes and poses."""
    faces = model.faces_left.numpy()
    pairs = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    edges = np.unique(np.sort(pairs, axis=1), axis=0)

    def normals(v: np.ndarray) -> np.ndarray:
        t = v[:, faces]
        return np.cross(t[:, :, 1] - t[:, :, 0], t[:, :, 2] - t[:, :, 0])

    print(
        f"\nskinning quality over {n} random shapes per pose distribution (issue 2: no degenerate faces, stretch < 30%)"
    )
    print(
        f"{'poses':<10} {'edges within 30%':>17} {'p99 |stretch-1|':>16} {'max stretch':>12} "
        f"{'folded faces':>13} {'poses with a fold':>18} {'min area ratio':>15}"
    )
    for method in ("natural", "ik"):
        shape = torch.from_numpy(rng.normal(size=(n, model.num_components)))
        with torch.no_grad():
            rest = model(shape)
            angles = sample_poses(rest.rest_joints, rng, n, method=method)
            posed = model(shape, angles).vertices.numpy()
        rest_v = rest.vertices.numpy()
        length = lambda v: np.linalg.norm(v[:, edges[:, 0]] - v[:, edges[:, 1]], axis=2)  # noqa: E731
        stretch = length(posed) / length(rest_v)
        n_rest, n_posed = normals(rest_v), normals(posed)
        folded = (n_rest * n_posed).sum(axis=2) < 0
        area = np.linalg.norm(n_posed, axis=2) / np.linalg.norm(n_rest, axis=2)
        print(
            f"{method:<10} {100 * (np.abs(stretch - 1) < 0.3).mean():>16.2f}% "
            f"{np.quantile(np.abs(stretch - 1), 0.99):>16.3f} {stretch.max():>12.2f} "
            f"{100 * folded.mean():>12.3f}% {100 * folded.any(axis=1).mean():>17.1f}% {area.min():>15.3f}"
        )


if __name__ == "__main__":
    main()
