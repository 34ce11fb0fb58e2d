"""The outer interreflection loop of a press's solve (:class:`OuterLoop`): the indirect light of the solved surface
(radiosity gather on its points, normals and filled albedo) subtracted and the press solved again, under-relaxed
per pixel (:func:`_relaxation`), on the mask's bounding box (:class:`BoxCompensation`), until the normals stop
changing."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..core import tolerances
from ..core.capture import Press
from ..core.metrics import angle_deg
from . import radiosity, reuse, threads
from .frame_box import FrameBox
from .indirect import IndirectModel, Surface, patch_size, reference_surface, scaled_into, surface_indirect
from .interreflection import compensate
from .nlips import SolveResult
from .roi import box_of, merge_focus

if TYPE_CHECKING:  # named in hints only
    from ..core.camera import Camera
    from ..core.leds import Leds


RELAXATION_MAX_RATIO = 3.0
"""Largest indirect/direct light ratio g that :func:`_relaxation` uses, so every pixel moves at least 1 / (1 + 3) of
the way to its gathered light per pass. Why a cap: g is 0.3-0.5 in a dent (benchmarks/RESULTS.md), where it does not
bind; it binds where the images hold (next to) no direct light -- a cast shadow, or a subtracted light that reaches
the images -- where g is a ratio of small, noisy numbers and an unbounded one would all but freeze the pixel's light
at its first (undeformed-surface) value. The value 3 itself has no recorded measurement (commit 32a19f9)."""


RELAXATION_DIRECT_FLOOR = 1e-3
"""Least direct light of a pixel in :func:`_relaxation`, as a fraction of its indirect light: where the subtracted
light reaches or exceeds the images, the direct light (images minus it) would be zero or negative and g infinite or
negative; with the floor g is 1 / this, above :data:`RELAXATION_MAX_RATIO`, so such a pixel gets the capped,
slowest relaxation."""


class OuterLoop:
    """NLiPs with the undeformed surface's indirect light subtracted, then passes with the indirect light of
    the solved surface, under-relaxed per pixel (:func:`_relaxation`), until the normals stop changing.

    When the solve's mask is much larger than the dent (a whole frame), the passes before the last solve only
    the ``focus`` (the dent's box, :func:`.roi.dent_focus`), where the light changes most from pass to pass, and
    keep the rest of the last result; the last pass solves the whole mask. On the default twin's 640x480
    one-bounce sphere and cube presses that takes 11-12 s of solver time instead of 19-21 s, at contact AAE
    0.497 / 0.412 deg against 0.492 / 0.414 with every pass on the whole frame (all pixels 0.51 against 0.73:
    fewer refined passes leave the frame's border better off; benchmarks/RESULTS.md). The light is updated
    on the mask's bounding box (outside it both the light and the gathered light are zero).

    The gathers before those focus passes compute the light at the focus only (what they solve), and the
    surface the last gather reads is the previous one with the focus's pixels replaced (all else is the same
    result); the light outside the focus then catches up at the last gather with one relaxed update per pass
    it missed (:meth:`_update`)."""

    def __init__(
        self,
        model: IndirectModel,
        press: Press,
        leds: Leds,
        images: np.ndarray,
        mask: np.ndarray,
        shading: reuse.Deferred | None,
        relaxation: float | str,
        focus: np.ndarray | None = None,
        radius: float = 0.0,
    ):
        self.model, self.press, self.leds, self.mask, self.relaxation = model, press, leds, mask, relaxation
        self.focus = focus
        self.radius = radius
        """mm -- the LEDs' emitting disk radius (``leds`` their centres and axes: the solve's disks); 0: point LEDs.
        The reference and solved surfaces are shaded with it (:func:`.indirect.term_shading`)."""
        """(H, W) bool or None -- what the passes before the last solve (None: the mask)."""
        x0, y0, w, h = box_of(mask)
        self.box = (slice(y0, y0 + h), slice(x0, x0 + w))
        """The mask's bounding box (rows, columns): the lights of the passes are held on it alone."""
        # the images' per-pixel total, for the relaxation: the same in every pass
        self.image_total = led_channel_sum(images[:, self.box[0], self.box[1]])
        self.shading = shading
        self.passes, self.changes, self.solver_seconds, self.seconds = 0, [], [], 0.0

    def run(self, solve_with: Callable[..., SolveResult], max_passes: int) -> SolveResult:
        """``solve_with(light, init=None, unrefined=0, receivers=None)`` -> SolveResult, called once per
        pass (``light``: (L, h, w, 3) on ``self.box``; ``receivers``: the pixels to solve, None for the mask);
        returns the last result. Every pass but
        the last leaves the finest levels unrefined (:func:`_unrefined_levels`: its light is a gather over
        patches several pixels wide, which finer detail does not change); the last solves the finest level of
        the whole mask from the depth before it, so the result is refined everywhere."""
        t0 = time.perf_counter()
        press, ref = self.press, self.press.reference
        light = _first_light(self.model, self.mask, self.box)
        self.seconds += time.perf_counter() - t0
        rough = _unrefined_levels(press.camera)
        result = solve_with(light, unrefined=0 if max_passes == 0 else rough)
        self.solver_seconds.append(result.report["seconds"])
        t0 = time.perf_counter()
        ref_surface = reference_surface(
            press.camera, self.leds, ref.depth, ref.normals, shading=self.shading, radius=self.radius
        )
        self.seconds += time.perf_counter() - t0
        settled = False
        before = None  # (surface, focus, reconstructed) of the last gather, when a focus pass followed it
        missed = 0  # focus passes whose gather left the light outside the focus as it was
        for k in range(max_passes):
            last = settled or k == max_passes - 1
            region = None if last else self.focus
            t0 = time.perf_counter()
            surface = _solved_surface(ref_surface, result, before)
            where = self.mask if region is None else region
            window = self.box if region is None else _slices(box_of(region))
            gathered = _solved_surface_light(self.model, press, self.leds, result, where, surface, window)
            light = self._update(light, gathered, window, region, 0 if region is not None else missed)
            del gathered  # in the light now: not held through the solve (44 MB at 640x480 with 12 LEDs)
            if region is None:  # only a focus pass's surface is recomputed after it: not held through the solve
                surface = None  # (~9 MB of whole-frame maps at 640x480)
            missed = missed + 1 if region is not None else 0
            self.seconds += time.perf_counter() - t0
            # a small change of the light: start from the last depth; refined (and on the whole mask) at the last
            new = solve_with(light, init=result.depth, unrefined=0 if last else rough, receivers=region)
            if region is not None:
                new = merge_focus(result, new, region)
            self.passes += 1
            change = _median_change_deg(result, new, where)
            self.changes.append(round(change, 4))
            self.solver_seconds.append(new.report["seconds"])
            before = (surface, region, result.reconstructed) if region is not None else None
            result = new
            if last:
                break
            settled = change < tolerances.OUTER_TOL_DEG  # then one refined pass over the whole mask ends the loop
        return result

    def _update(
        self,
        light: np.ndarray,
        gathered: np.ndarray,
        window: tuple[slice, slice],
        focus: np.ndarray | None,
        missed: int,
    ) -> np.ndarray:
        """The next pass's light ``L + w (gathered - L)``, clipped at 0, written into ``light`` (on the mask's
        bounding box) and returned.

        ``gathered`` : (L, h, w, 3) on ``window`` (rows, columns of the frame, inside the box); ``focus`` : (H, W)
        bool, the pixels gathered when not the whole mask (None); ``missed`` : focus passes since the light
        outside the focus was last updated: it takes that many more updates with this ``gathered``, standing in
        for the gathers it missed (the surface changed only in the focus since; against the light left as it
        was, contact AAE moved 0.005 deg on the twin's sphere press, with them 0.0016; benchmarks/RESULTS.md).

        Per pixel, so by blocks of rows on the thread pool (:data:`UPDATE_ROWS` each, the same bits as the whole
        window at once): on a 640x480 whole frame's last pass, one relaxed update and one catching up, each
        several passes over (L, H, W, 3) float32 arrays of 44 MB, took ~0.25 s of CPU on one core, and their
        temporaries as many fresh pages."""
        rows, cols = _within(window, self.box)
        part, total = light[:, rows, cols], self.image_total[rows, cols]
        # the pixels updated (None: all of the window's); a focus pass's window is the focus's box, whose other
        # pixels were not gathered. Per channel, (1, h, w, 3): a copy masked by a (1, h, w, 1) array broadcast over
        # the channels took 1.0 ms per 16-row band of a 640x480 frame, with the channels spelt out 0.27 ms
        updated = None if focus is None else _per_channel(focus[window])
        # catching up happens on the last pass, whose window is the whole box
        outside = _per_channel(~self.focus[self.box]) if missed else None

        def block(r: slice) -> None:
            here, gathered_here, total_here = part[:, r], gathered[:, r], total[r]
            if updated is None:  # every pixel: written in place, no masked copy
                self._relaxed(here, gathered_here, total_here, out=here)
            else:
                np.copyto(here, self._relaxed(here, gathered_here, total_here), where=updated[:, r])
            for _ in range(missed):
                np.copyto(here, self._relaxed(here, gathered_here, total_here), where=outside[:, r])

        threads.map_items(block, threads.chunks(part.shape[1], -(-part.shape[1] // UPDATE_ROWS)))
        return light

    def _relaxed(
        self, light: np.ndarray, gathered: np.ndarray, total: np.ndarray, out: np.ndarray | None = None
    ) -> np.ndarray:
        """``max(L + w (gathered - L), 0)``, a new array or ``out`` (which may be ``light``: it is read before it is
        written); ``total``: the images' per-pixel total there."""
        omega = _relaxation(total, light) if self.relaxation == "auto" else float(self.relaxation)
        # in one buffer (the same bits as the expression): at 640x480 each temporary is 44 MB of fresh pages
        step = gathered - light
        step *= omega
        step += light
        return np.maximum(step, 0.0, out=step if out is None else out)


UPDATE_ROWS = 16
"""Rows of the outer loop's light per task of its relaxed update (:meth:`OuterLoop._update`): at 640 columns and 12
LEDs a block's temporaries take 1.5 MB and stay in the cache."""


def _first_light(model: IndirectModel, mask: np.ndarray, box: tuple[slice, slice]) -> np.ndarray:
    """The outer loop's first light: the undeformed dome's indirect light as its fit left it (``model.fitted_light``,
    per unit receiver albedo, times the fit's typical albedo ``off_view_albedo``), on ``box``.

    ``mask`` : (H, W) bool, the solve's pixels; ``box`` : (rows, columns) slices of the frame, the mask's bounding
    box. Returns (L, h, w, 3) float32 on ``box``, 0 off the mask.

    Why not a gather: the fit has just gathered this light (on its coarser patches), and the loop's first pass only
    seeds the relaxed passes that follow. Gathering it again on the loop's patches with a uniform albedo took
    0.07-0.15 s of CPU in a warm 640x480 auto-ROI solve; the fitted light moved the default twin's one-bounce sphere
    and cube presses' contact AAE by <= 0.0003 deg with an auto ROI, <= 0.0014 deg on the whole frame
    (benchmarks/RESULTS.md).

    One LED per task on the thread pool (:func:`.indirect.scaled_into`, the same bits as all LEDs at once): on a
    640x480 whole frame the upsampling, the albedo's product and the zeroing off the mask, each over an (L, H, W, 3)
    float32 array of 44 MB, took ~0.13 s of one core while the other waited."""
    light, size = model.fitted_light
    H, W = mask.shape
    # bilinear upsampling of the patches around the box only: one patch of margin holds every box pixel's
    # neighbours, so the numbers are those of the whole frame's upsampling cut to the box
    pr = slice(max(box[0].start // size - 1, 0), min((box[0].stop - 1) // size + 2, light.shape[1]))
    pc = slice(max(box[1].start // size - 1, 0), min((box[1].stop - 1) // size + 2, light.shape[2]))
    r0, c0 = pr.start * size, pc.start * size
    shape = (min(pr.stop * size, H) - r0, min(pc.stop * size, W) - c0)
    rows, cols = slice(box[0].start - r0, box[0].stop - r0), slice(box[1].start - c0, box[1].stop - c0)
    out = np.empty((len(light), box[0].stop - box[0].start, box[1].stop - box[1].start, 3), np.float32)
    albedo = np.asarray(model.off_view_albedo, np.float32)
    scaled_into(out, radiosity.Upsampled(light[:, pr, pc], shape, size), (rows, cols), albedo, ~mask[box])
    return out


def _unrefined_levels(camera: Camera) -> int:
    """How many of the finest pyramid levels the outer loop's passes before the last leave unrefined: the finest
    iterated level keeps two pixels along an indirect-light patch's side (the gather reads the patch's mean), and
    it is at least the next-to-finest. 640x480: 8 px patches, 2 levels (the solve iterates up to 160x120); 320x240
    and smaller: 1. On the default twin's one-bounce 640x480 presses the contact AAE moved by <= 0.001 deg against
    1 level (auto ROI and whole frame, sphere and cube) and each of those passes took about a third less
    (benchmarks/RESULTS.md)."""
    return max(1, int(np.log2(patch_size(camera) / 2)))


class BoxCompensation:
    """The images minus an indirect light given on the mask's bounding box (the outer loop's, zero outside it):
    ``compensate`` on that box only, written into one box-sized buffer kept across the passes, and handed to the
    solve as a :class:`.frame_box.FrameBox` (the images themselves outside the box). The same values as
    ``compensate(images, light)`` for the whole-frame light, without a whole-frame pass per solve (an auto ROI's
    box is a sixth of a 640x480 frame) or a whole-frame copy of the images (44 MB at 640x480 with 12 LEDs).

    One LED per pool task (the same bits): on a 640x480 whole frame each call's subtraction and clipping over the
    whole box, 44 MB arrays with 12 LEDs, ran in the main thread."""

    def __init__(self, images: np.ndarray, mask: np.ndarray):
        self.images, self.mask, self.buffer, self.box = images, mask, None, None

    def __call__(self, light: np.ndarray, receivers: np.ndarray | None = None) -> FrameBox:
        """``light``: (L, h, w, 3) on the mask's bounding box; ``receivers``: (H, W) bool, the pixels the solve
        reads when not the whole mask (a focus pass): only their box is compensated (the solve crops to it),
        the rest of the buffer is left as the last call wrote it."""
        first = self.buffer is None  # on the first pass: a solve without the outer loop needs neither
        if first:
            x0, y0, w, h = box_of(self.mask)
            self.box = (slice(y0, y0 + h), slice(x0, x0 + w))
            self.buffer = np.empty((len(self.images), h, w, self.images.shape[-1]), np.float32)
        window = self.box if receivers is None else _slices(box_of(receivers))
        rows, cols = _within(window, self.box)
        fill = first and window != self.box  # the box's pixels that this call leaves: the images themselves

        def one_led(i: int) -> None:
            if fill:
                self.buffer[i] = self.images[i, self.box[0], self.box[1]]
            compensate(
                self.images[i : i + 1, window[0], window[1]],
                light[i : i + 1, rows, cols],
                out=self.buffer[i : i + 1, rows, cols],
            )

        threads.map_items(one_led, range(len(self.buffer)))
        return FrameBox(self.images, self.buffer, self.box)


def _slices(box: list[int]) -> tuple[slice, slice]:
    """(rows, columns) of the box [x0, y0, w, h]."""
    x0, y0, w, h = box
    return slice(y0, y0 + h), slice(x0, x0 + w)


def _within(window: tuple[slice, slice], box: tuple[slice, slice]) -> tuple[slice, slice]:
    """(rows, columns) of ``window`` in an array held on ``box`` (both frame slices, the window inside the box)."""
    return tuple(slice(w.start - b.start, w.stop - b.start) for w, b in zip(window, box))


def _solved_surface(
    ref_surface: Surface, result: SolveResult, before: tuple[Surface, np.ndarray, np.ndarray] | None = None
) -> Surface:
    """The solved surface as patches: ``result``'s depth and normals where reconstructed, the reference
    (``ref_surface``) elsewhere.

    ``before`` : (surface, focus, reconstructed) -- the surface of the result that ``result`` merged a focus
    pass into, that pass's pixels ((H, W) bool) and what that result reconstructed; the surface is then the
    former one recomputed around the focus only (the same numbers). None, or a focus pixel reconstructed
    before but not now (it goes back to the reference): made from the reference."""
    rec = result.reconstructed
    if before is not None:
        surface, focus, was = before
        if not (focus & was & ~rec).any():
            # replaced() reads the solved depth and normals at the changed pixels only, in their box
            return surface.replaced(result.depth, result.normals, focus & rec)
    return ref_surface.replaced(result.depth, result.normals, rec)


def _solved_surface_light(
    model: IndirectModel,
    press: Press,
    leds: Leds,
    result: SolveResult,
    mask: np.ndarray,
    solved: Surface,
    window: tuple[slice, slice],
) -> np.ndarray:
    """Indirect light of the solved surface (``solved``, from :func:`_solved_surface`) at the ``mask``'s pixels,
    (L, h, w, 3) on ``window`` (rows, columns; it holds the mask)."""
    albedo = _filled_albedo(result, np.asarray(model.off_view_albedo))
    return surface_indirect(
        model, press.camera, leds, solved.depth, solved.normals, albedo, mask, surface=solved, window=window
    )


def _filled_albedo(result: SolveResult, fallback: np.ndarray) -> np.ndarray:
    """(H, W, 3) -- ``result``'s albedo where reconstructed, else its median there per channel (``fallback`` (3,)
    when nothing is): the outer loop's gathers read the albedo of the whole visible surface.

    On the thread pool, the same bits as ``np.where(rec[..., None], albedo, np.median(albedo[rec], axis=0))``: the
    three channels' medians one per task (a median is the middle values, whatever order they are read in), the
    filling by bands of rows. Why: both ran on the main thread before every outer gather while the other core
    waited, 8 ms on a cube press's auto ROI, ~18 ms on a 640x480 frame."""
    rec, values = result.reconstructed, result.albedo
    if rec.any():
        # each a NumPy scalar of the albedo's type, as np.median(axis=0) gives
        typical = np.array(threads.map_items(lambda c: np.median(values[..., c][rec]), range(values.shape[-1])))
    else:
        typical = fallback
    filled = np.empty(values.shape, np.result_type(values, typical))

    def band(rows: slice) -> None:
        filled[rows] = np.where(rec[rows][..., None], values[rows], typical)

    threads.map_items(band, threads.chunks(len(values), -(-len(values) // FILL_ROWS)))
    return filled


FILL_ROWS = 64
"""Rows per pool task of :func:`_filled_albedo`."""


def _relaxation(image_total: np.ndarray, light: np.ndarray) -> np.ndarray:
    """(1, h, w, 3) float32 -- per-pixel relaxation 1 / (1 + g) of the outer loop, g = indirect / direct light (the
    same in the three channels: spelt out, a product with the (L, h, w, 3) light runs along whole rows instead of
    three elements at a time, 0.26-0.41 -> 0.05 ms per 16-row band of a 640x480 frame, the same bits).

    ``image_total`` : (h, w) the images summed over LEDs and channels; ``light`` : (L, h, w, 3) the
    indirect light now subtracted.

    Why: the indirect light is proportional to the solved albedo, and the albedo is solved from the
    images minus that light, so an error dL of the light comes back as about -g dL: the plain iteration
    alternates around the answer with rate g (measured 0.49 per pass on a 640x480 sphere press: 3.4, 1.7,
    0.8 deg). The update L + (gathered - L) / (1 + g) cancels that first-order feedback (the same press:
    2.27, 0.16, 0.02 deg). Not the feedback through the solved geometry: on the default twin's 640x480 cube
    press the loop still alternates, each step of the light about -0.5 times the one before, over the whole box
    and not only the dent's slopes. With the gathers' geometry held fixed it converges without alternating; with
    their albedo held fixed it alternates only weakly (benchmarks/RESULTS.md, s16-f)."""
    indirect = led_channel_sum(light)
    direct = np.maximum(image_total - indirect, RELAXATION_DIRECT_FLOOR * np.maximum(indirect, 1e-30))
    g = np.clip(indirect / direct, 0.0, RELAXATION_MAX_RATIO)
    return _per_channel((1.0 / (1.0 + g)).astype(np.float32))


def _per_channel(values: np.ndarray) -> np.ndarray:
    """(1, h, w, 3) -- per-pixel ``values`` (h, w) repeated in the three channels, for an operation with an (L, h,
    w, 3) stack (NumPy broadcasts a length-1 channel axis three elements per inner loop)."""
    return np.repeat(values[None, ..., None], 3, axis=3)


def led_channel_sum(stack: np.ndarray) -> np.ndarray:
    """(h, w) -- ``stack.sum(axis=(0, 3))`` of an (L, h, w, 3) stack (contiguous or a view), the same bits: each
    pixel's three channels added in order, then the LEDs in order, as NumPy's reduction adds them.

    Why: NumPy reduces a length-3 last axis three elements per inner loop: 1.4 ms for a 16-row band of a 640x480
    light with 12 LEDs (float32), 0.13 ms as 2 L whole-band additions. The outer loop's relaxation sums its light
    per band in every update (:func:`_relaxation`): ~85 ms of CPU in a whole frame's last pass."""
    total = np.zeros(stack.shape[1:3], stack.dtype)  # NumPy starts at +0: a sum of -0.0 is +0.0
    for led in stack:
        part = led[..., 0] + led[..., 1]
        part += led[..., 2]
        total += part
    return total


def _median_change_deg(a: SolveResult, b: SolveResult, where: np.ndarray) -> float:
    """Median angle (deg) between the normals of ``a`` and ``b`` on the pixels of ``where`` both reconstruct."""
    both = a.reconstructed & b.reconstructed & where
    if not both.any():
        return 0.0
    return float(np.median(angle_deg(a.normals[both], b.normals[both])))
