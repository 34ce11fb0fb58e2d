"""Where a press differs from the undeformed dome: one classification for the auto ROI and anchoring.

Per pixel, the undeformed model (the capture of the undeformed dome, or the direct model on the
reference geometry plus the fitted indirect term) is fitted to the LED images with one scale per
channel (the albedo); what it leaves is the pixel's *misfit*. The misfit is compared in absolute
terms with what the image noise alone leaves (noise estimated from the images, Immerkaer, "Fast noise
variance estimation", CVIU 64(2), 1996), so the decision does not depend on how much of the view the
dent fills: a capture that is mostly dent has mostly large misfits, and none of them is called
undeformed.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..core import masks, tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.errors import CaptureError, NoContactError
from ..core.leds import Leds, disk_shading, led_shading
from ..core.robust_scale import mad_scale
from . import reuse, threads
from .sensor_fit import gain_fitted_misfit, gel_samples

log = logging.getLogger(__name__)

EDGE_CONTACT_PX = 2
"""``--roi auto`` notes a contact whose misfitting pixels come within this many pixels of the image's border: its box
has no undeformed gel beyond it on that side."""

ANCHOR_MIN_FRACTION = 0.02
"""Anchoring is off (weak evidence) when fewer than this fraction of the gel's pixels fit the undeformed model at noise
level (:func:`anchor_weights`); the auto ROI is then not widened for anchors either (:func:`widen_to_anchor`)."""


@dataclasses.dataclass(frozen=True)
class ContactMap:
    """Result of :func:`classify_contact` (computed once per solve)."""

    misfit: np.ndarray
    """(H, W) float64 -- RMS residual of the undeformed model over live LEDs and channels, linear image
    units; NaN off the gel."""
    expected: np.ndarray
    """(H, W) float64 -- the misfit that image noise alone leaves at that pixel, same units."""
    live_leds: tuple[int, ...]
    """LEDs used (0-based): dead LEDs (dark image) are left out."""
    dead_leds: tuple[int, ...]
    """LEDs whose image is dark (0-based)."""
    noise: float
    """Estimated image noise sigma, linear units (full scale 1)."""
    level: np.ndarray
    """(H, W) float64 -- RMS of the (smoothed) images over live LEDs and channels, linear units."""
    samples: tuple[np.ndarray, np.ndarray] | None = None
    """The undeformed model and the images on a sample of the gel (:func:`.sensor_fit.gel_samples`), for
    :attr:`sensor_fit`; None when too few pixels are usable."""
    sample_noise: float = float("nan")
    """The noise-only misfit's median over the gel, linear units (the unit of :attr:`sensor_fit`'s floor)."""

    @functools.cached_property
    def sensor_fit(self) -> tuple[float, float, float]:
        """(share, best share, floor): what the undeformed model, with a gain per LED fitted too, misses of the
        images -- the median over the gel of a pixel's RMS misfit over the median pixel's brightness, the best
        tenth's (:data:`.sensor_fit.FIT_PIXELS_QUANTILE`) likewise, and the median misfit in units of the noise-only
        misfit (:func:`.sensor_fit.gain_fitted_misfit`); large when the images were taken with another sensor than
        the capture's files describe. NaNs when not measured. Worked out when first asked: a solve asks its last
        classification only (the samples and the fit: 11-12 ms of CPU per 640x480 solve, benchmarks/RESULTS.md
        s27-sensorfit)."""
        if self.samples is None:
            return float("nan"), float("nan"), float("nan")
        share, best, misfit = gain_fitted_misfit(*self.samples)
        return share, best, misfit / max(self.sample_noise, 1e-12)

    @property
    def ratio(self) -> np.ndarray:
        """(H, W) misfit over its noise-only value (NaN off the gel)."""
        return self.misfit / np.maximum(self.expected, 1e-12)

    def undeformed(self, factor: float = tolerances.ANCHOR_NOISE_FACTOR) -> np.ndarray:
        """(H, W) bool -- pixels the data show undeformed: misfit within ``factor`` times the noise."""
        return np.nan_to_num(self.ratio, nan=np.inf) <= factor

    @functools.cached_property
    def median_misfit(self) -> float:
        """The misfit's median over the gel (NaN when no pixel sees it). Kept: :func:`contact_hits` reads it for
        the auto ROI, the dent's focus and the refit's exclusion (~3 ms each at 640x480)."""
        valid = np.isfinite(self.misfit)
        return float(np.median(self.misfit[valid])) if valid.any() else float("nan")

    @functools.cached_property
    def peak(self) -> float:
        """:func:`contact_peak`: the largest misfit over its floor on the gel (0 when no pixel sees it)."""
        valid = np.isfinite(self.misfit)
        if not valid.any():
            return 0.0
        floor = np.maximum(self.expected[valid], self.median_misfit)
        return float(np.max(self.misfit[valid] / np.maximum(floor, 1e-9)))


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


NOISE_SAMPLES = masks.STATISTIC_PIXELS
"""Pixels :func:`image_noise` and :func:`led_levels` sample at least (all of the gel when it has fewer)."""


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


def classify_contact(
    press: Press,
    leds: Leds | None = None,
    *,
    undeformed_images: np.ndarray | reuse.Deferred | None = None,
    undeformed_light: np.ndarray | None = None,
    indirect: np.ndarray | None = None,
    dead_level: float = tolerances.LIT_LEVEL,
    undeformed_noise: bool = False,
    blur_px: float = 1.5,
    cache: dict | None = None,
    block: int | None = None,
) -> ContactMap:
    """Misfit of the undeformed dome to a press's LED images, and the noise-only misfit, per pixel.

    Parameters
    ----------
    press : Press -- with ``reference``.
    leds : sequence of Led or None -- the LED model (calibrated LEDs when given), default ``press.leds``.
    undeformed_images : (L, H, W, 3) float, a ``solver.reuse.Deferred`` of it, or None -- what the undeformed
        dome looks like under each LED up to a per-pixel albedo (a capture of it: linear images; or the model
        with its indirect term). None: the direct model on ``press.reference`` with ``leds``.
    undeformed_light : (L, H, W, 3) float, a sequence of L (H, W, 3) float images made as they are read
        (:class:`nlipscalib.solver.radiosity.Upsampled`), or None -- added to ``undeformed_images`` (e.g. the
        fitted indirect light of the undeformed dome added to its direct shading), unsmoothed: it must be smooth at
        the scale of ``blur_px``. Kept apart so the smoothed ``undeformed_images`` -- a sensor's direct
        shading -- is computed once and reused by the next classification against it.
    indirect : (L, H, W, 3) float or None -- light to subtract from the press's images first.
    dead_level : an LED whose image's 99th percentile (linear) is below this is dead and left out
        (``SolverOptions.dead_led_level`` in a solve).
    undeformed_noise : ``undeformed_images`` is a capture with its own noise (the noise-only misfit is
        then sqrt(2) times larger).
    blur_px : Gaussian sigma, pixels, of the smoothing before the fit (0: none).
    cache : dict or None -- shared by classifications of the same press against different undeformed
        models (e.g. before and after a refit of the indirect term): holds the press's side (live
        LEDs, smoothed images, noise), filled by the first call. Not used with ``indirect``.
    block : side, pixels, of the square blocks whose gel pixels' mean the classification works on (1: every
        pixel); None: :func:`classify_block` of the frame. Its maps come back per pixel (each pixel gets its
        block's value); the blur is then ``blur_px`` / ``block`` blocks (:meth:`_Grid.of`).

    Returns
    -------
    ContactMap
    """
    if press.reference is None:
        raise CaptureError(f"{press.folder}: --roi auto and anchoring need the capture's reference (undeformed dome)")
    leds = press.leds if leds is None else tuple(leds)
    ref = press.reference
    valid = np.isfinite(ref.depth)
    grid = _grid_of(press, blur_px, block)
    side = cache if cache is not None and indirect is None else {}
    _fill_press_side(side, press, grid, indirect, dead_level)
    live, img, ok, count = side["live"], side["images"], side["ok"], side["count"]
    if undeformed_images is not None:
        S = _smoothed_undeformed(undeformed_images, live, grid)
    else:
        pts = depth_to_points(np.where(valid, ref.depth, 0.0), press.camera.rays)
        S = grid.smooth(grid.means(led_shading(pts, np.where(valid[..., None], ref.normals, 0.0), leds), live))
    if undeformed_light is not None:
        # not smoothed: the fitted light is a gather over patches many pixels wide, bilinearly upsampled; the
        # blur changed it by < 5e-5 of its peak (640x480 one-bounce twin) and cost 0.06 s per classification
        S = S + grid.means(undeformed_light, live)
    misfit = _misfit(S, img, ok, count)
    # the model and the images on a sample of the gel: does the model describe the sensor at all (asked once)?
    samples = gel_samples(S, img, grid.valid, ok)
    noise = side["noise"]
    dof = np.clip((count - 3) / count, 0.0, 1.0)  # three albedo scales absorb part of the noise
    noise_blurred = noise * grid.gain * (np.sqrt(2.0) if undeformed_noise else 1.0)
    dof_median = float(np.median(dof[grid.valid])) if grid.valid.any() else 1.0
    expected = grid.per_pixel(np.full(grid.valid.shape, noise_blurred) * np.sqrt(dof))
    misfit = np.where(valid, grid.per_pixel(misfit), np.nan)
    level = grid.per_pixel(side["level"])
    sample_noise = float(noise_blurred) * np.sqrt(dof_median)
    return ContactMap(misfit, expected, tuple(live), side["dead"], noise, level, samples, sample_noise)


def prepare_press_side(
    press: Press,
    cache: dict,
    *,
    dead_level: float = tolerances.LIT_LEVEL,
    blur_px: float = 1.5,
    block: int | None = None,
) -> None:
    """Fill ``cache`` with the press's side of :func:`classify_contact` (live LEDs, smoothed images, noise), as
    its first call with ``cache`` and the same keywords would; that call then only fits the undeformed model.

    Why apart: that side does not depend on the undeformed model, so a solve makes it while it fits the indirect
    term that the model needs (:func:`nlipscalib.solver.light_and_contact.light_and_contact`, on a second core)."""
    if press.reference is None:
        raise CaptureError(f"{press.folder}: --roi auto and anchoring need the capture's reference (undeformed dome)")
    _fill_press_side(cache, press, _grid_of(press, blur_px, block), None, dead_level)


def _grid_of(press: Press, blur_px: float, block: int | None) -> _Grid:
    """The :class:`_Grid` that :func:`classify_contact` works on for ``press`` (its reference's gel pixels)."""
    valid = np.isfinite(press.reference.depth)
    return _Grid.of(valid, classify_block(valid.shape) if block is None else int(block), blur_px)


def _fill_press_side(side: dict, press: Press, grid: _Grid, indirect: np.ndarray | None, dead_level: float) -> None:
    """:func:`_press_side` into ``side`` unless it holds it already for ``grid``'s block size."""
    if side.get("block") != grid.block:  # empty, or filled at another block size
        side.clear()
        side.update(_press_side(press, grid, indirect, dead_level))


def _press_side(press: Press, grid: _Grid, indirect: np.ndarray | None, dead_level: float) -> dict:
    """The press's half of :func:`classify_contact`: live LEDs, smoothed images (on ``grid``) and their level,
    noise (of the pixels), and the block size they were made at."""
    img, valid = press.linear_led_images, grid.pixels
    level = led_levels(img, valid)
    dead = tuple(int(i) for i in np.flatnonzero(~lit_leds(level, dead_level)))
    live = [i for i in range(len(img)) if i not in dead]
    if len(live) < tolerances.MIN_LEDS_PER_PIXEL:
        from .exposure import no_light_reason

        why = no_light_reason(press, valid, level >= dead_level)  # black or saturated throughout: say so
        raise CaptureError(
            f"{press.folder}: only {len(live)} LED images are lit (dead: {[i + 1 for i in dead]}); "
            f"nothing can be reconstructed{why}"
        )
    # the press's own mask, made once per press; every LED live (the usual case): that mask, not a copy of it
    sat = press.saturated_led_images if len(live) == len(img) else press.saturated_led_images[live]
    # nothing saturated (the usual case): no mask to multiply by; else a block is usable where all its samples are
    ok = None if not sat.any() else (~sat if grid.block == 1 else grid.means(sat, range(len(live))) <= 0)
    # Deformation changes the shading coherently over many pixels, noise does not: classify on
    # smoothed images (normalised convolution inside the gel) and scale the noise alike.
    if grid.block == 1:
        img = grid.smooth((img if indirect is None else img - indirect)[live])
    else:
        img = grid.means(img, live)
        if indirect is not None:  # block means are linear: subtracted from them, not from the whole frames
            img -= grid.means(indirect, live)
        img = grid.smooth(img)
    shape = grid.valid.shape
    count = np.maximum(ok.sum((0, 3)), 1) if ok is not None else np.full(shape, img.shape[0] * img.shape[3])
    return {
        "block": grid.block,
        "live": live,
        "dead": dead,
        "images": img,
        "ok": ok,
        "count": count,
        "noise": image_noise([press.linear_led_images[i] for i in live], valid),  # no copy of the stack
        "level": np.sqrt(_sum_squares(img, ok) / count),
    }


BLOCK_MIN_SIDE = 480
"""Short side, pixels, of the frames that :func:`classify_contact` classifies on 2 x 2 block means
(:func:`classify_block`). Why: it smooths by 1.5 px anyway, and what it gives -- a box with an 8-pixel margin,
the pixels to anchor, the contact left out of a refit -- moves by a pixel or two, while its whole-frame passes
over the LED images (blur, the misfit's sums, the undeformed model and its light) read a quarter of the
pixels. Measured on the one-bounce 640x480 twin presses with ``--roi auto``: the two classifications of a
solve took 0.17 s of CPU instead of 1.2 s (in process, on the shared 2-core machine); the boxes moved by 1-2 px
(sphere [281, 173, 216, 210] -> [280, 172, 218, 210]); contact AAE / MabsE / depth RMSE sphere 0.525 deg /
0.0044 / 0.0384 mm -> 0.524 / 0.0044 / 0.0372, cube 0.427 / 0.0036 / 0.0900 -> 0.427 / 0.0036 / 0.0896.
Smaller frames keep every pixel: their classification costs little, and a 96x72 dent is a few blocks wide."""


def classify_block(shape: tuple[int, int]) -> int:
    """Block side, pixels, that :func:`classify_contact` works on for a frame of ``shape`` = (H, W): 2 from
    :data:`BLOCK_MIN_SIDE` on (both sides even), else 1 (every pixel)."""
    H, W = shape
    return 2 if min(H, W) >= BLOCK_MIN_SIDE and H % 2 == 0 and W % 2 == 0 else 1


@dataclasses.dataclass(frozen=True)
class _Grid:
    """The pixels :func:`classify_contact` works on: the frame's, or the means of square blocks of them."""

    pixels: np.ndarray
    """(H, W) bool -- the gel's pixels."""
    block: int
    """Block side, pixels (1: every pixel)."""
    valid: np.ndarray
    """(H / block, W / block) bool -- blocks holding a gel pixel."""
    sigma: float
    """Gaussian blur, in blocks, of :meth:`smooth`."""
    gain: float
    """How much block mean and blur scale white pixel noise (L2 norm of their kernel)."""

    @classmethod
    def of(cls, pixels: np.ndarray, block: int, blur_px: float) -> _Grid:
        """The grid of ``block`` x ``block`` blocks of ``pixels`` (H, W) bool that smooths like a blur of ``blur_px``.

        The blur on the blocks is ``blur_px`` / b blocks. A block mean's noise is the pixels' over b (b^2
        independent samples), white again, so the noise gain is the blur's over b. Why not a blur that makes up
        only the rest of ``blur_px``^2 after the block mean's own box (variance (b^2 - 1) / 12 px^2, 0.71 blocks
        for b = 2): on the 640x480 one-bounce sphere press its noise-only misfit came out 7.5 % above the
        per-pixel classification's and its undeformed pixels 7 % more; with 1.5 px / 2 both are within 1 %
        (median misfit 2.550e-3 against 2.549e-3)."""
        if block == 1:
            return cls(pixels, 1, pixels, blur_px, _gain(blur_px))
        H, W = pixels.shape
        if H % block or W % block:
            raise ValueError(f"a {W}x{H} frame is not a whole number of {block}x{block} blocks")
        valid = pixels.reshape(H // block, block, W // block, block).any(axis=(1, 3))
        sigma = blur_px / block
        return cls(pixels, block, valid, sigma, _gain(sigma) / block)

    def means(self, stack: np.ndarray, index: Sequence[int]) -> np.ndarray:
        """(n, h, w, 3) float32 -- the images ``stack[index]`` ((L, H, W, 3), or a sequence of L (H, W, 3) images
        read one at a time, :class:`radiosity.Upsampled`; any real or bool dtype) averaged
        over each block's gel pixels (0 where it has none); ``stack[index]`` as float32 on a grid of pixels."""
        if self.block == 1:
            return np.asarray(stack, np.float32)[list(index)]
        import cv2

        index = list(index)
        h, w = self.valid.shape
        whole = bool(self.pixels.all())
        weight = None if whole else self.pixels.astype(np.float32)[..., None]
        if not whole:  # 1 / the gel's share of each block
            share = cv2.resize(weight[..., 0], (w, h), interpolation=cv2.INTER_AREA)
            norm = np.where(share > 0, 1.0 / np.maximum(share, 1e-6), 0.0).astype(np.float32)[..., None]
        out = np.empty((len(index), h, w, 3), np.float32)

        def one(k: int):
            x = np.asarray(stack[index[k]], np.float32)  # one image at a time: no float32 copy of the stack
            if weight is None:
                out[k] = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA)  # the block mean (integer factor)
            else:
                out[k] = cv2.resize(x * weight, (w, h), interpolation=cv2.INTER_AREA) * norm

        threads.map_items(one, range(len(index)))
        return out

    def smooth(self, stack: np.ndarray) -> np.ndarray:
        """:func:`_smooth` of an (n, h, w, 3) stack on this grid."""
        return _smooth(stack, self.valid, self.sigma)

    def per_pixel(self, values: np.ndarray) -> np.ndarray:
        """(H, W) -- each pixel gets its block's value of ``values`` (h, w)."""
        b = self.block
        return values if b == 1 else np.repeat(np.repeat(values, b, axis=0), b, axis=1)


def _undeformed_advice(folder: str | Path, reference: str | Path | None) -> str:
    """What to do with a press that is the undeformed dome, fitted to where its reference came from.

    Why: the advice was always "use it as the reference", also to a folder that had its reference/ already (the
    press is then a second capture of the undeformed dome, best moved out of the folder) and to a press solved
    with an explicit --reference (which is that capture already)."""
    if reference is None:
        return f"if it is the undeformed dome, use it as the reference (--reference {folder}, or a folder's reference/)"
    press, reference = Path(folder), Path(reference)
    if reference.resolve() == (press.parent / "reference").resolve():
        return (
            f"if it is another capture of the undeformed dome, it needs no solve: move it out of {press.parent}, "
            f"whose reference/ is that capture"
        )
    return f"if it is another capture of the undeformed dome, it needs no solve: {reference} is that capture"


def auto_roi(contact: ContactMap, shape: tuple[int, int], **kwargs: Any) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, w, h) of the pixels whose images disagree with the undeformed dome: :func:`contact_box`
    (the same keywords) without its note, which goes to the log as a warning."""
    box, note = contact_box(contact, shape, **kwargs)
    if note:
        log.warning("%s: %s", kwargs.get("folder", ""), note)
    return box


def contact_box(
    contact: ContactMap,
    shape: tuple[int, int],
    margin: int = 8,
    min_size: int = 32,
    threshold: float = tolerances.CONTACT_MISFIT_FACTOR,
    min_component: float = 0.05,
    folder: str | Path = "",
    reference: str | Path | None = None,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None = None,
    flank: bool = False,
) -> tuple[tuple[int, int, int, int], str]:
    """Bounding box (x0, y0, w, h) of the pixels whose images disagree with the undeformed dome, and a note.

    ``folder`` is the press's, ``reference`` the folder of the undeformed dome's capture it was compared with (None:
    not known), both named in the refusal of a press without contact (:func:`_undeformed_advice`).

    Candidates are the pixels :func:`contact_hits` calls hit (with ``threshold``); of their connected
    components only those at least ``min_component`` times the largest are kept, so isolated misfits (cast
    shadows far from the dent, silhouette aliasing, hot pixels) do not stretch the box.

    When that box would cover most of the gel (:data:`tolerances.ROI_LARGE_FRACTION` of the gel's bounding
    box), the components along the gel's edge are left out if a large one remains inside
    (:func:`_inner_regions`): an unmodelled effect that grows toward the view's edge -- vignetting, the view
    through the gel at grazing angles, a glossy coat -- misfits there, away from the dent. Seen on the
    ``nlipstac_realistic`` twin (160x120): the four corners misfit as much as the dent and the box was the
    whole frame; without them it is the dent's. A dent that reaches the edge keeps its edge part (parts
    within ``2 margin`` pixels of the inner one join it).

    Where the images fit the undeformed model to noise, components that peak below what noise reaches
    (:func:`_noise_like`) are left out first: a tiny or shallow contact's hits are fewer than the weak ones noise
    makes along the view's edge, and ``min_component`` alone kept those and boxed the whole gel.
    ``edge_model_error``, given the (H, W) bool pixels left out along the edge, returns the misfit (H, W, image
    units) the undeformed model is known to leave there (:func:`point_led_misfit`); pixels within ``threshold``
    times it (and their floor, in quadrature: :func:`_beyond`) are that model's error, and unless the others hold
    :data:`tolerances.ROI_MIN_INNER_FRACTION` of the gel they are left out without a note (the box is the same
    either way). ``flank``: the box grows over the contact's flank (:func:`grow_over_flank`; ``--roi auto``'s box,
    not the outer loop's dent focus, whose wide margin holds it).

    Returns
    -------
    box : (x0, y0, w, h) pixels
    note : str -- empty, or what was left out, or a warning that the box still covers most of the gel.
    """
    valid = np.isfinite(contact.misfit)
    if not valid.any():
        raise CaptureError(f"{folder}: no pixel sees the gel; nothing to reconstruct")
    hit = contact_hits(contact, threshold)
    if why := no_contact(contact, hit, edge_model_error):
        reason, within_noise = why
        solve_anyway = "pass --roi X0 Y0 W H, or no --roi, to solve it anyway"
        if within_noise:
            # what to do, as well as what was found: a press too light to show, or the undeformed dome's capture
            raise NoContactError(
                f"{folder}: --roi auto found no contact ({reason}); nothing solved: the surface is the reference's. "
                f"If it was pressed, press deeper (or with a larger object) and capture it again; "
                f"{_undeformed_advice(folder, reference)} ({solve_anyway})"
            )
        raise CaptureError(f"{folder}: --roi auto found no contact ({reason}); nothing solved ({solve_anyway})")
    labels, sizes = masks.components(hit)
    sizes = np.where(_noise_like(contact, labels, len(sizes), 2 * margin), 0, sizes)
    keep = np.flatnonzero(sizes >= min_component * sizes.max()) + 1
    region = np.isin(labels, keep)
    note = ""
    if _box_fraction(region, valid) >= tolerances.ROI_LARGE_FRACTION:
        inner = _inner_regions(labels, sizes, valid, 2 * margin, min_component)
        left = region & ~inner if inner is not None else None
        if left is not None and left.any():
            region = inner
            unexplained = (
                left if edge_model_error is None else left & _beyond(contact, edge_model_error(left), threshold)
            )
            # specks beyond it (the capsule's image corners: 6-118 px each, an effect not modelled here) are not
            # worth a warning; an effect that is makes a patch as large as an inner component the box counts
            if _largest_patch(unexplained) >= (
                1 if edge_model_error is None else tolerances.ROI_MIN_INNER_FRACTION * valid.sum()
            ):
                note = (
                    f"--roi auto left out {int(left.sum())} misfitting pixels along the gel's edge "
                    f"({int(unexplained.sum())} beyond the point-LED model's known error; an effect the undeformed "
                    f"model does not have there, e.g. vignetting or the view at grazing angles); pass --roi X0 Y0 W H "
                    f"to solve them too"
                )
            else:
                log.info(
                    "%s: --roi auto left out %d pixels along the gel's edge that misfit by what the point-LED model "
                    "misses of LEDs %.1f mm across",
                    folder,
                    int(left.sum()),
                    2 * tolerances.LED_EMITTER_RADIUS_MM,
                )
    rows, cols = np.nonzero(region)
    H, W = shape
    y0, y1 = max(rows.min() - margin, 0), min(rows.max() + 1 + margin, H)
    x0, x1 = max(cols.min() - margin, 0), min(cols.max() + 1 + margin, W)
    if flank:
        x0, y0, x1, y1 = grow_over_flank(contact, region, (x0, y0, x1, y1), margin)
    if x1 - x0 < min_size:
        c = (x0 + x1) // 2
        x0, x1 = max(c - min_size // 2, 0), min(c + min_size // 2, W)
    if y1 - y0 < min_size:
        c = (y0 + y1) // 2
        y0, y1 = max(c - min_size // 2, 0), min(c + min_size // 2, H)
    box = (int(x0), int(y0), int(x1 - x0), int(y1 - y0))
    # judged on the misfit itself, not on the box's margin and minimum size: at 96x72 those alone make a
    # small dent's box cover half the gel, and the warning is about images that do not fit the model
    spread = _box_fraction(region, valid)
    if not note and spread >= tolerances.ROI_LARGE_FRACTION:
        note = (
            f"--roi auto: the pixels whose images differ from the undeformed model span {100 * spread:.0f} % of "
            f"the gel's extent (its bounding box): a press that large, or LEDs / reference that do not fit this "
            f"sensor (try nlips calibrate-leds or --reference); pass --roi X0 Y0 W H to choose the region"
        )
    # the contact itself at the border, not its box's margin: at 64x48-96x72 (tests, the demo) every contact lies
    # within the 8-pixel margin of some border, and the note fired on presses whose box holds undeformed gel
    # all round (the lead, s27)
    edge = EDGE_CONTACT_PX
    at_edge = min(rows.min(), cols.min()) < edge or rows.max() + edge >= H or cols.max() + edge >= W
    if not note and at_edge:
        # the twin at polar 40-70 deg, 320x240: 0.1-0.4 deg more contact AAE than the whole gel (s27-unusual)
        note = (
            "--roi auto: the contact reaches the image's edge, where its box has no undeformed gel around it on that "
            "side: its normals near the edge are less reliable than a whole-gel solve's (drop --roi to solve the "
            "whole gel)"
        )
    return box, note


def grow_over_flank(
    contact: ContactMap, region: np.ndarray, edges: tuple[int, int, int, int], margin: int, step: int = 4
) -> tuple[int, int, int, int]:
    """The box ``edges`` = (x0, y0, x1, y1), pixels (x1, y1 exclusive), grown side by side over a contact's flank:
    while the ``step``-pixel strip beyond a side holds :data:`tolerances.ROI_FLANK_SHARE` of its pixels above
    :data:`tolerances.ROI_FLANK_FACTOR` times the floor of :func:`contact_hits` (only those joined to ``region``, the
    (H, W) bool pixels the box holds, and not within ``margin`` of the gel's edge), the side moves to ``margin``
    pixels past that strip (within the image). The first strips lie :data:`tolerances.ROI_FLANK_START` of the
    image's short side beyond ``region``; a box at the image's border on one axis does not grow along it.

    Why: a large flat indenter (the 20 mm coin face) moves the gel far beyond the pixels hit at
    :data:`tolerances.CONTACT_MISFIT_FACTOR`; its flank misfits by less, over many pixels, and the box of the hits
    plus ``margin`` left out a third of the contact."""
    H, W = region.shape
    box = list(edges)
    # the first strips lie a share of the view beyond the contact's hits: a plain dent's weak rim and the change of
    # its light around it lie within (12 px at 320x240, 24 at 640x480)
    start = max(int(round(tolerances.ROI_FLANK_START * min(H, W))) - margin, 0)
    probe = [max(box[0] - start, 0), max(box[1] - start, 0), min(box[2] + start, W), min(box[3] + start, H)]
    over = _over_flank_level(contact)
    # a plain dent (most presses): no first strip shows flank even before the checks below, which cost a whole
    # frame's erosion and labelling (~25 ms at 640x480)
    if not any(_is_flank(over, _strip(side, probe[side], box, step, (H, W))) for side in range(4)):
        return edges
    gel = np.isfinite(contact.misfit)
    # not within a margin of the gel's edge or the image's border: the view there misfits more (the smoothing's fewer
    # pixels, grazing angles); only the flank that joins the box's contact: misfits that contact_box left out
    # (noise-like, or too small beside the contact) are not its flank
    over &= masks.erode(gel, iterations=margin)
    labels, _ = masks.components(over | region)
    over &= np.isin(labels, np.unique(labels[region]))
    growing = [True] * 4
    while any(growing):
        for side in range(4):
            # a box at the image's border on one axis grows not along it: the view there misfits more than the
            # gel's edge band (the twin at polar 55: 1.5-3.7 times the floor 30 px in from the right border, the
            # whole height), and the box grew along it from one end of the image to the other
            along_border = (box[1] == 0 or box[3] == H) if side in (0, 2) else (box[0] == 0 or box[2] == W)
            if along_border or not (growing[side] and _is_flank(over, _strip(side, probe[side], box, step, (H, W)))):
                growing[side] = False
                continue
            outward = -1 if side < 2 else 1
            probe[side] = int(np.clip(probe[side] + outward * step, 0, (W, H)[side % 2]))
            moved = int(np.clip(probe[side] + outward * margin, 0, (W, H)[side % 2]))
            box[side] = min(box[side], moved) if side < 2 else max(box[side], moved)
    return box[0], box[1], box[2], box[3]


def _over_flank_level(contact: ContactMap) -> np.ndarray:
    """(H, W) bool -- misfit above :data:`tolerances.ROI_FLANK_FACTOR` times the floor of :func:`contact_hits`."""
    floor = np.maximum(contact.expected, contact.median_misfit)
    return np.nan_to_num(contact.misfit) > tolerances.ROI_FLANK_FACTOR * np.maximum(floor, 1e-9)


def _strip(side: int, probe: int, box: list[int], step: int, shape: tuple[int, int]) -> tuple[slice, slice]:
    """(rows, cols) slices of the ``step``-pixel strip beyond ``box`` = [x0, y0, x1, y1]'s ``side`` (0 left, 1 top,
    2 right, 3 bottom) that starts at ``probe`` (outward), spanning the box along that side, within ``shape``."""
    H, W = shape
    x0, y0, x1, y1 = box
    if side == 0:
        return slice(y0, y1), slice(max(probe - step, 0), probe)
    if side == 1:
        return slice(max(probe - step, 0), probe), slice(x0, x1)
    if side == 2:
        return slice(y0, y1), slice(probe, min(probe + step, W))
    return slice(probe, min(probe + step, H)), slice(x0, x1)


def _is_flank(over: np.ndarray, strip: tuple[slice, slice]) -> bool:
    """Whether :data:`tolerances.ROI_FLANK_SHARE` of the strip's pixels are ``over`` (False for an empty strip)."""
    part = over[strip]
    return part.size > 0 and int(part.sum()) >= tolerances.ROI_FLANK_SHARE * part.size


def _noise_like(contact: ContactMap, labels: np.ndarray, count: int, join: int) -> np.ndarray:
    """(count,) bool -- the hit components (``labels`` 1..count of :func:`contact_hits`) that noise alone could
    make: peak misfit below :data:`tolerances.NO_CONTACT_PEAK` times its floor, and farther than ``join`` pixels
    from any component above it (the weaker rim of a dent joins its core). None is noise-like where the images
    fit the undeformed model only to model error (:data:`tolerances.MODEL_MISFIT_FLOOR`): a dent's peak there
    stands out by less.

    Why: the twin at 320x240 has 3-4x-floor hits in the image's corners; a 1 mm sphere's contact (peak 38, 187
    hits) or a 0.05 mm-deep press's (7.4, 110 hits) was smaller than them, so the box was the whole gel
    (benchmarks/RESULTS.md, s27-unusual)."""
    weak = np.zeros(count, bool)
    if count == 0 or contact_floor(contact) >= tolerances.MODEL_MISFIT_FLOOR:
        return weak
    on = labels > 0
    floor = np.maximum(contact.expected[on], contact.median_misfit)
    peaks = np.zeros(count + 1)
    np.maximum.at(peaks, labels[on], contact.misfit[on] / np.maximum(floor, 1e-9))
    strong = peaks >= tolerances.NO_CONTACT_PEAK
    strong[0] = False
    if not strong.any():
        return weak
    near = masks.dilate(strong[labels], iterations=join)
    weak = ~strong[1:]
    weak[np.unique(labels[near & on]) - 1] = False
    return weak


def widen_to_anchor(
    contact: ContactMap, box: tuple[int, int, int, int], shape: tuple[int, int], step: int = 8
) -> tuple[tuple[int, int, int, int], float, float]:
    """``box`` (x0, y0, w, h, pixels) widened by ``step`` pixels at a time, within the image of ``shape`` (H, W),
    until :data:`tolerances.ROI_MIN_UNDEFORMED_SHARE` of its gel pixels look undeformed (the pixels anchoring pins to
    the reference), or it is the whole image; not where anchoring is off (:data:`ANCHOR_MIN_FRACTION`: a noise-free
    render, whose model error leaves next to no pixel within noise).

    Returns
    -------
    box : (x0, y0, w, h) pixels -- ``box`` itself when it holds enough.
    before, after : float -- the share of undeformed gel pixels in ``box`` and in the returned box.
    """
    H, W = shape
    valid = np.isfinite(contact.misfit)
    undeformed = contact.undeformed(tolerances.ANCHOR_NOISE_FACTOR) & valid
    x0, y0, w, h = box
    x1, y1 = x0 + w, y0 + h

    def share() -> float:
        return float(undeformed[y0:y1, x0:x1].sum()) / max(int(valid[y0:y1, x0:x1].sum()), 1)

    first = now = share()
    if float(undeformed.sum()) < ANCHOR_MIN_FRACTION * max(int(valid.sum()), 1):
        return box, first, first  # anchoring is off (anchor_weights): nothing to widen for
    while now < tolerances.ROI_MIN_UNDEFORMED_SHARE and (x0, y0, x1, y1) != (0, 0, W, H):
        x0, y0, x1, y1 = max(x0 - step, 0), max(y0 - step, 0), min(x1 + step, W), min(y1 + step, H)
        now = share()
    return (int(x0), int(y0), int(x1 - x0), int(y1 - y0)), first, now


def point_led_misfit(
    press: Press,
    leds: Leds,
    contact: ContactMap,
    pixels: np.ndarray,
    radius: float = tolerances.LED_EMITTER_RADIUS_MM,
    indirect_light: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """What the undeformed model's point LEDs alone make a pixel misfit: the misfit of the point model to LEDs that
    emit from disks of ``radius`` (:func:`nlipscalib.core.leds.disk_shading`), both on the reference surface, as a
    share of their shading, times the direct light's part of the pixel's image level (:attr:`ContactMap.level`).

    From the design (reference surface, LEDs), not from the images: large where the gel comes within a few LED
    sizes of an LED (the ``capsule`` design's wall at the image border: 2-6 % there, s27-shapes2).

    Parameters
    ----------
    press : Press -- with ``reference``.
    leds : sequence of Led -- the undeformed model's LEDs (all of the press's; ``contact.live_leds`` are used).
    contact : ContactMap -- of that model.
    pixels : (H, W) bool -- where to evaluate it (a few thousand edge pixels: ~5 ms each 1,000 with 12 LEDs).
    radius : float, mm.
    indirect_light : sequence of L (H, W, 3) float or None -- the undeformed model's indirect light per unit
        albedo, per LED (``IndirectModel.undeformed_light_per_led``), when its interreflection term is on; None:
        the images are direct light only. The point-LED error is the direct light's, so it is scaled by each pixel's
        direct share, point shading / (point shading + that light): not the term's median share (the capsule's
        0.885, a direct share of 0.53), since the gel beside an LED takes more direct light than the median pixel.
        With that median share the capsule's image corners misfit 1.5-2 times the error predicted (s28-capsule).

    Returns
    -------
    (H, W) float64 -- linear image units; 0 off ``pixels`` and off the gel.
    """
    out = np.zeros(pixels.shape)
    ref = press.reference
    rows, cols = np.nonzero(pixels & np.isfinite(ref.depth))
    if rows.size == 0:
        return out
    live = [tuple(leds)[i] for i in contact.live_leds]
    points = depth_to_points(ref.depth[rows, cols], press.camera.rays[rows, cols])
    normals = ref.normals[rows, cols]
    point = led_shading(points, normals, live).astype(np.float32)[:, :, None]  # (L, N, 1, 3): a 1-wide image
    disk = disk_shading(points, normals, live, radius).astype(np.float32)[:, :, None]
    count = np.full((rows.size, 1), point.shape[0] * point.shape[3])
    share = _misfit(point, disk, None, count)[:, 0] / np.maximum(np.sqrt(_sum_squares(disk, None) / count)[:, 0], 1e-30)
    direct = 1.0
    if indirect_light is not None:
        lit = point.sum(axis=(0, 2, 3), dtype=np.float64)  # (N,): the direct shading over the live LEDs and colours
        bounced = sum(np.asarray(indirect_light[i])[rows, cols].sum(-1, dtype=np.float64) for i in contact.live_leds)
        direct = lit / np.maximum(lit + bounced, 1e-30)
    out[rows, cols] = share * direct * np.nan_to_num(contact.level[rows, cols])
    return out


def _largest_patch(mask: np.ndarray) -> int:
    """Pixels in the largest connected patch of ``mask`` (H, W) bool (0 when empty)."""
    if not mask.any():
        return 0
    return int(masks.components(mask)[1].max())


def _beyond(contact: ContactMap, model_error: np.ndarray, threshold: float, blur_px: float = 1.5) -> np.ndarray:
    """(H, W) bool -- pixels whose misfit exceeds ``threshold`` times their floor and a known model error
    ``model_error`` (H, W) added in quadrature (independent errors). The floor is :func:`contact_hits`'s plus, in
    quadrature, the noise the smoothing leaves beyond the noise-only misfit where it averages fewer pixels
    (:func:`edge_noise_gain`, on the pixel grid with :func:`classify_contact`'s ``blur_px``). Why: the capsule's
    undeformed capture misfits 4.2-5.7 times the plain floor in the image's corners (s27-shapes2)."""
    gel = np.isfinite(contact.misfit)
    floor = np.maximum(contact.expected, contact.median_misfit)
    extra_noise = contact.expected * np.sqrt(np.maximum(edge_noise_gain(gel, blur_px) ** 2 - 1.0, 0.0))
    return np.nan_to_num(contact.misfit) > threshold * np.sqrt(floor**2 + extra_noise**2 + model_error**2)


def edge_noise_gain(valid: np.ndarray, sigma: float) -> np.ndarray:
    """How much more white noise :func:`_smooth` leaves at each pixel than inside the gel: near the gel's
    silhouette and the image border its normalised convolution averages fewer pixels (and the border's reflected
    ones twice), 1.7 times the noise in an image corner at 1.5 px.

    Parameters
    ----------
    valid : (H, W) bool -- the gel's pixels.
    sigma : float -- the blur, pixels.

    Returns
    -------
    (H, W) float64 -- >= about 1 on the gel (1 far from its edge); 1 off it.

    Exact for :func:`_smooth`: its blur is separable, so the squared weights of a pixel's average are
    ``Gy**2 valid Gx**2.T`` with ``Gy``, ``Gx`` the 1-D blurs as matrices (OpenCV's kernel and border, got by
    blurring identity matrices), and the average's weights sum to ``Gy valid Gx.T``."""
    if sigma <= 0:
        return np.ones(valid.shape)
    import cv2

    def matrix(n: int) -> np.ndarray:  # (n, n): row i = the weights that output i takes from each input
        eye = np.eye(n, dtype=np.float32)
        # blurred along its columns only: entry (j, i) is what input j gives output i (asymmetric at the border)
        return cv2.GaussianBlur(eye, (0, 0), sigmaX=sigma, sigmaY=1e-6).astype(np.float64).T

    Gx, Gy = matrix(valid.shape[1]), matrix(valid.shape[0])
    v = valid.astype(np.float64)
    weights = Gy @ v @ Gx.T
    squares = (Gy**2) @ v @ (Gx**2).T
    gain = np.sqrt(squares) / np.maximum(weights, 1e-12)
    return np.where(valid, gain / _gain(sigma), 1.0)  # over the gain far from any edge


def contact_hits(contact: ContactMap, threshold: float = tolerances.CONTACT_MISFIT_FACTOR) -> np.ndarray:
    """Pixels in or at the contact: misfit above ``threshold`` times the larger of its noise-only value and the
    misfit's median over the gel (the undeformed model is never exact on a real sensor).

    Parameters
    ----------
    contact : ContactMap
    threshold : float -- see :data:`nlipscalib.core.tolerances.CONTACT_MISFIT_FACTOR`.

    Returns
    -------
    (H, W) bool -- all False when no pixel sees the gel.
    """
    mis = contact.misfit
    valid = np.isfinite(mis)
    if not valid.any():
        return valid
    floor = np.maximum(contact.expected, contact.median_misfit)
    return valid & (mis > threshold * np.maximum(floor, 1e-9))  # NaN compares False, off the gel anyway


def no_contact(
    contact: ContactMap,
    hit: np.ndarray | None = None,
    model_error: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[str, bool] | None:
    """Why the press shows no contact, and whether its images match the undeformed dome within noise; None when it
    shows one.

    Where the images fit the model to noise, a contact's peak misfit is far above
    :data:`~nlipscalib.core.tolerances.NO_CONTACT_PEAK` times its floor and noise's below, or, where the LEDs see
    the dent from a narrow cone (a faint dent), its hits make a patch of a dent's size away from the gel's edge
    (:func:`_inner_dent`), which noise's scattered hits do not. Where they fit it only to
    model error (the floor :data:`~nlipscalib.core.tolerances.MODEL_MISFIT_FLOOR` times the noise or more: LEDs
    off their design power or place), a plain dent stands out by less, so only a press without a single hit
    (:func:`contact_hits`) has none, and the remedy is an LED model that fits.

    Parameters
    ----------
    contact : ContactMap
    hit : (H, W) bool or None -- :func:`contact_hits` of ``contact`` when at hand.
    model_error : as :func:`contact_box`'s ``edge_model_error`` (:func:`point_led_misfit`), or None -- asked of the
        whole gel only when the floor says the LEDs do not fit and no pixel is hit: a floor that the point-LED
        model's known error explains (the ``flat`` design with its exact LEDs: 3.9 times the noise, 1.01 times
        hypot(noise, that error); s27-shapes2) is then "within noise", not "the LED model does not fit". And of
        the pixels that reach NO_CONTACT_PEAK times the floor when no patch says "dent": the peak is then over the
        floor and that error together (:func:`_peak_beyond_model_error`; the ``capsule``'s image corners,
        s28-capsule).

    Returns
    -------
    (reason, within_noise) or None -- ``reason`` is one clause with the numbers; ``within_noise`` False says the
        images do not fit the LED model (the press may well have a contact).
    """
    floor = contact_floor(contact)
    hit = contact_hits(contact) if hit is None else hit
    if floor < tolerances.MODEL_MISFIT_FLOOR:
        peak = contact_peak(contact)
        within = f"within noise: the strongest misfit is {peak:.1f} times its floor"
        if peak >= tolerances.NO_CONTACT_PEAK and model_error is not None:
            # the point-LED model's own error can reach it (the capsule's image corners, s28-capsule): the peak
            # over the floor and that error together decides
            peak = _peak_beyond_model_error(contact, model_error)
            within = (
                f"within noise and the point-LED model's known error: the strongest misfit is {peak:.1f} times both"
            )
        if peak >= tolerances.NO_CONTACT_PEAK or _inner_dent(hit, np.isfinite(contact.misfit)):
            return None
        return (
            f"images match the undeformed dome {within}, a contact's above {tolerances.NO_CONTACT_PEAK:g}, and no "
            f"patch of misfit away from the gel's edge is a dent's size ({100 * tolerances.NO_CONTACT_PATCH:g} % of "
            f"the gel)",
            True,
        )
    if hit.any():
        return None
    if model_error is not None:
        gel = np.isfinite(contact.misfit)
        known = np.hypot(contact.expected[gel], model_error(gel)[gel])
        explained = contact.median_misfit / max(float(np.median(known)), 1e-12)
        if explained < tolerances.MODEL_MISFIT_FLOOR:
            return (
                f"images match the undeformed dome within noise and the point-LED model's known error (the misfit's "
                f"median is {explained:.1f} times theirs, {floor:.1f} times the noise alone), and no pixel misfits by "
                f"{tolerances.CONTACT_MISFIT_FACTOR:g} times more",
                True,
            )
    return (
        f"the images differ from the undeformed model all over the gel, {floor:.0f} times the noise, and no pixel "
        f"by {tolerances.CONTACT_MISFIT_FACTOR:g} times more: the LED model does not fit this sensor; calibrate the "
        f"LEDs on its undeformed capture (nlips calibrate-leds REF --out leds.json) and solve with --leds leds.json, "
        f"or solve against that capture (--reference REF)",
        False,
    )


def _peak_beyond_model_error(contact: ContactMap, model_error: Callable[[np.ndarray], np.ndarray]) -> float:
    """:func:`contact_peak` with the model's known error ``model_error`` (:func:`point_led_misfit`) added to the
    floor in quadrature (independent errors), asked only of the pixels at or above
    :data:`~nlipscalib.core.tolerances.NO_CONTACT_PEAK` times the plain floor (no other can reach it), and of the
    :data:`_PEAK_FIRST` strongest of those first: when one of them still reaches it (a dent), that value is
    returned, a lower bound of the peak that settles the question without asking about the rest.

    Why: the ``capsule`` design's wall in the image corners comes within 4.4 mm of a 3.6 mm LED, where the point
    model misses 3-4 % of that LED's light, 3-5 times the floor of a 16-spp capture: its undeformed captures
    peaked at 8.0-10.1 there and 7 of 8 were solved as presses (benchmarks/RESULTS.md, s28-capsule)."""
    mis = np.nan_to_num(contact.misfit)
    floor = np.maximum(contact.expected, contact.median_misfit)
    strong = np.isfinite(contact.misfit) & (mis >= tolerances.NO_CONTACT_PEAK * floor)
    index = np.flatnonzero(strong)
    # strongest first, sorting only those (the whole frame's argsort: 0.1 s at 640x480)
    order = index[np.argsort(mis.flat[index] / np.maximum(floor.flat[index], 1e-12))[::-1]]
    peak = 0.0
    for part in (order[:_PEAK_FIRST], order[_PEAK_FIRST:]):
        if part.size == 0:
            break
        asked = np.zeros(strong.shape, bool)
        asked.flat[part] = True
        known = np.hypot(floor.flat[part], model_error(asked).flat[part])
        peak = max(peak, float((mis.flat[part] / np.maximum(known, 1e-12)).max()))
        if peak >= tolerances.NO_CONTACT_PEAK:
            break
    return peak


_PEAK_FIRST = 64
"""Strongest pixels :func:`_peak_beyond_model_error` asks about first (~5 ms with 12 LEDs; all of a dent's)."""


def _inner_dent(hit: np.ndarray, valid: np.ndarray) -> bool:
    """Whether a connected patch of ``hit`` (H, W) bool that does not touch the gel's edge (``valid``'s silhouette
    or the image border) holds :data:`~nlipscalib.core.tolerances.NO_CONTACT_PATCH` of the gel: a dent,
    however faintly it stands out.

    Why, besides the peak: where the LEDs light the dent from a narrow cone of directions (the ``capsule``
    design's apex, 22 mm above its 6.5 mm LED ring) a plain dent misfits by little per pixel but over thousands of
    them: at 320x240 / 8 spp against its undeformed capture the 1 mm cube peaked at 5.4 and a 5 mm cylinder at 4.5
    times the floor, refused as "no contact"; their patches held 3.1 and 0.65 % of the gel, while noise's (a second
    undeformed capture) held at most 10 pixels, model error's (the design LEDs) 48 inside the edge and 600-640
    along it (the capsule's and the default twin's undeformed captures as presses; benchmarks/RESULTS.md,
    s27-shapesfa)."""
    if not hit.any():
        return False
    labels, sizes = masks.components(hit)
    edge = valid & ~masks.erode(valid)
    inner = np.setdiff1d(np.arange(1, len(sizes) + 1), np.unique(labels[edge]))
    return bool((sizes[inner - 1] >= tolerances.NO_CONTACT_PATCH * valid.sum()).any())


def contact_floor(contact: ContactMap) -> float:
    """The misfit's median over the gel in units of its noise-only value's median: about 1-2 where the images fit
    the undeformed model to noise, more where the LED model is off (0 when no pixel sees the gel)."""
    valid = np.isfinite(contact.misfit)
    if not valid.any():
        return 0.0
    return contact.median_misfit / max(float(np.median(contact.expected[valid])), 1e-12)


def contact_peak(contact: ContactMap) -> float:
    """The largest misfit over its floor (the floor of :func:`contact_hits`) on the gel; 0 when no pixel sees it.
    A contact's peak is far above :data:`nlipscalib.core.tolerances.NO_CONTACT_PEAK`, noise's below. Kept on the
    map (:attr:`ContactMap.peak`): the auto ROI and the dent's focus both ask (2-3 ms each at 640x480)."""
    return contact.peak


def _box_fraction(region: np.ndarray, valid: np.ndarray) -> float:
    """Area of ``region``'s bounding box over that of the gel's (``valid``), both (H, W) bool."""

    def area(mask: np.ndarray):
        # from the rows and columns that hold a pixel: 50x faster than the pixels' coordinates (2.4 ms at 640x480)
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
        return 0 if rows.size == 0 else (rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1)

    return area(region) / max(area(valid), 1)


def _inner_regions(
    labels: np.ndarray, sizes: np.ndarray, valid: np.ndarray, join: int, min_component: float
) -> np.ndarray | None:
    """(H, W) bool -- the misfit components that do not touch the gel's edge (the gel's silhouette or the image
    border), at least ``min_component`` times the largest of them and :data:`tolerances.ROI_MIN_INNER_FRACTION`
    of the gel, plus the edge components that come within ``join`` pixels of them; None when no such inner
    component exists (then every component is kept: a dent may lie at the edge)."""
    edge = valid & ~masks.erode(valid)
    edge_labels = np.unique(labels[edge])
    inner = np.setdiff1d(np.arange(1, len(sizes) + 1), edge_labels)
    inner = inner[sizes[inner - 1] >= tolerances.ROI_MIN_INNER_FRACTION * valid.sum()]
    if inner.size == 0:
        return None
    inner = inner[sizes[inner - 1] >= min_component * sizes[inner - 1].max()]
    region = np.isin(labels, inner)
    near = masks.dilate(region, iterations=join)
    touching = np.setdiff1d(np.unique(labels[near & (labels > 0)]), inner)
    return region | np.isin(labels, touching)


def anchor_weights(
    contact: ContactMap,
    mask: np.ndarray,
    weight: float,
    factor: float,
    min_fraction: float = ANCHOR_MIN_FRACTION,
    max_relative: float = 0.05,
) -> tuple[np.ndarray | None, str]:
    """Prior weight multipliers and a report line: ``1 + weight`` where the data show the gel undeformed.

    Parameters
    ----------
    contact : ContactMap
    mask : (H, W) bool -- the solve mask.
    weight : SolverOptions.anchor_weight (0: off).
    factor : a pixel is undeformed when its misfit is within ``factor`` times the noise-only misfit.
    min_fraction : evidence is weak -- no anchoring -- when fewer than this fraction of the gel's
        pixels fit at noise level (the undeformed model does not explain the data at all, e.g. strong
        unmodelled interreflection or a wrong LED model).
    max_relative : a pixel's verdict counts only when its threshold, ``factor`` times the noise-only
        misfit, is at most this fraction of its image level: with more noise a real dent (a 1 deg
        tilt changes the shading by ~2 %) would pass as undeformed.

    Returns
    -------
    weights : (H, W) float64 or None
    note : str -- what was decided and why.
    """
    if weight <= 0:
        return None, "anchoring off (anchor_weight = 0)"
    gel = np.isfinite(contact.misfit)
    sharp = factor * contact.expected <= max_relative * np.nan_to_num(contact.level)
    undeformed = contact.undeformed(factor) & gel & sharp
    fraction = float(undeformed.sum()) / max(int(gel.sum()), 1)
    if contact.noise <= 0 or fraction < min_fraction:
        return None, (
            f"anchoring off: weak evidence (only {100 * fraction:.1f} % of the gel fits the undeformed model within "
            f"{factor:g} x the noise level {contact.noise:.2g} at a threshold below {100 * max_relative:g} % of the "
            f"image)"
        )
    pins = undeformed & mask
    weights = np.ones(mask.shape)
    weights[pins] += weight
    return weights, f"anchored {int(pins.sum())} of {int(mask.sum())} pixels (misfit within {factor:g} x noise)"


def _misfit(S: np.ndarray, img: np.ndarray, ok: np.ndarray | None, count: np.ndarray) -> np.ndarray:
    """(H, W) float32 -- RMS residual of ``S`` scaled per pixel and channel (the albedo) to ``img``.

    ``S``, ``img`` : (L, H, W, 3) float32; ``ok`` : (L, H, W, 3) bool or None (all usable); ``count`` :
    (H, W) usable samples. The sums run in ``np.einsum``: one pass over each stack, no (L, H, W, 3)
    product temporaries (0.04 s against 0.11-0.17 s at 640x480 with 12 LEDs, the same numbers)."""
    Sk = S if ok is None else S * ok
    alb = np.einsum("lhwc,lhwc->hwc", Sk, img) / np.maximum(np.einsum("lhwc,lhwc->hwc", Sk, Sk), 1e-30)
    return np.sqrt(_residual_squares(alb, S, img, ok) / count)


def _residual_squares(alb: np.ndarray, S: np.ndarray, img: np.ndarray, ok: np.ndarray | None) -> np.ndarray:
    """(H, W) float32 -- sum over LEDs and channels of (``alb`` S - img)^2 where ``ok``, LED by LED in one (H, W, 3)
    buffer: each LED's channels summed, (r_0^2 + r_1^2) + r_2^2, then added to the sum, the order in which
    ``np.einsum("lhwc,lhwc->hw", res, res)`` of the whole residual stack sums them at a frame's size (the same bits
    there, tests/solver/test_contact.py), without the stack's two (L, H, W, 3) temporaries: ~3 against ~7 ms of
    one core per classification at 240 x 320 blocks with 12 LEDs (benchmarks/RESULTS.md, s21-cpu)."""
    total = np.zeros(S.shape[1:3], np.float32)
    res = np.empty(S.shape[1:], np.float32)
    for k in range(len(S)):
        np.multiply(alb, S[k], out=res)
        res -= img[k]
        if ok is not None:
            res *= ok[k]
        res *= res
        total += (res[..., 0] + res[..., 1]) + res[..., 2]
    return total


def _sum_squares(stack: np.ndarray, ok: np.ndarray | None) -> np.ndarray:
    """(H, W) -- sum over LEDs and channels of ``stack`` squared where ``ok`` (None: everywhere)."""
    masked = stack if ok is None else stack * ok
    return np.einsum("lhwc,lhwc->hw", masked, masked)


def _smoothed_undeformed(images: np.ndarray | reuse.Deferred, live: Sequence[int], grid: _Grid) -> np.ndarray:
    """``grid.smooth`` of ``grid.means(images, live)`` (float32). When ``images`` is one that ``solver.reuse``
    returned or defers (the sensor's direct shading, shared by the solves of its presses) the result is kept
    under its key, in this process and on disk for the next (a deferred ``images`` is then read only when the
    result is not kept); when it is another read-only array, for the next classification against that same
    array; a writable array could change in place, so it is smoothed anew."""

    def smooth():
        return grid.smooth(grid.means(reuse.values(images), live))

    kept = isinstance(images, reuse.Deferred) or (isinstance(images, np.ndarray) and not images.flags.writeable)
    if not kept:
        return smooth()
    origin = reuse.origin(images)  # the sensor's shading: named by its own key, kept on disk too
    made = (tuple(live), float(grid.sigma), reuse.digest(grid.pixels), grid.block)
    if origin is not None:
        return reuse.reused("smoothed undeformed", (origin, *made), smooth, persist=True)
    return reuse.reused("smoothed undeformed", (id(images), *made), smooth, keep=images)


def _smooth(stack: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur of (L, H, W, 3) images inside ``valid`` (normalised convolution), float32."""
    if sigma <= 0:
        return stack
    import cv2

    w = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sigma)
    inv = np.where(valid, 1.0 / np.maximum(w, 1e-6), 0.0)[..., None]
    out = np.empty(stack.shape, np.float32)

    def blur(i: int):
        out[i] = cv2.GaussianBlur(np.where(valid[..., None], stack[i], 0).astype(np.float32), (0, 0), sigma) * inv

    threads.map_items(blur, range(len(stack)))
    return out


def _gain(sigma: float) -> float:
    """How much a Gaussian blur of ``sigma`` pixels scales white noise: the kernel's L2 norm."""
    if sigma <= 0:
        return 1.0
    import cv2

    k = cv2.getGaussianKernel(2 * int(np.ceil(3 * sigma)) + 1, sigma)[:, 0]
    return float(np.sum(k**2))  # separable: (sum k^2)^(1/2) per axis, squared over two axes
