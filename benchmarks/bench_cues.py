"""2D-cues networks on this CPU: inference time per image beside the 60 ms goal, and training throughput.

Inference: batch 1, median of ``--runs`` calls after warm-up, at 2 and 1 torch threads, for the default network
of each input kind (the shipped weights when present, otherwise an untrained network of the same configuration:
the time does not depend on the weights' values) and for the thesis' network; "network" times the forward pass
of an input already at the network's side, "predict_cues" the whole call on a 224 x 224 photo (resize, forward,
silhouette and joints mapped back; with the mirror image in the same batch for ``MIRROR_AVERAGED_INPUTS``).
"Both passes" times the cues of one whole photo as the pipeline gets them (``pipeline.whole_photo_cues`` on a
1600 x 1200 photo padded to a square, then ``predict_cues`` on a 700 px crop)
beside issue 18's 150 ms goal, with the shipped networks. Training: images per second of the default network at
batch 32, counting batch assembly, augmentation, forward, backward and the optimiser step
(``footmesh.train.cues.CuesTask``).

Run: ``python benchmarks/bench_cues.py [--quick] [--data DIR]`` (or ``python -m benchmarks bench_cues``).
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from dataclasses import replace

import numpy as np
import torch

GOAL_MS = 60.0
"""Inference time per image at batch 1 (issue 5)."""
PHOTO_GOAL_MS = 150.0
"""Both passes of the cues of one photo (issue 18)."""
WHOLE_PHOTO = (1200, 1600)
CROP_SIDE = 700
INPUTS = ("rgbd", "depth", "rgb")
PHOTO_SIDE = 224


def _median_ms(fn, runs: int, warmup: int) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000 * statistics.median(times)


def _network(kind: str, thesis: bool):
    """The network to time, its configuration and where its weights come from."""
    from footmesh.config import CuesNetConfig
    from footmesh.cues.net import build_network
    from footmesh.cues.weights import load_network, packaged_weights

    if not thesis:
        try:
            model, config, _ = load_network(packaged_weights(kind))
            return model, config, "shipped"
        except FileNotFoundError:
            pass
    config = CuesNetConfig.thesis(kind) if thesis else CuesNetConfig(input=kind)
    torch.manual_seed(0)
    return build_network(config).eval(), config, "untrained"


def _photo(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A 224 x 224 photo-like image and depth map (timing does not depend on the content)."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (PHOTO_SIDE, PHOTO_SIDE, 3), dtype=np.uint8)
    depth = rng.uniform(300, 700, (PHOTO_SIDE, PHOTO_SIDE)).astype(np.float32)
    return rgb, depth


def inference_rows(threads: list[int], runs: int, warmup: int, thesis: bool) -> list[tuple]:
    """(network, weights, threads, network ms, predict_cues ms) per input kind and thread count."""
    from footmesh.cues.inputs import network_input
    from footmesh.cues.predict import MIRROR_AVERAGED_INPUTS, predict_batch, resize_inputs

    rows = []
    rgb, depth = _photo()
    kinds = [(k, False) for k in INPUTS] + ([("rgbd", True)] if thesis else [])
    for kind, is_thesis in kinds:
        model, config, source = _network(kind, is_thesis)
        s = config.image_size
        x = network_input(
            kind,
            torch.rand(1, 3, s, s) if kind != "depth" else None,
            300 + 400 * torch.rand(1, 1, s, s) if kind != "rgb" else None,
        )
        stacks = f"{config.stacks} stack{'s' if config.stacks > 1 else ''}"
        if config.encoder != "scratch":
            stacks = config.encoder
        name = f"{'thesis' if is_thesis else 'default'} {kind} ({stacks}, {s} px)"

        def predict(model=model, config=config, kind=kind) -> None:
            # predict_cues' body without its per-process cache of shipped files, so any network can be timed
            r, d = resize_inputs(rgb if kind != "depth" else None, depth if kind != "rgb" else None, config.image_size)
            predict_batch(model, config, None if r is None else r[None], None if d is None else d[None],
                          out_size=(PHOTO_SIDE, PHOTO_SIDE),
                          mirror_average=kind in MIRROR_AVERAGED_INPUTS)  # fmt: skip

        for n in threads:
            torch.set_num_threads(n)
            with torch.no_grad():
                net_ms = _median_ms(lambda model=model, x=x: model(x), runs, warmup)
            rows.append((name, source, n, net_ms, _median_ms(predict, runs, warmup)))
    return rows


def _training_arrays(size: int, data: str | None, n: int = 256):
    """Arrays to draw training batches from: a dataset folder's cache, or random images of the same form."""
    from footmesh.train.data import CuesArrays, load_arrays

    if data:
        return load_arrays(data, size, progress=False)
    rng = np.random.default_rng(0)
    joints = rng.uniform(0, size, (n, 18, 2)).astype(np.float32)
    yy, xx = np.mgrid[:size, :size]
    disc = ((xx - size / 2) ** 2 + (yy - size / 2) ** 2 < (size / 4) ** 2).astype(np.uint8) * 255
    return CuesArrays(
        rgb=rng.integers(0, 256, (n, size, size, 3), dtype=np.uint8),
        depth=rng.integers(300, 700, (n, size, size), dtype=np.uint16),
        silhouette=np.broadcast_to(disc, (n, size, size)).copy(),
        joints2d=joints,
        joints_visible=rng.random((n, 18)) < 0.7,
        view_id=np.full(n, -1, np.int16),
        side=(rng.random(n) < 0.5).astype(np.int8),
        index=np.arange(n),
        size=size,
    )


def _train_step(task, model: torch.nn.Module, optimizer: torch.optim.Optimizer):
    """One call = one training step of ``task`` (a new batch each call, as in ``run_training``)."""
    count = [0]

    def step() -> None:
        generator = torch.Generator().manual_seed(count[0])
        loss, _ = task.loss(model, count[0], generator, 0, 1)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        optimizer.step()
        count[0] += 1

    return step


def photo_rows(threads: list[int], runs: int, warmup: int) -> list[tuple]:
    """(input kind, threads, both passes ms) with the shipped networks, on a random whole photo."""
    from footmesh.cues.predict import predict_cues
    from footmesh.pipeline import whole_photo_cues

    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, (*WHOLE_PHOTO, 3), dtype=np.uint8)
    depth = rng.uniform(300, 700, WHOLE_PHOTO).astype(np.float32)
    rows = []
    for kind in INPUTS:
        photo_rgb = None if kind == "depth" else rgb
        photo_depth = None if kind == "rgb" else depth

        def both(kind=kind, photo_rgb=photo_rgb, photo_depth=photo_depth) -> None:
            whole_photo_cues(kind, photo_rgb, photo_depth)
            crop = (slice(100, 100 + CROP_SIDE), slice(300, 300 + CROP_SIDE))
            predict_cues(
                kind, None if photo_rgb is None else photo_rgb[crop], None if photo_depth is None else photo_depth[crop]
            )

        for n in threads:
            torch.set_num_threads(n)
            with torch.no_grad():
                rows.append((kind, n, _median_ms(both, runs, warmup)))
    return rows


def training_rows(threads: list[int], steps: int, batch: int, data: str | None) -> list[tuple]:
    """(what, threads, images/s, ms/step) of the default RGB-D network's training step."""
    from footmesh.config import CuesTrainingConfig
    from footmesh.cues.net import build_network
    from footmesh.train.cues import CuesTask

    config = CuesTrainingConfig()
    config = replace(config, train=replace(config.train, batch_size=batch))
    arrays = _training_arrays(config.net.image_size, data)
    task = CuesTask(arrays, arrays, config)
    rows = []
    for n in threads:
        torch.set_num_threads(n)
        torch.manual_seed(0)
        model = build_network(config.net).train()
        optimizer = torch.optim.AdamW(model.parameters(), lr=config.train.lr)

        ms = _median_ms(_train_step(task, model, optimizer), steps, 1)
        what = f"default {config.net.input}, batch {batch}, augmentation on"
        rows.append((what, n, 1000 * batch / ms, ms))
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="a few runs, 1 thread, small batch: a check")
    parser.add_argument("--runs", type=int, default=50, help="timed calls per inference figure (default 50)")
    parser.add_argument("--train-steps", type=int, default=5, help="timed training steps (default 5; 0: none)")
    parser.add_argument("--batch", type=int, default=32, help="training batch size (default 32)")
    parser.add_argument("--data", help="synthetic dataset folder for the training batches (default: random arrays)")
    args = parser.parse_args(argv)

    threads = [1] if args.quick else sorted({min(2, os.cpu_count() or 1), 1}, reverse=True)
    runs, warmup = (2, 1) if args.quick else (args.runs, 5)
    train_steps, batch = (2, 8) if args.quick else (args.train_steps, args.batch)

    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, torch {torch.__version__}")
    if args.quick:
        print("QUICK CHECK: few runs, small batch; the numbers are not the benchmark's")
    rows = inference_rows(threads, runs, warmup, thesis=True)
    print(f"\ninference at batch 1, median of {runs} calls after {warmup} warm-up ({PHOTO_SIDE} px photo)")
    print(f"{'network':<34} {'weights':<10} {'threads':>7} {'network ms':>11} {'predict_cues ms':>16} {'goal ms':>8}")
    for name, source, n, net_ms, call_ms in rows:
        mark = "" if call_ms <= GOAL_MS else "  over the goal"
        print(f"{name:<34} {source:<10} {n:>7} {net_ms:>11.1f} {call_ms:>16.1f} {GOAL_MS:>8.0f}{mark}")

    print(f"\ncues of one {WHOLE_PHOTO[1]} x {WHOLE_PHOTO[0]} photo, both passes (whole photo + {CROP_SIDE} px crop), "
          "shipped networks")  # fmt: skip
    print(f"{'input':<8} {'threads':>7} {'both passes ms':>15} {'goal ms':>8}")
    for kind, n, ms in photo_rows(threads, runs, warmup):
        mark = "" if ms <= PHOTO_GOAL_MS else "  over the goal"
        print(f"{kind:<8} {n:>7} {ms:>15.1f} {PHOTO_GOAL_MS:>8.0f}{mark}")

    if train_steps < 1:  # inference only
        return 0
    rows = training_rows(threads, train_steps, batch, args.data)
    source = args.data or "random arrays"
    print(f"\ntraining step (batch assembly + augmentation + forward + backward + AdamW), median of "
          f"{train_steps} steps, data: {source}")  # fmt: skip
    print(f"{'what':<40} {'threads':>7} {'images/s':>9} {'ms/step':>9}")
    for what, n, rate, ms in rows:
        print(f"{what:<40} {n:>7} {rate:>9.1f} {ms:>9.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
