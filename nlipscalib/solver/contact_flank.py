"""``--roi auto``'s box grown over a large contact's flank (:func:`grow_over_flank`): the gel a wide flat
indenter moves beyond the pixels that misfit strongly.
"""

from __future__ import annotations

import numpy as np

from ..core import masks, tolerances
from .contact import ContactMap


def grow_over_flank(
    contact: ContactMap, region: np.ndarray, edges: tuple[int, int, int, int], margin: int, step: int = 4
) -> tuple[int, int, int, int]:
    """The box ``edges`` = (x0, y0, x1, y1), pixels (x1, y1 exclusive), grown side by side over a contact's flank:
    while the ``step``-pixel strip beyond a side holds :data:`tolerances.ROI_FLANK_SHARE` of its pixels above
    :data:`tolerances.ROI_FLANK_FACTOR` times the floor of :func:`.contact_verdict.contact_hits` (only those joined to
    ``region``, the (H, W) bool pixels the box holds, and not within ``margin`` of the gel's edge), the side moves to
    ``margin`` pixels past that strip (within the image). The first strips lie :data:`tolerances.ROI_FLANK_START` of the
    image's short side beyond ``region``; a box at the image's border on one axis does not grow along it. A contact
    whose pixels misfit by a median of :data:`tolerances.ROI_FLANK_MAX_CONTACT_MISFIT` times the floor or more is a
    plain dent: its box does not grow.

    Why: a large flat indenter (the 20 mm coin face) moves the gel far beyond the pixels hit at
    :data:`tolerances.CONTACT_MISFIT_FACTOR`; its flank misfits by less, over many pixels, and the box of the hits
    plus ``margin`` left out a third of the contact."""
    H, W = region.shape
    box = list(edges)
    # the first strips lie a share of the view beyond the contact's hits: a plain dent's weak rim and the change of
    # its light around it lie within (12 px at 320x240, 24 at 640x480)
    start = max(int(round(tolerances.ROI_FLANK_START * min(H, W))) - margin, 0)
    probe = [max(box[0] - start, 0), max(box[1] - start, 0), min(box[2] + start, W), min(box[3] + start, H)]
    over = _over_flank_level(contact)
    # a plain dent (most presses): no first strip shows flank even before the checks below, which cost a whole
    # frame's erosion and labelling (~25 ms at 640x480)
    if not any(_is_flank(over, _strip(side, probe[side], box, step, (H, W))) for side in range(4)):
        return edges
    if _contact_strength(contact, region) >= tolerances.ROI_FLANK_MAX_CONTACT_MISFIT:
        return edges  # a plain dent: what passes as flank beside it is the change of its light around it
    over = _joined_flank(contact, over, region, margin)
    return _grown_sides(over, box, probe, step, margin)


def _contact_strength(contact: ContactMap, region: np.ndarray) -> float:
    """The median over ``region`` ((H, W) bool, the box's contact) of the misfit over the floor of
    :func:`.contact_verdict.contact_hits` -- how strongly the contact's images differ from the undeformed dome's."""
    floor = np.maximum(contact.expected[region], contact.median_misfit)
    return float(np.median(np.nan_to_num(contact.misfit[region]) / np.maximum(floor, 1e-9)))


def _joined_flank(contact: ContactMap, over: np.ndarray, region: np.ndarray, margin: int) -> np.ndarray:
    """(H, W) bool -- the pixels ``over`` the flank level that count as the contact's flank: not within ``margin`` of
    the gel's edge, and joined to ``region`` (the box's contact)."""
    gel = np.isfinite(contact.misfit)
    # not within a margin of the gel's edge or the image's border: the view there misfits more (the smoothing's fewer
    # pixels, grazing angles); only the flank that joins the box's contact: misfits that contact_box left out
    # (noise-like, or too small beside the contact) are not its flank
    over = over & masks.erode(gel, iterations=margin)
    labels, _ = masks.components(over | region)
    return over & np.isin(labels, np.unique(labels[region]))


def _grown_sides(
    over: np.ndarray, box: list[int], probe: list[int], step: int, margin: int
) -> tuple[int, int, int, int]:
    """:func:`grow_over_flank`'s box [x0, y0, x1, y1] once no side grows: each side's strip from ``probe`` (outward)
    moves ``step`` pixels while it is flank (:func:`_is_flank` of ``over``), the side ``margin`` pixels past it.
    ``box`` and ``probe`` are changed in place."""
    H, W = over.shape
    growing = [True] * 4
    while any(growing):
        for side in range(4):
            # a box at the image's border on one axis grows not along it: the view there misfits more than the
            # gel's edge band (the twin at polar 55: 1.5-3.7 times the floor 30 px in from the right border, the
            # whole height), and the box grew along it from one end of the image to the other
            along_border = (box[1] == 0 or box[3] == H) if side in (0, 2) else (box[0] == 0 or box[2] == W)
            if along_border or not (growing[side] and _is_flank(over, _strip(side, probe[side], box, step, (H, W)))):
                growing[side] = False
                continue
            outward = -1 if side < 2 else 1
            probe[side] = int(np.clip(probe[side] + outward * step, 0, (W, H)[side % 2]))
            moved = int(np.clip(probe[side] + outward * margin, 0, (W, H)[side % 2]))
            box[side] = min(box[side], moved) if side < 2 else max(box[side], moved)
    return box[0], box[1], box[2], box[3]


def _over_flank_level(contact: ContactMap) -> np.ndarray:
    """(H, W) bool -- misfit above :data:`tolerances.ROI_FLANK_FACTOR` times the floor of
    :func:`.contact_verdict.contact_hits`."""
    floor = np.maximum(contact.expected, contact.median_misfit)
    return np.nan_to_num(contact.misfit) > tolerances.ROI_FLANK_FACTOR * np.maximum(floor, 1e-9)


def _strip(side: int, probe: int, box: list[int], step: int, shape: tuple[int, int]) -> tuple[slice, slice]:
    """(rows, cols) slices of the ``step``-pixel strip beyond ``box`` = [x0, y0, x1, y1]'s ``side`` (0 left, 1 top,
    2 right, 3 bottom) that starts at ``probe`` (outward), spanning the box along that side, within ``shape``."""
    H, W = shape
    x0, y0, x1, y1 = box
    if side == 0:
        return slice(y0, y1), slice(max(probe - step, 0), probe)
    if side == 1:
        return slice(max(probe - step, 0), probe), slice(x0, x1)
    if side == 2:
        return slice(y0, y1), slice(probe, min(probe + step, W))
    return slice(probe, min(probe + step, H)), slice(x0, x1)


def _is_flank(over: np.ndarray, strip: tuple[slice, slice]) -> bool:
    """Whether :data:`tolerances.ROI_FLANK_SHARE` of the strip's pixels are ``over`` (False for an empty strip)."""
    part = over[strip]
    return part.size > 0 and int(part.sum()) >= tolerances.ROI_FLANK_SHARE * part.size
