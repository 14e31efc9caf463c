"""Render one synthetic sample (RGB, depth, silhouette, labels) from its ``Scene``.

Image formation (per sample; the per-sample and per-pixel loops are compiled with numba in ``kernels``):

1. The foot model gives the posed foot (float64, one sample at a time so that batching never changes a bit);
   the scene places it on the floor and grows a lower leg from its ankle cap.
2. Supersampling: the mesh and the floor are evaluated on a ``(2S+1) x (2S+1)`` grid of samples at half-pixel
   spacing whose odd samples are exactly the pixel centres. Depth, face ids, silhouette and labels come from the
   pixel-centre samples (exact, not filtered); colour is filtered with the tent ``[1, 2, 1] / 4`` in each
   direction (anti-aliasing with no shift of the image against its labels; ``kernels.compose``).
3. Shading: Lambert (ambient + one directional light) on per-vertex normals (Gouraud); the floor gets the
   foot's and leg's cast shadow (their projection along the light onto the floor, blurred into a penumbra) and a
   soft contact shadow under the foot. The foot does not shadow itself (only ``n . l``).
4. The floor (and a reference object lying on it) is exact ray-plane intersection, textured procedurally; it is
   drawn only when the camera is above it. Rays missing the floor within ``FAR_MM`` see a plain wall (depth 0).
   ``kernels.floor_shade`` does all of it per pixel centre, skipping the texture where the mesh hides the pixel
   and its neighbours (``kernels.floor_needed``); the shadow maps are rasterised and blurred first.
5. Sensor noise: RGB gets Gaussian noise of ``SynthConfig.rgb_noise_sd`` (0..1 units); depth gets ``depth_noise``.
   The draws are compiled (``kernels.gaussians``, ``kernels.uniforms``: SplitMix64 and a ziggurat, since format
   4), seeded from the sample's ``noise_seed``.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
import torch
from scipy import sparse

from footmesh import references
from footmesh.geometry.camera import project
from footmesh.geometry.mesh import vertex_normals
from footmesh.model import anatomy
from footmesh.model import skeleton as sk
from footmesh.model.layer import FootModel
from footmesh.model.skin import SkinColours, load_skin_colours
from footmesh.synth import kernels, raster, textures
from footmesh.synth.scene import (
    OTHER_FOOT_STREAM,
    Scene,
    SynthConfig,
    camera_pose,
    intrinsics,
    sample_angles,
    sample_scene,
    sample_skin,
)
from footmesh.threads import RENDER_THREADS, torch_threads

FAR_MM = 4000.0
"""Floor points farther than this from the camera (and rays that miss the floor) show the background wall."""
DEPTH_RANGE_MM = (100.0, 3000.0)
"""The simulated depth sensor's range; outside it the noisy depth is 0 (missing)."""
DEPTH_NOISE_A_MM = 0.25
DEPTH_NOISE_B_PER_MM = 1.5e-6
"""Depth noise: ``sigma(z) = A + B z^2`` mm (structured light / stereo: error grows with distance squared)."""
DEPTH_EDGE_JUMP = (10.0, 0.03)
"""A pixel is on a depth edge when a 4-neighbour differs by more than max(10 mm, 3 % of its depth)."""
DEPTH_EDGE_DROPOUT = 0.6
DEPTH_RANDOM_DROPOUT = 0.002
JOINT_VISIBILITY_MARGIN_MM = 10.0
"""A joint is visible when, within one pixel of its projection, the front surface is the foot and no more than
(the joint's distance to the nearest vertex + this margin) in front of it. Inner joints lie under the skin."""
REFERENCE_VISIBILITY_TOLERANCE_MM = 3.0
LEG_SEGMENTS = 40
WEIGHT_BEARING_STEPS = 48
"""Grid of the toes' flexion and of the hindfoot angle searched for a weight-bearing foot
(``SynthConfig.weight_bearing``): 0.024 rad apart, a heel level with the ball within about 2 mm."""
WEIGHT_BEARING_TOLERANCE_MM = 1.0
"""A weight-bearing foot's toes may reach this far below its ball (before the hindfoot's angle is set, which moves
the ball region's back edge by up to about as much again)."""
LEG_RING_MM = 15.0
LEG_SKIN_DRIFT = 0.02
"""How far a bare leg's skin drifts from one ring to the next (``SynthConfig.skin_legs``): SD of the log brightness
(and a third of it per colour channel); over a 400 mm shin about +-12 % brightness."""
LEG_SKIN_STREAM, OTHER_LEG_SKIN_STREAM = 5, 6
"""Random streams of the legs' skin (``default_rng([seed, index, stream])``; 1-3 are the scene's other draws)."""
LEG_UPRIGHT = 1.5
"""The leg's axis is the ankle cap's normal plus this much of the vertical, normalised."""
CAP_MIN_HEIGHT_MM = 100.0
CAP_NORMAL_Z = 0.8
"""The model's ankle cap: template vertices above this height whose normal points up this much."""

CAST_TEXEL_MM = 4.0
CONTACT_TEXEL_MM = 5.0
"""Texel sizes of the cast shadow map (blurred with SD 4 mm: 1 texel) and the contact shadow map (SD 10 mm: 2
texels), read bilinearly; 3 mm each before format 4 (2.8 and 1.8 times as many texels, the same look)."""

LABEL_BACKGROUND, LABEL_FOOT, LABEL_LEG, LABEL_REFERENCE = 0, 1, 2, 3


@dataclass(frozen=True)
class Mesh:
    """A triangle mesh in the scene frame (mm) with per-vertex albedo."""

    vertices: np.ndarray  # (V, 3)
    faces: np.ndarray  # (F, 3)
    albedo: np.ndarray  # (V, 3)


@dataclass(frozen=True)
class Geometry:
    """The posed scene's meshes in the scene frame (mm) with per-vertex albedo; ``other_foot`` and ``other_leg``
    are the second foot in view (or None), drawn and labelled like the first but without joints."""

    foot_vertices: np.ndarray  # (V, 3)
    foot_joints: np.ndarray  # (18, 3)
    foot_faces: np.ndarray  # (F, 3)
    foot_albedo: np.ndarray  # (V, 3)
    leg_vertices: np.ndarray  # (L, 3)
    leg_faces: np.ndarray  # (G, 3)
    leg_albedo: np.ndarray  # (L, 3)
    scene_from_foot: np.ndarray  # (4, 4)
    other_foot: Mesh | None = None
    other_leg: Mesh | None = None

    def feet(self) -> list[Mesh]:
        """The feet in view, the sample's first."""
        first = Mesh(self.foot_vertices, self.foot_faces, self.foot_albedo)
        return [first] + ([self.other_foot] if self.other_foot is not None else [])

    def legs(self) -> list[Mesh]:
        """The legs in view, the sample's first."""
        first = Mesh(self.leg_vertices, self.leg_faces, self.leg_albedo)
        return [first] + ([self.other_leg] if self.other_leg is not None else [])


class Renderer:
    """Renders samples of a ``SynthConfig``; holds the foot model and the skin colour model (read-only)."""

    def __init__(self, config: SynthConfig, model: FootModel | None = None, skin: SkinColours | None = None) -> None:
        self.config = config
        self.model = (model if model is not None else FootModel()).double().eval()
        self.skin = skin if skin is not None else load_skin_colours()
        faces = self.model.faces_left.numpy()
        self._faces = {"left": faces, "right": faces[:, [0, 2, 1]]}
        mean = self.model.mean_vertices.numpy().astype(np.float64)
        nv = len(mean)
        rows = np.repeat(np.arange(len(faces)), 3)
        # (V, F) vertex-face incidence: vertex normals = incidence @ face normals (area weighted)
        self._incidence = sparse.csr_matrix((np.ones(rows.size), (faces.reshape(-1), rows)), shape=(nv, len(faces)))
        normals = vertex_normals(mean, faces)
        self.cap = np.flatnonzero((mean[:, 2] > CAP_MIN_HEIGHT_MM) & (normals[:, 2] > CAP_NORMAL_Z))
        if len(self.cap) < 8:
            raise ValueError(f"foot model: found only {len(self.cap)} ankle-cap vertices to grow the leg from")
        self._heel, self._ball = anatomy.heel_region(mean), anatomy.ball_region(mean)
        self._toes = np.flatnonzero(mean[:, 0] > mean[self._ball, 0].max())

    def __repr__(self) -> str:
        return f"Renderer(size={self.config.size}, views={self.config.views}, reference={self.config.reference})"

    # --- geometry ------------------------------------------------------------------------------------------

    def scene(self, seed: int, index: int) -> Scene:
        return sample_scene(seed, index, self.config, self.model.num_components)

    def geometry(self, scene: Scene) -> tuple[Geometry, np.ndarray]:
        """Posed foot and leg in the scene frame, and the joint angles drawn (the model on ``RENDER_THREADS``)."""
        with torch.no_grad(), torch_threads(RENDER_THREADS):
            return self._geometry(scene)

    def _geometry(self, scene: Scene) -> tuple[Geometry, np.ndarray]:
        shape = torch.from_numpy(scene.shape)[None]
        # only the IK poses need the shaped foot's rest joints (one more pass of the model)
        rest = self.model(shape).rest_joints[0] if scene.pose_method == "ik" else None
        angles = sample_angles(scene.seed, scene.index, scene.pose_method, rest)
        if self.config.weight_bearing and not scene.lifted:
            angles = self._bearing_weight(shape, angles)
        out = self.model(shape, torch.from_numpy(angles)[None], side=scene.side)
        verts, joints = out.vertices[0].numpy(), out.joints[0].numpy()
        pitch, roll = scene.tilt
        rot = _rot_y(pitch) @ _rot_x(roll)
        moved = verts @ rot.T
        scene_from_foot = np.eye(4)
        scene_from_foot[:3, :3] = rot
        scene_from_foot[2, 3] = scene.lift_mm - moved[:, 2].min()
        verts = moved + scene_from_foot[:3, 3]
        joints = joints @ rot.T + scene_from_foot[:3, 3]
        albedo = sample_skin(scene.seed, scene.index, scene.skin_tone, self.skin)
        leg_v, leg_f, leg_a = self._leg(scene, verts, albedo, LEG_SKIN_STREAM)
        other_foot = other_leg = None
        if scene.other_foot is not None:
            other_foot, other_leg = self._other_foot(scene, shape, rest, albedo)
        geo = Geometry(
            verts, joints, self._faces[scene.side], albedo, leg_v, leg_f, leg_a, scene_from_foot, other_foot, other_leg
        )
        return geo, angles

    def _bearing_weight(self, shape: torch.Tensor, angles: np.ndarray) -> np.ndarray:
        """(22,) ``angles`` of a standing foot bearing weight (shape (1, K)): the toes' downward flexion scaled back
        until no toe reaches below the ball (``WEIGHT_BEARING_TOLERANCE_MM``), then the hindfoot angle that sets
        the heel level with the ball; the others as drawn. Each by one batched pass of the model over a grid of
        ``WEIGHT_BEARING_STEPS``."""
        flexion = np.array([sk.DOF_NAMES.index(f"toe{k}_{j}_y") for k in range(1, 6) for j in ("proximal", "distal")])
        factor = np.linspace(1.0, 0.0, WEIGHT_BEARING_STEPS)
        trial = np.repeat(angles[None], WEIGHT_BEARING_STEPS, axis=0)
        trial[:, flexion] = np.where(angles[flexion] > 0, factor[:, None] * angles[flexion], angles[flexion])
        out = trial[self._level(shape, trial, self._toes, self._ball, allow_above=True)].copy()
        dof = sk.DOF_NAMES.index("midfoot_ankle_y")
        trial = np.repeat(out[None], WEIGHT_BEARING_STEPS, axis=0)
        trial[:, dof] = np.linspace(sk.DOF_LOWER[dof], sk.DOF_UPPER[dof], WEIGHT_BEARING_STEPS)
        k = self._level(shape, trial, self._heel, self._ball)
        out[dof] = trial[k, dof]
        return out

    def _level(
        self, shape: torch.Tensor, trial: np.ndarray, region: np.ndarray, base: np.ndarray, allow_above: bool = False
    ) -> int:
        """Index of the first of the (N, 22) ``trial`` angles whose ``region`` lowest point is level with the
        ``base`` region's (``allow_above``: or above it), else the nearest to level."""
        verts = self.model(shape.expand(len(trial), -1), torch.from_numpy(trial)).vertices.numpy()
        gap = verts[:, region, 2].min(axis=1) - verts[:, base, 2].min(axis=1)
        ok = np.flatnonzero(gap >= -WEIGHT_BEARING_TOLERANCE_MM) if allow_above else np.zeros(0, np.int64)
        if len(ok):
            return int(ok[0])
        return int(np.argmin(np.abs(gap)))

    def _other_foot(
        self, scene: Scene, shape: torch.Tensor, rest: torch.Tensor | None, albedo: np.ndarray
    ) -> tuple[Mesh, Mesh]:
        """The other foot (same shape and skin, the mirror side, its own pose) standing beside the first; its leg."""
        side = "left" if scene.side == "right" else "right"
        angles = sample_angles(scene.seed, scene.index, scene.pose_method, rest, stream=OTHER_FOOT_STREAM)
        verts = self.model(shape, torch.from_numpy(angles)[None], side=side).vertices[0].numpy()
        c, s = math.cos(scene.other_foot.yaw), math.sin(scene.other_foot.yaw)
        verts = verts @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
        dx, dy = scene.other_foot.offset_mm
        verts = verts + np.array([dx, dy, -verts[:, 2].min()])
        leg = Mesh(*self._leg(scene, verts, albedo, OTHER_LEG_SKIN_STREAM))
        return Mesh(verts, self._faces[side], albedo), leg

    def _leg(self, scene: Scene, verts: np.ndarray, albedo: np.ndarray, stream: int) -> tuple[np.ndarray, ...]:
        """A truncated elliptic cone from the ankle cap up to ``leg_top_mm`` above the floor (bare, sock, trouser),
        its skin from the foot's ``albedo`` (V, 3) (``SynthConfig.skin_legs``; ``stream`` draws its variation)."""
        cap = verts[self.cap]
        skin = albedo[self.cap].mean(axis=0)
        centre = cap.mean(axis=0)
        _, _, vt = np.linalg.svd(cap - centre, full_matrices=False)
        normal = vt[2] if vt[2, 2] > 0 else -vt[2]
        # the shin stays nearer upright than the cap turns with the ankle angle (the foot moves under the leg)
        axis = normal + LEG_UPRIGHT * np.array([0.0, 0.0, 1.0])
        axis /= np.linalg.norm(axis)
        e1 = vt[0] - axis * (vt[0] @ axis)
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(axis, e1)
        a = np.abs((cap - centre) @ e1).max() * 1.02
        b = np.abs((cap - centre) @ e2).max() * 1.02
        length = float(np.clip((scene.leg_top_mm - centre[2]) / max(axis[2], 0.3), 150.0, 900.0))
        band = min(scene.leg_band_mm, length - 20.0)
        start = -8.0  # below the cap, so the cone overlaps the foot's sides and hides the seam

        def width(h: float) -> float:
            return 1.0 + 0.35 * (h - start) / (length - start)  # the calf widens upwards

        leg_colour = np.asarray(scene.leg_colour)
        pieces = []  # (heights, growth, colour (None: bare skin), outward)
        if scene.leg_style == "trouser":
            pieces.append(([start, band + 5], 1.0, None, True))
            pieces.append(([band, length], 1.3, leg_colour, True))
            pieces.append(([band, length], 1.28, leg_colour * 0.6, False))  # inside of the hem
        elif scene.leg_style == "sock":
            pieces.append(([start, band], 1.03, leg_colour, False))
            pieces.append(([band, length], 1.0, None, True))
        else:
            pieces.append(([start, length], 1.0, None, True))
        around = None
        if self.config.skin_legs:
            # the cap vertex nearest each point's angle around the leg, so the shin continues the foot's colours
            rel = cap - centre
            cap_angle = np.arctan2((rel @ e2) / b, (rel @ e1) / a)
            gap = np.abs(np.angle(np.exp(1j * (_RING_ANGLES[:, None] - cap_angle[None]))))
            around = albedo[self.cap][np.argmin(gap, axis=1)]  # (LEG_SEGMENTS, 3)
            rng = np.random.default_rng([scene.seed, scene.index, stream])
        vs, fs, cs, offset = [], [], [], 0
        for heights, grow, colour, outward in pieces:
            top = heights[1] == length
            v, f = _tube(centre, axis, e1, e2, a * grow, b * grow, heights, width, outward, cap_top=top)
            if colour is None and around is not None:
                c = _skin_along(around, (len(v) - top) // LEG_SEGMENTS, rng)
                if top:  # the closed top's centre
                    c = np.concatenate([c, c[-LEG_SEGMENTS:].mean(axis=0, keepdims=True)])
            else:
                c = np.broadcast_to(skin if colour is None else colour, v.shape)
            vs.append(v)
            fs.append(f + offset)
            cs.append(np.clip(c, 0, 1))
            offset += len(v)
        return np.concatenate(vs), np.concatenate(fs), np.concatenate(cs)

    # --- rendering -----------------------------------------------------------------------------------------

    def render(self, seed: int, index: int) -> dict[str, np.ndarray]:
        """One sample as a dict of arrays (see ``footmesh.synth.dataset.SAMPLE_KEYS`` for keys and units)."""
        scene = self.scene(seed, index)
        geo, angles = self.geometry(scene)
        size = self.config.size
        k = intrinsics(size, scene.fov_deg)
        lo, hi = geo.foot_vertices.min(axis=0), geo.foot_vertices.max(axis=0)
        if self.config.frame_reference and scene.reference is not None and scene.view_id < 0:
            corners = scene.reference.corners()
            lo, hi = np.minimum(lo, corners.min(axis=0)), np.maximum(hi, corners.max(axis=0))
        centre = (lo + hi) / 2
        radius = float(np.linalg.norm(hi - lo) / 2)
        cam_from_scene = camera_pose(scene, centre, radius)
        cam_from_foot = cam_from_scene @ geo.scene_from_foot
        rng = np.random.default_rng(scene.noise_seed)

        # supersampled grid: sample j sits at pixel coordinate j / 2 - 1/2 (odd j = pixel centres)
        n_ss = 2 * size + 1
        k_ss = k.copy()
        k_ss[:2] *= 2.0
        k_ss[:2, 2] += 1.0
        rot, trans = cam_from_scene[:3, :3], cam_from_scene[:3, 3]
        feet, legs = geo.feet(), geo.legs()
        verts, faces, albedo = _merge(feet + legs)
        n_foot_faces = sum(len(m.faces) for m in feet)
        v_cam = verts @ rot.T + trans
        xy, z = project(v_cam, k_ss)
        frag = raster.rasterize(xy, z, faces, n_ss, n_ss)

        light = scene.light_dir
        normals = np.concatenate(
            [self._vertex_normals(m.vertices, m.faces) for m in feet]
            + [_mesh_normals(m.vertices, m.faces) for m in legs]
        )
        lambert = np.clip(normals @ light, 0.0, None)
        sky = 0.8 + 0.2 * normals[:, 2]  # hemispheric ambient: surfaces facing down get a little less light
        shade = (scene.ambient * sky)[:, None] + (scene.diffuse * lambert)[:, None] * scene.light_colour[None]
        v_colour = albedo * shade

        # floor, reference object and background: evaluated at the pixel centres (exact depth and labels), and
        # upsampled bilinearly to the samples between them, where the mesh does not cover them
        eye = -rot.T @ trans
        # scene-frame direction with camera z = 1 of pixel (column c, row r): (c, r, 1) @ rays
        rays = np.linalg.inv(k).T @ rot
        n_foot_verts = sum(len(m.vertices) for m in feet)
        floor_rgb, floor_depth, ref_hit = self._floor(
            scene, geo, eye, rays, kernels.floor_needed(frag.face), (verts, faces, n_foot_verts, n_foot_faces)
        )
        rgb = kernels.compose(frag.face, frag.bary, faces, v_colour, floor_rgb.reshape(size, size, 3))
        rgb = kernels.noisy_rgb_to_uint8(rgb, self.config.rgb_noise_sd, int(rng.integers(2**63)))

        # labels at pixel centres (odd samples)
        centre_face = frag.face[1::2, 1::2]
        mesh_depth = frag.depth[1::2, 1::2]
        floor_depth = floor_depth.reshape(size, size)
        depth = np.where(centre_face >= 0, mesh_depth, np.where(np.isfinite(floor_depth), floor_depth, 0.0))
        labels = np.where(ref_hit.reshape(size, size), LABEL_REFERENCE, LABEL_BACKGROUND).astype(np.uint8)
        labels[centre_face >= 0] = LABEL_LEG
        labels[(centre_face >= 0) & (centre_face < n_foot_faces)] = LABEL_FOOT
        silhouette = labels == LABEL_FOOT

        v_foot_cam = geo.foot_vertices @ rot.T + trans
        j_cam = geo.foot_joints @ rot.T + trans
        j2d, jz = project(j_cam, k)
        tol = kernels.nearest_distance(geo.foot_joints, geo.foot_vertices)
        j_vis = _visible(j2d, jz, silhouette, depth, tol + JOINT_VISIBILITY_MARGIN_MM)

        ref_kind = scene.reference.kind if scene.reference is not None else "none"
        ref3d = np.full((4, 3), np.nan)
        ref2d = np.full((4, 2), np.nan)
        ref_vis = np.zeros(4, dtype=bool)
        if scene.reference is not None:
            ref3d = scene.reference.corners() @ rot.T + trans
            ref2d, rz = project(ref3d, k)
            if eye[2] > 0:
                ref_vis = _visible(ref2d, rz, depth > 0, depth, np.full(4, REFERENCE_VISIBILITY_TOLERANCE_MM))

        return {
            "index": np.int64(index),
            "rgb": rgb,
            "depth": depth_noise(depth, rng),
            "depth_clean": depth.astype(np.float32),
            "silhouette": silhouette,
            "labels": labels,
            "joints2d": j2d.astype(np.float32),
            "joints_visible": j_vis,
            "joints3d": j_cam.astype(np.float32),
            "vertices": v_foot_cam.astype(np.float32),
            "shape": scene.shape.astype(np.float32),
            "angles": angles.astype(np.float32),
            "side": np.int8(scene.side == "right"),
            "K": k,
            "cam_from_foot": cam_from_foot,
            "cam_from_scene": cam_from_scene,
            "ref_type": np.int8(0 if ref_kind == "none" else references.kind(ref_kind).dataset_id),
            "ref_corners3d": ref3d.astype(np.float32),
            "ref_corners2d": ref2d.astype(np.float32),
            "ref_corners_visible": ref_vis,
            "view_id": np.int16(scene.view_id),
            "lifted": np.bool_(scene.lifted),
        }

    def _vertex_normals(self, verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
        """(V, 3) unit area-weighted vertex normals of the foot model's mesh (its vertex-face incidence)."""
        inc = self._incidence
        n = kernels.csr_rows(inc.indptr, inc.indices, inc.data, kernels.area_normals(verts, faces))
        return kernels.unit_rows(n, 1e-12)

    def _floor(
        self,
        scene: Scene,
        geo: Geometry,
        eye: np.ndarray,
        rays: np.ndarray,
        needed: np.ndarray,
        merged: tuple[np.ndarray, np.ndarray, int, int],
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Colour (N, 3), camera depth (N,) (inf = none) and reference-object mask (N,) at the N = S^2 pixel
        centres (row-major).

        ``rays`` (3, 3): pixel (column c, row r) looks along the scene-frame direction ``(c, r, 1) @ rays``
        (``inv(K).T @ R``), whose camera z is 1, so the ray parameter at the floor is the camera depth. The colour
        is computed only where ``needed`` (any shape, N values; elsewhere 0: the mesh hides those pixel centres and
        their neighbourhood). ``merged``: ``_merge(geo.feet() + geo.legs())``'s vertices and faces and how many of them
        are the feet's (``render`` has them already).
        """
        ref = scene.reference
        if ref is not None:
            ref_args = textures.reference_params(ref.kind, ref.tint, ref.salt)[2:]
            ref_origin, ref_angle = np.asarray(ref.origin, dtype=np.float64), ref.angle
        else:
            ref_args = (0, 1.0, 1.0, 0.0, np.zeros(3), np.zeros(3), 0.0)
            ref_origin, ref_angle = np.zeros(2), 0.0
        light = scene.light_dir
        if eye[2] > 0:
            verts, faces, n_foot_verts, n_foot_faces = merged
            cast = self._floor_shadow(verts, faces, light)
            contact = self._contact_shadow(verts[:n_foot_verts], faces[:n_foot_faces])
        else:  # the camera is under the floor: the floor is one-sided and not seen
            cast = contact = (np.zeros((1, 1)), np.zeros(2), 1.0)
        table, *floor_args = textures.floor_params(scene.floor)
        return kernels.floor_shade(
            np.ascontiguousarray(rays),
            self.config.size,
            eye,
            FAR_MM,
            textures.background_tint(scene.floor.salt),
            scene.ambient + 0.5 * scene.diffuse,
            table,
            *floor_args,
            ref_args[0],
            ref_origin,
            ref_angle,
            *ref_args[1:],
            textures.ARUCO_BITS,
            *cast,
            *contact,
            scene.ambient,
            scene.diffuse * light[2],
            np.asarray(scene.light_colour, dtype=np.float64),
            needed.reshape(-1),
        )

    def _floor_shadow(
        self, verts: np.ndarray, faces: np.ndarray, light: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, float]:
        """Cast shadow map of the feet and legs (``verts``, ``faces`` merged) on the floor, 0..1: their projection
        along the light, blurred."""
        flat = verts[:, :2] - verts[:, 2:3] * (light[:2] / light[2])[None]
        # a closed surface's shadow is that of its faces turned to the light: counter-clockwise on the floor seen
        # from above, which the rasteriser (y-down convention) keeps after re-winding
        faces = faces[:, [0, 2, 1]]
        return _coverage_map(flat, np.ones(len(flat)), faces, texel=CAST_TEXEL_MM, blur_mm=4.0, mode="cover")

    def _contact_shadow(self, v: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """Ambient occlusion map under the feet (``v``, ``faces`` merged), 0..1 (the floor is darkened by 0.6 of
        it): strong where the sole is close to the floor, blurred."""
        # the faces seen from below (the sole side) are clockwise seen from above: kept as they are
        return _coverage_map(v[:, :2], v[:, 2], faces, texel=CONTACT_TEXEL_MM, blur_mm=10.0, mode="height")


def _mesh_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V, 3) ``geometry.mesh.vertex_normals``, compiled (the same bits)."""
    area = kernels.area_normals(np.ascontiguousarray(vertices, dtype=np.float64), np.ascontiguousarray(faces))
    return kernels.unit_rows(kernels.scatter_faces(faces, area, len(vertices)), 1e-12)


def _merge(meshes: list[Mesh]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One vertex, face and albedo array of several meshes, in their order (face ids follow that order)."""
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
    verts = np.concatenate([m.vertices for m in meshes])
    faces = np.concatenate([m.faces + o for m, o in zip(meshes, offsets, strict=True)])
    return verts, faces, np.concatenate([m.albedo for m in meshes])


def _coverage_map(
    flat: np.ndarray, height: np.ndarray, faces: np.ndarray, texel: float, blur_mm: float, mode: str
) -> tuple[np.ndarray, np.ndarray, float]:
    """Rasterise triangles flattened onto the floor into a small map and blur it: (map, its origin (x, y) mm, texel).

    ``mode="cover"``: 1 where covered. ``mode="height"``: ``exp(-h / 25 mm)`` of the lowest surface height h.
    The renderer reads the map bilinearly at floor points (0 outside it).
    """
    pad = 4 * blur_mm
    lo = flat.min(axis=0) - pad
    hi = flat.max(axis=0) + pad
    w, h = (np.ceil((hi - lo) / texel).astype(int) + 1).tolist()
    if w * h > 2_000_000:  # a grazing light stretches the shadow: coarser map
        scale = math.sqrt(w * h / 2_000_000)
        texel *= scale
        w, h = (np.ceil((hi - lo) / texel).astype(int) + 1).tolist()
    grid = (flat - lo) / texel
    frag = raster.rasterize(grid, height + 1.0, faces, h, w, perspective=False, cull_back=True)
    if mode == "cover":
        value = (frag.face >= 0).astype(np.float64)
    else:
        value = np.where(frag.face >= 0, np.exp(-(frag.depth - 1.0) / 25.0), 0.0)
    value = kernels.gaussian_blur(np.ascontiguousarray(value), gaussian_weights(blur_mm / texel))
    return value, lo, float(texel)


def gaussian_weights(sigma: float, truncate: float = 4.0) -> np.ndarray:
    """(2r + 1,) normalised Gaussian weights of SD ``sigma`` (texels), ``r = int(truncate sigma + 0.5)``: scipy's
    ``gaussian_filter`` kernel, value for value (``kernels.gaussian_blur`` applies it)."""
    radius = int(truncate * float(sigma) + 0.5)
    x = np.arange(-radius, radius + 1)
    phi = np.exp(-0.5 / (sigma * sigma) * x**2)
    return phi / phi.sum()


def _visible(uv: np.ndarray, z: np.ndarray, mask: np.ndarray, depth: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """Points whose projection lies in the image and, within one pixel, on ``mask`` with depth >= z - tolerance."""
    return kernels.visible(
        np.ascontiguousarray(uv, dtype=np.float64),
        np.ascontiguousarray(z, dtype=np.float64),
        np.ascontiguousarray(mask, dtype=bool),
        np.ascontiguousarray(depth, dtype=np.float64),
        np.ascontiguousarray(tolerance, dtype=np.float64),
    )


def depth_noise(depth: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Simulated sensor depth (uint16 mm, 0 = missing) from exact depth (mm, 0 = no surface).

    ``z + N(0, sigma(z))`` with ``sigma(z) = DEPTH_NOISE_A_MM + DEPTH_NOISE_B_PER_MM z^2``; dropouts: pixels on a
    depth edge (``DEPTH_EDGE_JUMP``) vanish with probability ``DEPTH_EDGE_DROPOUT``, any pixel with
    ``DEPTH_RANDOM_DROPOUT``; outside ``DEPTH_RANGE_MM`` the depth is missing; rounded to whole millimetres. The
    draws: ``kernels.gaussians`` and ``kernels.uniforms`` of two seeds drawn from ``rng``.
    """
    z = np.ascontiguousarray(depth, dtype=np.float64)
    seeds = rng.integers(2**63, size=2)
    normal = kernels.gaussians(int(seeds[0]), z.size, 1.0).reshape(z.shape)
    u = kernels.uniforms(int(seeds[1]), z.size).reshape(z.shape)
    return kernels.depth_sensor(
        z,
        normal,
        u,
        DEPTH_NOISE_A_MM,
        DEPTH_NOISE_B_PER_MM,
        *DEPTH_EDGE_JUMP,
        DEPTH_EDGE_DROPOUT,
        1.0 - DEPTH_RANDOM_DROPOUT,
        *DEPTH_RANGE_MM,
    )


def _tube(
    centre: np.ndarray,
    axis: np.ndarray,
    e1: np.ndarray,
    e2: np.ndarray,
    a: float,
    b: float,
    heights: list[float],
    width,
    outward: bool,
    cap_top: bool,
) -> tuple[np.ndarray, np.ndarray]:
    """Elliptic tube rings at ``heights`` along ``axis``; faces wound outwards (or inwards), top optionally closed."""
    # rings every LEG_RING_MM at most: long thin triangles would make the rasteriser test huge bounding boxes
    steps = max(int(np.ceil((heights[-1] - heights[0]) / LEG_RING_MM)), 1)
    heights = np.linspace(heights[0], heights[-1], steps + 1)
    ring = a * _RING_COS * e1 + b * _RING_SIN * e2  # (n, 3)
    scale = np.array([width(h) for h in heights])
    verts = (centre + heights[:, None, None] * axis + scale[:, None, None] * ring).reshape(-1, 3)
    faces = _tube_faces(len(heights), cap_top)
    if cap_top:
        verts = np.concatenate([verts, (centre + heights[-1] * axis)[None]])
    # orient: the first side face's normal must point away from the axis (or towards it for an inner surface)
    f0 = faces[0]
    normal = np.cross(verts[f0[1]] - verts[f0[0]], verts[f0[2]] - verts[f0[0]])
    radial = verts[f0[0]] - (centre + heights[0] * axis)
    if (normal @ radial > 0) != outward:
        faces = faces[:, [0, 2, 1]]
    return verts, faces


def _skin_along(around: np.ndarray, rings: int, rng: np.random.Generator) -> np.ndarray:
    """(rings * LEG_SEGMENTS, 3) colours of a bare leg's rings: ``around`` (LEG_SEGMENTS, 3) at the ankle, each ring
    drifting from the one below by a few per cent in brightness and tone (a random walk, smoothed around the ring)."""
    patchy = rng.normal(0.0, LEG_SKIN_DRIFT / 2, (rings, LEG_SEGMENTS, 1))
    patchy = sum(w * np.roll(patchy, k, axis=1) for w, k in ((0.25, -1), (0.5, 0), (0.25, 1)))
    steps = rng.normal(0.0, LEG_SKIN_DRIFT, (rings, 1, 1)) + rng.normal(0.0, LEG_SKIN_DRIFT / 3, (rings, 1, 3)) + patchy
    steps[0] = 0.0  # the first ring is the ankle's own colours
    return (around[None] * np.exp(np.cumsum(steps, axis=0))).reshape(-1, 3)


_RING_ANGLES = np.linspace(0, 2 * np.pi, LEG_SEGMENTS, endpoint=False)
_RING_COS = np.cos(_RING_ANGLES)[:, None]
_RING_SIN = np.sin(_RING_ANGLES)[:, None]


@functools.lru_cache(maxsize=64)
def _tube_faces(rings: int, cap_top: bool) -> np.ndarray:
    """(F, 3) faces of ``rings`` rings of LEG_SEGMENTS vertices (read-only; with the top's centre after them)."""
    n = LEG_SEGMENTS
    i = np.arange(n)
    p = (np.arange(rings - 1) * n)[:, None] + i  # (rings - 1, n)
    q = (np.arange(rings - 1) * n)[:, None] + (i + 1) % n
    # per ring: its n quads' first triangles, then their second ones
    faces = np.stack([np.stack([p, q, q + n], -1), np.stack([p, q + n, p + n], -1)], 1).reshape(-1, 3)
    if cap_top:
        top, last = rings * n, (rings - 1) * n
        faces = np.concatenate([faces, np.stack([last + i, last + (i + 1) % n, np.full(n, top)], 1)])
    faces.setflags(write=False)
    return faces


def _rot_x(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def _rot_y(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1.0, 0], [-s, 0, c]])
