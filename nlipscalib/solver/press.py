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
   changing. The loop is under-relaxed per pixel (:func:`.outer_loop._relaxation`): the plain iteration alternates
   around its answer because the light it subtracts feeds back through the solved albedo.

This module is the entry (:func:`solve_press`: the arguments, the runner of each NLiPs solve, the report); each part
lives in a file of its own:

- ``press_checks.py``: the arguments' checks, made before any work;
- ``light_and_contact.py``: steps 1 and 2, the indirect term's fit and the contact classification;
- ``outer_loop.py``: step 3's outer interreflection loop and its light on the mask's bounding box.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import inspect
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import said_once, tolerances
from ..core.blas import blas_threads
from ..core.capture import Press, as_press, select_leds, with_led_gains, with_unusable_samples
from ..core.errors import CaptureError, ShapeError, check_kind
from ..core.lag_blind import lag_blind_pairs
from ..core.leds import Led
from ..core.repeated_frames import (
    DarkBand,
    LaggedBand,
    dark_band_mask,
    dark_line,
    frame_checks,
    lagged_line,
    model_light,
    repeated_line,
)
from ..progress import PRESS_DETAIL
from . import reuse, threads
from .anchoring import anchor_weights, rescale_to_anchors, widen_to_anchor
from .camera_shift import shift_note
from .contact import ContactMap
from .contact_roi import contact_box
from .contact_verdict import no_contact
from .exposure import dark_frame_fault, nothing_to_fit, saturated_share, saturation_note
from .image_stats import led_levels, lit_leds
from .interreflection import compensate
from .led_checks import (
    NOTHING_FOUND,
    ExchangedImages,
    LedFindings,
    agreed_gains,
    dark_rows,
    drift_samples,
    exposure_drift_note,
    exposure_ratio,
    given_leds_exchange,
    image_names,
    led_check_measured,
    led_gains,
    linearity_notes,
    model_gain_check,
    reference_exchanges,
    reference_gain,
    reference_gain_note,
    reorder_note,
    reordered,
)
from .light_and_contact import (
    REFIT_ALTERNATIONS,
    Sources,
    capture_key,
    light_and_contact,
    split_indirect,
    undeformed_contact,
)
from .nlips import SolveResult, solve
from .options import SolverOptions
from .outer_loop import FILL_ROWS, UPDATE_ROWS, BoxCompensation, OuterLoop, led_channel_sum
from .point_led_error import point_led_misfit
from .press_checks import check_keywords, check_modes, check_roi
from .resolution import contact_steepness, resolution_note
from .roi import box_mask, box_of, dent_focus
from .sensor_fit import sensor_check_note, sensor_mismatch

if TYPE_CHECKING:  # named in hints only
    from ..core.leds import Leds
    from .indirect import IndirectModel

log = logging.getLogger(__name__)

__all__ = ["FILL_ROWS", "REFIT_ALTERNATIONS", "UPDATE_ROWS", "led_channel_sum", "solve_press"]


def solve_press(press: Press | str | os.PathLike, **kwargs: Any) -> SolveResult:
    """Solve one press; the parameters are :func:`_solve_press`'s (below), and ``leds_name``: where
    ``leds`` came from (an LED file's path), named when the checks find them the exchanged ones (None: "the LEDs
    given (--leds)").

    ``press`` and ``indirect`` may also be press folders' paths (str or Path), loaded by :func:`.as_press` (all
    their LEDs): a script's ``solve_press("out/press", indirect="out/reference")`` failed deep inside the solve
    (``'str' object has no attribute 'leds'``, ``could not convert string to float``).

    A guard against a failure seen on small, noisy captures: when the noise-adapted smoothness
    (``SolverOptions.noise_smoothness``) was applied and the solved surface left the physically possible
    range (median distance to the undeformed surface above ``tolerances.MAX_MEDIAN_DISPLACEMENT_MM``: the
    gel cannot move that far), the press is solved again without it and the report says so. Seen on a
    96x72 and a 160x120 twin capture with a tight box around a sphere press: depth 13 mm off, AAE 18 deg;
    without the raised smoothness 0.05 mm and 7.7 deg.

    Against an undeformed capture (``indirect`` a Press), LEDs that aged on their own since it (their brightness
    against it beyond ``tolerances.LED_GAIN_CORRECTION`` after the overall gain) are solved with their images
    rescaled to its brightness (:func:`.led_checks.led_gains`, :func:`.capture.with_led_gains`), recorded as the
    report's ``led_gains`` ((L, 3) per LED and channel; None when none was rescaled).
    """
    check_keywords(kwargs, KEYWORDS)
    press = as_press(press, "press")
    if isinstance(kwargs.get("indirect"), (str, os.PathLike)):
        kwargs["indirect"] = as_press(kwargs["indirect"], "indirect")
    check_kind(
        kwargs.get("indirect"),
        (Press, np.ndarray, type(None)),
        "indirect",
        "the undeformed capture (a Press or its folder's path), an (L, H, W, 3) array of indirect light, or None",
    )
    check_kind(kwargs.get("options"), (SolverOptions, type(None)), "options", "a SolverOptions, or None (defaults)")
    _check_indirect_light(press, kwargs.get("indirect"))
    if kwargs.get("leds") is not None:
        kwargs["leds"] = _given_leds(press, kwargs["leds"])
    if not isinstance(kwargs.get("indirect"), Press):  # against an undeformed capture they may go unused
        _rays_ahead(press)
    # One BLAS thread throughout, not only inside the NLiPs solves: the LED checks' np.corrcoef of (24, 2008)
    # samples took 55-70 ms on OpenBLAS's two threads on the 2-core VM, 0.1 ms on one, on the main thread while the
    # other core waited (benchmarks/RESULTS.md, s30-lastpass2; core.blas.blas_threads' why).
    with blas_threads(1):
        return _checked_solve(press, kwargs)


def _outside_box(roi: object, shape: tuple[int, int]) -> np.ndarray | None:
    """(H, W) bool -- the pixels outside an explicit solve box ``roi`` = (x0, y0, w, h); None for "auto", None (the
    whole gel) or anything :func:`.press_checks.check_roi` refuses later (the solve says so there)."""
    if roi is None or isinstance(roi, str):
        return None
    try:
        return ~box_mask(check_roi(roi, shape[1], shape[0]), shape)
    except ShapeError:
        return None


def _outside_auto_box(press: Press, kwargs: dict[str, Any]) -> np.ndarray | None:
    """(H, W) bool -- the pixels outside the box ``--roi auto`` finds (:func:`_auto_box`) on ``press``'s images as
    they are, against the undeformed capture ``kwargs["indirect"]``, for :func:`.led_checks.exposure_ratio`'s
    ``outside`` (as an explicit box's, :func:`_outside_box`); None without a contact (the solve says so later).

    Why: the auto box was found only after the per-LED gains were measured over the whole gel; the twin's flat pad
    pressed 1 mm by a 5 mm cube (65-72 % of the gel in contact) read 7 of 12 LEDs 0.974-1.011 there, the solve
    rescaled them and its contact AAE went 0.26 -> 0.89 deg (benchmarks/RESULTS.md, s41-autogain). The box, not the
    misfitting pixels (:func:`.roi.contact_pixels`): the pad's flat contact barely misfits, and outside the dilated
    misfit LED 1 still read 0.989. An LED's 1-3 % gain is far below a contact's misfit, so the box found here is the
    solve's. Found only when the whole gel says an LED strays (:func:`.led_checks.led_gains`): a solve with no gain
    to correct classifies its contact once, as before."""
    leds = press.leds if kwargs.get("leds") is None else tuple(kwargs["leds"])
    dead_level = (kwargs.get("options") or SolverOptions()).dead_led_level
    cmap = undeformed_contact(press, leds, kwargs["indirect"], dead_level)
    try:
        _, _, (wide, _, _) = _auto_box(press, cmap, kwargs["indirect"].folder)
    except CaptureError:
        return None
    return _outside_box(wide, press.camera.shape)


def _check_indirect_light(press: Press, indirect: object) -> None:
    """ShapeError unless an ``indirect`` array is one float image per LED image of ``press``, (L, H, W, 3).

    Why: an array of another shape went through the LED checks first and failed (or ran on) deep inside them; the
    solve's own check (:func:`.light_and_contact.split_indirect`) comes after them (s38-apikinds)."""
    if not isinstance(indirect, np.ndarray):
        return
    if indirect.shape != press.led_images.shape:
        raise ShapeError(
            f"indirect must be the undeformed capture or {press.led_images.shape} light (one image per LED), "
            f"got {indirect.shape}"
        )


def _given_leds(press: Press, leds: Any) -> tuple[Led, ...]:
    """``leds`` (:func:`_solve_press`'s) as a tuple of Led, one per LED image of ``press``; ShapeError for anything
    else, CaptureError for another count. Why: a list of numbers or an LED file's path failed deep inside the LED
    checks ("tuple index out of range") before the solve's own count check was reached."""
    if isinstance(leds, (str, os.PathLike)):
        raise ShapeError(
            f"leds: {os.fspath(leds)!r} is a path; give the LEDs themselves: "
            "nlipscalib.core.ledfile.read_led_file(path).leds (an LED file of `nlips calibrate-leds`)"
        )
    given = tuple(leds) if isinstance(leds, (Sequence, np.ndarray)) else None
    if given is None or not all(isinstance(led, Led) for led in given):
        what = type(leds).__name__ if given is None else f"a {type(leds).__name__} of {type(given[0]).__name__}"
        raise ShapeError(
            f"leds must be a sequence of Led (read_led_file(path).leds, calibrate_leds(reference).leds), got {what}"
        )
    if len(given) != len(press.leds):
        raise CaptureError(f"{press.folder}: {len(given)} LEDs given for {len(press.leds)} LED images")
    return given


def _rays_ahead(press: Press) -> None:
    """Start computing the press camera's whole-frame viewing rays (``Camera.rays``, kept on the camera) on a
    thread of its own; nothing on one core or when they are computed already.

    Why: the contact search's point-LED error (:func:`.point_led_misfit`) computed them first, on the main thread
    while the other core waited: 25-35 ms of NumPy at 640x480 (the fisheye lens's Newton unprojection), which
    releases the GIL. The LED checks and the light's fit run on the main thread meanwhile; the contact search then
    finds them made or waits for them (``cached_property`` holds its lock while one thread computes). The same
    bits on any thread. Not against an undeformed capture (``--reference``): its solve need not unproject the whole
    image (the auto ROI's box alone), and a second core's 25 ms would then be spent for nothing."""
    camera = press.camera
    if threads.workers() == 1 or "rays" in vars(camera):
        return

    def run() -> None:
        with contextlib.suppress(Exception):  # a camera that cannot unproject raises where its rays are used
            camera.rays  # noqa: B018  (the cached property computed and kept)

    threading.Thread(target=run, name="camera-rays", daemon=True).start()


def _checked_solve(press: Press, kwargs: dict[str, Any]) -> SolveResult:
    """:func:`solve_press`'s body on a loaded press: the LED checks, the solve and its report."""
    keep_order = not kwargs.pop("reorder_leds", True)
    leds_name = kwargs.pop("leds_name", None)
    blind = _lag_blind(press)  # in the capture's LED order, before any LED is reordered or left out
    checks = _capture_notes(press, kwargs.get("leds"), kwargs.get("options"), say=False)
    led_notes, left_out, misplaced, order, measured, dark, exchanged = checks
    if order is not None and not keep_order:  # the images' own order: the physics is right again
        press, kwargs, checks = _in_detected_order(press, kwargs, order)
        led_notes, left_out, misplaced, measured, dark, exchanged = checks
    else:
        for note in led_notes:
            log.warning("%s", note)
    samples = None  # the press's and the undeformed capture's images on the gel: their order, then the drift
    if isinstance(kwargs.get("indirect"), Press):  # the undeformed capture's images in another order
        samples = drift_samples(press, kwargs["indirect"])
        named = [*misplaced, *(i for found in exchanged for i in found.leds)]
        fitting = measured.live if measured is not None else ()
        exchanged += reference_exchanges(press, kwargs["indirect"], samples, named, fitting)
    if kwargs.get("leds") is not None:  # the LED model given may be the one holding them exchanged
        name = leds_name or "the LEDs given (--leds)"
        exchanged = [given_leds_exchange(found, press.leds, kwargs["leds"], name) for found in exchanged]
    led_notes += _exchanged_notes(exchanged, keep_order)
    if misplaced and kwargs.get("check_sensor", True):  # out of order: they misfit any description (their warning)
        kwargs["check_sensor"] = None
    if isinstance(kwargs.get("indirect"), Press) and (moved := shift_note(press, kwargs["indirect"])):
        log.warning("%s", moved)
        led_notes.append(moved)
    undeformed_dark, undeformed_repeated = _undeformed_dark_bands(press, kwargs)
    led_notes += _undeformed_band_notes(kwargs.get("indirect"), undeformed_dark)
    # an undeformed image that repeats the one before it holds none of its LED's light: that LED left out, as a
    # repeated press image is (nothing to compare the press's light with, nor to fit its interreflection on)
    repeated_out = [i for i, _ in undeformed_repeated if i not in left_out]
    if len(press.leds) - len(left_out) - len(repeated_out) < tolerances.MIN_LEDS_PER_PIXEL:
        repeated_out = []  # too few LEDs to solve without them: only warned about, as in the press
    led_notes += _undeformed_repeated_notes(kwargs.get("indirect"), undeformed_repeated)
    left_out = sorted({*left_out, *repeated_out})
    gains = None
    if isinstance(kwargs.get("indirect"), Press):
        # measured away from the contact where the box says where it is: a contact over most of the gel moves the
        # median by its own shading (the flat pad's cube press, benchmarks/RESULTS.md s41-flatcube)
        outside = _outside_box(kwargs.get("roi"), press.camera.shape)
        taken = samples if outside is None else None  # the whole gel's samples; those outside the box taken there
        # an LED's dark or lagged band (in the press or the undeformed capture) holds no light of it
        ratio = exposure_ratio(press, kwargs["indirect"], dark + undeformed_dark, taken, outside)
        if ratio is not None and repeated_out:  # another LED's light there: no verdict, the LED is left out below
            ratio[repeated_out] = 1.0
        gains = None if ratio is None else led_gains(ratio, misplaced)
        if gains is not None and kwargs.get("roi") == "auto":
            # --roi auto finds its box after the gains: measured again outside the box the images show as they are
            # (an LED's 1-3 % gain is far below a contact's misfit), as outside an explicit box (one code path);
            # rescaled where both measures agree (a large contact moves each by its own shading: agreed_gains)
            outside = _outside_auto_box(press, kwargs)
            ratio = exposure_ratio(press, kwargs["indirect"], dark + undeformed_dark, None, outside)
            if ratio is not None and repeated_out:
                ratio[repeated_out] = 1.0
            gains = None if ratio is None else agreed_gains(gains, led_gains(ratio, misplaced))
        if drifted := exposure_drift_note(press, kwargs["indirect"], ratio, gains):
            log.warning("%s", drifted)
            led_notes.append(drifted)
        if ratio is not None and kwargs.get("light_gain") is None:  # on every LED, before any is left out below
            kwargs["light_gain"] = reference_gain(ratio)  # a caller's own gain is theirs
            if aged := reference_gain_note(press, kwargs["indirect"], kwargs["light_gain"]):
                _say_once_per_session(aged, f"reference gain\0{press.folder.parent}\0{kwargs['indirect'].folder}")
                led_notes.append(aged)
        if gains is not None:  # LEDs aged on their own: their images at the undeformed capture's brightness
            log.info("%s: LED images rescaled by %s", press.folder, np.round(gains, 3).tolist(), extra=PRESS_DETAIL)
            press = with_led_gains(press, gains)
    elif press.reference is not None:  # no undeformed capture: LEDs aged on their own, against the LED model
        darkened = {band.index for band in dark}  # off the model in their dark rows: no gain measured on them
        live = [
            i
            for i in _live_leds(press, kwargs.get("options"))
            if i not in left_out and i not in misplaced and i not in darkened
        ]
        # the weak-LED check's samples of the same LEDs, when it judged these: measured once
        aged, gains = model_gain_check(press, _model_leds(press, kwargs.get("leds")), live, measured)
        led_notes.extend(aged)
        if gains is not None:  # the sensor's fault, alike on a session's presses: warned once for them
            which = np.flatnonzero(gains[:, 0] != 1).tolist()
            _say_once_per_session(aged[0], f"model led gains\0{press.folder.parent}\0{which}")
            press = with_led_gains(press, gains)
    keep = [i for i in range(len(press.leds)) if i not in left_out]
    if left_out:  # LEDs whose light does not fit the model: solved without them, as without a dead LED
        press, kwargs = _without_leds(press, kwargs, keep)
    if dark or undeformed_dark:  # rows (columns) read while their LED was off, or before it switched (the previous
        # LED's light): left out for that LED, as saturated samples are; the undeformed capture's dark ones too, there
        # and in the press (nothing to compare the press with there)
        press = with_unusable_samples(press, dark_band_mask(dark + undeformed_dark, keep, press.camera.shape))
    if undeformed_dark:
        mask = dark_band_mask(undeformed_dark, keep, press.camera.shape)
        kwargs["indirect"] = with_unusable_samples(kwargs["indirect"], mask)
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
        with _not_said_again(result.report.get("warnings", [])):
            result = _solve_press(press, **kwargs)
        result.report["smoothness_fallback"] = (
            f"noise-adapted smoothness dropped: the first solve drifted {drift:.1f} mm"
        )
    _report_saturation(result, press)
    result.report["led_gains"] = gains.tolist() if gains is not None else None
    if left_out:  # the solver numbers the LEDs it was given: back to the capture's
        for key in LED_LIST_KEYS:
            if key in result.report:
                result.report[key] = [keep[i] for i in result.report[key]]
        result.report["leds_left_out"] = left_out
    if repeated_out:
        result.report["undeformed_repeated_left_out"] = repeated_out
    lagged = [band for band in dark if isinstance(band, LaggedBand)]
    dark = [band for band in dark if not isinstance(band, LaggedBand)]
    undeformed_lagged = [band for band in undeformed_dark if isinstance(band, LaggedBand)]
    undeformed_dark = [band for band in undeformed_dark if not isinstance(band, LaggedBand)]
    for key, bands in (
        ("dark_bands_left_out", dark),
        ("lagged_bands_left_out", lagged),
        ("undeformed_dark_bands_left_out", undeformed_dark),
        ("undeformed_lagged_bands_left_out", undeformed_lagged),
    ):
        if bands:
            result.report[key] = [
                {"led": band.index, band.axis: [band.rows[0], band.rows[1]], "margin": tolerances.DARK_BAND_MARGIN}
                for band in bands
            ]
    if blind:
        result.report["lag_blind_pairs"] = [pair.to_dict() for pair in blind]
    if order is not None:
        result.report["led_order"] = order if not keep_order else list(range(len(order)))
        result.report["leds_reordered"] = not keep_order
    if exchanged:  # solved as captured (--keep-led-order): which
        result.report["leds_exchanged"] = [list(found.leds) for found in exchanged]
    if led_notes:
        result.report["warnings"] = [*led_notes, *result.report.get("warnings", [])]
    return result


def _lag_blind(press: Press) -> list:
    """The consecutive LEDs a lag between which the press's lag-band check cannot see (:func:`.lag_blind_pairs`,
    kept with the check's LED model: ~0.5 ms); none without an undeformed surface."""
    from .exposure import expected_light_of

    if press.reference is None:
        return []
    return lag_blind_pairs(expected_light_of(press), np.isfinite(press.reference.depth))


class _SaidAlready(logging.Filter):
    """Drops a log record whose message is one of ``said`` (the first solve's warnings)."""

    def __init__(self, said: Sequence[str]) -> None:
        super().__init__()
        self.said = set(said)

    def filter(self, record: logging.LogRecord) -> bool:
        return record.getMessage() not in self.said


def _say_once_per_session(note: str, key: str) -> None:
    """``note`` as a WARNING the first time this command meets ``key`` (a fault of the whole session, such as
    LEDs aged since the undeformed capture: a batch of 6 presses said it 6 times), at INFO afterwards; each press's
    report keeps it either way."""
    if said_once.first_time(key):
        log.warning("%s (said once for this session's presses; each press's report.json keeps its own)", note)
    else:
        log.info("%s", note)


@contextlib.contextmanager
def _not_said_again(said: Sequence[str]) -> Iterator[None]:
    """The solve again without the raised smoothness says none of the first solve's warnings a second time (its
    report keeps them): a capture's linearity, an override or a contact at the resolution limit was logged twice."""
    said_already = _SaidAlready(said)
    log.addFilter(said_already)
    try:
        yield
    finally:
        log.removeFilter(said_already)


KEEP_ORDER_FLAG = "--keep-led-order"
"""The command-line flag that solves LED images out of order as captured (``reorder_leds=False``)."""
EXCHANGE_REFUSED = {
    "model": (
        f"; not solved: put the images in the LEDs' order (their files, or images.leds in meta.json) and run again, "
        f"or pass {KEEP_ORDER_FLAG} to solve them as captured (right only when the LED model misplaces those LEDs: "
        "calibrate them, nlips calibrate-leds, and solve with --leds FILE)"
    ),
    "reference": (
        "; not solved: put the exchanged capture's images in the LEDs' order (their files, or images.leds in "
        f"meta.json) and run again, or pass {KEEP_ORDER_FLAG} to solve them as captured"
    ),
    "leds": (
        "; not solved: calibrate the LEDs again on an undeformed capture with its images in the LEDs' order (nlips "
        f"calibrate-leds) and solve with that file, or solve without --leds, or pass {KEEP_ORDER_FLAG} to solve "
        "them as captured"
    ),
}
"""The tail of the solve's refusal of LED images exchanged with a neighbour's (:func:`_exchanged_notes`), as ``nlips
calibrate-leds`` refuses them (:data:`.calibrate.EXCHANGE_REFUSED`), by what told it
(:attr:`.led_checks.ExchangedImages.against`).

Why refused, where images far apart that show other LEDs' light are solved in the order they show
(:func:`.led_checks.detected_order`): those correlate 0.98 with the LED they show and below 0.5 with their own; a
neighbour's light differs less from an LED's own than an LED model 3 mm off the sensor can (the evidence:
:data:`~nlipscalib.core.tolerances.MODEL_EXCHANGE_FACTOR`), so the images' order is the user's to fix, not the
solve's to guess; solved as captured, the twin's sphere presses lost their auto box and 0.3-0.5 deg of the whole gel."""
EXCHANGE_KEPT = f"; solved as captured ({KEEP_ORDER_FLAG}; report.json leds_exchanged)"
"""The tail of the warning of :func:`_exchanged_notes` with ``--keep-led-order``."""


def _exchanged_notes(exchanged: Sequence[ExchangedImages], keep_order: bool) -> list[str]:
    """The warnings (``keep_order``: ``--keep-led-order``) naming LED images exchanged with a neighbour's
    (:class:`.led_checks.ExchangedImages`), each logged; [] when none. CaptureError with their line otherwise:
    :data:`EXCHANGE_REFUSED` says why."""
    if not exchanged:
        return []
    if not keep_order:
        raise CaptureError("; ".join(found.line for found in exchanged) + EXCHANGE_REFUSED[exchanged[0].against])
    notes = [found.line + EXCHANGE_KEPT for found in exchanged]
    for note in notes:
        log.warning("%s", note)
    return notes


def _in_detected_order(press: Press, kwargs: dict, order: list[int]) -> tuple[Press, dict, tuple]:
    """The press with its LED images in the ``order`` they show (:func:`.led_checks.detected_order`), the undeformed
    capture given (``indirect``) likewise when its own images show the same order (the same wiring), and the
    warnings, LEDs to leave out, misplaced LEDs, measured gains, dark and lagged bands and exchanged images of the
    reordered press (its checks made again, logged).

    Why: two swapped LED images of the twin's cube press were solved as captured to a contact AAE of 6.1 deg after a
    warning that named the pair; the image labelled 3 was lit by LED 7, so solving it as LED 7's is the physics."""
    note = reorder_note(press, order, KEEP_ORDER_FLAG)
    # a wiring error is the whole session's: said once per command (its workers too), each press's report keeps it
    if said_once.first_time(f"led order\0{press.folder.parent}\0{order}"):
        log.warning("%s (said once for the presses of %s out of this order)", note, press.folder.parent)
    else:
        log.info("%s", note)
    kwargs = dict(kwargs)
    indirect = kwargs.get("indirect")
    if isinstance(indirect, Press) and indirect.reference is not None:
        its_order = _led_notes(indirect, kwargs.get("leds"), kwargs.get("options"), say=False)[3]
        if its_order == order:
            kwargs["indirect"] = reordered(indirect, order)
    press = reordered(press, order)
    notes, left_out, misplaced, _, measured, dark, exchanged = _capture_notes(
        press, kwargs.get("leds"), kwargs.get("options")
    )
    return press, kwargs, ([note, *notes], left_out, misplaced, measured, dark, exchanged)


LED_LIST_KEYS = ("leds_used", "dead_leds", "dead_leds_contact", "leds_left_out")
"""Report entries that list LEDs (0-based): renumbered to the capture's LEDs where a solve had a subset of them."""


def _capture_notes(press: Press, leds: Leds | None, options: SolverOptions | None, say: bool = True) -> LedFindings:
    """Warnings about the capture, each logged: its dark frame (:func:`.exposure.dark_frame_fault`; CaptureError
    when it holds light) and :func:`.led_checks.led_check` of its live LEDs; the LEDs to leave out and those whose
    images show another LED's light (0-based), the order the images show (None: theirs, or not clear), the LEDs'
    light against the model as the check measured it (:class:`.led_checks.MeasuredGains`, or None), the LED
    images' dark bands (rows or columns read while the LED was off, :class:`.repeated_frames.DarkBand`) and the
    images exchanged with a neighbour's (:class:`.led_checks.ExchangedImages`; said by the caller).
    Made before the solve, so a solve that then fails has said why first."""
    notes = []
    if fault := dark_frame_fault(press):
        message, refuse = fault
        if refuse:
            raise CaptureError(message)
        if say:
            log.warning("%s", message)
        notes.append(message)
    found = _led_notes(press, leds, options, say)
    return found._replace(notes=notes + found.notes)


def _led_notes(press: Press, leds: Leds | None, options: SolverOptions | None, say: bool = True) -> LedFindings:
    """:func:`.led_checks.led_check_measured` of the press's live LEDs, each note logged as a warning (``say``)."""
    leds = _model_leds(press, leds)
    if press.reference is None or len(leds) != len(press.leds):
        return NOTHING_FOUND  # no undeformed dome to model; a wrong LED count is refused by the solve
    live = _live_leds(press, options)
    checks = led_check_measured(press, leds, live)
    for note in checks[0] if say else ():
        log.warning("%s", note)
    return checks


UNDEFORMED_DARK = (
    "; in the undeformed capture the press is solved against: capture the undeformed dome again; until then those "
    f"rows (columns), with {tolerances.DARK_BAND_MARGIN} more either side, are left out for that LED, there and in "
    "the press"
)
"""What the solve does about dark rows of the undeformed capture (``--reference``; :func:`.dark_line`'s ``done``).

Why: the twin's sphere press (640x480, --roi auto) solved against an undeformed capture with LED 5's top 60 rows dark
gave a contact AAE of 0.622 deg (0.509 against the clean capture), with "--roi auto left out 39680 misfitting pixels
along the gel's edge (... vignetting ...)": the interreflection term fitted on it and the contact map compare with
light it does not hold. Those rows left out for LED 5 in both: 0.509 (benchmarks/RESULTS.md, s30-darkcols)."""


UNDEFORMED_LAGGED = (
    "; in the undeformed capture the press is solved against: capture the undeformed dome again; until then those "
    f"rows (columns), with {tolerances.DARK_BAND_MARGIN} more and to the frame's edge, are left out for that LED, "
    "there and in the press"
)
"""What the solve does about rows (columns) of the undeformed capture read before their LED switched (``--reference``;
:func:`.lagged_line`'s tail), as about its dark rows (:data:`UNDEFORMED_DARK`)."""


def _undeformed_band_notes(undeformed: object, bands: list[DarkBand | LaggedBand]) -> list[str]:
    """The warnings about the undeformed capture's dark and lagged bands (:func:`_undeformed_dark_bands`), each said
    once for a session's presses (each press's report keeps it)."""
    if not bands:
        return []
    names = image_names(undeformed)
    lagged = [band for band in bands if isinstance(band, LaggedBand)]
    dark = [band for band in bands if not isinstance(band, LaggedBand)]
    notes = [dark_line(undeformed.folder, names, dark, UNDEFORMED_DARK)] if dark else []
    notes += [f"{lagged_line(undeformed.folder, names, lagged)}{UNDEFORMED_LAGGED}"] if lagged else []
    for note in notes:
        _say_once_per_session(note, f"undeformed bands\0{undeformed.folder}\0{note[:40]}")
    return notes


UNDEFORMED_REPEATED = (
    "; in the undeformed capture the press is solved against: capture the undeformed dome again; until then that LED "
    "is left out of the solve (nothing of its own light to compare the press with)"
)
"""What the solve does about an undeformed capture's LED image that repeats the one before it (``--reference``;
:func:`.repeated_line`'s tail), as about a press's (:data:`.led_checks.REPEATED_REASON`)."""


def _undeformed_repeated_notes(undeformed: object, repeated: list[tuple[int, float]]) -> list[str]:
    """The warning about the undeformed capture's repeated LED images (:func:`_undeformed_dark_bands`' second
    list), said once for a session's presses (each press's report keeps it)."""
    if not repeated:
        return []
    note = f"{repeated_line(undeformed.folder, image_names(undeformed), repeated)}{UNDEFORMED_REPEATED}"
    _say_once_per_session(note, f"undeformed repeated\0{undeformed.folder}\0{note[:40]}")
    return [note]


def _undeformed_dark_bands(press: Press, kwargs: dict) -> tuple[list[DarkBand | LaggedBand], list[tuple[int, float]]]:
    """The undeformed capture's (``kwargs["indirect"]``, a Press with a surface) LED images' dark bands
    (:func:`.led_checks.dark_rows` of its live LEDs against the solve's LED model) and lagged bands (rows or columns
    read before the LED switched, :func:`.repeated_frames.lagged_bands`: the LED before it's light; its LED not
    looked at for dark rows, as in the press), and its LED images that repeat the one before them whole
    (:func:`.repeated_frames.frame_checks`' first list: (index, difference)), once per capture's content and LED model
    (~4 ms and ~10 ms, and its images' decoding); ([], []) without one, or when its LEDs are not the press's."""
    undeformed = kwargs.get("indirect")
    if not isinstance(undeformed, Press) or undeformed.reference is None:
        return [], []
    leds = _model_leds(press, kwargs.get("leds"))
    if len(undeformed.leds) != len(leds) or undeformed.camera.shape != press.camera.shape:
        return [], []

    def bands() -> tuple[list[DarkBand | LaggedBand], list[tuple[int, float]]]:
        # each LED's modelled light (the solve's LEDs) judges the bands: LEDs in close pairs light the gel alike
        expected = model_light(undeformed.reference.depth, undeformed.reference.normals, undeformed.camera, leds)
        gel = np.isfinite(undeformed.reference.depth)
        repeated, lagged = frame_checks(undeformed.linear_led_images, gel, expected)[:2]
        # another LED's light there: no verdict on its own light
        shifted = {band.index for band in lagged} | {i for i, _ in repeated}
        live = [i for i in _live_leds(undeformed, kwargs.get("options")) if i not in shifted]
        return [*dark_rows(undeformed, leds, live), *lagged], [(int(i), float(d)) for i, d in repeated]

    # kept on disk under the capture's content, as its interreflection fit: a warm solve never decodes its images
    # (the key's digest holds the package's source: entries written before repeated images were kept are not read)
    level = (kwargs.get("options") or SolverOptions()).dead_led_level
    return reuse.reused("undeformed bands", (capture_key(undeformed), leds, level), bands, persist=True)


def _model_leds(press: Press, leds: Leds | None) -> tuple:
    """The LED model a solve uses: ``leds`` given, else the press's own."""
    return tuple(press.leds if leds is None else leds)


def _live_leds(press: Press, options: SolverOptions | None) -> list[int]:
    """The LEDs (0-based) whose images hold light over the gel (``SolverOptions.dead_led_level``)."""
    level = (options or SolverOptions()).dead_led_level
    lit = lit_leds(led_levels(press.linear_led_images, np.isfinite(press.reference.depth)), level)
    return [int(i) for i in np.flatnonzero(lit)]


def _without_leds(press: Press, kwargs: dict, keep: list[int]) -> tuple[Press, dict]:
    """The press and :func:`_solve_press`'s keywords with only the LEDs ``keep``: its LED images, the LEDs given
    (``leds``) and the undeformed capture or light given (``indirect``)."""
    kwargs = dict(kwargs)
    for key in ("leds", "emitters"):
        if kwargs.get(key) is not None:
            kwargs[key] = tuple(kwargs[key][i] for i in keep)
    indirect = kwargs.get("indirect")
    if isinstance(indirect, Press):
        kwargs["indirect"] = select_leds(indirect, keep)
    elif indirect is not None:
        kwargs["indirect"] = np.asarray(indirect)[keep]
    return select_leds(press, keep), kwargs


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
    check_sensor: bool | None = True,
    reorder_leds: bool = True,
    light_gain: np.ndarray | None = None,
    led_radius: float = 0.0,
    emitters: Sequence[Led | dict] | None = None,
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
        same sequence within 0.004 deg): on the cube the relaxed loop alternates (:func:`.outer_loop._relaxation`), and
        two passes stop on its good side, 0.03-0.05 deg better than the fixed point (benchmarks/RESULTS.md, s16-f).
    outer_relaxation : "auto" (per pixel 1 / (1 + indirect / direct light), see :func:`.outer_loop._relaxation`) or a
        number: the light of each outer pass is ``L + w (gathered - L)``; 1.0 is the plain iteration.
    check_sensor : refuse (CaptureError) a press whose images do not fit the sensor its meta.json and reference.npz
        describe (:func:`.sensor_fit.sensor_mismatch`); False (``--allow-sensor-misfit``): solve it anyway, the
        report's ``sensor_check`` saying what was overridden (and ``warnings``, when it was); None: not checked
        (:func:`solve_press` sets it when the LED images show other LEDs' light: their own warning says so).
    reorder_leds : LED images out of order (a clean pair or cycle, :func:`.led_checks.detected_order`) are solved
        in the order they show, with a warning and the report's ``led_order`` / ``leds_reordered``
        (:func:`solve_press` does it); False (``--keep-led-order``): as captured, only warned about.
    light_gain : (3,) the press's images' brightness over the undeformed capture's (``indirect``), per channel
        (:func:`.led_checks.reference_gain`; :func:`solve_press` measures it): the indirect term fitted on that
        capture is scaled by it (:meth:`.indirect.IndirectModel.with_gain`); None: taken as 1.
    led_radius : mm; > 0: the NLiPs solves model the LEDs as disks of this radius (:func:`nlipscalib.solver.solve`'s
        ``led_radius``), ``emitters`` (or ``leds`` when None), and so does everything that shades with the LEDs
        for the indirect term: the reference surface's shading (the term's fit and the contact map read it), the
        off-view dome's light and the outer loop's reference and solved surfaces (:func:`.indirect.term_shading`;
        the point term under a disk solve lost 0.5 -> 0.85 deg of a one-bounce gel-filling sphere's whole gel,
        benchmarks/RESULTS.md, s33-disklose / s33-diskterm); the cached term's keys name the radius. The point
        LEDs ``leds`` stay where a point model is meant: the ``--roi auto`` edge's point-LED misfit; 0: points.
    emitters : sequence of Led (or their dicts, as an LED file's ``emitters``) -- ``calibrate-leds``' disks, in the
        order of ``leds``; used only with ``led_radius`` > 0.

    Returns
    -------
    SolveResult -- ``report`` adds roi, roi_note (what ``--roi auto`` left out or a warning; empty when none),
    prior, interreflection (the fitted model and the decision), reference_gain (``light_gain``),
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
    ref_capture, fixed_light = split_indirect(press, indirect)
    H, W = press.camera.shape
    prior = press.reference.depth if press.reference is not None else None
    mask = np.isfinite(prior) if prior is not None else np.ones((H, W), bool)
    if prior is not None and not mask.any():
        raise CaptureError(f"{press.folder}: the reference surface covers no pixel; nothing to reconstruct")
    explicit_roi = None if roi is None or isinstance(roi, str) else check_roi(roi, W, H)
    if isinstance(roi, str) and roi != "auto":
        raise ShapeError(f"roi must be (x0, y0, w, h) or 'auto', got {roi!r}")

    disks = _disk_leds(press, leds, emitters, led_radius)
    # the indirect term, the contact map and the outer loop shade with the solve's LED model (s33-diskterm)
    term_leds, term_radius = disks if disks is not None else (leds, 0.0)
    sources = Sources(press, term_leds, ref_capture, fixed_light, explicit_roi, interreflection, bounces, term_radius)
    light = light_and_contact(sources, options.dead_led_level)
    model, cmap = light.model, light.cmap
    linear_notes = _linearity_warnings(press, model, cmap)
    # with the indirect term forced off and no undeformed capture, the model leaves out the gel's own light on
    # purpose (10 % of the twin's brightness at one bounce): its misfit then says nothing of the sensor's files
    modelled = ref_capture is not None or interreflection != "off"
    undeformed = Path(ref_capture.folder) if ref_capture is not None and ref_capture.folder is not None else None
    if check_sensor and modelled and cmap is not None and (other := sensor_mismatch(cmap, press, undeformed)):
        raise CaptureError(other)
    sensor_note = None
    if check_sensor is False:  # the user's override: what it overrode goes in the report (and a warning)
        sensor_note = sensor_check_note(cmap, press) if modelled and cmap is not None else "off; not measured"
        if sensor_note.startswith(str(press.folder)):
            log.warning("%s", sensor_note)
    if model is not None and ref_capture is not None and light_gain is not None:
        model = model.with_gain(light_gain)  # the undeformed capture's brightness, as the press's
    if model is not None and model.enabled and coating_albedo is not None:
        model = model.with_reflectance(coating_albedo)
    elif coating_albedo is not None:  # nothing for it to scale: say so rather than drop the user's value
        why = model.reason if model is not None else "no interreflection term (a fixed light or no reference surface)"
        log.warning("%s: --coating-reflectance not used: %s", press.folder, why)
    t0 = time.perf_counter()
    # against a capture of the undeformed dome the model has no point-LED error to allow for at the edge
    bounced = model.undeformed_light_per_led(press.camera.shape) if model is not None and model.enabled else None
    edge_error = None
    if ref_capture is None:
        edge_error = functools.partial(point_led_misfit, press, leds, cmap, indirect_light=bounced)
    reference = ref_capture.folder if ref_capture is not None else None
    roi, roi_note = _region(press, roi, explicit_roi, cmap, reference, edge_error)
    if roi is not None:
        mask &= box_mask(roi, (H, W))
    weights, anchoring = (None, "anchoring off (no reference surface)")
    if cmap is not None:
        weights, anchoring = anchor_weights(cmap, mask, options.anchor_weight, tolerances.ANCHOR_NOISE_FACTOR)
    options, noise = _noise_regularised(options, press, cmap)
    t_contact = light.contact_seconds + time.perf_counter() - t0

    images = press.linear_led_images
    run = _Runner(press, leds, images, prior, weights, mask, options, backend, progress, fixed_light, disks)
    if model is not None and model.enabled:
        focus = dent_focus(cmap, mask) if cmap is not None and dent_interreflection else None
        loop = OuterLoop(model, press, term_leds, images, mask, light.shading, outer_relaxation, focus, term_radius)
        result = loop.run(run, max_outer if dent_interreflection else 0)
    else:
        loop, result = None, run(fixed_light)
    if prior is not None:  # the depth scale, which the data pull off the anchors (0.1-0.5 %), put back onto them
        result, scale = rescale_to_anchors(result, prior, weights)
        if scale is not None:
            anchoring += f"; the depth scaled by {scale:.5f} onto the reference there"
    rep = result.report
    rep["roi"] = list(roi) if roi is not None else None
    rep["roi_note"] = roi_note
    rep["prior"] = "reference" if prior is not None else "nominal_distance"
    rep["interreflection"] = model.to_json() if model is not None else None
    rep["indirect_compensation"] = bool(fixed_light is not None or (model is not None and model.enabled))
    _report_loop(rep, loop)
    rep["anchoring"] = anchoring
    rep["reference_gain"] = [float(g) for g in light_gain] if light_gain is not None else None
    if sensor_note is not None:
        rep["sensor_check"] = sensor_note
        if sensor_note.startswith(str(press.folder)):
            rep["warnings"] = [*rep.get("warnings", []), sensor_note]
    elif check_sensor is None:
        rep["sensor_check"] = "not made: the LED images show other LEDs' light (their warning)"
    rep["anchored_pixels"] = int((weights > 1).sum()) if weights is not None else 0
    rep["dead_leds_contact"] = list(cmap.dead_leds) if cmap is not None else []
    rep["contact_seconds"] = t_contact
    rep["image_noise"] = noise
    rep["smoothness"] = options.smoothness
    rep["indirect_seconds"] = light.indirect_seconds + (loop.seconds if loop is not None else 0.0)
    if linear_notes:
        rep["warnings"] = [*linear_notes, *rep.get("warnings", [])]
    if cmap is not None and (note := _resolution_warning(press, cmap, result)):
        log.warning("%s", note)
        rep["warnings"] = [*rep.get("warnings", []), note]
    if model is not None:
        log.info("%s: %s", press.folder, model.reason, extra=PRESS_DETAIL)
    log.info("%s: %s", press.folder, anchoring, extra=PRESS_DETAIL)
    return result


def _disk_leds(
    press: Press, leds: Leds, emitters: Sequence[Led | dict] | None, led_radius: float
) -> tuple[Leds, float] | None:
    """(the LEDs as disks, their radius) for the NLiPs solves, or None (point LEDs): see :func:`_solve_press`."""
    if not led_radius > 0:
        return None
    disks = tuple(leds if emitters is None else (e if isinstance(e, Led) else Led.from_dict(e) for e in emitters))
    if len(disks) != len(leds):
        raise CaptureError(f"{press.folder}: {len(disks)} disk LEDs (emitters) given for {len(leds)} LEDs")
    return disks, float(led_radius)


def _linearity_warnings(press: Press, model: IndirectModel | None, cmap: ContactMap | None) -> list[str]:
    """:func:`.led_checks.linearity_notes` of the live LEDs, each logged as a warning: against the direct light and
    the indirect light of the solve's fitted term (the check fits its own when the solve has none: the term off,
    or a fixed light). Made once the term is fitted, before NLiPs runs, so a solve that then fails has said it."""
    if cmap is None:  # no reference surface: nothing to model
        return []
    fitted = model is not None and model.fitted_light is not None
    indirect = model.undeformed_light_per_led(press.camera.shape) if fitted else None
    notes = linearity_notes(press, cmap.live_leds, indirect)
    for note in notes:
        log.warning("%s", note)
    return notes


def _resolution_warning(press: Press, cmap: ContactMap, result: SolveResult) -> str | None:
    """:func:`.resolution.resolution_note` of the solved contact (None: resolved, or no contact solved)."""
    steepness = contact_steepness(cmap, result.normals, press.reference.normals, result.reconstructed)
    return resolution_note(press.folder, *steepness) if steepness is not None else None


def _region(
    press: Press,
    roi: tuple[int, int, int, int] | str | None,
    explicit_roi: tuple[int, int, int, int] | None,
    cmap: ContactMap | None,
    reference: os.PathLike | None = None,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None = None,
):
    """The box to solve, (x0, y0, w, h) or None for the whole gel, and what ``--roi auto`` left out or warns
    about ("" when nothing). ``reference``: the folder of the undeformed capture ``cmap`` compares with;
    ``edge_model_error`` as :func:`.contact.contact_box`'s."""
    if roi is None and cmap is not None and (why := no_contact(cmap, model_error=edge_model_error)):
        reason, within_noise = why
        if within_noise:
            note = f"no contact found: the {reason}: the solved surface is the reference's up to noise"
        else:
            note = f"no contact found: {reason}"
        log.warning("%s: %s", press.folder, note)
        return None, note
    if roi != "auto":
        return explicit_roi, ""
    if cmap is None:
        raise CaptureError(f"{press.folder}: --roi auto needs the capture's reference (undeformed dome)")
    box, note, (wide, before, after) = _auto_box(press, cmap, reference, edge_model_error)
    if note:
        log.warning("%s: %s", press.folder, note)
    if wide != box:  # a deep press: the gel deforms well beyond the pixels that misfit most
        log.info(
            "%s: --roi auto widened its box from %s to %s: %.0f %% of it looked undeformed, too few to anchor the "
            "depth to the reference (now %.0f %%)",
            press.folder,
            list(box),
            list(wide),
            100 * before,
            100 * after,
        )
    return wide, note


def _auto_box(
    press: Press,
    cmap: ContactMap,
    reference: os.PathLike | None = None,
    edge_model_error: Callable[[np.ndarray], np.ndarray] | None = None,
) -> tuple[tuple[int, int, int, int], str, tuple[tuple[int, int, int, int], float, float]]:
    """``--roi auto``'s box, unsaid: (the contact's box, its note, :func:`.anchoring.widen_to_anchor`'s (the box
    solved, its undeformed share before and after)); arguments as :func:`_region`'s. CaptureError without a
    contact (:func:`.contact_roi.contact_box`'s refusal)."""
    shape = press.camera.shape
    box, note = contact_box(
        cmap, shape, folder=press.folder, reference=reference, edge_model_error=edge_model_error, flank=True
    )
    return box, note, widen_to_anchor(cmap, box, shape)


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
        disks: tuple[Leds, float] | None = None,
    ):
        # the NLiPs solves' LEDs: the disks (with their radius) where given, else the point LEDs
        self.solve_leds, self.led_radius = disks if disks is not None else (leds, 0.0)
        self.press, self.leds, self.images, self.prior, self.weights = press, leds, images, prior, weights
        self.mask, self.options, self.backend, self.progress = mask, options, backend, progress
        self.fixed_light = fixed_light
        self.saturated = _saturated_samples(press)
        self.boxed = BoxCompensation(images, mask)

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
            self.solve_leds,
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
            led_radius=self.led_radius,
            # a pass left unrefined on the whole mask: the last pass iterates its finest level (a focus pass's never)
            finest_later=receivers is None and unrefined > 0,
        )
        if receivers is None and not result.reconstructed.any():  # a focus pass is merged into the last result
            dead = [i + 1 for i in result.report["dead_leds"]]
            raise CaptureError(
                f"{self.press.folder}: no pixel could be reconstructed ({result.report['pixels_too_few_leds']} "
                f"pixels with fewer than {self.options.min_leds} usable LEDs; dead LEDs {dead})"
                + nothing_to_fit(self.press)  # black or saturated throughout: say so
            )
        return result


def _saturated_samples(press: Press) -> np.ndarray:
    """(L, H, W, 3) bool, read-only -- the samples a solve leaves out as saturated: the LED images' own
    (``press.saturated_led_images``) and, in every image, the dark frame's saturated pixels. Why not always their
    union: a dark frame without a saturated pixel (every capture that is not broken) added nothing but a second
    copy of the press's whole-frame flags (11 MB at 640x480 with 12 LEDs), held through every pass of the solve
    (benchmarks/RESULTS.md, s36-cubemem)."""
    dark = press.saturated(press.dark)
    if not dark.any():
        return press.saturated_led_images
    union = press.saturated_led_images | dark[None]
    union.setflags(write=False)
    return union


def _report_loop(rep: dict, loop: OuterLoop | None) -> None:
    """The outer interreflection loop's entries of a solve's report (``loop``: an :class:`OuterLoop` or None)."""
    rep["dent_interreflection"] = bool(loop is not None and loop.passes > 0)
    rep["outer_passes"] = loop.passes if loop is not None else 0
    rep["outer_changes_deg"] = loop.changes if loop is not None else []
    rep["outer_focus"] = box_of(loop.focus) if loop is not None and loop.focus is not None else None
    if loop is not None:  # the solver's timer over every NLiPs solve of the outer loop, and each one
        rep["seconds"], rep["pass_seconds"] = (
            float(sum(loop.solver_seconds)),
            [round(t, 3) for t in loop.solver_seconds],
        )


def _noise_regularised(options: SolverOptions, press: Press, cmap: ContactMap | None):
    """(options with the noise-adapted smoothness, relative noise level) -- see SolverOptions.noise_smoothness."""
    from .image_stats import image_noise

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


# inspect.signature(solve_press) shows _solve_press's keywords (the pipeline records them with their defaults)
solve_press.__wrapped__ = _solve_press
KEYWORDS = (*(name for name in inspect.signature(_solve_press).parameters if name != "press"), "leds_name")
""":func:`solve_press`'s keywords: :func:`_solve_press`'s and ``leds_name``."""
if solve_press.__doc__ and _solve_press.__doc__:  # None under python -OO
    # help(solve_press) (a notebook's Shift-Tab) describes them too: it said "see _solve_press", a private name
    solve_press.__doc__ += "\n" + _solve_press.__doc__[_solve_press.__doc__.index("    Parameters\n") :]
