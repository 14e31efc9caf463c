"""Build a PCA foot model from a folder of scans: register the template to each scan, then PCA.

The product feature of issue 3 (``footmesh model build --scans DIR --out MODEL.npz``): a retailer or a clinic with
its own scans rebuilds the shape model in the same asset format as the FIND-built one, so it drops into the
pipeline.

Steps:
1. every ``*.obj|*.ply|*.stl|*.off`` in the folder is loaded and checked (:func:`footmesh.model.scans.load_scan`),
   its markers read when a marker file exists (``<markers_dir>/<stem>.markers.json`` or ``<stem>.json``);
2. the template (the mean of a model asset, by default the packaged one) is registered to it
   (:func:`footmesh.model.register.register`, with that asset's components as shape prior unless disabled);
   each result is cached in the work folder (``<stem>.npz``, keyed by a hash of the scan, its markers, the
   template and the settings), so a rerun skips finished scans and an interrupted run loses at most one scan;
3. a scan that fails (unreadable, wrong units, registration off: mean distance or folds over the limits) is
   reported and skipped; the summary lists them;
4. every registered shape is stood in the foot frame (:func:`footmesh.model.template.to_foot_frame`: heel
   origin, floor z = 0; no scale: size is shape) -- the same convention as the FIND-built model
   (:mod:`footmesh.model.build_find`), so the components describe shape in the foot frame and not rigid motion
   about a Procrustes centroid --, the PCA is fitted (:func:`footmesh.model.pca.fit_pca`), the mean re-stood
   (components turned alike) and rigged (:func:`footmesh.model.rig.build_rig`), and the asset is written with
   :func:`footmesh.model.assets.save_asset`.
"""

from __future__ import annotations

import hashlib
import logging
import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from footmesh.geometry.alignment import umeyama
from footmesh.model.assets import FootModelAsset
from footmesh.model.register import RegistrationConfig, RegistrationResult, register
from footmesh.model.scans import (
    SCAN_SUFFIXES,
    check_markers_on_scan,
    load_markers,
    load_scan,
    template_landmarks,
    template_markers,
)

log = logging.getLogger(__name__)

CACHE_VERSION = 1
MIN_SCANS = 2


@dataclass(frozen=True)
class BuildConfig:
    """Settings of :func:`build_model`.

    Attributes:
        registration: the registration settings.
        unit: length unit of the scan files (``mm``, ``cm``, ``m``); marker files carry their own.
        use_prior: use the template asset's components as the registration's shape prior.
        variance: fraction of the variance the PCA keeps (passed to ``fit_pca``).
        max_mean_distance_mm: a registration whose mean vertex-to-scan distance exceeds this is rejected.
        max_flipped_fraction: ... or whose fraction of folded (flipped) faces exceeds this.
    """

    registration: RegistrationConfig = field(default_factory=RegistrationConfig)
    unit: str = "mm"
    use_prior: bool = True
    variance: float = 0.99
    max_mean_distance_mm: float = 2.0
    max_flipped_fraction: float = 0.005


@dataclass(frozen=True)
class ScanOutcome:
    """What happened to one scan."""

    name: str
    ok: bool
    cached: bool
    message: str
    seconds: float = 0.0
    mean_distance_mm: float = float("nan")


@dataclass(frozen=True)
class BuildSummary:
    """Result of :func:`build_model`: the outcome per scan and, when at least two scans succeeded, the asset."""

    outcomes: tuple[ScanOutcome, ...]
    asset: FootModelAsset | None
    out: Path | None

    @property
    def succeeded(self) -> int:
        return sum(o.ok for o in self.outcomes)

    def text(self) -> str:
        """A human-readable table of the outcomes."""
        lines = [f"{'scan':32s} {'status':8s} {'mean dist mm':>12s} {'s':>6s}  note"]
        for o in self.outcomes:
            status = "cached" if o.ok and o.cached else ("ok" if o.ok else "FAILED")
            lines.append(f"{o.name:32s} {status:8s} {o.mean_distance_mm:12.3f} {o.seconds:6.1f}  {o.message}")
        failed = len(self.outcomes) - self.succeeded
        lines.append(f"{self.succeeded} of {len(self.outcomes)} scans registered, {failed} failed")
        return "\n".join(lines)


def find_scans(scan_dir: str | os.PathLike) -> list[Path]:
    """Scan files in a folder (not recursive), sorted by name."""
    d = Path(scan_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"scan folder not found: {d}")
    return sorted(p for p in d.iterdir() if p.is_file() and p.suffix.lower() in SCAN_SUFFIXES)


def markers_path(scan: Path, markers_dir: str | os.PathLike | None) -> Path | None:
    """The marker file of a scan: ``<markers_dir>/<stem>.markers.json`` or ``<stem>.json`` (default: its folder)."""
    d = Path(markers_dir) if markers_dir is not None else scan.parent
    for name in (f"{scan.stem}.markers.json", f"{scan.stem}.json"):
        if (d / name).is_file():
            return d / name
    return None


def register_scan_file(
    scan_path: str | os.PathLike,
    template: FootModelAsset,
    markers_file: str | os.PathLike | None = None,
    config: BuildConfig | None = None,
) -> RegistrationResult:
    """Load, check and register one scan to the template asset's mean (scan frame, mm)."""
    cfg = config or BuildConfig()
    mesh, _ = load_scan(scan_path, unit=cfg.unit)
    scan_markers = load_markers(markers_file) if markers_file is not None else None
    if scan_markers:
        check_markers_on_scan(scan_markers, mesh, name=str(markers_file))
    tmpl_markers = template_markers(template.num_vertices) if scan_markers else None
    return register(
        template.mean_vertices,
        template.faces,
        mesh,
        tmpl_markers,
        scan_markers,
        cfg.registration,
        shape_basis=template.components if cfg.use_prior and template.num_components else None,
        shape_sd=template.component_sd if cfg.use_prior and template.num_components else None,
    )


def _cache_key(scan: Path, markers_file: Path | None, template: FootModelAsset, cfg: BuildConfig) -> str:
    h = hashlib.sha256()
    h.update(f"v{CACHE_VERSION}".encode())
    h.update(scan.read_bytes())
    h.update(markers_file.read_bytes() if markers_file is not None else b"-")
    for arr in (template.mean_vertices, template.faces, template.components, template.component_sd):
        h.update(np.ascontiguousarray(arr).tobytes())
    h.update(repr(cfg).encode())
    return h.hexdigest()


def _save_npz_atomic(path: Path, **arrays: np.ndarray) -> None:
    from footmesh.report import atomic_path

    with atomic_path(path) as tmp, tmp.open("wb") as fh:
        np.savez(fh, **arrays)


def register_folder(
    scan_dir: str | os.PathLike,
    work_dir: str | os.PathLike,
    template: FootModelAsset,
    markers_dir: str | os.PathLike | None = None,
    config: BuildConfig | None = None,
    progress: bool = True,
) -> tuple[list[ScanOutcome], dict[str, np.ndarray]]:
    """Register every scan of a folder, resumably.

    Returns:
        (outcomes in file order, name -> registered vertices (V, 3) scan frame mm for the successful ones).
    """
    from tqdm import tqdm

    cfg = config or BuildConfig()
    scans = find_scans(scan_dir)
    if not scans:
        raise FileNotFoundError(f"no scans ({', '.join(SCAN_SUFFIXES)}) in {scan_dir}")
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    outcomes: list[ScanOutcome] = []
    shapes: dict[str, np.ndarray] = {}
    bar = tqdm(scans, desc="registering", unit="scan", disable=not progress)
    for scan in bar:
        bar.set_postfix_str(scan.name)
        mfile = markers_path(scan, markers_dir)
        cache = work / f"{scan.stem}.npz"
        t0 = time.perf_counter()
        try:
            key = _cache_key(scan, mfile, template, cfg)
            if cache.is_file():
                with np.load(cache, allow_pickle=False) as npz:
                    if str(npz["key"]) == key:
                        shapes[scan.name] = npz["vertices"]
                        outcomes.append(ScanOutcome(scan.name, True, True, "", 0.0, float(npz["mean_distance_mm"])))
                        continue
            res = register_scan_file(scan, template, mfile, cfg)
            flipped = res.flipped_faces / len(res.faces)
            if res.mean_distance_mm > cfg.max_mean_distance_mm or flipped > cfg.max_flipped_fraction:
                raise ValueError(
                    f"registration rejected: mean distance {res.mean_distance_mm:.2f} mm (limit "
                    f"{cfg.max_mean_distance_mm:g}), {res.flipped_faces} folded faces ({flipped:.2%}, limit "
                    f"{cfg.max_flipped_fraction:.2%}); add a marker file or check the scan"
                )
            _save_npz_atomic(
                cache,
                key=np.array(key),
                vertices=res.vertices,
                mean_distance_mm=np.array(res.mean_distance_mm),
                seconds=np.array(res.seconds),
            )
            shapes[scan.name] = res.vertices
            note = f"init {res.init_method}" + (f", markers {mfile.name}" if mfile else "")
            outcomes.append(ScanOutcome(scan.name, True, False, note, res.seconds, res.mean_distance_mm))
        except KeyboardInterrupt:
            raise
        except Exception as exc:  # one bad scan must never lose the run: report it and go on
            log.warning("%s: skipped: %s", scan.name, exc)
            outcomes.append(ScanOutcome(scan.name, False, False, str(exc), time.perf_counter() - t0))
    return outcomes, shapes


def align_rigid(shapes: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Rotate and translate each shape (N, V, 3) onto the reference (V, 3) by least squares (no scale)."""
    out = np.empty_like(shapes, dtype=np.float64)
    for i, s in enumerate(shapes):
        sim = umeyama(s, reference)
        out[i] = s @ sim.rotation.T + (reference.mean(axis=0) - s.mean(axis=0) @ sim.rotation.T)
    return out


def pca_asset(shapes: np.ndarray, template: FootModelAsset, variance: float, provenance: str) -> FootModelAsset:
    """PCA asset (same format as the FIND-built model) from registered shapes on the template's topology.

    Args:
        shapes: (N, V, 3) mm, any rigid pose each (each is stood in the foot frame here).
        template: supplies the faces (and the reference pose); 4,002 vertices (footmesh's template) or 1,002
            (FIND's, its first vertices). The landmarks are footmesh's on that template
            (:func:`footmesh.model.scans.template_landmarks`), used for the foot frame and the rig and stored.
    """
    from footmesh.model.pca import fit_pca
    from footmesh.model.rig import build_rig
    from footmesh.model.template import to_foot_frame

    x = np.asarray(shapes, dtype=np.float64)
    # footmesh's landmarks on this template (vertex_ids.LANDMARKS, or moved to the 1,002-vertex base): the rig
    # and the foot frame need them, and the template's own list may lack some (a cut-down template)
    landmarks = template_landmarks(template.num_vertices)
    # Stand EVERY shape in the foot frame, as build_find does for the FIND-built model. Not Procrustes: a
    # least-squares alignment about the centroid is another convention (a longer foot grows both ways from its
    # centroid instead of forward from the heel; a higher arch tilts the sole off the floor), which gives the PCA
    # other components than the reference model's -- principal angles of 29-73 degrees for the first 5 on the
    # reference's own shapes, 0.1-6 degrees when stood (docs/registration.md).
    try:
        aligned = np.stack([to_foot_frame(s, landmarks) for s in x])
        frame = True
    except (KeyError, ValueError) as exc:
        log.warning("could not stand the shapes in the foot frame (%s); aligned them by Procrustes", exc)
        aligned = align_rigid(x, template.mean_vertices.astype(np.float64))
        aligned = align_rigid(aligned, aligned.mean(axis=0))  # generalised Procrustes: onto the sample mean
        frame = False
    mean, components, sd, ratio = fit_pca(aligned, variance=variance)
    # the mean of stood feet is nearly stood already: re-stand it and turn the components by the same rotation
    standing = to_foot_frame(mean, landmarks) if frame else align_rigid(mean[None], template.mean_vertices)[0]
    sim = umeyama(mean, standing)  # rigid (to_foot_frame keeps the size): rotate the components alike
    mean = sim.apply(mean)
    components = np.asarray(components) @ sim.rotation.T
    rig = build_rig(mean, template.faces, landmarks)
    return FootModelAsset(
        mean_vertices=mean.astype(np.float32),
        components=components.astype(np.float32),
        component_sd=np.asarray(sd, dtype=np.float32),
        explained_variance_ratio=np.asarray(ratio, dtype=np.float32),
        faces=template.faces.astype(np.int32),
        landmark_names=np.array(list(landmarks)),
        landmark_vertices=np.array(list(landmarks.values()), dtype=np.int32),
        joint_regressor=rig.joint_regressor.astype(np.float32),
        skin_weights=rig.skin_weights.astype(np.float32),
        provenance=provenance,
    )


def build_model(
    scan_dir: str | os.PathLike,
    out: str | os.PathLike,
    template: FootModelAsset | None = None,
    markers_dir: str | os.PathLike | None = None,
    work_dir: str | os.PathLike | None = None,
    config: BuildConfig | None = None,
    progress: bool = True,
) -> BuildSummary:
    """Register every scan in ``scan_dir`` and write the PCA asset to ``out``.

    Args:
        scan_dir: folder of scans (mm unless ``config.unit`` says otherwise).
        out: the asset file to write (``.npz``).
        template: the template asset (its mean is registered to the scans; faces, landmarks and, with
            ``use_prior``, components come from it); the packaged model by default.
        markers_dir: where marker files are (default: beside the scans).
        work_dir: cache of registered scans (default: ``<out without suffix>.work``).
        config: settings.
        progress: show a progress bar.

    Returns:
        :class:`BuildSummary`; its ``asset`` is None when fewer than two scans succeeded (nothing written).
    """
    from footmesh.model.assets import load_asset, save_asset

    cfg = config or BuildConfig()
    tmpl = template if template is not None else load_asset()
    out_p = Path(out)
    work = Path(work_dir) if work_dir is not None else out_p.with_suffix(".work")
    outcomes, shapes = register_folder(scan_dir, work, tmpl, markers_dir, cfg, progress)
    if len(shapes) < MIN_SCANS:
        return BuildSummary(tuple(outcomes), None, None)
    names = sorted(shapes)
    provenance = (
        f"footmesh model build: PCA of {len(names)} scans from {Path(scan_dir).name}/ registered by per-vertex "
        f"affine transforms (Allen, Curless, Popovic 2003) to the template of [{tmpl.provenance[:200]}]; "
        f"shape prior: {'yes' if cfg.use_prior else 'no'}; variance kept {cfg.variance}; scans: "
        + ", ".join(names[:50])
        + (" ..." if len(names) > 50 else "")
    )
    asset = pca_asset(np.stack([shapes[n] for n in names]), tmpl, cfg.variance, provenance)
    save_asset(asset, out_p)
    return BuildSummary(tuple(outcomes), asset, out_p)
