"""Which pixels of a tri-colour frame differ from the undeformed reference frame.

Used twice with the same rule: the calibration dataset separates the contact from the undeformed
rest with it, and real-time inference sends only the changed pixels through the network.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError

NOISE_SIGMAS = 6.0
"""A pixel has changed when its colour differs from the reference by more than this many noise sigmas."""
MIN_REL_CHANGE = 0.02
"""... and by more than this fraction of the reference's intensity (rendering/shading noise floor)."""
DILATE_PX = 2
"""Changed regions grow by this many pixels, so a contact's soft rim is not cut off."""


def changed_pixels(frame: np.ndarray, reference: np.ndarray, valid: np.ndarray, dilate: int = DILATE_PX) -> np.ndarray:
    """Pixels whose tri-colour value differs from the undeformed reference frame.

    The noise level is estimated robustly (median absolute deviation of the difference over the gel),
    so the rule adapts to sensor noise without a tuned absolute threshold; isolated noisy pixels are
    removed by a morphological opening.

    Parameters
    ----------
    frame, reference : (H, W, 3) float, linear tri-colour images (``Press.linear``)
    valid : (H, W) bool -- pixels that see the gel
    dilate : grow the changed region by this many pixels

    Returns
    -------
    (H, W) bool
    """
    from scipy import ndimage

    if frame.shape != reference.shape or frame.ndim != 3 or frame.shape[:2] != valid.shape:
        raise ShapeError(f"frame {frame.shape}, reference {reference.shape} and valid {valid.shape} must match")
    diff = np.abs(frame.astype(np.float32) - reference.astype(np.float32)).sum(-1)
    inside = diff[valid]
    if inside.size == 0:
        return np.zeros(valid.shape, bool)
    sigma = 1.4826 * float(np.median(np.abs(inside - np.median(inside)))) + 1e-6
    level = reference.astype(np.float32).sum(-1)
    hit = valid & (diff > np.median(inside) + NOISE_SIGMAS * sigma) & (diff > MIN_REL_CHANGE * level)
    hit = ndimage.binary_opening(hit, iterations=1)
    if dilate > 0:
        hit = ndimage.binary_dilation(hit, iterations=dilate)
    return hit & valid
