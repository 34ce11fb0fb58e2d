"""Checks of :func:`nlipscalib.solver.press.solve_press`'s arguments, made before any work.

The pipeline makes the same checks before it looks for an earlier result (``nlipscalib.pipeline.settings``), so a bad
argument is refused before a capture is loaded or a result reused.
"""

from __future__ import annotations

import numbers
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core.errors import NUMBER, CaptureError, ConfigError, ShapeError, check_flag, check_kind, check_whole
from ..core.leds import led_geometry_mismatch
from ..core.sensor_record import surface_mismatch

if TYPE_CHECKING:  # names in hints only: the checks read the captures' attributes, whichever kind they are
    from ..core.capture import CaptureOptics, Press

INTERREFLECTION_MODES = ("auto", "on", "off")
MIN_ROI_SIDE = 4
"""Smallest width and height of an explicit ROI box, pixels (the API's and --roi's checks both state it)."""


def check_modes(
    interreflection: str,
    bounces: int,
    outer_relaxation: str | float,
    coating_albedo: float | Sequence[float] | None = None,
) -> None:
    """ConfigError when one of :func:`.press.solve_press`'s interreflection keywords is out of range (checked before any
    work, also by the pipeline before it looks for an earlier result)."""
    if not isinstance(interreflection, str) or interreflection not in INTERREFLECTION_MODES:
        raise ConfigError(f"interreflection must be one of {INTERREFLECTION_MODES}, got {interreflection!r}")
    if isinstance(bounces, bool) or not isinstance(bounces, numbers.Integral) or bounces not in (1, 2):
        raise ConfigError(f"bounces must be 1 or 2, got {bounces!r}")
    relaxation_number = isinstance(outer_relaxation, NUMBER) and not isinstance(outer_relaxation, bool)
    if outer_relaxation != "auto" and not (relaxation_number and 0 < outer_relaxation <= 2):
        raise ConfigError(f"outer_relaxation must be 'auto' or a number in (0, 2], got {outer_relaxation!r}")
    if coating_albedo is not None:
        values = _numbers(coating_albedo)
        if values is None or values.size not in (1, 3) or not np.all((values > 0) & (values <= 1)):
            raise ConfigError(
                "coating reflectance (--coating-reflectance) must be one value or three in (0, 1], "
                f"got {coating_albedo!r}"
            )


KEYWORD_KINDS = {
    "progress": "flag",
    "dent_interreflection": "flag",
    "reorder_leds": "flag",
    "check_sensor": "flag or None",
}
""":func:`.press.solve_press`'s keywords that are flags (a string such as "no" is truthy: it did the opposite)."""


def check_keywords(keywords: Mapping[str, Any], allowed: Sequence[str]) -> None:
    """One NlipsError naming the keyword when one of :func:`.press.solve_press`'s ``keywords`` is unknown (not in
    ``allowed``) or of another kind than it takes; checked before any work, also by the pipeline (its
    ``solver_keywords``) before it looks for an earlier result.

    Why: ``solve_press(press, max_outer="2")``, ``led_radius="1.8"``, ``emitters=3`` or ``light_gain=[1, 2]`` failed
    deep inside the solve (or after it, in the report), ``check_sensor="no"`` turned the check on, and a misspelt
    keyword was Python's TypeError naming the private ``_solve_press`` after the press's LED checks (s38-apikinds)."""
    from ..core.config import did_you_mean

    for name in keywords:
        if name not in allowed:
            hint = did_you_mean(name, list(allowed))
            raise ConfigError(f"solve_press has no keyword {name!r}{hint} (it takes {', '.join(sorted(allowed))})")
    for name, kind in KEYWORD_KINDS.items():
        if name in keywords:
            check_flag(keywords[name], name, none=kind == "flag or None")
    check_modes(*(keywords.get(k, d) for k, d in _MODE_DEFAULTS))
    if "max_outer" in keywords:
        check_whole(keywords["max_outer"], "max_outer", minimum=0)
    radius = keywords.get("led_radius", 0.0)
    check_kind(radius, NUMBER, "led_radius", "a number of mm (0: point LEDs)")
    if not (np.isfinite(radius) and radius >= 0):
        raise ConfigError(f"led_radius must be a finite radius >= 0 mm, got {radius}")
    emitters = keywords.get("emitters")
    if emitters is not None:
        _check_emitters(emitters)
    gain = keywords.get("light_gain")
    if gain is not None and ((values := _numbers(gain)) is None or values.shape != (3,)):
        raise ShapeError(f"light_gain must be 3 numbers (red, green, blue) or None, got {_kind_of(gain)}")


_MODE_DEFAULTS = (("interreflection", "auto"), ("bounces", 1), ("outer_relaxation", "auto"), ("coating_albedo", None))


def _check_emitters(emitters: object) -> None:
    """ShapeError unless ``emitters`` is a sequence of Led or of their dicts (an LED file's ``emitters``)."""
    from ..core.leds import Led

    ok = isinstance(emitters, (Sequence, np.ndarray)) and not isinstance(emitters, str)
    if not ok or not all(isinstance(e, (Led, dict)) for e in emitters):
        raise ShapeError(
            "emitters must be a sequence of Led (calibrate_leds(reference).emitters) or their dicts, "
            f"got {_kind_of(emitters)}"
        )


def _numbers(value: object) -> np.ndarray | None:
    """``value`` (a number or a sequence of them) as a float array, or None when it is anything else (a string,
    which NumPy converts: "0.5" passed for 0.5)."""
    if isinstance(value, (str, bytes, bool)):
        return None
    try:
        values = np.atleast_1d(np.asarray(value))
    except (TypeError, ValueError):
        return None
    if values.dtype.kind not in "iuf":
        return None
    return values.astype(float)


def _kind_of(value: object) -> str:
    """``value``'s kind and a short repr of it, for the messages above."""
    import reprlib

    return f"{type(value).__name__} {reprlib.repr(value)}"


def check_undeformed(press: Press | CaptureOptics, undeformed: Press | CaptureOptics) -> None:
    """CaptureError naming ``undeformed`` unless it is an undeformed capture of ``press``'s sensor.

    Parameters
    ----------
    press, undeformed : core.Press or core.capture.CaptureOptics
        Anything with ``folder``, ``camera``, ``leds`` and ``reference``: the pipeline checks the captures'
        optics before it says anything about an earlier result, the solver the loaded presses.
    """
    why = optics_difference(undeformed, press)
    if why:
        raise CaptureError(f"{undeformed.folder}: not a capture of the sensor of {press.folder} ({why})")
    if undeformed.reference is None:
        raise CaptureError(f"{undeformed.folder}: the undeformed capture needs its reference surface (reference.npz)")
    why = _other_sensor(press, undeformed)
    if why:
        raise CaptureError(f"{undeformed.folder}: not a capture of the sensor of {press.folder} ({why})")


def optics_difference(capture: Press | CaptureOptics, other: Press | CaptureOptics) -> str | None:
    """How ``capture``'s camera or LED count differs from ``other``'s, in words, or None when they are the same.

    Why: "camera or LED count differs" left the user to find which, when the usual cause is a capture of another
    image size (``--width 160 --height 120`` on one command and not on the other).
    """
    a, b = capture.camera, other.camera
    if (a.width, a.height) != (b.width, b.height):
        return f"its images are {a.width}x{a.height} pixels, those of {other.folder} {b.width}x{b.height}"
    if a != b:
        return f"its camera's intrinsics or lens distortion differ from those of {other.folder}"
    if len(capture.leds) != len(other.leds):
        return f"it has {len(capture.leds)} LEDs, {other.folder} {len(other.leds)}"
    return None


def _other_sensor(press: Press | CaptureOptics, undeformed: Press | CaptureOptics) -> str | None:
    """Why ``undeformed`` is not a capture of ``press``'s sensor (LED geometry, undeformed surface), or None."""
    why = led_geometry_mismatch(
        [led.position for led in press.leds],
        [led.direction for led in press.leds],
        [led.position for led in undeformed.leds],
        [led.direction for led in undeformed.leds],
    )
    if why or press.reference is None:
        return why
    return surface_mismatch(press.reference.depth, undeformed.reference.depth)


def check_roi(roi: Sequence[int], W: int, H: int) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) as ints; ShapeError unless the box lies inside the W x H image and is at least 4x4."""
    x0, y0, w, h = roi_numbers(roi)
    if min(w, h) < MIN_ROI_SIDE or x0 < 0 or y0 < 0 or x0 + w > W or y0 + h > H:
        side = MIN_ROI_SIDE
        raise ShapeError(f"roi {tuple(roi)} must lie inside the {W}x{H} image and be at least {side}x{side} pixels")
    return x0, y0, w, h


def roi_numbers(roi: object) -> tuple[int, int, int, int]:
    """An explicit ROI box (x0, y0, w, h) as four ints; ShapeError unless it is four whole numbers of pixels (not
    2.5, which ``int`` turned into 2, nor "10" or True)."""
    whole = (
        isinstance(roi, (Sequence, np.ndarray))
        and not isinstance(roi, str)
        and len(roi) == 4
        and all(isinstance(v, numbers.Integral) and not isinstance(v, (bool, np.bool_)) for v in roi)
    )
    if not whole:  # another count, or not whole numbers: "not enough values to unpack" from deep inside
        raise ShapeError(f"roi must be (x0, y0, w, h) pixels, 'auto' or None, got {roi!r}")
    return tuple(int(v) for v in roi)
