"""Boxes and masks of a press's solve: the bounding box of pixels, a box as a mask, the contact's pixels,
the outer interreflection loop's focus on the dent, and a focus pass merged into the whole solve."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..core import masks, tolerances
from ..core.errors import CaptureError
from .contact import ContactMap
from .contact_roi import contact_box
from .contact_verdict import contact_hits
from .nlips import SolveResult


def box_of(pixels: np.ndarray) -> list[int]:
    """[x0, y0, w, h] -- the bounding box of the True pixels."""
    rows, cols = np.nonzero(pixels.any(axis=1))[0], np.nonzero(pixels.any(axis=0))[0]
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)]


def box_mask(roi: Sequence[int], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool -- True inside the box ``roi`` = (x0, y0, w, h), pixels, in an image of ``shape`` = (H, W)."""
    x0, y0, w, h = roi
    box = np.zeros(shape, bool)
    box[y0 : y0 + h, x0 : x0 + w] = True
    return box


def contact_pixels(cmap: ContactMap, margin: int = 4) -> np.ndarray:
    """(H, W) bool -- the pixels the auto ROI would box (:func:`contact_hits`), dilated by ``margin``."""
    hit = contact_hits(cmap)
    return masks.dilate(hit, iterations=margin) if hit.any() else hit


def dent_focus(cmap: ContactMap, mask: np.ndarray) -> np.ndarray | None:
    """(H, W) bool -- what the outer loop's passes before the last solve: the auto ROI's box widened by
    ``tolerances.DENT_FOCUS_MARGIN`` of the image's short side, within ``mask``; None where that is
    most of the mask anyway (an ROI around the contact) or where no contact is found."""
    H, W = mask.shape
    margin = int(round(tolerances.DENT_FOCUS_MARGIN * min(H, W)))
    try:
        box, _ = contact_box(cmap, (H, W), margin=margin)  # its note is for a user's --roi auto
    except CaptureError:  # no contact: nothing to focus on
        return None
    focus = box_mask(box, (H, W)) & mask
    # a contact outside an explicit ROI leaves (next to) nothing to focus on
    return focus if tolerances.DENT_FOCUS_MIN_PIXELS <= focus.sum() < tolerances.DENT_FOCUS_SHARE * mask.sum() else None


def merge_focus(whole: SolveResult, part: SolveResult, focus: np.ndarray) -> SolveResult:
    """``whole`` with ``part``'s pixels inside ``focus``. The report is ``part``'s (its levels, timer), with
    ``whole``'s pixel counts (its mask is the solve's; a pass changes only the light subtracted inside the
    focus) and the merged map's count of reconstructed pixels."""
    fields = {}
    for name, a in whole.arrays().items():
        if name != "mask":
            f = focus.reshape(focus.shape + (1,) * (a.ndim - focus.ndim))
            fields[name] = np.where(f, getattr(part, name), a)
    report = dict(part.report)
    for key in ("pixels_solved", "pixels_too_few_leds", "pixels_no_gradient"):
        report[key] = whole.report[key]
    report["pixels_reconstructed"] = int(fields["reconstructed"].sum())
    return dataclasses.replace(whole, report=report, **fields)
