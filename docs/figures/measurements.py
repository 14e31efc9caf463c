"""Render docs/img/measure_overview.png: the eight measurements drawn on the model's mean foot.

Run from the repository root: ``python docs/figures/measurements.py``.
"""
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import trimesh
from matplotlib.collections import PolyCollection
from scipy.spatial import ConvexHull
from footmesh import measure as M

def load():
    from footmesh.model.assets import load_asset

    a = load_asset()
    v = a.mean_vertices.astype(float)
    lm = M.FootLandmarks.from_joints(a.joint_regressor.astype(float) @ v)
    return v, a.faces, lm, "mean foot of the packaged model"


v, f, lm, what = load()
m = M.measure_foot(v, f, lm)
val = m.values_mm()
mesh = trimesh.Trimesh(v, f, process=False)
L = val["stick_length"]; hx = M._heel_x(v)
ankle_z = lm.ankle[2]; leg = M.LEG_CUT_FACTOR * ankle_z
xh = hx + M.HEEL_WIDTH_FRACTION * L; xi = hx + M.INSTEP_FRACTION * L
X = np.array([1.0, 0, 0])
heel = M.plane_section(mesh, [xh, 0, 0], X, M.HEEL_WIDTH_MAX_HEIGHT * ankle_z)
inst = M.plane_section(mesh, [xi, 0, 0], X, leg)
toe = M.plane_section(mesh, lm.toe1_distal, X, leg)
arch = M.plane_section(mesh, lm.midfoot, X, leg)
n = np.cross((lm.mtp5 - lm.mtp1) * [1, 1, 0], [0, 0, 1.0])
ball = M.plane_section(mesh, lm.mtp1, n, leg)

def shade(ax, i, j, order):
    tri = v[f][:, :, [i, j]]
    depth = v[f][:, :, order].mean(1)
    idx = np.argsort(depth)
    ax.add_collection(PolyCollection(tri[idx], facecolor="0.85", edgecolor="0.7", linewidths=0.2))
    ax.set_aspect("equal"); ax.autoscale_view()

def segs(ax, s, i, j, **kw):
    for a, b in s:
        ax.plot([a[i], b[i]], [a[j], b[j]], **kw)

def dim(ax, p, q, text, c, off=(0, 0), **kw):
    ax.annotate("", xy=q, xytext=p, arrowprops=dict(arrowstyle="<->", color=c, lw=1.5))
    mid = (np.asarray(p) + q) / 2 + off
    ax.text(*mid, text, color=c, fontsize=8, ha="center", va="center",
            bbox=dict(fc="white", ec="none", alpha=0.8, pad=1), **kw)

fig, axes = plt.subplots(2, 2, figsize=(13, 9), gridspec_kw=dict(height_ratios=[1, 1]))
ax = axes[0, 0]; shade(ax, 0, 2, 1)  # side view from the medial side (-y), x right, z up
ax.set_title("side view (medial side, x heel->toe, z up)")
ax.axhline(0, color="k", lw=0.8)
dim(ax, (hx, -8), (hx + L, -8), f"stick length {val['stick_length']:.1f}", "C0", (0, -7))
segs(ax, heel, 0, 2, color="C2", lw=2)
ax.text(xh, M.HEEL_WIDTH_MAX_HEIGHT * ankle_z + 6, "heel width\nsection", color="C2", fontsize=8, ha="center")
dim(ax, (lm.toe1_distal[0], 0), (lm.toe1_distal[0], val["toe_height"]), f"toe h.\n{val['toe_height']:.1f}", "C3", (14, 8))
dim(ax, (lm.midfoot[0], 0), (lm.midfoot[0], val["arch_height"]), f"arch h. {val['arch_height']:.1f}", "C4", (0, -16))
dim(ax, (xi, 0), (xi, val["instep_height"]), f"instep h.\n{val['instep_height']:.1f}", "C5", (16, 12))
segs(ax, inst, 0, 2, color="C5", lw=1)
segs(ax, ball, 0, 2, color="C1", lw=1)
ax.axhline(leg, color="0.4", ls="--", lw=0.8); ax.text(hx + L, leg + 3, "leg cut", fontsize=7, ha="right", color="0.4")
for name, p in [("ankle", lm.ankle), ("midfoot", lm.midfoot), ("mtp1", lm.mtp1), ("IP1", lm.toe1_distal), ("mtp5", lm.mtp5)]:
    ax.plot(p[0], p[2], "k.", ms=5); ax.text(p[0] + 2, p[2] + 2, name, fontsize=7)
ax.set_ylim(-25, 150)

ax = axes[1, 0]; shade(ax, 0, 1, 2)  # top view, x right, y up (big toe at -y: bottom)
ax.set_title("top view (x heel->toe, y up; left foot: big toe at -y)")
b0, b1 = [hx + r * L for r in M.BALL_REGION]
ax.axvspan(b0, b1, color="C0", alpha=0.08)
band = v[(v[:, 0] >= b0) & (v[:, 0] <= b1)]
ylo, yhi = band[:, 1].min(), band[:, 1].max()
dim(ax, (hx + L + 12, ylo), (hx + L + 12, yhi), f"ball width\n{val['ball_width']:.1f}", "C0", (0, 0))
hy = heel[..., 1]
dim(ax, (xh, hy.min()), (xh, hy.max()), f"heel width\n{val['heel_width']:.1f}", "C2", (0, 0))
segs(ax, ball, 0, 1, color="C1", lw=2); segs(ax, inst, 0, 1, color="C5", lw=2)
for name, p in [("mtp1", lm.mtp1), ("mtp5", lm.mtp5), ("midfoot", lm.midfoot), ("IP1", lm.toe1_distal), ("ankle", lm.ankle)]:
    ax.set_xlim(-10, hx + L + 40)
    ax.plot(p[0], p[1], "k.", ms=5); ax.text(p[0] + 2, p[1] + 2, name, fontsize=7)
ax.axhline(lm.mtp1[1], color="C4", lw=0.6, ls=":")

for ax, s, nrm, title, c, key in [(axes[0, 1], ball, n, "ball girth section (plane through mtp1, mtp5)", "C1", "ball_girth"),
                                  (axes[1, 1], inst, X, f"instep section (x = {M.INSTEP_FRACTION:.0%} of length) and arch", "C5", "instep_girth")]:
    basis = M.plane_basis(nrm)
    p2 = s.reshape(-1, 3) @ basis.T
    for a, b in p2.reshape(-1, 2, 2):
        ax.plot([a[0], b[0]], [a[1], b[1]], color="0.3", lw=1)
    hull = ConvexHull(p2); h = p2[np.r_[hull.vertices, hull.vertices[0]]]
    ax.plot(h[:, 0], h[:, 1], color=c, lw=2, label=f"{key.replace('_', ' ')} (convex) {val[key]:.1f} mm")
    ax.axhline(0, color="k", lw=0.8); ax.set_aspect("equal"); ax.set_title(title)
    ax.set_xlabel("in-plane horizontal (mm)"); ax.set_ylabel("z (mm)")
axes[1, 1].set_title(f"instep section (x = {M.INSTEP_FRACTION:.0%} L) and arch section (x = midfoot)")
a2 = arch.reshape(-1, 3)[:, 1:]
for a, b in a2.reshape(-1, 2, 2):
    axes[1, 1].plot([a[0], b[0]], [a[1], b[1]], color="C4", lw=1, alpha=0.8)
axes[1, 1].plot([lm.mtp1[1]] * 2, [0, val["arch_height"]], color="C4", lw=2.5,
                label=f"arch height {val['arch_height']:.1f} mm (y = mtp1)")
axes[1, 1].plot([lm.mtp1[1]], [val["arch_height"]], "o", color="C4")
axes[1, 1].annotate("", xy=(0, val["instep_height"]), xytext=(0, 0), arrowprops=dict(arrowstyle="<->", color="C5"))
axes[1, 1].text(2, val["instep_height"] / 2, f"instep h. {val['instep_height']:.1f}", color="C5", fontsize=8)
for ax in axes[:, 1]:
    ax.legend(loc="upper right", fontsize=8)
axes[1, 1].set_xlabel("y (mm); medial (-y) at left")
fig.suptitle(f"The eight measurements on the {what}", fontsize=11)
fig.tight_layout()
fig.savefig("docs/img/measure_overview.png", dpi=110)
print({k: round(x, 1) for k, x in val.items()})
