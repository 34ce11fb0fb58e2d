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

from ..core.steepness import MIN_CONTACT_PX, patch_steepness, resolved_diameter_px
from .contact import ContactMap
from .contact_verdict import contact_hits

__all__ = ["MIN_CONTACT_PX", "contact_steepness", "resolution_note"]


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
    :func:`nlipscalib.core.steepness.patch_steepness` of the contact's hits among ``solved``.
    """
    return patch_steepness(contact_hits(contact) & solved, normals, reference_normals)


def resolution_note(folder: str | Path, diameter_px: float, tilt_deg: float) -> str | None:
    """The warning for a contact too small for its slopes
    (:data:`~nlipscalib.core.tolerances.RESOLVED_TILT_PER_PX`), or None."""
    needed = resolved_diameter_px(tilt_deg)
    if diameter_px >= needed:
        return None
    return (
        f"{folder}: contact about {diameter_px:.0f} px across with its normals tilted ~{tilt_deg:.0f} deg: below "
        f"the ~{needed:.0f} px the solver resolves at that tilt; normals there are smoothed (expect several "
        f"degrees of error against a normal press's ~0.5); capture at a higher resolution or press with a larger "
        f"indenter"
    )
