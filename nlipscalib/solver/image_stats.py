"""Statistics of a press's LED images: each image's bright end, which images hold light, the images' noise.

Shared by the contact classification (:mod:`.contact`), the indirect fit, the LED calibration and the
exposure checks: one copy of each statistic.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core import masks, tolerances
from ..core.robust_scale import mad_scale
from . import reuse, threads

NOISE_SAMPLES = masks.STATISTIC_PIXELS
"""Pixels :func:`image_noise` and :func:`led_levels` sample at least (all of the gel when it has fewer)."""


def led_levels(images: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Bright end of each LED image: the 99th percentile over the gel's pixels and the channels.

    A statistic, taken on a regular subgrid of the gel of at least ``NOISE_SAMPLES`` pixels
    (:func:`nlipscalib.core.masks.sample_grid`: the same dead-LED verdicts at a fraction of the cost of all
    10^6 samples per image, which cost ~0.5 s per call at 640x480).

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear images.
    valid : (H, W) bool -- the gel's pixels.

    Returns
    -------
    (L,) float64 -- zeros when no pixel is valid.
    """
    if not valid.any():
        return np.zeros(len(images))

    def levels() -> np.ndarray:
        index = np.flatnonzero(masks.sample_grid(valid, NOISE_SAMPLES))
        # one LED per pool task (each its own percentile, so the same numbers): ~13 ms of one core at 640x480
        return np.array(
            threads.map_items(lambda image: np.percentile(image.reshape(-1, image.shape[-1])[index], 99), images)
        )

    if not isinstance(images, np.ndarray) or images.flags.writeable:
        return levels()
    # a press's read-only linear images (``Press.linear_led_images``): a press fitted on itself asks twice, for
    # its indirect fit and its contact classification (13 ms each at 640x480). The store holds the images: no
    # other array takes their id while it does.
    return reuse.reused("led levels", (id(images), reuse.digest(valid)), levels, keep=images, most=1)


def lit_leds(levels: np.ndarray, dead_level: float = tolerances.LIT_LEVEL) -> np.ndarray:
    """Which LED images hold light: bright end at least ``dead_level`` and at least
    :data:`~nlipscalib.core.tolerances.DEAD_LED_FRACTION` of the median LED image's (a dead LED's image is the dark
    frame's noise, whose bright end can pass ``dead_level``).

    Parameters
    ----------
    levels : (L,) float -- :func:`led_levels` (or another 99th percentile of each LED image), linear units.
    dead_level : float -- absolute level, linear units (``SolverOptions.dead_led_level`` in a solve).

    Returns
    -------
    (L,) bool
    """
    levels = np.asarray(levels, float)
    if levels.size == 0:
        return np.zeros(0, bool)
    return levels >= max(dead_level, tolerances.DEAD_LED_FRACTION * float(np.median(levels)))


def image_noise(images: np.ndarray | Sequence[np.ndarray], valid: np.ndarray) -> float:
    """Noise sigma of linear images (Immerkaer 1996: a Laplacian-difference mask cancels smooth shading).

    Parameters
    ----------
    images : (L, H, W, 3) float, or a sequence of L (H, W, 3) float -- linear images.
    valid : (H, W) bool -- pixels to measure on (eroded by one so the gel's border does not count).

    Returns
    -------
    float -- median over LEDs and channels of the per-image estimate (robust form: 1.4826 MAD of the
    filtered image over sqrt(36), the mask's squared norm). The medians are taken on a regular subsample
    of the gel, at least ``NOISE_SAMPLES`` pixels where the gel has them (a statistic: the MAD of 2x10^4
    samples is within ~1 % of the MAD of all of them, and 36 estimates are pooled; a 640x480 dome keeps
    one pixel in 8, a 96x72 one all). Images of a Bayer camera (:func:`bayer_noise`, more than
    :data:`BAYER_NOISE_RATIO` times this) get that estimate instead.
    """
    import cv2

    inner = masks.erode(valid, iterations=2)
    if inner.sum() < 16:
        return 0.0
    index = np.flatnonzero(masks.sample_grid(inner, NOISE_SAMPLES))
    kernel = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], np.float32)

    def per_image(img: np.ndarray):
        # the kernel is symmetric: correlation (OpenCV) = convolution; replicated border = scipy's "nearest"
        filtered = cv2.filter2D(np.asarray(img, np.float32), -1, kernel, borderType=cv2.BORDER_REPLICATE)
        out = []
        for f in filtered.reshape(-1, filtered.shape[-1])[index].T:  # flat indices: a third of a mask's cost
            out.append(mad_scale(f, dtype=np.float32) / 6.0)  # float32: the filtered image's precision
        return out

    est = float(np.median([e for per in threads.map_items(per_image, images) for e in per]))
    first = images[0] if len(images) else None
    if first is None or not bayer_noise([first], inner) > BAYER_NOISE_RATIO * max(est, np.finfo(np.float32).tiny):
        return est
    return bayer_noise(images, inner)


BAYER_NOISE_RATIO = 2.0
""":func:`image_noise` takes :func:`bayer_noise` where the first image's is more than this times the plain estimate
(of all images): a Bayer camera's demosaicing interpolates each colour linearly between the pixels that record it,
which the plain 3x3 mask cancels at three pixels in four (red, blue) or one in two (green): its median filtered value
was 0, the noise 3.5e-8 for 0.016 of an RGB camera's on the same light, and the solve anchored no pixel of the
undeformed gel (depth 0.13 mm off, 0.045 -> 0.19 mm RMSE on the contact; docs/experiments/RESULTS.md, s43-bayer).
On independent pixels the two agree (within a few %), and the plain one is kept: every three-colour capture's
numbers as before."""


def bayer_noise(images: np.ndarray | Sequence[np.ndarray], inner: np.ndarray) -> float:
    """Noise sigma of linear images of a camera whose pixels come in a 2x2 pattern (a Bayer mosaic, demosaiced): the
    Immerkaer mask over every second pixel (its 9 taps 2 px apart, so each filtered value mixes pixels of one of
    the pattern's four positions), its robust spread taken per position and channel, the largest of the four
    positions per channel (the pixels that record that colour: their own raw noise; the others are interpolated
    and hold less), then the median over images and channels.

    Parameters
    ----------
    images : (L, H, W, 3) float, or a sequence of L (H, W, 3) float -- linear images.
    inner : (H, W) bool -- pixels to measure on (the gel, eroded).

    Returns
    -------
    float
    """
    import cv2

    kernel = np.zeros((5, 5), np.float32)
    kernel[::2, ::2] = [[1, -2, 1], [-2, 4, -2], [1, -2, 1]]
    width = inner.shape[1]
    phases = []
    for dy, dx in ((0, 0), (0, 1), (1, 0), (1, 1)):
        sub = np.flatnonzero(masks.sample_grid(inner[dy::2, dx::2], NOISE_SAMPLES // 4))
        rows, cols = np.divmod(sub, inner[dy::2, dx::2].shape[1])
        phases.append((2 * rows + dy) * width + 2 * cols + dx)

    def per_image(img: np.ndarray):
        filtered = cv2.filter2D(np.asarray(img, np.float32), -1, kernel, borderType=cv2.BORDER_REPLICATE)
        flat = filtered.reshape(-1, filtered.shape[-1])
        spread = [[mad_scale(flat[index, c], dtype=np.float32) / 6.0 for c in range(flat.shape[1])] for index in phases]
        return list(np.max(spread, axis=0)) if all(len(index) for index in phases) else [0.0]

    return float(np.median([e for per in threads.map_items(per_image, images) for e in per]))
