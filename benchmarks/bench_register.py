"""Template registration benchmark (issue 3): time and accuracy per scan, beside the issue's targets.

Scans are made on the fly (:func:`footmesh.model.scans.synthetic_scan`): a known shape on the template's topology
(the packaged model with random coefficients, or FIND itself with ``--find DIR``) remeshed to another vertex count,
0.3 mm noise, 3 small holes, a random rigid pose and scale, 13 markers with 1 mm noise.

    python benchmarks/bench_register.py                     # 3 scans with markers + 1 without, prior on
    python benchmarks/bench_register.py --no-prior          # plain Allen et al. (no shape prior)
    python benchmarks/bench_register.py --find ../shared/find   # FIND shapes as ground truth
    python benchmarks/bench_register.py --build 50          # model from 50 registered scans vs the packaged one

Columns: correspondence = mean distance of each registered vertex to its true corresponding point (mm, in the
shape's own scale); surface = mean distance of the registered vertices to the scan surface (mm); folds = faces whose
normal turned by more than 90 degrees from the true shape's.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

from footmesh.model import register as reg
from footmesh.model.assets import load_asset
from footmesh.model.scans import synthetic_scan, template_markers

TARGET_SECONDS = 30.0
TARGET_CORRESPONDENCE_MM = 1.0
TARGET_SURFACE_MM = 0.5
TARGET_RECONSTRUCTION_GAP_MM = 0.3


def model_shapes(asset, n: int, seed: int) -> np.ndarray:
    """(n, V, 3) mm: the model's mean plus N(0, sd^2) coefficients."""
    rng = np.random.default_rng(seed)
    c = rng.standard_normal((n, asset.num_components)) * asset.component_sd
    return asset.mean_vertices + np.tensordot(c, asset.components, axes=1)


def truth_shapes(asset, n: int, seed: int, find_dir: str | None) -> np.ndarray:
    if find_dir is None:
        return model_shapes(asset, n, seed)
    from footmesh.model.find import sample_find_shapes

    return sample_find_shapes(find_dir, n, seed)


def run_one(asset, truth, seed, use_markers, use_prior, target_vertices, scale_range=(0.9, 1.1)):
    ids = template_markers(asset.num_vertices)
    scan = synthetic_scan(truth, asset.faces, ids, seed=seed, target_vertices=target_vertices, scale_range=scale_range)
    t0 = time.perf_counter()
    res = reg.register(
        asset.mean_vertices,
        asset.faces,
        scan.mesh,
        ids if use_markers else None,
        scan.markers if use_markers else None,
        shape_basis=asset.components if use_prior else None,
        shape_sd=asset.component_sd if use_prior else None,
    )
    seconds = time.perf_counter() - t0
    err = np.linalg.norm(res.vertices - scan.true_vertices, axis=1) / scan.scale
    _, dist, _ = trimesh.proximity.closest_point(scan.mesh, res.vertices)
    folds = int(((reg.face_normals(res.vertices, asset.faces) * reg.face_normals(scan.true_vertices, asset.faces))
                 .sum(axis=1) < 0).sum())  # fmt: skip
    return scan, res, seconds, float(err.mean()), float(np.quantile(err, 0.95)), float(dist.mean()), folds


def table(asset, args) -> None:
    truths = truth_shapes(asset, args.scans + 1, args.seed, args.find)
    print(
        f"template: {asset.num_vertices} vertices, {len(asset.faces)} faces; shape prior: "
        f"{'no' if args.no_prior else f'{asset.num_components} components'}; truth: "
        f"{'FIND' if args.find else 'packaged model, random coefficients'}"
    )
    head = f"{'scan':>4s} {'scan V':>7s} {'markers':>7s} {'init':>7s} {'time s':>7s} {'corr mm':>8s} {'p95':>6s}"
    print(head + f" {'surface mm':>10s} {'folds':>5s}")
    rows = []
    for i in range(args.scans + 1):
        use_markers = i < args.scans  # the last scan has no markers (principal-axes init)
        scan, res, sec, corr, p95, surf, folds = run_one(
            asset, truths[i], args.seed + i, use_markers, not args.no_prior, args.scan_vertices
        )
        rows.append((sec, corr, surf, folds))
        print(
            f"{i:4d} {len(scan.mesh.vertices):7d} {'yes' if use_markers else 'no':>7s} {res.init_method:>7s} "
            f"{sec:7.1f} {corr:8.3f} {p95:6.2f} {surf:10.3f} {folds:5d}"
        )
    a = np.array(rows)
    print(
        f"{'mean':>4s} {'':7s} {'':7s} {'':7s} {a[:, 0].mean():7.1f} {a[:, 1].mean():8.3f} {'':6s} "
        f"{a[:, 2].mean():10.3f} {int(a[:, 3].sum()):5d}"
    )
    goals = f"{'<' + str(TARGET_SECONDS):>7s} {'<' + str(TARGET_CORRESPONDENCE_MM):>8s}"
    print(f"{'goal':>4s} {'':7s} {'':7s} {'':7s} {goals} {'':6s} {'<' + str(TARGET_SURFACE_MM):>10s} {'0':>5s}")


def reconstruction_error(asset_mean, components, shapes, k) -> float:
    """Mean vertex error (mm) of the best k-component fit of each shape after rigid alignment to the mean."""
    from footmesh.model.build_scans import align_rigid

    aligned = align_rigid(shapes, asset_mean)
    basis = components[:k].reshape(k, -1)  # (k, 3V) orthonormal rows
    d = (aligned - asset_mean).reshape(len(shapes), -1)
    fit = (d @ basis.T) @ basis
    return float(np.linalg.norm((d - fit).reshape(len(shapes), -1, 3), axis=2).mean())


def build_experiment(asset, args) -> None:
    """A model from N registered scans against the reference (packaged) model: principal angles, reconstruction."""
    from scipy.linalg import subspace_angles

    from footmesh.model.build_scans import pca_asset

    n = args.build
    truths = model_shapes(asset, n + 20, args.seed + 1000)
    held_out = truths[n:]
    registered = []
    t0 = time.perf_counter()
    for i in range(n):
        # scale 1: a scan's size is part of its shape here (a random scale would add a size mode to the model)
        _, res, *_ = run_one(
            asset, truths[i], args.seed + 1000 + i, True, not args.no_prior, args.scan_vertices, (1.0, 1.0)
        )
        registered.append(res.vertices)
        print(f"\rregistered {i + 1}/{n} ({time.perf_counter() - t0:.0f} s)", end="", flush=True)
    print()
    built = pca_asset(np.stack(registered), asset, 0.999, "benchmark")
    k = min(args.components, built.num_components, asset.num_components)
    ref = asset.components[:k].reshape(k, -1).T.astype(np.float64)
    new = built.components[:k].reshape(k, -1).T.astype(np.float64)
    # the built model may sit in a slightly different rigid frame: compare after aligning its mean
    sim = reg.umeyama(built.mean_vertices, asset.mean_vertices)
    new = (built.components[:k].astype(np.float64) @ sim.rotation.T).reshape(k, -1).T
    angles = np.degrees(subspace_angles(ref, new))
    print(f"principal angles between the first {k} components (degrees): {np.round(np.sort(angles), 2).tolist()}")
    for j in range(k):
        cos = abs(float(ref[:, j] @ new[:, j]) / np.linalg.norm(ref[:, j]) / np.linalg.norm(new[:, j]))
        print(
            f"  component {j}: |cos| with the reference's = {cos:.3f}; sd {built.component_sd[j]:.2f} mm "
            f"(reference {asset.component_sd[j]:.2f})"
        )
    e_ref = reconstruction_error(asset.mean_vertices.astype(np.float64), asset.components, held_out, k)
    e_new = reconstruction_error(
        built.mean_vertices.astype(np.float64), built.components.astype(np.float64), held_out, k
    )
    print(
        f"reconstruction of {len(held_out)} held-out shapes with {k} components: reference {e_ref:.3f} mm, "
        f"built {e_new:.3f} mm, gap {e_new - e_ref:+.3f} mm (goal < {TARGET_RECONSTRUCTION_GAP_MM})"
    )


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", help="model asset (.npz); default: the packaged one")
    p.add_argument("--scans", type=int, default=3, help="scans with markers (plus one without)")
    p.add_argument("--scan-vertices", type=int, default=5000, help="vertex count of the remeshed scans")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--find", help="FIND folder: use FIND shapes as ground truth")
    p.add_argument("--no-prior", action="store_true", help="plain Allen et al., no shape prior")
    p.add_argument("--build", type=int, default=0, help="also build a model from this many scans (slow)")
    p.add_argument("--components", type=int, default=5, help="components compared in --build")
    args = p.parse_args(argv)
    asset = load_asset(args.model)
    table(asset, args)
    if args.build:
        build_experiment(asset, args)


if __name__ == "__main__":
    main()
