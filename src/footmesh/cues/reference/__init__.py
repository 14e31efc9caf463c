"""Reference objects on the floor (A4 sheet, ID-1 card, printed ArUco marker) and the metric floor plane.

A plain photo has no scale; a known rectangle lying on the floor gives it. ``detect_reference`` finds the object,
its four corners to a fraction of a pixel, tells which object it is from its metric aspect ratio (recovered with
the intrinsics K), and solves the plane's pose in millimetres (planar PnP, IPPE). Method and measured accuracy:
docs/reference.md.

Steps:

0. White balance: the photo's channels scaled so that its brightest surfaces are grey (``quads.white_balanced``):
   the colour tests read the surfaces, not the light.
1. Marker: ``cv2.aruco.ArucoDetector`` (DICT_4X4_50, id 0) on the image, else on its mirror image (a mirrored
   photo, or a mirrored print, still gives a metric plane).
2. Sheet and card: candidate quadrilaterals from the outlines of regions at several levels of whiteness (sheet),
   grey, each colour channel and chroma (card), and of Canny edges: each outline's convex hull is simplified
   (``approxPolyDP``) and every four of its sides that enclose it make a candidate (the foot on a sheet cuts
   corners off its region), screened at once by a loose metric test (3), its sides then re-fitted to the outline
   points near them.
3. Metric test: the rays through the four corners, cut by a plane, give a parallelogram (unique up to scale); a
   rectangle's image gives a right angle, and its side ratio names the object (A4 1.414, card 1.586).
4. Sub-pixel sides: along each side (its ends skipped: rounded card corners) the blurred image is sampled across
   the side and the strongest colour gradient that is a step (not a thin line) is located to sub-pixel
   precision; a robust line fit through these points and the intersections of neighbouring lines give the
   corners. The same for the marker's black square.
5. Strict tests: right angle and side ratio (tolerances widened by the corners' own noise), every side's edge
   present where it is not covered (the foot over a sheet may hide part of a side or a corner), straight (as
   straight as a real, slightly bowed sheet), and not running on past the corners (planks, tiles), a white sheet
   whose every side parts the paper from the floor, inside the image.
6. A sheet's sides fitted again through paper-to-floor edges only (the leg's outline left out) and, where they
   bow, its corners placed from the stretches of the sides next to them; then the pose:
   ``cv2.solvePnP(..., SOLVEPNP_IPPE)`` on the known rectangle, floor z pointing to the camera.
7. Uncertainty: each line's offset and angle SD from its fit residuals (counting their correlation along the
   side), pushed through intersection and PnP by finite differences to the camera-to-object distance; plus the
   object's size tolerance.
8. Nothing found with the caller's mask: the same candidates again without it (``search_reference`` says why the
   largest was rejected when nothing is found at all).
9. Last, a sheet with one side beyond the photo's edge: its far corners placed from the three sides in view and its
   size, where only one of its sides can be the one in view whole, the focal length's effect on the scale counted
   (``cut``).

Frames: image pixels with the centre of the top-left pixel at (0, 0); camera OpenCV (x right, y down, z forward),
mm. The floor frame has its origin at corner 0, x along the first side (the length L), y along the width W,
z = x cross y up out of the floor (towards the camera).
"""

from footmesh.cues.reference.objects import ReferenceObject, ReferenceSearch
from footmesh.cues.reference.params import KINDS, SIZE_REL_SD, SIZES_MM
from footmesh.cues.reference.pose import rectangle_pose, seen_with
from footmesh.cues.reference.search import detect_reference, search_reference

__all__ = [
    "KINDS",
    "SIZES_MM",
    "SIZE_REL_SD",
    "ReferenceObject",
    "ReferenceSearch",
    "detect_reference",
    "rectangle_pose",
    "search_reference",
    "seen_with",
]
