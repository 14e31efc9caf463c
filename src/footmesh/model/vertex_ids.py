"""Named surface landmarks of the footmesh template (vertex ids), like smplx's ``vertex_ids.py``.

The template is FIND's 1,002-vertex mesh subdivided once by Loop subdivision (4,002 vertices; see
:mod:`footmesh.model.template`). It is a LEFT foot: the big toe and the arch lie on -y, the little toe
(lateral side) on +y.

How the ids were derived (:func:`footmesh.model.build_find.derive_landmarks` re-derives them from FIND's files;
``tests/model/test_build_find.py`` checks they still agree):

* The first 12 come from FOCUS' ``hires/keypoints.csv`` (row ``FIND``: vertex ids on ``hires/template.obj``,
  44,395 vertices). That mesh is a slightly different foot (about 4.6 mm from FIND's template, toes spread
  wider), so plain nearest-vertex transfer put the 2nd toe tip on the big toe. The high-resolution template is
  first aligned to ours by an affine ICP (nearest vertices both ways, least squares, 30 iterations), then each
  keypoint goes to its nearest vertex (the mean distance after alignment is about 3.4 mm). Keypoint -> name: big
  toe .. little toe -> ``toe1_tip`` .. ``toe5_tip``; heel -> ``heel`` (the back of the heel); outer extrema (+y,
  lateral, the 5th metatarsal head) -> ``ball_lateral``; inner extrema (-y, medial, the 1st metatarsal head) ->
  ``ball_medial``; lower heel -> ``heel_low``; arch1..3 (medial arch, heel to ball) -> ``arch1`` .. ``arch3``.
* The malleoli: FIND's ankle is smooth and shows no clear bumps, so they are placed by ANSUR II proportions on
  FIND's neutral mean foot stood in the foot frame (L = its x-extent): the lateral malleolus is the most lateral
  (+y) vertex within 3 mm of height 72.9 / 271.2 L (ANSUR lateral malleolus height / foot length, men), the
  medial one the most medial (-y) vertex within 3 mm of height 82.9 / 271.2 L (the medial malleolus sits about
  1 cm higher), each searched within 8 mm (in x) of the middle of the rear foot's cross-section at that height
  (x < 0.45 L). The frame needs the malleoli only for a rough "up", so this fixed point is stable.
"""

from __future__ import annotations

LANDMARKS: dict[str, int] = {
    "toe1_tip": 1747,
    "toe2_tip": 399,
    "toe3_tip": 3521,
    "toe4_tip": 2834,
    "toe5_tip": 1505,
    "heel": 2125,
    "ball_lateral": 768,
    "ball_medial": 1770,
    "heel_low": 1479,
    "arch1": 3906,
    "arch2": 361,
    "arch3": 3403,
    "malleolus_lateral": 3288,
    "malleolus_medial": 2457,
}
"""Landmark name -> vertex id on the 4,002-vertex template."""

FIND_KEYPOINT_NAMES: dict[str, str] = {
    "big toe": "toe1_tip",
    "2nd toe": "toe2_tip",
    "3rd toe": "toe3_tip",
    "4th toe": "toe4_tip",
    "little toe": "toe5_tip",
    "heel": "heel",
    "outer extrema": "ball_lateral",
    "inner extrema": "ball_medial",
    "lower heel": "heel_low",
    "arch1": "arch1",
    "arch2": "arch2",
    "arch3": "arch3",
}
"""Column of FOCUS' ``keypoints.csv`` -> footmesh landmark name."""

LANDMARK_NAMES: tuple[str, ...] = tuple(LANDMARKS)
