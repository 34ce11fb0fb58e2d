"""Which pixels of a tri-colour frame differ from the undeformed reference frame.

Used twice with the same rule: the calibration dataset separates the contact from the undeformed
rest with it, and real-time inference sends only the changed pixels through the network.
"""

from __future__ import annotations

import numpy as np

from ..errors import ShapeError

NOISE_SIGMAS = 5.0
"""A pixel has changed when its (locally averaged) colour differs from the reference by more than this
many noise sigmas of the averaged difference."""
MIN_REL_CHANGE = 0.005
"""... and by more than this fraction of the reference's intensity (shading noise floor)."""
SMOOTH_PX = 5
"""Side of the box the signed difference is averaged over: sensor noise averages out, the smooth
shading change of a shallow, wide deformation does not."""
DILATE_PX = 3
"""Changed regions grow by this many pixels, so a contact's soft rim is not cut off."""


def changed_pixels(frame: np.ndarray, reference: np.ndarray, valid: np.ndarray, dilate: int = DILATE_PX) -> np.ndarray:
    """Pixels whose tri-colour value differs from the undeformed reference frame.

    The signed difference is box-averaged (sensor noise falls, a smooth shading change stays), and
    its noise level is estimated robustly (median absolute deviation over the gel), so the rule adapts
    to sensor noise without a tuned absolute threshold; isolated specks are removed by an opening.

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
    signed = np.where(valid[..., None], frame.astype(np.float32) - reference.astype(np.float32), 0)
    diff = np.abs(ndimage.uniform_filter(signed, size=(SMOOTH_PX, SMOOTH_PX, 1), mode="nearest")).sum(-1)
    inside = diff[valid]
    if inside.size == 0:
        return np.zeros(valid.shape, bool)
    median = float(np.median(inside))
    sigma = 1.4826 * float(np.median(np.abs(inside - median))) + 1e-6
    level = reference.astype(np.float32).sum(-1)
    hit = valid & (diff > median + NOISE_SIGMAS * sigma) & (diff > MIN_REL_CHANGE * level)
    hit = ndimage.binary_opening(hit, iterations=1)
    if dilate > 0:
        hit = ndimage.binary_dilation(hit, iterations=dilate)
    return hit & valid
