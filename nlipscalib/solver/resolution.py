"""Whether a press's contact is large enough, in pixels, for the solve's normals there to be trusted.

The solve's depth is smoothed over a few pixels whatever the dent's size (the smoothness term, the depth's
normals), so a dent whose normals turn steeply within few pixels -- a 1 mm sphere at 320x240 -- comes out with
its slopes flattened by several degrees, silently. :func:`resolution_note` says so from the solve's own
quantities: the contact's hits (:func:`.contact.contact_hits`) among the solved pixels and the solved normals'
tilt from the undeformed surface there.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..core import masks, tolerances
from .contact import ContactMap, contact_hits

MIN_CONTACT_PX = 9
"""Hits fewer than this (a 3x3 patch) are not a contact to judge: noise specks, or no contact at all."""


def contact_steepness(
    contact: ContactMap, normals: np.ndarray, reference_normals: np.ndarray, solved: np.ndarray
) -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of the contact as solved, or None where no contact was solved.

    Parameters
    ----------
    contact : ContactMap -- the solve's contact classification.
    normals : (H, W, 3) float32, unit, camera frame -- the solved normals.
    reference_normals : (H, W, 3) float32, unit, camera frame -- the undeformed surface's normals.
    solved : (H, W) bool -- pixels the solve reconstructed.

    Returns
    -------
    diameter : float, px -- 2 sqrt(area / pi) of the largest connected component of hits among ``solved``.
    tilt : float, degrees -- 75th percentile over that component of the angle between solved and undeformed normals.
    """
    hits = contact_hits(contact) & solved
    labels, sizes = masks.components(hits)
    if sizes.size == 0 or sizes.max() < MIN_CONTACT_PX:
        return None
    largest = labels == int(np.argmax(sizes)) + 1
    cosine = np.sum(normals[largest].astype(np.float64) * reference_normals[largest], axis=-1)
    tilt = np.degrees(np.arccos(np.clip(cosine[np.isfinite(cosine)], -1.0, 1.0)))
    if tilt.size == 0:
        return None
    return 2.0 * float(np.sqrt(sizes.max() / np.pi)), float(np.percentile(tilt, 75))


def resolution_note(folder: str | Path, diameter_px: float, tilt_deg: float) -> str | None:
    """The warning for a contact too small for its slopes (:data:`tolerances.RESOLVED_TILT_PER_PX`), or None."""
    needed = tilt_deg / tolerances.RESOLVED_TILT_PER_PX
    if diameter_px >= needed:
        return None
    return (
        f"{folder}: contact about {diameter_px:.0f} px across with its normals tilted ~{tilt_deg:.0f} deg: below "
        f"the ~{needed:.0f} px the solver resolves at that tilt; normals there are smoothed (expect several "
        f"degrees of error against a normal press's ~0.5); capture at a higher resolution or press with a larger "
        f"indenter"
    )
