"""Render docs/img/rig_joints.png, rig_weights.png and poses.png from the packaged foot model.

Run from the repository root: ``python docs/figures/rig.py``.
"""

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import torch

from footmesh import viz
from footmesh.model import skeleton as sk
from footmesh.model.ik import sample_poses
from footmesh.model.layer import FootModel

model = FootModel().double()
asset = model.asset
v, f = asset.mean_vertices.astype(float), asset.faces
joints = asset.joint_regressor.astype(float) @ v

# Joints and the vertex groups they average.
fig, axes = plt.subplots(1, 3, figsize=(18, 5.2))
group_colour = np.tile([0.86, 0.80, 0.74], (len(v), 1))
palette = plt.cm.tab20(np.arange(sk.NUM_JOINTS) % 20)[:, :3]
for j in range(sk.NUM_JOINTS):
    group_colour[asset.joint_regressor[j] > 0] = palette[j]
for ax, view, title in zip(
    axes, ["top", "medial", viz.oblique_view(-130, 25)], ["top", "medial side", "lateral, from behind"], strict=True
):
    rot = viz.draw_mesh(ax, v, f, view, vertex_colours=group_colour, alpha=0.45)
    viz.draw_skeleton(ax, joints, rot, labels=True)
    ax.set_title(f"18 joints and their vertex groups ({title})")
fig.tight_layout()
fig.savefig("docs/img/rig_joints.png", dpi=100)

# Skinning weights: each segment's colour blended by weight.
fig, axes = plt.subplots(1, 3, figsize=(18, 5.2))
for ax, view in zip(axes, ["top", "medial", viz.oblique_view(-120, -35)], strict=True):
    viz.draw_mesh(ax, v, f, view, vertex_colours=asset.skin_weights.astype(float) @ palette)
axes[0].set_title("bone-heat skinning weights (colour = segment ending at each joint)")
fig.tight_layout()
fig.savefig("docs/img/rig_weights.png", dpi=100)

# Random shapes in natural poses.
rng = np.random.default_rng(3)
n = 6
shape = torch.from_numpy(rng.normal(size=(n, model.num_components)))
rest = model(shape)
angles = sample_poses(rest.rest_joints, rng, n, method="natural")
posed = model(shape, angles)
fig, axes = plt.subplots(2, 3, figsize=(16, 8))
for k, ax in enumerate(axes.ravel()):
    rot = viz.draw_mesh(ax, posed.vertices[k].numpy(), f, viz.oblique_view(-65, 25))
    viz.draw_skeleton(ax, posed.joints[k].numpy(), rot, size=8)
fig.suptitle("random shapes from the PCA model in natural poses (sample_poses(method='natural'))")
fig.tight_layout()
fig.savefig("docs/img/poses.png", dpi=90)
print("wrote docs/img/rig_joints.png, rig_weights.png, poses.png")
