"""Command-line interface: ``footmesh <command> ...``; ``main(argv) -> exit code`` so tests can call it."""

from __future__ import annotations

import argparse
import logging
import sys

from footmesh import __version__, references
from footmesh.errors import InputError, is_users_fault, write_internal_report

log = logging.getLogger("footmesh")

DEVELOPER_COMMANDS = ("model", "synth", "train", "eval")
"""Commands that read the developer's own folders and JSON configurations: their ``ValueError`` and
``FileNotFoundError`` name the file or field at fault, so they are reported as input errors (``footmesh.errors``)."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="footmesh", description=__doc__)
    parser.add_argument("--version", action="version", version=f"footmesh {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="more log output")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_model_commands(sub)
    _add_measure_command(sub)
    _add_demo_command(sub)
    _add_synth_command(sub)
    _add_train_commands(sub)
    _add_eval_commands(sub)
    from footmesh.web.cli import add_serve_command  # FastAPI is imported only when `serve` runs

    add_serve_command(sub)
    return parser


# --- footmesh measure (issue 7: the product's main job) ------------------------------------------------------


def _add_measure_command(sub: argparse._SubParsersAction) -> None:
    from footmesh.formats import accepted

    m = sub.add_parser(
        "measure",
        help="measure the foot in one or more photos: mesh, joints, measurements, shoe sizes",
        description="Measure the foot in each photo; writes result.json, mesh.obj, mesh.glb, canonical.obj and "
        "overlay.png per photo (docs/measure.md). Millimetres come only from a depth map or a reference object "
        f"({references.described_choices()}) in the photo; otherwise the result is unscaled.",
    )
    m.add_argument(
        "images", nargs="+", metavar="IMAGE", help=f"photo(s), each {accepted.PHOTO_HELP} (EXIF orientation honoured)"
    )
    m.add_argument("--depth", action="append", help=f"depth map per photo, {accepted.DEPTH_HELP}; repeatable")
    m.add_argument(
        "--same-foot",
        action="store_true",
        help="the photos show one foot: also combine them (inverse-variance) and warn where they disagree",
    )
    m.add_argument(
        "--no-embedded-depth",
        action="store_true",
        help="ignore a depth map stored inside the photo (iPhone HEIC, Android depth JPEG); measure it as RGB",
    )
    m.add_argument("--depth-unit", choices=("mm", "m"), default="mm", help="unit of float .npy depth (default mm)")
    m.add_argument("--intrinsics", action="append", help="K.json per photo (or one for all): fx, fy, cx, cy, ...")
    m.add_argument("--side", choices=("left", "right", "auto"), default="auto", help="which foot (default auto)")
    m.add_argument(
        "--reference",
        choices=("auto", *references.NAMES),
        default="auto",
        help="the reference object in the photos, only it looked for (default auto: any; a sheet with a corner "
        "hidden or cut off is then taken to be A4)",
    )
    m.add_argument("--out", default="footmesh_out", help="output folder (default footmesh_out)")
    m.add_argument("--json", action="store_true", help="print the result JSON to stdout")
    m.set_defaults(func=_run_measure)


def _run_measure(args: argparse.Namespace) -> int:
    from footmesh.batch import measure_batch

    n = len(args.images)
    depths = args.depth or []
    if depths and len(depths) != n:
        raise InputError(f"give one --depth per photo: {n} photo(s) but {len(depths)} --depth")
    intrinsics = args.intrinsics or []
    if args.same_foot and n < 2:
        raise InputError("--same-foot combines several photos of one foot; give at least two")
    if len(intrinsics) not in (0, 1, n):
        raise InputError(f"give one --intrinsics for all photos or one per photo, not {len(intrinsics)} for {n}")
    return measure_batch(
        args.images,
        args.out,
        depths=depths or None,
        depth_unit=args.depth_unit,
        intrinsics=intrinsics or None,
        side=args.side,
        print_json=args.json,
        embedded_depth=not args.no_embedded_depth,
        same_foot=args.same_foot,
        reference=args.reference,
    )


# --- footmesh demo ------------------------------------------------------------------------------------------


def _add_demo_command(sub: argparse._SubParsersAction) -> None:
    demo = sub.add_parser("demo", help="measure the bundled example photos and compare with their known truth")
    demo.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    demo.add_argument(
        "--model", action="store_true", help="instead: sample, pose, canonicalise and measure a model foot"
    )
    demo.add_argument("--seed", type=int, default=0, help="random seed of --model (default: 0)")
    demo.add_argument("--side", choices=("left", "right"), default="left", help="side of --model")
    demo.set_defaults(func=_run_demo)


def _run_demo(args: argparse.Namespace) -> int:
    from footmesh.demo import DemoConfig, run_demo, run_photo_demo

    if args.model:
        run_demo(args.out, DemoConfig(seed=args.seed, side=args.side))
    else:
        run_photo_demo(args.out)
    return 0


# --- footmesh model ... -------------------------------------------------------------------------------------


def _add_model_commands(sub: argparse._SubParsersAction) -> None:
    model = sub.add_parser("model", help="build and inspect foot models")
    model_sub = model.add_subparsers(dest="model_command", required=True)
    _add_model_register_commands(model_sub)
    _add_model_find_command(model_sub)


def _add_model_find_command(model_sub: argparse._SubParsersAction) -> None:
    """``model build-from-find`` (issue 2: the packaged PCA model from FIND)."""
    find = model_sub.add_parser("build-from-find", help="build the PCA foot model (and skin colours) from FIND")
    find.add_argument("--find", required=True, help="FIND folder (template.obj, model.onnx, latents.json)")
    find.add_argument("--out", required=True, help="model asset to write (.npz)")
    find.add_argument("--n", type=int, default=2000, help="training samples (default 2000)")
    find.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    find.add_argument("--skin-out", help="also write the skin colour asset (.npz) here")
    find.add_argument("--no-progress", action="store_true", help="no progress bar")
    find.set_defaults(func=_run_model_build_from_find)


def _run_model_build_from_find(args: argparse.Namespace) -> int:
    from footmesh.model.build_find import build_from_find, build_skin_colours

    if args.n < 2:
        raise InputError(f"--n must be at least 2, got {args.n}")
    report = build_from_find(args.find, args.out, n_samples=args.n, seed=args.seed, progress=not args.no_progress)
    log.info(
        "wrote %s (%.2f MB) in %.0f s: %d components, %.3f%% of the variance, held-out error %.3f mm",
        report.path,
        report.size_bytes / 1e6,
        report.seconds,
        report.num_components,
        100 * report.explained_variance,
        report.heldout_error_mm,
    )
    for sex, st in report.stats.items():
        log.info(
            "  %s (n=%d): length %.1f +- %.1f mm, ball width %.1f +- %.1f mm, width/length %.3f +- %.3f",
            sex,
            st["n"],
            st["length_mean"],
            st["length_sd"],
            st["width_mean"],
            st["width_sd"],
            st["ratio_mean"],
            st["ratio_sd"],
        )
    if args.skin_out:
        log.info("wrote %s", build_skin_colours(args.find, args.skin_out, seed=args.seed))
    return 0


def _add_model_register_commands(model_sub: argparse._SubParsersAction) -> None:
    """``model register`` and ``model build`` (issue 3: template registration, models from scans)."""
    reg = model_sub.add_parser(
        "register", help="fit the template to one scan (Allen et al. per-vertex affine registration)"
    )
    reg.add_argument("scan", help="scan mesh: .obj, .ply, .stl or .off (mm unless --unit)")
    reg.add_argument("--markers", help="marker file (JSON, see docs/registration.md)")
    reg.add_argument("--out", required=True, help="registered mesh to write (.ply, .obj, .stl)")
    reg.add_argument("--unit", choices=("mm", "cm", "m"), default="mm", help="the scan's length unit")
    reg.add_argument("--template", help="model asset (.npz) whose mean is the template (default: packaged)")
    reg.add_argument("--no-prior", action="store_true", help="do not use the model's components as prior")
    reg.set_defaults(func=_run_model_register)

    build = model_sub.add_parser("build", help="build a PCA foot model from a folder of scans (resumable)")
    build.add_argument("--scans", required=True, help="folder of scans (.obj, .ply, .stl, .off)")
    build.add_argument("--out", required=True, help="model asset to write (.npz)")
    build.add_argument("--markers-dir", help="folder of marker files <scan stem>[.markers].json (default: --scans)")
    build.add_argument("--work", help="cache of registered scans (default: <out>.work)")
    build.add_argument("--unit", choices=("mm", "cm", "m"), default="mm", help="the scans' length unit")
    build.add_argument("--template", help="model asset (.npz) whose mean is the template (default: packaged)")
    build.add_argument("--no-prior", action="store_true", help="do not use the model's components as prior")
    build.add_argument("--variance", type=float, default=0.99, help="fraction of variance kept (default 0.99)")
    build.add_argument("--no-progress", action="store_true", help="no progress bar")
    build.set_defaults(func=_run_model_build)


def _run_model_register(args: argparse.Namespace) -> int:
    from footmesh.model.assets import load_asset
    from footmesh.model.build_scans import BuildConfig, register_scan_file
    from footmesh.report import write_mesh

    template = load_asset(args.template)
    cfg = BuildConfig(unit=args.unit, use_prior=not args.no_prior)
    res = register_scan_file(args.scan, template, args.markers, cfg)
    write_mesh(args.out, res.vertices, res.faces)
    log.info(
        "registered %s in %.1f s (init: %s): mean distance to the scan %.3f mm, %d folded faces; wrote %s",
        args.scan,
        res.seconds,
        res.init_method,
        res.mean_distance_mm,
        res.flipped_faces,
        args.out,
    )
    return 0


def _run_model_build(args: argparse.Namespace) -> int:
    from footmesh.model.assets import load_asset
    from footmesh.model.build_scans import BuildConfig, build_model

    template = load_asset(args.template)
    cfg = BuildConfig(unit=args.unit, use_prior=not args.no_prior, variance=args.variance)
    summary = build_model(
        args.scans, args.out, template, args.markers_dir, args.work, cfg, progress=not args.no_progress
    )
    print(summary.text())
    if summary.asset is None:
        raise InputError(f"{summary.succeeded} scans registered; a model needs at least 2, nothing written")
    print(f"wrote {summary.out}: {summary.asset!r}")
    return 0


# --- footmesh synth (issue 4: synthetic images with full ground truth) ----------------------------------------


def _add_synth_command(sub: argparse._SubParsersAction) -> None:
    synth = sub.add_parser("synth", help="render synthetic foot images with full ground truth, in shards")
    synth.add_argument("--out", required=True, help="dataset folder (or, with --preview, the sheet .png)")
    synth.add_argument("--n", type=int, default=None, help="number of samples of the whole dataset")
    synth.add_argument("--size", type=int, default=224, help="image size in pixels (default 224)")
    synth.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    synth.add_argument("--shards", type=int, default=1, help="number of shards K (default 1)")
    synth.add_argument("--shard-index", type=int, default=0, help="this shard's index I in 0..K-1 (default 0)")
    synth.add_argument("--views", choices=("random", "thesis"), default="random", help="camera views")
    synth.add_argument(
        "--reference", choices=("none", *references.NAMES, "mixed"), default="mixed", help="reference object"
    )
    synth.add_argument(
        "--other-foot", type=float, default=0.0, metavar="P", help="share of samples with the other foot in view"
    )
    synth.add_argument(
        "--first-person",
        type=float,
        default=0.0,
        metavar="P",
        help="share of views from above and behind the heels, down the legs (as one photographs one's own feet)",
    )
    synth.add_argument(
        "--front",
        type=float,
        default=0.0,
        metavar="P",
        help="share of the other views from in front of the toes and above, the foot on the sheet, the shin hiding "
        "the heel (as most real photos of a foot on a sheet are taken)",
    )
    synth.add_argument(
        "--skin-legs",
        action="store_true",
        help="bare legs take the foot's skin colours around the ankle, drifting up the leg (default: one even colour)",
    )
    synth.add_argument("--workers", type=int, default=1, help="rendering processes (default 1)")
    synth.add_argument(
        "--threads",
        type=int,
        default=None,
        help="rendering threads in each process (default: one per core with --workers 1, else 1)",
    )
    synth.add_argument("--preview", type=int, metavar="N", help="write a contact sheet of N samples to --out")
    synth.add_argument("--no-progress", action="store_true", help="no progress bar")
    synth.set_defaults(func=_run_synth)


def _run_synth(args: argparse.Namespace) -> int:
    from footmesh.synth.scene import SynthConfig

    try:
        config = SynthConfig(
            size=args.size,
            views=args.views,
            reference=args.reference,
            other_foot_fraction=args.other_foot,
            first_person_fraction=args.first_person,
            front_fraction=args.front,
            skin_legs=args.skin_legs,
        )
    except ValueError as exc:
        raise InputError(str(exc)) from None
    if args.workers < 1:
        raise InputError(f"--workers must be at least 1, got {args.workers}")
    if args.threads is not None and args.threads < 1:
        raise InputError(f"--threads must be at least 1, got {args.threads}")
    if args.preview is not None:
        from footmesh.synth.preview import write_preview
        from footmesh.synth.render import Renderer

        if not 1 <= args.preview <= 400:
            raise InputError(f"--preview must be 1..400 samples, got {args.preview}")
        if not args.out.lower().endswith(".png"):
            raise InputError(f"with --preview, --out is the contact sheet and must end in .png, got {args.out}")
        renderer = Renderer(config)
        write_preview(args.out, [renderer.render(args.seed, i) for i in range(args.preview)])
        log.info("wrote %s (%d samples, seed %d)", args.out, args.preview, args.seed)
        return 0
    if args.n is None or args.n < 1:
        raise InputError("--n must be given and at least 1 (the number of samples of the whole dataset)")
    if args.shards < 1 or not 0 <= args.shard_index < args.shards:
        raise InputError(f"--shard-index must be in 0..{args.shards - 1} for --shards {args.shards}")
    from footmesh.synth.dataset import generate

    written = generate(
        args.out,
        args.n,
        args.seed,
        config,
        args.shards,
        args.shard_index,
        workers=args.workers,
        progress=not args.no_progress,
        threads=args.threads,
    )
    log.info("wrote %d chunk files into %s (shard %d of %d)", len(written), args.out, args.shard_index, args.shards)
    return 0


# --- footmesh train ... (issue 5: 2D cues) --------------------------------------------------------------------


def _add_train_commands(sub: argparse._SubParsersAction) -> None:
    train = sub.add_parser("train", help="train footmesh's networks on synthetic data (resumable, torchrun-ready)")
    train_sub = train.add_subparsers(dest="train_command", required=True)
    cues = train_sub.add_parser("cues", help="train the 2D-cues network (silhouette + 18 joints)")
    cues.add_argument("--input", choices=("rgb", "rgbd", "depth"), required=True, help="input channels")
    cues.add_argument("--data", required=True, help="synthetic dataset folder (footmesh synth)")
    cues.add_argument("--out", help="run folder: checkpoint, logs, weights.pt (default runs/cues-INPUT)")
    cues.add_argument("--config", help="JSON configuration (see footmesh.config); command-line flags override it")
    cues.add_argument("--thesis", action="store_true", help="the thesis' network (3 stacks, ResNet-18, 224 px)")
    cues.add_argument("--steps", type=int, help="training steps")
    cues.add_argument("--batch-size", type=int, help="batch size per process")
    cues.add_argument("--max-minutes", type=float, help="stop (resumable) after this many minutes")
    cues.add_argument("--init-from", help="weights to start from (e.g. the RGB-D network's weights.pt)")
    cues.add_argument("--threads", type=int, help="torch threads per process")
    cues.add_argument("--no-progress", action="store_true", help="no progress bar")
    cues.set_defaults(func=_run_train_cues)
    recon = train_sub.add_parser("recon", help="train the image -> mesh network (or the EdgeConv baseline)")
    recon.add_argument("--input", choices=("rgb", "rgbd", "depth"), required=True, help="input channels")
    recon.add_argument("--data", required=True, help="synthetic dataset folder with vertices (footmesh synth)")
    recon.add_argument(
        "--out", help="run folder: checkpoint, logs, weights.pt, MODEL_CARD.md (default runs/recon-INPUT-LOSS)"
    )
    recon.add_argument("--config", help="JSON configuration (footmesh.train.recon); command-line flags override it")
    recon.add_argument("--loss", choices=("thesis", "structure"), help="mesh loss (default thesis)")
    recon.add_argument(
        "--kind",
        choices=("ism", "edgeconv", "model"),
        help="ism: the thesis' spiral mesh decoder (default); model: the foot model's parameters plus an ISM "
        "residual; edgeconv: the point-cloud baseline",
    )
    recon.add_argument(
        "--encoder",
        choices=("resnet", "efficientnet_lite0"),
        help="image encoder: resnet (from scratch, the default) or the ImageNet-pretrained EfficientNet-Lite0",
    )
    recon.add_argument("--steps", type=int, help="training steps")
    recon.add_argument("--batch-size", type=int, help="batch size per process")
    recon.add_argument("--max-minutes", type=float, help="stop (resumable) after this many minutes")
    recon.add_argument("--init-from", help="recon weights.pt to start from (e.g. the RGB-D network's for RGB)")
    recon.add_argument("--threads", type=int, help="torch threads per process")
    recon.add_argument("--no-progress", action="store_true", help="no progress bar")
    recon.set_defaults(func=_run_train_recon)


def _train_flags(train, args: argparse.Namespace):
    """``train`` (a ``TrainConfig``) with the command-line flags that were given."""
    from dataclasses import replace

    flags = {
        "steps": args.steps,
        "batch_size": args.batch_size,
        "max_minutes": args.max_minutes,
        "init_from": args.init_from,
        "threads": args.threads,
    }
    for name in ("steps", "batch_size", "threads"):
        value = flags[name]
        if value is not None and value < 1:
            raise InputError(f"--{name.replace('_', '-')} must be at least 1, got {value}")
    return replace(train, **{k: v for k, v in flags.items() if v is not None})


def _log_training(result, out: str) -> None:
    state = "finished" if result.finished else "stopped (rerun the same command to resume)"
    metrics = ", ".join(f"{k} {v:.4g}" for k, v in result.metrics.items())
    log.info(
        "%s after %d steps in %.0f min; %s; weights: %s/weights.pt",
        state,
        result.steps_done,
        result.seconds / 60,
        metrics,
        out,
    )


def _run_train_cues(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from footmesh.config import CuesNetConfig, load_config
    from footmesh.train.cues import train_cues

    config = load_config(args.config, input=args.input)
    if args.thesis:
        config = replace(config, net=CuesNetConfig.thesis(args.input))
    config = replace(config, train=_train_flags(config.train, args))
    out = args.out or f"runs/cues-{args.input}"
    result = train_cues(args.data, out, config, progress=not args.no_progress)
    _log_training(result, out)
    return 0


def _run_train_recon(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from footmesh.recon.model import EFFICIENTNET_WIDTHS, LOSSES
    from footmesh.train.recon import load_recon_config, train_recon

    config = load_recon_config(args.config)
    kind = args.kind or config.model.kind
    # a kind changed by the flag brings its own default loss (the EdgeConv baseline: the Chamfer distance)
    loss = args.loss or (config.model.loss if kind == config.model.kind else LOSSES[kind][0])
    model = replace(config.model, input=args.input, kind=kind, loss=loss)
    if args.encoder == "efficientnet_lite0" and model.widths != EFFICIENTNET_WIDTHS:
        decoder = replace(model.decoder, skip_in_channels=tuple(reversed(EFFICIENTNET_WIDTHS)))
        model = replace(model, widths=EFFICIENTNET_WIDTHS, decoder=decoder, encoder=args.encoder)
    elif args.encoder:
        model = replace(model, encoder=args.encoder)
    config = replace(config, model=model, train=_train_flags(config.train, args))
    out = args.out or f"runs/recon-{args.input}-{loss if kind == 'ism' else kind}"
    result = train_recon(args.data, out, config, progress=not args.no_progress)
    _log_training(result, out)
    return 0


# --- footmesh eval ... ------------------------------------------------------------------------------------------


def _add_eval_commands(sub: argparse._SubParsersAction) -> None:
    ev = sub.add_parser("eval", help="evaluate on held-out synthetic test splits; thesis tables beside ours")
    ev_sub = ev.add_subparsers(dest="eval_command", required=True)
    cues = ev_sub.add_parser("cues", help="Tables 4.1, 4.2 (and 4.3 per viewpoint) of the 2D-cues networks")
    cues.add_argument("--input", choices=("rgb", "rgbd", "depth", "all"), default="all", help="network(s)")
    cues.add_argument("--data", required=True, help="test folder (footmesh synth, another seed than training)")
    cues.add_argument("--views-data", help="test folder made with --views thesis, for Table 4.3")
    cues.add_argument("--weights", help="weights.pt to evaluate instead of the shipped ones (one --input)")
    cues.add_argument("--json", help="also write the numbers to this JSON file")
    cues.set_defaults(func=_run_eval_cues)
    meas = ev_sub.add_parser("measure", help="Tables 4.7 (4.8, 4.9): the whole pipeline on synthetic photos")
    meas.add_argument(
        "--modes", default="rgb_ref,rgbd,depth,rgb", help="comma list of rgb_ref, rgbd, depth, rgb, rgbd_heic"
    )
    meas.add_argument("--n", type=int, default=60, help="photos per mode (default 60)")
    meas.add_argument("--size", type=int, default=640, help="photo side, px (default 640)")
    meas.add_argument(
        "--views",
        choices=("random", "thesis", "guided", "ood", "sweep", "tele", "front", "front_tele"),
        default="random",
        help="camera views: random (any side and height), thesis (its 22 viewpoints), guided (as the photo guide "
        "asks: from the side and above, foot flat on the floor), ood (unlike the training renders: other fields of "
        "view and distances, lifted and posed feet, a leg stump, re-toned skin, heavier noise), sweep (flat feet "
        "from every side and height, end-on included: benchmarks/bench_end_on.py), tele (the guided views through a "
        "2x-3x lens), front (from in front of the toes and above, the foot on the sheet and the shin hiding the heel, "
        "as most real photos are taken), front_tele (the same through a 2x-3x lens)",
    )
    meas.add_argument(
        "--withhold-intrinsics",
        action="store_true",
        help="measure the RGB photos without their K.json, as photos without EXIF are (the focal length assumed, "
        "or taken from the reference object's perspective)",
    )
    meas.add_argument("--seed", type=int, default=4242, help="seed of the test photos (default 4242; training: 1-3)")
    meas.add_argument("--json", help="also write per-photo records to this JSON file")
    meas.add_argument("--no-progress", action="store_true", help="no progress bar")
    meas.set_defaults(func=_run_eval_measure)
    real = ev_sub.add_parser("real", help="the RGB silhouette on real photos with hand-drawn foot masks")
    real.add_argument(
        "--set", required=True, dest="real_set", help="folder with labels.json (../shared/real/rafiansyah)"
    )
    real.add_argument("--sheet", help="write a contact sheet of overlays to this PNG")
    real.add_argument("--json", help="also write per-photo scores to this JSON file")
    real.add_argument("--weights", help="an RGB 2D-cues weights file to evaluate (default: the shipped one)")
    real.add_argument(
        "--measure",
        action="store_true",
        help="also run footmesh measure on each photo and score the mask.png of each foot it measured (~5 s a "
        "photo); the contact sheet then shows those masks",
    )
    real.add_argument("--no-progress", action="store_true", help="no progress bar")
    real.set_defaults(func=_run_eval_real)
    recon = ev_sub.add_parser("recon", help="Tables 4.4, 4.5 (and 4.6 per viewpoint) of the reconstruction networks")
    recon.add_argument("--input", choices=("rgb", "rgbd", "depth", "all"), default="all", help="network(s)")
    recon.add_argument("--data", required=True, help="test folder (footmesh synth, another seed than training)")
    recon.add_argument("--views-data", help="test folder made with --views thesis, for Table 4.6")
    recon.add_argument("--weights", help="weights.pt to evaluate instead of the shipped ones (one --input)")
    recon.add_argument("--edgeconv-weights", help="weights.pt of an EdgeConv baseline run, for Table 4.4")
    recon.add_argument(
        "--model-weights", help="weights.pt of a model-based run (train recon --kind model), beside the ISM decoder"
    )
    recon.add_argument("--limit", type=int, help="evaluate only the first N samples of each folder")
    recon.add_argument(
        "--pipeline",
        choices=("rgb", "rgbd", "depth"),
        action="append",
        help="also the whole pipeline's mesh (decoder start + fit) for this input (repeatable; ~1 s a photo)",
    )
    recon.add_argument("--pipeline-limit", type=int, help="the whole pipeline on the first N samples only")
    recon.add_argument(
        "--mirror-average",
        action="store_true",
        help="each network's mesh the average of its answers for the image and its mirror image",
    )
    recon.add_argument("--json", help="also write the numbers to this JSON file")
    recon.set_defaults(func=_run_eval_recon)


def _run_eval_cues(args: argparse.Namespace) -> int:
    from footmesh.eval.cues import INPUTS, run_eval

    inputs = list(INPUTS) if args.input == "all" else [args.input]
    if args.weights and len(inputs) != 1:
        raise InputError("--weights needs a single --input (rgb, rgbd or depth)")
    weights = {inputs[0]: args.weights} if args.weights else None
    print(run_eval(args.data, inputs, args.views_data, weights, args.json))
    return 0


def _run_eval_measure(args: argparse.Namespace) -> int:
    from footmesh.eval.measure import MODES, run_eval

    modes = [m.strip() for m in args.modes.split(",") if m.strip()]
    bad = [m for m in modes if m not in MODES]
    if bad or not modes:
        raise InputError(f"--modes must be a comma list of {', '.join(MODES)}; got {args.modes!r}")
    if args.n < 1 or args.size < 128:
        raise InputError("--n must be at least 1 and --size at least 128")
    run_eval(
        modes,
        args.n,
        args.size,
        args.views,
        args.json,
        progress=not args.no_progress,
        seed=args.seed,
        withhold_intrinsics=args.withhold_intrinsics,
    )
    return 0


def _run_eval_real(args: argparse.Namespace) -> int:
    from footmesh.eval.real import run_eval

    try:
        table = run_eval(
            args.real_set, args.sheet, args.json, not args.no_progress, weights=args.weights, measure=args.measure
        )
        print(table)
    except ValueError as exc:
        raise InputError(str(exc)) from None
    return 0


def _run_eval_recon(args: argparse.Namespace) -> int:
    from footmesh.eval.recon import INPUTS, run_eval

    inputs = list(INPUTS) if args.input == "all" else [args.input]
    if args.weights and len(inputs) != 1:
        raise InputError("--weights needs a single --input (rgb, rgbd or depth)")
    for flag, value in (("--limit", args.limit), ("--pipeline-limit", args.pipeline_limit)):
        if value is not None and value < 1:
            raise InputError(f"{flag} must be at least 1, got {value}")
    weights = {inputs[0]: args.weights} if args.weights else None
    print(
        run_eval(
            args.data,
            inputs,
            args.views_data,
            weights,
            args.json,
            args.edgeconv_weights,
            args.limit,
            model_weights=args.model_weights,
            pipeline=args.pipeline,
            pipeline_limit=args.pipeline_limit,
            mirror_average=args.mirror_average,
        )
    )
    return 0


# --- entry point ---------------------------------------------------------------------------------------------


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(message)s")
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("footmesh: interrupted", file=sys.stderr)
        return 130
    except Exception as exc:
        if is_users_fault(exc) or (args.command in DEVELOPER_COMMANDS and _developer_input_error(exc)):
            print(f"footmesh: error: {exc}", file=sys.stderr)
            return 2
        print(f"footmesh: {write_internal_report(exc, __version__)}", file=sys.stderr)
        return 1


def _developer_input_error(exc: BaseException) -> bool:
    """A developer command's error that names its folder or configuration (not linear algebra that failed)."""
    import numpy as np

    return isinstance(exc, ValueError | FileNotFoundError) and not isinstance(exc, np.linalg.LinAlgError)
