"""A camera's undeclared black level (pedestal): the one judgement of a dark frame raised evenly above the
declared black level, shared by the solve's dark-frame check (``solver.exposure.dark_frame_fault``) and the
capture's check of the session's reference (``device.exposure.check_exposure``), neither of which may import the
other's package."""

from __future__ import annotations

import numpy as np

from . import tolerances


def even_dark_offset(dark: np.ndarray, offset: float) -> bool:
    """Whether dark-frame samples sit ``offset`` above the black level evenly, their spread (5th to 95th
    percentile) under :data:`~nlipscalib.core.tolerances.DARK_PEDESTAL_SPREAD` of it: a camera's black level
    (pedestal) not declared, where an LED left lit or room light falls off across the dome.

    Parameters
    ----------
    dark : (N, 3) or (N,) stored values -- the gel's samples of the dark frame (any integer or float dtype).
    offset : float -- their median less the declared black level, in the same stored values (> 0).

    Why: a camera with a pedestal, captured with the default ``--black-level 0``, had every press refused with
    "not a dark frame ... (an LED lit, or room light?); capture it with every LED off" (s36 device walk: the
    emulated sensor's frames through the board's path), which the lab had done: the fix is the black level."""
    low, high = np.percentile(dark, [5, 95])
    return float(high - low) < tolerances.DARK_PEDESTAL_SPREAD * offset


def camera_dn(stored: float, bit_depth: int) -> float:
    """A stored (16-bit) value in the camera's own ``bit_depth``-bit values, as ``nlips capture --black-level``
    takes it."""
    return stored / 2 ** (16 - bit_depth)
