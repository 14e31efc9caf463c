"""Training the 2D-cues network: ``footmesh train cues --input rgb|rgbd|depth --data DIR``."""

from __future__ import annotations

import logging
import os
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812
from torch import nn

from footmesh.config import CuesLossConfig, CuesNetConfig, CuesTrainingConfig
from footmesh.cues.inputs import network_input
from footmesh.cues.net import HEATMAP_STRIDE, SILHOUETTE_STRIDE, CuesOutput, build_network, gaussian_targets
from footmesh.cues.weights import save_weights
from footmesh.train.data import Augment, Batch, CuesArrays, augment_batch, load_arrays, make_batch
from footmesh.train.loop import TrainResult, run_training

log = logging.getLogger("footmesh.train")

EVAL_SIZE = 224
"""Image side the thesis reports joint errors in (Tables 4.2, 4.3)."""
WEIGHTS = "weights.pt"
FIRST_CONV = "stem1.0.weight"
"""The convolution that sees the input channels (adapted between input kinds)."""


def cues_loss(
    outputs: list[CuesOutput], batch: Batch, net: CuesNetConfig, weights: CuesLossConfig
) -> tuple[torch.Tensor, dict[str, float]]:
    """Intermediate supervision: the sum over stacks of the silhouette and joint losses of ``net.head``."""
    size = batch.silhouette.shape[-1]
    sil_target = F.avg_pool2d(batch.silhouette, SILHOUETTE_STRIDE)
    heat_size = size // HEATMAP_STRIDE
    centres = (batch.joints + 0.5) / HEATMAP_STRIDE - 0.5
    heat_target = gaussian_targets(centres, batch.inside, heat_size, net.heatmap_sigma_px)
    inside = batch.inside
    n_inside = inside.sum().clamp(min=1)
    total = batch.silhouette.new_zeros(())
    terms: dict[str, float] = {}
    for k, out in enumerate(outputs):
        sil = F.binary_cross_entropy_with_logits(out.silhouette_logits, sil_target)
        if net.head == "soft_argmax":
            target = heat_target / heat_target.flatten(2).sum(-1).clamp(min=1e-6)[..., None, None]
            log_prob = torch.log_softmax(out.heatmap_logits.flatten(2), -1).view_as(out.heatmap_logits)
            heat = -((target * log_prob).flatten(2).sum(-1) * inside).sum() / n_inside
            dist_px = ((out.joints - batch.joints).norm(dim=-1) * inside).sum() / n_inside
            vis = F.binary_cross_entropy_with_logits(out.visibility_logits, batch.visible)
            loss = weights.silhouette * sil + weights.heatmap * heat + weights.joints_px * dist_px
            loss = loss + weights.visibility * vis
            stack_terms = {"sil": sil, "heat": heat, "joint_px": dist_px, "vis": vis}
        else:  # the thesis: sigmoid maps and binary cross-entropy everywhere
            heat = F.binary_cross_entropy_with_logits(out.heatmap_logits, heat_target)
            loss = weights.silhouette * sil + weights.heatmap * heat
            with torch.no_grad():
                dist_px = ((out.joints - batch.joints).norm(dim=-1) * inside).sum() / n_inside
            stack_terms = {"sil": sil, "heat": heat, "joint_px": dist_px}
        if out.side_logits is not None and batch.side is not None:
            side = F.binary_cross_entropy_with_logits(out.side_logits, batch.side)
            loss = loss + weights.side * side
            stack_terms["side"] = side
        total = total + loss
        if k == len(outputs) - 1:
            terms = {name: float(v.detach()) for name, v in stack_terms.items()}
    terms["loss"] = float(total.detach())
    return total, terms


class CuesTask:
    """Batches of the training folder (augmented) and the metrics of its validation slice."""

    def __init__(
        self, train: CuesArrays, val: CuesArrays, config: CuesTrainingConfig, augment: Augment | None = None
    ) -> None:
        self.train, self.val, self.config = train, val, config
        self.augment = augment if config.train.augment else None
        if self.augment is None and config.train.augment:
            self.augment = Augment()

    def loss(self, model: nn.Module, step: int, generator: torch.Generator, rank: int, world: int):
        bs = self.config.train.batch_size
        rows = torch.randint(len(self.train), (bs * world,), generator=generator)[rank * bs : (rank + 1) * bs]
        batch = make_batch(self.train, rows.numpy())
        if self.augment is not None:
            batch = augment_batch(batch, self.augment, generator)
        x = network_input(self.config.net.input, batch.rgb, batch.depth)
        return cues_loss(model(x), batch, self.config.net, self.config.loss)

    @torch.no_grad()
    def validate(self, model: nn.Module) -> dict[str, float]:
        return evaluate_arrays(model, self.val, self.config.net)


@torch.no_grad()
def evaluate_arrays(model: nn.Module, arrays: CuesArrays, net: CuesNetConfig, batch_size: int = 64) -> dict:
    """Silhouette error (% of pixels, at the network's side), mean joint error (px of a 224 image) and, for networks
    with a side head, the share of samples whose side is wrong (%)."""
    wrong, pixels, dist, count = 0.0, 0, 0.0, 0.0
    side_wrong, side_count = 0, 0
    for start in range(0, len(arrays), batch_size):
        rows = np.arange(start, min(start + batch_size, len(arrays)))
        batch = make_batch(arrays, rows)
        out = model(network_input(net.input, batch.rgb, batch.depth))[-1]
        sil = F.interpolate(out.silhouette_logits, size=batch.silhouette.shape[-2:], mode="bilinear") > 0
        wrong += float((sil != (batch.silhouette >= 0.5)).sum())
        pixels += sil.numel()
        d = (out.joints - batch.joints).norm(dim=-1) * batch.inside
        dist += float(d.sum()) * EVAL_SIZE / arrays.size
        count += float(batch.inside.sum())
        if out.side_logits is not None:
            side_wrong += int(((out.side_logits > 0).float() != batch.side).sum())
            side_count += len(rows)
    metrics = {"silhouette_wrong_pct": 100 * wrong / max(pixels, 1), "joint_px224": dist / max(count, 1)}
    if side_count:
        metrics["side_wrong_pct"] = 100 * side_wrong / side_count
    return metrics


def copy_matching(model: nn.Module, state: dict[str, torch.Tensor]) -> int:
    """Copy the tensors of ``state`` whose names and shapes match into ``model``; the first convolution is
    adapted when only its input channels differ (RGB-D -> RGB or depth). Returns the number copied."""
    own = model.state_dict()
    copied = 0
    for name, value in state.items():
        if name not in own:
            continue
        target = own[name]
        if value.shape == target.shape:
            own[name] = value.to(target.dtype)
            copied += 1
        elif (
            name == FIRST_CONV
            and value.shape[0] == target.shape[0]
            and value.shape[1] > target.shape[1]
            and value.shape[2:] == target.shape[2:]
        ):
            cin = target.shape[1]
            # RGB-D -> RGB keeps the first 3 input channels, -> depth the last one
            own[name] = (value[:, :cin] if cin == 3 else value[:, -cin:]).to(target.dtype)
            copied += 1
    model.load_state_dict(own)
    return copied


def train_cues(
    data: str | os.PathLike, out: str | os.PathLike, config: CuesTrainingConfig, progress: bool = True
) -> TrainResult:
    """Train (or resume training) the cues network on a synthetic folder; write checkpoints and ``weights.pt``."""
    net_cfg = config.net
    arrays = load_arrays(data, net_cfg.image_size, progress=progress)
    n_val = max(1, int(round(len(arrays) * config.train.val_fraction)))
    if len(arrays) - n_val < config.train.batch_size:
        raise ValueError(f"{data} has {len(arrays)} samples: too few for batches of {config.train.batch_size}")
    train = arrays.subset(np.arange(len(arrays) - n_val))
    val = arrays.subset(np.arange(len(arrays) - n_val, len(arrays)))
    torch.manual_seed(config.train.seed)
    out = Path(out)
    # the pretrained encoder starts from ImageNet; a resumed run then takes everything from its checkpoint
    model = build_network(net_cfg, pretrained=True)
    if config.train.init_from and not (out / "checkpoint.pt").is_file():
        from footmesh.cues.weights import load_state

        copied = copy_matching(model, load_state(config.train.init_from))
        log.info("initialised %d tensors from %s", copied, config.train.init_from)
    task = CuesTask(train, val, config)

    def export(model: nn.Module, metrics: dict[str, float]) -> None:
        save_weights(out / WEIGHTS, model, net_cfg, {"training": asdict(config), "validation": metrics})

    return run_training(model, task, out, config.train, config.to_dict(), progress, on_checkpoint=export)


def thesis_config(input: str) -> CuesTrainingConfig:
    """The thesis' network with our training settings (for a GPU; far too slow for the 2-core CPU)."""
    return replace(CuesTrainingConfig(), net=CuesNetConfig.thesis(input))
