"""LED self-calibration from captures of the undeformed dome (known geometry: Press.reference).

Per LED i, non-linear least squares (scipy.optimize.least_squares, robust loss) of
``I_ic(p) = K_ic * (n_s . d)^mu * max(0, (x_s - x) . n) / |x_s - x|^3`` over the reference's pixels,
with K_ic = rho_c Psi_ic. Parameters: log K_ic (3), mu, n_s (polar and azimuth angles), x_s (3).

Gauge (Psi and albedo are only known up to a common scale): the coating's albedo is taken uniform per
channel and the LED intensities are normalised so that **mean_i Psi_ic = 1 for every channel c**; the
common factor rho_c = mean_i K_ic is reported as ``albedo``. The solver recovers albedo relative to it.

What the user is told (``LedCalibration.warnings``, logged as warnings): a coating reflectance given but not
used, a fit that leaves more than the images' own noise
unexplained (:func:`fit_quality`), i.e. LEDs not to be trusted, and a capture with many saturated samples
(left out of the fit, :data:`nlipscalib.core.tolerances.SATURATED_SHARE_WARN`), and in a fit called reliable, a
single LED not to be trusted (:func:`.calibration_quality.single_led_warnings`).

This module is the entry (:func:`calibrate_leds`: the settings, the calibration and its reruns with one setting
changed, the warnings); each part lives in a file of its own:

- ``led_fit.py``: a capture's samples and the LED model's robust least squares (points or disks), in the gauge;
- ``calibration_term.py``: the interreflection term inside the calibration (its rounds with the LED fit, the auto
  decision, the reflectance profile);
- ``calibration_contact.py``: the contact checks of a capture (refused, or its contact left out);
- ``calibration_quality.py``: the fit's quality against the images' noise (:func:`fit_quality`) and its warning.
"""

from __future__ import annotations

import dataclasses
import logging
import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core import tolerances
from ..core.capture import Press, as_press
from ..core.compression import blockiness_line, compressed
from ..core.errors import NUMBER, CaptureError, ConfigError, check_flag, check_kind, check_whole
from ..core.leds import Led, Leds
from ..core.repeated_frames import dark_everywhere_line, dark_line, frame_checks
from ..core.tricolor_check import press_tricolor_note
from .calibration_bands import (
    NOTHING_TO_FIT,
    dark_notes,
    half_dark_bands,
    masked,
    without_dark_bands,
    without_lagged_bands,
    without_repeated_images,
)
from .calibration_contact import contact_notes, contact_refusal, contact_regions, led_cause
from .calibration_quality import fit_quality, quality_warning, single_led_warnings
from .calibration_term import (
    emitters_and_profile,
    indirect_rounds,
    no_interreflection,
    runoff_note,
    runoff_reflectance,
    term_gain,
    term_wins,
    unprofiled_note,
    unsettled_range,
    unused_reflectance,
)
from .exposure import nothing_to_fit, saturated_share, saturation_note
from .led_checks import image_names, linearity_notes
from .led_fit import LedFitRanOff, Samples, capture_samples, to_leds

if TYPE_CHECKING:  # named in hints only
    from pathlib import Path

    from ..core.led_exchange import PlaceExchanges


log = logging.getLogger(__name__)

__all__ = ["LedCalibration", "calibrate_leds", "fit_quality"]


@dataclasses.dataclass(frozen=True)
class LedCalibration:
    """Result of :func:`calibrate_leds`."""

    leds: tuple[Led, ...]
    """Calibrated LEDs (camera frame, mm), gauge mean Psi = 1 per channel."""
    albedo: tuple[float, float, float]
    """Uniform coating albedo per channel in the same gauge (image units)."""
    std: list[dict]
    """Per LED 1-sigma uncertainties from the Jacobian: intensity (3,), mu, direction_deg, position_mm (3,)."""
    rms: list[float]
    """Per LED RMS residual, linear image units."""
    interreflection: list = dataclasses.field(default_factory=list)
    """Per capture, the fitted indirect term (``IndirectModel.to_json()``) of the last round."""
    emitters: tuple[Led, ...] = ()
    """With ``led_radius``: each LED as the disk it emits from (centre, axis, mu, Psi in the same gauge),
    fitted with :func:`nlipscalib.core.leds.disk_shading`: the physical LEDs, to compare with the CAD.
    ``leds`` stay the point LEDs that best reproduce the images, which the solver's point model uses (for
    a 3.6 mm disk about 0.2 mm behind its centre). Empty without ``led_radius``."""
    led_radius: float = 0.0
    """The emitting disk's radius the emitters were fitted with, mm (0: none)."""
    reflectance_profile: dict | None = None
    """With ``led_radius`` and no known coating reflectance: how the reflectance was chosen
    (:func:`.calibration_term._profiled_reflectance`): the freely fitted one, the scales of it tried, their disk-fit
    residuals and the chosen reflectance. None otherwise."""
    quality: dict | None = None
    """:func:`fit_quality` of the point LEDs: each LED's residual against its images' noise, and whether the
    calibration is reliable."""
    warnings: tuple[str, ...] = ()
    """What the user must know (one line each; also logged): options given but not used, an unreliable fit, captures
    with many saturated samples."""
    saturated_share: tuple[float, ...] = ()
    """Per capture, the share of the gel's samples left out as saturated (:func:`.exposure.saturated_share`)."""
    contact_pixels: tuple[int, ...] = ()
    """With ``allow_contact``, per capture, the pixels left out of the fit as a contact (:func:`contact_regions`);
    empty when no capture showed one."""
    led_order: tuple[int, ...] | None = None
    """For each LED, the image (0-based, the capture's images.leds order) it was fitted to, when the images were out
    of order (:func:`_in_shown_order`); None: as captured."""
    contact_causes: tuple[str | None, ...] = ()
    """With ``allow_contact``, per capture, the words naming an LED near the gel as its misfit's cause
    (:func:`.calibration_contact.led_cause`), None where it is a press's (or none); what its warning says."""
    dark_bands: tuple = ()
    """Per capture, the LED images' dark bands left out of their LEDs' fits
    (:func:`.calibration_bands.without_dark_bands`, :class:`.repeated_frames.DarkBand`); empty when no capture had
    one."""
    not_fitted: tuple[int, ...] = ()
    """The LEDs (0-based) not fitted, kept at their starting values: their image repeats the one before it in every
    capture (:func:`.calibration_bands.without_repeated_images`); their ``std`` and ``rms`` NaN. Empty: all fitted."""

    def to_json(self) -> dict:
        out = {
            "gauge": "mean Psi = 1 per channel, uniform albedo",
            "albedo": list(self.albedo),
            "std": self.std,
            "rms": self.rms,
            "interreflection": self.interreflection,
            "quality": self.quality,
            "warnings": list(self.warnings),
            "saturated_share": list(self.saturated_share),
        }
        if self.emitters:
            out["emitters"] = {"radius_mm": self.led_radius, "leds": [led.to_dict() for led in self.emitters]}
        if self.reflectance_profile is not None:
            out["reflectance_profile"] = self.reflectance_profile
        if self.contact_pixels:
            out["contact_pixels"] = list(self.contact_pixels)
        if self.led_order is not None:
            out["led_order"] = list(self.led_order)
        if self.not_fitted:
            out["not_fitted"] = list(self.not_fitted)
        return out


PRESSES_KIND = "an undeformed capture (a Press or its folder's path, str or Path), or a list of them"
"""What :func:`calibrate_leds`' ``presses`` must be, as its kind check says it."""
FIT_PIXELS = 76_800
"""Pixels of the frame that :func:`default_stride` keeps for the LED fit: a 640x480 capture at stride 2. Why: a
larger camera's fit at stride 2 costs the frame's pixels and gains nothing. Measured at 1280x960 (one bounce, 2 spp,
load 4-5 on the shared 2-core VM): stride 2 took 159 s of wall and 91 s of CPU, stride 4 32 s and 23 s, and their
LEDs lie alike off the truth (median position 0.212 / 0.211 mm, axis 1.11 / 1.10 deg; the 640x480 capture's at
stride 2: 0.215 mm, 1.09 deg; benchmarks/RESULTS.md, s24-hires)."""


def default_stride(shape: tuple[int, int]) -> int:
    """Stride, pixels, of the LED fit on frames of ``shape`` = (H, W): 2 up to 640x480 (and a few pixels more),
    else about the one that keeps :data:`FIT_PIXELS` of the frame (1280x720: 3, 1280x960: 4, 1920x1080: 5)."""
    H, W = shape
    return max(2, round(np.sqrt(H * W / FIT_PIXELS)))


def _check_arguments(
    initial: object, stride: object, led_radius: object, rounds: object, allow_contact: object, reorder_leds: object
) -> None:
    """An NlipsError naming the argument of :func:`calibrate_leds` of another kind or out of range, before any
    capture is loaded.

    Why: ``led_radius=-1`` was refused as "the LED disk radius" after the captures were loaded and checked,
    ``stride=2.5`` or ``initial=[1, 2]`` failed deep inside the fit, ``allow_contact="no"`` allowed it
    (s38-apikinds)."""
    check_kind(led_radius, NUMBER, "led_radius", "a number of mm (0: point LEDs)")
    if not (np.isfinite(led_radius) and led_radius >= 0):
        raise ConfigError(f"led_radius must be a finite radius >= 0 mm (0: point LEDs), got {led_radius}")
    if stride is not None:
        check_whole(stride, "stride", minimum=1)
    check_whole(rounds, "rounds", minimum=0)
    check_flag(allow_contact, "allow_contact")
    check_flag(reorder_leds, "reorder_leds")
    if initial is not None and not (isinstance(initial, Sequence) and all(isinstance(led, Led) for led in initial)):
        check_kind(initial, (), "initial", "a sequence of Led (starting values), or None (the capture's LEDs)")


def calibrate_leds(
    presses: Press | str | os.PathLike | Sequence[Press | str | os.PathLike],
    initial: Leds | None = None,
    stride: int | None = None,
    loss: str = "cauchy",
    *,
    interreflection: str = "auto",
    bounces: int = 1,
    rounds: int = 3,
    led_radius: float = 0.0,
    coating_reflectance: float | tuple[float, float, float] | None = None,
    allow_contact: bool = False,
    reorder_leds: bool = True,
) -> LedCalibration:
    """Estimate Psi_c, mu, n_s and x_s of every LED from undeformed captures.

    With interreflection (any real sensor) the images hold more than the direct model: the LEDs are
    fitted, the indirect term (:func:`nlipscalib.solver.indirect.fit_indirect`, radiosity gather on the
    known undeformed surface, coating reflectance fitted) is computed with them, subtracted, and the
    LEDs fitted again from where they are, ``rounds`` times.

    Parameters
    ----------
    presses : Press or sequence of Press -- undeformed dome, with ``reference``; same camera and LEDs (a press
        folder's path, str or Path, is loaded with all its LEDs: :func:`.as_press`).
    initial : sequence of Led or None -- starting values (default: the capture's LEDs).
    stride : use every ``stride``-th pixel in u and v (speed); None: :func:`default_stride` of the captures' frame.
    loss : scipy robust loss ("cauchy", "soft_l1", "huber", "linear").
    interreflection : "auto" (subtract the indirect term when the data show it: its share with the starting LEDs
        turns it on, and it is kept when, converged, it explains the images better than direct light alone,
        :func:`term_gain`), "on", "off".
    bounces : diffuse bounces of the indirect term (1 or 2).
    rounds : LED fit / indirect term alternations (with the term on).
    led_radius : radius of each LED's emitting disk, mm (a WS2812B's light cup: 1.8); > 0 adds a last
        fit of the LEDs as disks (``LedCalibration.emitters``) from the point LEDs, to the same images
        minus the same indirect light. On the twin's bounce-free 3.6 mm disk LEDs the disks come out
        within 0.02 deg and 0.005 mm of the truth, where the best points sit 0.24 mm behind
        (benchmarks/RESULTS.md).
    coating_reflectance : the coating's reflectance (0-1], one value or per channel, when it is known
        (measured, or from the coating's datasheet) instead of fitted. Why it matters: a ring-wide tilt of
        the LED axes and the indirect term's magnitude explain the images almost alike; on the twin the
        fitted reflectance comes out 0.89 for a true 0.8 and the axes ~2 deg too upright, with the true
        reflectance ~1 deg (benchmarks/RESULTS.md). Unknown, with ``led_radius`` and the indirect term on,
        it is profiled instead (:func:`.calibration_term._profiled_reflectance`): the reflectance whose disk fit leaves
        the least residual, then the whole calibration again with it. Not used when no capture's indirect term
        is on (``interreflection`` "off", or "auto" on a capture without interreflection): a warning says so.
    allow_contact : a capture that shows a contact (a press, :func:`contact_regions`) is refused (CaptureError)
        unless this is set; then its contact's pixels are left out of the LED fit and of the indirect term's, with
        a warning.
    reorder_leds : LED images out of order (a wiring error: a clean pair or cycle,
        :func:`.led_checks.detected_order`) are fitted in the order they show, with a warning and the file's
        ``led_order``; False (``--keep-led-order``): as captured (each LED then fitted where its image's light comes
        from, with no word but the warning).

    Returns
    -------
    LedCalibration -- with ``quality`` (:func:`fit_quality`) and ``warnings``, each also logged as a warning:
    a ``coating_reflectance`` not used, an unreliable fit, a contact left out (LED disks whose reflectance could not
    be profiled: an INFO line).
    """
    one = isinstance(presses, (Press, str, os.PathLike))
    check_kind(presses, (Press, str, os.PathLike, list, tuple), "presses", PRESSES_KIND)
    _check_arguments(initial, stride, led_radius, rounds, allow_contact, reorder_leds)
    presses = [as_press(p, "presses") for p in ([presses] if one else list(presses))]
    if not presses:
        raise CaptureError("calibrate_leds needs at least one capture")
    presses, order_notes, order = _in_shown_order(presses, initial, reorder_leds)
    _check_one_order(presses)  # captures in different LED orders: no joint fit means anything
    # a stale frame (an LED image repeating the one before it): out of that LED's fit, its LED held where no capture
    # holds its light
    presses, repeated_notes, held = without_repeated_images(presses)
    presses, lagged_notes = without_lagged_bands(presses)  # read across the LED switch: that band out of its LED's fit
    if stride is None:
        stride = default_stride(presses[0].camera.shape)
    settings = _Settings(
        initial, stride, loss, interreflection, bounces, rounds, led_radius, coating_reflectance, allow_contact
    )
    try:
        cal = _with_term_if_needed(_calibrate(presses, settings), presses, settings)
        cal = _without_half_dark(cal, presses, settings)
    except LedFitRanOff as error:
        raise CaptureError(ran_off_line(presses, error.led, settings.initial)) from None
    _check_finite(cal, presses[0].folder)
    # two neighbours' images exchanged: fitted each where its image shows it, unseen by the images' own check
    exchange_notes, exchanged = _exchanged_images(presses, cal.leds, initial, held, reorder_leds)
    shares = [saturated_share(p) for p in presses]  # first: a likely cause of the warnings after it
    notes = order_notes + exchange_notes + repeated_notes + lagged_notes + dark_notes(presses, cal.dark_bands)
    notes += [n for p, share in zip(presses, shares) if (n := saturation_note(p, share, "the LED fit"))]
    # the tri-colour frame against the LED images (a pair of two colour groups exchanged spoils every LED's fit):
    # not said again of LEDs the exchange check above names
    notes += [n for p in presses if (n := press_tricolor_note(p, exchanged))]
    notes += contact_notes(presses, cal.contact_pixels, cal.contact_causes)
    notes += unused_reflectance(cal.interreflection, interreflection, coating_reflectance)
    if note := unprofiled_note(cal.interreflection, interreflection, led_radius, coating_reflectance):
        log.info(note)
    notes += runoff_note(cal.interreflection)
    notes += quality_warning(cal.quality, cal.interreflection, interreflection)
    notes += single_led_warnings(cal.quality, cal.leds)
    for note in notes:
        log.warning(note)
    shares = tuple(round(v, 4) for v in shares)
    return dataclasses.replace(cal, warnings=tuple(notes), saturated_share=shares, led_order=order, not_fitted=held)


def _without_half_dark(cal: LedCalibration, presses: list[Press], s: _Settings) -> LedCalibration:
    """``cal``, or, when a capture's LED image is dark over more than half against its LEDs
    (:func:`.calibration_bands.half_dark_bands`), the calibration again with those bands left out of their LEDs' fits
    as the other dark bands are (:func:`.calibration_bands.masked`: refused when a band leaves an LED under
    ``tolerances.CALIBRATION_MIN_LED_KEPT`` of the gel), its ``dark_bands`` holding them (the warning names them)."""
    known = cal.dark_bands or ((),) * len(presses)
    half = half_dark_bands(presses, cal.leds, known)
    if not any(half):
        return cal
    found = tuple((*k, *h) for k, h in zip(known, half))
    names = [image_names(p) for p in presses]
    masked_presses = [
        masked(p, list(bands), dark_line(p.folder, n, list(bands))) if bands else p
        for p, bands, n in zip(presses, found, names)
    ]
    s = dataclasses.replace(s, dark_bands=found)
    again = _with_term_if_needed(_calibrate(masked_presses, s), masked_presses, s)
    return dataclasses.replace(again, dark_bands=found)


def _in_shown_order(
    presses: list[Press], initial: Leds | None, reorder: bool
) -> tuple[list[Press], list[str], tuple[int, ...] | None]:
    """The captures with their LED images in the order they show (:func:`.led_checks.detected_order`, against
    ``initial`` or each capture's LEDs) when ``reorder``; the warnings (one per capture out of order), and the order
    applied (None: none). Why: the captures of the undeformed dome of a session with a wiring error show the same
    swap as its presses; fitted as captured, LED 3 is moved to LED 7's place (s26-degen: "reliable"), a file that
    then describes the wiring, not the sensor. A capture whose check finds no clear order is kept as it is (its
    own warning says what it found, as a solve's does)."""
    from .image_stats import led_levels, lit_leds
    from .led_checks import detected_order_of, reorder_note, reordered

    out, notes, applied = [], [], None
    for p in presses:
        if p.reference is None:  # refused further on, naming reference.npz
            out.append(p)
            continue
        leds = tuple(initial) if initial is not None else p.leds
        live = np.flatnonzero(lit_leds(led_levels(p.linear_led_images, np.isfinite(p.reference.depth))))
        order = detected_order_of(p, leds, live)
        if order is not None and reorder:
            notes.append(reorder_note(p, order, "--keep-led-order", fit=True))
            p, applied = reordered(p, order), tuple(order)
        elif order is not None:
            notes.append(f"{p.folder}: the LED images are out of order, fitted as captured (--keep-led-order)")
        out.append(p)
    return out, notes, applied


EXCHANGE_REFUSED = (
    "; not calibrated: put the images in the LEDs' order (their files, or images.leds in meta.json) and run again, or "
    "pass --keep-led-order to calibrate each LED where its image shows it (right only for captures taken in this order)"
)
"""The tail of the LED calibration's refusal of LED images captured in each other's place (:func:`_exchanged_images`).

Why refused, not written with a warning: the file would place each of those LEDs at the other's place, and every solve
with it takes them so without a word (a solve cannot tell two neighbours' images apart either); a warning scrolls by in
a script, the refusal costs one run again."""
EXCHANGE_KEPT = (
    "; calibrated as captured (--keep-led-order): each LED where its image shows it, right only for captures taken in "
    "this order"
)
"""The tail of the warning of :func:`_exchanged_images` with ``--keep-led-order``."""


def _exchanged_images(
    presses: Sequence[Press], leds: Leds, initial: Leds | None, held: Sequence[int], reorder: bool
) -> tuple[list[str], set[int]]:
    """The warning (``reorder`` False: ``--keep-led-order``) naming LED images captured in each other's place, told by
    the fitted ``leds`` against the design's (``initial``, else the capture's meta.json LEDs:
    :func:`nlipscalib.core.led_exchange.place_exchanges`; ``held``: LEDs not fitted); [] when none; and the LEDs
    (0-based) it names. CaptureError with that line when ``reorder`` (the default): :data:`EXCHANGE_REFUSED` says
    why."""
    from ..core.led_exchange import place_exchanges
    from ..core.leds import led_arrays

    design = led_arrays(tuple(initial) if initial is not None else presses[0].leds)[0]
    found = place_exchanges(design, led_arrays(leds)[0], tuple(held))
    notes = [_doubtful_line(presses, found, design)] if found.doubtful else []
    if not found.cycles:
        return notes, set()
    folders = ", ".join(str(p.folder) for p in presses)
    parts = [f"{_said(presses[0], cycle)} look exchanged ({_where(found, design, cycle)})" for cycle in found.cycles]
    line = (
        f"{folders}: {'; '.join(parts)}: their images were captured in each other's place (the LED wiring, the "
        "controller's LED order or the images' order)"
    )
    if reorder:
        raise CaptureError(line + EXCHANGE_REFUSED)
    return [line + EXCHANGE_KEPT, *notes], {int(i) for cycle in found.cycles for i in cycle}


def _said(press: Press, cycle: Sequence[int]) -> str:
    """The images of the LEDs ``cycle`` (0-based), named: "led_03.png and led_04.png", or "..., ... and ... (a
    cycle)"."""
    files = [image_names(press)[i] for i in cycle]
    return " and ".join(files) if len(files) == 2 else ", ".join(files[:-1]) + f" and {files[-1]} (a cycle)"


def _where(found: PlaceExchanges, design: np.ndarray, cycle: Sequence[int]) -> str:
    """Where each LED of ``cycle`` was fitted against the design's places (``found``:
    :class:`nlipscalib.core.led_exchange.PlaceExchanges`; ``design`` (L, 3) mm), and the other LEDs' scatter."""
    places = []
    for k, i in enumerate(cycle):
        j = cycle[(k + 1) % len(cycle)]
        near, own = (np.linalg.norm(found.aligned[i] - design[m]) for m in (j, i))
        places.append(f"LED {i + 1} {near:.2f} mm from LED {j + 1}'s design place and {own:.2f} mm from its own")
    return f"fitted {', '.join(places)}{_scatter_said(found.scatter)}"


DOUBTFUL_EXCHANGE = (
    ": not refused, as the other LEDs scatter too far about their design places to tell an exchange from the fit's "
    "error (LEDs designed this close); if the LED wiring, the controller's LED order or the images' order may differ "
    "from the design, light each of these LEDs alone and see which image shows it"
)
"""The tail of the warning of :func:`_exchanged_images` naming a doubtful exchange
(:class:`nlipscalib.core.led_exchange.PlaceExchanges` ``doubtful``): warned, not refused, since the fit itself may have
put them so."""


def _doubtful_line(presses: Sequence[Press], found: PlaceExchanges, design: np.ndarray) -> str:
    """The warning naming ``found.doubtful``'s cycles: LEDs fitted each 3 times nearer another's design place than
    their own, by less than the calibration's scatter lets be told (:data:`DOUBTFUL_EXCHANGE`)."""
    folders = ", ".join(str(p.folder) for p in presses)
    parts = [f"{_said(presses[0], c)} may be exchanged ({_where(found, design, c)})" for c in found.doubtful]
    return f"{folders}: {'; '.join(parts)}{DOUBTFUL_EXCHANGE}"


def _scatter_said(scatter: float) -> str:
    """The clause of :func:`_exchanged_images`' line saying how far the other LEDs sit from their places (``scatter``,
    mm, :class:`nlipscalib.core.led_exchange.PlaceExchanges`): what the exchanged ones stand out against; "" when no
    other LED was fitted."""
    if not np.isfinite(scatter):
        return ""
    return f"; the other LEDs {scatter:.2f} mm from theirs, median; all LEDs' common shift, turn and scale taken out"


CHECK_ORDER_STEP = 4
"""Every this-many-th gel pixel the captures' LED images are correlated on (:func:`_check_one_order`): 4,800 at
160x120 (the twin's seeds: 0.9987 and more for one LED's images, 0.83 at most for neighbours'), ~60,000 at
640x480."""


def _check_one_order(presses: Sequence[Press]) -> None:
    """CaptureError (one line naming the captures and images) when a capture's LED images hold the light of other LEDs'
    images of the first capture (:func:`nlipscalib.core.led_exchange.exchanged_images`): the same sensor captured in
    another LED order. Why before the fit: calibrated together, led_03.png and led_04.png exchanged in one of two
    captures pulled LEDs 3 and 4 halfway and were refused as a contact naming LED 4's mounting (s33-ledswap)."""
    from ..core.led_exchange import exchanged_images

    first = presses[0]
    for p in presses[1:]:
        if first.reference is None or p.reference is None or p.camera.shape != first.camera.shape:
            continue  # refused further on (no reference.npz, another sensor)
        if len(p.leds) != len(first.leds):
            continue
        gel = np.isfinite(first.reference.depth) & np.isfinite(p.reference.depth)
        pick = np.flatnonzero(gel.ravel())[::CHECK_ORDER_STEP]
        cycles = exchanged_images(_gel_images(first, pick), _gel_images(p, pick))
        if not cycles:
            continue
        names, theirs = image_names(p), image_names(first)
        said = "; ".join(
            f"{' and '.join(names[i] for i in cycle)} hold the light {first.folder}'s "
            f"{' and '.join(theirs[cycle[(k + 1) % len(cycle)]] for k in range(len(cycle)))} hold"
            for cycle in cycles
        )
        raise CaptureError(
            f"{p.folder}: {said}: the captures' LED images are in different orders (the LED wiring, the controller's "
            "LED order or the images' order changed between them); not calibrated: calibrate each capture alone (it "
            "names images exchanged against the design), put the odd one's images in order, then calibrate them "
            "together"
        )


def _gel_images(press: Press, pick: np.ndarray) -> np.ndarray:
    """(L, len(pick)) float -- the capture's linear LED images at the flat pixel indices ``pick``, channels' mean."""
    return press.linear_led_images.reshape(len(press.leds), -1, 3)[:, pick].mean(-1)


def _check_finite(cal: LedCalibration, folder: Path) -> None:
    """CaptureError naming the capture when a fitted LED is not finite (the fit ran off): never written."""
    for i, led in enumerate(cal.leds + tuple(cal.emitters or ())):
        values = [*led.position, *led.direction, led.mu, *led.intensity]
        if not np.all(np.isfinite(values)):
            raise CaptureError(f"{folder}: the fit of LED {i % len(cal.leds) + 1} did not converge (not finite)")


def ran_off_line(presses: Sequence[Press], led: int, initial: Leds | None = None) -> str:
    """One line for an LED fit that ran off (:class:`.led_fit.LedFitRanOff`, ``led`` 0-based): a capture's LED
    images' dark bands over more than half an image (:func:`.calibration_bands.half_dark_line`, against the starting
    LEDs ``initial``, else the capture's own) when one has some, else the captures, the LED and its image, the likely
    causes and what to do (the fit's own error named neither)."""
    from .calibration_bands import half_dark_line
    from .led_checks import image_names

    for p in presses:
        if line := half_dark_line(p, tuple(initial) if initial is not None else p.leds):
            return line
    folders = ", ".join(str(p.folder) for p in presses)
    name = image_names(presses[0])[led]
    return (
        f"{folders}: the fit of LED {led + 1} ({name}) ran off (its brightness or place left finite numbers): its "
        "image does not hold its light where an LED can give it: likely a dark band over much of it (rows read while "
        "the LED was off), the LED dead or very dim, or the LED far from the place the capture's meta.json gives it; "
        f"compare {name} with the other LED images, then fix the LED or capture the undeformed dome again (with "
        "--flush 1 or more)"
    )


@dataclasses.dataclass(frozen=True)
class _Settings:
    """What :func:`calibrate_leds` was asked (its arguments but the captures): one bundle for the steps that run the
    calibration again with one of them changed (``dataclasses.replace``)."""

    initial: Leds | None
    stride: int
    loss: str
    interreflection: str
    bounces: int
    rounds: int
    led_radius: float
    coating_reflectance: float | tuple[float, float, float] | None
    allow_contact: bool = False
    left_out: tuple[np.ndarray, ...] | None = None
    """Per capture, (H, W) bool: its pixels left out of the fit (a contact, with ``allow_contact``); None: not
    looked for yet (:func:`contact_regions`, after the first fit)."""
    dark_bands: tuple | None = None
    """Per capture, its LED images' dark bands, marked unusable in the captures
    (:func:`.calibration_bands.without_dark_bands`, after the first fit); None: not looked for yet."""


def _calibrate(presses: Sequence[Press], s: _Settings) -> LedCalibration:
    """:func:`calibrate_leds` without its warnings (it calls itself once more after a reflectance profile, and after
    a contact found with ``allow_contact``)."""
    first = presses[0]
    leds0 = tuple(s.initial) if s.initial is not None else first.leds
    left_out = s.left_out or (None,) * len(presses)
    data = [capture_samples(p, first, len(leds0), s.stride, out) for p, out in zip(presses, left_out)]
    _check_calibration_inputs(presses, data, s.stride, s.led_radius, s.coating_reflectance)
    samples = Samples(
        x=np.concatenate([d[0] for d in data]),
        n=np.concatenate([d[1] for d in data]),
        img=np.concatenate([d[2] for d in data], axis=1),
        ok=np.concatenate([d[3] for d in data], axis=1),
        selections=[d[4] for d in data],
    )
    trace: list[float] = []
    args = (presses, samples, leds0, s.loss, s.interreflection, s.bounces, s.rounds, s.coating_reflectance, left_out)
    fitted, direct, models = indirect_rounds(*args, trace, settle=True)  # a set reflectance: from far off, to settle
    if s.left_out is None and s.dark_bands is None:  # rows read while an LED was off: out of its fit, fitted again
        # (before the run-off check: the dark rows' misfit ran the free reflectance off, 0.70 -> 0.39)
        masked, found = without_dark_bands(presses, to_leds(fitted)[0])
        if any(found):
            again = _calibrate(masked, dataclasses.replace(s, dark_bands=found))
            return dataclasses.replace(again, dark_bands=found)
    # before the contact check: a run-off, or a term held low by LEDs far from their start, misfits as a press
    if s.coating_reflectance is None and (bounds := unsettled_range(trace)) is not None:
        return _after_runoff(presses, samples, leds0, s, left_out, trace, bounds)
    if s.left_out is None:  # once per calibration: the reruns below keep the verdict
        s = dataclasses.replace(s, left_out=contact_regions(presses, to_leds(fitted)[0], models))
        if any(region.any() for region in s.left_out):
            if not s.allow_contact:
                leds, albedo = to_leds(fitted)[:2]
                raise CaptureError(contact_refusal(presses, s.left_out, leds, albedo, models, leds0))
            leds, albedo = to_leds(fitted)[:2]
            causes = tuple(
                led_cause(p, r, leds, albedo, m, leds0) if r.any() else None
                for p, r, m in zip(presses, s.left_out, models)
            )
            again = _calibrate(presses, s)  # the same fit without the contact's pixels
            pixels = tuple(int(r.sum()) for r in s.left_out)
            return dataclasses.replace(again, contact_pixels=pixels, contact_causes=causes)
    models = [m.to_json() for m in models]
    quality = fit_quality(presses, fitted, samples.x, samples.n, direct, samples.ok)
    if s.interreflection == "auto" and any(m["enabled"] for m in models):  # on by the share with the starting LEDs
        gain = term_gain(samples, fitted, direct, s.loss, quality)
        if gain <= tolerances.CALIBRATION_MIN_TERM_GAIN:
            return _direct_after_all(presses, s, models, gain)
        note = (
            f"; kept: against the direct-only fit it lowers the LED fits' squared residual by {gain:.0f} noise "
            f"variances (more than {tolerances.CALIBRATION_MIN_TERM_GAIN:g})"
        )
        models = [dict(m, term_gain=round(gain, 1), reason=m["reason"] + note) for m in models]
    leds, albedo, std = to_leds(fitted)
    emitters, profile = emitters_and_profile(leds, samples, direct, s.loss, s.led_radius, s.coating_reflectance, models)
    if profile is not None:  # the whole calibration again with the profiled reflectance
        again = _calibrate(presses, dataclasses.replace(s, initial=leds, coating_reflectance=tuple(profile["chosen"])))
        return _with_profile(again, profile)
    rms = [f[2] for f in fitted]
    return LedCalibration(leds, albedo, std, rms, models, emitters, float(s.led_radius), quality=quality)


def _after_runoff(
    presses: Sequence[Press],
    samples: Samples,
    leds0: Leds,
    s: _Settings,
    left_out: Sequence,
    trace: list[float],
    bounds: tuple[float, float],
) -> LedCalibration:
    """The calibration with the coating reflectance set to :func:`.calibration_term.runoff_reflectance`'s choice
    within ``bounds`` (:func:`.calibration_term.unsettled_range`), after the free one ran off or was still rising over
    the rounds (``trace``); the terms carry ``reflectance_runoff`` (the rounds' values and the choice), which
    :func:`calibrate_leds` warns about."""
    args = (presses, samples, leds0, s.loss, s.interreflection, s.bounces, s.rounds, left_out, bounds)
    chosen = runoff_reflectance(*args)
    log.info(
        "the free coating reflectance did not settle over the rounds (%s); chosen %.3f",
        ", ".join(f"{v:.3f}" for v in trace),
        chosen,
    )
    again = _calibrate(presses, dataclasses.replace(s, initial=leds0, coating_reflectance=chosen))
    if not any(m.get("enabled") for m in again.interreflection):  # "auto" dropped the term there: nothing was set
        return again
    run = {"rounds": [round(v, 4) for v in trace], "chosen": round(chosen, 4)}
    return dataclasses.replace(again, interreflection=[dict(m, reflectance_runoff=run) for m in again.interreflection])


def _with_profile(again: LedCalibration, profile: dict) -> LedCalibration:
    """The calibration rerun with the profiled reflectance (``profile``:
    :func:`.calibration_term._profiled_reflectance`), carrying the profile while its term is on. With "auto" the rerun
    checks the term again (:func:`term_gain`, now at the profiled reflectance); when that drops it, the result is
    direct-only LEDs, which a reflectance scales nothing of: the profile is not attached (it read as the reflectance the
    LEDs were fitted with), and the terms' ``reason`` says what it chose."""
    if any(m.get("enabled") for m in again.interreflection):
        return dataclasses.replace(again, reflectance_profile=profile)
    chosen = np.round(profile["chosen"], 3).tolist()
    note = f"; the reflectance profile had chosen {chosen}, with which the term was then not used"
    models = [dict(m, reason=m["reason"] + note) for m in again.interreflection]
    return dataclasses.replace(again, interreflection=models)


def _check_calibration_inputs(
    presses: Sequence[Press],
    data: Sequence[tuple],
    stride: int,
    led_radius: float,
    coating_reflectance: float | tuple[float, float, float] | None,
) -> None:
    """CaptureError or ConfigError before any fit: a capture with nothing to fit, a stride that leaves too few
    samples (``data``: each capture's :func:`capture_samples`), a negative LED disk radius, a coating reflectance out of
    range."""
    from .indirect import checked_reflectance

    # black or saturated throughout: said here, not as a fit that fails further on. Asked of every capture, not
    # only after a failure: a black capture's noise is fitted without failing, or ends on "led.intensity must be
    # 3 finite numbers" (~40 ms per 640x480 capture; its linear images are the ones capture_samples made)
    for p in presses:
        if why := nothing_to_fit(p):
            raise CaptureError(NOTHING_TO_FIT.format(folder=p.folder, why=why))
        _check_lit(p)
    used = sum(len(d[0]) for d in data)
    if used < tolerances.CALIBRATION_MIN_PIXELS:
        raise ConfigError(
            f"{presses[0].folder}: stride {stride} leaves {used} pixels of the gel; the LED fit needs at least "
            f"{tolerances.CALIBRATION_MIN_PIXELS}: use a smaller stride"
        )
    if coating_reflectance is not None:
        checked_reflectance(coating_reflectance)  # before any fit


def _with_term_if_needed(cal: LedCalibration, presses: Sequence[Press], s: _Settings) -> LedCalibration:
    """``cal``, or the calibration with the indirect term on when "auto" left it off and that fit did not explain
    the images (:func:`fit_quality` unreliable) while the term makes it reliable.

    Why: the share decision (:data:`tolerances.CALIBRATION_MIN_SHARE`, with the starting LEDs) cannot tell a weakly
    interreflecting dome from starting LEDs a few % off. A direct-only fit that leaves more than the noise
    settles it: measured on the oblate twin (one bounce, 16 spp, 160x120; share 0.088 with the starting LEDs)
    direct-only 1.23x the noise with its worst LED 16 deg off, with the term 1.06x and 2.8 deg. Not tried where
    the direct-only fit is reliable: on a bounce-free capture the term fits as well (1.04x) but is wrong (16 deg),
    so a reliable direct fit keeps priority. A ``coating_reflectance`` given then applies (the term is on).

    Tried whatever the share with the starting LEDs (no gate on it): that share is the start's, not the images'
    (the bounce-free twin at 160x120: 0.014 from its true LEDs, 0.04-0.08 from LEDs 0.3-0.5 mm / 5 deg off, on
    either side of :data:`tolerances.INDIRECT_MIN_SHARE`; after a direct-only fit 0.000, and 0.004 on the oblate
    twin, so no share tells them apart), while both fits compared here converge from either start. The try is
    the point LEDs' (no disks, no reflectance profile: 50 s on that twin where the profile took ~110 s); only when
    the term wins there is the whole calibration with it run and compared. A term not used says why in its
    ``reason``."""
    if s.interreflection != "auto" or cal.quality["reliable"]:
        return cal
    if no_interreflection(cal.interreflection, "auto") is None:
        return cal
    if any("term_gain" in m for m in cal.interreflection):  # the term was fitted and compared already (term_gain)
        return cal
    on = _calibrate(presses, dataclasses.replace(s, interreflection="on", led_radius=0.0))
    if term_wins(cal, on) and s.led_radius > 0:
        on = _calibrate(presses, dataclasses.replace(s, interreflection="on"))
    if not term_wins(cal, on):
        note = f"; tried on: {on.quality['median_ratio']:.2f}x the noise against {cal.quality['median_ratio']:.2f}x"
        models = [dict(m, reason=m["reason"] + note) for m in cal.interreflection]
        return dataclasses.replace(cal, interreflection=models)
    log.info(
        "interreflection term used after all: the direct-only fit left %.2fx the images' noise, with the term %.2fx",
        cal.quality["median_ratio"],
        on.quality["median_ratio"],
    )
    why = " (used: the direct-only fit did not explain the images)"
    models = [dict(m, reason=m["reason"].replace(" (forced on)", why)) for m in on.interreflection]
    return dataclasses.replace(on, interreflection=models)


def _direct_after_all(presses: Sequence[Press], s: _Settings, models: list[dict], gain: float) -> LedCalibration:
    """The direct-only calibration (``s`` with ``interreflection="off"``, disks with its ``led_radius``) after "auto"
    turned the indirect term on (``models``, JSON) and it gained ``gain`` noise variances, at most
    :data:`tolerances.CALIBRATION_MIN_TERM_GAIN`: the terms are reported off, with why."""
    log.info("interreflection term not used after all: it lowered the LED fits' residual by %.0f noise variances", gain)
    note = (
        f"; not used after all: against the direct-only fit it lowered the LED fits' squared residual by {gain:.0f} "
        f"noise variances (negative: raised it), at most {tolerances.CALIBRATION_MIN_TERM_GAIN:g}"
    )
    off = [m["reason"].replace("interreflection on:", "interreflection off:") + note for m in models]
    cal = _calibrate(presses, dataclasses.replace(s, interreflection="off", coating_reflectance=None))
    terms = [dict(m, enabled=False, term_gain=round(gain, 1), reason=r) for m, r in zip(models, off)]
    return dataclasses.replace(cal, interreflection=terms)


def _check_lit(press: Press) -> None:
    """CaptureError, in one line naming the file, for a capture whose dark frame holds light or one of whose LED
    images is dark (a dead LED: no light to fit it on). Why: the LED fit of a dead LED diverged, ending on
    numpy's "Mean of empty slice" and "led.intensity must be 3 finite numbers, got (inf, inf, inf)"; an LED image
    saved as the dark frame ran past 200 s (s26 QA walk on the twin's 640x480 reference). Also for rows dark in
    every LED image (an LED image that repeats the one before it is left out of its LED's fit before:
    :func:`.calibration_bands.without_repeated_images`). Gamma-encoded LED images are warned
    about (:func:`.led_checks.linearity_notes`): the fit absorbed an sRGB curve and called itself reliable; so are
    JPEG-compressed ones (:mod:`nlipscalib.core.compression`)."""
    from .exposure import dark_file, dark_frame_fault, expected_light_of, gel_of
    from .image_stats import led_levels, lit_leds

    gel = gel_of(press)
    if (fault := dark_frame_fault(press, gel)) and fault[1]:
        raise CaptureError(fault[0])
    dead = np.flatnonzero(~lit_leds(led_levels(press.linear_led_images, gel)))
    if dead.size:
        names = (press.meta.get("images") or {}).get("leds") or []
        said = ", ".join(f"LED {i + 1}" + (f" ({names[i]})" if len(names) == len(press.leds) else "") for i in dead)
        raise CaptureError(
            f"{press.folder}: {said}: image dark (no light above the dark frame {dark_file(press)}'s noise: dead "
            f"LED?); the LED calibration needs every LED lit: fix the LED and capture again"
        )
    # a repeated image is left out by calibration_bands, before the fit: only the dark rows matter here
    dark = frame_checks(press.linear_led_images, gel, expected_light_of(press))[2]
    if dark is not None:
        # rows at the dark frame's level in every image: each LED would be fitted to light it never gave
        line = dark_everywhere_line(press.folder, dark)
        raise CaptureError(f"{line}; the LED calibration needs each LED's light over the whole gel")
    if (value := compressed(press.led_images, gel)) is not None:
        log.warning("%s", blockiness_line(press.folder, "the LED images", value))
    if press.reference is not None:
        # a tone curve is absorbed by the fit (LEDs moved, "reliable"): said against the recorded LEDs, before it
        for note in linearity_notes(press, range(len(press.leds))):
            log.warning("%s", note.replace("the solve's normals", "an LED calibration and the solves with it"))
