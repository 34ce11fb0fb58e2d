"""How steeply a contact's normals turn per pixel of its size: whether a reconstruction of it can be trusted.

A reconstruction smooths a dent over a few pixels whatever its size (the solve's smoothness term and depth
normals; NLiPsNet learns the solve's labels from pre-filtered colours), so a contact whose normals turn steeply
within few pixels -- a 1 mm sphere at 320x240 -- comes out with its slopes flattened by several degrees, silently.
The one formula both the solve (``solver.resolution``) and NLiPsNet's inference (``learn.resolution``) judge a
contact by: its equivalent diameter in pixels and its normals' tilt from the undeformed surface
(:data:`~nlipscalib.core.tolerances.RESOLVED_TILT_PER_PX`).
"""

from __future__ import annotations

import numpy as np

from . import masks, tolerances

MIN_CONTACT_PX = 9
"""Patches smaller than this (a 3x3 patch) are not a contact to judge: noise specks, or no contact at all."""


def patch_steepness(
    patch: np.ndarray, normals: np.ndarray, reference_normals: np.ndarray
) -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of the largest connected component of ``patch``; None when it is smaller
    than :data:`MIN_CONTACT_PX` or none of its normals is finite.

    Parameters
    ----------
    patch : (H, W) bool -- the contact's pixels (the solve's hits, or the change rule's changed pixels).
    normals : (H, W, 3) float, unit, camera frame -- the reconstructed normals.
    reference_normals : (H, W, 3) float, unit, camera frame -- the undeformed surface's normals.

    Returns
    -------
    diameter : float, px -- 2 sqrt(area / pi) of the largest 4-connected component.
    tilt : float, degrees -- 75th percentile over that component of the angle between the normals and the
        undeformed ones.
    """
    labels, sizes = masks.components(patch)
    if sizes.size == 0 or sizes.max() < MIN_CONTACT_PX:
        return None
    largest = labels == int(np.argmax(sizes)) + 1
    cosine = np.sum(normals[largest].astype(np.float64) * reference_normals[largest], axis=-1)
    tilt = np.degrees(np.arccos(np.clip(cosine[np.isfinite(cosine)], -1.0, 1.0)))
    if tilt.size == 0:
        return None
    return 2.0 * float(np.sqrt(sizes.max() / np.pi)), float(np.percentile(tilt, 75))


def resolved_diameter_px(tilt_deg: float) -> float:
    """The smallest contact diameter (px) whose normals tilted ``tilt_deg`` (degrees) are resolved
    (:data:`~nlipscalib.core.tolerances.RESOLVED_TILT_PER_PX`)."""
    return tilt_deg / tolerances.RESOLVED_TILT_PER_PX
