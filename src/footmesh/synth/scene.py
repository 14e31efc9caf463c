"""What one synthetic sample shows, drawn deterministically from ``np.random.default_rng([seed, index])``.

Frames (mm): the *foot frame* is the foot model's own (``docs/conventions.md``: origin at the heel on the floor,
x heel -> toe, z up); the *scene frame* has the floor at ``z = 0`` and equals the foot frame of a foot standing
on it. ``scene_from_foot`` places the posed foot (identity up to a shift for a standing foot; a tilt and a lift for
a lifted one). The camera is OpenCV (x right, y down, z forward); ``cam_from_scene`` maps scene to camera.

Sampling (all uniform unless stated; see ``SynthConfig`` for the ranges):

- shape: ``N(0, 1)`` coefficients of every PCA component (the model's components include foot size);
- pose: ``sample_poses(method="natural")`` with probability ``1 - ik_fraction``, else ``method="ik"`` (the
  thesis' random reachable branch ends; angle distributions in ``footmesh.model.ik.sample_poses``);
- side: left or right with probability 1/2;
- skin: FIND's per-vertex colours (``sample_skin_colours``), then with probability ``retone_fraction`` re-toned
  to a mean tone drawn between a light and a dark end that both satisfy Kolkur et al.'s RGB skin bounds
  (R > 95, G > 40, B > 20, R > G > B, R - G > 15), keeping each vertex's ratio to the foot's mean colour;
- leg: a truncated elliptic cone from the model's ankle cap up to ``leg_top_mm`` above the floor, bare, with a
  sock band, or under a trouser hem;
- placement: standing (the lowest vertex touches the floor) or, with probability ``lifted_fraction``, tilted and
  raised;
- floor: ``textures.FloorParams`` (wood, tiles, carpet, plain); lighting: ambient + one directional light;
- camera: horizontal FOV 60-75 deg, distance 300-700 mm to a point near the foot's centre, azimuth within
  ``max_azimuth_deg`` of the toes (never from behind the heel, thesis 3.5.3), elevation 20-80 deg, roll jitter;
  or one of the 22 fixed viewpoints of thesis chapter 4 (``thesis_view``);
- reference object (optional): A4 sheet (sometimes under the foot), ID-1 card or printed ArUco marker, lying on
  the floor on the camera's side of the foot;
- the other foot (probability ``other_foot_fraction``): the mirror side with the same shape, its own pose, beside
  the first (where a standing person's other foot is: 110-230 mm to its side, up to 90 mm ahead or behind,
  turned up to 20 deg), with the same leg covering;
- first-person views (probability ``first_person_fraction``): the camera above and behind the heels, looking
  down the legs as one photographs one's own feet (azimuth 180 +- 40 deg, elevation 50-88 deg, 450-900 mm), so
  the shins enter from the image's edge and may hide the heel;
- front views (probability ``front_fraction`` of the others): as ``VIEW_PRESETS["front"]``, the camera within
  35 deg of straight ahead of the toes and 45-85 deg up, the foot standing on the sheet (where one is drawn), the
  shin 500-800 mm tall, rising out of the picture over the heel.

The last three are drawn after everything else, so datasets made before them keep every other value. Weight-bearing
feet (``weight_bearing``, the ``front`` views) draw nothing: a standing foot's toes and hindfoot angle are set so
that its heel rests on the floor with its ball, not only its lowest vertex.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from footmesh import references
from footmesh.synth.textures import FloorParams, reference_extent

REFERENCE_KINDS = ("none", *references.NAMES)
"""``--reference`` choices besides ``mixed``; a sample's ``ref_type`` is its kind's ``ReferenceKind.dataset_id``."""
REFERENCE_CHOICES = (*REFERENCE_KINDS, "mixed")
VIEW_CHOICES = ("random", "thesis")
NUM_THESIS_VIEWS = 22

SKIN_LIGHT = np.array([0.93, 0.78, 0.66])
"""Light end of the re-toned skin range (sRGB 0..1)."""
SKIN_DARK = np.array([0.38, 0.24, 0.16])
"""Dark end: (97, 61, 41) / 255, just inside Kolkur et al.'s bounds (R > 95, G > 40, B > 20, R - G > 15)."""


@dataclass(frozen=True)
class SynthConfig:
    """Generator settings; every field is written to the dataset's ``meta.json``."""

    size: int = 224
    views: str = "random"
    reference: str = "mixed"
    ik_fraction: float = 0.15
    retone_fraction: float = 0.6
    lifted_fraction: float = 0.2
    fov_deg: tuple[float, float] = (60.0, 75.0)
    distance_mm: tuple[float, float] = (300.0, 700.0)
    max_azimuth_deg: float = 140.0
    min_azimuth_deg: float = 0.0
    """Views within this of straight ahead of the toes (azimuth 0) are not drawn: the drawn |azimuth| is mapped
    linearly onto [min, max] (same random numbers: 0 keeps the datasets made before this field)."""
    elevation_deg: tuple[float, float] = (20.0, 80.0)
    roll_deg: float = 10.0
    leg_top_mm: tuple[float, float] = (380.0, 520.0)
    reference_probs: dict[str, float] = field(
        default_factory=lambda: {"none": 0.25, **{k.name: k.synth_share for k in references.KINDS}}
    )
    sheet_under_foot_fraction: float = 0.4
    """Share of the sheets (A4, letter) that the foot stands on; the others lie beside it."""
    other_foot_fraction: float = 0.0
    """Share of samples showing the other foot and leg beside the first (both labelled foot; joints of the first)."""
    first_person_fraction: float = 0.0
    """Share of random views taken from above and behind the heels, down the legs (they replace the view drawn)."""
    weight_bearing: bool = False
    """True: a standing foot bears weight, as a person standing for the photo does: its toes' downward flexion
    scaled back until none reaches below the ball, its hindfoot angle (``midfoot_ankle_y``) set so that the heel
    rests on the floor with the ball. False: any everyday pose on its lowest vertex (the heel or the ball up to
    ~45 mm off the floor: a foot at rest; datasets made before this field)."""
    skin_legs: bool = False
    """True: a bare leg's skin continues the foot's (``render.Renderer._leg``): each point around the leg takes the
    colour of the ankle cap's vertex at that angle, varied slowly along the leg, as a shin continues the foot's skin
    without an edge. False: one colour, the cap's mean (datasets before this field). Fine-tuning the RGB 2D-cues
    network on such renders did not stop it taking real bare shins for feet (its model card)."""
    front_fraction: float = 0.0
    """Share of the other random views taken from in front of the toes and above, as most real photos of a foot on
    a sheet are (``VIEW_PRESETS["front"]``): the foot stands on the sheet, the shin rises out of the picture."""
    rgb_noise_sd: float = 1.5 / 255
    """SD of the Gaussian sensor noise added to RGB (0..1 units)."""
    frame_reference: bool = False
    """True: random views frame the foot and the reference object together, like a whole photo taken as the photo
    guide asks (a reference half out of frame cannot give the scale; ``eval measure``, the bundled examples).
    False: the foot alone, as the pipeline's crop frames it (training data for the networks that see the crop)."""

    def __post_init__(self) -> None:
        if self.size < 16 or self.size > 4096:
            raise ValueError(f"size must be 16..4096 pixels, got {self.size}")
        if self.views not in VIEW_CHOICES:
            raise ValueError(f"views must be one of {VIEW_CHOICES}, got {self.views!r}")
        if not 0 <= self.min_azimuth_deg <= self.max_azimuth_deg <= 180:
            raise ValueError(
                f"azimuths must satisfy 0 <= min <= max <= 180 deg, got {self.min_azimuth_deg}, {self.max_azimuth_deg}"
            )
        for name in (
            "other_foot_fraction",
            "first_person_fraction",
            "front_fraction",
            "ik_fraction",
            "lifted_fraction",
            "sheet_under_foot_fraction",
        ):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must be in 0..1, got {getattr(self, name)}")
        if self.reference not in REFERENCE_CHOICES:
            raise ValueError(f"reference must be one of {REFERENCE_CHOICES}, got {self.reference!r}")
        if not 0.0 <= self.rgb_noise_sd <= 0.5:
            raise ValueError(f"rgb_noise_sd must be in 0..0.5, got {self.rgb_noise_sd}")


@dataclass(frozen=True)
class Reference:
    """A reference object on the floor: kind, its corner 0 (x, y) in the scene frame (mm) and its heading."""

    kind: str
    origin: tuple[float, float]
    angle: float
    tint: tuple[float, float, float]
    salt: float
    under_foot: bool

    def corners(self) -> np.ndarray:
        """(4, 3) scene-frame corners of the stored rectangle: local (0,0), (L,0), (L,W), (0,W), on z = 0."""
        from footmesh.synth.textures import reference_size

        length, width = reference_size(self.kind)
        local = np.array([[0, 0], [length, 0], [length, width], [0, width]], dtype=np.float64)
        c, s = math.cos(self.angle), math.sin(self.angle)
        xy = local @ np.array([[c, s], [-s, c]]) + np.asarray(self.origin)
        return np.concatenate([xy, np.zeros((4, 1))], axis=1)

    def to_local(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Scene-frame floor points -> object coordinates (u along the length, v along the width), mm."""
        c, s = math.cos(self.angle), math.sin(self.angle)
        dx, dy = x - self.origin[0], y - self.origin[1]
        return c * dx + s * dy, -s * dx + c * dy


@dataclass(frozen=True)
class OtherFoot:
    """The other foot beside the sample's foot: its offset (x ahead, y to the side; scene frame, mm) and yaw (rad).

    Its pose comes from ``sample_angles(..., stream=OTHER_FOOT_STREAM)``."""

    offset_mm: tuple[float, float]
    yaw: float


OTHER_FOOT_STREAM = 3
"""Random stream of the other foot's joint angles (``default_rng([seed, index, 3])``)."""


@dataclass(frozen=True)
class Scene:
    """Everything drawn for one sample (the geometry follows from it and the foot model)."""

    seed: int
    index: int
    shape: np.ndarray  # (K,) SD units
    pose_method: str  # the angles are drawn by ``sample_angles`` (they need the shaped foot's rest joints)
    side: str
    skin_tone: np.ndarray | None  # (3,) target mean sRGB, None = FIND's colours as drawn
    leg_style: str  # "bare", "sock", "trouser"
    leg_colour: tuple[float, float, float]
    leg_band_mm: float  # sock top / trouser hem height above the ankle cap
    leg_top_mm: float
    lifted: bool
    tilt: tuple[float, float]  # pitch (about y), roll (about x), radians
    lift_mm: float
    floor: FloorParams
    ambient: float
    diffuse: float
    light_dir: np.ndarray  # (3,) unit, scene frame, towards the light
    light_colour: np.ndarray  # (3,)
    fov_deg: float
    distance_mm: float
    azimuth: float  # radians from +x (toes), about +z
    elevation: float  # radians above the floor
    roll: float
    target_jitter: np.ndarray  # (3,) mm, look-at offset from the foot's centre
    view_id: int  # 0..21 for thesis views, -1 for random
    reference: Reference | None
    noise_seed: int
    other_foot: OtherFoot | None = None
    first_person: bool = False
    front: bool = False


_GUIDED_VIEWS = dict(min_azimuth_deg=60.0, max_azimuth_deg=120.0, elevation_deg=(35.0, 75.0), lifted_fraction=0.0)
_FRONT_VIEWS = dict(
    max_azimuth_deg=35.0,
    elevation_deg=(45.0, 85.0),
    lifted_fraction=0.0,
    leg_top_mm=(500.0, 800.0),
    sheet_under_foot_fraction=1.0,
    weight_bearing=True,
)
_TELE_FOV_DEG = (20.0, 36.0)
"""A phone's 2x-3x lens, or a zoomed, cropped photo: a focal length 2-3.5x the main camera's."""

VIEW_PRESETS: dict[str, dict] = {
    # photos taken as the photo guide asks (docs/measure.md): from the side (60-120 deg off the toes' direction) and
    # above (35-75 deg), the whole foot flat on the floor
    "guided": _GUIDED_VIEWS,
    # how the error grows as a foot is seen end-on (benchmarks/bench_end_on.py): any side including straight behind
    # the heel, from just above the floor to straight down, the foot flat on the floor
    "sweep": dict(max_azimuth_deg=180.0, elevation_deg=(5.0, 89.0), lifted_fraction=0.0),
    # deliberately unlike the training scenes (issue 19's out-of-distribution eval): tele and ultra-wide lenses,
    # nearer and farther cameras, any side and height, more roll, half the feet lifted and posed by IK, a short
    # leg stump (150 mm above the ankle), every skin re-toned, the other foot in view, four times the sensor noise
    "ood": dict(
        fov_deg=(35.0, 100.0),
        distance_mm=(200.0, 1100.0),
        max_azimuth_deg=180.0,
        elevation_deg=(10.0, 89.0),
        roll_deg=30.0,
        lifted_fraction=0.5,
        ik_fraction=0.5,
        retone_fraction=1.0,
        leg_top_mm=(150.0, 260.0),
        other_foot_fraction=0.3,
        rgb_noise_sd=6.0 / 255,
    ),
    # the guided views through a tele lens: a focal length that a photo without intrinsics does not tell (issue
    # 19: the reference's perspective has to)
    "tele": {**_GUIDED_VIEWS, "fov_deg": _TELE_FOV_DEG},
    # the way most real photos of a foot on a sheet are taken (issue 19, ../shared/real/a4): from in front of the
    # toes and above, the person standing on the sheet (the foot bearing weight), the shin rising out of the picture
    # and hiding the heel
    "front": _FRONT_VIEWS,
    # the same through a tele lens: the sheet, seen square, barely tells the focal length
    "front_tele": {**_FRONT_VIEWS, "fov_deg": _TELE_FOV_DEG},
}
"""Named sets of random views (``footmesh eval measure --views NAME``), each framing the reference object too."""


def view_config(name: str, **fields) -> SynthConfig:
    """``SynthConfig`` of the view set ``name`` (a key of ``VIEW_PRESETS``) with the reference object framed;
    ``fields`` override any of it."""
    if name not in VIEW_PRESETS:
        raise ValueError(f"view set must be one of {tuple(VIEW_PRESETS)}, got {name!r}")
    return SynthConfig(**{**VIEW_PRESETS[name], "frame_reference": True, **fields})


def guided_view_config(**fields) -> SynthConfig:
    """``view_config("guided", **fields)``: photos taken as the photo guide asks."""
    return view_config("guided", **fields)


def sample_scene(seed: int, index: int, config: SynthConfig, num_components: int) -> Scene:
    """Draw one sample's parameters; deterministic in (seed, index, config)."""
    rng = np.random.default_rng([seed, index])
    shape = rng.standard_normal(num_components)
    pose_method = "ik" if rng.random() < config.ik_fraction else "natural"
    side = "right" if rng.random() < 0.5 else "left"
    skin_tone = None
    if rng.random() < config.retone_fraction:
        t = rng.random() ** 0.8
        skin_tone = (1 - t) * SKIN_LIGHT + t * SKIN_DARK + rng.normal(0, 0.02, 3)
    leg_style = ("bare", "sock", "trouser")[int(rng.choice(3, p=[0.4, 0.25, 0.35]))]
    leg_colour = tuple(float(c) for c in np.clip(rng.uniform(0.05, 0.85) * rng.uniform(0.6, 1.0, 3), 0, 1))
    leg_band = float(rng.uniform(20, 140))
    leg_top = float(rng.uniform(*config.leg_top_mm))
    lifted = rng.random() < config.lifted_fraction
    tilt = (float(rng.uniform(-0.45, 0.3)), float(rng.uniform(-0.2, 0.2))) if lifted else (0.0, 0.0)
    lift = float(rng.uniform(15, 120)) if lifted else 0.0
    floor = FloorParams.sample(rng)
    ambient = float(rng.uniform(0.3, 0.6))
    diffuse = float(rng.uniform(0.45, 0.85))
    light_az, light_el = rng.uniform(0, 2 * np.pi), np.deg2rad(rng.uniform(30, 80))
    light_dir = np.array(
        [math.cos(light_el) * math.cos(light_az), math.cos(light_el) * math.sin(light_az), math.sin(light_el)]
    )
    warm = rng.uniform(-1, 1)
    light_colour = np.array([1.0 + 0.06 * warm, 1.0, 1.0 - 0.08 * warm])
    fov = float(rng.uniform(*config.fov_deg))
    distance = float(rng.uniform(*config.distance_mm))
    azimuth_deg = rng.uniform(-config.max_azimuth_deg, config.max_azimuth_deg)
    if config.min_azimuth_deg > 0:
        spread = (config.max_azimuth_deg - config.min_azimuth_deg) / config.max_azimuth_deg
        azimuth_deg = math.copysign(config.min_azimuth_deg + abs(azimuth_deg) * spread, azimuth_deg)
    azimuth = math.radians(azimuth_deg)
    elevation = math.radians(rng.uniform(*config.elevation_deg))
    roll = math.radians(rng.normal(0, config.roll_deg / 2))
    jitter = rng.normal(0, 15.0, 3) * np.array([1, 1, 0.5])
    view_id = index % NUM_THESIS_VIEWS if config.views == "thesis" else -1
    kind = config.reference
    if kind == "mixed":
        kinds = list(config.reference_probs)
        probs = np.array([config.reference_probs[k] for k in kinds])
        kind = kinds[int(rng.choice(len(kinds), p=probs / probs.sum()))]
    reference = None
    if kind != "none":
        reference = _sample_reference(rng, kind, azimuth, config.sheet_under_foot_fraction)
    noise_seed = int(rng.integers(2**62))
    # drawn last, so that datasets made before these fields existed keep all their other values
    other_foot = None
    if rng.random() < config.other_foot_fraction:
        # a right foot stands on the left foot's -y side (the foot frame's y points to the left)
        towards = -1.0 if side == "left" else 1.0
        offset = (float(rng.normal(0, 40.0)), towards * float(rng.uniform(110.0, 230.0)))
        other_foot = OtherFoot((float(np.clip(offset[0], -90, 90)), offset[1]), float(rng.uniform(-0.35, 0.35)))
    first_person = config.views == "random" and rng.random() < config.first_person_fraction
    if first_person:
        azimuth = math.pi + math.radians(rng.uniform(-40, 40))
        elevation = math.radians(rng.uniform(50, 88))
        distance = float(rng.uniform(450, 900))
        jitter = jitter + np.array([rng.uniform(-60, 40), 0.0, 0.0])
        leg_top = float(rng.uniform(600, 900))  # shin and thigh: the legs run out of the picture
    front = config.views == "random" and not first_person and rng.random() < config.front_fraction
    if front:
        azimuth = math.radians(rng.uniform(-_FRONT_VIEWS["max_azimuth_deg"], _FRONT_VIEWS["max_azimuth_deg"]))
        elevation = math.radians(rng.uniform(*_FRONT_VIEWS["elevation_deg"]))
        leg_top = float(rng.uniform(*_FRONT_VIEWS["leg_top_mm"]))
        lifted, tilt, lift = False, (0.0, 0.0), 0.0
        if reference is not None:  # a sheet under the foot (an object beside it, on the camera's side)
            reference = _sample_reference(rng, kind, azimuth, _FRONT_VIEWS["sheet_under_foot_fraction"])
    return Scene(
        seed=seed,
        index=index,
        shape=shape,
        pose_method=pose_method,
        side=side,
        skin_tone=skin_tone,
        leg_style=leg_style,
        leg_colour=leg_colour,
        leg_band_mm=leg_band,
        leg_top_mm=leg_top,
        lifted=lifted,
        tilt=tilt,
        lift_mm=lift,
        floor=floor,
        ambient=ambient,
        diffuse=diffuse,
        light_dir=light_dir,
        light_colour=light_colour,
        fov_deg=fov,
        distance_mm=distance,
        azimuth=azimuth,
        elevation=elevation,
        roll=roll,
        target_jitter=jitter,
        view_id=view_id,
        reference=reference,
        noise_seed=noise_seed,
        other_foot=other_foot,
        first_person=first_person,
        front=front,
    )


def _sample_reference(rng: np.random.Generator, kind: str, camera_azimuth: float, under_foot: float) -> Reference:
    """A reference object on the floor; its placement is relative to a nominal foot (heel at 0, 260 mm long);
    a sheet lies under the foot with probability ``under_foot``."""
    under = references.kind(kind).detector == "sheet" and rng.random() < under_foot
    margin, length, width = reference_extent(kind)
    tint = tuple(float(c) for c in np.clip(rng.uniform(0.9, 1.0) - rng.uniform(0, 0.05, 3), 0, 1))
    salt = float(rng.uniform(0, 100))
    if under:  # the foot stands on the sheet: sheet centre near the foot's centre, roughly aligned
        centre = np.array([130.0 + rng.normal(0, 15), rng.normal(0, 10)])
        angle = float(rng.normal(0, 0.15))
    else:  # beside the foot, on the camera's side, any heading
        side_az = camera_azimuth + rng.uniform(-0.9, 0.9)
        dist = 110.0 + 0.5 * math.hypot(length, width) + rng.uniform(0, 60)
        centre = np.array([130.0 + dist * math.cos(side_az) * 1.3, dist * math.sin(side_az)])
        angle = float(rng.uniform(0, 2 * np.pi))
    c, s = math.cos(angle), math.sin(angle)
    # corner 0 of the stored rectangle, so that the drawn object (with its margin) is centred on ``centre``
    half = np.array([length / 2 - margin, width / 2 - margin])
    origin = centre - np.array([c * half[0] - s * half[1], s * half[0] + c * half[1]])
    return Reference(kind, (float(origin[0]), float(origin[1])), angle, tint, salt, under)


def look_at(eye: np.ndarray, target: np.ndarray, up: np.ndarray, roll: float = 0.0) -> np.ndarray:
    """4x4 ``cam_from_scene`` of an OpenCV camera at ``eye`` looking at ``target``; ``up`` is image-up."""
    forward = target - eye
    forward = forward / np.linalg.norm(forward)
    right = np.cross(forward, up)
    norm = np.linalg.norm(right)
    if norm < 1e-9:
        raise ValueError("look_at: the up vector is parallel to the viewing direction")
    right = right / norm
    down = np.cross(forward, right)
    if roll:
        c, s = math.cos(roll), math.sin(roll)
        right, down = c * right + s * down, -s * right + c * down
    pose = np.eye(4)
    pose[:3, :3] = np.stack([right, down, forward])
    pose[:3, 3] = -pose[:3, :3] @ eye
    return pose


def thesis_view(view_id: int, side: str) -> tuple[np.ndarray, np.ndarray, str, int]:
    """Unit direction from the foot to the camera and the image-up vector (scene frame) of a thesis viewpoint.

    Thesis chapter 4: views every 30 deg about the X and Y axes of its Figure 4.1, one axis at a time,
    counter-clockwise; 0 and 180 deg occur on both axes, leaving 22. We read Figure 4.1's 0-deg view as looking
    straight down on the foot with the toes at the top of the image, X to the image's right and Y up the image
    (towards the toes): the thesis says 270 deg about X shows "the front of the foot with the toes pointing toward
    the camera", which this reading reproduces. In the foot frame of a left foot: X = -y, Y = +x, Z = +z; a right
    foot mirrors y. Ids 0-11: about X at 0, 30, ..., 330 deg; ids 12-21: about Y at 30..150, 210..330 deg.

    Returns:
        direction (3,), up (3,), axis ("X" or "Y"), angle in degrees.
    """
    if not 0 <= view_id < NUM_THESIS_VIEWS:
        raise ValueError(f"thesis view id must be 0..{NUM_THESIS_VIEWS - 1}, got {view_id}")
    if view_id < 12:
        axis, deg = "X", 30 * view_id
    else:
        axis, deg = "Y", [30, 60, 90, 120, 150, 210, 240, 270, 300, 330][view_id - 12]
    t = math.radians(deg)
    if axis == "X":  # R_x(t) applied to the camera offset (0, 0, 1) and to image-up (0, 1, 0), figure frame
        d_fig, up_fig = np.array([0.0, -math.sin(t), math.cos(t)]), np.array([0.0, math.cos(t), math.sin(t)])
    else:
        d_fig, up_fig = np.array([math.sin(t), 0.0, math.cos(t)]), np.array([0.0, 1.0, 0.0])
    mirror = -1.0 if side == "right" else 1.0
    to_foot = np.array([[0.0, 1.0, 0.0], [-mirror, 0.0, 0.0], [0.0, 0.0, 1.0]])  # foot = M @ figure
    return to_foot @ d_fig, to_foot @ up_fig, axis, deg


def camera_pose(scene: Scene, centre: np.ndarray, radius: float) -> np.ndarray:
    """``cam_from_scene`` (4x4) for the scene, looking near the foot's ``centre`` (scene frame, mm).

    The distance is at least what keeps a sphere of ``radius`` around the centre inside 90 % of the field.
    """
    half = math.radians(scene.fov_deg) / 2
    distance = max(scene.distance_mm, radius / math.sin(0.9 * half))
    target = centre + scene.target_jitter
    if scene.view_id >= 0:
        direction, up, _, _ = thesis_view(scene.view_id, scene.side)
        target = centre
        roll = 0.0
    else:
        ce, se = math.cos(scene.elevation), math.sin(scene.elevation)
        direction = np.array([ce * math.cos(scene.azimuth), ce * math.sin(scene.azimuth), se])
        up = np.array([0.0, 0.0, 1.0])
        roll = scene.roll
    eye = target + distance * direction
    return look_at(eye, target, up, roll)


def intrinsics(size: int, fov_deg: float) -> np.ndarray:
    """K (3x3, pixels) of a square ``size`` image with horizontal = vertical FOV; principal point at the centre.

    Pixel centres are integers and the image spans -0.5 .. size - 0.5, so the centre is ``(size - 1) / 2``.
    """
    f = (size / 2) / math.tan(math.radians(fov_deg) / 2)
    c = (size - 1) / 2
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def sample_angles(seed: int, index: int, method: str, rest_joints, stream: int = 1) -> np.ndarray:
    """(22,) float64 joint angles of sample (seed, index), from the stream ``default_rng([seed, index, stream])``.

    ``method="ik"`` is ``model.ik.sample_poses``' IK compiled for one foot (``synth.posing``, dataset format 2);
    the others are ``sample_poses`` itself.
    """
    from footmesh.model.ik import sample_poses

    rng = np.random.default_rng([seed, index, stream])
    if method == "ik":
        from footmesh.synth.posing import sample_ik_angles

        rest = rest_joints.numpy() if hasattr(rest_joints, "numpy") else np.asarray(rest_joints)
        return sample_ik_angles(rest, rng)
    return sample_poses(rest_joints, rng, 1, method=method)[0].numpy()


def sample_skin(seed: int, index: int, tone: np.ndarray | None, colours) -> np.ndarray:
    """(V, 3) per-vertex skin albedo (sRGB 0..1) of sample (seed, index), stream ``default_rng([seed, index, 2])``.

    FIND's colours as drawn, or re-toned: each vertex keeps its ratio to the foot's mean colour, scaled so that
    the mean becomes ``tone``.
    """
    from footmesh.model.skin import sample_skin_colours

    rng = np.random.default_rng([seed, index, 2])
    skin = sample_skin_colours(rng, 1, colours)[0].astype(np.float64)
    if tone is not None:
        skin = skin * (np.asarray(tone) / skin.mean(axis=0))[None]
    return np.clip(skin, 0.0, 1.0)
