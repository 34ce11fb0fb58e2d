"""Where a press differs from the undeformed dome: one classification for the auto ROI and anchoring.

Per pixel, the undeformed model (the capture of the undeformed dome, or the direct model on the
reference geometry plus the fitted indirect term) is fitted to the LED images with one scale per
channel (the albedo); what it leaves is the pixel's *misfit*. The misfit is compared in absolute
terms with what the image noise alone leaves (noise estimated from the images, Immerkaer, "Fast noise
variance estimation", CVIU 64(2), 1996), so the decision does not depend on how much of the view the
dent fills: a capture that is mostly dent has mostly large misfits, and none of them is called
undeformed.

This module makes the classification (:func:`classify_contact`, its :class:`ContactMap`); what it starts from and
what reads it live in files of their own:

- ``image_stats.py``: the LED images' statistics (each image's bright end, the lit LEDs, the noise);
- ``contact_grid.py``: the pixels or 2 x 2 blocks it works on, their smoothing and the noise that leaves;
- ``contact_verdict.py``: what the map says: the hit pixels, the misfit's floor and peak, no contact and why;
- ``contact_roi.py``: ``--roi auto``'s box around the contact, and the refusal of a press without one;
- ``contact_flank.py``: that box grown over a large contact's flank;
- ``anchoring.py``: the pixels anchored to the reference, and the box widened to hold enough of them;
- ``point_led_error.py``: the point-LED model's known misfit, which the verdicts and the box allow for.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import numpy as np

from ..core import tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.errors import CaptureError
from ..core.leds import Leds, led_shading
from . import reuse
from .contact_grid import ContactGrid, classify_block
from .image_stats import image_noise, led_levels, lit_leds
from .sensor_fit import gain_fitted_misfit, gel_samples


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
        """The misfit's median over the gel (NaN when no pixel sees it). Kept: :func:`.contact_verdict.contact_hits`
        reads it for the auto ROI, the dent's focus and the refit's exclusion (~3 ms each at 640x480)."""
        valid = np.isfinite(self.misfit)
        return float(np.median(self.misfit[valid])) if valid.any() else float("nan")

    @functools.cached_property
    def peak(self) -> float:
        """:func:`.contact_verdict.contact_peak`: the largest misfit over its floor on the gel (0 when no pixel sees
        it)."""
        valid = np.isfinite(self.misfit)
        if not valid.any():
            return 0.0
        floor = np.maximum(self.expected[valid], self.median_misfit)
        return float(np.max(self.misfit[valid] / np.maximum(floor, 1e-9)))


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
        pixel); None: :func:`.contact_grid.classify_block` of the frame. Its maps come back per pixel (each pixel gets
        its block's value); the blur is then ``blur_px`` / ``block`` blocks (:meth:`.contact_grid.ContactGrid.of`).

    Returns
    -------
    ContactMap
    """
    if press.reference is None:
        raise CaptureError(f"{press.folder}: --roi auto and anchoring need the capture's reference (undeformed dome)")
    leds = press.leds if leds is None else tuple(leds)
    valid = np.isfinite(press.reference.depth)
    grid = _grid_of(press, blur_px, block)
    side = cache if cache is not None and indirect is None else {}
    _fill_press_side(side, press, grid, indirect, dead_level)
    live, img, ok, count = side["live"], side["images"], side["ok"], side["count"]
    S = _undeformed_model(press, leds, live, grid, undeformed_images, undeformed_light)
    misfit = rms_misfit(S, img, ok, count)
    # the model and the images on a sample of the gel: does the model describe the sensor at all (asked once)?
    samples = gel_samples(S, img, grid.valid, ok)
    noise = side["noise"]
    expected, sample_noise = _noise_only_misfit(noise, count, grid, undeformed_noise)
    misfit = np.where(valid, grid.per_pixel(misfit), np.nan)
    level = grid.per_pixel(side["level"])
    return ContactMap(misfit, expected, tuple(live), side["dead"], noise, level, samples, sample_noise)


def _undeformed_model(
    press: Press,
    leds: Leds,
    live: Sequence[int],
    grid: ContactGrid,
    images: np.ndarray | reuse.Deferred | None,
    light: np.ndarray | Sequence[np.ndarray] | None,
) -> np.ndarray:
    """(n, h, w, 3) float32 -- the undeformed model on ``grid`` for the ``live`` LEDs: ``images`` smoothed, or the
    direct model on ``press.reference`` with ``leds`` where None, plus ``light`` unsmoothed where given
    (:func:`classify_contact`'s ``undeformed_images`` and ``undeformed_light``)."""
    if images is not None:
        S = _smoothed_undeformed(images, live, grid)
    else:
        ref = press.reference
        valid = np.isfinite(ref.depth)
        pts = depth_to_points(np.where(valid, ref.depth, 0.0), press.camera.rays)
        S = grid.smooth(grid.means(led_shading(pts, np.where(valid[..., None], ref.normals, 0.0), leds), live))
    if light is not None:
        # not smoothed: the fitted light is a gather over patches many pixels wide, bilinearly upsampled; the
        # blur changed it by < 5e-5 of its peak (640x480 one-bounce twin) and cost 0.06 s per classification
        S = S + grid.means(light, live)
    return S


def _noise_only_misfit(
    noise: float, count: np.ndarray, grid: ContactGrid, undeformed_noise: bool
) -> tuple[np.ndarray, float]:
    """(expected, sample_noise): the misfit that image noise ``noise`` alone leaves at each pixel ((H, W) float64),
    and its median over the gel (:attr:`ContactMap.sample_noise`), on ``grid`` with ``count`` (h, w) usable samples
    per block; sqrt(2) times more where the undeformed model is a capture with its own noise."""
    dof = np.clip((count - 3) / count, 0.0, 1.0)  # three albedo scales absorb part of the noise
    noise_blurred = noise * grid.gain * (np.sqrt(2.0) if undeformed_noise else 1.0)
    dof_median = float(np.median(dof[grid.valid])) if grid.valid.any() else 1.0
    expected = grid.per_pixel(np.full(grid.valid.shape, noise_blurred) * np.sqrt(dof))
    return expected, float(noise_blurred) * np.sqrt(dof_median)


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


def _grid_of(press: Press, blur_px: float, block: int | None) -> ContactGrid:
    """The :class:`.contact_grid.ContactGrid` that :func:`classify_contact` works on for ``press`` (its reference's gel
    pixels)."""
    valid = np.isfinite(press.reference.depth)
    return ContactGrid.of(valid, classify_block(valid.shape) if block is None else int(block), blur_px)


def _fill_press_side(
    side: dict, press: Press, grid: ContactGrid, indirect: np.ndarray | None, dead_level: float
) -> None:
    """:func:`_press_side` into ``side`` unless it holds it already for ``grid``'s block size."""
    if side.get("block") != grid.block:  # empty, or filled at another block size
        side.clear()
        side.update(_press_side(press, grid, indirect, dead_level))


def _press_side(press: Press, grid: ContactGrid, indirect: np.ndarray | None, dead_level: float) -> dict:
    """The press's half of :func:`classify_contact`: live LEDs, smoothed images (on ``grid``) and their level,
    noise (of the pixels), and the block size they were made at."""
    img, valid = press.linear_led_images, grid.pixels
    dead, live = _live_leds(press, valid, dead_level)
    # the press's own mask, made once per press; every LED live (the usual case): that mask, not a copy of it
    sat = press.saturated_led_images if len(live) == len(img) else press.saturated_led_images[live]
    # nothing saturated (the usual case): no mask to multiply by; else a block is usable where all its samples are
    ok = None if not sat.any() else (~sat if grid.block == 1 else grid.means(sat, range(len(live))) <= 0)
    img = _smoothed_images(img, live, grid, indirect)
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
        "level": np.sqrt(sum_squares(img, ok) / count),
    }


def _live_leds(press: Press, valid: np.ndarray, dead_level: float) -> tuple[tuple[int, ...], list[int]]:
    """(dead, live): the press's LEDs (0-based) whose image is dark (:func:`.image_stats.lit_leds` on the gel's
    ``valid`` pixels) and the rest; a :class:`CaptureError` that says why where too few are lit."""
    level = led_levels(press.linear_led_images, valid)
    dead = tuple(int(i) for i in np.flatnonzero(~lit_leds(level, dead_level)))
    live = [i for i in range(len(press.linear_led_images)) if i not in dead]
    if len(live) < tolerances.MIN_LEDS_PER_PIXEL:
        from .exposure import no_light_reason

        why = no_light_reason(press, valid, level >= dead_level)  # black or saturated throughout: say so
        raise CaptureError(
            f"{press.folder}: only {len(live)} LED images are lit (dead: {[i + 1 for i in dead]}); "
            f"nothing can be reconstructed{why}"
        )
    return dead, live


def _smoothed_images(
    img: np.ndarray, live: Sequence[int], grid: ContactGrid, indirect: np.ndarray | None
) -> np.ndarray:
    """(n, h, w, 3) float32 -- the ``live`` LEDs' images ``img`` (L, H, W, 3), less ``indirect`` where given, on
    ``grid`` and smoothed."""
    # Deformation changes the shading coherently over many pixels, noise does not: classify on
    # smoothed images (normalised convolution inside the gel) and scale the noise alike.
    if grid.block == 1:
        return grid.smooth((img if indirect is None else img - indirect)[live])
    img = grid.means(img, live)
    if indirect is not None:  # block means are linear: subtracted from them, not from the whole frames
        img -= grid.means(indirect, live)
    return grid.smooth(img)


def rms_misfit(S: np.ndarray, img: np.ndarray, ok: np.ndarray | None, count: np.ndarray) -> np.ndarray:
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


def sum_squares(stack: np.ndarray, ok: np.ndarray | None) -> np.ndarray:
    """(H, W) -- sum over LEDs and channels of ``stack`` squared where ``ok`` (None: everywhere)."""
    masked = stack if ok is None else stack * ok
    return np.einsum("lhwc,lhwc->hw", masked, masked)


def _smoothed_undeformed(images: np.ndarray | reuse.Deferred, live: Sequence[int], grid: ContactGrid) -> np.ndarray:
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
