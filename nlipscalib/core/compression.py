"""LED images that went through JPEG (a camera streaming MJPEG, or frames saved as JPEG): their 8x8 blocks.

Why: JPEG quantises each 8x8 block's cosine coefficients on its own, so the values step across block edges more
than they change inside a block. Photometric stereo reads those steps as shading: the one-bounce twin's 8-bit
linear captures through JPEG quality 85 solved to a contact AAE of 1.21 / 0.98 deg on the sphere / cube press
instead of 0.47 / 0.46, and nothing said so (s27 QA walk, webcam-grade camera).

The statistic follows the blocking feature of Wang, Sheikh and Bovik (2002, "No-reference perceptual quality
assessment of JPEG compressed images", ICIP): the mean absolute difference of neighbouring pixels across block
boundaries against the same mean inside the blocks, horizontally and vertically. Two changes: each step's
difference is taken less the mean of the steps either side (:func:`_phase_means`: the gel's smooth shading cancels),
and each of the 8 phases of the grid gets its mean, the largest against the median of the 8 (a frame cut out at a
column that is not a multiple of 8 keeps its blocks at another phase); the smaller of the two directions is kept
(JPEG blocks both; a scene's stripes at an 8-pixel period rarely do). No library computes it (scikit-image, OpenCV
and scipy have no blockiness measure).
"""

from __future__ import annotations

import numpy as np

from .sensor_response import CAMERA_SETTINGS_GUIDE
from .tolerances import JPEG_BLOCKINESS

BLOCK = 8
"""JPEG's block side, pixels (the luma's; the chroma's 16 with 4:2:0 subsampling falls on the same edges)."""
SAMPLE_LINES = 64
"""Every k-th row (for the steps along the rows) and column (along the columns) is read, k odd (prime to
:data:`BLOCK`: the samples cover every row of a block alike) and at most 7, with at least this many lines read
where the frame has them: a seventh of a 640x480 frame keeps the check at ~4 ms, and a small frame
is read whole (at 64x48 a seventh of it left the 8 phases' means 18 % apart on noise-free images)."""
MAX_IMAGES = 6
"""At most this many LED images are read, spread over the ring (every k-th): each holds the blocks alike, and 6
of a 640x480 press's 12 keep ~30 000 steps per phase at half the cost (~4 ms instead of ~9)."""
OUTLIER_JUMP = 4.0
"""Each jump counts at most this many times the mean jump of its direction: a few glints or a marker (the
synthetic 64x48 dome with 20 of its pixels saturated in one image read 4.4 without the cap, 1.07 with it) must not
make one phase stand out."""
MIN_PAIRS = 50
"""Fewest neighbour pairs on the gel per phase and direction for a verdict (a smaller gel says nothing)."""


def blockiness(images: np.ndarray, gel: np.ndarray) -> float | None:
    """How much more the LED images change across the edges of an 8x8 block grid than inside its blocks.

    Parameters
    ----------
    images : (L, H, W, 3) stored values (any dtype: raw DN, not linearised: JPEG coded these values) -- the LED
        images; their green channel is read (the nearest to JPEG's luma, coded at full resolution).
    gel : (H, W) bool -- the pixels that see the gel; a pair counts when both its pixels do.

    Returns
    -------
    float, or None when the gel holds fewer than :data:`MIN_PAIRS` steps per phase or the images are flat -- the
    smaller over the two directions of (largest phase's mean discontinuity) / (median over the 8 phases): about 1
    for a frame never compressed (the twin's 1.00-1.01), 1.5-1.9 after JPEG quality 85.
    """
    images = np.asarray(images)
    green = images[:: -(-len(images) // MAX_IMAGES), ..., 1]
    gel = np.asarray(gel, bool)
    step = max(1, min(7, min(gel.shape) // SAMPLE_LINES)) | 1
    across_columns = _phase_means(green[:, ::step, :], gel[::step, :])
    across_rows = _phase_means(np.swapaxes(green[:, :, ::step], 1, 2), gel[:, ::step].T)
    if across_columns is None or across_rows is None:
        return None
    typical = min(np.median(across_columns), np.median(across_rows))
    if typical <= 0:  # flat images (black, or saturated throughout): no jumps, no verdict
        return None
    return float(min(ratio.max() / np.median(ratio) for ratio in (across_columns, across_rows)))


def _phase_means(lines: np.ndarray, gel: np.ndarray) -> np.ndarray | None:
    """(8,) float64: the mean discontinuity along the last axis of (L, n, W) ``lines`` by the phase (column mod 8)
    of the step's first pixel, over the steps whose four pixels are on ``gel`` (n, W); None below MIN_PAIRS.

    The discontinuity of the step from column x to x + 1 is its difference less the mean of the steps either side,
    ``|2 d(x) - d(x - 1) - d(x + 1)|``: a linear shading gradient cancels, so a small capture's steep shading does
    not drown the blocks (as the plain difference ``|d(x)|`` did: the twin at 96x72 through JPEG quality 85 gave
    1.27 with it, 1.7-1.9 with this)."""
    width = (lines.shape[-1] - 3) // BLOCK * BLOCK
    if width <= 0:
        return None
    inside = gel[:, : width + 3]
    every = inside[:, :width] & inside[:, 1 : width + 1] & inside[:, 2 : width + 2] & inside[:, 3 : width + 3]
    pairs = every.reshape(-1, BLOCK).sum(axis=0) * len(lines)
    if pairs.min() < MIN_PAIRS:
        return None
    # 2 d(x) - d(x - 1) - d(x + 1) with d(x) = I(x + 1) - I(x), from the values: I(x + 2) - I(x - 1) - 3 d(x),
    # in place, with few temporaries: this runs on every solve
    values = lines[..., : width + 3].astype(np.float32)
    jump = values[..., 3:] - values[..., :width]
    jump -= 3 * (values[..., 2 : width + 2] - values[..., 1 : width + 1])
    np.abs(jump, out=jump)
    jump *= every
    np.minimum(jump, OUTLIER_JUMP * jump.sum(dtype=np.float64) / pairs.sum(), out=jump)
    sums = jump.reshape(-1, BLOCK).sum(axis=0, dtype=np.float64)
    return sums / pairs


def blockiness_line(folder: object, what: str, value: float) -> str:
    """One line naming the compressed images (``what``), the measure and the fix."""
    return (
        f"{folder}: {what} show JPEG compression blocks (values jump {value:.1f} times as much across an 8x8 "
        f"block grid's edges as inside its blocks; an uncompressed frame about 1, the limit {JPEG_BLOCKINESS:g}): a "
        f"camera streaming MJPEG, or images saved as JPEG? Photometric stereo reads the steps as shading (the twin "
        f"at quality 85: contact AAE 1.0-1.2 deg instead of 0.47): capture an uncompressed format (YUYV or Y16: "
        f"CAP_PROP_FOURCC) and store PNG ({CAMERA_SETTINGS_GUIDE})"
    )


def compressed(images: np.ndarray, gel: np.ndarray) -> float | None:
    """:func:`blockiness` when it is above :data:`~nlipscalib.core.tolerances.JPEG_BLOCKINESS` (the images went
    through JPEG), else None."""
    value = blockiness(images, gel)
    return value if value is not None and value > JPEG_BLOCKINESS else None
