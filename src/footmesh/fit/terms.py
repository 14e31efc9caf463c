"""The fit's cost terms, one class each: its data association, its whitened residual, its robust kernel and what
it says of the fit's quality, registered in ``TERMS`` (the order the residuals are stacked in).

Adding a term = one class here and one line in ``TERMS`` (its weights in ``FitConfig``). At every iteration each
term's ``associate`` matches the model (``Frame``: every vertex, its normal and projection at the current state)
to its evidence and returns its block, or None when the photo gives it none (no depth, no floor): it is then
left out of that iteration's cost. A term that needs vertices beyond the fit's spread subset names them in its
block's ``extra`` and places them in ``place`` once every term's are known.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from footmesh.fit.core import FitConfig, _SideProblem

Block = dict[str, Any]
"""What a term's association fixed for one iteration (indices, matched points, ``scale``, later ``sqrt_weight``)."""
Blocks = dict[str, Block]


@dataclass(frozen=True, eq=False)
class Frame:
    """The model at the state being associated, camera frame: every vertex (V, 3) mm, its normal (V, 3) and its
    projection (V, 2) px; the fit's spread ``subset`` (N,) of them, which of those the leg hides (N,) bool and
    which face the camera (subset positions); the ``rim``, vertices seen edge-on (their projections lie on the
    outline)."""

    vertices: np.ndarray
    normals: np.ndarray
    projected: np.ndarray
    subset: np.ndarray
    hidden: np.ndarray
    facing: np.ndarray
    rim: np.ndarray
    sample: Callable[[np.ndarray, np.ndarray], np.ndarray]
    """``sample(image, uv)``: an image read bilinearly at (M, 2) px."""
    shows_leg: Callable[[np.ndarray], np.ndarray]
    """``shows_leg(uv)``: (M,) bool, the sight line through each pixel (M, 2) meets the model's leg."""

    @property
    def num(self) -> int:
        return len(self.subset)

    @property
    def v(self) -> np.ndarray:
        """(N, 3) the subset's vertices."""
        return self.vertices[self.subset]

    @property
    def n(self) -> np.ndarray:
        return self.normals[self.subset]

    @property
    def uv(self) -> np.ndarray:
        return self.projected[self.subset]


class Term:
    """A cost term: ``residual`` (B, m) whitened, summed as ``scale * rho_kernel(r)`` over its m entries."""

    name: ClassVar[str]

    def associate(self, problem: _SideProblem, frame: Frame) -> Block | None:
        """This iteration's block (at least its ``scale``: the term's weight), or None without evidence for it."""
        return {"scale": 1.0}

    def place(self, block: Block, position: Callable[[np.ndarray], np.ndarray]) -> None:
        """Set the block's indices of its ``extra`` vertices: ``position(vertex ids)`` -> their places among the
        vertices evaluated (the subset, then every term's extra ones)."""

    def kernel(self, config: FitConfig) -> tuple[str, float]:
        """(kind, scale) of the robust kernel: ``l2``, ``huber``, ``gm`` (Geman-McClure) or ``gm_above``."""
        return "l2", 0.0

    def residual(self, problem: _SideProblem, out: dict[str, torch.Tensor], blocks: Blocks) -> torch.Tensor | None:
        """(B, m) residuals of the model ``out`` (``_SideProblem.evaluate``), or None when the term has no block."""
        raise NotImplementedError

    def quality(self, problem: _SideProblem, residual: np.ndarray) -> dict[str, float]:
        """Figures of ``FitQuality`` this term gives, from its unweighted residual (m,) at the optimum."""
        return {}


class Joints(Term):
    """Projected model joint - 2D joint, px, weighted by the joint's confidence (Huber)."""

    name = "joints"

    def associate(self, problem, frame):
        return {"scale": np.repeat(problem.ev.joint_weight, 2)}

    def kernel(self, config):
        return "huber", config.joint_huber

    def residual(self, problem, out, blocks):
        j = out["joints"]
        detected = torch.from_numpy(problem.ev.joints)
        return ((problem.project(j) - detected) / problem.config.joint_sigma_px).reshape(len(j), -1)

    def quality(self, problem, residual):
        errors = np.linalg.norm(residual.reshape(-1, 2), axis=1) * problem.config.joint_sigma_px
        weight = np.maximum(problem.ev.joint_weight, 1e-9)
        return {"joint_error_px": float(np.sum(weight * errors) / np.sum(weight))}


class Inside(Term):
    """Distance transform of the silhouette's outside at each projected vertex, px: vertices must fall inside the
    silhouette (those hidden by the leg skipped) (Geman-McClure)."""

    name = "inside"

    def associate(self, problem, frame):
        ev, t = problem.ev, torch.from_numpy
        value = frame.sample(ev.outside_dt, frame.uv)
        idx = np.flatnonzero(~frame.hidden & (value > 0))
        return {
            "index": t(idx),
            "value": t(value[idx]),
            "uv": t(frame.uv[idx]),
            "grad": t(frame.sample(ev.outside_grad, frame.uv[idx]).T.copy()),
            "scale": problem.config.inside_count / frame.num,
        }

    def kernel(self, config):
        return "gm", config.silhouette_robust

    def residual(self, problem, out, blocks):
        b = blocks["inside"]
        if not len(b["index"]):
            return None
        u = problem.project(out["vertices"][:, b["index"]])
        # the distance transform to first order about the association's projection
        return (b["value"] + ((u - b["uv"]) * b["grad"]).sum(-1)) / problem.config.silhouette_sigma_px

    def quality(self, problem, residual):
        outside = residual * problem.config.silhouette_sigma_px
        return {"vertices_outside_2px": float(np.sum(outside > 2.0) / len(problem.arrays.subset))}


class Contour(Term):
    """Silhouette contour samples to their nearest projected vertex (of the subset or the mesh's rim), along the
    contour normal, px (Geman-McClure)."""

    name = "contour"

    def associate(self, problem, frame):
        ev, cfg, t, num = problem.ev, problem.config, torch.from_numpy, frame.num
        # the nearest projected vertex of each contour sample, among the subset and the whole mesh's rim (the
        # subset alone sits a little inside the outline and biased the fit outwards by about 0.3 px)
        _, nearest = cKDTree(np.concatenate([frame.uv, frame.projected[frame.rim]])).query(ev.contour)
        on_rim = nearest >= num
        rest_height = problem.arrays.mean[:, 2].numpy()[np.concatenate([frame.subset, frame.rim])[nearest]]
        keep = rest_height < cfg.contour_max_height_mm
        counted = len(ev.contour)
        if cfg.contour_leg_probe_px is not None:
            behind_leg = frame.shows_leg(ev.contour + cfg.contour_leg_probe_px * ev.contour_normal)
            if behind_leg.mean() <= cfg.contour_leg_max_fraction:
                keep &= ~behind_leg
                # their weight goes to the rest: a pose whose leg hides more of the outline must not cost less for
                # it (the side whose fit hid more won the comparison of the two sides' costs)
                counted -= int(behind_leg.sum())
        nearest, on_rim = nearest[keep], on_rim[keep]
        return {
            "nearest": nearest,
            "on_rim": on_rim,
            "extra": frame.rim[nearest[on_rim] - num],
            "points": t(ev.contour[keep]),
            "normal": t(ev.contour_normal[keep]),
            "scale": cfg.contour_count / max(counted, 1),
        }

    def place(self, block, position):
        index = block["nearest"].copy()
        index[block["on_rim"]] = position(block["extra"])
        block["index"] = torch.from_numpy(index)

    def kernel(self, config):
        return "gm", config.silhouette_robust

    def residual(self, problem, out, blocks):
        b = blocks["contour"]
        u = problem.project(out["vertices"][:, b["index"]])
        return ((b["points"] - u) * b["normal"]).sum(-1) / problem.config.silhouette_sigma_px

    def quality(self, problem, residual):
        off = np.abs(residual) * problem.config.silhouette_sigma_px
        # no outline point associated at all (a fit far off the silhouette): none of it follows the outline
        return {"contour_within_2px": float(np.mean(off <= 2.0)) if off.size else 0.0}


class Depth(Term):
    """Back-projected depth pixels to their nearest camera-facing vertex, point to plane, mm (Geman-McClure)."""

    name = "depth"

    def associate(self, problem, frame):
        ev, t = problem.ev, torch.from_numpy
        if ev.depth_points is None:
            return None
        # the nearest vertex facing the camera, point to plane
        _, k = cKDTree(frame.v[frame.facing]).query(ev.depth_points)
        nearest = frame.facing[k]
        normal = frame.n[nearest] / np.linalg.norm(frame.n[nearest], axis=1, keepdims=True)
        return {
            "index": t(nearest),
            "points": t(ev.depth_points),
            "normal": t(normal),
            "scale": problem.config.depth_count / len(ev.depth_points),
        }

    def kernel(self, config):
        return "gm", config.depth_robust

    def residual(self, problem, out, blocks):
        if "depth" not in blocks:
            return None
        b = blocks["depth"]
        return ((b["points"] - out["vertices"][:, b["index"]]) * b["normal"]).sum(-1) / problem.config.depth_sigma_mm

    def quality(self, problem, residual):
        if not residual.size:
            return {}
        return {"depth_median_mm": float(np.median(np.abs(residual))) * problem.config.depth_sigma_mm}


class FreeSpace(Term):
    """Camera-facing vertices must not lie in front of the nearest measured depth around their pixel, mm (Huber)."""

    name = "free_space"
    HUBER = 3.0
    """Huber threshold, in sigmas: a grossly misplaced start must not be dominated by this term."""

    def associate(self, problem, frame):
        ev, cfg, t = problem.ev, problem.config, torch.from_numpy
        if ev.depth_points is None:
            return None
        # read bilinearly (missing depth = 0 = no constraint) so that the cost does not jump from pixel to pixel
        measured = frame.sample(ev.near_depth, frame.uv)
        limit = measured - cfg.free_space_tolerance_mm
        valid = measured > 0
        front = np.zeros(frame.num, dtype=bool)
        front[frame.facing] = True
        idx = np.flatnonzero(valid & front & (frame.v[:, 2] < limit))
        return {"index": t(idx), "limit": t(limit[idx]), "scale": cfg.free_space_count / max(int(valid.sum()), 1)}

    def kernel(self, config):
        return "huber", self.HUBER

    def residual(self, problem, out, blocks):
        if "free_space" not in blocks or not len(blocks["free_space"]["index"]):
            return None
        b = blocks["free_space"]
        return (b["limit"] - out["vertices"][:, b["index"], 2]) / problem.config.depth_sigma_mm


class FloorContact(Term):
    """The lowest vertex touches the floor plane, mm (Geman-McClure above the floor: a foot clearly lifted is let
    go; least squares below it: nothing goes through the floor)."""

    name = "floor_contact"

    def associate(self, problem, frame):
        floor = problem.ev.floor
        if floor is None:
            return None
        lowest = int(np.argmin(frame.vertices @ floor[:3] + floor[3]))
        return {"extra": np.array([lowest]), "scale": 1.0}

    def place(self, block, position):
        block["index"] = torch.from_numpy(position(block["extra"]))

    def kernel(self, config):
        return "gm_above", config.floor_robust

    def residual(self, problem, out, blocks):
        if self.name not in blocks:
            return None
        plane = torch.from_numpy(problem.ev.floor)
        return (out["vertices"][:, blocks[self.name]["index"]] @ plane[:3] + plane[3]) / problem.config.floor_sigma_mm


class SoleContact(FloorContact):
    """A foot bearing weight (``FitConfig.sole_contact``): the lowest vertex of its heel and that of its ball each
    touch the floor plane, mm (least squares: a standing foot is neither on tiptoe nor rocked onto its heel)."""

    name = "sole_contact"

    def associate(self, problem, frame):
        floor = problem.ev.floor
        if floor is None or not problem.config.sole_contact:
            return None
        height = frame.vertices @ floor[:3] + floor[3]
        lowest = [region[np.argmin(height[region])] for region in problem.arrays.sole]
        return {"extra": np.array(lowest), "scale": 1.0}

    def kernel(self, config):
        return "l2", 0.0


class Upright(Term):
    """The foot's z axis along the floor normal (a standing foot), radians (Geman-McClure)."""

    name = "upright"

    def associate(self, problem, frame):
        return None if problem.ev.floor is None else {"scale": 1.0}

    def kernel(self, config):
        return "gm", config.upright_robust

    def residual(self, problem, out, blocks):
        if problem.ev.floor is None:
            return None
        up = torch.from_numpy(problem.ev.floor)[:3] @ out["rotation"]  # the floor normal in the foot frame (B, 3)
        return up[:, :2] / problem.config.upright_sigma_rad


class CameraAbove(Term):
    """No floor and no depth: the camera is above the foot's sole plane (removes the mirror-in-depth twin)."""

    name = "camera_above"

    def associate(self, problem, frame):
        ev = problem.ev
        return {"scale": 1.0} if ev.floor is None and ev.depth_points is None else None

    def residual(self, problem, out, blocks):
        if "camera_above" not in blocks:
            return None
        # camera centre in the foot frame: -R^T t; it must not be below the sole plane z = 0
        height = -(out["rotation"][:, :, 2] * out["translation"]).sum(-1)
        return (height.clamp_max(0.0) / problem.config.camera_above_sigma_mm)[:, None]


class Distance(Term):
    """No scale evidence: the midfoot stays at the distance of the mean-size foot (``scaled=False``)."""

    name = "distance"

    def residual(self, problem, out, blocks):
        if problem.distance0 is None:
            return None
        return ((out["joints"][:, 0].norm(dim=-1) - problem.distance0) / problem.config.distance_sigma_mm)[:, None]


class ShapePrior(Term):
    """Shape coefficients ~ N(0, 1) (SD units)."""

    name = "shape_prior"

    def residual(self, problem, out, blocks):
        return out["shape"] * math.sqrt(problem.config.shape_prior_weight)


class AnglePrior(Term):
    """Angles ~ N(mean, (f SD)^2) per DOF: everyday poses' spread widened by ``angle_prior_sd_factor``."""

    name = "angle_prior"

    def residual(self, problem, out, blocks):
        return (out["angles"] - problem.angle_mean) / problem.angle_sd


TERMS: tuple[Term, ...] = (
    Joints(),
    Inside(),
    Contour(),
    Depth(),
    FreeSpace(),
    FloorContact(),
    SoleContact(),
    Upright(),
    CameraAbove(),
    Distance(),
    ShapePrior(),
    AnglePrior(),
)
"""Every term, in the order their residuals are stacked."""
BY_NAME: dict[str, Term] = {term.name: term for term in TERMS}


def associate(problem: _SideProblem, frame: Frame) -> tuple[Blocks, np.ndarray]:
    """Every term's block at ``frame``, and the vertices (subset, then the terms' extra ones sorted) to evaluate."""
    blocks = {}
    for term in TERMS:
        block = term.associate(problem, frame)
        if block is not None:
            blocks[term.name] = block
    extra = np.unique(np.concatenate([np.zeros(0, np.int64)] + [b["extra"] for b in blocks.values() if "extra" in b]))

    def position(vertex_ids: np.ndarray) -> np.ndarray:
        return frame.num + np.searchsorted(extra, vertex_ids)

    for name, block in blocks.items():
        BY_NAME[name].place(block, position)
    return blocks, np.concatenate([frame.subset, extra])


def residuals(problem: _SideProblem, out: dict[str, torch.Tensor], blocks: Blocks) -> dict[str, torch.Tensor]:
    """Whitened residuals (B, m) of every term that has evidence this iteration, by name, in ``TERMS`` order."""
    res = {}
    for term in TERMS:
        r = term.residual(problem, out, blocks)
        if r is not None:
            res[term.name] = r
    return res


def kernel(name: str, config: FitConfig) -> tuple[str, float]:
    """The robust kernel of the term ``name`` (KeyError for a name no term has: never a silent least squares)."""
    return BY_NAME[name].kernel(config)
