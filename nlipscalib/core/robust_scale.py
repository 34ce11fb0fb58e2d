"""Robust scale of a sample: the one copy of 1.4826 x MAD (used by solver/ and learn/, neither of which may
import the other)."""

from __future__ import annotations

import numpy as np

MAD_TO_SIGMA = 1.4826
"""1 / Phi^-1(3/4): the median absolute deviation of a normal sample times this is its standard deviation."""


def mad_scale(values: np.ndarray, center: float | None = None, dtype: type[np.floating] = np.float64) -> float:
    """Robust standard deviation: 1.4826 x the median absolute deviation (0 for an empty input).

    Parameters
    ----------
    values : (...) float -- the sample, any shape (flattened), any unit; the result is in the same unit.
    center : the sample's median when the caller already has it (a second median of a live frame's sample
        is not free); None computes it.
    dtype : the precision the medians are taken in. float64 by default; a float32 caller passes float32 to keep
        its arithmetic (and the live change rule's parity with its float32 torch copy) without a float64 copy.

    Returns
    -------
    float -- the scale, >= 0.
    """
    r = np.asarray(values, dtype=dtype).ravel()
    if r.size == 0:
        return 0.0
    c = np.median(r) if center is None else center
    # float() before the product: a float32 median times a Python float stays float32 under NumPy 2
    return MAD_TO_SIGMA * float(np.median(np.abs(r - c)))
