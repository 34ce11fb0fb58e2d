"""The gel's outline on a view past the gel (``solver/outline.py``) and its hold in the solve's anchoring."""

import numpy as np
from scipy import ndimage

from nlipscalib.solver.anchoring import (
    OUTLINE_HOLD,
    OUTLINE_HOLD_MIN_SHARE,
    OUTLINE_HOLD_TAPER,
    OUTLINE_HOLD_TAPER_STEP,
    OUTLINE_HOLD_WIDTH,
    anchor_weights,
    outline_share,
)
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
    benchmarks/RESULTS.md, s37-outline), the next OUTLINE_HOLD_TAPER rings OUTLINE_HOLD_TAPER_STEP times less a ring
    (s38-outline34, s39-outline); a pixel there that the press deforms is not held (nor anchored), and the pixels
    further in keep an anchor's weight. A gel-filling view has no outline: its weights are 1 and 1 + weight, as before,
    so its results keep their bits."""
    rows, cols = np.indices((48, 64))
    gel = (rows - 24) ** 2 + (cols - 32) ** 2 < 20**2
    deformed = (rows - 24) ** 2 + (cols - 49) ** 2 < 8**2  # a dent that reaches the outline, across the 8 rings
    assert (OUTLINE_HOLD_WIDTH, OUTLINE_HOLD_TAPER, OUTLINE_HOLD_TAPER_STEP) == (2, 6, 5.0)
    reach = OUTLINE_HOLD_WIDTH + OUTLINE_HOLD_TAPER
    weights, note = anchor_weights(_contact_map(gel, deformed), gel, 1000.0, 3.0)
    expected = [1 + 1000.0 * OUTLINE_HOLD] * 2 + [1 + 1000.0 * 1e5 / 5.0**k for k in range(1, 7)]  # 2e4 .. 6.4
    for k, want in enumerate(expected):
        ring = gel_outline(gel, k + 1) & ~gel_outline(gel, k) if k else gel_outline(gel)
        assert (ring & deformed).any() and (ring & ~deformed).any()
        np.testing.assert_allclose(weights[ring & ~deformed], want, rtol=1e-12)
    np.testing.assert_array_equal(weights[gel & ~gel_outline(gel, reach) & ~deformed], 1001.0)
    np.testing.assert_array_equal(weights[deformed | ~gel], 1.0)
    held = gel_outline(gel, 2) & ~deformed
    tapered = gel_outline(gel, reach) & ~gel_outline(gel, 2) & ~deformed
    assert f"{int(held.sum())} of them at the gel's outline held to the reference ({int(tapered.sum())} more" in note
    assert f"within {reach} px of it" in note

    filling = np.ones((48, 64), bool)
    weights, note = anchor_weights(_contact_map(filling, deformed), filling, 1000.0, 3.0)
    np.testing.assert_array_equal(weights, np.where(deformed, 1.0, 1001.0))
    assert "outline" not in note


def test_the_outline_is_held_only_where_it_runs_along_enough_of_the_regions_border():
    """A box that the gel's outline grazes, or misses while its corner reaches the rings inside it, holds nothing
    (held, those rings pinned the depth level at the box's corner and the rest of the box bent away: the flat pad's
    sphere with the design LEDs, 0.891 -> 0.963 deg; benchmarks/RESULTS.md, s39-outline); a box along the outline
    holds it as a whole-frame solve does. The share is of the region's own border (the gel's outline on a whole
    frame, a box's edges and the outline within it), known answers on a straight outline."""
    gel = np.zeros((32, 64), bool)
    gel[:, :32] = True  # the gel's outline: column 31
    nothing = np.zeros_like(gel)
    cmap = _contact_map(gel, nothing)
    assert OUTLINE_HOLD_MIN_SHARE == 0.02

    half = gel.copy()
    half[:, :16] = False  # the gel's right half: its border is column 16 and the outline (the frame's edge is none)
    assert outline_share(gel_outline(gel), half) == 0.5
    assert outline_share(gel_outline(gel), nothing) == 0.0

    corner = np.zeros_like(gel)
    corner[:10, 20:31] = True  # reaches ring 1 (column 30), not the outline: as anchoring was before any hold
    weights, note = anchor_weights(cmap, corner, 1000.0, 3.0)
    np.testing.assert_array_equal(weights, np.where(corner, 1001.0, 1.0))
    assert "the gel's outline not held: its anchored pixels are 0.0 % of the region's border (under 2 %)" in note

    along = corner.copy()
    along[:10, 31] = True  # now with 10 of the outline's pixels: a third of its border (10 + 10 + 12 - 2 corners)
    assert outline_share(gel_outline(gel), along) == 10 / 30
    weights, note = anchor_weights(cmap, along, 1000.0, 3.0)
    np.testing.assert_array_equal(weights[:10, 30:32], 1 + 1000.0 * OUTLINE_HOLD)
    np.testing.assert_allclose(weights[:10, 29], 1 + 1000.0 * OUTLINE_HOLD / OUTLINE_HOLD_TAPER_STEP, rtol=1e-12)
    assert "20 of them at the gel's outline held to the reference" in note
