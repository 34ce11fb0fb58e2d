"""What changed between two LED calibrations of one sensor (``nlips calibrate-leds --previous OLD``).

A real sensor's LEDs age: a group on one driver channel dims by ~10 % over months. A calibration alone measures the
LEDs as they are now and cannot tell ageing from the LEDs' own spread; against an earlier calibration of the same
sensor it can. In core with the LED file it reads (:mod:`nlipscalib.core.ledfile`): the CLI wires it, the solver
only gets its LEDs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import tolerances
from .errors import CaptureError
from .ledfile import LedFile
from .leds import TRICOLOR_NAMES, Leds, led_arrays, led_offsets, tricolor_groups
from .sensor_record import leds_file_mismatch


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
    previous: LedFile, where: str | Path, leds: Leds, not_fitted: tuple[int, ...] | list[int] = ()
) -> dict:
    """The changes between an earlier calibration ``previous`` (read from ``where``) and the new LEDs ``leds``.

    A tri-colour group (:func:`~nlipscalib.core.leds.tricolor_groups`) whose median brightness ratio
    (:func:`led_brightness_ratios`) strays beyond :data:`~nlipscalib.core.tolerances.LED_GROUP_CHANGE` is one change
    (its LEDs aged together, as on one driver channel); an LED whose own ratio over its group's strays beyond
    :data:`~nlipscalib.core.tolerances.LED_BRIGHTNESS_CHANGE` is one; an LED that moved beyond
    :data:`~nlipscalib.core.tolerances.LED_MOVED_MM` or turned beyond ``LED_TURNED_DEG`` is one. LEDs either
    calibration did not fit (``not_fitted``, ``previous.not_fitted``) are not compared.

    Returns
    -------
    dict, JSON-ready (the LED file's ``previous``): ``file`` (``where``), ``brightness`` (L,) ratios, ``moved_mm`` (L,),
    ``turned_deg`` (L,) (NaN for an LED not compared), ``tolerances`` (the four), ``changes`` (one line per change, in
    LED order; empty when nothing changed beyond them).
    """
    left_out = set(previous.not_fitted) | {int(i) for i in not_fitted}
    ratio = led_brightness_ratios(previous.leds, leds, left_out)
    old, new = led_arrays(previous.leds), led_arrays(leds)
    moved, turned = led_offsets(old[0], old[1], new[0], new[1])
    moved[sorted(left_out)], turned[sorted(left_out)] = np.nan, np.nan
    changes = _brightness_changes(ratio, where) + _place_changes(moved, turned, where)
    return {
        "file": str(where),
        "brightness": [float(v) for v in ratio],
        "moved_mm": [float(v) for v in moved],
        "turned_deg": [float(v) for v in turned],
        "tolerances": {
            "group_brightness": tolerances.LED_GROUP_CHANGE,
            "led_brightness": tolerances.LED_BRIGHTNESS_CHANGE,
            "moved_mm": tolerances.LED_MOVED_MM,
            "turned_deg": tolerances.LED_TURNED_DEG,
        },
        "changes": [line for _, line in sorted(changes, key=lambda change: change[0])],
    }


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


def _place_changes(moved: np.ndarray, turned: np.ndarray, where: str | Path) -> list[tuple[int, str]]:
    """(LED, line) of each LED that moved or turned beyond the tolerances since ``where``."""
    # "not within": an LED whose axis has no angle (NaN) for a reason other than being left out is a change
    off = np.isfinite(moved) & (~(moved <= tolerances.LED_MOVED_MM) | ~(turned <= tolerances.LED_TURNED_DEG))
    return [
        (
            int(i),
            f"LED {i + 1} sits {moved[i]:.2f} mm and points {turned[i]:.1f} deg from where it did in {where} (beyond "
            f"{tolerances.LED_MOVED_MM:g} mm / {tolerances.LED_TURNED_DEG:g} deg): loosened, bent or replaced?",
        )
        for i in np.flatnonzero(off)
    ]
