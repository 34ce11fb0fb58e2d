"""The gel's outline on a view past the gel (``solver/outline.py``) and its hold in the solve's anchoring."""

import numpy as np
from scipy import ndimage

from nlipscalib.solver.anchoring import OUTLINE_HOLD, OUTLINE_HOLD_TAPER, OUTLINE_HOLD_WIDTH, anchor_weights
from nlipscalib.solver.contact import ContactMap
from nlipscalib.solver.outline import gel_outline, outline_rings


def _contact_map(gel: np.ndarray, deformed: np.ndarray) -> ContactMap:
    """A contact map whose misfit is the noise's on ``gel`` but ten times it at ``deformed`` (NaN off the gel)."""
    expected = np.full(gel.shape, 1e-3)
    misfit = np.where(gel, np.where(deformed, 10.0, 1.0) * expected, np.nan)
    return ContactMap(misfit, expected, tuple(range(12)), (), 1e-3, np.full(gel.shape, 0.5))


def test_the_outline_is_the_gels_pixels_beside_the_black_beyond_and_none_on_a_gel_filling_view():
    rows, cols = np.indices((48, 64))
    gel = (rows - 24) ** 2 + (cols - 32) ** 2 < 20**2
    outline = gel & ~ndimage.binary_erosion(gel, np.ones((3, 3)), border_value=1)
    np.testing.assert_array_equal(gel_outline(gel), outline)
    assert outline.sum() > 50
    inner = gel & ~outline
    next_ring = inner & ~ndimage.binary_erosion(inner, np.ones((3, 3)), border_value=1)
    np.testing.assert_array_equal(gel_outline(gel, 2), outline | next_ring)
    assert not gel_outline(np.ones((48, 64), bool)).any()  # the frame's own border is no outline


def test_the_outline_rings_count_8_neighbour_steps_from_the_black_beyond():
    rows, cols = np.indices((48, 64))
    gel = (rows - 24) ** 2 + (cols - 32) ** 2 < 20**2
    ring = outline_rings(gel, 6)
    for k in range(6):  # ring k: k + 1 steps of the 3x3 square from the nearest pixel off the gel
        inside = gel_outline(gel, k) if k else np.zeros_like(gel)
        np.testing.assert_array_equal(ring == k, gel_outline(gel, k + 1) & ~inside)
    assert ((ring >= 0) == gel_outline(gel, 6)).all() and (ring[~gel] == -1).all() and (ring[24, 32] == -1)
    square = np.zeros((9, 9), bool)
    square[1:8, 1:8] = True  # a 7x7 square: its rings are concentric squares, the centre the fourth
    np.testing.assert_array_equal(outline_rings(square, 4)[4, 1:8], [0, 1, 2, 3, 2, 1, 0])
    assert (outline_rings(np.ones((48, 64), bool), 6) == -1).all()  # the frame's own border is no outline


def test_the_undeformed_outline_is_held_to_the_reference_tapering_inward_and_a_gel_filling_view_is_as_before():
    """On a view past the gel the anchored pixels of its outline and of the ring inside it weigh OUTLINE_HOLD times an
    anchor (the outline's partly covered light pulled the depth off the reference at an anchor's weight:
    benchmarks/RESULTS.md, s37-outline), the next OUTLINE_HOLD_TAPER rings a decade less a ring (s38-outline34); a
    pixel there that the press deforms is not held (nor anchored), and the pixels further in keep an anchor's weight.
    A gel-filling view has no outline: its weights are 1 and 1 + weight, as before, so its results keep their bits."""
    rows, cols = np.indices((48, 64))
    gel = (rows - 24) ** 2 + (cols - 32) ** 2 < 20**2
    deformed = (rows - 24) ** 2 + (cols - 50) ** 2 < 7**2  # a dent that reaches the outline, across the 6 rings
    assert (OUTLINE_HOLD_WIDTH, OUTLINE_HOLD_TAPER) == (2, 4)
    weights, note = anchor_weights(_contact_map(gel, deformed), gel, 1000.0, 3.0)
    expected = [1 + 1000.0 * OUTLINE_HOLD] * 2 + [1 + 1000.0 * h for h in (1e4, 1e3, 1e2, 1e1)]
    for k, want in enumerate(expected):
        ring = gel_outline(gel, k + 1) & ~gel_outline(gel, k) if k else gel_outline(gel)
        assert (ring & deformed).any() and (ring & ~deformed).any()
        np.testing.assert_array_equal(weights[ring & ~deformed], want)
    np.testing.assert_array_equal(weights[gel & ~gel_outline(gel, 6) & ~deformed], 1001.0)
    np.testing.assert_array_equal(weights[deformed | ~gel], 1.0)
    held = gel_outline(gel, 2) & ~deformed
    tapered = gel_outline(gel, 6) & ~gel_outline(gel, 2) & ~deformed
    assert f"{int(held.sum())} of them at the gel's outline held to the reference ({int(tapered.sum())} more" in note

    filling = np.ones((48, 64), bool)
    weights, note = anchor_weights(_contact_map(filling, deformed), filling, 1000.0, 3.0)
    np.testing.assert_array_equal(weights, np.where(deformed, 1.0, 1001.0))
    assert "outline" not in note
