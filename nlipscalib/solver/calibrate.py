"""LED self-calibration from captures of the undeformed dome (known geometry: Press.reference).

Per LED i, non-linear least squares (scipy.optimize.least_squares, robust loss) of
``I_ic(p) = K_ic * (n_s . d)^mu * max(0, (x_s - x) . n) / |x_s - x|^3`` over the reference's pixels,
with K_ic = rho_c Psi_ic. Parameters: log K_ic (3), mu, n_s (polar and azimuth angles), x_s (3).

Gauge (Psi and albedo are only known up to a common scale): the coating's albedo is taken uniform per
channel and the LED intensities are normalised so that **mean_i Psi_ic = 1 for every channel c**; the
common factor rho_c = mean_i K_ic is reported as ``albedo``. The solver recovers albedo relative to it.

What the user is told (``LedCalibration.warnings``, logged as warnings): a coating reflectance given but not
used, a reflectance that could not be profiled, a fit that leaves more than the images' own noise
unexplained (:func:`fit_quality`), i.e. LEDs not to be trusted, and a capture with many saturated samples
(left out of the fit, :data:`nlipscalib.core.tolerances.SATURATED_SHARE_WARN`).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core import masks, tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.errors import CaptureError, ConfigError
from ..core.leds import Led, Leds, disk_shading, led_shading
from ..core.robust_scale import mad_scale
from .blas import blas_threads
from .exposure import nothing_to_fit, saturated_share, saturation_note
from .press_checks import _other_sensor, optics_difference

if TYPE_CHECKING:  # named in hints only: the functions import the indirect module where they use it
    from pathlib import Path

    from .indirect import IndirectModel

log = logging.getLogger(__name__)


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
    (:func:`_profiled_reflectance`): the freely fitted one, the scales of it tried, their disk-fit residuals
    and the chosen reflectance. None otherwise."""
    quality: dict | None = None
    """:func:`fit_quality` of the point LEDs: each LED's residual against its images' noise, and whether the
    calibration is reliable."""
    warnings: tuple[str, ...] = ()
    """What the user must know (one line each; also logged): options given but not used, an unreliable fit, captures
    with many saturated samples."""
    saturated_share: tuple[float, ...] = ()
    """Per capture, the share of the gel's samples left out as saturated (:func:`.exposure.saturated_share`)."""
    contact_pixels: tuple[int, ...] = ()
    """With ``allow_contact``, per capture, the pixels left out of the fit as a contact (:func:`_contact_regions`);
    empty when no capture showed one."""

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
        return out


def _unit(theta: float, phi: float):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _led(params: np.ndarray) -> Led:
    """The Led a parameter vector (log K (3), mu, polar, azimuth of n_s, x_s (3)) stands for."""
    return Led(
        tuple(params[6:9]), tuple(_unit(params[4], params[5])), max(float(params[3]), 0.0), tuple(np.exp(params[:3]))
    )


def _model(params: np.ndarray, x: np.ndarray, n: np.ndarray):
    """(N, 3) model images of one LED: the one LED image model, ``core.leds.led_shading``."""
    return led_shading(x, n, (_led(params),))[0]


def _disk_model(radius: float):
    """``_model`` for an LED emitting from a disk of ``radius`` mm (``core.leds.disk_shading``)."""

    def model(params: np.ndarray, x: np.ndarray, n: np.ndarray):
        return disk_shading(x, n, (_led(params),), radius)[0]

    return model


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


def calibrate_leds(
    presses: Press | Sequence[Press],
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
) -> LedCalibration:
    """Estimate Psi_c, mu, n_s and x_s of every LED from undeformed captures.

    With interreflection (any real sensor) the images hold more than the direct model: the LEDs are
    fitted, the indirect term (:func:`nlipscalib.solver.indirect.fit_indirect`, radiosity gather on the
    known undeformed surface, coating reflectance fitted) is computed with them, subtracted, and the
    LEDs fitted again from where they are, ``rounds`` times.

    Parameters
    ----------
    presses : Press or sequence of Press -- undeformed dome, with ``reference``; same camera and LEDs.
    initial : sequence of Led or None -- starting values (default: the capture's LEDs).
    stride : use every ``stride``-th pixel in u and v (speed); None: :func:`default_stride` of the captures' frame.
    loss : scipy robust loss ("cauchy", "soft_l1", "huber", "linear").
    interreflection : "auto" (subtract the indirect term when the data show it: its share with the starting LEDs
        turns it on, and it is kept when, converged, it explains the images better than direct light alone,
        :func:`_term_gain`), "on", "off".
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
        it is profiled instead (:func:`_profiled_reflectance`): the reflectance whose disk fit leaves the
        least residual, then the whole calibration again with it. Not used when no capture's indirect term
        is on (``interreflection`` "off", or "auto" on a capture without interreflection): a warning says so.
    allow_contact : a capture that shows a contact (a press, :func:`_contact_regions`) is refused (CaptureError)
        unless this is set; then its contact's pixels are left out of the LED fit and of the indirect term's, with
        a warning.

    Returns
    -------
    LedCalibration -- with ``quality`` (:func:`fit_quality`) and ``warnings``, each also logged as a warning:
    a ``coating_reflectance`` not used, a reflectance not profiled, an unreliable fit, a contact left out.
    """
    presses = [presses] if isinstance(presses, Press) else list(presses)
    if not presses:
        raise CaptureError("calibrate_leds needs at least one capture")
    if stride is None:
        stride = default_stride(presses[0].camera.shape)
    settings = _Settings(
        initial, stride, loss, interreflection, bounces, rounds, led_radius, coating_reflectance, allow_contact
    )
    cal = _with_term_if_needed(_calibrate(presses, settings), presses, settings)
    _check_finite(cal, presses[0].folder)
    shares = [saturated_share(p) for p in presses]  # first: a likely cause of the warnings after it
    notes = [n for p, share in zip(presses, shares) if (n := saturation_note(p, share, "the LED fit"))]
    notes += _contact_notes(presses, cal.contact_pixels)
    notes += _unused_reflectance(cal.interreflection, interreflection, led_radius, coating_reflectance)
    notes += _quality_warning(cal.quality, cal.interreflection, interreflection)
    for note in notes:
        log.warning(note)
    return dataclasses.replace(cal, warnings=tuple(notes), saturated_share=tuple(round(v, 4) for v in shares))


def _check_finite(cal: LedCalibration, folder: Path) -> None:
    """CaptureError naming the capture when a fitted LED is not finite (the fit ran off): never written."""
    for i, led in enumerate(cal.leds + tuple(cal.emitters or ())):
        values = [*led.position, *led.direction, led.mu, *led.intensity]
        if not np.all(np.isfinite(values)):
            raise CaptureError(f"{folder}: the fit of LED {i % len(cal.leds) + 1} did not converge (not finite)")


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
    looked for yet (:func:`_contact_regions`, after the first fit)."""


def _calibrate(presses: Sequence[Press], s: _Settings) -> LedCalibration:
    """:func:`calibrate_leds` without its warnings (it calls itself once more after a reflectance profile, and after
    a contact found with ``allow_contact``)."""
    first = presses[0]
    leds0 = tuple(s.initial) if s.initial is not None else first.leds
    left_out = s.left_out or (None,) * len(presses)
    data = [_samples(p, first, len(leds0), s.stride, out) for p, out in zip(presses, left_out)]
    _check_calibration_inputs(presses, data, s.stride, s.led_radius, s.coating_reflectance)
    samples = _Samples(
        x=np.concatenate([d[0] for d in data]),
        n=np.concatenate([d[1] for d in data]),
        img=np.concatenate([d[2] for d in data], axis=1),
        ok=np.concatenate([d[3] for d in data], axis=1),
        selections=[d[4] for d in data],
    )
    fitted, direct, models = _indirect_rounds(
        presses, samples, leds0, s.loss, s.interreflection, s.bounces, s.rounds, s.coating_reflectance, left_out
    )
    if s.left_out is None:  # once per calibration: the reruns below keep the verdict
        s = dataclasses.replace(s, left_out=_contact_regions(presses, _to_leds(fitted)[0], models))
        if any(region.any() for region in s.left_out):
            if not s.allow_contact:
                raise CaptureError(_contact_refusal(presses, s.left_out))
            again = _calibrate(presses, s)  # the same fit without the contact's pixels
            return dataclasses.replace(again, contact_pixels=tuple(int(r.sum()) for r in s.left_out))
    models = [m.to_json() for m in models]
    quality = fit_quality(presses, fitted, samples.x, samples.n, direct, samples.ok)
    if s.interreflection == "auto" and any(m["enabled"] for m in models):  # on by the share with the starting LEDs
        gain = _term_gain(samples, fitted, direct, s.loss, quality)
        if gain <= tolerances.CALIBRATION_MIN_TERM_GAIN:
            return _direct_after_all(presses, s, models, gain)
        models = [dict(m, term_gain=round(gain, 1)) for m in models]
    leds, albedo, std = _to_leds(fitted)
    emitters, profile = _emitters_and_profile(
        leds, samples, direct, s.loss, s.led_radius, s.coating_reflectance, models
    )
    if profile is not None:  # the whole calibration again with the profiled reflectance
        again = _calibrate(presses, dataclasses.replace(s, initial=leds, coating_reflectance=tuple(profile["chosen"])))
        return _with_profile(again, profile)
    rms = [f[2] for f in fitted]
    return LedCalibration(leds, albedo, std, rms, models, emitters, float(s.led_radius), quality=quality)


def _with_profile(again: LedCalibration, profile: dict) -> LedCalibration:
    """The calibration rerun with the profiled reflectance (``profile``: :func:`_profiled_reflectance`), carrying the
    profile while its term is on. With "auto" the rerun checks the term again (:func:`_term_gain`, now at the profiled
    reflectance); when that drops it, the result is direct-only LEDs, which a reflectance scales nothing of: the
    profile is not attached (it read as the reflectance the LEDs were fitted with), and the terms' ``reason`` says
    what it chose."""
    if any(m.get("enabled") for m in again.interreflection):
        return dataclasses.replace(again, reflectance_profile=profile)
    chosen = np.round(profile["chosen"], 3).tolist()
    note = f"; the reflectance profile had chosen {chosen}, with which the term was then not used"
    models = [dict(m, reason=m["reason"] + note) for m in again.interreflection]
    return dataclasses.replace(again, interreflection=models)


@dataclasses.dataclass(frozen=True)
class _Samples:
    """The samples of every capture, pooled: what the LED fits run on."""

    x: np.ndarray
    """(N, 3) float64, mm, camera frame -- the samples' points on the reference surface."""
    n: np.ndarray
    """(N, 3) float64, unit, camera frame -- their normals."""
    img: np.ndarray
    """(L, N, 3) float64, linear image units -- the LED images at the samples."""
    ok: np.ndarray
    """(L, N, 3) bool -- usable (not saturated) samples."""
    selections: list
    """Per capture, (H, W) bool -- its pixels among the samples, in order."""


def _check_calibration_inputs(
    presses: Sequence[Press],
    data: Sequence[tuple],
    stride: int,
    led_radius: float,
    coating_reflectance: float | tuple[float, float, float] | None,
) -> None:
    """CaptureError or ConfigError before any fit: a capture with nothing to fit, a stride that leaves too few
    samples (``data``: each capture's :func:`_samples`), a negative LED disk radius, a coating reflectance out of
    range."""
    from .indirect import checked_reflectance

    # black or saturated throughout: said here, not as a fit that fails further on. Asked of every capture, not
    # only after a failure: a black capture's noise is fitted without failing, or ends on "led.intensity must be
    # 3 finite numbers" (~40 ms per 640x480 capture; its linear images are the ones _samples made)
    for p in presses:
        if why := nothing_to_fit(p):
            raise CaptureError(f"{p.folder}: no usable pixel to calibrate the LEDs on{why}")
    used = sum(len(d[0]) for d in data)
    if used < tolerances.CALIBRATION_MIN_PIXELS:
        raise ConfigError(
            f"{presses[0].folder}: stride {stride} leaves {used} pixels of the gel; the LED fit needs at least "
            f"{tolerances.CALIBRATION_MIN_PIXELS}: use a smaller stride"
        )
    if not led_radius >= 0:
        raise ConfigError(f"the LED disk radius must be >= 0 mm, got {led_radius}")
    if coating_reflectance is not None:
        checked_reflectance(coating_reflectance)  # before any fit


def _indirect_rounds(
    presses: Sequence[Press],
    samples: _Samples,
    leds0: Leds,
    loss: str,
    interreflection: str,
    bounces: int,
    rounds: int,
    coating_reflectance: float | tuple[float, float, float] | None,
    left_out: Sequence[np.ndarray | None],
):
    """(per-LED fits as :func:`_fit_all` returns them, the images minus the indirect light they were fitted to,
    the captures' last indirect terms) -- ``rounds`` alternations of indirect fit and LED fit, or one direct-only
    LED fit from ``leds0`` when no term is on. ``left_out``: per capture, (H, W) bool or None -- pixels the term's
    fit leaves out as the LED fit does (a contact, ``allow_contact``): a dent's light fitted as the undeformed
    dome's would bias the term's reflectance, and through it every LED fitted to the images minus it.

    A direct-only fit would absorb the indirect light into wrong LED parameters (up to 17 deg off on the twin),
    after which nothing correlates with the indirect term any more: the term is fitted with the starting LEDs
    first, and the LEDs are always fitted to the images minus it."""
    from .indirect import fit_indirect

    x, n, img, ok = samples.x, samples.n, samples.img, samples.ok
    leds, fitted, models = leds0, None, []
    direct = img  # the images minus the indirect light the last LED fit used
    for r in range(rounds if interreflection != "off" else 0):
        if r > 0:
            leds = _to_leds(fitted)[0]
        models = [
            fit_indirect(p, leds, mode=interreflection, bounces=bounces, exclude=out)
            for p, out in zip(presses, left_out)
        ]
        if r == 0 and interreflection == "auto":
            models = [_decide(m) for m in models]
        if coating_reflectance is not None and r > 0:
            # not in the first round: with the starting LEDs a lower light than fitted let an LED fit run off
            # (seen: one LED 6.6 mm away); from the first round's LEDs the known value only refines
            models = [m.with_reflectance(coating_reflectance) if m.enabled else m for m in models]
        if not any(m.enabled for m in models):
            break
        direct = img - _sampled_indirect_light(presses, models, samples.selections, len(leds))
        fitted = _fit_all(leds, x, n, direct, ok, loss)
    if fitted is None or (models and not any(m.enabled for m in models)):
        direct = img
        fitted = _fit_all(leds0, x, n, img, ok, loss)
    return fitted, direct, models


def _contact_regions(presses: Sequence[Press], leds: Leds, models: Sequence[IndirectModel]) -> tuple[np.ndarray, ...]:
    """Per capture, (H, W) bool: where it shows a contact -- the connected regions of pixels that the fitted
    undeformed model (``leds`` and the capture's indirect term when on) misfits far beyond the images' noise
    (:func:`nlipscalib.solver.contact.contact_hits`, the solver's own classification of a press), each at least
    :data:`tolerances.CALIBRATION_CONTACT_FRACTION` of the gel. All False on a capture of the undeformed dome.

    Why from the fit: the capture holds no ground truth (a real sensor has none), and its LEDs are what the
    calibration finds; the robust loss keeps a dent from pulling them far, so the dent is what they misfit.
    Dilated by :data:`CONTACT_MARGIN_PX`: the dent's rim misfits just below the hit threshold.
    """
    from .contact import classify_contact, contact_hits

    out = []
    for p, m in zip(presses, list(models) or [None] * len(presses)):
        light = m.undeformed_light(p.camera.shape) if m is not None and m.enabled else None
        contact = classify_contact(p, leds, undeformed_light=light)
        # the LED model's own error counts as noise, as in fit_quality: without it a noise-free render's edge (its
        # noise the ADC step) misfit as a contact (80x60 bounce-free twin: 1.4 % of the gel; with it none)
        model_error = tolerances.CALIBRATION_MODEL_ERROR * np.nan_to_num(contact.level)
        contact = dataclasses.replace(contact, expected=np.hypot(contact.expected, model_error))
        labels, sizes = masks.components(contact_hits(contact))
        gel = int(np.isfinite(contact.misfit).sum())
        large = np.flatnonzero(sizes >= tolerances.CALIBRATION_CONTACT_FRACTION * gel) + 1
        region = np.isin(labels, large)
        out.append(masks.dilate(region, iterations=CONTACT_MARGIN_PX) & np.isfinite(contact.misfit))
    return tuple(out)


CONTACT_MARGIN_PX = 2
"""Pixels by which a contact found in a calibration capture is grown before it is left out (``allow_contact``):
its rim misfits less than the threshold of a hit yet still shows the dent."""


def _contact_refusal(presses: Sequence[Press], regions: Sequence[np.ndarray]) -> str:
    """The one line that refuses captures showing a contact (``regions``: :func:`_contact_regions`)."""
    found = [(p, r) for p, r in zip(presses, regions) if r.any()]
    p, region = found[0]
    gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
    rows, cols = np.nonzero(region)
    more = f" (and {len(found) - 1} more of the captures)" if len(found) > 1 else ""
    return (
        f"{p.folder}: not a capture of the undeformed dome{more}: {100 * region.sum() / gel:.1f} % of the gel, around "
        f"pixel ({int(np.median(cols))}, {int(np.median(rows))}), differs from the fitted undeformed model far beyond "
        "the images' noise, as a press does; calibrate the LEDs on the undeformed dome (a session's reference/), or "
        "pass --allow-contact to fit without those pixels"
    )


def _contact_notes(presses: Sequence[Press], pixels: Sequence[int]) -> list[str]:
    """The warnings for contacts left out of the fit (``pixels``: ``LedCalibration.contact_pixels``)."""
    notes = []
    for p, count in zip(presses, pixels):
        if count:
            gel = max(int(np.isfinite(p.reference.depth).sum()), 1)
            notes.append(
                f"{p.folder}: shows a contact (a press?): its {count} pixels ({100 * count / gel:.1f} % of the gel) "
                "were left out of the LED fit (--allow-contact); the rest of the gel was taken as undeformed"
            )
    return notes


def _sampled_indirect_light(
    presses: Sequence[Press], models: Sequence[IndirectModel], selections: Sequence[np.ndarray], count: int
) -> np.ndarray:
    """(L, N, 3) float -- each capture's own indirect light (its fitted term at its typical albedo; zero where the
    term is off) at its samples, pooled as :class:`_Samples` pools them."""
    light = []
    for p, m, sel in zip(presses, models, selections):
        if not m.enabled:
            light.append(np.zeros((count, int(sel.sum()), 3)))
            continue
        light.append((m.undeformed_light(p.camera.shape) * np.asarray(m.off_view_albedo, np.float32))[:, sel])
    return np.concatenate(light, axis=1)


def _emitters_and_profile(
    leds: Leds,
    samples: _Samples,
    direct: np.ndarray,
    loss: str,
    led_radius: float,
    coating_reflectance: float | tuple[float, float, float] | None,
    models: list[dict],
):
    """(the LEDs fitted as disks of ``led_radius`` from the point ``leds``, or () without a radius; the
    reflectance profile (:func:`_profiled_reflectance`) when the reflectance is to be profiled, else None).
    ``models``: the captures' indirect terms as JSON."""
    if not led_radius > 0:
        return (), None
    # from the points (0.2 mm off at most): the disk fit only refines them
    x, n, ok = samples.x, samples.n, samples.ok
    emitters = _to_leds(_fit_all(leds, x, n, direct, ok, loss, _disk_model(led_radius)))[0]
    fitted_reflectance = _fitted_reflectance(models)
    if coating_reflectance is not None or fitted_reflectance is None:
        return emitters, None
    profile = _profiled_reflectance(emitters, x, n, samples.img, direct, ok, loss, led_radius, fitted_reflectance)
    return emitters, profile


def _fitted_reflectance(models: list[dict]) -> np.ndarray | None:
    """(3,) the coating reflectance the indirect term was fitted with (the first capture's whose term is on),
    or None when no capture's term is on."""
    for m in models:
        if m.get("enabled"):
            return np.asarray(m["coating_reflectance"], float)
    return None


PROFILE_SCALES = (0.6, 1.15)
"""Range of the reflectance profile, as multiples of the freely fitted reflectance (:func:`_profiled_reflectance`)."""
PROFILE_XTOL = 0.01
"""The profile's tolerance on that multiple."""
PROFILE_SAMPLES = 20_000
"""The profile's disk fits use every k-th sample, k the smallest that leaves at most this many (a 640x480
capture at stride 2 has ~55,000; every second of a 160x120 capture's ~3,400 moved the chosen reflectance from
0.78 to 0.75, and its LED positions by 0.03 mm)."""


def _profiled_reflectance(
    emitters: Leds,
    x: np.ndarray,
    n: np.ndarray,
    img: np.ndarray,
    direct: np.ndarray,
    ok: np.ndarray,
    loss: str,
    radius: float,
    fitted: np.ndarray,
) -> dict:
    """The coating reflectance whose LED disk fit leaves the least residual, as a multiple of ``fitted``.

    Why: a ring-wide tilt of the LED axes trades against the indirect term's magnitude, and the alternation
    of LED fit and indirect fit settles on the tilted side (on the twin: 0.89-0.91 for a true 0.8, start
    dependent). The point LEDs cannot arbitrate (a point is not the disk the light comes from: their residual
    keeps falling with the reflectance), but the disk model is the emitter's own: its residual, with the
    indirect light scaled by s (exact for one bounce, linear in the reflectance), is least near the true
    reflectance (twin, 160x120: 0.75-0.80 for 0.8; benchmarks/RESULTS.md). Bounded Brent search over s
    (scipy.optimize.minimize_scalar), each step a disk fit from ``emitters`` on at most
    :data:`PROFILE_SAMPLES` samples.

    Parameters
    ----------
    emitters : sequence of Led -- the disks fitted to ``direct`` (the start of every fit).
    x, n : (N, 3) float, mm / unit, camera frame -- the samples' points and normals.
    img, direct : (L, N, 3) float -- the images, and the images minus the indirect light at ``fitted``.
    ok : (L, N, 3) bool -- usable samples.
    loss : the LED fit's robust loss; radius : the disks' radius, mm.
    fitted : (3,) float -- the freely fitted coating reflectance.

    Returns
    -------
    dict -- fitted (3,), scales, residuals (sum over LEDs of the disk fit's squared RMS, image units), chosen (3,).
    """
    from scipy.optimize import minimize_scalar

    light = img - direct
    every = slice(None, None, -(-len(x) // PROFILE_SAMPLES))
    xs, ns, imgs, lights, oks = x[every], n[every], img[:, every], light[:, every], ok[:, every]
    model = _disk_model(radius)
    tried: dict[float, float] = {}

    def residual(s: float) -> float:
        out = _fit_all(emitters, xs, ns, imgs - s * lights, oks, loss, model)
        tried[float(s)] = float(sum(f[2] ** 2 for f in out))
        return tried[float(s)]

    top = min(PROFILE_SCALES[1], 1.0 / float(np.max(fitted)))
    best = minimize_scalar(residual, bounds=(PROFILE_SCALES[0], top), method="bounded", options={"xatol": PROFILE_XTOL})
    scales = sorted(tried)
    return {
        "fitted": [float(v) for v in fitted],
        "scales": [round(s, 4) for s in scales],
        "residuals": [tried[s] for s in scales],
        "chosen": [float(v) for v in np.minimum(fitted * float(best.x), 1.0)],
    }


def _decide(model: IndirectModel):
    """The calibration's auto decision (:data:`tolerances.CALIBRATION_MIN_SHARE`) on a model fitted with the
    starting LEDs."""
    import dataclasses

    on = model.share >= tolerances.CALIBRATION_MIN_SHARE
    limit = tolerances.CALIBRATION_MIN_SHARE
    note = f"; calibration: {'used' if on else 'not used'} (threshold {limit} with the starting LEDs)"
    reason = model.reason.replace("interreflection on:", "interreflection off:") if not on else model.reason
    return dataclasses.replace(model, enabled=on, reason=reason + note)


def _samples(p: Press, first: Press, count: int, stride: int, left_out: np.ndarray | None = None):
    """Points, normals, linear images, usable flags and the pixel selection of one capture (without the pixels
    ``left_out``, (H, W) bool, when given)."""
    if p.reference is None:
        raise CaptureError(f"{p.folder}: LED calibration needs the undeformed reference (reference.npz)")
    if p.camera != first.camera or len(p.leds) != count:
        why = optics_difference(p, first) or f"it has {len(p.leds)} LEDs, the starting LEDs {count}"
        raise CaptureError(f"{p.folder}: not a capture of the sensor of {first.folder} ({why})")
    # the LED ring and the dome too: two sensors of one camera were fitted together and refused as "a press"
    why = _other_sensor(first, p) if p is not first else None
    if why:
        raise CaptureError(f"{p.folder}: not a capture of the sensor of {first.folder} ({why})")
    valid = np.isfinite(p.reference.depth)
    sub = np.zeros_like(valid)
    sub[::stride, ::stride] = True
    sel = valid & sub
    if left_out is not None:
        sel &= ~left_out
    rays = p.camera.rays[sel]
    x = depth_to_points(p.reference.depth[sel].astype(np.float64), rays)
    n = p.reference.normals[sel].astype(np.float64)
    # the press's linear images, made once for it (nothing_to_fit, _led_noise and fit_indirect read them too)
    return x, n, p.linear_led_images[:, sel].astype(np.float64), ~p.saturated(p.led_images[:, sel]), sel


def _fit_all(
    leds: Leds,
    x: np.ndarray,
    n: np.ndarray,
    img: np.ndarray,
    ok: np.ndarray,
    loss: str,
    model: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = _model,
):
    """[(params, std, rms)] per LED: robust non-linear least squares of ``model`` from ``leds``.

    The unknowns are the parameters' offsets from the start: trf's first trust region is the start's norm in its
    scaled units (scipy's ``Delta = norm(x0 * scale_inv)``), so with positions in camera coordinates (the ring 9 mm
    off the axis) its first step could carry an LED 9.8 mm, behind the camera, into another minimum: on the
    bounce-free twin at 80x60, from LEDs 0.4-0.8 mm / 5-10 deg off, 6 of 24 starts left one LED 11-97 deg and
    4-7 mm off at a median quality like a good fit's (160x120 with noise: that LED 1.08x the noise, the others
    0.99-1.02x). From offsets the first region is 1 (its norm when zero): none of them (benchmarks/RESULTS.md)."""
    from scipy.optimize import least_squares  # imported here: ~0.5 s that `nlips solve` never needs

    out = []
    # one BLAS thread: trf's SVD of each step's (N, 9) Jacobian took 4-6x the CPU on 2 threads of a loaded
    # machine, the same bits (s17-d, benchmarks/RESULTS.md)
    with blas_threads(1):
        for i, led in enumerate(leds):
            d = np.asarray(led.direction)
            p0 = np.concatenate(
                [
                    np.log(np.maximum(led.intensity, 1e-12)),
                    [led.mu, np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])],
                    led.position,
                ]
            )
            # initial intensity: least-squares scale of the model
            geo = model(p0, x, n) / np.exp(p0[:3])
            k0 = (geo * img[i] * ok[i]).sum(0) / np.maximum((geo * geo * ok[i]).sum(0), 1e-30)
            p0[:3] = np.log(np.maximum(k0, 1e-12))
            use = _fit_samples(img[i], ok[i])
            scale = float(np.percentile(img[i][use], 90)) if use.any() else 1.0

            def resid(step: np.ndarray, i: int = i, use: np.ndarray = use, scale: float = scale, p0: np.ndarray = p0):
                return ((model(p0 + step, x, n) - img[i]) / scale)[use]

            r0 = resid(np.zeros_like(p0))
            f_scale = max(3 * mad_scale(r0), 1e-3)
            res = least_squares(resid, np.zeros_like(p0), loss=loss, f_scale=f_scale, x_scale="jac", method="trf")
            dof = max(len(res.fun) - len(p0), 1)
            s2 = float(np.sum(res.fun**2) / dof)
            try:
                sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(res.jac.T @ res.jac) * s2), 0))
            except np.linalg.LinAlgError:
                sd = np.full(len(p0), np.nan)
            out.append((p0 + res.x, sd, float(np.sqrt(np.mean(res.fun**2))) * scale))
    return out


def _to_leds(fitted: Sequence[tuple[np.ndarray, np.ndarray, float]]):
    """(LEDs in the gauge mean Psi = 1 per channel, albedo (3,), std dicts) from per-LED fits."""
    K = np.exp(np.array([f[0][:3] for f in fitted]))  # (L, 3)
    albedo = K.mean(axis=0)
    leds, std = [], []
    for (f, sd, _), k in zip(fitted, K):
        psi = k / albedo
        leds.append(Led(tuple(f[6:9]), tuple(_unit(f[4], f[5])), float(max(f[3], 0.0)), tuple(psi)))
        std.append(
            {
                "intensity": list(psi * sd[:3]),
                "mu": float(sd[3]),
                "direction_deg": float(np.degrees(np.hypot(sd[4], np.sin(f[4]) * sd[5]))),
                "position_mm": list(sd[6:9]),
            }
        )
    return tuple(leds), tuple(float(a) for a in albedo), std


def _fit_samples(img: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N, 3) bool -- the samples one LED is fitted on: usable and lit (above 1 % of its 99th percentile per
    channel); :func:`fit_quality` judges the fit on the same samples.

    img : (N, 3) float -- that LED's samples, linear; ok : (N, 3) bool -- usable.
    """
    return ok & (img > 0.01 * np.percentile(img, 99, axis=0))


def _led_noise(presses: Sequence[Press]) -> np.ndarray:
    """(L,) float -- the white noise of each LED's images, linear units: Immerkaer's estimate
    (:func:`nlipscalib.solver.contact.image_noise`) on the gel, median over the captures, at least one ADC step
    (a noise-free capture holds only quantisation, where the estimate says nothing)."""
    from .contact import image_noise

    per = []
    for p in presses:
        valid = np.isfinite(p.reference.depth)
        lin = p.linear_led_images
        per.append([image_noise(lin[i : i + 1], valid) for i in range(len(lin))])
    r = presses[0].response
    step = 2.0 ** (16 - r.bit_depth) / (r.white_level - r.black_level)
    return np.maximum(np.median(np.asarray(per, float), axis=0), step)


def fit_quality(
    presses: Sequence[Press],
    fitted: Sequence[tuple[np.ndarray, np.ndarray, float]],
    x: np.ndarray,
    n: np.ndarray,
    img: np.ndarray,
    ok: np.ndarray,
    model: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = _model,
) -> dict:
    """How much of the images the fitted LEDs leave unexplained, in units of the images' own noise.

    Each LED's residual scale (1.4826 x the median absolute deviation of model minus image over its fitted
    samples: robust, so a few bad pixels do not count) over the white noise of its images (Immerkaer's
    estimate, which a Laplacian mask makes blind to smooth shading) and the LED model's own error
    (:data:`tolerances.CALIBRATION_MODEL_ERROR` of its median fitted sample), in quadrature. A model that
    explains the images leaves the noise alone: a ratio near 1. The model's error matters without noise only:
    a noise-free render's Immerkaer estimate is its quantisation (the ADC step, the floor), while the smooth
    error of sampling a pixel's footprint at its centre is not noise, 0.24-0.28 % of the level on the twin.
    Light the model does not explain is mostly smooth (measured below: the Monte Carlo error of a low-spp
    render, which the bounce light's denoiser turns into blotches; an interreflection term left out; the
    realistic twin's optics), so it raises the residual and not the noise estimate, and it biases the LEDs far
    beyond their Jacobian ``std``: at 160x120, 4 spp the worst LED's axis is 2-4 deg off while its ``std`` says
    0.15 deg.

    Measured (``nlips render --undeformed``, then ``calibrate_leds`` from the capture's own LEDs; median ratio
    over the LEDs, worst LED against the truth, points, or with ``led_radius`` 1.8 the disks; 2026-12-03, the
    noise alone; the model's error moves these by at most 0.01, below):

    ==================================================  ==============  ==========================
    capture                                             median ratio    worst LED
    ==================================================  ==============  ==========================
    nlipstac, bounces 0, 160x120, 4 spp / 1 spp         1.01 / 1.04     0.51-0.80 deg, 0.24-0.29 mm
    nlipstac, one bounce, 16 spp, 160x120 (3 seeds)     1.06-1.07       disks 0.87-1.43 deg, 0.13-0.30 mm
    ... 320x240 / 640x480                               1.04 / 1.03     1.33 / 1.31 deg (points)
    nlipstac_ideal / fingertip, one bounce, 16 spp      1.08 / 1.11     disks 0.87 / 1.45 deg
    nlipstac, one bounce, 8 spp, 320x240                1.15            1.58 deg, 0.25 mm (points)
    nlipstac, one bounce, 4 spp, 640x480                1.19            3.33 deg, 0.69 mm (points)
    nlipstac, one bounce, 8 spp, 160x120 (3 seeds)      1.20-1.22       disks 2.91-4.58 deg, 0.29-0.55 mm
    oblate, one bounce, 16 spp (term not used: share    1.23            disks 16.2 deg
    0.09 with the starting LEDs; forced on, as
    auto now does: 1.06, points 2.8 deg)
    nlipstac, one bounce, 4 spp, 160x120 (3 seeds)      1.34-1.36       disks 1.81-3.57 deg, 0.43-0.80 mm
    nlipstac_realistic, one bounce, 16 spp              1.52            disks 13.0 deg, 4.9 mm
    nlipstac, one bounce, 2 spp, 160x120 (3 seeds)      1.63-1.64       disks 2.44-5.89 deg, 0.42-0.56 mm
    ==================================================  ==============  ==========================

    Without noise (2026-12-05: the noise-free ``twin()`` of tests/solver/test_twin.py, stride 2, from the true
    LEDs and ones 0.3-0.5 mm / 5 deg off; ratio without / with the model's error; residual: % of the median
    fitted sample):

    ==============================================  ============  =========  ============================
    capture                                         ratio         residual   worst LED
    ==============================================  ============  =========  ============================
    nlipstac, bounces 0, 4 spp, 80x60               1.52-1.56 /   0.26-0.28  0.49-0.61 deg (disks 0.16)
                                                    0.75-0.80
    ... 160x120                                     1.54 / 0.71   0.24       0.43-0.45 deg (disks 0.07)
    nlipstac, one bounce, 16 spp, 160x120           8.6 / 2.9     0.93       1.73-3.12 deg, 0.31-0.36 mm
    ==============================================  ============  =========  ============================

    With the sensor's noise (2.2-3.8 % of the median fitted sample) the model's error moves the median ratio by
    at most 0.01 (the quality tests' captures, stride 4: bounces 0 1.006 -> 0.997, one bounce 16 spp 1.068 ->
    1.061, 2 spp 1.689 -> 1.678, the oblate dome 1.095 -> 1.092).

    Good captures stay at or below 1.11; the poor ones (worst LED beyond the README's 2 deg or 0.3 mm) start at
    1.19, so :data:`tolerances.FIT_NOISE_RATIO` = 1.15 sits between them (the ratio's own scatter at 160x120: about 0.01
    between seeds, up to 0.03 between strides 2, 3 and 4). The worst single LED of a good capture reached 1.13: the
    verdict is the median's, so one LED's chance excess does not raise it. Blind spot: light the LEDs can absorb
    by tilting (the indirect term forced on a bounce-free capture: worst LED 16 deg off at 1.04).

    Parameters
    ----------
    presses : sequence of Press -- the captures (their LED images give the noise).
    fitted : list of (params, std, rms) -- per LED, as :func:`_fit_all` returns them.
    x, n : (N, 3) float -- the samples' points (mm) and normals (unit), camera frame.
    img : (L, N, 3) float -- the images the LEDs were fitted to (minus the indirect light), linear.
    ok : (L, N, 3) bool -- usable samples.
    model : the LED model the parameters are of (default the point LED).

    Returns
    -------
    dict -- ``noise`` (L,), ``model_error`` (L,) and ``residual`` (L,), linear image units; ``ratio`` (L,)
    residual over noise and model error in quadrature;
    ``median_ratio``; ``threshold`` (:data:`tolerances.FIT_NOISE_RATIO`); ``reliable`` (median_ratio <= threshold).
    """
    noise = _led_noise(presses)
    residual, level = [], []
    for i, (params, _, _) in enumerate(fitted):
        use = _fit_samples(img[i], ok[i])
        r = (model(params, x, n) - img[i])[use]
        residual.append(mad_scale(r) if r.size else float("nan"))
        level.append(float(np.median(img[i][use])) if r.size else float("nan"))
    model_error = tolerances.CALIBRATION_MODEL_ERROR * np.asarray(level)
    ratio = np.asarray(residual) / np.hypot(noise, model_error)  # independent errors: their variances add
    median = float(np.nanmedian(ratio))
    return {
        "noise": [float(v) for v in noise],
        "model_error": [float(v) for v in model_error],
        "residual": residual,
        "ratio": [round(float(v), 4) for v in ratio],
        "median_ratio": round(median, 4),
        "threshold": tolerances.FIT_NOISE_RATIO,
        "reliable": bool(median <= tolerances.FIT_NOISE_RATIO),
    }


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
    if _no_interreflection(cal.interreflection, "auto") is None:
        return cal
    if any("term_gain" in m for m in cal.interreflection):  # the term was fitted and compared already (_term_gain)
        return cal
    on = _calibrate(presses, dataclasses.replace(s, interreflection="on", led_radius=0.0))
    if _term_wins(cal, on) and s.led_radius > 0:
        on = _calibrate(presses, dataclasses.replace(s, interreflection="on"))
    if not _term_wins(cal, on):
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


TERM_CHECK_SAMPLES = 2500
"""The term's check (:func:`_term_gain`) fits every k-th sample, k the smallest that leaves at most this many: its
cost stays that of a 160x120 capture at stride 2-4 (1,200-4,800 samples, where its gain was measured) on larger
captures (test_interreflection.py's stride 1: ~19,000), and the gain, which grows with the samples, stays on the
scale it was measured on."""


def _term_gain(
    samples: _Samples,
    fitted: Sequence[tuple[np.ndarray, np.ndarray, float]],
    direct: np.ndarray,
    loss: str,
    quality: dict,
) -> float:
    """How much the indirect term lowers the point LED fits' summed squared residual against a direct-only fit, in
    units of each LED's noise variance (its noise and model error in quadrature, ``quality`` of :func:`fit_quality`).

    Both fits converged, on the same samples (every k-th, :data:`TERM_CHECK_SAMPLES`), from the term's LEDs: the
    term's fit again on them (when they are a subsample: neither fit then fits noise the other does not see) and a
    direct-only fit of the images. A term that only fits noise gains about a chi-squared with its 3 parameters; one
    that subtracts light that is not there loses (negative): LEDs started 0.8 mm / 10 deg off pose as 12-20 % of
    indirect light on a bounce-free capture, the term then fits every LED worse than direct light alone; on an
    interreflecting one it gains hundreds of variances although its direct-only LEDs end 17 deg off
    (benchmarks/RESULTS.md, s15-m and s17-d).

    Parameters
    ----------
    samples : the calibration's samples; fitted : per LED (params, std, rms), the term's fit (:func:`_fit_all`).
    direct : (L, N, 3) float -- the images minus the term's indirect light, linear.
    loss : the LED fit's robust loss; quality : :func:`fit_quality` of ``fitted``.
    """
    every = slice(None, None, -(-len(samples.x) // TERM_CHECK_SAMPLES))
    x, n, img, ok, lit = (
        samples.x[every],
        samples.n[every],
        samples.img[:, every],
        samples.ok[:, every],
        direct[:, every],
    )
    leds = _to_leds(fitted)[0]
    on = fitted if every.step == 1 else _fit_all(leds, x, n, lit, ok, loss)
    off = _fit_all(leds, x, n, img, ok, loss)
    variance = np.asarray(quality["noise"]) ** 2 + np.asarray(quality["model_error"]) ** 2
    uses = [_fit_samples(img[i], ok[i]) for i in range(len(leds))]  # the images' lit samples, for both fits

    def squares(fits: list, images: np.ndarray) -> np.ndarray:
        return np.array([np.sum((_model(f[0], x, n) - im)[u] ** 2) for f, im, u in zip(fits, images, uses)])

    return float(np.sum((squares(off, img) - squares(on, lit)) / variance))


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


def _term_wins(direct: LedCalibration, on: LedCalibration) -> bool:
    """Whether the calibration with the indirect term explains the images (reliable) and better than ``direct``."""
    return on.quality["reliable"] and on.quality["median_ratio"] < direct.quality["median_ratio"]


def _no_interreflection(models: list[dict], interreflection: str) -> str | None:
    """Why no capture's indirect term is on (one clause), or None when one is."""
    if any(m.get("enabled") for m in models):
        return None
    if interreflection == "off" or not models:
        return "the interreflection term is off (requested)"
    share = max(m["indirect_share"] for m in models)
    if any("term_gain" in m for m in models):  # on by the share, then off by _term_gain
        return (
            f"the interreflection term did not explain the images better than direct light (fitted indirect share "
            f"{share:.3f} with the starting LEDs)"
        )
    return (
        f"no capture shows interreflection (fitted indirect share {share:.3f} with the starting LEDs, below "
        f"{tolerances.CALIBRATION_MIN_SHARE})"
    )


def _unused_reflectance(
    models: list[dict], interreflection: str, led_radius: float, reflectance: float | tuple[float, float, float] | None
) -> list[str]:
    """The warnings for a coating reflectance given but not used, or not profiled (with ``led_radius``).

    Not honoured on purpose: the reflectance sets the magnitude of the indirect term, and with the term off
    there is nothing to scale. On a capture the auto decision found without interreflection (a bounce-free
    render of the twin: share 0.014, where its one-bounce renders show 0.31-0.33) the term would subtract light
    that is not there; ``interreflection="on"`` forces it with the given reflectance (there, 160x120, 4 spp: worst
    LED 16.0 deg and 0.73 mm off against 0.54 deg and 0.25 mm, and :func:`fit_quality` cannot tell: 1.04).
    """
    from .indirect import checked_reflectance

    why = _no_interreflection(models, interreflection)
    if why is None:
        return []
    if reflectance is not None:
        a = np.round(checked_reflectance(reflectance), 3)
        shown = f"{a[0]:g}" if np.all(a == a[0]) else str(a.tolist())
        force = "" if interreflection == "off" else "; --interreflection on forces the term with this reflectance"
        return [
            f"coating reflectance {shown} (--coating-reflectance) not used: {why}, so the LEDs were fitted to the "
            f"images as direct light{force}"
        ]
    if led_radius > 0 and interreflection != "off":
        return [
            f"coating reflectance not profiled (--led-diameter without --coating-reflectance): {why}, so the LEDs "
            "were fitted to the images as direct light"
        ]
    return []


def _quality_warning(quality: dict, models: list[dict], interreflection: str) -> list[str]:
    """The warning for an unreliable fit (:func:`fit_quality`), with what to do; [] when reliable."""
    if quality["reliable"]:
        return []
    ratio = np.asarray(quality["ratio"])
    worst = int(np.nanargmax(ratio))
    hint = ""
    if interreflection == "auto" and _no_interreflection(models, interreflection) is not None:
        hint = "; the interreflection term was not used: if the gel interreflects, try --interreflection on"
    return [
        f"LED calibration unreliable: its residual is {quality['median_ratio']:.2f}x the images' noise (median "
        f"over the LEDs, reliable up to {quality['threshold']}; LED {worst + 1} {ratio[worst]:.2f}x): the images hold "
        "light the LED model does not explain. Capture again with more samples per pixel (a render) or more frames "
        "averaged, and check the capture (nothing moved, no stray light, the undeformed dome)" + hint
    ]
