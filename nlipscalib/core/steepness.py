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
    patch: np.ndarray,
    normals: np.ndarray,
    reference_normals: np.ndarray,
    origin: tuple[int, int] = (0, 0),
    measured: np.ndarray | None = None,
) -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of the largest connected component of ``patch``; None when it is smaller
    than :data:`MIN_CONTACT_PX` or none of its (measured) normals is finite.

    Parameters
    ----------
    patch : (h, w) bool -- the contact's pixels (the solve's hits, or the change rule's changed pixels) in the
        window of the image whose first row and column are ``origin`` (the whole image: (H, W), (0, 0)).
    normals : (H, W, 3) float, unit, camera frame -- the reconstructed normals of the whole image.
    reference_normals : (H, W, 3) float, unit, camera frame -- the undeformed surface's normals.
    origin : (row, column) int, px -- where ``patch`` lies in the image (a contact's bounding box: the components
        are found in it alone, a fraction of the pixels).
    measured : (h, w) bool, or None -- the pixels of the window whose normals the tilt is taken over (None: all of
        the component's): the component's size still sets the diameter (``learn.resolution.measure_contact``).

    Returns
    -------
    diameter : float, px -- 2 sqrt(area / pi) of the largest 4-connected component.
    tilt : float, degrees -- 75th percentile over that component (its ``measured`` pixels) of the angle between
        the normals and the undeformed ones.
    """
    labels, sizes = masks.components(patch)
    if sizes.size == 0 or sizes.max() < MIN_CONTACT_PX:
        return None
    found = np.flatnonzero(labels == int(np.argmax(sizes)) + 1)
    if measured is not None:
        found = found[measured.reshape(-1)[found]]
    rows, cols = np.divmod(found, patch.shape[1])
    at = (rows + origin[0]) * normals.shape[1] + (cols + origin[1])
    # flat indices into the whole image, gathered with np.take: a boolean gather of a window's pixels cost 2.7 ms of
    # a 640x480 frame's 70,000 contact pixels, this 1.1 ms; the same float64 products summed in the same order
    a = np.take(normals.reshape(-1, 3), at, axis=0).astype(np.float64)
    b = np.take(reference_normals.reshape(-1, 3), at, axis=0).astype(np.float64)
    cosine = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]
    tilt = np.degrees(np.arccos(np.clip(cosine[np.isfinite(cosine)], -1.0, 1.0)))
    if tilt.size == 0:
        return None
    return 2.0 * float(np.sqrt(sizes.max() / np.pi)), float(np.percentile(tilt, 75))


def resolved_diameter_px(tilt_deg: float) -> float:
    """The smallest contact diameter (px) whose normals tilted ``tilt_deg`` (degrees) are resolved
    (:data:`~nlipscalib.core.tolerances.RESOLVED_TILT_PER_PX`)."""
    return tilt_deg / tolerances.RESOLVED_TILT_PER_PX
