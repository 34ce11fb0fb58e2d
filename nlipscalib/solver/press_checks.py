"""Checks of :func:`nlipscalib.solver.press.solve_press`'s arguments, made before any work.

The pipeline makes the same checks before it looks for an earlier result (``nlipscalib.pipeline.settings``), so a bad
argument is refused before a capture is loaded or a result reused.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CaptureError, ConfigError, ShapeError
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
    if interreflection not in INTERREFLECTION_MODES:
        raise ConfigError(f"interreflection must be one of {INTERREFLECTION_MODES}, got {interreflection!r}")
    if bounces not in (1, 2):
        raise ConfigError(f"bounces must be 1 or 2, got {bounces}")
    if outer_relaxation != "auto" and not (isinstance(outer_relaxation, (int, float)) and 0 < outer_relaxation <= 2):
        raise ConfigError(f"outer_relaxation must be 'auto' or a number in (0, 2], got {outer_relaxation!r}")
    if coating_albedo is not None:
        values = np.atleast_1d(np.asarray(coating_albedo, float))
        if values.size not in (1, 3) or not np.all((values > 0) & (values <= 1)):
            raise ConfigError(
                "coating reflectance (--coating-reflectance) must be one value or three in (0, 1], "
                f"got {coating_albedo!r}"
            )


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
    try:
        x0, y0, w, h = (int(v) for v in roi)
    except (TypeError, ValueError):  # another count, or not numbers: "not enough values to unpack" from deep inside
        raise ShapeError(f"roi must be (x0, y0, w, h) pixels, 'auto' or None, got {roi!r}") from None
    if min(w, h) < MIN_ROI_SIDE or x0 < 0 or y0 < 0 or x0 + w > W or y0 + h > H:
        side = MIN_ROI_SIDE
        raise ShapeError(f"roi {tuple(roi)} must lie inside the {W}x{H} image and be at least {side}x{side} pixels")
    return x0, y0, w, h
