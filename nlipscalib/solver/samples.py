"""Which samples a solve's data term uses: the (LED, pixel, channel) exclusions (dead LEDs, dead pixels,
saturated samples, shadows) and the intensity scale of the usable samples the images are divided by."""

from __future__ import annotations

import functools

import numpy as np

from ..core import masks
from . import threads
from .frame_box import FrameBox
from .image_stats import lit_leds
from .options import SolverOptions


def exclusions(
    images: np.ndarray,
    saturated: np.ndarray | None,
    options: SolverOptions,
    whole: np.ndarray | FrameBox | None = None,
) -> tuple[np.ndarray, dict]:
    """Which (LED, pixel, channel) samples the data term may use, and why others are excluded.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1, finite
    saturated : (L, H, W, 3) bool or None
    options : SolverOptions
    whole : (L, H', W', 3) float, a :class:`.frame_box.FrameBox` of them, or None -- the whole images when
        ``images`` is a crop of them: the dead-LED and shadow thresholds are statistics of the whole images
        (default ``images``).

    Returns
    -------
    usable : (L, H, W, 3) bool
    report : dict -- dead_leds (0-based list), dead_pixels, saturated_samples, shadow_samples (counts)
    """
    per_led_high, per_channel_high = _bright_ends(images if whole is None else whole, images.dtype)
    dead_leds = [int(i) for i in np.flatnonzero(~lit_leds(per_led_high, options.dead_led_level))]
    # Shadow threshold per LED and channel, relative to that image's bright end.
    shadow_level = options.shadow_level * per_channel_high  # (L, 3)
    usable = np.empty(images.shape, bool)

    def rows(part: slice) -> tuple[int, int, int]:
        sat = None if saturated is None else saturated[:, part]
        return _usable_rows(images[:, part], sat, shadow_level, options.dead_pixel_level, usable[:, part])

    # elementwise over (L, H, W, 3): row blocks on the thread pool, the counts (integers) added up
    counts = np.sum(threads.map_items(rows, threads.chunks(images.shape[1])), axis=0, dtype=np.int64)
    usable[dead_leds] = False
    report = {
        "dead_leds": dead_leds,
        "dead_pixels": int(counts[0]),
        "saturated_samples": int(counts[1]),
        "shadow_samples": int(counts[2]),
    }
    return usable, report


def _bright_ends(images: np.ndarray | FrameBox, dtype: np.typing.DTypeLike) -> tuple[np.ndarray, np.ndarray]:
    """The 99th percentile of each image over its pixels and channels, (L,), and per channel, (L, 3).

    ``images`` (L, H, W, 3) float, linear, or a :class:`.frame_box.FrameBox` of them (its samples the same values);
    the percentiles are taken in ``dtype``. Image statistics: a regular subgrid of the pixels
    (:func:`bright_end_pixels`) gives the same 99th percentiles as all of them at a fraction of the cost (this
    dominated small ROI solves). One LED per pool task: the gather and the two percentiles took ~15 ms of one core per
    solve at 640x480 with 12 LEDs, once per outer-loop pass, while the other waited. Each LED's percentiles are
    the same numbers whether taken alone or along an axis of the stack (the same order statistics and
    interpolation), so the same bits."""
    index = bright_end_pixels(images.shape[1:3])

    def percentiles(sample: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sample = sample.astype(dtype, copy=False)
        # NumPy < 2 returns float64 percentiles of float32 samples: cast, so the caller gets ``dtype`` either way
        return np.percentile(sample, 99).astype(dtype), np.percentile(sample, 99, axis=0).astype(dtype)

    if isinstance(images, FrameBox):  # the same samples, read from the frame and the box
        read = images.pixel_reader(index)
        per_led = threads.map_items(lambda i: percentiles(read(i)), range(images.shape[0]))
    else:
        per_led = threads.map_items(lambda image: percentiles(image.reshape(-1, 3)[index]), images)
    return np.array([high for high, _ in per_led]), np.stack([channels for _, channels in per_led])


def bright_end_pixels(shape: tuple[int, int]) -> np.ndarray:
    """(n,) int -- the flat (row-major) pixels of an (H, W) image whose samples give its bright ends (the dead-LED
    and shadow thresholds of :func:`exclusions`): a regular subgrid (:func:`nlipscalib.core.masks.sample_grid`)."""
    return np.flatnonzero(masks.sample_grid(np.ones(shape, bool)))


def _usable_rows(
    images: np.ndarray, saturated: np.ndarray | None, shadow_level: np.ndarray, dead_level: float, out: np.ndarray
) -> tuple[int, int, int]:
    """:func:`exclusions`' samples on a block of rows, written to ``out``; (dead pixels, saturated samples,
    shadow samples not saturated) counted there.

    Parameters
    ----------
    images : (L, h, W, 3) float; saturated : (L, h, W, 3) bool or None
    shadow_level : (L, 3) float -- a sample below its LED's and channel's level is in shadow.
    dead_level : a pixel no LED lights above this in any channel is dead.
    out : (L, h, W, 3) bool, written.
    """
    L, h, w, c = images.shape
    # max over LEDs first (a reduction along the contiguous leading axis), then over the channels one by one
    # (a reduction along the 3-long last axis took 12 ms of a whole frame's 15)
    brightest = images.max(axis=0)
    dead_px = functools.reduce(np.maximum, [brightest[..., k] for k in range(c)]) <= dead_level
    # The per-channel levels repeated along a row, so that NumPy's loops run along whole (w, c) rows: broadcast
    # along a 3-long last axis they took 30 ms of a whole frame's 40. In ``out`` itself, counted as it goes
    # (count_nonzero, no temporaries); the images are finite, so not in shadow is ``>=`` the level.
    np.greater_equal(images, np.tile(shadow_level, (1, w)).reshape(L, 1, w, c), out=out)
    if saturated is None:
        n_sat, shadow = 0, out.size - np.count_nonzero(out)
    else:
        np.greater(out, saturated, out=out)  # lit and not saturated (booleans: a > b is a and not b)
        n_sat = np.count_nonzero(saturated)
        shadow = out.size - n_sat - np.count_nonzero(out)  # shadow and not saturated: neither lit nor saturated
    out &= np.repeat(~dead_px, c, axis=-1).reshape(1, h, w, c)
    return int(dead_px.sum()), int(n_sat), int(shadow)


def high_level(images: np.ndarray, usable: np.ndarray) -> float:
    """The images' 99th percentile over the usable samples (1 where there is none or it is not positive): the
    value of ``np.percentile(images[usable], 99)``, to the bit.

    Parameters
    ----------
    images : (L, h, w, 3) float; usable : (L, h, w, 3) bool
    """
    n = int(np.count_nonzero(usable))
    if n == 0:
        return 1.0
    # numpy's linear method: the order statistics at floor(v) and the next, v = (n - 1) q, interpolated
    virtual = (n - 1) * (99 / 100)
    below = int(np.floor(virtual))
    top, n_under = _top_samples(images, usable, n, below)
    ranks = sorted({below - n_under, min(below + 1, n - 1) - n_under})
    top.partition(ranks)
    scale = float(_lerp(top[ranks[0]], top[ranks[-1]], virtual - below))
    return scale if scale > 0 else 1.0


def _top_samples(images: np.ndarray, usable: np.ndarray, n: int, rank: int) -> tuple[np.ndarray, int]:
    """The usable samples from a bound at or below the one of order ``rank`` (0-based, of ``n``) up, and how many
    usable samples lie under that bound: an order statistic of the few percent at the top is that of all of them.

    A partition of every usable sample of a 640x480 frame (~10^7) took 0.05 s of each NLiPs call, and gathering
    them 0.03 s more; the bound is a lower percentile of a 1-in-64 subsample. Where it is not low enough (a sample
    unlike the whole), every usable sample is returned, under a bound of 0.

    Returns
    -------
    (k,) float, a new array (any order); the count of usable samples under it.
    """
    sub = images[:, ::8, ::8][usable[:, ::8, ::8]]
    if sub.size:
        bound = np.percentile(sub, 98)
        above = images >= bound
        above &= usable
        top = images[above]
        if n - top.size <= rank:
            return top, n - top.size
    # a flat boolean index: indexing the (L, h, w, 3) array with a mask that selects every sample took 0.11 s
    # at 640x480 against 0.01 s
    return images.reshape(-1)[usable.reshape(-1)], 0


def _lerp(a: np.floating, b: np.floating, t: float) -> np.floating:
    """numpy's interpolation of a percentile between its order statistics ``a <= b`` at ``t`` in [0, 1), in their
    dtype, the same bits (``numpy.lib._function_base_impl._lerp``: from the nearer end)."""
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t
