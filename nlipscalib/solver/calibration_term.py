"""The interreflection term inside the LED calibration: its alternation with the LED fit, the auto decision (the
share with the starting LEDs, then the gain over a direct-only fit), the coating reflectance profile of the LED
disks, and the warnings for a reflectance given but not used."""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core import tolerances
from ..core.capture import Press
from ..core.leds import Led, Leds
from .led_fit import Samples, disk_model, fit_leds, fit_samples, point_model, summed_squares, to_leds

if TYPE_CHECKING:  # named in hints only: the functions import the indirect module where they use it
    from .calibrate import LedCalibration
    from .indirect import IndirectModel


def indirect_rounds(
    presses: Sequence[Press],
    samples: Samples,
    leds0: Leds,
    loss: str,
    interreflection: str,
    bounces: int,
    rounds: int,
    coating_reflectance: float | tuple[float, float, float] | None,
    left_out: Sequence[np.ndarray | None],
    trace: list[float] | None = None,
    settle: bool = False,
) -> tuple[list[tuple[np.ndarray, np.ndarray, float]], np.ndarray, list[IndirectModel]]:
    """(per-LED fits as :func:`fit_leds` returns them, the images minus the indirect light they were fitted to,
    the captures' last indirect terms) -- ``rounds`` alternations of indirect fit and LED fit, or one direct-only
    LED fit from ``leds0`` when no term is on. ``left_out``: per capture, (H, W) bool or None -- pixels the term's
    fit leaves out as the LED fit does (a contact, ``allow_contact``): a dent's light fitted as the undeformed
    dome's would bias the term's reflectance, and through it every LED fitted to the images minus it. ``trace``, when
    given, gets each round's term reflectance (the first capture's whose term is on, its largest channel)
    appended: what :func:`ran_off` reads. ``settle``, with a ``coating_reflectance``: more rounds while the last one
    still moved an LED far (:func:`moved_far`), at most :data:`SETTLE_EXTRA_ROUNDS`.

    A direct-only fit would absorb the indirect light into wrong LED parameters (up to 17 deg off on the twin),
    after which nothing correlates with the indirect term any more: the term is fitted with the starting LEDs
    first, and the LEDs are always fitted to the images minus it."""
    from .indirect import fit_indirect

    x, n, img, ok = samples.x, samples.n, samples.img, samples.ok
    leds, fitted, models = leds0, None, []
    direct = img  # the images minus the indirect light the last LED fit used
    first: list[float | None] = [None] * len(presses)  # each capture's share with the starting LEDs
    planned = rounds if interreflection != "off" else 0
    settle = settle and coating_reflectance is not None
    before, r = None, 0
    while r < planned or (settle and r < planned + SETTLE_EXTRA_ROUNDS and moved_far(before, fitted)):
        if r > 0:
            leds = to_leds(fitted)[0]
        models = [
            fit_indirect(p, leds, mode=interreflection, bounces=bounces, exclude=out)
            for p, out in zip(presses, left_out)
        ]
        if r == 0 and interreflection == "auto":
            models = [_decide(m) for m in models]
        models = [calibration_reason(m, interreflection, share) for m, share in zip(models, first)]
        if r == 0:
            first = [m.share for m in models]
        if coating_reflectance is not None and r > 0:
            # not in the first round: with the starting LEDs a lower light than fitted let an LED fit run off
            # (seen: one LED 6.6 mm away); from the first round's LEDs the known value only refines
            models = [m.with_reflectance(coating_reflectance) if m.enabled else m for m in models]
        if not any(m.enabled for m in models):
            break
        if trace is not None:
            trace.append(float(np.max(next(m.reflectance for m in models if m.enabled))))
        direct = img - _sampled_indirect_light(presses, models, samples.selections, len(leds))
        before, fitted = fitted, fit_leds(leds, x, n, direct, ok, loss)
        r += 1
    if fitted is None or (models and not any(m.enabled for m in models)):
        direct = img
        fitted = fit_leds(leds0, x, n, img, ok, loss)
    return fitted, direct, models


SETTLE_MOVE_MM = 0.2
"""An LED fit whose last round moved an LED more than this (or its axis more than :data:`SETTLE_MOVE_DEG`) has not
settled (:func:`moved_far`). Why: from LEDs far off their places, three rounds at a set reflectance stop half way:
the twin 3 mm / 25 deg off the design, one bounce, seed 3, at the true 0.8: moves 2.26, 1.07, 0.56, 0.30, 0.16 mm
(11.9, 7.2, 3.2, 1.7, 0.9 deg) at rounds 2-6, LED 10's disk 0.64 mm / 2.6 deg off after three rounds, 0.09 mm / 0.5
deg after six. The usual captures' third round moves them at most 0.053 mm / 0.94 deg (the twin's one-bounce
references from 0-2 mm off the design, or from the truth 0.3-0.5 mm / 5 deg off), so they are not touched; seed 2 of
the far twin 0.22 mm / 1.6 deg; benchmarks/RESULTS.md, s31-ledfar."""
SETTLE_MOVE_DEG = 3.0
"""The axis part of :data:`SETTLE_MOVE_MM`, deg."""
SETTLE_EXTRA_ROUNDS = 4
"""The most rounds :func:`indirect_rounds` adds to settle (each a term fit and an LED fit: ~0.5 s of CPU at
160x120)."""


def moved_far(before: list | None, after: list | None) -> bool:
    """Whether any LED moved more than :data:`SETTLE_MOVE_MM` or turned more than :data:`SETTLE_MOVE_DEG` from the LED
    fits ``before`` to ``after`` (as :func:`fit_leds` returns them); False without both."""
    if before is None or after is None:
        return False
    old, new = to_leds(before)[0], to_leds(after)[0]
    move = max(float(np.linalg.norm(np.subtract(a.position, b.position))) for a, b in zip(old, new))
    cosine = min(float(np.dot(a.direction, b.direction)) for a, b in zip(old, new))
    return move > SETTLE_MOVE_MM or np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))) > SETTLE_MOVE_DEG


RUNOFF_RATIO = 0.8
"""The free reflectance of the indirect term has run off (:func:`ran_off`) when its last round's value is below
this share of the second round's (the first fitted with fitted LEDs). Why: an LED whose visible light is mostly
indirect (the twin with its LEDs 3 mm / 25 deg off the design, LED 10 pointing up from outside the ring: 1.25x
more indirect than direct light on the gel) moves where it takes up the term's light, the term's reflectance falls,
and the next round moves it further: 0.927, 0.913, 0.654, 0.380 for a true 0.8, LED 10 0.65, 2.45, 3.23 mm off, and
the capture was refused as a press. Converged fits change it by < 1 % after the second round (the twin's one-bounce
references: 0.986, 0.895, 0.895); benchmarks/RESULTS.md, s30-ledmargin."""
RUNOFF_RANGE = (0.5, 1.0)
"""The reflectances :func:`runoff_reflectance` tries, as multiples of the second round's (capped at 1)."""
RUNOFF_XTOL = 0.02
"""Its tolerance on the reflectance."""


RISING_STEP = 0.02
"""The free reflectance is still rising (:func:`still_rising`) when its last round raised it by more than this share
of the round's before. Why: LEDs that start far from their places take up part of the interreflection's light in the
first round (the term is fitted with the starting LEDs), and the alternation of term and LED fits gives it back a
few % a round: the twin with its LEDs 3 mm / 25 deg / mu 2 off the design, one bounce, seeds 2 and 3 (true 0.8):
0.507, 0.568, 0.588 (+3.5 %), ..., 0.666 after 8 rounds, and 0.387, 0.411, 0.434 (+5.6 %), ..., 0.523; their LEDs at
the third round 0.5 / 1.1 mm and 3.6 / 8.4 deg off, and the capture refused as a press (a 1 % patch at the frame's
corner the low term misfits). Settled rounds change it by < 0.3 % at the third (the twin's one-bounce references
and the design ring from 0-2 mm off; benchmarks/RESULTS.md, s31-ledfar)."""
RISING_RANGE = (1.0, 2.0)
"""The reflectances :func:`runoff_reflectance` tries for a reflectance still rising, as multiples of the last round's
(capped at 1): the alternation was moving it up, toward where whole fits at set reflectances are least."""


def ran_off(trace: Sequence[float]) -> bool:
    """Whether the free reflectance of the rounds (``trace``, :func:`indirect_rounds`) ran off
    (:data:`RUNOFF_RATIO`): it needs 3 rounds or more."""
    return len(trace) >= 3 and trace[-1] < RUNOFF_RATIO * trace[1]


def still_rising(trace: Sequence[float]) -> bool:
    """Whether the free reflectance of the rounds (``trace``) was still rising at the last round
    (:data:`RISING_STEP`): it needs 3 rounds or more (the first round's is the starting LEDs')."""
    return len(trace) >= 3 and trace[-1] > (1.0 + RISING_STEP) * trace[-2]


def unsettled_range(trace: Sequence[float]) -> tuple[float, float] | None:
    """The coating reflectances to search by whole fits (:func:`runoff_reflectance`) when the free one did not
    settle over the rounds (``trace``): ran off (:func:`ran_off`), :data:`RUNOFF_RANGE` times the second round's;
    still rising (:func:`still_rising`), :data:`RISING_RANGE` times the last round's; both capped at 1. None: it
    settled."""
    if ran_off(trace):
        return RUNOFF_RANGE[0] * trace[1], min(RUNOFF_RANGE[1] * trace[1], 1.0)
    if still_rising(trace):
        return min(RISING_RANGE[0] * trace[-1], 1.0), min(RISING_RANGE[1] * trace[-1], 1.0)
    return None


def runoff_reflectance(
    presses: Sequence[Press],
    samples: Samples,
    leds0: Leds,
    loss: str,
    interreflection: str,
    bounces: int,
    rounds: int,
    left_out: Sequence[np.ndarray | None],
    bounds: tuple[float, float],
) -> float:
    """The coating reflectance whose whole rounds (:func:`indirect_rounds` from ``leds0`` with it set) leave the point
    LED fits the least summed squared residual (image units), within ``bounds`` (:func:`unsettled_range`). Bounded
    Brent search (scipy.optimize.minimize_scalar), each step a calibration's rounds.

    Why the whole rounds, not the LEDs' fit to one round's images: the reflectance and the LED that took up the term's
    light trade within a round (on the run-off twin capture the LED fits' residual was lower at its wrong round than at
    the first), while rounds held at a reflectance settle where that reflectance puts the LEDs: there the residual
    is least at the true one (summed squared RMS x 1e4: 2.49 at 0.6, 2.35 at 0.7, 2.32 at 0.8, 3.15 at 0.9, 4.27 at
    1.0; LEDs 0.48 mm off at 0.8, 3.2 mm at 0.9; benchmarks/RESULTS.md, s30-ledmargin). Each step's rounds are
    ``rounds`` only (not settled, :func:`moved_far`): the residual ranks the reflectances already (the twin 3 mm / 25
    deg off, seed 3: 1.855, 1.778, 1.757, 1.788, 1.867 x 1e-4 at 0.6-1.0), and the calibration at the chosen one
    settles."""
    from scipy.optimize import minimize_scalar

    def residual(a: float) -> float:
        fitted = indirect_rounds(presses, samples, leds0, loss, interreflection, bounces, rounds, float(a), left_out)[0]
        return summed_squares(fitted)

    best = minimize_scalar(residual, bounds=bounds, method="bounded", options={"xatol": RUNOFF_XTOL})
    return float(best.x)


def runoff_note(models: list[dict]) -> list[str]:
    """The warning for a calibration whose free reflectance ran off or was still rising and was chosen by
    :func:`runoff_reflectance` (the terms' ``reflectance_runoff``), or none."""
    for m in models:
        if run := m.get("reflectance_runoff"):
            rounds = ", ".join(f"{v:.3f}" for v in run["rounds"])
            what = (
                f"was still rising over the rounds ({rounds}): the LEDs, far from their starting places, had taken "
                "up part of the interreflection's light"
                if run["rounds"][-1] > run["rounds"][-2]
                else f"ran off over the rounds ({rounds}): an LED took up the interreflection's light"
            )
            return [
                f"the coating reflectance fitted with the LEDs {what}; chosen {run['chosen']:.3f} by whole fits at set "
                "reflectances instead: give --coating-reflectance if the coating's is known"
            ]
    return []


def _decide(model: IndirectModel):
    """The calibration's auto decision (:data:`tolerances.CALIBRATION_MIN_SHARE`) on a model fitted with the
    starting LEDs."""
    import dataclasses

    on = model.share >= tolerances.CALIBRATION_MIN_SHARE
    reason = model.reason.replace("interreflection on:", "interreflection off:") if not on else model.reason
    return dataclasses.replace(model, enabled=on, reason=reason)


def calibration_reason(model: IndirectModel, mode: str, first_share: float | None) -> IndirectModel:
    """``model`` with the rule of its ``reason`` in the LED calibration's terms.

    Why: :func:`.indirect.fit_indirect` names the solver's auto threshold (:data:`tolerances.INDIRECT_MIN_SHARE`,
    0.02), which the calibration's first round does not use (:data:`tolerances.CALIBRATION_MIN_SHARE`, 0.1, with
    the starting LEDs): `nlips calibrate-leds` printed "auto threshold 0.02" and "threshold 0.1" side by side.

    Parameters
    ----------
    model : a term fitted in a round of :func:`indirect_rounds` (the first round's after :func:`_decide`)
    mode : the calibration's ``interreflection``, "auto" or "on" (on: no threshold is named)
    first_share : the capture's share with the starting LEDs, the first round's; None: this is the first round
    """
    import dataclasses

    from .indirect import AUTO_THRESHOLD_SAID

    limit, later = tolerances.CALIBRATION_MIN_SHARE, tolerances.INDIRECT_MIN_SHARE
    if mode != "auto":
        said = ""
    elif first_share is None:
        side = "at least" if model.enabled else "below"
        said = f" with the starting LEDs ({side} the LED calibration's auto threshold {limit:g})"
    elif model.enabled:
        said = (
            f" (on since its share with the starting LEDs, {first_share:.3f}, reached the LED calibration's auto "
            f"threshold {limit:g})"
        )
    else:
        said = f" (below {later:g} with the refitted LEDs, after {first_share:.3f} with the starting LEDs)"
    return dataclasses.replace(model, reason=model.reason.replace(" " + AUTO_THRESHOLD_SAID, said))


def _sampled_indirect_light(
    presses: Sequence[Press], models: Sequence[IndirectModel], selections: Sequence[np.ndarray], count: int
) -> np.ndarray:
    """(L, N, 3) float -- each capture's own indirect light (its fitted term at its typical albedo; zero where the
    term is off) at its samples, pooled as :class:`Samples` pools them."""
    light = []
    for p, m, sel in zip(presses, models, selections):
        if not m.enabled:
            light.append(np.zeros((count, int(sel.sum()), 3)))
            continue
        light.append((m.undeformed_light(p.camera.shape) * np.asarray(m.off_view_albedo, np.float32))[:, sel])
    return np.concatenate(light, axis=1)


TERM_CHECK_SAMPLES = 2500
"""The term's check (:func:`term_gain`) fits every k-th sample, k the smallest that leaves at most this many: its
cost stays that of a 160x120 capture at stride 2-4 (1,200-4,800 samples, where its gain was measured) on larger
captures (test_interreflection.py's stride 1: ~19,000), and the gain, which grows with the samples, stays on the
scale it was measured on."""


def term_gain(
    samples: Samples,
    fitted: Sequence[tuple[np.ndarray, np.ndarray, float]],
    direct: np.ndarray,
    loss: str,
    quality: dict,
) -> float:
    """How much the indirect term lowers the point LED fits' summed squared residual against a direct-only fit, in
    units of each LED's noise variance (its noise and model error in quadrature, ``quality`` of
    :func:`.calibration_quality.fit_quality`).

    Both fits converged, on the same samples (every k-th, :data:`TERM_CHECK_SAMPLES`), from the term's LEDs: the
    term's fit again on them (when they are a subsample: neither fit then fits noise the other does not see) and a
    direct-only fit of the images. A term that only fits noise gains about a chi-squared with its 3 parameters; one
    that subtracts light that is not there loses (negative): LEDs started 0.8 mm / 10 deg off pose as 12-20 % of
    indirect light on a bounce-free capture, the term then fits every LED worse than direct light alone; on an
    interreflecting one it gains hundreds of variances although its direct-only LEDs end 17 deg off
    (benchmarks/RESULTS.md, s15-m and s17-d).

    Parameters
    ----------
    samples : the calibration's samples; fitted : per LED (params, std, rms), the term's fit (:func:`fit_leds`).
    direct : (L, N, 3) float -- the images minus the term's indirect light, linear.
    loss : the LED fit's robust loss; quality : :func:`.calibration_quality.fit_quality` of ``fitted``.
    """
    every = slice(None, None, -(-len(samples.x) // TERM_CHECK_SAMPLES))
    x, n, img, ok, lit = (
        samples.x[every],
        samples.n[every],
        samples.img[:, every],
        samples.ok[:, every],
        direct[:, every],
    )
    leds = to_leds(fitted)[0]
    on = fitted if every.step == 1 else fit_leds(leds, x, n, lit, ok, loss)
    off = fit_leds(leds, x, n, img, ok, loss)
    variance = np.asarray(quality["noise"]) ** 2 + np.asarray(quality["model_error"]) ** 2
    uses = [fit_samples(img[i], ok[i]) for i in range(len(leds))]  # the images' lit samples, for both fits

    def squares(fits: list, images: np.ndarray) -> np.ndarray:
        return np.array([np.sum((point_model(f[0], x, n) - im)[u] ** 2) for f, im, u in zip(fits, images, uses)])

    # an LED not fitted (no usable sample, led_fit.held_fit): no samples, its variance NaN: it gains nothing
    return float(np.nansum((squares(off, img) - squares(on, lit)) / variance))


def term_wins(direct: LedCalibration, on: LedCalibration) -> bool:
    """Whether the calibration with the indirect term explains the images (reliable) and better than ``direct``."""
    return on.quality["reliable"] and on.quality["median_ratio"] < direct.quality["median_ratio"]


def no_interreflection(models: list[dict], interreflection: str) -> str | None:
    """Why no capture's indirect term is on (one clause), or None when one is."""
    if any(m.get("enabled") for m in models):
        return None
    if interreflection == "off" or not models:
        return "the interreflection term is off (requested)"
    share = max(m["indirect_share"] for m in models)
    if any("term_gain" in m for m in models):  # on by the share, then off by term_gain
        return (
            f"the interreflection term did not explain the images better than direct light (fitted indirect share "
            f"{share:.3f} with the starting LEDs)"
        )
    return (
        f"no capture shows interreflection (fitted indirect share {share:.3f} with the starting LEDs, below "
        f"{tolerances.CALIBRATION_MIN_SHARE})"
    )


def unused_reflectance(
    models: list[dict], interreflection: str, reflectance: float | tuple[float, float, float] | None
) -> list[str]:
    """The warning for a coating reflectance given but not used.

    Not honoured on purpose: the reflectance sets the magnitude of the indirect term, and with the term off
    there is nothing to scale. On a capture the auto decision found without interreflection (a bounce-free
    render of the twin: share 0.014, where its one-bounce renders show 0.31-0.33) the term would subtract light
    that is not there; ``interreflection="on"`` forces it with the given reflectance (there, 160x120, 4 spp: worst
    LED 16.0 deg and 0.73 mm off against 0.54 deg and 0.25 mm, and :func:`.calibration_quality.fit_quality` cannot
    tell: 1.04).
    """
    from .indirect import checked_reflectance

    why = no_interreflection(models, interreflection)
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
    return []


def unprofiled_note(models: list[dict], interreflection: str, led_radius: float, reflectance: object) -> str | None:
    """The INFO line for LED disks whose coating reflectance was not profiled (no capture's indirect term on), or None.

    Not a warning since the disks are fitted by default from the design (s29-ledsize): on a capture without
    interreflection (the twin's bounce-free renders) there is no reflectance to choose, and the disks and points are
    fitted to the images as direct light alike; every such calibration warned."""
    why = no_interreflection(models, interreflection)
    if why is None or not led_radius > 0 or reflectance is not None or interreflection == "off":
        return None
    return f"LED disks fitted to the images as direct light, no coating reflectance profiled: {why}"


def emitters_and_profile(
    leds: Leds,
    samples: Samples,
    direct: np.ndarray,
    loss: str,
    led_radius: float,
    coating_reflectance: float | tuple[float, float, float] | None,
    models: list[dict],
) -> tuple[tuple[Led, ...], dict | None]:
    """(the LEDs fitted as disks of ``led_radius`` from the point ``leds``, or () without a radius; the
    reflectance profile (:func:`_profiled_reflectance`) when the reflectance is to be profiled, else None).
    ``models``: the captures' indirect terms as JSON."""
    if not led_radius > 0:
        return (), None
    # from the points (0.2 mm off at most): the disk fit only refines them, on every k-th sample (DISK_FIT_SAMPLES)
    x, n, ok = samples.x, samples.n, samples.ok
    every = slice(None, None, -(-len(x) // DISK_FIT_SAMPLES))
    disks = fit_leds(leds, x[every], n[every], direct[:, every], ok[:, every], loss, disk_model(led_radius))
    emitters = to_leds(disks)[0]
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
"""Range of the reflectance profile, as multiples of the freely fitted reflectance (:func:`_profiled_reflectance`).
A profile least at its top is searched again above it, over a range as many times wider (up to a reflectance of 1):
where the LEDs start far from their places the free fit can come out far low (the twin with its LEDs 3 mm / 25 deg
off the design, one bounce: 0.60 and 0.42 for 0.8, the profile then chose its top, 0.69 and 0.49, and the disks ended
2.2 and 7.9 deg off; benchmarks/RESULTS.md, s30-ledmargin)."""


PROFILE_XTOL = 0.01
"""The profile's tolerance on that multiple."""


DISK_FIT_SAMPLES = 10_000
"""The LED disk fits (the emitters and each step of the reflectance profile, :func:`_profiled_reflectance`) use every
k-th sample, k the smallest that leaves at most this many. Why: since the disks are fitted by default (a design that
declares its LEDs' size, s29-ledsize) their cost is every calibration's; a disk evaluates the point model at 7
places, so each fit cost 7x a point fit on all samples, and a 640x480 one-bounce calibration took 5.3x the CPU of
points only. The disk fit only refines the converged points (9 parameters an LED), which a few thousand samples
determine. Measured on the 320x240 one-bounce twin reference (~14,000 samples; CPU s / worst disk position mm / worst
axis deg / chosen reflectance, true 0.8; benchmarks/RESULTS.md): all samples (the profile on at most 20,000)
25.6 / 0.080 / 0.83 / 0.824; 10,000: 17.0 / 0.087 / 0.93 / 0.829; 5,000: 10.8-11.0 / 0.099 / 1.07 / 0.836; points
only 3.8. Fewer samples move the profile's reflectance up (every second of a 160x120 capture's ~3,400 moved it from
0.78 to 0.75, and its LED positions by 0.03 mm), and with it the point LEDs the solver uses."""


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
    :data:`DISK_FIT_SAMPLES` samples.

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
    every = slice(None, None, -(-len(x) // DISK_FIT_SAMPLES))
    xs, ns, imgs, lights, oks = x[every], n[every], img[:, every], light[:, every], ok[:, every]
    model = disk_model(radius)
    tried: dict[float, float] = {}

    def residual(s: float) -> float:
        out = fit_leds(emitters, xs, ns, imgs - s * lights, oks, loss, model)
        tried[float(s)] = summed_squares(out)
        return tried[float(s)]

    cap = 1.0 / float(np.max(fitted))  # a reflectance of at most 1
    low, top = PROFILE_SCALES[0], min(PROFILE_SCALES[1], cap)
    best = minimize_scalar(residual, bounds=(low, top), method="bounded", options={"xatol": PROFILE_XTOL})
    while best.x > top - 2 * PROFILE_XTOL and top < cap:  # least at the range's top: the minimum lies above it
        low, top = top, min(top * PROFILE_SCALES[1] / PROFILE_SCALES[0], cap)
        best = minimize_scalar(residual, bounds=(low, top), method="bounded", options={"xatol": PROFILE_XTOL})
    scales = sorted(tried)
    return {
        "fitted": [float(v) for v in fitted],
        "scales": [round(s, 4) for s in scales],
        "residuals": [tried[s] for s in scales],
        "chosen": [float(v) for v in np.minimum(fitted * float(best.x), 1.0)],
    }
