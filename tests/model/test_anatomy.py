"""footmesh.model.anatomy: the regions a standing foot bears weight on."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh.model import anatomy
from footmesh.model.layer import default_model


def test_heel_and_ball_regions_lie_at_their_fractions_of_the_foot():
    rest = default_model().mean_vertices.detach().double().numpy()
    x = (rest[:, 0] - rest[:, 0].min()) / np.ptp(rest[:, 0])
    heel, ball = anatomy.heel_region(rest), anatomy.ball_region(rest)
    assert len(heel) and len(ball) and not set(heel) & set(ball)
    assert x[heel].max() < anatomy.HEEL_REGION_FRACTION
    assert anatomy.BALL_REGION[0] <= x[ball].min() and x[ball].max() <= anatomy.BALL_REGION[1]
    # the rest foot stands flat: both regions reach the floor
    assert rest[heel, 2].min() == pytest.approx(0.0, abs=1.0) and rest[ball, 2].min() == pytest.approx(0.0, abs=1.0)


def test_regions_refuse_what_is_not_a_mesh():
    with pytest.raises(ValueError, match="shape"):
        anatomy.heel_region(np.zeros((3, 2)))
