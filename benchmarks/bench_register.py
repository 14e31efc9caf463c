"""Template registration benchmark (issue 3): time and accuracy per scan, beside the issue's targets.

Scans are made on the fly (:func:`footmesh.model.scans.synthetic_scan`): a known shape on the template's topology
(the packaged model with random coefficients, or FIND itself with ``--find DIR``) remeshed to another vertex count,
0.3 mm noise, 3 small holes, a random rigid pose and scale, 13 markers with 1 mm noise.

    python benchmarks/bench_register.py                     # 3 scans with markers + 1 without, prior on
    python benchmarks/bench_register.py --no-prior          # plain Allen et al. (no shape prior)
    python benchmarks/bench_register.py --find ../shared/find   # FIND shapes as ground truth
    python benchmarks/bench_register.py --build 50          # model from 50 registered scans vs the packaged one
    python benchmarks/bench_register.py --scans 0 --build 50 --truth-build   # same from the true shapes (seconds)

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


def reconstruction_error(asset_mean, components, shapes, k, rounds: int = 10) -> float:
    """Mean vertex error (mm) of the best fit of each shape by a k-component model over coefficients AND pose.

    Each shape is stood in the foot frame first (the convention of the FIND-built model and of ``pca_asset``),
    then pose and coefficients are refined alternately (project onto the model, align the shape rigidly onto
    that reconstruction, repeat). The same rule for every model, and independent of the frame a shape comes in:
    a Procrustes alignment onto each model's mean (the first version) moved the reference model's own shapes by
    up to 8 degrees out of its span and gave it 4.3 mm on them.
    """
    from footmesh.model.build_scans import align_rigid
    from footmesh.model.scans import template_landmarks
    from footmesh.model.template import to_foot_frame

    mean = np.asarray(asset_mean, dtype=np.float64)
    basis = np.asarray(components[:k], dtype=np.float64).reshape(k, -1)  # (k, 3V) orthonormal rows
    lm = template_landmarks(len(mean))
    errs = []
    for s in np.asarray(shapes, dtype=np.float64):
        x = to_foot_frame(s, lm)
        for r in range(rounds + 1):
            d = (x - mean).reshape(-1)
            rec = mean + ((basis @ d) @ basis).reshape(mean.shape)
            if r < rounds:
                x = align_rigid(x[None], rec)[0]
        errs.append(np.linalg.norm(x - rec, axis=1).mean())
    return float(np.mean(errs))


def build_experiment(asset, args) -> None:
    """A model from N registered scans against the reference (packaged) model: principal angles, reconstruction.

    The truths are the reference model with N(0, sd^2) coefficients on ALL its components; the reconstruction is
    compared both with the first ``--components`` and with all of the reference's components (what the data
    has). ``--truth-build`` skips the registration and builds from the true shapes (seconds): it isolates the
    PCA and frame handling, and shows what N samples can pin down at all.
    """
    from scipy.linalg import subspace_angles

    from footmesh.model.build_scans import pca_asset

    n = args.build
    truths = model_shapes(asset, n + args.held_out, args.seed + 1000)
    held_out = truths[n:]
    if args.truth_build:
        rng = np.random.default_rng(args.seed + 2000)
        from scipy.spatial.transform import Rotation

        rots = Rotation.random(n, random_state=rng.integers(2**31)).as_matrix()  # pca_asset must undo any pose
        samples = np.einsum("nij,nvj->nvi", rots, truths[:n]) + rng.normal(0.0, 100.0, (n, 1, 3))
        print(f"built from the {n} true shapes in random poses (no registration)")
    else:
        registered, errors = [], []
        t0 = time.perf_counter()
        for i in range(n):
            # scale 1: a scan's size is part of its shape here (a random scale would add a size mode to the model)
            _, res, _, corr, *_ = run_one(
                asset, truths[i], args.seed + 1000 + i, True, not args.no_prior, args.scan_vertices, (1.0, 1.0)
            )
            registered.append(res.vertices)
            errors.append(corr)
            print(f"\rregistered {i + 1}/{n} ({time.perf_counter() - t0:.0f} s)", end="", flush=True)
        print()
        e = np.array(errors)
        print(
            f"correspondence error per scan: mean {e.mean():.3f}, max {e.max():.3f} mm (scans > 1 mm: "
            f"{np.flatnonzero(e > TARGET_CORRESPONDENCE_MM).tolist()})"
        )
        samples = np.stack(registered)
        if args.save_registered:
            np.savez(args.save_registered, registered=samples, truths=truths, errors=e)
    built = pca_asset(samples, asset, 1.0, "benchmark")  # all N - 1 components; compared up to the reference's
    kk = min(built.num_components, asset.num_components)
    print(f"built model: {built.num_components} components; reference: {asset.num_components}")
    # both models are in the foot frame (the built one stood by pca_asset): compare the components as they are
    ref = asset.components[:kk].reshape(kk, -1).astype(np.float64)
    new = built.components[:kk].reshape(kk, -1).astype(np.float64)
    for k in sorted({2, min(args.components, kk), kk}):
        angles = np.degrees(subspace_angles(ref[:k].T, new[:k].T))
        print(f"principal angles between the first {k} components (degrees): {np.round(np.sort(angles), 2).tolist()}")
    for j in range(kk):
        cos = abs(float(ref[j] @ new[j]))  # orthonormal rows; abs: a component's sign is a convention
        print(
            f"  component {j}: |cos| with the reference's = {cos:.3f}; sd {built.component_sd[j]:.2f} mm "
            f"(reference {asset.component_sd[j]:.2f})"
        )
    for k in sorted({min(args.components, kk), asset.num_components}):
        kb = min(k, built.num_components)
        e_ref = reconstruction_error(asset.mean_vertices, asset.components, held_out, k)
        e_new = reconstruction_error(built.mean_vertices, built.components, held_out, kb)
        print(
            f"reconstruction of {len(held_out)} held-out shapes with {k} components (built: {kb}): reference "
            f"{e_ref:.3f} mm, built {e_new:.3f} mm, gap {e_new - e_ref:+.3f} mm (goal < {TARGET_RECONSTRUCTION_GAP_MM})"
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
    p.add_argument("--components", type=int, default=5, help="components compared in --build (and all of them)")
    p.add_argument("--held-out", type=int, default=20, help="held-out shapes for the reconstruction in --build")
    p.add_argument("--save-registered", help="--build: save the registered shapes and truths here (.npz)")
    p.add_argument("--truth-build", action="store_true", help="--build from the true shapes, no registration")
    args = p.parse_args(argv)
    asset = load_asset(args.model)
    if not (args.build and args.truth_build):
        table(asset, args)
    if args.build:
        build_experiment(asset, args)


if __name__ == "__main__":
    main()
