"""Solving a capture (Press): prior from the undeformed reference, ROI, anchoring, interreflection, LEDs.

The order of work in :func:`solve_press`:

1. the indirect term of the image model is fitted (:func:`nlipscalib.solver.indirect.fit_indirect`) on
   the capture of the undeformed dome when one is given, else on the press itself outside its contact
   (``interreflection="auto"`` applies it only when the data show indirect light);
2. the contact classification (:mod:`nlipscalib.solver.contact`) compares the press to the
   undeformed model *with* that term and with the LEDs the solve uses (calibrated ones when given):
   it gives the auto ROI and the anchored pixels. Its press side (smoothed images, noise) is computed
   once; when the press itself stands in for the undeformed capture, a first, rough fit only finds the
   contact, the term is fitted again without it and the model side of the classification redone;
3. NLiPs on the images minus the indirect light of the undeformed surface, then an outer loop: the
   indirect light of the *solved* surface (its points, normals and albedo; radiosity gather,
   :mod:`nlipscalib.solver.radiosity`) is subtracted and the press solved again, until the normals stop
   changing. The loop is under-relaxed per pixel (:func:`_relaxation`): the plain iteration alternates
   around its answer because the light it subtracts feeds back through the solved albedo.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import diskcache, tolerances
from ..core.capture import Press
from ..core.errors import CaptureError, ShapeError
from ..core.metrics import angle_deg
from ..progress import PRESS_DETAIL
from . import radiosity, reuse, threads
from .contact import ContactMap, anchor_weights, classify_contact, contact_box, led_levels, prepare_press_side
from .exposure import nothing_to_fit, saturated_share, saturation_note
from .indirect import (
    IndirectModel,
    Surface,
    design_of,
    fit_indirect,
    patch_size,
    reference_shading,
    reference_surface,
    scaled_into,
    surface_indirect,
)
from .interreflection import compensate
from .nlips import SolveResult, solve
from .options import SolverOptions
from .press_checks import check_modes, check_roi, check_undeformed
from .roi import box_mask, box_of, contact_pixels, dent_focus, merge_focus

if TYPE_CHECKING:  # named in hints only
    from ..core.camera import Camera
    from ..core.leds import Leds

log = logging.getLogger(__name__)

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


def solve_press(press: Press, **kwargs: Any) -> SolveResult:
    """Solve one press; see :func:`_solve_press` for the parameters (the same keywords).

    A guard against a failure seen on small, noisy captures: when the noise-adapted smoothness
    (``SolverOptions.noise_smoothness``) was applied and the solved surface left the physically possible
    range (median distance to the undeformed surface above ``tolerances.MAX_MEDIAN_DISPLACEMENT_MM``: the
    gel cannot move that far), the press is solved again without it and the report says so. Seen on a
    96x72 and a 160x120 twin capture with a tight box around a sphere press: depth 13 mm off, AAE 18 deg;
    without the raised smoothness 0.05 mm and 7.7 deg.
    """
    result = _solve_press(press, **kwargs)
    drift = _median_displacement(result, press)
    options = kwargs.get("options") or SolverOptions()
    raised = result.report.get("smoothness", 0.0) > options.smoothness
    if raised and drift > tolerances.MAX_MEDIAN_DISPLACEMENT_MM:
        log.warning(
            "%s: the solve drifted %.1f mm from the undeformed surface with the noise-adapted smoothness %.3g; "
            "solving again without it",
            press.folder,
            drift,
            result.report["smoothness"],
        )
        kwargs["options"] = dataclasses.replace(options, noise_smoothness=0.0)
        result = _solve_press(press, **kwargs)
        result.report["smoothness_fallback"] = (
            f"noise-adapted smoothness dropped: the first solve drifted {drift:.1f} mm"
        )
    _report_saturation(result, press)
    return result


def _report_saturation(result: SolveResult, press: Press) -> None:
    """The share of the gel's samples left out as saturated in the report (``saturated_share``), and a warning,
    logged and in the report's ``warnings``, when it reaches ``tolerances.SATURATED_SHARE_WARN``."""
    share = saturated_share(press)
    result.report["saturated_share"] = round(share, 4)
    note = saturation_note(press, share, "the solve")
    if note is not None:
        result.report["warnings"] = [*result.report.get("warnings", []), note]
        log.warning("%s", note)


def _median_displacement(result: SolveResult, press: Press) -> float:
    """Median |solved depth - undeformed depth| over the reconstructed pixels, mm (0 without a reference)."""
    if press.reference is None or not result.reconstructed.any():
        return 0.0
    diff = result.depth[result.reconstructed] - press.reference.depth[result.reconstructed]
    diff = diff[np.isfinite(diff)]
    return float(np.median(np.abs(diff))) if diff.size else 0.0


def _solve_press(
    press: Press,
    *,
    roi: tuple[int, int, int, int] | str | None = None,
    leds: Leds | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    progress: bool = False,
    indirect: np.ndarray | Press | None = None,
    dent_interreflection: bool = True,
    coating_albedo: float | tuple[float, float, float] | None = None,
    interreflection: str = "auto",
    bounces: int = 1,
    max_outer: int = 2,
    outer_relaxation: float | str = "auto",
) -> SolveResult:
    """Solve one press.

    Parameters
    ----------
    press : Press -- load with ``load_press(folder, led_subset=...)`` for an LED ablation.
    roi : (x0, y0, w, h) pixels, "auto", or None for the whole visible gel.
    leds : sequence of Led replacing ``press.leds`` (e.g. from ``calibrate-leds``); same count. Used
        everywhere: the solve, the indirect term, the contact classification (auto ROI, anchoring).
    options, backend, progress : see :func:`nlipscalib.solver.solve`.
    indirect : a Press of the undeformed dome (same camera, LEDs, LED subset and exposure) to fit the
        indirect term on; None: fit it on the press itself, away from the contact; an (L, H, W, 3)
        float array: light to subtract as is (linear units), no model.
    dent_interreflection : run the outer loop (indirect light of the solved surface, solve again);
        False: only the undeformed surface's indirect light is subtracted.
    coating_albedo : the coating's reflectance (0-1], one value or per channel, overriding the
        fitted one (None: fitted from the data).
    interreflection : "auto" (apply the term when the data show indirect light), "on", "off".
    bounces : diffuse bounces in the indirect term (1 or 2).
    max_outer : most outer passes (solves after the first). Two are not the loop's fixed point on the default
        twin's 640x480 sphere and cube presses: a third moves their contact AAE by 0.02-0.08 deg. The cause is
        not the levels the passes before the last leave unrefined (with every pass refined the AAE follows the
        same sequence within 0.004 deg): on the cube the relaxed loop alternates (:func:`_relaxation`), and two
        passes stop on its good side, 0.03-0.05 deg better than the fixed point (benchmarks/RESULTS.md, s16-f).
    outer_relaxation : "auto" (per pixel 1 / (1 + indirect / direct light), see :func:`_relaxation`) or a
        number: the light of each outer pass is ``L + w (gathered - L)``; 1.0 is the plain iteration.

    Returns
    -------
    SolveResult -- ``report`` adds roi, roi_note (what ``--roi auto`` left out or a warning; empty when none),
    prior, interreflection (the fitted model and the decision),
    indirect_compensation, dent_interreflection, outer_passes, outer_changes_deg (median normal change of
    each outer pass; all but the last pass are unrefined), outer_focus (the box [x0, y0, w, h] the passes
    before the last solved, or None), pass_seconds (the solver's timer of each NLiPs solve; ``seconds`` is
    their sum), anchoring (what was decided and why), anchored_pixels, dead_leds_contact, contact_seconds,
    indirect_seconds.
    """
    check_modes(interreflection, bounces, outer_relaxation, coating_albedo)
    leds = press.leds if leds is None else tuple(leds)
    if len(leds) != len(press.leds):
        raise CaptureError(f"{press.folder}: {len(leds)} LEDs given for {len(press.leds)} LED images")
    options = options or SolverOptions()
    ref_capture, fixed_light = _split_indirect(press, indirect)
    H, W = press.camera.shape
    prior = press.reference.depth if press.reference is not None else None
    mask = np.isfinite(prior) if prior is not None else np.ones((H, W), bool)
    if prior is not None and not mask.any():
        raise CaptureError(f"{press.folder}: the reference surface covers no pixel; nothing to reconstruct")
    explicit_roi = None if roi is None or isinstance(roi, str) else check_roi(roi, W, H)
    if isinstance(roi, str) and roi != "auto":
        raise ShapeError(f"roi must be (x0, y0, w, h) or 'auto', got {roi!r}")

    sources = _Sources(press, leds, ref_capture, fixed_light, explicit_roi, interreflection, bounces)
    light = _light_and_contact(sources, options.dead_led_level)
    model, cmap = light.model, light.cmap
    if model is not None and model.enabled and coating_albedo is not None:
        model = model.with_reflectance(coating_albedo)
    elif coating_albedo is not None:  # nothing for it to scale: say so rather than drop the user's value
        why = model.reason if model is not None else "no interreflection term (a fixed light or no reference surface)"
        log.warning("%s: --coating-albedo not used: %s", press.folder, why)
    t0 = time.perf_counter()
    roi, roi_note = _region(press, roi, explicit_roi, cmap)
    if roi is not None:
        mask &= box_mask(roi, (H, W))
    weights, anchoring = (None, "anchoring off (no reference surface)")
    if cmap is not None:
        weights, anchoring = anchor_weights(cmap, mask, options.anchor_weight, tolerances.ANCHOR_NOISE_FACTOR)
    options, noise = _noise_regularised(options, press, cmap)
    t_contact = light.contact_seconds + time.perf_counter() - t0

    images = press.linear_led_images
    run = _Runner(press, leds, images, prior, weights, mask, options, backend, progress, fixed_light)
    if model is not None and model.enabled:
        focus = dent_focus(cmap, mask) if cmap is not None and dent_interreflection else None
        loop = _OuterLoop(model, press, leds, images, mask, light.shading, outer_relaxation, focus)
        result = loop.run(run, max_outer if dent_interreflection else 0)
    else:
        loop, result = None, run(fixed_light)
    rep = result.report
    rep["roi"] = list(roi) if roi is not None else None
    rep["roi_note"] = roi_note
    rep["prior"] = "reference" if prior is not None else "nominal_distance"
    rep["interreflection"] = model.to_json() if model is not None else None
    rep["indirect_compensation"] = bool(fixed_light is not None or (model is not None and model.enabled))
    _report_loop(rep, loop)
    rep["anchoring"] = anchoring
    rep["anchored_pixels"] = int((weights > 1).sum()) if weights is not None else 0
    rep["dead_leds_contact"] = list(cmap.dead_leds) if cmap is not None else []
    rep["contact_seconds"] = t_contact
    rep["image_noise"] = noise
    rep["smoothness"] = options.smoothness
    rep["indirect_seconds"] = light.indirect_seconds + (loop.seconds if loop is not None else 0.0)
    if model is not None:
        log.info("%s: %s", press.folder, model.reason, extra=PRESS_DETAIL)
    log.info("%s: %s", press.folder, anchoring, extra=PRESS_DETAIL)
    return result


@dataclasses.dataclass
class _Light:
    """What a solve knows before NLiPs runs: the indirect term, the contact classification, the reference
    surface's direct shading, and the seconds each took."""

    model: object
    """IndirectModel or None (a fixed light, or no reference surface)."""
    cmap: ContactMap | None
    """The contact classification (None without a reference surface)."""
    shading: reuse.Deferred | None
    """The reference surface's direct shading (:func:`reference_shading`, deferred), or None."""
    indirect_seconds: float
    """The term's fits."""
    contact_seconds: float
    """The contact classifications."""


@dataclasses.dataclass(frozen=True, eq=False)
class _Sources:
    """What the indirect term's fit and the contact classification read of a solve's arguments (the same for
    both: :func:`_light_and_contact`, :func:`_indirect_fitter`)."""

    press: Press
    leds: Leds
    """The LEDs the solve uses (``solve_press``'s ``leds`` or the press's)."""
    ref_capture: Press | None
    """The undeformed dome's capture to fit the term on, or None (the press itself, away from its contact)."""
    fixed_light: np.ndarray | None
    """(L, H, W, 3) float32 -- a light to subtract as is (no term fitted), or None."""
    explicit_roi: tuple[int, int, int, int] | None
    """(x0, y0, w, h) pixels of an explicit ROI (the press's own fit leaves it out), or None."""
    interreflection: str
    """The term's mode: "auto", "on" or "off"."""
    bounces: int
    """Diffuse bounces in the term (1 or 2)."""


def _light_and_contact(sources: _Sources, dead_level: float) -> _Light:
    """Fit the indirect term, then classify the contact against the undeformed model with it (when the press
    stands in for the undeformed capture: a rough fit finds the contact, the term is fitted again without it
    and the classification redone). ``dead_level``: ``SolverOptions.dead_led_level``, the classification's too."""
    press, leds, ref_capture, fixed_light = sources.press, sources.leds, sources.ref_capture, sources.fixed_light
    prior = press.reference.depth if press.reference is not None else None
    t0 = time.perf_counter()
    # the reference surface's direct shading, computed once: the fit, the contact and the outer loop share it
    # (and the next press of the same sensor: solver.reuse). Deferred: when they all find their own results
    # kept (a warm process), it is only named in their keys, and the 88 MB (640x480) array is never loaded
    shading = None
    if prior is not None:
        shading = reference_shading(press.camera, leds, prior, press.reference.normals, defer=True)
    fit = _indirect_fitter(sources, shading)
    cache = fit.contact_cache if fit else {}
    with ThreadPoolExecutor(1, "contact-press-side") as pool:  # left (joined) before anything else, on an error too
        side = None
        if fit is not None:  # a term to fit, so a reference surface to classify against
            # the press's side of the contact classification (its images' block means, blur and noise; ~0.08 s of
            # CPU at 640x480) does not depend on the term: made on the second core while the term is fitted
            # made once here, not by both threads (the fit's inputs and the contact's press side each ask for the
            # LED levels on the gel; reuse.reused keeps them, but two threads asking at once both computed them)
            led_levels(press.linear_led_images, np.isfinite(prior))
            side = pool.submit(prepare_press_side, press, cache, dead_level=dead_level)
        model = fit.first() if fit is not None else None
        if side is not None:
            side.result()  # its error (no LED lit) is raised here
    t_indirect = time.perf_counter() - t0  # the fit, and the press's side of the classification beside it

    t0 = time.perf_counter()
    cmap, refit = None, 0.0
    if press.reference is not None:
        cmap = _contact(press, leds, ref_capture, fixed_light, model, shading, dead_level, cache)
        if fit is not None and fit.refits and model.enabled:
            # the press stands in for the undeformed capture: fit again without its contact
            t1 = time.perf_counter()
            model = fit.again(exclude=contact_pixels(cmap))
            refit = time.perf_counter() - t1
            cmap = _contact(press, leds, None, None, model, shading, dead_level, fit.contact_cache)
    t_contact = time.perf_counter() - t0 - refit
    return _Light(model, cmap, shading, t_indirect + refit, t_contact)


def _region(
    press: Press,
    roi: tuple[int, int, int, int] | str | None,
    explicit_roi: tuple[int, int, int, int] | None,
    cmap: ContactMap | None,
):
    """The box to solve, (x0, y0, w, h) or None for the whole gel, and what ``--roi auto`` left out or warns
    about ("" when nothing)."""
    if roi != "auto":
        return explicit_roi, ""
    if cmap is None:
        raise CaptureError(f"{press.folder}: --roi auto needs the capture's reference (undeformed dome)")
    box, note = contact_box(cmap, press.camera.shape, folder=press.folder)
    if note:
        log.warning("%s: %s", press.folder, note)
    return box, note


class _Runner:
    """One NLiPs solve of the press's images, minus an indirect light (none, a fixed light, or the outer
    loop's on the mask's bounding box): ``runner(light, init=None, unrefined=0, receivers=None)``."""

    def __init__(
        self,
        press: Press,
        leds: Leds,
        images: np.ndarray,
        prior: np.ndarray | None,
        weights: np.ndarray | None,
        mask: np.ndarray,
        options: SolverOptions,
        backend: str,
        progress: bool,
        fixed_light: np.ndarray | None,
    ):
        self.press, self.leds, self.images, self.prior, self.weights = press, leds, images, prior, weights
        self.mask, self.options, self.backend, self.progress = mask, options, backend, progress
        self.fixed_light = fixed_light
        self.saturated = press.saturated_led_images | press.saturated(press.dark)[None]
        self.boxed = _BoxCompensation(images, mask)

    def compensated(self, light: np.ndarray | None, receivers: np.ndarray | None = None):
        if light is None:
            return self.images
        # a fixed light may be anything; the outer loop's is zero outside the mask's box
        return compensate(self.images, light) if light is self.fixed_light else self.boxed(light, receivers)

    def __call__(
        self,
        light: np.ndarray | None,
        init: np.ndarray | None = None,
        unrefined: int = 0,
        receivers: np.ndarray | None = None,
    ) -> SolveResult:
        result = solve(
            self.compensated(light, receivers),
            self.press.camera,
            self.leds,
            prior_depth=self.prior,
            prior_weights=self.weights,
            mask=self.mask if receivers is None else receivers,
            saturated=self.saturated,
            options=self.options,
            backend=self.backend,
            progress=self.progress,
            init_depth=init,
            unrefined=unrefined,
            where=self.press.folder,
        )
        if receivers is None and not result.reconstructed.any():  # a focus pass is merged into the last result
            dead = [i + 1 for i in result.report["dead_leds"]]
            raise CaptureError(
                f"{self.press.folder}: no pixel could be reconstructed ({result.report['pixels_too_few_leds']} "
                f"pixels with fewer than {self.options.min_leds} usable LEDs; dead LEDs {dead})"
                + nothing_to_fit(self.press)  # black or saturated throughout: say so
            )
        return result


def _report_loop(rep: dict, loop: _OuterLoop | None) -> None:
    """The outer interreflection loop's entries of a solve's report (``loop``: an :class:`_OuterLoop` or None)."""
    rep["dent_interreflection"] = bool(loop is not None and loop.passes > 0)
    rep["outer_passes"] = loop.passes if loop is not None else 0
    rep["outer_changes_deg"] = loop.changes if loop is not None else []
    rep["outer_focus"] = box_of(loop.focus) if loop is not None and loop.focus is not None else None
    if loop is not None:  # the solver's timer over every NLiPs solve of the outer loop, and each one
        rep["seconds"], rep["pass_seconds"] = (
            float(sum(loop.solver_seconds)),
            [round(t, 3) for t in loop.solver_seconds],
        )


@dataclasses.dataclass
class _IndirectFitter:
    """How a solve fits its indirect term: once on the undeformed capture (the sensor's fit, reused by
    later presses), or on the press itself, where the first fit only finds the contact (``refits``) and
    :meth:`again` fits without it."""

    first: object
    """() -> IndirectModel: the first fit."""
    again: object
    """(exclude=...) -> IndirectModel: the fit again, leaving out ``exclude`` (the press's own fit)."""
    refits: bool
    """Whether the contact found with the first fit should be left out of a second one."""
    contact_cache: dict = dataclasses.field(default_factory=dict)
    """The press's side of the contact classification, shared by the classifications of one solve."""


def _indirect_fitter(sources: _Sources, shading: reuse.Deferred | None) -> _IndirectFitter | None:
    """The :class:`_IndirectFitter` of a solve; None when no term is fitted (a fixed light, no reference)."""
    press, leds, ref_capture, explicit_roi = sources.press, sources.leds, sources.ref_capture, sources.explicit_roi
    interreflection, bounces = sources.interreflection, sources.bounces
    if sources.fixed_light is not None or press.reference is None:
        return None
    H, W = press.camera.shape
    source = ref_capture if ref_capture is not None else press
    exclude = box_mask(explicit_roi, (H, W)) if ref_capture is None and explicit_roi is not None else None
    # a press without a known contact is fitted twice: the first fit only finds the contact
    rough = ref_capture is None and explicit_roi is None
    cache = {}
    fit = functools.partial(
        fit_indirect,
        source,
        leds,
        mode=interreflection,
        bounces=bounces,
        shading=shading if source is press else None,
        cache=cache,
    )
    if ref_capture is not None:  # the undeformed capture's fit is the sensor's: reused by later presses

        def first():
            model = reuse.reused(
                "fit",
                (_capture_key(ref_capture), leds, interreflection, bounces),
                lambda: fit(exclude=None, iterations=3),
                persist=True,
            )
            reuse.freeze(model.off_view, model.fitted_light)
            return model

    else:

        def first():
            return fit(exclude=exclude, iterations=1 if rough else 3)

    def again(exclude: np.ndarray) -> IndirectModel:
        # on from the rough fit's kappa and light (warm): 2 alternations land as near the fixed point as 3 from
        # kappa = 0 (kappa within 1e-6 of it on the twin's sphere, cube and coin presses, as close as a 4th
        # alternation moves it), one kappa search and gather fewer
        return fit(exclude=exclude, iterations=REFIT_ALTERNATIONS, warm=True)

    return _IndirectFitter(first=first, again=again, refits=rough)


REFIT_ALTERNATIONS = 2
"""Alternations of a press's refit without its contact (:func:`_indirect_fitter`), started from the rough fit
(``fit_indirect(warm=True)``). Measured (kappa relative to 3 alternations from kappa = 0, the refit before; the twin's
one-bounce 640x480 presses sphere / cube / coin): 1 warm 8e-3 / 3e-2 / 9e-3, 2 warm 1e-6 / 3e-6 / 9e-7; 2 from kappa =
0 2.6e-5 / 2.4e-5 / 1.7e-5; 4 from kappa = 0 1e-6 / 5e-7 / 4e-7 (benchmarks/RESULTS.md, s20-fixed)."""


def _capture_key(capture: Press) -> tuple:
    """What an indirect fit reads of a capture, named by content: camera, response, a digest of the stored
    images (:meth:`Press.images_digest`) and of the reference surface, and the sensor design (the dome beyond
    the view). A fit on the undeformed dome is the sensor's, so it is kept for later presses and processes
    under this key. Worked out once per loaded capture.

    The images are named by the raw bytes of their files when the capture was loaded undecoded (``load_press(...,
    decode=False)``), not by a stamp (size, mtime, inode): a file replaced in place by one of the same size, with
    its time kept (``cp -p``, ``rsync -t``) or within the clock's tick, would keep its stamp and be served the
    old file's fit. Hashing the bytes costs ~10 ms at 640x480; decoding them to hash the arrays 0.2-0.3 s, for a
    warm process that then reads nothing else of the capture (its fit and blurred images are on disk)."""

    def key():
        ref = capture.reference
        surface = reuse.digest(ref.depth, ref.normals)
        design = diskcache.stable_key(design_of(capture))
        return capture.camera, capture.response, capture.images_digest(), surface, design

    return reuse.reused("capture key", id(capture), key, keep=capture)


def _undeformed_images(capture: Press) -> reuse.Deferred:
    """The undeformed capture's linear images ((L, H, W, 3) float32, read-only), deferred (:func:`reuse.deferred`)
    under its content key: the contact classification's blur of them (0.13-0.25 s at 640x480) names them by that
    key and is kept on disk for the next process (``contact._smoothed_undeformed``), which then does not
    linearise them at all (a 44 MB array at 640x480 with 12 LEDs)."""
    return reuse.deferred("undeformed capture", _capture_key(capture), lambda: capture.linear_led_images)


class _OuterLoop:
    """NLiPs with the undeformed surface's indirect light subtracted, then passes with the indirect light of
    the solved surface, under-relaxed per pixel (:func:`_relaxation`), until the normals stop changing.

    When the solve's mask is much larger than the dent (a whole frame), the passes before the last solve only
    the ``focus`` (the dent's box, :func:`dent_focus`), where the light changes most from pass to pass, and
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
    ):
        self.model, self.press, self.leds, self.mask, self.relaxation = model, press, leds, mask, relaxation
        self.focus = focus
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
        ref_surface = reference_surface(press.camera, self.leds, ref.depth, ref.normals, shading=self.shading)
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
"""Rows of the outer loop's light per task of its relaxed update (:meth:`_OuterLoop._update`): at 640 columns and 12
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


class _BoxCompensation:
    """The images minus an indirect light given on the mask's bounding box (the outer loop's, zero outside it):
    ``compensate`` on that box only, written into one copy of the images kept across the passes. The same
    array as ``compensate(images, light)`` for the whole-frame light, without a whole-frame pass per solve (an
    auto ROI's box is a sixth of a 640x480 frame).

    One LED per pool task (the same bits): on a 640x480 whole frame the first call's copy of the images and each
    call's subtraction and clipping over the whole box, 44 MB arrays with 12 LEDs, ran in the main thread."""

    def __init__(self, images: np.ndarray, mask: np.ndarray):
        self.images, self.mask, self.buffer, self.box = images, mask, None, None

    def __call__(self, light: np.ndarray, receivers: np.ndarray | None = None) -> np.ndarray:
        """``light``: (L, h, w, 3) on the mask's bounding box; ``receivers``: (H, W) bool, the pixels the solve
        reads when not the whole mask (a focus pass): only their box is compensated (the solve crops to it),
        the rest of the buffer is left as the last call wrote it."""
        first = self.buffer is None  # on the first pass: a solve without the outer loop needs neither
        if first:
            x0, y0, w, h = box_of(self.mask)
            self.box = (slice(y0, y0 + h), slice(x0, x0 + w))
            self.buffer = np.empty(np.shape(self.images), np.float32)
        window = self.box if receivers is None else _slices(box_of(receivers))
        rows, cols = _within(window, self.box)

        def one_led(i: int) -> None:
            if first:
                self.buffer[i] = self.images[i]  # outside the box the images themselves
            here = (slice(i, i + 1), window[0], window[1])
            compensate(self.images[here], light[i : i + 1, rows, cols], out=self.buffer[here])

        threads.map_items(one_led, range(len(self.buffer)))
        return self.buffer


def _noise_regularised(options: SolverOptions, press: Press, cmap: ContactMap | None):
    """(options with the noise-adapted smoothness, relative noise level) -- see SolverOptions.noise_smoothness."""
    from .contact import image_noise

    if options.noise_smoothness <= 0:
        return options, None
    valid = np.isfinite(press.reference.depth) if press.reference is not None else np.ones(press.camera.shape, bool)
    if cmap is not None:
        sigma, level = cmap.noise, float(np.nanmedian(np.where(valid, cmap.level, np.nan)))
    else:
        lin = press.linear_led_images
        sigma = image_noise(lin, valid)
        level = float(np.median(np.sqrt((lin[:, valid] ** 2).mean(axis=(0, 2)))))
    rel = sigma / max(level, 1e-12)
    gamma = max(options.smoothness, options.noise_smoothness * rel**2)
    return dataclasses.replace(options, smoothness=gamma), rel


def _split_indirect(press: Press, indirect: np.ndarray | Press | None):
    """(reference capture or None, fixed light array or None) from ``solve_press``'s ``indirect``."""
    if indirect is None:
        return None, None
    if isinstance(indirect, Press):
        check_undeformed(press, indirect)
        return indirect, None
    light = np.asarray(indirect, np.float32)
    if light.shape != press.led_images.shape:
        raise ShapeError(f"indirect light {light.shape} must match the LED images {press.led_images.shape}")
    return None, light


def _contact(
    press: Press,
    leds: Leds,
    ref_capture: Press | None,
    fixed_light: np.ndarray | None,
    model: IndirectModel | None,
    shading: reuse.Deferred | None,
    dead_level: float,
    cache: dict | None = None,
) -> ContactMap:
    """The one contact classification: against the undeformed capture, or the model with its indirect term.

    ``shading``: :func:`reference_shading` of the reference surface, deferred; ``dead_level``:
    ``SolverOptions.dead_led_level``, the fit's level of a dead LED; ``cache``: the press's side of the
    classification, shared by the classifications of one solve (``classify_contact(cache=...)``)."""
    classify = functools.partial(classify_contact, press, leds, dead_level=dead_level, cache=cache)
    if ref_capture is not None:
        return classify(undeformed_images=_undeformed_images(ref_capture), undeformed_noise=True)
    if model is not None and model.enabled:
        # one LED's light at a time: the classification block-averages each, and never needs the 44 MB stack
        light = model.undeformed_light_per_led(press.camera.shape)
        return classify(undeformed_images=shading, undeformed_light=light)
    return classify(undeformed_images=shading, indirect=fixed_light)


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


# inspect.signature(solve_press) shows _solve_press's keywords (the pipeline records them with their defaults)
solve_press.__wrapped__ = _solve_press
