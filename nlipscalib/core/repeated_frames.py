"""LED images that repeat the image captured before them, whole or in part: a camera whose frames lag the LED switch.

Why: a USB camera with a deep frame queue (or a driver that ignores ``CAP_PROP_BUFFERSIZE``) can hand out, after
the LEDs switch from LED k-1 to LED k, a frame exposed before the switch. The capture then holds LED k-1's light
under LED k's name, and nothing downstream said so (s27 QA walk, webcam-grade camera on the one-bounce twin at
320x240): ``nlips calibrate-leds`` fitted LED 5 at LED 4's place and called the fit "reliable" (residual 1.05x the
noise), and ``nlips solve --roi auto`` gave a contact AAE of 0.62 / 0.76 deg on the sphere / cube press instead
of 0.47 / 0.46. Two different LEDs never light the gel alike, so an LED image within noise of its predecessor is
that predecessor's light.

Partly (:func:`lagged_bands`): a rolling shutter reads the rows one after another over a good part of the frame time
(~30 ms on a USB webcam); a frame whose readout the LED switch falls into holds the light captured before it (LED
k-1's) above a row and LED k's below it. Whole-frame medians missed it (s28 QA: LED 5
of the twin's sphere press with its top half from LED 4 was called a repeat, its top quarter not seen at all), so
the check compares the images row of blocks by row of blocks.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .tolerances import (
    CAPTURE_CHECK_BLUR,
    EXPOSURE_LIGHT_FRACTION,
    LAGGED_BAND_ROWS,
    REPEATED_FRAME_DIFFERENCE,
)

MIN_LIT_PIXELS = 100
"""Fewest lit gel pixels two images need for a verdict (a smaller lit patch says nothing either way)."""
MIN_LIT_ROW_BLOCKS = 8
"""Fewest lit blocks a row of blocks needs to count in :func:`lagged_bands` (200 pixels: its median is steady)."""


class LaggedBand(NamedTuple):
    """Rows of one LED image that hold the light captured before it (:func:`lagged_bands`)."""

    index: int
    """The LED image, 0-based in capture order."""
    rows: tuple[int, int]
    """First and one-past-last pixel row of the band (block rows: to :data:`CAPTURE_CHECK_BLUR` pixels)."""
    top: bool
    """The band is at the image's top (a shutter reading downwards), else at its bottom."""


def repeated_leds(linear: np.ndarray, gel: np.ndarray) -> list[tuple[int, float]]:
    """The LED images that repeat the image captured just before them, in capture order (:func:`frame_lags`'s first
    list)."""
    return frame_lags(linear, gel)[0]


def frame_lags(linear: np.ndarray, gel: np.ndarray) -> tuple[list[tuple[int, float]], list[LaggedBand]]:
    """The LED images that repeat the image captured before them, whole and in part (one block average each).

    Parameters
    ----------
    linear : (L, H, W, 3) float -- the LED images in capture order, linear (dark frame subtracted, full scale 1:
        :func:`nlipscalib.core.sensor_response.linearise`).
    gel : (H, W) bool -- the pixels that see the gel.

    Returns
    -------
    repeated : list of (index, difference) -- ``index`` (0-based, >= 1) of each LED image whose median relative
        difference from image ``index - 1`` over the pixels either lights (above
        :data:`~nlipscalib.core.tolerances.EXPOSURE_LIGHT_FRACTION`), both averaged over blocks of
        :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` pixels a side (:func:`_block_means`), is below
        :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE`, and which holds no rows of its own light
        (then it is a lagged band); empty when none is.
    bands : list of LaggedBand -- the images lagged only in part (:func:`lagged_bands`).
    """
    inside = _block_means(np.asarray(gel, np.float32)[..., None]) > 1 - 1e-6  # blocks wholly on the gel (rounding)
    blocks = [_block_means(image) for image in linear]
    bands = lagged_bands(blocks, inside)
    partly = {band.index for band in bands}
    found = []
    for index in range(1, len(blocks)):
        current, previous = blocks[index][inside], blocks[index - 1][inside]
        brighter = np.maximum(current, previous)
        lit = brighter > EXPOSURE_LIGHT_FRACTION
        if index not in partly and lit.sum() * CAPTURE_CHECK_BLUR**2 >= MIN_LIT_PIXELS:
            difference = float(np.median(np.abs(current[lit] - previous[lit]) / brighter[lit]))
            if difference < REPEATED_FRAME_DIFFERENCE:
                found.append((index, difference))
    return found, bands


def lagged_bands(blocks: list[np.ndarray], inside: np.ndarray) -> list[LaggedBand]:
    """The LED images whose top or bottom rows hold the light captured before them: the LED switched while a
    rolling shutter read the frame out.

    Row of blocks by row of blocks, over the blocks either image lights: the median relative difference from the
    previous LED image (below :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE`: that image's light). An
    image whose first (or last) :data:`~nlipscalib.core.tolerances.LAGGED_BAND_ROWS` rows or more are that light,
    and not all of its rows, is lagged in part.

    Parameters
    ----------
    blocks : list of (h, w) float32 -- the LED images' block means (:func:`_block_means`), in capture order.
    inside : (h, w) bool -- the blocks wholly on the gel.

    Returns
    -------
    list of LaggedBand -- one per partly lagged image, in capture order; empty when none is.
    """
    bands = []
    for index in range(1, len(blocks)):
        current, neighbour = blocks[index], blocks[index - 1]
        brighter = np.maximum(current, neighbour)
        lit = inside & (brighter > EXPOSURE_LIGHT_FRACTION)
        rows = np.flatnonzero(lit.sum(axis=1) >= MIN_LIT_ROW_BLOCKS)
        if len(rows) <= LAGGED_BAND_ROWS:
            continue
        scale = np.where(lit[rows], brighter[rows], 1)
        difference = _row_medians(np.abs(current[rows] - neighbour[rows]) / scale, lit[rows])
        # 1: the previous LED's light, 0: the image's own light. Dark rows (read while no LED was lit) are not
        # looked for: an LED's own light can end as sharply at its terminator (the synthetic ring with LEDs far from
        # their design: dark top rows in 2 of 12 images, s28-rolling); the weak-LED check leaves such an LED out
        kind = (difference < REPEATED_FRAME_DIFFERENCE).astype(np.int8)
        if band := _edge_band(kind, rows, index):
            bands.append(band)
    return bands


def _row_medians(values: np.ndarray, counted: np.ndarray) -> np.ndarray:
    """(n,) float: the median of each row of ``values`` (n, w) over its ``counted`` entries (at least one each).
    A sort with the others pushed to the end: np.nanmedian took ~10 ms an image at 640x480, this ~0.3 ms."""
    ordered = np.sort(np.where(counted, values, np.inf), axis=1)
    count = counted.sum(axis=1)
    at = np.arange(len(values))
    return 0.5 * (ordered[at, (count - 1) // 2] + ordered[at, count // 2])


def _edge_band(kind: np.ndarray, rows: np.ndarray, index: int) -> LaggedBand | None:
    """The band of rows of the previous image's light (``kind`` 1) at the top, else at the bottom, of the counted
    ``rows`` (block rows, ascending) when it is :data:`LAGGED_BAND_ROWS` long or more and not all of them."""
    b = CAPTURE_CHECK_BLUR
    for top in (True, False):
        ordered = kind if top else kind[::-1]
        if ordered[0] == 0:
            continue
        run = int(np.argmax(ordered != ordered[0])) if (ordered != ordered[0]).any() else len(ordered)
        if LAGGED_BAND_ROWS <= run < len(ordered):
            span = (int(rows[0]) * b, int(rows[run]) * b) if top else (int(rows[-run]) * b, (int(rows[-1]) + 1) * b)
            return LaggedBand(index, span, top)
    return None


def _block_means(image: np.ndarray) -> np.ndarray:
    """(H // b, W // b) float32: the channels' mean of one (H, W, C) image over b x b blocks
    (b = :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR`; the last H % b rows and W % b columns left out).
    Block means, not a sliding box blur: they average the noise alike (b * b pixels each) at a twenty-fifth of the
    samples, and every solve runs this check on 12 full frames (a box blur with scipy.ndimage took 0.1 s and its
    import 0.09 s of a 640x480 solve's ~2 s, s27 lead)."""
    import cv2  # imported by the solve already (core.camera)

    b = CAPTURE_CHECK_BLUR
    h, w = image.shape[0] // b, image.shape[1] // b
    # INTER_AREA at an integer factor is the b x b block mean (~1 ms at 640x480; NumPy's reduction over the
    # reshaped block axes took 1.5 ms an image)
    blocks = cv2.resize(np.asarray(image[: h * b, : w * b], np.float32), (w, h), interpolation=cv2.INTER_AREA)
    return blocks.reshape(h, w, -1).mean(axis=2, dtype=np.float32)


def repeated_line(folder: object, names: list[str], repeated: list[tuple[int, float]]) -> str:
    """One line naming the repeated LED images (``names`` in capture order) and the fix."""
    said = ", ".join(
        f"{names[i]} repeats {names[i - 1]} ({100 * difference:.1f} % apart)" for i, difference in repeated
    )
    return (
        f"{folder}: {said}: the camera handed out a frame exposed before the LED switched (frames lag the LEDs); "
        "capture again with a larger --flush (frames dropped after each LED change) or CAP_PROP_BUFFERSIZE 1"
    )


def lagged_line(folder: object, names: list[str], bands: list[LaggedBand]) -> str:
    """One line naming the partly lagged LED images (``names`` in capture order), their rows, the cause and the fix."""
    said = []
    for band in bands:
        where = f"rows {band.rows[0]}-{band.rows[1] - 1} ({'top' if band.top else 'bottom'})"
        said.append(f"{names[band.index]}'s {where} show {names[band.index - 1]}'s light")
    return (
        f"{folder}: {'; '.join(said)}: the LEDs switched while the camera read the frame out (a rolling shutter "
        "reads the rows one after another: a frame read across the switch holds both lights); capture again with "
        "--flush 1 or more (frames dropped after each LED change, default 2), and a frame source that drops them "
        "(a recorded video or image sequence does not)"
    )
