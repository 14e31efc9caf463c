"""The 18-joint kinematic foot model (thesis 3.5.2, Figure 3.9, Table 3.1): names, tree and rotation limits.

One table for the whole package; every array of joints follows ``JOINT_NAMES`` and every array of angles
follows ``DOF_NAMES``.

Frame: the foot frame of docs/conventions.md (mm, x heel->toe, y to the left of a person facing +x, z up).
The model is a LEFT foot, so the big toe lies on -y.

Each non-root joint ``c`` ends a segment (bone) ``parent(c) -> c``. The segment's rotation pivots at the parent
joint and carries ``c`` and everything below it. Rotations are about the parent's (posed) axes:
positive Y turns the segment's +x towards -z (toes bend down, plantar flexion); positive Z turns +x towards +y
(towards the little toe on a left foot). A two-DOF segment (the proximal phalanges) rotates as
``R = R_y(angle_y) @ R_z(angle_z)``.
"""

from __future__ import annotations

from dataclasses import dataclass

JOINT_NAMES: tuple[str, ...] = (
    "midfoot",
    "toe1_proximal",
    "toe1_distal",
    "toe1_tip",
    "toe2_proximal",
    "toe2_distal",
    "toe2_tip",
    "toe3_proximal",
    "toe3_distal",
    "toe3_tip",
    "toe4_proximal",
    "toe4_distal",
    "toe4_tip",
    "toe5_proximal",
    "toe5_distal",
    "toe5_tip",
    "ankle",
    "heel",
)
"""DESIGN.md order: 0 midfoot; 1-3 toe 1 (big toe) proximal joint (MTP), distal joint (IP), tip; 4-15 toes 2-5;
16 ankle; 17 heel. "proximal" is the metatarsophalangeal joint where the proximal phalanx starts, "distal" the
interphalangeal joint where the distal phalanx starts."""

NUM_JOINTS = len(JOINT_NAMES)
JOINT_INDEX = {name: i for i, name in enumerate(JOINT_NAMES)}

PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11, 0, 13, 14, 0, 16)
"""Parent of each joint; the midfoot is the root of six branches."""

TOE_BRANCHES: tuple[tuple[int, int, int], ...] = tuple((1 + 3 * k, 2 + 3 * k, 3 + 3 * k) for k in range(5))
"""(proximal, distal, tip) joint indices of toes 1..5."""
TOE_TIPS: tuple[int, ...] = tuple(tip for _, _, tip in TOE_BRANCHES)
"""The tips of toes 1..5."""
HEEL_BRANCH: tuple[int, int] = (16, 17)
"""(ankle, heel) joint indices."""
BRANCHES: tuple[tuple[int, ...], ...] = (*TOE_BRANCHES, HEEL_BRANCH)
"""The six branches from the midfoot, each as its chain of joints (root excluded)."""
TIP_JOINTS: tuple[int, ...] = (3, 6, 9, 12, 15, 17)
"""End of each branch (toe tips and heel)."""


@dataclass(frozen=True)
class Dof:
    """One rotational degree of freedom: the segment ending at ``joint`` turns about ``axis``."""

    name: str
    joint: int
    axis: str  # "y" or "z", about the parent's posed axes
    lower: float  # radians
    upper: float  # radians


def _build_dofs() -> tuple[Dof, ...]:
    dofs = [
        Dof("midfoot_ankle_y", 16, "y", -0.35, 0.8),  # Table 3.1 "Midfoot-Ankle"
        Dof("ankle_y", 17, "y", -0.1, 0.1),  # Table 3.1 "Ankle"
    ]
    for k, (proximal, distal, tip) in enumerate(TOE_BRANCHES, start=1):
        dofs += [
            Dof(f"toe{k}_metatarsal_y", proximal, "y", 0.0, 0.1),  # "Midfoot-Metatarsals"
            Dof(f"toe{k}_proximal_y", distal, "y", -1.4, 1.4),  # "Proximal phalanxes" Y
            Dof(f"toe{k}_proximal_z", distal, "z", -0.13, 0.13),  # "Proximal phalanxes" Z
            Dof(f"toe{k}_distal_y", tip, "y", 0.0, 1.6),  # "Distal phalanxes"
        ]
    return tuple(dofs)


DOFS: tuple[Dof, ...] = _build_dofs()
NUM_DOFS = len(DOFS)  # 22
DOF_NAMES: tuple[str, ...] = tuple(d.name for d in DOFS)
DOF_LOWER: tuple[float, ...] = tuple(d.lower for d in DOFS)
DOF_UPPER: tuple[float, ...] = tuple(d.upper for d in DOFS)
