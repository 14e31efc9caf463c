"""A resumable training loop: checkpoints, time budget, CSV/TensorBoard logs, and DDP under ``torchrun``.

One process by default; under ``torchrun --nproc_per_node N`` each process trains on its slice of every global
batch and gradients are averaged by ``DistributedDataParallel`` (gloo on CPU, NCCL on GPUs). Batches are drawn
from a generator seeded by ``(seed, step)``, so a resumed run sees the same batches as an uninterrupted one.
"""

from __future__ import annotations

import csv
import json
import logging
import math
import os
import signal
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import torch
import torch.distributed as dist
from torch import nn

from footmesh.config import TrainConfig
from footmesh.report import atomic_path

log = logging.getLogger("footmesh.train")

CHECKPOINT = "checkpoint.pt"
LOG_CSV = "log.csv"


class TrainingTask(Protocol):
    """What the loop needs from a task (e.g. ``footmesh.train.cues.CuesTask``)."""

    def loss(
        self, model: nn.Module, step: int, generator: torch.Generator, rank: int, world: int
    ) -> tuple[torch.Tensor, dict[str, float]]:
        """Loss of this process's share of global batch ``step`` and its terms (floats) for the log."""

    def validate(self, model: nn.Module) -> dict[str, float]:
        """Validation metrics of the (unwrapped) model, in eval mode."""


@dataclass(frozen=True)
class Distributed:
    rank: int = 0
    world: int = 1
    local_rank: int = 0

    @property
    def is_main(self) -> bool:
        return self.rank == 0


def init_distributed() -> Distributed:
    """The process group of a ``torchrun`` launch (from its environment), or a single process."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world <= 1:
        return Distributed()
    if not dist.is_initialized():
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend=backend)
    return Distributed(dist.get_rank(), dist.get_world_size(), int(os.environ.get("LOCAL_RANK", "0")))


def lr_at(step: int, config: TrainConfig) -> float:
    """Linear warm-up, then cosine decay to 2 % of the peak learning rate at ``config.steps``."""
    if step < config.warmup_steps:
        return config.lr * (step + 1) / config.warmup_steps
    t = min(1.0, (step - config.warmup_steps) / max(1, config.steps - config.warmup_steps))
    return config.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * t)))


def param_groups(model: nn.Module, config: TrainConfig) -> list[dict[str, Any]]:
    """The optimiser's parameter groups, each with its ``lr_scale``: the parts a model names in
    ``pretrained_submodules`` at ``config.pretrained_lr_scale`` (one group when that is 1, as older checkpoints
    have), the rest at 1."""
    names = getattr(model, "pretrained_submodules", ())
    if config.pretrained_lr_scale == 1.0 or not names:
        return [{"params": list(model.parameters()), "lr_scale": 1.0}]
    pretrained = {id(p) for name in names for p in model.get_submodule(name).parameters()}
    rest = [p for p in model.parameters() if id(p) not in pretrained]
    chosen = [p for p in model.parameters() if id(p) in pretrained]
    return [{"params": rest, "lr_scale": 1.0}, {"params": chosen, "lr_scale": config.pretrained_lr_scale}]


@dataclass
class TrainResult:
    steps_done: int
    finished: bool
    seconds: float
    metrics: dict[str, float]


class _Stop:
    """SIGTERM/SIGINT set a flag so the loop checkpoints and exits cleanly instead of losing work."""

    def __init__(self) -> None:
        self.requested = False
        self._old = {}

    def __enter__(self) -> _Stop:
        for sig in (signal.SIGTERM, signal.SIGINT):
            try:
                self._old[sig] = signal.signal(sig, self._handle)
            except ValueError:  # not the main thread: leave signals alone
                pass
        return self

    def _handle(self, signum, frame) -> None:
        self.requested = True

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)


def run_training(
    model: nn.Module,
    task: TrainingTask,
    out: str | os.PathLike,
    config: TrainConfig,
    full_config: dict[str, Any],
    progress: bool = True,
    on_checkpoint: Callable[[nn.Module, dict[str, float]], None] | None = None,
) -> TrainResult:
    """Train ``model`` on ``task`` for ``config.steps`` steps, resuming from ``out/checkpoint.pt`` if present.

    ``full_config`` is stored in every checkpoint; resuming with a different one is refused (mixing settings
    would silently make a model no command reproduces).
    """
    ctx = init_distributed()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    threads = config.threads or max(1, (os.cpu_count() or 1) // ctx.world)
    torch.set_num_threads(threads)
    torch.manual_seed(config.seed)

    optimizer = torch.optim.AdamW(param_groups(model, config), lr=config.lr, weight_decay=config.weight_decay)
    step, elapsed, metrics = 0, 0.0, {}
    ckpt_path = out / CHECKPOINT
    if ckpt_path.is_file():
        ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=False)
        if _comparable(ckpt["config"]) != _comparable(full_config):
            raise ValueError(
                f"{ckpt_path} was written with another configuration; use another --out or the same settings"
            )
        model.load_state_dict(ckpt["model"])
        optimizer.load_state_dict(ckpt["optimizer"])
        step, elapsed, metrics = ckpt["step"], ckpt["elapsed"], ckpt.get("metrics", {})
        if ctx.is_main:
            log.info("resuming %s at step %d of %d", ckpt_path, step, config.steps)

    net = model
    if ctx.world > 1:
        net = nn.parallel.DistributedDataParallel(model)

    def save() -> None:
        if not ctx.is_main:
            return
        state = {
            "model": model.state_dict(),
            "optimizer": optimizer.state_dict(),
            "step": step,
            "elapsed": elapsed,
            "metrics": metrics,
            "config": full_config,
        }
        with atomic_path(ckpt_path) as tmp:
            torch.save(state, tmp)
        if on_checkpoint is not None:
            on_checkpoint(model, metrics)

    logger = _Logger(out, enabled=ctx.is_main)
    start, last_save = time.time() - elapsed, time.time()
    budget_end = time.time() + config.max_minutes * 60 if config.max_minutes else math.inf
    from tqdm import tqdm

    bar = tqdm(
        total=config.steps, initial=step, disable=not (progress and ctx.is_main), unit="step", dynamic_ncols=True
    )
    with _Stop() as stop:
        model.train()
        while step < config.steps:
            t0 = time.time()
            for group in optimizer.param_groups:
                group["lr"] = lr_at(step, config) * group["lr_scale"]
            generator = torch.Generator().manual_seed(config.seed * 1_000_003 + step)
            loss, terms = task.loss(net, step, generator, ctx.rank, ctx.world)
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
            optimizer.step()
            step += 1
            elapsed = time.time() - start
            terms = {**terms, "lr": optimizer.param_groups[0]["lr"], "step_s": time.time() - t0}
            logger.write(step, elapsed, terms)
            bar.update(1)
            bar.set_postfix(loss=f"{loss.item():.3f}")
            last = step == config.steps
            if step % config.val_every == 0 or last:
                if ctx.is_main:
                    model.eval()
                    metrics = {f"val_{k}": v for k, v in task.validate(model).items()}
                    model.train()
                    logger.write(step, elapsed, metrics)
                    bar.write(f"step {step}: " + ", ".join(f"{k} {v:.4g}" for k, v in metrics.items()))
            out_of_time = _any(time.time() >= budget_end or stop.requested, ctx)
            if last or out_of_time or time.time() - last_save >= config.checkpoint_every_s:
                save()
                last_save = time.time()
            if out_of_time and not last:
                if ctx.is_main:
                    bar.write(f"stopping at step {step} (time budget or signal); rerun the same command to resume")
                break
    bar.close()
    logger.close()
    if ctx.world > 1:
        dist.barrier()
    return TrainResult(step, step >= config.steps, elapsed, metrics)


RUN_CONTROL = ("max_minutes", "threads", "checkpoint_every_s", "val_every")
"""Training fields that may change between a run and its resumption (they do not change the model)."""


def _comparable(config: dict[str, Any]) -> dict[str, Any]:
    data = json.loads(json.dumps(config))
    for section in data.values():
        if isinstance(section, dict):
            for name in RUN_CONTROL:
                section.pop(name, None)
    return data


def _any(flag: bool, ctx: Distributed) -> bool:
    """``flag`` of any process (all stop at the same step, or DDP would hang)."""
    if ctx.world == 1:
        return flag
    t = torch.tensor([int(flag)])
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item())


class _Logger:
    """Appends rows to ``log.csv`` (``step, elapsed_s, name, value``: new metrics need no new columns) and to
    TensorBoard when its package is installed."""

    def __init__(self, out: Path, enabled: bool) -> None:
        self.enabled = enabled
        self.file = self.writer = self.tb = None
        if not enabled:
            return
        path = out / LOG_CSV
        new = not path.is_file()
        self.file = open(path, "a", newline="")
        self.writer = csv.writer(self.file)
        if new:
            self.writer.writerow(["step", "elapsed_s", "name", "value"])
        try:
            from torch.utils.tensorboard import SummaryWriter

            self.tb = SummaryWriter(str(out / "tensorboard"))
        except (ImportError, ModuleNotFoundError):
            self.tb = None

    def write(self, step: int, elapsed: float, values: dict[str, float]) -> None:
        if not self.enabled:
            return
        for name, value in values.items():
            self.writer.writerow([step, f"{elapsed:.1f}", name, f"{float(value):.6g}"])
            if self.tb is not None:
                self.tb.add_scalar(name, float(value), step)
        self.file.flush()

    def close(self) -> None:
        if self.file is not None:
            self.file.close()
        if self.tb is not None:
            self.tb.close()
