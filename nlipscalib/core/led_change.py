"""What changed between two LED calibrations of one sensor (``nlips calibrate-leds --previous OLD``).

A real sensor's LEDs age: a group on one driver channel dims by ~10 % over months. A calibration alone measures the
LEDs as they are now and cannot tell ageing from the LEDs' own spread; against an earlier calibration of the same
sensor it can. In core with the LED file it reads (:mod:`nlipscalib.core.ledfile`): the CLI wires it, the solver
only gets its LEDs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from . import tolerances
from .errors import CaptureError
from .ledfile import LedFile
from .leds import TRICOLOR_NAMES, Leds, led_arrays, led_offsets, tricolor_groups
from .sensor_record import leds_file_mismatch

if TYPE_CHECKING:
    from .capture import Press


def check_previous_sensor(previous: LedFile, where: str | Path, sensor: dict, captures: str) -> None:
    """Refuse (CaptureError, one line naming ``where``) an earlier LED file of another sensor than ``sensor`` (the
    captures being calibrated: :func:`nlipscalib.core.sensor_record.sensor_of`), or one that records none.

    Why: brightness and place compared across two sensors say nothing about either. The check `nlips solve --leds`
    makes (:func:`~nlipscalib.core.sensor_record.leds_file_mismatch`)."""
    if previous.sensor is None:
        raise CaptureError(
            f"--previous {where}: records no sensor (written before 2026-12-04), so it cannot be told to be a "
            f"calibration of the sensor of {captures}; compare with a newer LED file, or calibrate without --previous"
        )
    why = leds_file_mismatch(previous.sensor, previous.leds, sensor)
    if why:
        raise CaptureError(
            f"--previous {where}: calibrated on another sensor than {captures} ({why}); give an earlier LED file of "
            "this sensor"
        )


def light_level(presses: Sequence[Press], order: Sequence[int] | None = None) -> dict:
    """How bright the LEDs light the undeformed gel, in the capture's own units: the LED file's ``light_level``.

    Why not the calibration's Psi or albedo: Psi is gauged to mean 1 per channel, and the albedo that then carries the
    scale trades against the coating's fitted reflectance (3.9 % between two noise seeds of one dome); the images'
    median over the gel repeats to 0.2 % (benchmarks/RESULTS.md, s32-prevbright).

    Parameters
    ----------
    presses : sequence of Press -- the undeformed captures calibrated (with their reference: the gel's pixels are
        those its depth covers; all pixels without one).
    order : sequence of int, length L, or None -- the image (0-based) each LED was fitted to, where the calibration
        found them out of order (its ``led_order``); None: as captured.

    Returns
    -------
    dict, JSON-ready: ``gel_median`` (L, 3) per LED and channel, its linear light above the dark frame (1 = the
    sensor's full range), median over the gel's pixels, mean over the captures; ``exposure_ms``, ``gain``: the first
    capture's camera settings (meta.json ``sensor``), which scale it.
    """
    medians = []
    for press in presses:
        depth = None if press.reference is None else press.reference.depth
        gel = np.ones(press.camera.shape, bool) if depth is None else np.isfinite(depth)
        medians.append(np.median(press.linear_led_images[:, gel], axis=1))  # (L, 3)
    response = presses[0].response
    level = np.mean(medians, axis=0)
    return {
        "gel_median": (level if order is None else level[list(order)]).tolist(),
        "exposure_ms": float(response.exposure_ms),
        "gain": float(response.gain),
    }


def overall_brightness_ratio(previous: dict, level: dict, left_out: set[int] | frozenset[int] = frozenset()) -> float:
    """The light of all LEDs alike now over in ``previous`` (two :func:`light_level` records): per channel the median
    LED's ratio (the scale :func:`led_brightness_ratios` divides out: an LED's change is this times its share's), then
    the geometric mean over the channels. LEDs in ``left_out`` are not counted; NaN when none are left.

    Why the median LED's, not the sum's: one tri-colour group aged to 0.9 moved the sum of 12 LEDs to 0.967, named
    a second time as all LEDs dimmed."""
    old, new = np.asarray(previous["gel_median"], float), np.asarray(level["gel_median"], float)
    if old.shape != new.shape:
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = new / old
    ratio[sorted(left_out)] = np.nan
    if not np.isfinite(ratio).any():
        return float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(np.exp(np.mean(np.log(np.nanmedian(ratio, axis=0)))))


def led_brightness_ratios(previous: Leds, leds: Leds, left_out: set[int] | frozenset[int] = frozenset()) -> np.ndarray:
    """Each LED's brightness now over in ``previous``, relative to the median LED.

    Both calibrations are in the gauge mean Psi = 1 per channel (the albedo takes the scale), so only the LEDs'
    shares of the light compare: per channel, each LED's Psi ratio over the median LED's; then the geometric mean
    over the channels (an aged LED dims in all three). ``left_out`` (0-based: LEDs either calibration could not fit,
    kept at starting values) are NaN and set no scale.

    Parameters
    ----------
    previous, leds : sequence of Led, length L -- the earlier and the new calibration of one sensor.

    Returns
    -------
    (L,) float64 -- 1 for an LED as bright as before, 0.9 for one 10 % dimmer than the others' change.
    """
    old, new = led_arrays(previous)[3], led_arrays(leds)[3]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = new / old
    ratio[sorted(left_out)] = np.nan
    ratio /= np.nanmedian(ratio, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.exp(np.mean(np.log(ratio), axis=1))


def _changed(ratio: float, tolerance: float) -> bool:
    """Whether a brightness ratio strays from 1 by more than ``tolerance`` (as a fraction, either way alike)."""
    return bool(abs(np.log(ratio)) > np.log1p(tolerance))


def compare_calibrations(
    previous: LedFile,
    where: str | Path,
    leds: Leds,
    not_fitted: tuple[int, ...] | list[int] = (),
    level: dict | None = None,
    emitters: Leds = (),
) -> dict:
    """The changes between an earlier calibration ``previous`` (read from ``where``) and the new LEDs ``leds``.

    A tri-colour group (:func:`~nlipscalib.core.leds.tricolor_groups`) whose median brightness ratio
    (:func:`led_brightness_ratios`) strays beyond :data:`~nlipscalib.core.tolerances.LED_GROUP_CHANGE` is one change
    (its LEDs aged together, as on one driver channel); an LED whose own ratio over its group's strays beyond
    :data:`~nlipscalib.core.tolerances.LED_BRIGHTNESS_CHANGE` is one; an LED that moved beyond
    :data:`~nlipscalib.core.tolerances.LED_MOVED_MM` or turned beyond ``LED_TURNED_DEG`` is one. LEDs either
    calibration did not fit (``not_fitted``, ``previous.not_fitted``) are not compared. All LEDs' light together
    (``level`` against ``previous.light_level``, :func:`light_level`) straying beyond
    :data:`~nlipscalib.core.tolerances.LED_OVERALL_CHANGE` is one change, first: the shares cannot see it.

    The places are the LED disks' (``emitters``, ``previous.emitters``: the physical LEDs) where both calibrations
    fitted disks, else the point LEDs'; both repeat alike (the twin's 21 pairs of clean calibrations at 160x120:
    disks 0.085 mm / 0.57 deg median, 0.43 mm / 2.65 deg at worst; points 0.087 / 0.57, 0.43 / 2.64; s33-ledswap), so
    one set of tolerances serves both. What only one file holds is not compared, and said (``not_compared``): an
    OLD file written before ``light_level`` (2026-12-06) cannot have all LEDs' light judged, disks in one file only
    are compared as points.

    Returns
    -------
    dict, JSON-ready (the LED file's ``previous``): ``file`` (``where``), ``brightness`` (L,) ratios, ``moved_mm`` (L,),
    ``turned_deg`` (L,) (NaN for an LED not compared), ``places`` ("disks" or "points": which LEDs' places those
    are), ``overall_brightness`` (all LEDs' light over OLD's; None where either file has no ``light_level``),
    ``not_compared`` (what either file lacks, in words: one item each; empty when all was compared), ``tolerances``
    (the five), ``changes`` (one line per change, the overall one first, then in LED order; empty when nothing changed
    beyond them).
    """
    left_out = set(previous.not_fitted) | {int(i) for i in not_fitted}
    ratio = led_brightness_ratios(previous.leds, leds, left_out)
    disks = bool(previous.emitters) and len(emitters) == len(previous.emitters)
    old, new = (
        (led_arrays(previous.emitters), led_arrays(emitters))
        if disks
        else (led_arrays(previous.leds), led_arrays(leds))
    )
    moved, turned = led_offsets(old[0], old[1], new[0], new[1])
    moved[sorted(left_out)], turned[sorted(left_out)] = np.nan, np.nan
    overall = None
    if level is not None and previous.light_level is not None:
        overall = overall_brightness_ratio(previous.light_level, level, left_out)
    changes = _overall_change(overall, previous.light_level, level, where)
    changes += _brightness_changes(ratio, where) + _place_changes(moved, turned, where, old, new)
    return {
        "file": str(where),
        "overall_brightness": None if overall is None or overall != overall else overall,
        "brightness": [float(v) for v in ratio],
        "moved_mm": [float(v) for v in moved],
        "turned_deg": [float(v) for v in turned],
        "places": "disks" if disks else "points",
        "not_compared": not_compared(previous, where, level, bool(emitters)),
        "tolerances": {
            "overall_brightness": tolerances.LED_OVERALL_CHANGE,
            "group_brightness": tolerances.LED_GROUP_CHANGE,
            "led_brightness": tolerances.LED_BRIGHTNESS_CHANGE,
            "moved_mm": tolerances.LED_MOVED_MM,
            "turned_deg": tolerances.LED_TURNED_DEG,
        },
        "changes": [line for _, line in sorted(changes, key=lambda change: change[0])],
    }


def not_compared(previous: LedFile, where: str | Path, level: dict | None, disks: bool) -> list[str]:
    """What :func:`compare_calibrations` could not compare, one item each in words: all LEDs' light together where
    ``previous`` (read from ``where``) records no ``light_level`` (written before 2026-12-06) or the new calibration
    none (``level`` None), and the LED disks where only one of the two fitted them (``disks``: the new one did).

    Why said: against a file written before ``light_level``, every LED dimmed alike read "no LED changed beyond the
    tolerances" as if it had been judged (s33-ledswap's run with s32-ledaged's r8.json)."""
    items = []
    if previous.light_level is None:
        items.append(f"all LEDs' light together ({where} records no light_level: written before 2026-12-06)")
    elif level is None:
        items.append("all LEDs' light together (this calibration records no light_level)")
    if bool(previous.emitters) != disks:
        holder = where if previous.emitters else "this calibration"
        items.append(f"the LED disks (only {holder} holds them: the places compared as point LEDs)")
    return items


def _overall_change(
    overall: float | None, old: dict | None, new: dict | None, where: str | Path
) -> list[tuple[int, str]]:
    """(-1, line) when all LEDs' light together changed beyond the tolerance since ``where``: sorted before LED 1."""
    if overall is None or overall != overall or not _changed(overall, tolerances.LED_OVERALL_CHANGE):
        return []
    settings = [(old[key], new[key]) for key in ("exposure_ms", "gain")]
    if any(a != b for a, b in settings):
        (t0, t1), (g0, g1) = settings
        cause = f"the camera's exposure or gain changed ({t0:g} ms at gain {g0:g}, now {t1:g} ms at gain {g1:g})"
    else:
        cause = "every LED aged alike, their drive changed, or the camera's exposure, gain or aperture (not recorded)"
    tol = tolerances.LED_OVERALL_CHANGE * 100
    return [
        (
            -1,
            f"all LEDs together give {overall:.2f} times the light they gave in {where} (the gel's median above the "
            f"dark frame; beyond the {tol:g} % a calibration repeats to): {cause}",
        )
    ]


def _brightness_changes(ratio: np.ndarray, where: str | Path) -> list[tuple[int, str]]:
    """(first LED, line) of each group and LED whose brightness changed beyond the tolerances."""
    groups = tricolor_groups(len(ratio))
    changes = []
    for g in np.unique(groups):
        members = np.flatnonzero((groups == g) & np.isfinite(ratio))
        if not members.size:
            continue
        median = float(np.median(ratio[members]))
        group_tol, led_tol = tolerances.LED_GROUP_CHANGE * 100, tolerances.LED_BRIGHTNESS_CHANGE * 100
        if _changed(median, tolerances.LED_GROUP_CHANGE):
            first, last = int(members[0]) + 1, int(members[-1]) + 1
            changes.append(
                (
                    first - 1,
                    f"LEDs {first}-{last} (the {TRICOLOR_NAMES[g]} tri-colour group) give {median:.2f} times the "
                    f"share of the light they gave in {where} (median; beyond the {group_tol:g} % "
                    "a calibration repeats to): aged together (one driver channel?) or their drive changed",
                )
            )
        else:
            median = 1.0  # within: each LED judged on its own against the others
        for i in members:
            own = float(ratio[i] / median)
            if _changed(own, tolerances.LED_BRIGHTNESS_CHANGE):
                changes.append(
                    (
                        int(i),
                        f"LED {i + 1} gives {ratio[i]:.2f} times the share of the light it gave in {where} (beyond the "
                        f"{led_tol:g} % an LED's calibration repeats to): aged, replaced "
                        "or partly covered?",
                    )
                )
    return changes


def _place_changes(
    moved: np.ndarray, turned: np.ndarray, where: str | Path, old: tuple[np.ndarray, ...], new: tuple[np.ndarray, ...]
) -> list[tuple[int, str]]:
    """(LED, line) of each LED that moved or turned beyond the tolerances since ``where``; two LEDs that each sit
    where the other did (``old``, ``new``: :func:`~nlipscalib.core.leds.led_arrays` of either calibration) are one
    line, naming an exchange.

    Why the exchange: two LED images captured in each other's place (wiring or the firmware's LED order changed)
    calibrate each LED at the other's place, as the images show it; said as two LEDs "loosened, bent or replaced"
    4.6 mm apart it sent a user to the hardware (s32-prevbright's trial with led_01.png and led_02.png exchanged)."""
    # "not within": an LED whose axis has no angle (NaN) for a reason other than being left out is a change
    off = np.isfinite(moved) & (~(moved <= tolerances.LED_MOVED_MM) | ~(turned <= tolerances.LED_TURNED_DEG))
    pairs = _exchanged_pairs(np.flatnonzero(off), old, new)
    paired = {i for pair in pairs for i in pair}
    lines = [
        (
            int(a),
            f"LEDs {a + 1} and {b + 1} each sit where the other did in {where} (within {tolerances.LED_MOVED_MM:g} mm"
            f" / {tolerances.LED_TURNED_DEG:g} deg): their images were captured in each other's place (the LED "
            "wiring, the controller's LED order or the capture's image order changed since): put the order back, "
            "or keep this calibration only for captures taken in the new order",
        )
        for a, b in pairs
    ]
    return lines + [
        (
            int(i),
            f"LED {i + 1} sits {moved[i]:.2f} mm and points {turned[i]:.1f} deg from where it did in {where} (beyond "
            f"{tolerances.LED_MOVED_MM:g} mm / {tolerances.LED_TURNED_DEG:g} deg): loosened, bent or replaced?",
        )
        for i in np.flatnonzero(off)
        if i not in paired
    ]


def _exchanged_pairs(
    candidates: np.ndarray, old: tuple[np.ndarray, ...], new: tuple[np.ndarray, ...]
) -> list[tuple[int, int]]:
    """Pairs (a, b), a < b, of ``candidates`` (LEDs that moved) where each new LED lies within the place
    tolerances of the other's old one."""

    def near(i: int, j: int) -> bool:  # the new LED i where the old LED j was
        gap, turn = led_offsets(old[0][[j]], old[1][[j]], new[0][[i]], new[1][[i]])
        return bool(gap[0] <= tolerances.LED_MOVED_MM and turn[0] <= tolerances.LED_TURNED_DEG)

    pairs: list[tuple[int, int]] = []
    for a in candidates:
        for b in candidates:
            taken = any(int(a) in pair or int(b) in pair for pair in pairs)
            if a < b and not taken and near(a, b) and near(b, a):
                pairs.append((int(a), int(b)))
    return pairs
