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
the check compares the images row of blocks by row of blocks, then column by column (a camera mounted turned 90
degrees: its rolling shutter reads the columns; the same test on the transposed blocks).
Where the capture's LED model is given (:class:`ModelLight`: its design's LEDs, or the solve's), a line counts only
where the model's lights of the two LEDs differ: LEDs designed in close pairs (0.5-1.2 mm apart) light the gel far
from the pair within 1 % of each other, which the images alone took for the previous LED's light (every clean
capture of such designs warned, s35-pairband). The model's light at the blocks is kept per design in the process
(:func:`model_blocks`), and each line's median is only compared with a threshold, by counts
(:func:`median_at_least`: the same verdicts, a sort only on a tie; s36-lagcost). The consecutive LEDs a lag between
which the model leaves unseen over much of the gel are named once: :mod:`nlipscalib.core.lag_blind`.

Dark rows (:func:`dark_bands`, :func:`dark_everywhere`): rows read while no LED was lit (the LED switched on late, or
off early, against the readout; a global-reset sensor's exposure that missed the LED in some rows) hold the dark
frame's level, not the previous LED's light. One LED's dark band is told from its own light's terminator by the LED
model (the solve's :func:`nlipscalib.solver.led_checks.led_check` feeds :func:`dark_bands` its samples); rows dark in
every LED image by the images alone (the LEDs together light the whole gel). Columns alike (a camera mounted turned 90
degrees: its rolling shutter reads the image's columns); bands shorter than the samples' bands of rows tell
(:func:`dark_candidates`) are told row by row on denser samples (:func:`dark_lines`; every LED image's:
:func:`dark_everywhere_lines`). A solve leaves out an LED's dark band, or its lagged band, for that LED only
(:func:`dark_band_mask`).
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from .diskcache import digest
from .tolerances import (
    CAPTURE_CHECK_BLUR,
    DARK_BAND_LIGHT,
    DARK_BAND_MARGIN,
    DARK_BAND_ROWS,
    DARK_BAND_SHARE,
    DARK_CANDIDATE_SHARE,
    DARK_LINES_MIN,
    EXPOSURE_LIGHT_FRACTION,
    LAGGED_BAND_CONTRAST,
    LAGGED_BAND_ROWS,
    REPEATED_FRAME_DIFFERENCE,
)

MIN_LIT_PIXELS = 100
"""Fewest lit gel pixels two images need for a verdict (a smaller lit patch says nothing either way)."""
MIN_LIT_ROW_BLOCKS = 8
"""Fewest lit blocks a row (column) of blocks needs to count in :func:`lagged_bands` (200 pixels: its median is
steady)."""
MIN_ROW_SAMPLES = 8
"""Fewest samples a band of :data:`CAPTURE_CHECK_BLUR` rows needs to count in :func:`dark_bands` (the solve's
~2000 gel samples give ~20 a band at 640x480, ~40 at 320x240)."""
EVERYWHERE_SAMPLES = 2000
"""Gel pixels :func:`dark_everywhere_lines` samples, at least (every k-th in raster order), as the solve's LED check
(:data:`nlipscalib.solver.led_checks.CHECK_PIXELS`): ~20 a band of 5 rows at 640x480."""
EVERYWHERE_LINE_SAMPLES = 100
"""Samples a pixel row (column) gets, about, where :func:`dark_everywhere_lines` looks line by line (as
:data:`nlipscalib.solver.led_checks.DENSE_LINE_SAMPLES`)."""
MIN_LINE_SAMPLES = 16
"""Fewest dense samples a pixel row (column) needs to count in :func:`dark_lines` (the solve samples ~100 a row:
:data:`nlipscalib.solver.led_checks.DENSE_LINE_SAMPLES`)."""
RING_SIDE_IMAGES = 3
"""Images each side of an LED image and the one before it that :func:`lagged_bands` looks along the ring, with a
model, for one whose LED the model tells from the previous LED at a line (an LED's partner in a close pair, or both
others of a close triple, light the gel there as it does)."""
LIT_QUANTILE = 0.95
"""The quantile of an LED's light (over the modelled light) that stands for its lit samples when over half of them
are dark (:func:`lit_level`): a dark band can cover at most this share of its image and be found."""


class LaggedBand(NamedTuple):
    """Rows (or columns) of one LED image that hold the light captured before it (:func:`lagged_bands`)."""

    index: int
    """The LED image, 0-based in capture order."""
    rows: tuple[int, int]
    """First and one-past-last pixel row (``axis`` "columns": column) of the band (blocks: to
    :data:`CAPTURE_CHECK_BLUR` pixels)."""
    top: bool
    """The band is at the image's top (a shutter reading downwards; columns: its left), else at its bottom (right)."""
    axis: str = "rows"
    """"rows", or "columns": a camera mounted turned 90 degrees, its rolling shutter reading the image's columns."""

    @property
    def where(self) -> str:
        """ "top" or "bottom" of the rows; "left" or "right" of the columns."""
        return ("top" if self.top else "bottom") if self.axis == "rows" else ("left" if self.top else "right")


class DarkBand(NamedTuple):
    """Rows (or columns) of an LED image (or of every one) at the dark frame's level: read while no LED was lit."""

    index: int | None
    """The LED image, 0-based in capture order; None: every LED image (:func:`dark_everywhere`)."""
    rows: tuple[int, int]
    """First and one-past-last pixel row (``axis`` "columns": column) of the band: to :data:`CAPTURE_CHECK_BLUR`
    pixels (:func:`dark_bands`), to the pixel (:func:`dark_lines`)."""
    where: str
    """"top", "bottom" or "middle" of the rows that count; "left", "right" or "middle" of the columns."""
    axis: str = "rows"
    """"rows", or "columns": a camera mounted turned 90 degrees, its rolling shutter reading the image's columns."""


def repeated_leds(linear: np.ndarray, gel: np.ndarray) -> list[tuple[int, float]]:
    """The LED images that repeat the image captured just before them, in capture order (:func:`frame_lags`'s first
    list)."""
    return frame_lags(linear, gel)[0]


def frame_lags(linear: np.ndarray, gel: np.ndarray) -> tuple[list[tuple[int, float]], list[LaggedBand]]:
    """:func:`frame_checks`' repeated and partly lagged LED images (its first two lists)."""
    return frame_checks(linear, gel)[:2]


ExpectedLight = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""The LEDs' summed light the image model gives the undeformed gel at pixels: (rows (n,) int, columns (n,) int) ->
(n,) float (:func:`model_light`)."""


class ModelLight:
    """The image model's light on the undeformed gel (``core.leds.led_shading``, albedo 1, the channels' mean) at
    the pixels asked for: called, the LEDs' summed light (an :data:`ExpectedLight`, what "dark in every LED image"
    is judged against); :meth:`each`, each LED's (what tells two LEDs' images alike by design from a lag band).

    Why: a camera that sees the whole dome down to its base (a wide view, the gel not filling the frame,
    s32-rimview) sees there gel that the LEDs, at the base's own height, light at a tenth of the median or less in
    direct light: a band of "columns 4-10 (left) of every LED image are dark" was reported at 160x120 and
    ``nlips calibrate-leds`` refused the capture. The light over the model's is even over the gel. And LEDs designed
    in close pairs (0.5-1.2 mm apart, s35-exchange) light the gel far from the pair within 1 % of each other: the
    images alone called those lines the previous LED's light (:func:`lagged_bands`).

    Parameters
    ----------
    depth : (H, W) float, mm -- camera-frame z of the undeformed gel, NaN off it (``reference.npz``).
    normals : (H, W, 3) float, unit, toward the camera.
    camera : core Camera -- the capture's (its ``unproject``: the asked pixels' rays only; the whole frame's,
        ``Camera.rays``, take 0.2 s at 640x480, where the check takes ~15 ms).
    leds : sequence of Led -- the capture's LEDs (its design's until calibrated), in capture order.
    """

    def __init__(self, depth: np.ndarray, normals: np.ndarray, camera: object, leds: object) -> None:
        self.depth, self.normals, self.camera, self.leds = depth, normals, camera, leds

    def each(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(L, n) float: each LED's light at the pixels (``rows``, ``cols``: (n,) int), the channels' mean."""
        shading = self._shading(rows, cols)
        # the mean's bits (the three summed in order, then divided), 12 times faster than a reduction over an axis
        # of three (1.6 of the model's ~6 ms at 640x480)
        return (shading[..., 0] + shading[..., 1] + shading[..., 2]) / 3

    def __call__(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(n,) float: the LEDs' summed light at the pixels (LEDs and channels summed)."""
        return self._shading(rows, cols).sum(axis=(0, 2))

    def _shading(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """(L, n, 3) float: ``led_shading`` at the pixels' points on the undeformed gel."""
        from .camera import depth_to_points
        from .leds import led_shading

        rays = self.camera.unproject(np.stack([cols, rows], axis=-1).astype(np.float64))
        points = depth_to_points(self.depth[rows, cols].astype(np.float64), rays)
        return led_shading(points, self.normals[rows, cols], self.leds)


def model_light(depth: np.ndarray, normals: np.ndarray, camera: object, leds: object) -> ModelLight:
    """The image model's light on the undeformed gel (:class:`ModelLight`: its parameters)."""
    return ModelLight(depth, normals, camera, leds)


def _over_model(light: np.ndarray, model: np.ndarray) -> np.ndarray:
    """``light`` over the ``model``'s, infinite (never dark) where the model gives no light: nothing to judge."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(model > 0, light / np.where(model > 0, model, 1), np.inf)


def frame_checks(
    linear: np.ndarray, gel: np.ndarray, expected: ExpectedLight | None = None
) -> tuple[list[tuple[int, float]], list[LaggedBand], DarkBand | None]:
    """The LED images that repeat the image captured before them, whole and in part (one block average each).

    Parameters
    ----------
    linear : (L, H, W, 3) float -- the LED images in capture order, linear (dark frame subtracted, full scale 1:
        :func:`nlipscalib.core.sensor_response.linearise`).
    gel : (H, W) bool -- the pixels that see the gel.
    expected : ExpectedLight or None -- the model's light on the undeformed gel (:func:`model_light`): rows that
        look dark in every LED image are judged again by their light over it; None: by their light alone.

    Returns
    -------
    repeated : list of (index, difference) -- ``index`` (0-based, >= 1) of each LED image whose median relative
        difference from image ``index - 1`` over the pixels either lights (above
        :data:`~nlipscalib.core.tolerances.EXPOSURE_LIGHT_FRACTION`), both averaged over blocks of
        :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` pixels a side (:func:`_block_means`), is below
        :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE`, and which holds no rows of its own light
        (then it is a lagged band); empty when none is.
    bands : list of LaggedBand -- the images lagged only in part (:func:`lagged_bands`).
    dark : DarkBand or None -- rows dark in every LED image (:func:`dark_everywhere`; shorter bands:
        :func:`dark_everywhere_lines`).
    """
    inside = gel_blocks(gel)
    blocks = [_block_means(image) for image in linear]
    # each LED's modelled light tells lines where two LEDs light the gel alike by design (LEDs in close pairs,
    # s35-pairband) from the previous light repeated; kept per design in the process (~5 ms the first time at
    # 640x480, ~0.3 ms a later check's key)
    model = (
        model_blocks(expected, inside)
        if isinstance(expected, ModelLight) and len(expected.leds) == len(blocks)
        else None
    )
    bands = lagged_bands(blocks, inside, model)
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
    dark = dark_everywhere(blocks, inside) or dark_everywhere_lines(linear, gel)
    if dark is not None and expected is not None:
        # lines the images alone call dark are judged again against the model, which tells gel that is merely lit
        # less (the dome's base seen by a wide view) from lines read while no LED was lit (dark both ways); asked
        # only then: ~30 ms at 640x480 that every solve of a capture without such lines is spared
        dark = dark_everywhere(blocks, inside, expected) or dark_everywhere_lines(linear, gel, expected)
    return found, bands, dark


def dark_everywhere(
    blocks: list[np.ndarray], inside: np.ndarray, expected: ExpectedLight | None = None
) -> DarkBand | None:
    """Rows (else columns) of blocks dark in every LED image: the LEDs' summed light below
    :data:`~nlipscalib.core.tolerances.DARK_BAND_LIGHT` of its median over the gel in
    :data:`~nlipscalib.core.tolerances.DARK_BAND_SHARE` of the row's (column's) blocks in a run of
    :data:`~nlipscalib.core.tolerances.DARK_BAND_ROWS` rows (columns) or more (not all of them).

    Why the images alone suffice: the LEDs together light the whole gel (each LED's own light may end at its
    terminator; a contact's shadow from every LED at once is a small hole, not whole rows).

    Parameters
    ----------
    blocks : list of (h, w) float32 -- the LED images' block means (:func:`_block_means`), in capture order.
    inside : (h, w) bool -- the blocks wholly on the gel.
    expected : ExpectedLight or None -- :func:`frame_checks`'; given, each block's light over the model's at its
        centre pixel.

    Returns
    -------
    DarkBand (``index`` None) or None.
    """
    if len(blocks) < 2:
        return None
    total = np.sum(blocks, axis=0)
    if expected is not None and inside.any():
        b = CAPTURE_CHECK_BLUR
        rows, cols = np.nonzero(inside)
        total[inside] = _over_model(total[inside], expected(rows * b + b // 2, cols * b + b // 2))
    level = float(np.median(total[inside])) if inside.any() else 0.0
    if not level > 0:
        return None
    for axis, light, counted in (("rows", total, inside), ("columns", total.T, inside.T)):
        lines = np.flatnonzero(counted.sum(axis=1) >= MIN_LIT_ROW_BLOCKS)
        if len(lines) <= DARK_BAND_ROWS:
            continue
        most = _row_quantiles(light[lines] / level, counted[lines], DARK_BAND_SHARE)
        if band := _dark_run(most < DARK_BAND_LIGHT, lines, None, axis):
            return band
    return None


def dark_everywhere_lines(
    linear: np.ndarray, gel: np.ndarray, expected: ExpectedLight | None = None
) -> DarkBand | None:
    """Rows (else columns) dark in every LED image in a band shorter than :func:`dark_everywhere`'s blocks tell
    (down to :data:`~nlipscalib.core.tolerances.DARK_LINES_MIN` lines), to the pixel: the LEDs' summed light over
    its median over the gel, at :data:`EVERYWHERE_SAMPLES` gel pixels, through the one LED's tests
    (:func:`dark_candidates`: bands of :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` lines that may hide
    one), and on the candidates' lines densely (:data:`EVERYWHERE_LINE_SAMPLES` a line) :func:`dark_lines`.

    Why the images alone, again: the LEDs together light the whole gel; a contact's shadow from every LED at once is
    a small hole, not whole lines (:func:`dark_lines` asks for :data:`~nlipscalib.core.tolerances.DARK_BAND_SHARE`
    of a line's samples dark).

    Parameters
    ----------
    linear : (L, H, W, 3) float -- the LED images in capture order, linear (:func:`frame_checks`').
    gel : (H, W) bool -- the pixels that see the gel.
    expected : ExpectedLight or None -- :func:`frame_checks`'; given, the light over the model's.

    Returns
    -------
    DarkBand (``index`` None) or None.
    """
    if len(linear) < 2:
        return None
    height, width = gel.shape
    index = _gel_samples(gel)
    if index.size == 0:
        return None
    flat = linear.reshape(len(linear), -1, linear.shape[-1])

    def summed(pixels: np.ndarray) -> np.ndarray:
        light = _summed(flat, pixels)
        return light if expected is None else _over_model(light, expected(pixels // width, pixels % width))

    light = summed(index)
    level = float(np.median(light))
    if not level > 0:
        return None
    for axis, at, length, across in (
        ("rows", index // width, height, width),
        ("columns", index % width, width, height),
    ):
        candidates = dark_candidates(light[None], at, length)[0]
        if candidates.size == 0:
            continue
        b = CAPTURE_CHECK_BLUR
        near = np.zeros(length, bool)
        for band in candidates:
            near[max(0, (band - 1) * b) : (band + 2) * b] = True
        lines = np.flatnonzero(near)
        inside = gel[lines] if axis == "rows" else gel[:, lines].T
        step = max(1, across // EVERYWHERE_LINE_SAMPLES)
        which, spot = np.nonzero(inside[:, ::step])
        line, spot = lines[which], spot * step
        pixels = line * width + spot if axis == "rows" else spot * width + line
        dense = summed(pixels) / level
        extent = (int(at.min()), int(at.max()) + 1)
        if band := dark_lines(dense, line, extent, None, axis):
            return band
    return None


def _gel_samples(gel: np.ndarray) -> np.ndarray:
    """(n,) int: about :data:`EVERYWHERE_SAMPLES` of the ``gel``'s (H, W) pixels, flat: every k-th pixel of the frame
    in raster order that is on the gel, k prime to the width (so the samples fall on every column as on every row).
    Why not every k-th gel pixel (``np.flatnonzero``): that pass over the frame took 0.1 ms of the check's ~0.3."""
    width = gel.shape[1]
    step = max(1, int(np.count_nonzero(gel)) // EVERYWHERE_SAMPLES)
    while math.gcd(step, width) != 1:
        step += 1
    index = np.arange(0, gel.size, step)
    return index[gel.reshape(-1)[index]]


def _summed(flat: np.ndarray, pixels: np.ndarray) -> np.ndarray:
    """(n,) float64: the LED images' (``flat``: (L, H * W, C)) light at the flat ``pixels`` (n,), summed over the
    LEDs and channels. np.take and the LEDs summed first: ~0.08 ms for 2000 pixels of 12 LED images (fancy indexing
    of the middle axis ~0.5 ms, one float64 sum over two axes ~0.26 ms)."""
    return np.take(flat, pixels, axis=1).sum(axis=0).sum(axis=1, dtype=np.float64)


def dark_bands(light: np.ndarray, lines: np.ndarray, length: int, axis: str = "rows") -> list[DarkBand]:
    """The LED images with a band of rows (or columns) far below the light they should hold: read while their LED
    was not lit.

    Per LED, the samples' ``light`` over its median below :data:`~nlipscalib.core.tolerances.DARK_BAND_LIGHT` in
    :data:`~nlipscalib.core.tolerances.DARK_BAND_SHARE` of the samples of each band of
    :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` rows (with :data:`MIN_ROW_SAMPLES` samples or more), in a
    run of
    :data:`~nlipscalib.core.tolerances.DARK_BAND_ROWS` bands or more, not all of them, at the top, the bottom or in
    the middle (a global-reset sensor's exposure that missed the LED in some rows). Shorter bands:
    :func:`dark_candidates` and :func:`dark_lines`.

    Parameters
    ----------
    light : (L, N) float -- each LED's image at N gel samples over the light expected there (the LED model with a
        per-pixel albedo fitted over the LEDs: :func:`nlipscalib.solver.led_checks.led_check`); 1 as modelled.
    lines : (N,) int -- the samples' pixel rows (``axis`` "columns": columns).
    length : int -- the image's rows (columns).
    axis : "rows" or "columns" -- what ``lines`` count (the names in the result).

    Returns
    -------
    list of DarkBand -- one per LED image with a dark band (its longest), in order; empty when none has one.
    """
    return dark_bands_and_candidates(light, lines, length, axis)[0]


def dark_bands_and_candidates(
    light: np.ndarray, lines: np.ndarray, length: int, axis: str = "rows", mostly_dark: bool = False
) -> tuple[list[DarkBand], list[np.ndarray]]:
    """:func:`dark_bands` and :func:`dark_candidates` of the same samples, their bands' table made once;
    ``mostly_dark``: also an LED dark at over half its samples (:func:`lit_level`)."""
    table, counted, bands = _band_table(light, lines, length, mostly_dark)
    found = []
    for index, values in enumerate(table):
        most = _row_quantiles(values[bands], counted[bands], DARK_BAND_SHARE)
        if dark := _dark_run(most < DARK_BAND_LIGHT, bands, index, axis):
            found.append(dark)
    return found, _candidates(table, counted, bands)


def dark_candidates(light: np.ndarray, lines: np.ndarray, length: int) -> list[np.ndarray]:
    """Per LED, the bands of :data:`~nlipscalib.core.tolerances.CAPTURE_CHECK_BLUR` rows (columns) whose samples may
    hide a dark band shorter than :func:`dark_bands` can tell: :data:`~nlipscalib.core.tolerances.DARK_CANDIDATE_SHARE`
    of them or more (and two or more) below :data:`~nlipscalib.core.tolerances.DARK_BAND_LIGHT`. Why: one row in
    five dark leaves the band's 90 % quantile lit; :func:`dark_lines` then looks at those rows pixel by pixel.

    Parameters
    ----------
    light, lines, length : as :func:`dark_bands`'s.

    Returns
    -------
    list (L) of (k,) int -- the candidate bands (band ``b``: pixel rows ``b * CAPTURE_CHECK_BLUR`` on), ascending;
    all empty when too few bands hold samples (as :func:`dark_bands`).
    """
    return _candidates(*_band_table(light, lines, length))


def _candidates(table: np.ndarray, counted: np.ndarray, bands: np.ndarray) -> list[np.ndarray]:
    """:func:`dark_candidates` of :func:`_band_table`'s table."""
    if table.size == 0:
        return [np.zeros(0, int) for _ in range(len(table))]
    dark = (table[:, bands] < DARK_BAND_LIGHT).sum(axis=2)  # padding is +inf: never dark
    share = dark / np.maximum(counted[bands].sum(axis=1), 1)
    return [bands[(d >= 2) & (s >= DARK_CANDIDATE_SHARE)] for d, s in zip(dark, share, strict=True)]


def dark_lines(
    light: np.ndarray, lines: np.ndarray, extent: tuple[int, int], index: int | None, axis: str = "rows"
) -> DarkBand | None:
    """One LED image's dark band to the pixel row (column), from samples dense along the rows :func:`dark_candidates`
    named: the rows whose samples' ``light`` is below :data:`~nlipscalib.core.tolerances.DARK_BAND_LIGHT` in
    :data:`~nlipscalib.core.tolerances.DARK_BAND_SHARE` of them (:data:`MIN_LINE_SAMPLES` or more a row), in a
    run of :data:`~nlipscalib.core.tolerances.DARK_LINES_MIN` rows or more (the longest run).

    Parameters
    ----------
    light : (n,) float -- the LED's light over the modelled light at the dense samples, relative to the LED's
        median over the gel (:func:`dark_bands`' ``light``'s scale).
    lines : (n,) int -- the samples' pixel rows (columns).
    extent : (first, stop) -- the rows (columns) the gel's samples span: a band from ``first`` is "top" ("left"),
        one to ``stop`` "bottom" ("right").
    index : int or None -- the LED image (0-based), for the result; None: every LED image.
    axis : "rows" or "columns".

    Returns
    -------
    DarkBand or None.
    """
    lines = np.asarray(lines)
    if lines.size == 0:
        return None
    first = int(lines.min())
    count = np.bincount(lines - first)
    order = np.argsort(lines, kind="stable")
    slot = np.arange(len(order)) - np.repeat(np.cumsum(count) - count, count)
    table = np.full((len(count), max(int(count.max()), 1)), np.inf)
    table[lines[order] - first, slot] = np.asarray(light, np.float64)[order]
    counted = np.zeros(table.shape, bool)
    counted[lines[order] - first, slot] = True
    kept = np.flatnonzero(count >= MIN_LINE_SAMPLES)
    if kept.size == 0:
        return None
    dark = _row_quantiles(table[kept], counted[kept], DARK_BAND_SHARE) < DARK_BAND_LIGHT
    # runs of dark lines among consecutive counted lines (a line without samples ends a run)
    run_id = np.cumsum(np.concatenate([[1], (np.diff(kept) != 1) | ~dark[1:] | ~dark[:-1]]))
    best = None
    for rid in np.unique(run_id[dark]):
        members = kept[(run_id == rid) & dark]
        if best is None or len(members) > len(best):
            best = members
    if best is None or len(best) < DARK_LINES_MIN:
        return None
    start, stop = int(best[0]) + first, int(best[-1]) + first + 1
    ends = ("top", "bottom") if axis == "rows" else ("left", "right")
    where = ends[0] if start <= extent[0] else ends[1] if stop >= extent[1] else "middle"
    return DarkBand(index, (start, stop), where, axis)


def dark_band_mask(bands: list[DarkBand | LaggedBand], leds: list[int], shape: tuple[int, int]) -> np.ndarray:
    """The samples an LED image's dark band (or lagged band) leaves without its LED's light: its rows (columns) and
    :data:`~nlipscalib.core.tolerances.DARK_BAND_MARGIN` either side, for that LED only; a lagged band also to the
    frame's edge it lies at (its first rows read, or its last: the gel's lines beyond the rows
    :func:`lagged_bands` counts hold the previous LED's light too).

    Parameters
    ----------
    bands : list of DarkBand or LaggedBand -- with ``index`` an LED (0-based, capture order; :func:`dark_bands`,
        :func:`dark_lines`, :func:`lagged_bands`).
    leds : list of int -- the LEDs of the images the mask is for (0-based), in their order; a band of another LED
        is left out.
    shape : (H, W) -- the image's rows and columns.

    Returns
    -------
    (len(leds), H, W) bool -- True where the sample is to be left out.
    """
    mask = np.zeros((len(leds), *shape), bool)
    at = {led: k for k, led in enumerate(leds)}
    for band in bands:
        if band.index not in at:
            continue
        start, stop = max(0, band.rows[0] - DARK_BAND_MARGIN), band.rows[1] + DARK_BAND_MARGIN
        if isinstance(band, LaggedBand):
            start, stop = (0, stop) if band.top else (start, max(shape))
        if band.axis == "rows":
            mask[at[band.index], start:stop] = True
        else:
            mask[at[band.index], :, start:stop] = True
    return mask


def _band_table(
    light: np.ndarray, lines: np.ndarray, length: int, mostly_dark: bool = False
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each LED's ``light`` (L, N) over its median, the samples of each band of :data:`CAPTURE_CHECK_BLUR` lines side
    by side (padded with +inf): (L, bands, most) float64; which entries are samples (bands, most) bool; and the
    bands that count (:data:`MIN_ROW_SAMPLES` samples or more), or none when :data:`DARK_BAND_ROWS` or fewer do.
    ``mostly_dark``: over :func:`lit_level`, else over the median (an LED dark at most samples: no verdict)."""
    b = CAPTURE_CHECK_BLUR
    light = np.asarray(light, np.float64)
    band = np.asarray(lines) // b
    count = np.bincount(band, minlength=-(-length // b))
    bands = np.flatnonzero(count >= MIN_ROW_SAMPLES)
    if len(bands) <= DARK_BAND_ROWS or light.size == 0:
        return np.zeros((len(light), 0, 0)), np.zeros((0, 0), bool), np.zeros(0, int)
    # each band's samples side by side (padded): one sort gives every band's median, every LED at once
    order = np.argsort(band, kind="stable")
    slot = np.arange(len(order)) - np.repeat(np.cumsum(count) - count, count)
    table = np.full((len(light), len(count), count.max()), np.inf)
    # an LED dark at most samples (the model lights what it does not): NaN, no verdict, unless asked: an LED far
    # from the model ends its own light at its terminator where the model's would not (s31-ledfar's twin: LEDs 4
    # and 5 "dark" over 56 % of their images against the first fit's LEDs)
    level = lit_level(light) if mostly_dark else np.median(light, axis=1, keepdims=True)
    table[:, band[order], slot] = light[:, order] / np.where(level > 0, level, np.nan)
    counted = np.zeros(table.shape[1:], bool)
    counted[band[order], slot] = True
    return table, counted, bands


def lit_level(light: np.ndarray) -> np.ndarray:
    """Each LED's ``light`` (L, N) level where it is lit: its median, or, when that is below
    :data:`~nlipscalib.core.tolerances.DARK_BAND_LIGHT` of its :data:`LIT_QUANTILE` quantile (more than about half
    its samples dark), the median of its samples above that. (L, 1) float64.

    Why: a band read while the LED was off over more than half of its image (the twin's LED 5 dark in rows 0-129 of
    240) put its median at the dark frame's noise, and every ratio to it said lit: the band was never found, and
    the LED calibration ran off ("led.intensity must be 3 finite numbers", s31-halfdark). Only asked where a fit
    ran off (:func:`nlipscalib.solver.calibrate.calibrate_leds`): an LED far from the model is dark past its own
    terminator over as much."""
    light = np.asarray(light, np.float64)
    level = np.median(light, axis=1, keepdims=True)
    if light.size == 0:
        return level
    top = np.quantile(light, LIT_QUANTILE, axis=1, keepdims=True)
    bright = light >= DARK_BAND_LIGHT * top
    dim = (level < DARK_BAND_LIGHT * top) & (top > 0)
    for k in np.flatnonzero(dim[:, 0]):
        level[k, 0] = np.median(light[k][bright[k]])
    return level


def _dark_run(dark: np.ndarray, bands: np.ndarray, index: int | None, axis: str = "rows") -> DarkBand | None:
    """The longest run of ``dark`` among the counted ``bands`` (rows or columns of blocks, ascending) when it is
    :data:`~nlipscalib.core.tolerances.DARK_BAND_ROWS` long or more and not all of them."""
    if dark.all() or not dark.any():
        return None
    edges = np.flatnonzero(np.diff(np.concatenate([[0], dark.astype(np.int8), [0]])))
    starts, stops = edges[::2], edges[1::2]
    longest = int(np.argmax(stops - starts))
    start, stop = int(starts[longest]), int(stops[longest])
    if stop - start < DARK_BAND_ROWS:
        return None
    ends = ("top", "bottom") if axis == "rows" else ("left", "right")
    where = ends[0] if start == 0 else ends[1] if stop == len(dark) else "middle"
    b = CAPTURE_CHECK_BLUR
    return DarkBand(index, (int(bands[start]) * b, (int(bands[stop - 1]) + 1) * b), where, axis)


class ModelBlocks:
    """Each LED's modelled light at the centres of the blocks wholly on the gel (:meth:`ModelLight.each`; 0
    elsewhere) and, asked for, two LEDs' relative difference there (:meth:`contrast`): what :func:`lagged_bands`
    reads of the LED model. Kept per design and geometry in this process (:func:`model_blocks`).

    Parameters
    ----------
    light : (L, h, w) float64 -- the LEDs' light, capture order.
    """

    def __init__(self, light: np.ndarray) -> None:
        self.light = light
        self.finite = bool(np.isfinite(light).all())
        """Whether every LED's light is finite (else :func:`median_at_least` looks for NaN lines)."""
        self._contrast: dict[tuple[int, int], np.ndarray] = {}
        self._alike: dict[tuple[int, int], np.ndarray] = {}
        self.blind: list | None = None
        """The consecutive LEDs the check is blind to (:func:`nlipscalib.core.lag_blind.lag_blind_pairs`), once
        asked."""

    def contrast(self, one: int, other: int) -> np.ndarray:
        """(h, w) float64, read-only: ``|a - b| / max(a, b)`` of LEDs ``one`` and ``other``'s light (0-based), as
        :func:`_contrast` gives it at the lit blocks; made once per pair."""
        key = (min(one, other), max(one, other))
        if key not in self._contrast:
            a, b = self.light[key[0]], self.light[key[1]]
            value = np.abs(a - b) / np.maximum(np.maximum(a, b), 1e-12)
            value.flags.writeable = False
            self._contrast[key] = value
        return self._contrast[key]

    def alike(self, one: int, other: int) -> np.ndarray:
        """(h, w) bool, read-only: :meth:`contrast` under :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST`
        (what :func:`median_at_least` counts); made once per pair."""
        key = (min(one, other), max(one, other))
        if key not in self._alike:
            value = self.contrast(one, other) < LAGGED_BAND_CONTRAST
            value.flags.writeable = False
            self._alike[key] = value
        return self._alike[key]


MODEL_BLOCKS_KEPT = 2
"""Designs (LEDs, camera, undeformed gel at the blocks) whose :class:`ModelBlocks` a process keeps: a solve checks its
press and its undeformed capture, ``nlips calibrate-leds`` each capture twice (its bands, its dark rows), a
calibration's presses one sensor; a second kept for runs that alternate."""
_MODEL_BLOCKS: OrderedDict[tuple, ModelBlocks] = OrderedDict()
_MODEL_BLOCKS_LOCK = threading.Lock()
"""Guards :data:`_MODEL_BLOCKS` (a solve's threads, a dataset build's, may check captures at once)."""


def model_blocks(model: ModelLight, inside: np.ndarray) -> ModelBlocks:
    """Each LED's modelled light at the centres of the ``inside`` blocks (:class:`ModelBlocks`), computed once per
    design and geometry in this process: keyed by the LEDs, the camera and the undeformed gel's depth and normals at
    those centres (the model's every input, by content: a press and its undeformed capture, loaded apart, share
    it). Why: the model took ~5 ms of each check at 640x480 (12288 blocks, 12 LEDs), and every solve and LED
    calibration checks the same design more than once (s36-lagcost)."""
    b = CAPTURE_CHECK_BLUR
    rows, cols = np.nonzero(inside)
    rows, cols = rows * b + b // 2, cols * b + b // 2
    key = (
        tuple(model.leds),
        model.camera,
        inside.shape,
        digest(np.packbits(inside), model.depth[rows, cols], model.normals[rows, cols]),
    )
    with _MODEL_BLOCKS_LOCK:
        if (hit := _MODEL_BLOCKS.get(key)) is not None:
            _MODEL_BLOCKS.move_to_end(key)
            return hit
    light = np.zeros((len(model.leds), *inside.shape))
    if rows.size:
        light[:, rows // b, cols // b] = model.each(rows, cols)
    light.flags.writeable = False
    found = ModelBlocks(light)
    with _MODEL_BLOCKS_LOCK:
        _MODEL_BLOCKS[key] = found
        while len(_MODEL_BLOCKS) > MODEL_BLOCKS_KEPT:
            _MODEL_BLOCKS.popitem(last=False)
    return found


def lagged_bands(
    blocks: list[np.ndarray], inside: np.ndarray, model: ModelBlocks | np.ndarray | None = None
) -> list[LaggedBand]:
    """The LED images whose top or bottom rows (else left or right columns) hold the light captured before them:
    the LED switched while a rolling shutter read the frame out (a camera mounted turned 90 degrees reads the
    columns one after another).

    Row of blocks by row of blocks (column by column), over the blocks either image lights: the median relative
    difference from the previous LED image (below :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE`:
    that image's light). An image whose first (or last) :data:`~nlipscalib.core.tolerances.LAGGED_BAND_ROWS` rows
    (columns) or more are that light, and not all of them, is lagged in part.

    Parameters
    ----------
    blocks : list of (h, w) float32 -- the LED images' block means (:func:`_block_means`), in capture order.
    inside : (h, w) bool -- the blocks wholly on the gel.
    model : ModelBlocks, (L, h, w) float or None -- each LED's modelled light at the blocks (:func:`model_blocks`),
        in capture order: a line counts only where the model's two lights (the image's LED's and the previous
        LED's) differ by :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST` or more (LEDs designed in close
        pairs light the gel far from the pair within 1 % of each other: there an image alike its predecessor is no
        lag); None: the images alone.

    Returns
    -------
    list of LaggedBand -- one per partly lagged image (of rows or of columns: where both look lagged, the band
    holding less of the image's own light), in capture order; empty when none is.
    """
    if isinstance(model, np.ndarray):
        model = ModelBlocks(model)
    finite = all(np.isfinite(image).all() for image in blocks)  # no NaN line for median_at_least to look for
    bands = []
    for index in range(1, len(blocks)):
        current, neighbour = blocks[index], blocks[index - 1]
        # the images after and before the pair (after the last, the first; before the first, the last: the LEDs
        # of a ring in capture order) tell where the ring's light changes from LED to LED around the previous one;
        # with two images there are none, and every line counts
        sides = _ring_sides(len(blocks), index, model is not None)
        lit = inside & (np.maximum(current, neighbour) > EXPOSURE_LIGHT_FRACTION)
        # the columns are the transposed blocks' rows: one test, one threshold for both readout directions
        found = [
            band
            for axis, turn in (("rows", np.asarray), ("columns", np.transpose))
            if (
                band := _lagged_lines(
                    turn(current),
                    turn(neighbour),
                    turn(lit),
                    index,
                    axis,
                    [[_side(blocks, model, i, index - 1, turn) for i in side] for side in sides],
                    None if model is None else _modelled(model, index, index - 1, turn),
                    finite,
                )
            )
        ]
        if len(found) > 1:
            # a band of columns can leave some rows mostly inside it, their medians lagged too (the twin's sphere
            # press with half its columns lagged: "rows 0-334 (top)"): the readout's band is the one whose blocks
            # are all the previous light
            difference = np.abs(current - neighbour) / np.where(lit, np.maximum(current, neighbour), 1)
            found.sort(key=lambda band: _own_light_share(band, difference, lit))
        bands += found[:1]
    return bands


def _ring_sides(count: int, index: int, modelled: bool) -> list[list[int]]:
    """The images (0-based, capture order) after ``index`` and before ``index - 1`` (a ring: after the last, the
    first) that :func:`_lagged_lines` compares the previous image with, each side's nearest first: one each, or
    with a model up to :data:`RING_SIDE_IMAGES` (the nearest whose LED the model tells from the previous one, line by
    line: an LED's partner in a close pair lights the gel far from the pair as it does); none with two images."""
    if count <= 2:
        return []
    reach = min(RING_SIDE_IMAGES if modelled else 1, count - 2)
    later = [(index + step) % count for step in range(1, reach + 1)]
    earlier = [(index - 1 - step) % count for step in range(1, reach + 1)]
    return [later, earlier]


SideImage = tuple[np.ndarray, Callable[[], "Modelled"] | None]
"""An image :func:`_lagged_lines` compares the previous image with: its block means (h, w) float32, turned, and,
with a model, what gives its LED's modelled contrast with the previous LED's (:class:`Modelled`, turned), asked only
where the image is reached (:func:`_side_tells`)."""


class Modelled(NamedTuple):
    """Two LEDs' modelled contrast at the blocks, turned as the lines tested (:meth:`ModelBlocks.contrast`)."""

    contrast: np.ndarray
    """(h, w) float: ``|a - b| / max(a, b)`` of their light."""
    alike: np.ndarray
    """(h, w) bool: ``contrast`` under :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST`."""
    finite: bool
    """Whether ``contrast`` is finite throughout."""


def _modelled(model: ModelBlocks, one: int, other: int, turn: Callable[[np.ndarray], np.ndarray]) -> Modelled:
    """LEDs ``one`` and ``other``'s :class:`Modelled` contrast, turned."""
    return Modelled(turn(model.contrast(one, other)), turn(model.alike(one, other)), model.finite)


def _side(
    blocks: list[np.ndarray],
    model: ModelBlocks | None,
    at: int,
    previous: int,
    turn: Callable[[np.ndarray], np.ndarray],
) -> SideImage:
    """Image ``at``'s block means and its LED's modelled contrast with LED ``previous`` (None without a model),
    turned."""
    return turn(blocks[at]), None if model is None else (lambda: _modelled(model, at, previous, turn))


def _own_light_share(band: LaggedBand, difference: np.ndarray, lit: np.ndarray) -> float:
    """The share of the ``lit`` blocks inside ``band`` whose relative ``difference`` (h, w) from the previous image
    is :data:`~nlipscalib.core.tolerances.REPEATED_FRAME_DIFFERENCE` or more: the image's own light, or noise alone
    where the whole band is the previous image's light."""
    b = CAPTURE_CHECK_BLUR
    lines = slice(band.rows[0] // b, -(-band.rows[1] // b))
    inside = (slice(None), lines) if band.axis == "columns" else (lines, slice(None))
    values = difference[inside][lit[inside]]
    return float(np.mean(values >= REPEATED_FRAME_DIFFERENCE)) if values.size else 1.0


def _lagged_lines(
    current: np.ndarray,
    neighbour: np.ndarray,
    lit: np.ndarray,
    index: int,
    axis: str,
    sides: list[list[SideImage]] | None = None,
    model: Modelled | None = None,
    finite: bool = False,
) -> LaggedBand | None:
    """:func:`lagged_bands`' test of one LED image's rows of blocks (``axis`` "columns": of the transposed blocks).

    Parameters
    ----------
    current, neighbour : (h, w) float32 -- the image's and the previous image's block means (rows: the lines
        tested).
    lit : (h, w) bool -- the blocks on the gel that either image lights.
    sides : list of lists of SideImage, or None -- the images after ``current`` and before ``neighbour``
        (:func:`_ring_sides`), each side's nearest first, with their LEDs' modelled contrast with the previous LED
        (or None): a line counts only where, on each side, the nearest image whose LED the model tells from the
        previous LED there (without a model: the nearest) differs from ``neighbour`` by
        :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST` or more (elsewhere the image's own light cannot be
        told from the previous one's); None or empty: every line counts.
    model : Modelled or None -- the modelled contrast of the image's LED and the previous LED at the blocks
        (:meth:`ModelBlocks.contrast`): a line counts only where its median is
        :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST` or more (where the LED model says the two lights
        are alike, LEDs in close pairs, the images' likeness is no lag); None: not asked.
    finite : bool -- the images' block means are finite throughout (no NaN line to look for).
    """
    lines = Lines(lit, np.count_nonzero(lit, axis=1))
    counted = lines.count >= MIN_LIT_ROW_BLOCKS
    # both sides: where the previous LED is the ring's brightest or dimmest at a line (a wide view's far base
    # rim; gel both LEDs light only by the indirect light), the image's own light lies as near it as the image
    # before it does, not between it and the image after (s33-rimband)
    for side in sides or []:
        counted[counted] = _side_tells(side, neighbour, lines, counted, finite)
    if model is not None:
        counted[counted] = median_at_least(
            model.contrast, lines, counted, LAGGED_BAND_CONTRAST, model.alike, model.finite
        )
    rows = np.flatnonzero(counted)
    if len(rows) <= LAGGED_BAND_ROWS:
        return None
    difference = np.abs(current - neighbour) / np.where(lit, np.maximum(current, neighbour), 1)
    # 1: the previous LED's light, 0: the image's own light. Dark rows (read while no LED was lit) are not
    # looked for here: an LED's own light can end as sharply at its terminator (the synthetic ring with LEDs far
    # from their design: dark top rows in 2 of 12 images, s28-rolling); the LED model tells (dark_bands)
    own = median_at_least(difference, lines, counted, REPEATED_FRAME_DIFFERENCE, finite=finite, below=True)
    return _edge_band(own.astype(np.int8), rows, index, axis)


class Lines(NamedTuple):
    """The blocks a line's median is taken over in :func:`_lagged_lines`: ``lit`` (h, w) bool, and ``count`` (h,)
    int, each line's."""

    lit: np.ndarray
    count: np.ndarray


def _contrast(one: np.ndarray, other: np.ndarray, lit: np.ndarray) -> np.ndarray:
    """(h, w) float: the relative difference of ``one`` and ``other`` (h, w) at the ``lit`` blocks (1 elsewhere)."""
    return np.abs(one - other) / np.where(lit, np.maximum(np.maximum(one, other), 1e-12), 1)


def _side_tells(
    side: list[SideImage], neighbour: np.ndarray, lines: Lines, counted: np.ndarray, finite: bool
) -> np.ndarray:
    """(n,) bool, the ``counted`` lines: the image of ``side`` (nearest first) that stands for its side at each
    line differs from ``neighbour`` by :data:`~nlipscalib.core.tolerances.LAGGED_BAND_CONTRAST` or more over its
    ``lines``' lit blocks. The nearest stands, or with modelled contrast the nearest whose LED the model tells from
    the previous LED's at that line; a line where none is told does not count. ``finite``: the images are."""
    tells = np.zeros(int(counted.sum()), bool)
    open_ = np.ones_like(tells)
    for image, modelled in side:
        if modelled is None:
            stands = open_
        else:
            model = modelled()
            stands = open_ & median_at_least(
                model.contrast, lines, counted, LAGGED_BAND_CONTRAST, model.alike, model.finite
            )
        differs = median_at_least(
            _contrast(image, neighbour, lines.lit), lines, counted, LAGGED_BAND_CONTRAST, None, finite
        )
        tells[stands] = differs[stands]
        open_ &= ~stands
        if not open_.any():
            break
    return tells


def median_at_least(
    values: np.ndarray,
    lines: Lines,
    counted: np.ndarray,
    threshold: float,
    under: np.ndarray | None = None,
    finite: bool = False,
    below: bool = False,
) -> np.ndarray:
    """(n,) bool: whether the median of ``values`` (h, w) over each ``counted`` line's lit blocks (``lines``; at
    least one each) is ``threshold`` or more (``below``: under it), as ``_row_medians(values[counted],
    lit[counted]) >= threshold`` (``<``) to the bit. ``under``: ``values < threshold`` when kept (the LED model's);
    ``finite``: ``values`` hold no NaN.

    Why counts: a line's median is at least the threshold when at most (n - 1) // 2 of its n values lie below it,
    and under it when more than n // 2 do; only a line of an even count with half below (or a NaN, which neither
    is) needs its median. The medians' sorts took ~5 of the ~10 ms of the check of 12 images at 640x480
    (s36-lagcost)."""
    lit = lines.lit
    if under is None:
        under = values < threshold
    n = lines.count[counted]
    low = np.count_nonzero(under & lit, axis=1)[counted]
    result = low > n // 2 if below else low <= (n - 1) // 2
    unsure = ((n - 1) // 2 < low) & (low <= n // 2)
    if not finite:
        unsure |= np.count_nonzero(np.isnan(values) & lit, axis=1)[counted] > 0
    if unsure.any():
        rows = np.flatnonzero(counted)[unsure]
        median = _row_medians(values[rows], lit[rows])
        result[unsure] = median < threshold if below else median >= threshold
    return result


def _row_medians(values: np.ndarray, counted: np.ndarray) -> np.ndarray:
    """(n,) float: the median of each row of ``values`` (n, w) over its ``counted`` entries (at least one each).
    A sort with the others pushed to the end: np.nanmedian took ~10 ms an image at 640x480, this ~0.3 ms."""
    ordered = np.sort(np.where(counted, values, np.inf), axis=1)
    count = counted.sum(axis=1)
    at = np.arange(len(values))
    return 0.5 * (ordered[at, (count - 1) // 2] + ordered[at, count // 2])


def _row_quantiles(values: np.ndarray, counted: np.ndarray, q: float) -> np.ndarray:
    """(n,) float: the ``q`` quantile (lower: an entry) of each row of ``values`` (n, w) over its ``counted``
    entries (at least one each), as :func:`_row_medians`."""
    ordered = np.sort(np.where(counted, values, np.inf), axis=1)
    count = counted.sum(axis=1)
    return ordered[np.arange(len(values)), np.floor(q * (count - 1)).astype(int)]


def _edge_band(kind: np.ndarray, rows: np.ndarray, index: int, axis: str = "rows") -> LaggedBand | None:
    """The band of rows (``axis`` "columns": columns) of the previous image's light (``kind`` 1) at the top (left),
    else at the bottom (right), of the counted ``rows`` (block rows, ascending) when it is :data:`LAGGED_BAND_ROWS`
    long or more and not all of them."""
    b = CAPTURE_CHECK_BLUR
    for top in (True, False):
        ordered = kind if top else kind[::-1]
        if ordered[0] == 0:
            continue
        run = int(np.argmax(ordered != ordered[0])) if (ordered != ordered[0]).any() else len(ordered)
        if LAGGED_BAND_ROWS <= run < len(ordered):
            span = (int(rows[0]) * b, int(rows[run]) * b) if top else (int(rows[-run]) * b, (int(rows[-1]) + 1) * b)
            return LaggedBand(index, span, top, axis)
    return None


def gel_blocks(gel: np.ndarray) -> np.ndarray:
    """(H // b, W // b) bool: the blocks of :func:`_block_means` wholly on the ``gel`` ((H, W) bool; the mean's
    rounding allowed for)."""
    return _block_means(np.asarray(gel, np.float32)[..., None]) > 1 - 1e-6


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
    """One line naming the partly lagged LED images (``names`` in capture order), their rows (columns), the cause
    and the fix."""
    said = []
    for band in bands:
        where = f"{band.axis} {band.rows[0]}-{band.rows[1] - 1} ({band.where})"
        said.append(f"{names[band.index]}'s {where} show {names[band.index - 1]}'s light")
    reads = (
        "a camera mounted turned 90 degrees: its rolling shutter reads the image's columns one after another"
        if bands and all(band.axis == "columns" for band in bands)
        else "a rolling shutter reads the rows one after another"
    )
    return (
        f"{folder}: {'; '.join(said)}: the LEDs switched while the camera read the frame out ({reads}: a frame read "
        "across the switch holds both lights); capture again with --flush 1 or more (frames dropped after each LED "
        "change, default 2), and a frame source that drops them (a recorded video or image sequence does not)"
    )


DARK_CAUSE = (
    "no LED was lit while the camera read (or exposed) those rows: the LED switched on late, or off early, against "
    "the readout (a rolling shutter reads the rows one after another; a global-reset sensor exposes them within one "
    "window)"
)
"""The cause of dark rows (:func:`dark_line`, :func:`dark_everywhere_line`, the LED calibration's refusal)."""
DARK_CAUSE_COLUMNS = (
    "no LED was lit while the camera read (or exposed) those columns: the LED switched on late, or off early, "
    "against the readout (a camera mounted turned 90 degrees: its rolling shutter reads the image's columns one "
    "after another)"
)
"""The cause of dark columns (:func:`dark_cause`)."""
DARK_FIX_TAIL = (
    "capture again with --flush 1 or more (frames dropped after each LED change, default 2) and each LED lit over the "
    "whole frame time"
)
"""The fix of dark rows or columns."""
DARK_FIX = f"{DARK_CAUSE}; {DARK_FIX_TAIL}"
"""The cause and fix of dark rows, shared by :func:`dark_line` and :func:`dark_everywhere_line`."""


def dark_line(folder: object, names: list[str], bands: list[DarkBand], done: str = "") -> str:
    """One line naming the LED images (``names`` in capture order) with dark rows or columns (:func:`dark_bands`,
    :func:`dark_lines`), their rows, the cause and the fix; ``done``: what the solve does about them, appended."""
    said = ", ".join(f"{names[band.index]}'s {dark_span(band)}" for band in bands)
    return (
        f"{folder}: {said} {'are' if len(bands) == 1 else 'are each'} dark (under {DARK_BAND_LIGHT:g} of the light "
        f"the LED model and the other LEDs give them: the dark frame's level, or a very dim LED): "
        f"{dark_fix(bands)}{done}"
    )


def dark_everywhere_line(folder: object, band: DarkBand) -> str:
    """One line naming the rows (columns) dark in every LED image (:func:`dark_everywhere`), the cause and the fix."""
    return (
        f"{folder}: {dark_span(band)} of every LED image are dark (the LEDs' light there under {DARK_BAND_LIGHT:g} "
        f"of its median over the gel: the dark frame's level): {dark_fix([band])}"
    )


def dark_cause(bands: list[DarkBand]) -> str:
    """:data:`DARK_CAUSE`, or its words for columns when every band is of columns (a camera turned 90 degrees)."""
    if bands and all(band.axis == "columns" for band in bands):
        return DARK_CAUSE_COLUMNS
    return DARK_CAUSE


def dark_fix(bands: list[DarkBand]) -> str:
    """:data:`DARK_FIX`, or its words for columns (:func:`dark_cause`)."""
    return DARK_FIX if dark_cause(bands) == DARK_CAUSE else f"{DARK_CAUSE_COLUMNS}; {DARK_FIX_TAIL}"


def dark_span(band: DarkBand) -> str:
    """'rows first-last (where)' (or 'columns ...') of a dark band's pixel rows (columns)."""
    first, last = band.rows[0], band.rows[1] - 1
    span = f"{band.axis} {first}-{last}" if last > first else f"{band.axis[:-1]} {first}"
    return f"{span} ({band.where})"
