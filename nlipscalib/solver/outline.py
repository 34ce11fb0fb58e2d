"""The gel's outline on a view past the gel: the pixels the gel covers only in part, whose light the image model (a
whole pixel of surface) does not hold. The LED calibration leaves them out of its samples
(:func:`.led_fit.capture_samples`); a solve holds their depth, and the next ring's, to the reference where the press
leaves them undeformed (:func:`.anchoring.anchor_weights`)."""

from __future__ import annotations

import numpy as np

from ..core import masks


def gel_outline(valid: np.ndarray, width: int = 1) -> np.ndarray:
    """(H, W) bool -- the pixels of ``valid`` with one of their 8 neighbours in the frame off it (``width`` > 1: within
    that many 8-neighbour steps of one, the outline and the ``width`` - 1 rings inside it): on a view past the gel its
    outline, pixels the gel covers only in part (a 160x120 wide view's 356: 0.89 on average, 160 under 1) and that
    the lens's defocus mixes with the black beyond, whose light the image model (a whole pixel of surface) overstates
    (their bounce light, 2.3x their direct light on that view's undeformed dome against 0.38x inside, is scaled by the
    coverage too, the image model's is not). None on a gel-filling view (the frame's own border is no outline).

    valid : (H, W) bool -- the reference's pixels on the gel (finite depth); width : rings, >= 1.
    """
    return valid & masks.dilate(~valid, width, masks.SQUARE)


def outline_rings(valid: np.ndarray, rings: int) -> np.ndarray:
    """(H, W) int8 -- each pixel of ``valid``'s ring from the outline: 0 on :func:`gel_outline`, 1 on the ring inside
    it, ... up to ``rings`` - 1; -1 further in and off ``valid`` (none on a gel-filling view).

    valid : (H, W) bool -- the reference's pixels on the gel; rings : >= 1.
    """
    out = np.full(valid.shape, -1, np.int8)
    reach = ~valid
    for k in range(rings):  # one 8-neighbour step a ring: gel_outline(valid, k + 1) is the rings 0..k
        reach = masks.dilate(reach, 1, masks.SQUARE)
        out[valid & reach & (out < 0)] = k
    return out
