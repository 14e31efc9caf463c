"""3D joints from a reconstructed mesh by the template's vertex groups (thesis 3.4), and the joint error metric.

The foot model's asset stores how its 18 joints are grafted onto the template: ``joint_regressor`` (18, V),
each row a convex combination of small vertex groups (``footmesh.model.rig``: tips and heel average the
vertices around a landmark; inner joints interpolate between groups on opposite sides of the foot). Because
the decoder keeps the template's vertex order, the same rows give the joints of any predicted mesh. The rows
sum to 1, so the result follows any rotation, translation, scale or mirror of the mesh exactly; on a rest-pose
(zero-angle) mesh it is the model's own joints. On a posed mesh it approximates the kinematic joints (skinning
does not carry the interior points rigidly); docs/recon.md gives the size of that difference.
"""

from __future__ import annotations

import torch

from footmesh.model.skeleton import JOINT_INDEX, NUM_JOINTS

MIDFOOT = JOINT_INDEX["midfoot"]


def joint_regressor() -> torch.Tensor:
    """The packaged model's (18, V) joint regressor (float32, rows summing to 1)."""
    from footmesh.model.layer import default_model

    return default_model().joint_regressor


def joints_from_vertices(vertices: torch.Tensor, regressor: torch.Tensor | None = None) -> torch.Tensor:
    """Joints (B, 18, 3) of meshes (B, V, 3) on the template topology, in the vertices' frame and unit (mm).

    Args:
        vertices: (B, V, 3) in the template's vertex order (any frame, left or right foot).
        regressor: (18, V); the packaged model's when None.
    """
    reg = regressor if regressor is not None else joint_regressor()
    if vertices.dim() != 3 or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must be (B, V, 3), got {tuple(vertices.shape)}")
    if reg.dim() != 2 or reg.shape != (NUM_JOINTS, vertices.shape[1]):
        raise ValueError(
            f"the joint regressor is {tuple(reg.shape)} but the vertices need ({NUM_JOINTS}, {vertices.shape[1]}):"
            " is this mesh on the template's topology?"
        )
    # the same contraction as FootModel.forward, so that a rest-pose mesh gives its joints bit for bit
    return torch.einsum("jv,bvc->bjc", reg.to(device=vertices.device, dtype=vertices.dtype), vertices)


def midfoot_aligned_error(pred_joints: torch.Tensor, true_joints: torch.Tensor) -> torch.Tensor:
    """Per-joint 3D error after moving the prediction so its midfoot meets the true one (thesis Table 4.5).

    Args:
        pred_joints, true_joints: (B, 18, 3) mm, same frame.
    Returns:
        (B, 18) Euclidean distances in mm; column 0 (the midfoot) is zero by construction, so the thesis' mean
        is ``error[:, 1:].mean()``.
    """
    if pred_joints.shape != true_joints.shape or pred_joints.dim() != 3 or pred_joints.shape[1:] != (NUM_JOINTS, 3):
        raise ValueError(
            f"joints must both be (B, {NUM_JOINTS}, 3), got {tuple(pred_joints.shape)} and {tuple(true_joints.shape)}"
        )
    aligned = pred_joints - pred_joints[:, MIDFOOT : MIDFOOT + 1] + true_joints[:, MIDFOOT : MIDFOOT + 1]
    return torch.linalg.vector_norm(aligned - true_joints, dim=-1)
