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
    one pixel in 8, a 96x72 one all).
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

    est = [e for per in threads.map_items(per_image, images) for e in per]
    return float(np.median(est))
