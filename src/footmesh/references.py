"""The reference objects that give a plain photo its millimetres: one entry each, read by every stage.

The detector (``cues.reference``), the renderer (``synth.scene``, ``synth.textures``), the pipeline's messages
and refusals, the measurement configuration, the CLI and the evaluation all take the kinds, their sizes, looks
and detectors from ``KINDS``. Adding a kind = one ``ReferenceKind`` entry (and, when none of the detectors
``sheet``, ``card`` or ``marker`` finds it, a detector in ``cues.reference``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

DETECTORS = ("sheet", "card", "marker")
"""How ``cues.reference`` finds a kind: ``sheet`` (a large bright rectangle of paper; it may bow, lie under the
foot and be completed from three sides), ``card`` (a small rigid rectangle of any colour beside the foot),
``marker`` (a printed ArUco square, decoded)."""
LOOKS = ("paper", "card", "marker")
"""How the renderer draws a kind (``synth.kernels.reference_texture``'s look 1, 2, 3)."""


@dataclass(frozen=True)
class ReferenceKind:
    """One kind of reference object."""

    name: str
    """Its word in the CLI, ``result.json`` (``scale_source``, ``reference.kind``) and the datasets."""
    described: str
    """In messages: "an A4 sheet"."""
    size_mm: tuple[float, float]
    """Length x width (mm) of the rectangle whose corners are found and stored."""
    size_tolerance_mm: float
    """Half-width of its manufacturing tolerance on the length: its true size is uniform within it."""
    detector: str
    """One of ``DETECTORS``."""
    preference: int
    """When several kinds are found in one photo, the lowest wins."""
    min_coverage: tuple[float, float]
    """Each side must show its edge along the first fraction of its length at least, the four together along the
    second (``cues.reference``: a sheet may lie under the foot, a card lies beside it, a marker is proven by its
    decoded pattern)."""
    dataset_id: int
    """``ref_type`` of the synthetic datasets (0 is none; never reuse a number)."""
    look: str
    """One of ``LOOKS``."""
    synth_share: float
    """Share of the samples of a ``--reference mixed`` dataset that show it."""
    margin_mm: float = 0.0
    """Drawn (white) margin around the stored rectangle: the printed sheet around a marker's square."""
    calibrates_focal: bool = True
    """Found in a photo whose focal length is a guess, its perspective may correct it (``cues.reference.focal``).
    Not a card: small (its corners fix the focal length poorly) and of any print, so with the focal length free
    single tile cells of patterned floors passed as cards (7 of the 80 photos of ``../shared/real/rafiansyah``)."""

    @property
    def named(self) -> str:
        """In messages, once found: "the A4 sheet" (``described`` with the definite article)."""
        return "the " + self.described.split(" ", 1)[1]

    @property
    def aspect(self) -> float:
        """Length over width."""
        return self.size_mm[0] / self.size_mm[1]

    @property
    def size_rel_sd(self) -> float:
        """Relative SD of its true size (uniform within the tolerance)."""
        return self.size_tolerance_mm / self.size_mm[0] / math.sqrt(3.0)

    def __post_init__(self) -> None:
        if self.detector not in DETECTORS or self.look not in LOOKS:
            raise ValueError(f"{self.name}: detector must be one of {DETECTORS}, look one of {LOOKS}")


KINDS: tuple[ReferenceKind, ...] = (
    ReferenceKind(
        "a4",
        "an A4 sheet",
        (297.0, 210.0),  # ISO 216
        size_tolerance_mm=2.0,  # ISO 216: +-2 mm
        detector="sheet",
        preference=1,
        min_coverage=(0.1, 0.4),
        dataset_id=1,
        look="paper",
        synth_share=0.35,
    ),
    ReferenceKind(
        "card",
        "a bank card",
        (85.60, 53.98),  # ISO/IEC 7810 ID-1
        size_tolerance_mm=0.125,  # ISO/IEC 7810: 85.47-85.72 mm
        detector="card",
        preference=3,
        min_coverage=(0.6, 0.8),
        dataset_id=2,
        look="card",
        synth_share=0.2,
        calibrates_focal=False,
    ),
    ReferenceKind(
        "marker",
        "the printed marker",
        (100.0, 100.0),  # the printed black square of the marker
        size_tolerance_mm=0.5,  # a printer at "100 %", checked with a ruler: +-0.5 %
        detector="marker",
        preference=0,
        min_coverage=(0.3, 0.6),
        dataset_id=3,
        look="marker",
        synth_share=0.2,
        margin_mm=20.0,
    ),
    ReferenceKind(
        "letter",
        "a US letter sheet",
        (279.4, 215.9),  # 11 x 8.5 in (ANSI/ASME Y14.1 size A)
        size_tolerance_mm=2.0,  # taken as A4's (no tolerance for it was looked up)
        detector="sheet",
        preference=2,  # after A4: a sheet whose proportions are not seen whole is taken to be A4
        min_coverage=(0.1, 0.4),
        dataset_id=4,
        look="paper",
        synth_share=0.0,  # the mixed datasets (and the networks trained on them) were made before it
    ),
)
"""Every kind, in dataset order (the synthetic datasets' random draws follow this order)."""

NAMES: tuple[str, ...] = tuple(k.name for k in KINDS)
BY_NAME: dict[str, ReferenceKind] = {k.name: k for k in KINDS}
BY_PREFERENCE: tuple[str, ...] = tuple(k.name for k in sorted(KINDS, key=lambda k: k.preference))
"""The names, most convincing first: a marker is unambiguous, a sheet is large, a card is small."""


def kind(name: str) -> ReferenceKind:
    """The kind called ``name`` (ValueError naming the kinds for any other)."""
    try:
        return BY_NAME[name]
    except KeyError:
        raise ValueError(f"unknown reference object {name!r}; one of {', '.join(NAMES)}") from None


def with_detector(detector: str, names: tuple[str, ...] | list[str] = NAMES) -> list[str]:
    """The kinds among ``names`` that ``detector`` finds, most preferred first."""
    return [n for n in BY_PREFERENCE if n in names and BY_NAME[n].detector == detector]


def described_choices() -> str:
    """ "an A4 sheet, a bank card or the printed marker": every kind, for a message saying what to put down."""
    words = [k.described for k in KINDS]
    return f"{', '.join(words[:-1])} or {words[-1]}"
