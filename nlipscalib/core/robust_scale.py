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
    c = median(r) if center is None else center
    # float() before the product: a float32 median times a Python float stays float32 under NumPy 2
    return MAD_TO_SIGMA * float(median(np.abs(r - c)))


SELECT_MIN_SIZE = 20_000
"""Samples from which :func:`median` selects within a band (fewer: ``np.median`` of them all)."""

BAND_SAMPLES = 4096
"""Evenly spaced samples whose sorted order gives :func:`median`'s band."""

BAND_HALF_WIDTH = 0.05
"""Half-width of :func:`median`'s band in quantiles of its samples: 6 standard errors of a median of 4096."""


def median(values: np.ndarray) -> np.floating:
    """``np.median`` of a float sample, the same value to the bit (NaN where it has one).

    Why: ``np.median`` partitions a copy of the whole sample; here only the values within a band around an
    evenly spaced subsample's median are copied and partitioned, after two counts, and the middle order
    statistics are averaged as ``np.median`` does (``np.mean`` of one or two values in their dtype). A median of
    190,000 float32 samples took 1.9 ms of one core, ~0.5 ms here (benchmarks/RESULTS.md, s21-cpu). Where the
    middle is not in the band (a subsample unlike the whole), or a value is NaN, ``np.median`` of them all.

    Parameters
    ----------
    values : (...) float -- any shape (flattened), any unit.

    Returns
    -------
    the median, a scalar of ``values``' dtype.
    """
    x = np.asarray(values).ravel()
    n = x.size
    if n < SELECT_MIN_SIZE or x.dtype.kind != "f":
        return np.median(x)
    sub = np.sort(x[:: n // BAND_SAMPLES])
    lo = sub[int(sub.size * (0.5 - BAND_HALF_WIDTH))]
    hi = sub[int(sub.size * (0.5 + BAND_HALF_WIDTH))]
    below = np.count_nonzero(x < lo)
    band = x[(x >= lo) & (x <= hi)]
    middle = [n // 2] if n % 2 else [n // 2 - 1, n // 2]  # np.median's ranks
    ranks = [k - below for k in middle]
    # a NaN is in no count: then the three do not add up to n
    if ranks[0] < 0 or ranks[-1] >= band.size or below + band.size + np.count_nonzero(x > hi) != n:
        return np.median(x)
    band.partition(ranks)
    return np.mean(band[ranks])
