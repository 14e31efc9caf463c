"""``footmesh demo``: measure the bundled example photos and compare with their known truth.

``run_photo_demo`` runs ``footmesh measure`` on each bundled photo (an A4 sheet beside a left foot, a right foot
with a depth map, a right foot with a bank card) and prints measured against true.

``run_demo`` (``footmesh demo --model``) exercises the foot model alone: it samples a foot from the shape model,
poses it inside the joint limits and places it anywhere, then recovers the canonical pose from the posed mesh
alone (IK -> zero pose by inverse skinning), measures it, gives shoe sizes, and writes ``posed.obj``,
``canonical.obj``, ``result.json`` and ``foot.png``, with the measured values beside the known answer.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from footmesh import __version__, report
from footmesh.measure import MEASUREMENT_NAMES, FootLandmarks, Measurements, measure_foot
from footmesh.model import skeleton as sk
from footmesh.model.canonical import canonicalise
from footmesh.model.ik import sample_poses
from footmesh.model.layer import FootModel
from footmesh.sizes import shoe_sizes


@dataclass(frozen=True)
class DemoConfig:
    """What the demo samples."""

    seed: int = 0
    side: str = "left"
    shape_sd: float = 1.0  # spread of the sampled shape coefficients, in component SDs


def run_photo_demo(out_dir: str | Path) -> list[dict]:
    """Measure every bundled example photo into ``out_dir/<name>`` and print measured vs true."""
    from footmesh.examples import examples
    from footmesh.pipeline import measure_photo

    out = Path(out_dir)
    rows = [
        f"{'photo':<12} {'input':<5} {'scale':<6} {'side':<10} {'length mm':>16} {'true':>6} {'ball width mm':>16}"
        f" {'true':>6} {'s':>5}  sizes"
    ]
    results = []
    for ex in examples():
        result = measure_photo(ex.image, out / ex.name, depth=ex.depth, intrinsics=ex.intrinsics)
        results.append(result)
        m = result["measurements"]

        def cell(name: str, m: dict = m) -> str:
            v, u = m[name]["value_mm"], m[name]["uncertainty_mm"]
            return "unscaled" if v is None else f"{v:.1f} +- {u:.1f}"

        side = result["side"] + ("" if result["side"] == ex.side else f" (is {ex.side})")
        sizes = ", ".join(s["label"] for k in ("eu", "uk", "us_men") if isinstance(s := result["sizes"].get(k), dict))
        rows.append(
            f"{ex.name:<12} {result['input']:<5} {result['scale_source']:<6} {side:<10} "
            f"{cell('stick_length'):>16} {ex.truth_mm['stick_length']:>6.1f} {cell('ball_width'):>16} "
            f"{ex.truth_mm['ball_width']:>6.1f} {result['seconds']:>5.1f}  {sizes}"
        )
    print("\n".join(rows))
    print(f"\nwrote {out}/<photo>/result.json, mesh.obj, mesh.glb, canonical.obj, overlay.png")
    return results


def run_demo(out_dir: str | Path, config: DemoConfig = DemoConfig()) -> dict:
    """Run the demo and write its files into ``out_dir``; returns the result dictionary."""
    out = Path(out_dir)
    rng = np.random.default_rng(config.seed)
    model = FootModel().double()
    k = model.num_components

    shape = torch.from_numpy(rng.normal(0.0, config.shape_sd, (1, k)))
    truth = model(shape)
    angles = sample_poses(truth.rest_joints[0], rng, 1, method="natural")
    rotation = torch.from_numpy(_random_rotation(rng))[None]
    translation = torch.from_numpy(rng.uniform(-300.0, 300.0, (1, 3)))
    posed = model(shape, angles, side=config.side, rotation=rotation, translation=translation)

    start = time.perf_counter()
    canonical = canonicalise(posed.vertices, model, side=config.side)
    rest_vertices = canonical.rest_vertices[0].detach().numpy()
    rest_joints = canonical.rest_joints[0].detach().numpy()
    faces = model.faces("left").numpy()
    measured = measure_foot(rest_vertices, faces, FootLandmarks.from_joints(rest_joints))
    elapsed = time.perf_counter() - start

    true_rest = truth.rest_vertices[0].numpy()
    expected = measure_foot(true_rest, faces, FootLandmarks.from_joints(truth.rest_joints[0].numpy()))
    sizes = shoe_sizes(measured.stick_length.value_mm, measured.ball_width.value_mm)

    posed_faces = model.faces(config.side).numpy()
    report.write_mesh(out / "posed.obj", posed.vertices[0].numpy(), posed_faces)
    report.write_mesh(out / "canonical.obj", rest_vertices, faces)
    _write_picture(out / "foot.png", posed, canonical, model, config.side, rest_vertices, rest_joints)
    result = {
        "version": __version__,
        "kind": "demo: random foot from the shape model, posed, canonicalised and measured",
        "seed": config.seed,
        "side": config.side,
        "scale_source": "model",
        "measurements": measured.to_dict(),
        "expected_measurements_mm": expected.values_mm(),
        "ratios": measured.ratios(),
        "sizes": sizes.to_dict(),
        "angles": dict(zip(sk.DOF_NAMES, angles[0].tolist(), strict=True)),
        "recovered_angles": dict(zip(sk.DOF_NAMES, canonical.angles[0].tolist(), strict=True)),
        "joints3d_mm": posed.joints[0].tolist(),
        "canonical_joints_mm": rest_joints.tolist(),
        "canonicalise_and_measure_seconds": round(elapsed, 3),
        "files": {"posed_mesh": "posed.obj", "canonical_mesh": "canonical.obj", "picture": "foot.png"},
    }
    report.write_json(out / "result.json", result)
    print(format_table(measured, expected, sizes.labels()))
    print(f"\nwrote {out}/result.json, posed.obj, canonical.obj, foot.png ({elapsed:.2f} s to canonicalise+measure)")
    return result


def format_table(measured: Measurements, expected: Measurements, size_labels: list[str]) -> str:
    """A plain-text table: measurement, measured value, the known answer, the difference."""
    rows = [f"{'measurement':<14} {'measured mm':>12} {'true mm':>9} {'error mm':>9}"]
    got, want = measured.values_mm(), expected.values_mm()
    for name in MEASUREMENT_NAMES:
        rows.append(f"{name:<14} {got[name]:>12.1f} {want[name]:>9.1f} {got[name] - want[name]:>+9.2f}")
    rows.append("sizes: " + ", ".join(size_labels))
    return "\n".join(rows)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _write_picture(path: Path, posed, canonical, model: FootModel, side: str, rest_v, rest_j) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from footmesh import viz

    # Show the posed foot in its own frame (rotation and translation undone) so both panels compare.
    r = canonical.rotation[0].detach().numpy()
    t = canonical.translation[0].detach().numpy()
    local_v = (posed.vertices[0].numpy() - t) @ r
    local_j = (posed.joints[0].numpy() - t) @ r
    posed_faces = model.faces(side).numpy()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    view = viz.oblique_view(-60 if side == "left" else 60, 25)
    rot = viz.draw_mesh(axes[0], local_v, posed_faces, view)
    viz.draw_skeleton(axes[0], local_j, rot)
    axes[0].set_title(f"posed {side} foot (input)")
    rot = viz.draw_mesh(axes[1], rest_v, model.faces("left").numpy(), "medial", alpha=0.55)
    viz.draw_skeleton(axes[1], rest_j, rot)
    axes[1].set_title("canonical pose (medial view)")
    rot = viz.draw_mesh(axes[2], rest_v, model.faces("left").numpy(), "top", alpha=0.55)
    viz.draw_skeleton(axes[2], rest_j, rot)
    axes[2].set_title("canonical pose (top view)")
    fig.tight_layout()
    with report.atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
