"""Reference objects on the floor (``footmesh.cues.reference``): found in rendered scenes with known truth, their
corners, kind and floor plane in millimetres; nothing where there is no object or a rectangle of the wrong shape."""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
import pytest

from footmesh import references
from footmesh.cues.reference import SIZES_MM, ReferenceObject, detect_reference, search_reference
from footmesh.cues.reference import quads as quad_tests
from footmesh.cues.reference.finish import _named_sheet
from footmesh.synth.render import Renderer
from footmesh.synth.scene import REFERENCE_KINDS, SynthConfig, guided_view_config, view_config

SIZE = 480
SEED = 31
MAX_CORNER_PX = 1.5
"""Largest error of a visible corner (px of a SIZE image)."""
MAX_DISTANCE_REL = 0.01
"""Largest relative error of the camera-to-floor and camera-to-object distances."""


@functools.cache
def _renderer(kind: str) -> Renderer:
    return Renderer(SynthConfig(size=SIZE, reference=kind))


@functools.cache
def _sample(kind: str, index: int) -> dict:
    return _renderer(kind).render(SEED, index)


def _scenes(kind: str, want: int, wanted=None, limit: int = 16) -> list[dict]:
    """The first ``want`` samples of ``kind`` that ``wanted(sample, scene)`` accepts (default: the whole object
    in view), searched among ``limit``."""
    if wanted is None:

        def wanted(sample, scene):
            return bool(np.all(sample["ref_corners_visible"]))

    found = []
    for i in range(limit):
        sample = _sample(kind, i)
        if wanted(sample, _renderer(kind).scene(SEED, i)):
            found.append(sample)
            if len(found) == want:
                return found
    pytest.fail(f"only {len(found)} of {want} wanted {kind} scenes among the first {limit} (seed {SEED})")


def _foot_and_leg(sample: dict) -> np.ndarray:
    return (sample["labels"] == 1) | (sample["labels"] == 2)


def _corner_error(obj: ReferenceObject, sample: dict) -> np.ndarray:
    """(4,) px error of each corner; a sheet or card may start at either end of its length (the same rectangle
    turned half a turn), a marker only where its pattern says."""
    truth = sample["ref_corners2d"].astype(np.float64)
    shifts = (0,) if obj.kind == "marker" else (0, 2)
    return min((np.linalg.norm(np.roll(obj.corners_px, s, axis=0) - truth, axis=1) for s in shifts), key=np.max)


def _truth_distances(sample: dict) -> tuple[float, float]:
    """True camera-to-floor and camera-to-object-centre distances (mm)."""
    cam = sample["cam_from_scene"]
    floor = float(-cam[:3, 2] @ cam[:3, 3])
    return floor, float(np.linalg.norm(sample["ref_corners3d"].astype(np.float64).mean(axis=0)))


def _check_found(obj: ReferenceObject | None, sample: dict, kind: str) -> None:
    assert obj is not None, f"no {kind} found"
    assert obj.kind == kind
    assert obj.size_mm == SIZES_MM[kind]
    visible = sample["ref_corners_visible"]
    error = _corner_error(obj, sample)
    assert error[visible].max() < MAX_CORNER_PX, f"corner errors {error.round(2)} px (visible {visible})"
    floor, centre = _truth_distances(sample)
    assert obj.floor_distance_mm == pytest.approx(floor, rel=MAX_DISTANCE_REL)
    assert obj.object_distance_mm == pytest.approx(centre, rel=MAX_DISTANCE_REL)
    # the floor's z points up out of the floor, towards the camera: along the scene's up axis
    up = sample["cam_from_scene"][:3, 2]
    assert math.degrees(math.acos(min(1.0, float(obj.floor_normal @ up)))) < 2.0
    assert 0 < obj.fit_rel_sd <= obj.scale_rel_sd < 0.03
    assert 0 <= obj.reprojection_px < 1.0


@pytest.mark.parametrize("kind", references.NAMES)
def test_whole_object_gives_corners_and_floor_plane(kind):
    for sample in _scenes(kind, 2):
        _check_found(detect_reference(sample["rgb"], sample["K"]), sample, kind)


@pytest.mark.parametrize("index", [8, 17])
def test_marker_beside_a_foot_in_guided_photos(index):
    """Two guided photos of the evaluation (seed 777) whose marker was once missed: the foot's shadow over half
    of a side (8), and OpenCV's corners of a large marker half a cell inside its outline, out of the first
    search's reach (17)."""
    sample = Renderer(guided_view_config(size=640, reference="marker")).render(777, index)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "marker")


def test_floor_frame_is_the_objects():
    """``cam_from_floor`` puts the rectangle's corners, in local order, where the camera sees them; floor points
    come back where they lie on the object."""
    sample = _scenes("marker", 1)[0]
    obj = detect_reference(sample["rgb"], sample["K"])
    length, width = obj.size_mm
    local = np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]], dtype=np.float64)
    cam = local @ obj.cam_from_floor[:3, :3].T + obj.cam_from_floor[:3, 3]
    truth = sample["ref_corners3d"].astype(np.float64)
    assert np.linalg.norm(cam - truth, axis=1).max() < MAX_DISTANCE_REL * np.linalg.norm(truth, axis=1).min()
    projected = cam @ sample["K"].T
    np.testing.assert_allclose(projected[:, :2] / projected[:, 2:], obj.corners_px, atol=1.0)
    on_floor = obj.floor_points(sample["ref_corners2d"], sample["K"])
    np.testing.assert_allclose(on_floor, local, atol=1.0)
    assert np.isnan(obj.floor_points(np.array([[sample["K"][0, 2], -1e6]]), sample["K"])).all()  # above the horizon


@pytest.mark.parametrize("kind", ["a4", "card"])
@pytest.mark.parametrize("light", [(1.2, 0.92, 0.65), (0.85, 1.0, 1.2)], ids=["warm", "cool"])
def test_an_object_under_coloured_light_is_found_as_under_white(kind, light):
    """Indoor lamps leave a photo orange, shade blue: a white sheet is then no longer grey, nor its edges the
    colour steps they were; the search white-balances the photo first (``quads.white_balanced``)."""
    for sample in _scenes(kind, 2):
        lit = np.clip(sample["rgb"].astype(np.float32) * np.array(light, np.float32), 0, 255).astype(np.uint8)
        _check_found(detect_reference(lit, sample["K"], exclude_mask=_foot_and_leg(sample)), sample, kind)


def test_white_balance_greys_the_brightest_surface_and_keeps_the_rest_in_proportion():
    rng = np.random.default_rng(0)
    image = rng.uniform(0.1, 0.5, (64, 64, 3)).astype(np.float32)
    image[20:40, 20:40] = 0.9  # white paper
    light = np.array([1.0, 0.85, 0.6], np.float32)
    balanced = quad_tests.white_balanced(image * light)
    np.testing.assert_allclose(balanced[30, 30], [0.9, 0.9, 0.9], rtol=1e-5)
    np.testing.assert_allclose(balanced[5, 5], image[5, 5], rtol=1e-5)
    # a brightest patch of strong colour is not taken for the light: no channel gains more than MAX_WHITE_GAIN
    yellow = image.copy()
    yellow[20:40, 20:40] = [0.9, 0.85, 0.2]
    assert (quad_tests.white_balanced(yellow) / yellow).max() <= quad_tests.MAX_WHITE_GAIN + 1e-6
    # the foot masked out does not count: its lit skin is no white
    skin = image.copy()
    skin[0:10, 0:64] = [0.98, 0.75, 0.6]
    valid = np.ones((64, 64), bool)
    valid[0:10] = False
    np.testing.assert_allclose(quad_tests.white_balanced(skin, valid)[30, 30], [0.9, 0.9, 0.9], rtol=1e-5)


def test_foot_standing_on_the_sheet():
    """The foot hides part of the sheet (and maybe a corner): the sides it leaves in view still give the sheet,
    with or without the foot's mask."""

    def under(sample, scene):
        return scene.reference.under_foot and int(sample["ref_corners_visible"].sum()) >= 3

    sample = _scenes("a4", 1, under, limit=24)[0]
    for mask in (None, _foot_and_leg(sample)):
        _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=mask), sample, "a4")


def test_a_sheet_stood_on_that_shows_little_of_its_far_side():
    """A guided photo (seed 999, 36) whose sheet was missed: the foot on it leaves little of its far side in view
    (``MIN_COVERAGE``)."""
    sample = Renderer(guided_view_config(size=640, reference="a4")).render(999, 36)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "a4")


def test_a_card_in_line_with_a_plank_seam():
    """A guided photo (seed 999, 4): a seam of the planks runs on from a corner of the card in line with its short
    side; one such line does not make the card a piece of the floor's pattern (``MIN_CONTINUATIONS``)."""
    sample = Renderer(guided_view_config(size=640, reference="card")).render(999, 4)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "card")


def test_a_sheet_stood_on_from_in_front_of_the_toes_with_the_shin_across_it_and_a_shadow_over_a_corner():
    """A front view of the eval (seed 4242, 15), as most real photos of a foot on a sheet are taken: the foot and
    the shin cut the sheet's white region in two pieces and the leg's shadow darkens a corner, so the pieces fill
    less than half of their hull (``MIN_PIECES_FILL``); all four corners are in view."""
    sample = Renderer(view_config("front", size=640, reference="a4")).render(4242, 15)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "a4")


def test_a_sheet_stood_on_with_the_legs_shadow_over_a_whole_side():
    """A front view (seed 4342, 6): the leg's shadow lies over one side of the sheet, darkening the paper inside it
    and the floor beyond it alike (``SHADOW_MAX_BRIGHTNESS``): that side still parts the paper from the floor."""
    sample = Renderer(view_config("front", size=640, reference="a4")).render(4342, 6)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "a4")


def test_a_green_card_touching_a_white_grout_line():
    """An ood view of the eval (seed 4242, 1): a green card on dark tiles with a white grout line touching a
    corner, which every channel's threshold joins to it; its chroma does not."""
    sample = Renderer(view_config("ood", size=640, reference="card")).render(4242, 1)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude), sample, "card")


def test_no_object_no_reference():
    for sample in _scenes("none", 3, lambda sample, scene: True):
        assert int(sample["ref_type"]) == REFERENCE_KINDS.index("none")
        assert detect_reference(sample["rgb"], sample["K"]) is None
        assert detect_reference(sample["rgb"], sample["K"], exclude_mask=_foot_and_leg(sample)) is None


def test_a_bright_blob_with_no_straight_sides_is_no_sheet():
    """The cut top of a rendered leg (a bright ellipse) once passed as an A4 sheet with a hidden corner completed,
    and a plain photo got millimetres from it: a completion needs every side's edge where the side is seen."""
    from footmesh.eval.measure import MODES
    from footmesh.synth.scene import guided_view_config

    sample = Renderer(guided_view_config(size=640, reference="none")).render(4242 + MODES.index("rgb"), 4)
    foot = cv2.dilate((sample["labels"] == 1).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    assert detect_reference(sample["rgb"], sample["K"], exclude_mask=foot) is None


def test_the_foots_lit_skin_is_no_sheet_when_searched_again_without_the_mask():
    """Nothing found with the foot's mask, the search runs again without it (real masks spread over the sheet); the
    lit forefoot with the floor around its toes then once passed as an A4 sheet: what the mask leaves of a sheet
    must be paper."""
    from footmesh.eval.measure import MODES
    from footmesh.synth.scene import guided_view_config

    sample = Renderer(guided_view_config(size=640, reference="none")).render(4242 + MODES.index("rgb"), 17)
    for mask in (_foot_and_leg(sample), cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15))) > 0):
        assert detect_reference(sample["rgb"], sample["K"], exclude_mask=mask) is None


def test_a_sheet_under_a_mask_spread_over_it_is_found_and_a_missed_one_says_why():
    """Where the silhouette network's mask spreads over half the sheet, hiding two of its sides, the sheet is still
    found (searched again without the mask); a sheet cut by the photo's edge is refused with its reason."""
    sample = _scenes("a4", 1)[0]
    corners = sample["ref_corners2d"].astype(np.float64)
    spread = _foot_and_leg(sample).copy()
    left = int(np.median(corners[:, 0]))
    spread[:, : left + 2] = True  # and everything left of the sheet's middle: two sides and two corners
    _check_found(detect_reference(sample["rgb"], sample["K"], exclude_mask=spread), sample, "a4")

    cut = sample["rgb"][:, : int(corners[:, 0].max()) - 20].copy()  # the sheet's right side beyond the border
    searched = search_reference(cut, sample["K"])
    assert searched.found is None or searched.found.kind != "a4"
    if searched.found is None:
        assert searched.rejected and 0.0 < searched.rejected_area < 1.0


def test_a_square_of_a_tiled_pattern_is_not_blank_inside():
    """A tiled floor's pattern makes light squares whose straight sides pass every test of a sheet's sides; what
    tells them from a sheet is the inside: blank paper, or a pattern (``_blank_inside``, 12 -> 8 false sheets on
    the 80 real photos of patterned floors in ../shared/real/rafiansyah)."""
    from footmesh.cues.reference.sides import _blank_inside, _fit_sides

    image = np.full((200, 260, 3), 0.4, np.float32)
    quad = np.array([[40.0, 40.0], [40.0, 160.0], [220.0, 160.0], [220.0, 40.0]])  # canonical order
    cv2.fillPoly(image, [quad.astype(np.int32)], (0.9, 0.9, 0.9))
    valid = np.ones(image.shape[:2], bool)
    blurred = cv2.GaussianBlur(image, (0, 0), 0.75)
    lines = _fit_sides(quad, blurred, valid, 3.0)
    assert _blank_inside(quad, lines, valid, blurred)
    patterned = image.copy()
    for x in range(45, 215, 24):  # dark tiles over most of the light square
        cv2.rectangle(patterned, (x, 60), (x + 22, 140), (0.25, 0.25, 0.25), -1)
    assert not _blank_inside(quad, lines, valid, cv2.GaussianBlur(patterned, (0, 0), 0.75))
    valid[:, :150] = False  # the foot's mask over the patterned half: the rest decides
    patterned[:, 150:] = image[:, 150:]
    assert _blank_inside(quad, lines, valid, cv2.GaussianBlur(patterned, (0, 0), 0.75))


def test_a_shadow_on_a_sheet_is_blank_but_a_sparse_pattern_is_not():
    """Mostly light, yet not blank: a sparse pattern of small dark squares (a tile's print) is many separate blobs,
    a shadow over the sheet one or two (``MAX_INSIDE_BLOBS``)."""
    from footmesh.cues.reference.params import MAX_INSIDE_BLOBS
    from footmesh.cues.reference.sides import _blank_inside, _fit_sides

    image = np.full((200, 260, 3), 0.4, np.float32)
    quad = np.array([[40.0, 40.0], [40.0, 160.0], [220.0, 160.0], [220.0, 40.0]])
    cv2.fillPoly(image, [quad.astype(np.int32)], (0.9, 0.9, 0.9))
    valid = np.ones(image.shape[:2], bool)
    lines = _fit_sides(quad, cv2.GaussianBlur(image, (0, 0), 0.75), valid, 3.0)
    shadow = image.copy()
    cv2.circle(shadow, (120, 150), 45, (0.55, 0.55, 0.55), -1)  # the leg's shadow over one side
    shadow[:40], shadow[160:], shadow[:, :40], shadow[:, 220:] = 0.4, 0.4, 0.4, 0.4
    assert _blank_inside(quad, lines, valid, cv2.GaussianBlur(shadow, (0, 0), 0.75))
    sparse = image.copy()
    for i, (x, y) in enumerate((x, y) for x in range(55, 205, 30) for y in range(55, 150, 30)):
        if i % 2 == 0:  # a light tile with a few dark squares: 80 % stays paper
            cv2.rectangle(sparse, (x, y), (x + 10, y + 10), (0.25, 0.25, 0.25), -1)
    blurred = cv2.GaussianBlur(sparse, (0, 0), 0.75)
    assert MAX_INSIDE_BLOBS < 10 and not _blank_inside(quad, lines, valid, blurred)


def test_the_pieces_of_a_foot_around_its_mask_are_one_blob():
    """A close-up's mask covers only the foot's middle: the instep above it and the toes below it show as
    separate pieces, which with a shadow made a sheet "not blank inside" (a real crop of ``arshoe_barefeet_3``);
    pieces touching the mask are one object with it. A pattern away from the mask still counts blob by blob."""
    from footmesh.cues.reference.sides import _blank_inside, _fit_sides

    image = np.full((200, 260, 3), 0.4, np.float32)
    quad = np.array([[40.0, 40.0], [40.0, 160.0], [220.0, 160.0], [220.0, 40.0]])
    cv2.fillPoly(image, [quad.astype(np.int32)], (0.9, 0.9, 0.9))
    skin = (0.75, 0.55, 0.45)
    cv2.rectangle(image, (95, 50), (135, 100), skin, -1)  # the instep
    for x in (92, 108, 124, 140):  # four toes
        cv2.circle(image, (x, 118), 6, skin, -1)
    cv2.circle(image, (190, 140), 15, (0.6, 0.6, 0.6), -1)  # a shadow
    valid = np.ones(image.shape[:2], bool)
    lines = _fit_sides(quad, cv2.GaussianBlur(image, (0, 0), 0.75), valid, 3.0)
    valid[95:112, 80:150] = False  # the mask: a band across the foot, between the instep and the toes
    blurred = cv2.GaussianBlur(image, (0, 0), 0.75)
    assert _blank_inside(quad, lines, valid, blurred)
    apart = valid.copy()
    apart[95:112, 80:150] = True
    apart[60:75, 150:170] = False  # the same mask moved off the foot: the instep, four toes and the shadow
    assert not _blank_inside(quad, lines, apart, blurred)


def test_only_the_kinds_asked_for():
    """A card is never reported as a sheet (nor a sheet as a card); asking for it alone still finds it."""
    card = _scenes("card", 1)[0]
    assert detect_reference(card["rgb"], card["K"], kinds=("a4", "marker")) is None
    assert detect_reference(card["rgb"], card["K"], kinds=("card",)).kind == "card"
    sheet = _scenes("a4", 1)[0]
    assert detect_reference(sheet["rgb"], sheet["K"], kinds=("card",)) is None


def test_mirrored_photo_of_a_marker():
    """A photo flipped left to right (a mirrored selfie) shows a mirrored marker: still read, and it gives the
    same floor distance; the corners are the flipped ones, their order keeps the floor's z towards the camera."""
    sample = _scenes("marker", 1)[0]
    direct = detect_reference(sample["rgb"], sample["K"])
    flipped_k = sample["K"].copy()
    flipped_k[0, 2] = (SIZE - 1) - flipped_k[0, 2]
    mirror = detect_reference(np.ascontiguousarray(sample["rgb"][:, ::-1]), flipped_k)
    assert mirror is not None and mirror.kind == "marker" and mirror.mirrored != direct.mirrored
    assert mirror.floor_distance_mm == pytest.approx(direct.floor_distance_mm, rel=0.005)
    flipped = sample["ref_corners2d"].astype(np.float64) * [-1, 1] + [SIZE - 1, 0]
    nearest = np.linalg.norm(mirror.corners_px[:, None] - flipped[None], axis=2).min(axis=1)
    assert nearest.max() < MAX_CORNER_PX
    assert mirror.floor_normal @ mirror.cam_from_floor[:3, 3] < 0


def _drawn_rectangle(length: float, width: float, tilt_deg: float = 40.0, size: int = 320) -> tuple:
    """A white rectangle (mm) lying on a plain grey floor seen by a pinhole camera, drawn at 4x and averaged down
    (anti-aliased): (rgb (size, size, 3) uint8, K, true corners (4, 2) px)."""
    f = 0.9 * size
    K = np.array([[f, 0, (size - 1) / 2], [0, f, (size - 1) / 2], [0, 0, 1.0]])
    t = math.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, -math.cos(t), -math.sin(t)], [0, math.sin(t), -math.cos(t)]])  # floor -> camera
    centre = np.array([10.0, -5.0, 700.0])
    local = np.array([[0, 0, 0], [length, 0, 0], [length, width, 0], [0, width, 0]]) - [length / 2, width / 2, 0]
    cam = local @ rot.T + centre
    px = cam @ K.T
    corners = px[:, :2] / px[:, 2:]
    big = np.full((4 * size, 4 * size, 3), (90, 95, 100), np.uint8)
    cv2.fillConvexPoly(
        big, np.round((corners + 0.5) * 4 * 16 - 0.5 * 16).astype(np.int32), (245, 245, 240), cv2.LINE_8, 4
    )
    rgb = cv2.resize(big, (size, size), interpolation=cv2.INTER_AREA)
    return rgb, K, corners


def test_metric_shape_names_the_object():
    """A white rectangle of A4's proportions is an A4 sheet, of a card's a card; one of neither (4:3, 2:1, a
    square) is nothing, however it is foreshortened in the image."""
    rgb, K, corners = _drawn_rectangle(*SIZES_MM["a4"])
    obj = detect_reference(rgb, K)
    assert obj is not None and obj.kind == "a4"
    nearest = np.linalg.norm(obj.corners_px[:, None] - corners[None], axis=2).min(axis=1)
    assert nearest.max() < 0.5
    assert obj.object_distance_mm == pytest.approx(np.linalg.norm([10.0, -5.0, 700.0]), rel=0.005)
    rgb, K, _ = _drawn_rectangle(*SIZES_MM["card"], tilt_deg=20.0)
    assert detect_reference(rgb, K).kind == "card"
    rgb, K, _ = _drawn_rectangle(*SIZES_MM["letter"])
    assert detect_reference(rgb, K).kind == "letter"
    for length, width in ((250.0, 210.0), (300.0, 150.0), (200.0, 200.0)):
        rgb, K, _ = _drawn_rectangle(length, width)
        assert detect_reference(rgb, K) is None, (length, width)


def test_a_sheet_is_named_by_its_side_ratio_and_the_preferred_one_where_the_photo_cannot_rule_it_out():
    """A4 (1.414) and letter (1.294) are told apart by the measured side ratio; where A4 lies within 3 SD of it
    but outside its tolerance, the sheet is neither, and the reason says so."""
    both = ["a4", "letter"]
    assert _named_sheet(1.294, 0.005, 0.045, both) == ("letter", None)
    assert _named_sheet(1.0 / 1.294, 0.005, 0.045, both) == ("letter", None)  # seen the other way up
    assert _named_sheet(1.414, 0.005, 0.045, both) == ("a4", None)
    assert _named_sheet(1.36, 0.02, 0.045, both) == ("a4", None)  # within A4's tolerance: as before letter
    assert _named_sheet(1.33, 0.005, 0.045, both) == ("letter", None)
    kind, why = _named_sheet(1.33, 0.025, 0.045, both)
    assert kind is None and "lies between an A4 sheet's 1.414 and a US letter sheet's 1.294" in why
    assert _named_sheet(1.36, 0.02, 0.045, ["letter"]) == (None, None)  # letter alone: too far from it


def test_a_letter_sheet_with_a_hidden_corner_is_taken_as_a4_unless_letter_is_named():
    """A front view (seed 4242, 18) of a foot on a letter sheet, its far side under the foot, its focal length
    known as EXIF's is: the three sides left cannot show its proportions, so searched for any kind it is completed
    as the preferred sheet, A4, and says so (``kind_assumed``); named by the user, it is found as letter, at the
    true distance."""
    sample = Renderer(view_config("front", size=640, reference="letter")).render(4242, 18)
    exclude = cv2.dilate(_foot_and_leg(sample).astype(np.uint8), np.ones((15, 15), np.uint8)) > 0
    _, centre = _truth_distances(sample)
    anything = detect_reference(sample["rgb"], sample["K"], exclude_mask=exclude, focal_prior_log_sd=0.1)
    assert anything.kind == "a4" and anything.kind_assumed
    named = detect_reference(sample["rgb"], sample["K"], ("letter",), exclude, focal_prior_log_sd=0.1)
    assert named.kind == "letter"
    assert named.object_distance_mm == pytest.approx(centre, rel=MAX_DISTANCE_REL)


def test_one_quad_shape_tests_agree_with_the_vectorised_ones():
    """``_parallelogram`` and ``_canonical`` (plain floats, for speed) give what their vectorised versions give."""
    rng = np.random.default_rng(5)
    K = np.array([[800.0, 1.5, 320.0], [0.0, 810.0, 240.0], [0.0, 0.0, 1.0]])
    quads = rng.uniform(0.0, 640.0, (3000, 4, 2))
    ratio, angle, depths, good = quad_tests._parallelogram_many(quads, K)
    canonical = quad_tests._canonical_many(quads)
    for i, quad in enumerate(quads):
        one = quad_tests._parallelogram(quad, K)
        assert (one is not None) == good[i]
        if one is not None:
            assert one[0] == pytest.approx(ratio[i], rel=1e-9) and one[1] == pytest.approx(angle[i], abs=1e-7)
            np.testing.assert_allclose(one[2], depths[i], rtol=1e-9)
        c = quad_tests._canonical(quad)
        assert (c is None) == bool(np.isnan(canonical[i]).any())
        if c is not None:
            np.testing.assert_array_equal(c, canonical[i])


def test_bad_input_is_refused_clearly():
    image = np.zeros((100, 100, 3), np.uint8)
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    with pytest.raises(ValueError, match="K must be the"):
        detect_reference(image, np.eye(2))
    with pytest.raises(ValueError, match="colour image"):
        detect_reference(image[..., 0], K)
    with pytest.raises(ValueError, match="colour image"):
        detect_reference(np.zeros((100, 100, 4), np.uint8), K)
    with pytest.raises(ValueError, match="0..1"):
        detect_reference(np.full((100, 100, 3), 2.0), K)
    with pytest.raises(ValueError, match="focal"):
        detect_reference(image, np.diag([-100.0, 100.0, 1.0]))
    with pytest.raises(ValueError, match="exclude_mask"):
        detect_reference(image, K, exclude_mask=np.zeros((10, 10), bool))
    with pytest.raises(ValueError, match="kinds"):
        detect_reference(image, K, kinds=("banana",))
    assert detect_reference(image, K) is None  # a blank image is no error, and no object


def test_the_searchs_remembered_profiles_change_nothing(monkeypatch):
    """``search_reference`` reads each line's profile once (``remembered_profiles``, for its second pass without the
    mask): the same objects, field for field, and the same reasons as the search that reads them again."""
    import dataclasses

    from footmesh.cues.reference import search
    from footmesh.cues.reference.sides import _median

    def forgetful(rgb, K, exclude_mask):
        with monkeypatch.context() as m:
            m.setattr(search, "_search_image", search._search_image.__wrapped__)
            return search_reference(rgb, K, exclude_mask=exclude_mask)

    sample = _scenes("a4", 1)[0]
    spread = _foot_and_leg(sample).copy()
    spread[:, : int(np.median(sample["ref_corners2d"][:, 0])) + 2] = True  # hides two sides: found in the second pass
    cut = sample["rgb"][:, : int(sample["ref_corners2d"][:, 0].max()) - 20].copy()  # nothing found: a reason
    for rgb, mask in ((sample["rgb"], spread), (cut, None)):
        remembered = search_reference(rgb, sample["K"], exclude_mask=mask)
        again = forgetful(rgb, sample["K"], exclude_mask=mask)  # without the memory
        assert (remembered.rejected, remembered.rejected_area) == (again.rejected, again.rejected_area)
        assert (remembered.found is None) == (again.found is None)
        if remembered.found is not None:
            for f in dataclasses.fields(remembered.found):
                assert np.array_equal(getattr(remembered.found, f.name), getattr(again.found, f.name)), f.name
    values = np.random.default_rng(0).random(101)
    for n in (1, 2, 7, 100, 101):
        assert _median(values[:n]) == np.median(values[:n])


def test_a_side_under_the_feet_mask_counts_where_its_own_two_colours_meet():
    """The feet's mask leaks onto shaded paper beside the foot on real photos (``arshoe_barefeet_1`` turned 90 deg:
    the sheet's side beside the shin masked, its corner 23 px off). Where the mask covers the side but the paper
    and the floor meet across it, the edge is the side's; where the foot covers the side, it is not."""
    from footmesh.cues.reference.sides import _side_edge_points

    image = np.full((240, 320, 3), (0.25, 0.22, 0.2), np.float32)  # a dark floor
    cv2.rectangle(image, (40, 30), (280, 180), (0.9, 0.9, 0.88), -1)  # the sheet, bottom side at y = 180
    cv2.rectangle(image, (130, 120), (180, 239), (0.8, 0.6, 0.5), -1)  # the shin across the bottom side
    blurred = cv2.GaussianBlur(image, (0, 0), 0.75)
    mask = np.zeros(image.shape[:2], bool)
    mask[110:, 120:250] = True  # the foot's mask, leaking 70 px right of the shin over paper and floor
    p, q = np.array([40.5, 180.0]), np.array([280.5, 180.0])
    edges, masked = _side_edge_points(blurred, p, q, 3.0, ~mask)
    assert masked and edges is not None
    x = edges.points[:, 0]
    assert np.all(np.abs(edges.points[:, 1] - 180.5) < 0.5)  # the fill covers row 180
    assert np.any((x > 190) & (x < 245)), "the side's edge under the leaked mask"
    assert not np.any((x > 132) & (x < 178)), "the shin's"
