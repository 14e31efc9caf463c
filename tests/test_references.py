"""The registry of reference objects (footmesh.references): each kind is drawn and found at its registered size."""

from __future__ import annotations

import numpy as np
import pytest

from footmesh import references
from footmesh.synth.render import Renderer
from footmesh.synth.scene import SynthConfig


def test_the_registry_is_consistent():
    ids = [k.dataset_id for k in references.KINDS]
    assert len(set(references.NAMES)) == len(references.NAMES) and 0 not in ids and len(set(ids)) == len(ids)
    assert len({k.preference for k in references.KINDS}) == len(references.KINDS)
    assert references.BY_PREFERENCE[0] == "marker"  # the unambiguous one wins
    # a sheet whose proportions are not seen is taken to be the first: A4
    assert references.with_detector("sheet") == ["a4", "letter"]
    assert references.described_choices() == "an A4 sheet, a bank card, the printed marker or a US letter sheet"
    with pytest.raises(ValueError, match="one of a4, card, marker, letter"):
        references.kind("legal")
    assert references.kind("card").size_rel_sd == pytest.approx(0.125 / 85.60 / np.sqrt(3))
    assert [k.named for k in references.KINDS] == [
        "the A4 sheet",
        "the bank card",
        "the printed marker",
        "the US letter sheet",
    ]


@pytest.mark.parametrize("name", references.NAMES)
def test_each_kind_is_rendered_at_its_registered_size(name):
    kind = references.kind(name)
    sample = Renderer(SynthConfig(size=160, reference=name)).render(5, 0)
    assert int(sample["ref_type"]) == kind.dataset_id
    corners = sample["ref_corners3d"].astype(np.float64)
    sides = np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1)
    np.testing.assert_allclose(sides, [*kind.size_mm, *kind.size_mm], atol=1e-3)


def test_a_kind_no_mixed_dataset_shows_leaves_the_mixed_datasets_as_they_were():
    """The letter sheet came after the mixed datasets the networks were trained on: its share is 0, so that their
    scenes draw the same objects, and everything after them, as without it."""
    from dataclasses import replace

    mixed = SynthConfig(size=96, reference="mixed")
    before = replace(mixed, reference_probs={k: p for k, p in mixed.reference_probs.items() if k != "letter"})
    now, then = Renderer(mixed), Renderer(before)
    drawn = [(now.scene(3, i), then.scene(3, i)) for i in range(60)]
    assert all(a.reference == b.reference and a.noise_seed == b.noise_seed for a, b in drawn)
    assert {a.reference.kind for a, _ in drawn if a.reference} == {"a4", "card", "marker"}
