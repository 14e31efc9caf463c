"""Typed configuration of the networks and their training, in one place; every default works as it is.

A configuration file (``--config FILE``, JSON) holds any subset of the fields, e.g.
``{"net": {"stacks": 3}, "train": {"batch_size": 16}}``; unknown keys are an error, not silently ignored.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass, field, fields, replace
from typing import TYPE_CHECKING, Any, Literal

from footmesh import references
from footmesh.sizes import HALF_SIZE_MM

if TYPE_CHECKING:  # the fit (and torch) is not needed to hold its settings
    from footmesh.fit import FitConfig

INPUT_CHANNELS = {"rgb": 3, "rgbd": 4, "depth": 1}
"""Channels of each input kind of the 2D-cues network."""
CUES_ENCODERS = ("scratch", "efficientnet_lite0")


@dataclass(frozen=True)
class CuesNetConfig:
    """Architecture of the 2D-cues network (``footmesh.cues.net.CuesNet``).

    ``thesis()`` is the thesis' network (3 stacks, ResNet-18 encoders, one head of sigmoid maps, arg-max
    decoding); the defaults are ours: one narrower stack at 128 px sized for a 2-core CPU (a second stack costs
    twice the time; ``stacks`` > 1 gives the thesis' intermediate supervision), separate silhouette and joint
    heads, soft-argmax (sub-pixel) joints with a visibility confidence per joint.
    """

    input: str = "rgbd"
    image_size: int = 128
    """Side of the square network input, px; photos' crops are resized to it."""
    stacks: int = 1
    widths: tuple[int, ...] = (32, 64, 96, 128)
    """Channels of the encoder stages at strides 4, 8, 16, 32 (ResNet-18: 64, 128, 256, 512)."""
    blocks: tuple[int, ...] = (1, 1, 1, 1)
    """Residual blocks per encoder stage (ResNet-18: 2 each)."""
    decoder_convs: int = 5
    """Convolutions per decoder (thesis: 5), spread over the up-sampling steps."""
    head: str = "soft_argmax"
    """``soft_argmax``: heatmap softmax -> expected position (+ visibility logits); ``sigmoid``: the thesis' maps."""
    heatmap_sigma_px: float = 1.0
    """SD of the Gaussian joint targets, in output-map pixels."""
    encoder: str = "scratch"
    """``scratch``: the stacked encoder-decoders above, trained from nothing (the thesis' design);
    ``efficientnet_lite0``: an ImageNet-pretrained EfficientNet-Lite0 (from its PyPI package) with an FPN decoder
    of ``decoder_width`` channels and a left/right head (``stacks``, ``widths`` and ``blocks`` do not apply)."""
    decoder_width: int = 64
    """Channels of the pretrained encoder's FPN decoder."""

    @property
    def in_channels(self) -> int:
        return INPUT_CHANNELS[self.input]

    @classmethod
    def thesis(cls, input: str = "rgbd") -> CuesNetConfig:
        """The thesis' stacked hourglass (section 3.2) at its 224 x 224 input."""
        return cls(
            input=input,
            image_size=224,
            stacks=3,
            widths=(64, 128, 256, 512),
            blocks=(2, 2, 2, 2),
            decoder_convs=5,
            head="sigmoid",
            heatmap_sigma_px=2.0,
        )

    def __post_init__(self) -> None:
        if self.input not in INPUT_CHANNELS:
            raise ValueError(f"input must be one of {sorted(INPUT_CHANNELS)}, got {self.input!r}")
        if self.head not in ("soft_argmax", "sigmoid"):
            raise ValueError(f"head must be 'soft_argmax' or 'sigmoid', got {self.head!r}")
        if len(self.widths) != 4 or len(self.blocks) != 4:
            raise ValueError("widths and blocks need one entry per encoder stage (4)")
        if self.image_size % 32 or self.image_size < 64:
            raise ValueError(f"image_size must be a multiple of 32 and at least 64, got {self.image_size}")
        if self.stacks < 1:
            raise ValueError(f"stacks must be at least 1, got {self.stacks}")
        if self.encoder not in CUES_ENCODERS:
            raise ValueError(f"encoder must be one of {CUES_ENCODERS}, got {self.encoder!r}")
        if self.decoder_width < 8:
            raise ValueError(f"decoder_width must be at least 8, got {self.decoder_width}")


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation, schedule, checkpoints and logging of a training run."""

    steps: int = 6000
    batch_size: int = 32
    lr: float = 2e-3
    weight_decay: float = 1e-4
    pretrained_lr_scale: float = 1.0
    """Learning-rate multiplier of a model's pretrained parts (its ``pretrained_submodules``, e.g. the ImageNet
    encoder): below 1 fine-tunes them gently, so more of what they learnt from real photos survives training on
    renders."""
    warmup_steps: int = 200
    val_fraction: float = 0.025
    """Share of the training folder held out for validation (the last samples)."""
    val_every: int = 500
    checkpoint_every_s: float = 120.0
    max_minutes: float | None = None
    """Stop cleanly (checkpoint written) after this much wall time; the next run resumes."""
    seed: int = 0
    threads: int | None = None
    """torch threads per process; default: the cores available divided by the processes."""
    augment: bool = True
    init_from: str | None = None
    """Weights to start from (e.g. the RGB-D network for the RGB one); matching layers are copied."""

    def __post_init__(self) -> None:
        for name in ("steps", "batch_size", "val_every"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1, got {getattr(self, name)}")
        if self.warmup_steps < 0:
            raise ValueError(f"warmup_steps must be at least 0, got {self.warmup_steps}")
        if self.lr <= 0 or self.weight_decay < 0:
            raise ValueError(f"lr must be > 0 and weight_decay >= 0, got {self.lr} and {self.weight_decay}")
        if not 0 <= self.pretrained_lr_scale <= 1:
            raise ValueError(f"pretrained_lr_scale must be in [0, 1], got {self.pretrained_lr_scale}")
        if not 0 <= self.val_fraction < 1:
            raise ValueError(f"val_fraction must be in [0, 1), got {self.val_fraction}")
        if self.checkpoint_every_s <= 0 or (self.max_minutes is not None and self.max_minutes <= 0):
            raise ValueError("checkpoint_every_s and max_minutes must be positive")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads must be at least 1, got {self.threads}")


@dataclass(frozen=True)
class CuesLossConfig:
    """Weights of the 2D-cues losses."""

    silhouette: float = 1.0
    heatmap: float = 1.0
    joints_px: float = 0.05
    """Weight of the L1 joint distance in input pixels (soft-argmax head)."""
    visibility: float = 0.1
    side: float = 0.2
    """Weight of the left/right binary cross-entropy (networks with a side head)."""

    def __post_init__(self) -> None:
        for name in ("silhouette", "heatmap", "joints_px", "visibility", "side"):
            if getattr(self, name) < 0:
                raise ValueError(f"loss weight {name} must be at least 0, got {getattr(self, name)}")


@dataclass(frozen=True)
class CuesTrainingConfig:
    """Everything ``footmesh train cues`` needs besides the data folder."""

    net: CuesNetConfig = field(default_factory=CuesNetConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    loss: CuesLossConfig = field(default_factory=CuesLossConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> CuesTrainingConfig:
        return _from_dict(cls, data, "config")


def _from_dict(cls, data: dict[str, Any], where: str):
    """Build dataclass ``cls`` from a (partial) dict, recursing into nested dataclasses; unknown keys fail."""
    if not isinstance(data, dict):
        raise ValueError(f"{where} must be a JSON object, got {type(data).__name__}")
    known = {f.name: f for f in fields(cls)}
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ValueError(f"unknown {where} keys {unknown}; known: {sorted(known)}")
    default = cls()
    values = {}
    for name, value in data.items():
        current = getattr(default, name)
        if hasattr(current, "__dataclass_fields__"):
            value = _from_dict(type(current), value, f"{where}.{name}")
        else:
            value = _check_type(value, current, cls, name, f"{where}.{name}")
        values[name] = value
    return replace(default, **values)


def _check_type(value: Any, current: Any, cls, name: str, where: str) -> Any:
    """``value`` for a field whose default is ``current``, as the field's type; ValueError naming it otherwise."""
    hint = cls.__dataclass_fields__[name].type
    optional = current is None or "None" in str(hint)
    if value is None and optional:
        return None
    if "tuple[str" in str(hint):
        if not isinstance(value, (list, tuple)) or not all(isinstance(v, str) for v in value):
            raise ValueError(f"{where} must be a list of strings, got {value!r}")
        return tuple(value)
    if isinstance(current, tuple) or "tuple" in str(hint):
        if not isinstance(value, (list, tuple)) or not all(
            isinstance(v, (int, float)) and not isinstance(v, bool) for v in value
        ):
            raise ValueError(f"{where} must be a list of numbers, got {value!r}")
        return tuple(value)
    if "bool" in str(hint):
        if not isinstance(value, bool):
            raise ValueError(f"{where} must be true or false, got {value!r}")
        return value
    if "int" in str(hint) and "float" not in str(hint):
        if not isinstance(value, int) or isinstance(value, bool):
            raise ValueError(f"{where} must be an integer, got {value!r}")
        return value
    if "float" in str(hint):
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise ValueError(f"{where} must be a number, got {value!r}")
        return float(value)
    if "str" in str(hint) and not isinstance(value, str):
        raise ValueError(f"{where} must be a string, got {value!r}")
    return value


def load_config(path: str | os.PathLike | None, **overrides: Any) -> CuesTrainingConfig:
    """The defaults, updated from a JSON file (if given) and then by ``overrides`` of the ``net`` fields."""
    config = CuesTrainingConfig()
    if path is not None:
        try:
            data = json.loads(open(path).read())
        except FileNotFoundError:
            raise FileNotFoundError(f"config file not found: {path}") from None
        except json.JSONDecodeError as exc:
            raise ValueError(f"config file {path} is not valid JSON: {exc}") from None
        config = CuesTrainingConfig.from_dict(data)
    net_overrides = {k: v for k, v in overrides.items() if v is not None}
    if net_overrides:
        config = replace(config, net=replace(config.net, **net_overrides))
    return config


DECODER_KINDS = ("ism", "model")
"""The mesh decoders ``MeasureConfig.decoder_kind`` may name (``footmesh.recon``)."""


@dataclass(frozen=True)
class MeasureConfig:
    """Settings of ``footmesh measure`` (``footmesh.pipeline``)."""

    working_max_side: int = 1024
    """Photos with a depth map are processed at no more than this many pixels on their longer side (results map
    back)."""
    rgb_working_max_side: int = 640
    """Plain photos (RGB, with or without a reference object) at no more than this: the side the fit was tuned
    at. 960-px guided photos with a reference (``footmesh eval measure --size 960 --views guided``, seeds 4242
    and 777, 36 scaled): length / width MAE 4.68 / 3.21 mm at 1024 px, 4.71 / 3.05 at 640, and the median time
    (idle, seed 4242) 1.89 -> 1.29 s. With depth the larger side is kept (RGB-D width MAE 0.67 mm at 1024 px,
    1.12 at 640, 20 photos)."""
    crop_fill: float = 0.45
    """The foot's longer side fills this fraction of the crop given to the networks (as in their training)."""
    reframe_below: float | None = 0.7
    """A foot found filling less than this fraction of ``crop_fill`` of its crop is looked at again in a crop
    framed on it (``pipeline._located_in``; the networks learnt feet at 0.8-1.25 of ``crop_fill``, so below 0.8
    with a margin). Looking down at one's own feet (``../shared/real/rafiansyah``) the first look framed shins and
    feet as one region: mask.png IoU 0.751 -> 0.761, 79 -> 80 of 80 photos answered; of 410 renders measured
    end to end (``eval measure``: RGB-D guided, random, ood; RGB + reference guided, front, random, ood; plain RGB
    guided, ood) two moved. None: never."""
    min_foot_fraction: float = 0.004
    """A foot must cover at least this fraction of the photo."""
    second_foot_ratio: float = 0.35
    """A second region at least this large relative to the foot means two feet."""
    second_look_ratio: float | None = 0.15
    """A smaller second region, at least this large relative to the foot, is looked at closer, and is a second
    foot where that look's silhouette (cut to its joints) is ``second_foot_ratio`` of the first foot's: looking
    down at both feet, the near foot's region takes in its shin (``../shared/real/rafiansyah`` ``64_49``: the far
    foot's region 0.31 of it, its silhouette 0.65 of the near one's). On rafiansyah that photo alone changed (its
    far foot found), and no render of ``eval measure`` (410, the sets ``reframe_below`` names). None: no."""
    first_look_zoom: int = 2
    """Where no look at the whole photo finds a foot region, a last look runs the network at this many times its
    own image side (a small, far foot: at 128 px a foot 60 px long in a 640-px photo is 12 px)."""
    wider_look_window: float | None = 1.6
    """Where the first look at the whole photo finds a foot region, the network also looks at the photo shrunk
    into a square this many times its longer side (its edges carried on outwards), and its regions are taken
    where they are larger and the closer look places the joints more confidently (the two settings below). A
    foot filling the photo, larger than the feet the networks saw whole photos with, was found by its toes
    alone: close crops of ``../shared/real/a4`` (the sheet and the foot cut 25 or 45 % in from one side) were
    measured as a foot in one or two toes, or as two feet (two toes; ``docs/measure.md``). None: no wider look."""
    wider_look_min_area_ratio: float = 1.5
    """...its largest region at least this many times the first look's largest (on the renders of
    ``footmesh eval measure``, guided and front, at most 1.58, ood up to 3.41; on the seven real A4 photos
    0.86-1.65; on the close crops 2-9)..."""
    wider_look_min_confidence_gain: float = 0.05
    """...and the closer look at that region places the joints with a mean confidence at least this much above
    the first look's largest region's (close crops: 0.14-0.34 more; the seven real photos within 0.03)."""
    two_feet_min_probability: float | None = 0.8
    """Where the photo shows one foot region, the halves of its box (across its width, and across its height) are
    shown to the networks too, and the feet found in them replace the region's where the left/right head takes
    them for a right and a left foot with at least this probability (the product of its two answers) and their
    joints lie apart (``two_feet_max_overlap``): two feet standing touching, photographed looking down at them,
    were found as one foot straddling both, its side a coin toss (``../shared/real/rafiansyah``: the whole
    region's p(right) 0.49-0.54 on three such photos, its halves' 0.92-1.0 and 0.01-0.04). The halves of one
    foot show the same foot, of one side. None: no such look."""
    two_feet_max_overlap: float = 0.2
    """...the convex hulls of the two halves' joints overlapping on at most this fraction of the smaller one (each
    half's silhouette takes in both feet where they touch: its pixels go to the foot whose joints lie nearer)."""
    same_foot_joints: float = 0.2
    """Two located feet whose joints lie closer than this fraction of the foot's image size S (median over the
    joints; ``cues.trim``) are one foot found twice."""
    min_joints_on_part: float = 3.0
    """A silhouette part is the crop's joints' foot when it holds at least this many of them (summed confidences)."""
    max_border_pixels: int = 12
    """More silhouette pixels than this on the photo's edge near the foot's joints: the foot is cut off."""
    foot_zone_margin: float = 0.15
    """Silhouette pixels on the photo's edge count for ``max_border_pixels`` only within this fraction of the
    foot's 2D length (heel to the farthest toe tip) around the convex hull of its joints: the leg leaving the
    frame (almost every real photo) is no cut-off foot; the toes or the heel on the edge are."""
    edge_margin_px: float = 2.0
    turned_looks: tuple[int, ...] = (1, 3, 2)
    """Where the joints put the foot past the photo's edge (``refusals.cut_off``), the photo is shown to the
    networks again turned this many times 90 deg counter-clockwise, in turn, and the first look that keeps the foot
    in the photo is measured: the networks learnt feet with the leg rising up the image, and a photo taken straight
    down (whose phone cannot tell which way is up) or held sideways shows them the leg across it, the heel under
    the shin read as past the edge (``pipeline.turned_where_needed``). Empty: never turned."""
    turned_min_size_ratio: float = 0.5
    """...where that look's foot is at least this large (its joints' image size, ``cues.trim.foot_axes``) against
    the cut-off one: a foot truly cut by the edge was found whole in one or two of its toes when turned (crops of
    ``../shared/real/a4``: 0.25-0.27, and measured as a foot there; the same foot turned into view: 0.81-1.23)."""
    floor_up_min_tilt_deg: float = 10.0
    """Where a reference object or the depth shows the floor, its up seen at the foot tells which way up the photo
    was taken, unless the line of sight to the foot lies within this of straight down (the training renders'
    cameras stood 10-70 deg from straight above; on the real photos of ``../shared/real/a4`` the floor's up and
    the leg agreed from 10 deg on, and at 4 deg did not) (``pipeline.floor_up_turns``)."""
    floor_up_turn_deg: float | None = 60.0
    """The photo is turned (``pipeline.turned_where_needed``) where the floor's up lies more than this from the
    picture's up: the training renders' roll (SD 5 deg) and augmentation (+-25 deg) stay well inside. None: the
    floor never turns it."""
    straight_down_ankle_up: bool = True
    """Where the floor a reference object or the depth shows is seen straight down (within
    ``floor_up_min_tilt_deg``: its up cannot say which way up the photo is), the feet are taken from the photo
    turned so that the largest foot's ankle lies above its toes (``pipeline.turned_where_needed``): seen straight
    down no view is from the side, the shin rises towards the camera over the heel, and from above the toes the
    networks learnt it up the picture. Real photos of a foot on A4 turned sideways (``benchmarks/bench_repeat.py``)
    were read with the leg across the picture, 30-50 mm off or unscaled, before. False: only the ankle below the
    toes turns such a photo (``upside_down_deg``)."""
    upside_down_deg: float | None = 150.0
    """Where no floor tells which way up the photo is (``floor_up_min_tilt_deg``) and the largest foot's ankle
    lies more than this from straight above its toe tips (``pipeline.leg_angle_deg``), the feet are taken from the
    photo turned 180 deg, where that look sees the ankle below the toes too (``pipeline.turned_where_needed``). On
    the renders the networks learnt from (any side and height, never from behind the heel; 150 of seed 1) the true
    angle is at most 147 deg (95 % below 123); on the 80 real photos looking down at one's own feet
    (``../shared/real/rafiansyah``) the networks' is 145-180, and turned their silhouettes cover the feet, not the
    shins (located-foot IoU 0.418 -> 0.620). None: never turned by this angle (``upside_down_min_confidence_gain``
    may still turn it)."""
    upside_down_min_confidence_gain: float | None = 0.25
    """Where no floor tells which way up the photo is and the rule above does not turn it (the largest foot's
    ankle below its toe tips by less than ``upside_down_deg``, or the turned look finds no foot where the upright
    one's largest lay, or the upright look reads its largest foot the right way up: a shin taken for a foot), the
    feet are still taken from the photo turned 180 deg where that look's surest foot, its ankle below the toes
    back in the photo, has joints placed with a mean confidence at least this much above the upright look's
    largest foot's: the networks place the joints of feet they see as they learnt them more surely. On 180 upright
    renders (``eval measure``'s guided, front and ood views, 60 each, seed 4242) the turned look's largest foot was
    at most 0.17 surer (37 with the ankle below the toes), and on 120 of them (40 each) its surest at most 0.17
    too; on the 80 real photos looking down at one's own feet (``../shared/real/rafiansyah``, the networks' leg
    angle 145-180 deg but for two shins read upright, 12-17 deg) 0.21 surer in the median. None: confidence never
    turns a photo."""
    max_rgb_end_on: float = 0.643
    """RGB photos (no depth) are refused when the fitted foot's long axis points within acos(this) = 50 deg of the
    line of sight: its length is then foreshortened and poorly seen. ``benchmarks/bench_end_on.py`` (refusal off,
    seed 4242), length MAE by the true view angle: 90 flat feet from every side, 0-30 deg 20.9 mm, 30-40 16.5,
    40-50 12.3, 50-60 10.8, 60-90 6-16; 60 from in front of the toes and above (``--views front``, as most real
    photos are taken), 40-50 4.9, 50-60 10.0, 60-70 12.2, 70-80 8.1, 80-90 11.6. No band of plain photos is within
    half a size on these views, so the limit sits where the error stops growing with the angle: at 60 deg it
    refused 28 of the 60 front views, whose errors were those of the views it kept."""
    max_rgbd_end_on: float = 0.766
    """RGB-D photos are refused within acos(this) = 40 deg: depth sees along the line of sight, and the same
    benchmark gives 7.0 / 8.7 mm below 30 / 30-40 deg, 2.2 at 40-50 and 1.5-3.2 beyond (the limit was 50 deg, from
    4 of 7 random views off by 11-28 mm)."""
    max_depth_end_on: float = 0.64
    """Depth maps alone are refused within acos(this) = 50 deg: the far end of the foot hides behind the near one
    and, without the photo's outline, the fit makes it up (the benchmark: 7.7 / 8.5 mm below 30 / 30-40 deg, 4.1
    at 40-50, at the edge of half a size, 1.2-2.7 at 50-80)."""
    joint_sigma_224_px: float = 3.0
    """Expected error of a network's 2D joint, in pixels of its crop resized to 224 px (the networks' mean error
    there is 3-4 px); the fit's joint sigma is this times crop side / 224, in working pixels. Against a fixed 3
    working pixels (crops are 300-700 px, so joints were weighed 1.5-3x too strongly against the silhouette) on
    the guided seed-777 photos: RGB-D length / width MAE 2.44 / 0.85 -> 2.39 / 0.68 mm (bias -1.3 -> -0.4 mm),
    RGB + floor 9.3 -> 7.9 mm (14 and 10 photos); 1.5 was worse."""
    decoder_start_inputs: tuple[str, ...] = ("rgbd",)
    """Inputs whose fit also starts from the shipped mesh decoder's foot (``footmesh.recon``), carried through every
    stage beside the PnP starts. Guided photos, seeds 4242 / 777 (20 each): RGB-D length / width MAE 1.66 / 0.70
    -> 1.26 / 0.67 mm and 1.79 / 0.59 -> 1.76 / 0.57; depth alone 2.50 / 1.14 -> 2.48 / 1.13 and 2.45 / 0.99 ->
    2.49 / 1.11, no gain for the time, so not for depth. Not RGB: its decoder is too far off (62 mm vertex error)."""
    decoder_side_inputs: tuple[str, ...] = ("rgbd", "depth")
    """Inputs whose side (with ``--side auto``) is taken from the shipped mesh decoder's foot when the other side's
    mean foot fits it ``decoder_side_ratio`` times worse (``fit.mesh_side_residuals``); only that side is then
    fitted, about half the fit's work. The nearer side was the true one on 52 of 52 RGB-D photos (guided and
    random; ratios 2.0-24) and 19 of 20 guided depth photos (the wrong one at 1.4, the 17 at 3 or more right).
    Not RGB: its decoder picked the true side on 14 of 20."""
    decoder_side_ratio: float = 3.0
    decoder_kind: str = "ism"
    """Which shipped mesh decoder gives that start and side: ``ism`` (the thesis' spiral decoder) or ``model`` (the
    model-based head, ``recon.parametric``; RGB-D only: its shipped weights are ``rgbd-model.pt``)."""
    cues_side_confidence: float = 0.95
    """With ``--side auto``, the side is the 2D-cues network's (networks with a left/right head) when its probability
    of a right foot is at least this or at most 1 minus this; only that side is then fitted. Below it, the decoder
    or the fit of both sides decides as before. Measured with the shipped RGB network (crops around hand-drawn feet
    of ``../shared/real/rafiansyah``): 52 % of real feet pass 0.95, and 96 % of those have the right side (80.5 % of
    all feet); on the synthetic test split 98 % of all sides are right."""
    pair_side_max_turn_deg: float | None = 100.0
    """With ``--side auto`` and two feet in view, their sides come from where they stand
    (``pipeline.pair_sides``) when their midfoot-to-toes directions in the photo lie within this of each other;
    None: never. Photos looking down at one's own feet show their heel-to-toe directions 55-86 deg apart (their
    splay and the perspective), beyond the 60 deg first tried; 90 deg was then the limit for heel-to-toe
    directions, and a pair's midfoot-to-toes directions splay about 12 deg more (the model foot's toe tips lie
    5.8 deg outward of its midfoot's line from the heel, 2.3 from the heel's)."""
    pair_side_min_lateral: float = 1.0
    """...and the step from one foot to the other is at least this many times more across their toes' direction
    than along it (1.0: within 45 deg of side by side): one foot set before the other says nothing about which is
    which."""
    min_depth_contour_followed: float = 0.85
    """With a depth map, refuse the photo when less of the foot's outline than this lies within 2 px of the fitted
    model's (``FootFit.quality["contour_within_2px"]``). Guided photos, seeds 4242 (60) and 777 (20), RGB-D and
    depth: 0.88-1.0 on the 159 measured within 18 mm, 0.78 on the one fit 80 mm short. Not for plain photos (no
    such separation there)."""
    min_depth_foot_shown: float = 0.75
    """With a depth map, refuse the photo when less of the fitted foot below the ankle than this lies on the foot's
    silhouette (``FootFit.quality["foot_shown"]``): the rest is hidden by the leg or a trouser and the fit makes it up.
    Guided photos, seeds 4242 and 777 (60 each), RGB-D and depth, 236 measured: refuses 9, off by -70, -23, -12,
    -10, -6, -4, -3, -1 and +3 mm; the 227 kept show 0.76-1.0. Plain photos have a lower limit of their own
    (``min_rgb_foot_shown``): without depth the fit shrinks the foot into what shows (0.75-1.0 on all 156 RGB +
    reference fits of seeds 4242, 777 and 999, the 16 off by more than 10 mm at 0.81-0.97)."""
    min_rgb_foot_shown: float = 0.3
    """Without depth, refuse the photo when less of the fitted foot below the ankle than this lies on the foot's
    silhouette: the fit then lies wholly off the foot the photo shows, as when the camera looks down the leg and
    the leg hides all but the toes (an ood render, 0.0: a foot 57 mm short). Every other RGB fit measured shows
    0.47-1.0 (guided seeds 4242, 777, 999, front and ood, 60 photos each: the 0.47 one 33 mm off; the real photos
    of ``../shared/real`` 0.82-1.0). The depth limit above is stricter: without depth the fit shrinks the foot
    into what shows."""
    plausible_length_mm: tuple[float, float] = (185.0, 335.0)
    """A scaled fit whose foot is not this long (5 SD beyond the shape population's women's and men's mean
    lengths, 246.5 +- 12.1 and 271.6 +- 12.7 mm) is wrong: with a reference object the object was something
    else (the cut top of a trouser leg passed as a card: 133 mm short) and the photo is measured unscaled; with
    depth the photo is refused (a fit 80 mm short, guided eval seed 4242). The model knows adult feet only."""
    trim_silhouette: bool = True
    """Cut the networks' silhouette to where their joints say the foot can be (``cues.trim``): the shin and the
    floor beyond it are not foot. Real photos (``../shared/real/rafiansyah``, ``footmesh eval real --measure``): the
    located foot's IoU with the hand-drawn one 0.329 -> 0.343, ``mask.png``'s 0.288 -> 0.318, 73 -> 75 of 80 photos
    answered (the same day, before the far one of two feet was given its own silhouette); renders: nothing cut
    (docs/cues.md)."""
    measured_mask_margin: float = 0.06
    """``mask.png`` and the overlay's outline keep the silhouette's pixels within this fraction of the fitted foot's
    image size of its image below the ankle (``fit.foot_image``): the foot measured, not the shin the network also
    took for foot. On renders 99.9 % of the true foot's pixels below the ankle lie within it (guided, front and ood
    views, 20-30 photos each: 0.03 %, 0.01 % and 0.04 % beyond); real photos (``../shared/real/rafiansyah``,
    ``footmesh eval real --measure``): ``mask.png``'s IoU with the hand-drawn feet 0.379 -> 0.429."""
    refine_silhouette: bool = True
    """Snap the networks' silhouette to the photo's edges (``cues.refine``; needs the RGB image)."""
    floor_from_depth: bool = True
    """With a depth map, fit the foot standing on the floor plane the depth shows around it (``cues.floor``),
    as with a reference object's floor. ``eval measure`` (seed 4242), length MAE without -> with: RGB-D front views
    (the heel behind the shin, 30) 3.51 -> 3.00 mm, guided (60) 1.52 -> 1.20; depth alone front 3.92 -> 2.44 but
    guided 1.72 -> 2.03 (docs/results-history.md)."""
    rgbd_with_depth_network: bool = True
    """With RGB-D, average the RGB-D network's cues with the depth network's (``cues.predict.average_cues``):
    on 20 guided RGB-D photos the RGB-D cues alone gave length / width MAE 4.06 / 1.75 mm, the depth network's
    2.92 / 2.06 mm (measured with ``footmesh eval measure --views guided``; the average: docs/results-history.md)."""
    focal_prior_log_sd: dict[str, float] = field(default_factory=lambda: {"file": 0.0, "exif": 0.1, "default": 0.7})
    """How well the photo's focal length is known, by ``Intrinsics.source`` (SD of its log; 0 = held): with a
    sheet or marker in view, the focal length its perspective gives (``cues.reference.focal``) is weighed
    against it. A guessed one (``default``: a phone's 26 mm-equivalent main camera) is often 2-3x short on real photos
    (the 2x / 3x lens, zoom, crops): the sheets of ``../shared/real/a4`` (no EXIF) give 1.3-3.1x on the three
    seen obliquely enough to tell. EXIF's 35 mm equivalent is right unless the photo was cropped."""
    camera_distance_prior_mm: tuple[float, float] = (550.0, 0.5)
    """Where the focal length is estimated (a guess, or EXIF), the camera's distance from the reference object is
    taken to be log-normal with this median (mm) and SD of its log (``cues.reference.focal.distance_prior_scale``):
    between a phone held crouching over the foot (0.3 m) and one held by a standing person (1-1.2 m); the photo
    guide's views are rendered at 0.3-0.7 m. It decides where the sheet's perspective cannot: a sheet seen nearly
    straight down, as in most real photos."""
    focal_uncertainty_min_log_sd: float = 0.2
    """Where the focal length was estimated to an SD (of its log) of at least this (a guess with the reference's
    perspective; not EXIF's 0.1), the foot is fitted again with it one SD longer and the change enters the
    measurements' uncertainty: one fit more per photo, spent only where the focal length is poorly known."""
    clear_paper: bool = True
    """With a white sheet found, the pixels of the foot's silhouette on it that are of the paper's colour (its
    shadow) are taken out before the fit (``cues.refine.clear_paper``)."""
    flat_refit_upright_robust: float = 1e3
    """A plain photo whose fit lifts the foot off the floor a reference shows (``refusals.heel_hidden``) is
    fitted again with the foot held upright on that floor: the fit's upright term (``FitConfig.upright_robust``)
    then this many sigmas wide, least squares in effect (normally it lets a foot tilted past 0.15 rad go). The
    refusal stands only if that fit fails too."""
    flat_fit_cost_ratio: float | None = 0.8
    """With a reference object's floor, the foot is also fitted held upright on it (as ``flat_refit_upright_robust``)
    and that fit is taken where its final cost is below this fraction of the free fit's: the free fit settled in a
    worse basin (the leg hiding the heel lets it tip the foot), as the held fit's stricter cost is lower still.
    ``footmesh eval measure --modes rgb_ref``, length MAE before -> after: guided 4242 (60) 3.46 -> 3.06 mm, front
    4242 (60) 6.62 -> 6.18, random (40) 13.05 -> 11.40, ood (60) 14.15 -> 13.71, and on the held-out seed 777 (40)
    guided 5.03 -> 4.76, front 7.11 -> 6.84. Between 0.8 and 0.9 the held fit was no better than the free one on
    renders (docs/results-history.md), and a real photo's length moved 26 mm there. None: held only to retry a fit
    that went wrong."""
    standing_max_side_cos: float | None = 0.25
    """With a reference object, a foot whose fit is seen from its front, its back or above (the line of sight to its
    midfoot within acos(this) = 75.5 deg of square to its lateral axis: the profile of its sole out of sight) is
    also fitted standing on the reference's floor: upright, its heel and its ball on the floor
    (``FitConfig.sole_contact``), as a person standing on a sheet for the photo does. Such a photo cannot show
    whether the heel or the ball is lifted, and a fit free to lift one tips the foot along the line of sight: on
    the seven real A4 photos the fits stood their toe tips 40-130 mm or their heels 55-145 mm above the sheet.
    ``footmesh eval measure --modes rgb_ref``, length MAE: front 4242 6.18 -> 5.95 mm, front 777 6.84 -> 6.20,
    guided 4242 and 777 unchanged (side views), random 11.40 -> 11.54, ood 13.71 -> 13.05 (docs/measure.md step
    4). None: never."""
    standing_max_cost_ratio: float = 1.5
    """... and that fit is taken unless its final cost is above this many times the other's: where holding the
    foot down explains the photo far worse, it was not standing (feet lifted off the floor cost 3-8x more)."""
    standing_full_starts: int = 4
    """The standing fit carries this many of its best starts through every stage (``FitConfig.full_starts``; 2 for
    the other fits). Held on the floor the foot can settle in a basin that explains the photo twice as badly: on the
    real A4 photo of a man's foot ``arshoe_barefeet_4`` with its joints moved 1 px at random six times, 2 starts
    ended at cost 199-205 and 212-217 mm; 4 starts took four of the six to cost 77-174 and 224-242 mm, like photo
    ``_3`` of the same foot (``fit_foot`` from the pipeline's cues; more than 4 starts found nothing better).
    Front renders, seeds 4242 / 777: length MAE 5.95 / 6.20 -> 5.76 / 6.05 mm, the fit stage 1.16 -> 1.19 s
    median; random and ood renders alike (11.54 -> 11.47, 13.05 -> 13.08); guided views do not take it."""
    max_reference_separation: float = 3.0
    """A reference object is put beside the foot (the photo guide; the renders place it 110-460 mm from the foot's
    centre): one whose floor puts the fitted foot's centre more than this many foot lengths from the object's is
    something else far off (single tile cells 1.0-1.3 m from the foot passed as a card or sheet) and is ignored."""
    max_model_outside: float = 0.25
    """Refuse the photo when more than this fraction of the fitted model's visible vertices fall more than 2 px
    outside the foot's silhouette (``FootFit.quality``): the fit went wrong and its millimetres would be too. Good
    fits on the synthetic eval: 0.01-0.08; the gross failures (50-140 mm off): 0.5-0.9."""
    uncertainty_factor: dict[str, float] = field(
        default_factory=lambda: {"depth": 0.80, **{kind: 1.35 for kind in references.NAMES}}
    )
    """Calibration of the fit's covariance-based SD per scale source: the old factor times the 68th percentile of
    |error| / uncertainty over length and ball width on ``footmesh eval measure --views guided --seed 777 --n 60``
    (0.879 over 224 depth errors, RGB-D and depth alone: 1.04 -> 0.91; 0.888 over 114 with a reference object:
    1.56 -> 1.39; re-measured with the fine-tuned 2D-cues networks), so that about 68 % of true errors fall within
    one uncertainty; checked on the seed-4242 photos in docs/results-history.md. With the cost's variance factor
    (``uncertainty_loss_reference``, 2026-12-06): 0.968 over 114 with a reference object, 1.39 -> 1.35; 0.880 over
    226 depth errors (RGB-D 0.867, depth alone 0.888; RGB-D alone was 0.854 before the variance factor too: the
    factor had drifted since it was set), 0.91 -> 0.80."""
    uncertainty_loss_reference: dict[str, float] = field(
        default_factory=lambda: {"depth": 30.3, **{kind: 11.1 for kind in references.NAMES}}
    )
    """The fit's covariance assumes its residuals as small as on a typical calibration photo; it is scaled by
    sqrt(final cost / this), per scale source, as a least-squares fit's covariance is by its residuals' variance
    factor (the median ``FootFit.loss`` on ``footmesh eval measure --views guided --seed 777 --n 60``: RGB + reference
    11.1, RGB-D 30.3). There the length error grew with the cost (RGB + reference, thirds by cost: mean 1.9 / 4.3 /
    7.0 mm) while the unscaled uncertainty did not (4.9 / 4.6 / 4.5 mm); real photos fit with costs of 37-200."""
    uncertainty_floor_mm: float = 0.5
    length_advice_mm: float | None = HALF_SIZE_MM
    """A result whose length is known only to more than this (+- one uncertainty; half a UK or US shoe size, 1/6
    inch = 4.23 mm) says so in its messages and which photos would narrow it (``sizes.length_advice``): one photo
    then does not tell the size to half a size (the seven real A4 photos: +- 10.8-24.9 mm, the heel hidden under
    the shin). None: never said."""

    def held_fit(self, fit_config: FitConfig, hold: Literal["upright", "standing"] | None) -> FitConfig:
        """``fit_config`` for a fit held on the floor: "upright" (``flat_refit_upright_robust``), "standing"
        (upright, its heel and its ball on the floor, ``standing_full_starts`` starts carried to the end), or as it
        is (None)."""
        if hold is not None:
            fit_config = replace(fit_config, upright_robust=self.flat_refit_upright_robust)
        if hold == "standing":
            fit_config = replace(fit_config, sole_contact=True, full_starts=self.standing_full_starts)
        return fit_config

    def __post_init__(self) -> None:
        if self.decoder_kind not in DECODER_KINDS:
            raise ValueError(f"decoder_kind must be one of {DECODER_KINDS}, got {self.decoder_kind!r}")
