"""The detector's settings: the kinds (``footmesh.references``) and every tuned threshold, with why."""

from __future__ import annotations

import itertools

import cv2
import numpy as np

from footmesh import references

KINDS = references.BY_PREFERENCE
"""Object kinds in order of preference (``footmesh.references``): a marker is unambiguous, a sheet is large, a
card is small."""
SIZES_MM: dict[str, tuple[float, float]] = {k.name: k.size_mm for k in references.KINDS}
"""Length x width (mm) of the rectangle whose corners are returned."""
SIZE_REL_SD: dict[str, float] = {k.name: k.size_rel_sd for k in references.KINDS}
"""Relative SD of the object's true size, uniform within its tolerance (``ReferenceKind.size_tolerance_mm``)."""
SHEETS = references.with_detector("sheet")
"""The kinds found as sheets of paper (bright, may bow, may lie under the foot and be completed)."""


def assumed_sheet(kinds: tuple[str, ...] | list[str]) -> str | None:
    """The sheet a sheet is taken to be where its proportions are not seen (a corner completed, a side cut by the
    photo's edge): the most preferred sheet among ``kinds`` (A4 before letter), None when none is."""
    return next((k for k in SHEETS if k in kinds), None)


SHEET_KIND_SDS = 3.0
"""Sheets of different sizes are told apart by their side ratio (A4 1.414, letter 1.294: 0.089 apart in log ratio).
A sheet is named the less preferred only where the preferred one's ratio lies beyond this many SDs of the measured
ratio (the corners' noise and the focal length's), else it is the preferred one, or, outside that one's tolerance,
neither. Measured log ratios of the A4 sheets found, against A4's (an EXIF-like focal length, 40 renders each):
guided -0.006 to +0.010, front -0.004 to +0.003, ood -0.029 to +0.072, the seven real photos -0.014 to +0.006;
letter's lies at -0.089, the midpoint at -0.044."""
RECTANGLES = references.with_detector("sheet") + references.with_detector("card")
MARKERS = references.with_detector("marker")
"""The kinds named by their side ratio (markers are named by their pattern)."""
FOCAL_KINDS = [k.name for k in references.KINDS if k.calibrates_focal]
"""The kinds whose perspective may correct a guessed focal length (``ReferenceKind.calibrates_focal``)."""
ARUCO_DICTIONARY = cv2.aruco.DICT_4X4_50
ARUCO_ID = 0
MARKER_SHEET_SCALE = 1.5
"""The printed sheet around a marker's black square (140 mm around 100 mm), with room for perspective."""
MARKER_CELLS = 6
"""Cells across a DICT_4X4 marker's black square (4 pattern cells and a one-cell black border)."""
MARKER_RETRY_RADII_CELLS = (0.4, 0.6)
"""Where OpenCV's corners of a large marker sit up to half a cell inside its outline (its sub-pixel window is too
small to move them there), the sides are searched again this many cells either way, in turn. The white sheet's own
edge lies 1.2 cells outside the outline, out of reach; a side caught on the pattern's edges a cell inside would
make the square a rectangle of ratio 5:6, which the metric test refuses."""
ASPECT_TOLERANCE = 0.045
"""Largest |log(measured side ratio / the object's)| accepted; A4 and card differ by 0.115 in log ratio."""
ANGLE_TOLERANCE_DEG = 3.5
"""Largest departure from a right angle of the recovered corner angle (metric, with K)."""
MAX_ASPECT_TOLERANCE = 0.05
MAX_ANGLE_TOLERANCE_DEG = 6.0
"""Where the corners are noisy the tolerances grow to 3 SD of the measured ratio and angle, up to these (never
so far that a sheet could pass for a card)."""
LOOSE_FACTOR = 3.0
"""Candidates are refined when they pass the metric test with tolerances this many times wider."""
MIN_BLANK_SHARE = 0.5
"""Of a sheet's inside that the foot's mask leaves, at least this share must be of the paper's colour (a shadow
over part of the sheet is allowed for)."""
MAX_INSIDE_BLOBS = 3
"""Of a sheet's inside that the foot's mask leaves, the parts not of the paper's colour may form at most this many
separate blobs (each at least ``MIN_BLOB_SHARE`` of it): a shadow is one or two (0-2 on 50 rendered sheets, guided
and random views, shadows of the foot and leg over them), a tiled floor's pattern many (5-26 on tile squares
taken for sheets)."""
MIN_BLOB_SHARE = 0.002
"""Blobs smaller than this share of the sheet's inside are noise, not counted."""
MIN_PAPER_SHOWN = 0.1
"""Searched again without the caller's mask, a sheet must show paper over at least this fraction of its area
outside the mask: the foot's lit skin (with the floor around the toes) passed as a white sheet once, while the
real sheets' masks, however spread, left 29-72 % of them in view."""
SHAPE_WEIGHT = 0.25
"""Of the candidates for one object, the score loses this much per tolerance that its shape departs from the
object's (side ratio and right angle): quads of one sheet that differ by a side caught on the leg's outline
differ by that most."""
MIN_SIDE_PX = 14.0
"""Shortest side (px) of an object worth measuring."""
FIRST_RADIUS_PX = 3.0
"""Search radius across a rough side of the first refinement pass (and of a sheet's completion), px."""
BORDER_MARGIN_PX = 2.0
"""Corners must lie this far inside the image: an object cut by the border gives a false quadrilateral."""
MIN_SIDE_SUPPORT = 0.35
MIN_MEAN_SUPPORT = 0.6
"""Each side must show its edge at this fraction (the four sides together: the second) of the positions along it
that show either the edge or plainly no edge; where the foot or its shadow covers the side nothing is known and
nothing counts (``_side_edge_points``)."""
MIN_COVERAGE: dict[str, tuple[float, float]] = {k.name: k.min_coverage for k in references.KINDS}
_LOOSEST_COVERAGE = tuple(min(c[i] for c in MIN_COVERAGE.values()) for i in (0, 1))
"""Each side must show its edge along the first fraction of its sampled length at least, and the four sides
together along the second: a sheet may lie under the foot, a card lies beside it; a marker is proven by its
decoded pattern, so the foot's shadow may cover more of its sides (the lines' fit still bounds the scale's SD).
A sheet stood on can show only 13-17 % of its far side: at 0.2, 7 of 60 sheets in guided photos (seeds 4242 /
777 / 999) were not found, at 0.1 five; the same on random views (``bench_reference --n 90``) and no new object
on 180 plain guided photos."""
OCCLUSION_MATCH = 0.35
"""Colours closer than this fraction of the change across a side count as the same colour."""
FLOOR_MATCH = 0.5
"""The floor beyond two sides of a sheet counts as the same floor when the colours differ by less than this
fraction of the typical change across the sides (light falls off across a sheet; a shadow lies over a side)."""
SHADOW_MAX_BRIGHTNESS = 0.8
"""A sheet's side whose paper is darker than this fraction of the paper elsewhere lies in a shadow (the leg's: 0.5
on the front render that showed it); lighter, it is lit like the rest and its floor is compared as it is (a tile's
side at 0.95-0.99 otherwise passed for a sheet's on a real photo of tiles)."""
MAX_RESIDUAL_RATIO = 2.0
STRAIGHT_EDGE_PX = 0.5
STRAIGHT_EDGE_FRACTION = 0.003
"""A side's edge points may scatter about its line up to this many times the median side's residual SD, or up
to this many px (an edge this straight is straight), or up to this fraction of the side's length: a sheet on a
real floor bows (curl, waves, the lens' residual distortion), and a bow of 1 % of the side (3 mm on A4's length)
scatters 0.3 % of it about the line. A side fitted to a curved outline (the foot's, where it hides the sheet's
side) scatters more."""
CORNER_SPAN = 0.3
CORNER_RADIUS_PX = (4.0, 1.5)
MIN_CORNER_COVERAGE = 0.3
"""A sheet's corners are placed where the stretches of its two sides nearest to each (up to this fraction of
the side from it) meet, each side searched again there this far (px) either way of its line, then closer: paper
on a real floor bows and waves (curl, a step on it, the lens' residual distortion), and the line through a
whole bowed side misses its corners by several px where its middle sags. A stretch whose edge shows along less
than this fraction of it keeps the whole side's line."""
CORNER_MOVE_PX = 1.0
"""A corner is placed from the stretches next to it only when that moves it this far from where the whole sides
meet: along straight sides the whole sides fix it better (their lines' SD at a corner is a few hundredths of a
px)."""
CONTINUATION_SPAN = (0.05, 0.3)
"""Stretch beyond each corner, in side lengths, where the side's edge must not go on."""
MAX_CONTINUATION = 0.5
CONTINUATION_RADIUS_PX = 1.0
"""Largest fraction of that stretch that may show an edge within this distance of the side's line."""
MIN_CONTINUATIONS = 2
"""A quad is cut out of longer lines when its edges run on past this many corner ends (of the eight). At 1, a card
whose short side lay in line with a plank's seam (guided 999, photo 4) and sheets in line with a tile's grout
(4242, 45: a grout line was then taken for a side, the scale 13.5 % off) were refused: 50 -> 53 of 60 guided cards
found (seeds 4242 / 777 / 999), random views (``bench_reference --n 90``) unchanged, no new object on 180 plain
guided photos."""
PAPER_MAX_SATURATION = 0.3
"""An A4 sheet is white: (max - min) / max of its colour just inside its sides stays below this (and it is
brighter than the floor around it)."""
WHITE_SHARE = 0.01
"""The image is white-balanced on the mean colour of this brightest share of its pixels (a sheet in view is
among them; without one, highlights, which take the light's colour): under warm indoor light a white sheet is
orange, beyond ``PAPER_MAX_SATURATION``, and its sides' colour steps weaker."""
MAX_WHITE_GAIN = 2.0
"""A channel is brightened at most this much by the white balance (a brightest patch of strong colour, a
yellow wall, is not taken for the light's)."""
WHITE_MIN_GAIN = 1.05
"""Below this gain on every channel the light is taken for white and the photo searched as it is."""
MIN_CONTRAST = 0.04
"""Smallest colour change across a side (image values 0..1, Euclidean over RGB) that counts as an edge."""
DISTANCE_RANGE_MM = (80.0, 5000.0)
"""Plausible camera-to-object distances of a foot photo."""
MAX_SCALE_REL_SD = 0.03
"""An object whose corners fix the scale worse than this (relative SD) is not reported."""
MIN_CORNER_SD_PX = 0.05
"""Floor of an edge's residual SD (px): residuals of a few points underestimate it."""
BLUR_SIGMA_PX = 0.75
"""Gaussian blur before locating edges; symmetric, so it does not move a straight edge."""
END_SKIP = 0.06
"""Fraction of each side skipped at both ends when fitting its line (a card's rounded corners: 3.7 % of its
length, 5.9 % of its width)."""
PLATEAU_PX = 2.5
"""The colours on both sides of an edge are read this far (px) beyond the search window."""
SHEET_MIN_AREA = 0.004
"""A white region smaller than this fraction of the image is not completed into a sheet with a hidden corner."""
COMPLETION_MIN_COVERAGE = 0.5
COMPLETION_MIN_SUPPORT = 0.8
"""A sheet is completed from three sides only when each shows its edge along this much of it (coverage,
support as in ``_Line``)."""
CUT_EDGE_PX = 3.0
"""A rough quad's side runs along the photo's edge where both its corners lie within this (px) of it; a sheet
completed across it must put its far corners farther than this beyond it (``cut``)."""
CUT_ANGLE_TRUST_DEG = 0.2
"""The direction of a side leaving the photo is trusted to this (deg) beyond its fit's own noise when the scale's SD
of a sheet cut by the photo's edge is worked out: the far corners are extrapolated along sides that bow on a real
sheet. On the seven real A4 photos cropped across their sheets (``bench_reference.py``'s cropped table) the
distance errors were up to 3.4 of the SD without it, within 2.4 with it (10 of 14 within one)."""
BEYOND_MIN_SHOWN = 0.5
"""A sheet with one corner beyond the photo's edge (its other three and all four sides' lines in view): each of the
two sides running to that corner must show at least this share of its length, or the corner, placed where their
lines meet, rests on too short a stretch of either."""
BEYOND_CLEAR_PX = 2 * FIRST_RADIUS_PX
"""...and its three corners in view must lie this far (px) inside the photo: a side running along the photo's edge
shows a sliver of itself, and the line read there is another edge's (a real photo cropped 1 px past a corner: the
sheet's end read 17 px inside the paper)."""
BEYOND_EDGE_INSET_PX = 3.0
"""...and its paper must reach the photo's edge between where those two sides leave it, read this far (px) inside
the edge (``finish._paper_to_the_edge``)."""
BEYOND_FLOOR_MATCH = 0.25
"""...and what lies outside each of its sides must match the floor beyond the others this closely (a share of the
sides' typical step; a whole sheet's: ``FLOOR_MATCH``): with a corner out of sight, a shadow's edge along the leg
across a sheet cut by the photo's edge made, with the sheet's three sides in view, a US letter sheet with a corner
beyond the edge (its outside 0.45 of the step from the floor's; a front render cropped,
``tests/cues/test_reference_cut.py``)."""
CUT_LENGTH_MARGIN = 0.1
"""A sheet cut by the photo's edge is taken only where one completion alone fits what shows: the other (the side in
view whole taken for the other side of the sheet) would have to leave the photo this fraction short of where the
cut sides do (their ends in view are where the edge cuts them, their directions from a vanishing point)."""
WEAK_SIDE_SHARE = 0.25
"""A sheet's side parts the paper from the floor (or from the foot over it) with a step of colour at least this
share of its strongest side's; a weaker one is the paper's own shading or the skin's, which a quad the search
completed itself may run along (a real photo cropped: a fourth side across the paper, a third along the foot's
creases)."""
COMPLETED_MIN_SIDE_SUPPORT = 0.7
"""Each side of a completed sheet must show its edge at this fraction of the positions where it is seen: the
hidden corner is hidden by the foot (where nothing counts), not missing from a bright blob (the top of a leg
once passed as a sheet with a corner completed, sides supported at 0.48 and 0.49)."""
MAX_HULL_SIDES = 8
"""A region's hull simplified to more sides than this is no quadrilateral with a few corners cut off."""
MAX_HIDDEN_AREA_RATIO = 2.0
"""A quadrilateral guessed from a region with corners cut off may be at most this many times the region."""
MIN_REGION_FILL = 0.45
"""A region fills at least this much of its convex hull: the foot on a sheet eats into it but leaves most of it; a
ring or an L is no rectangle."""
MIN_PIECES_FILL = 0.3
"""The same for two or three pieces of a sheet's region taken together: a foot standing on the sheet, seen from in
front of the toes, with the shin crossing the sheet's far side and the leg's shadow over a corner, leaves less
(front views 15 and 21 of the eval's seed: 0.3-0.45, all four corners in view; ``bench_reference.py --views
front``: A4 sheets found 18 -> 20 of 20)."""
_MIN_REGION_AREA_PX = 120.0
_THRESHOLD_LEVELS = 9
SEARCH_SIDE_PX = 640
"""Images larger than this (shorter side, px) are searched for a card's candidate regions at this size."""
_KERNEL3 = np.ones((3, 3), np.uint8)
_KERNEL5 = np.ones((5, 5), np.uint8)
_COMBINATIONS = {n: np.array(list(itertools.combinations(range(n), 4))) for n in range(4, MAX_HULL_SIDES + 1)}
