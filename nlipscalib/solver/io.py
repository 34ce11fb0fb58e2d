"""Saving solver results next to a press (the core reconstruction format) and LED parameter files.

No figures here: nlipscalib.report draws them (the CLI passes them in as ``extra_files``)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

from ..core.leds import Led, Leds
from ..core.reconstruction import (
    Reconstruction,
    load_reconstruction,
    save_reconstruction,
)
from ..errors import CaptureError


def save_result(
    result: Reconstruction,
    folder: str | Path,
    *,
    overwrite: bool = False,
    extra_files: Callable[[Path], object] | None = None,
) -> Path:
    """Write the reconstruction atomically into ``folder`` (core.reconstruction.save_reconstruction).

    ``extra_files(tmp_folder)`` may add files (figures) that appear together with the result.
    """
    return save_reconstruction(result, folder, overwrite, extra_files)


def load_result(folder: str | Path) -> Reconstruction:
    return load_reconstruction(folder)


def save_leds(path: str | Path, leds: Leds, extra: dict | None = None) -> Path:
    """Write an LED file: {"leds": [Led.to_dict() ...], ...extra} (``nlips solve --leds FILE``)."""
    from ..core.atomic import write_json

    return write_json(path, {"leds": [led.to_dict() for led in leds]} | (extra or {}))


class LedFile(NamedTuple):
    """An LED file as read back: its LEDs and the sensor they were calibrated on."""

    leds: tuple[Led, ...]
    """The calibrated LEDs, in the capture's order."""
    sensor: dict | None
    """The capture's sensor description (:func:`nlipscalib.core.sensor_record.describe_sensor`: camera,
    LED count and design geometry); None in files written before it was recorded (2026-12-04)."""


def load_leds(path: str | Path) -> tuple[Led, ...]:
    """The LEDs of an LED file (:func:`read_led_file`)."""
    return read_led_file(path).leds


def read_led_file(path: str | Path) -> LedFile:
    """Read an LED file from ``nlips calibrate-leds`` (CaptureError naming it when missing or malformed)."""
    from ..core.sensor_record import check_sensor_record

    path = Path(path)
    try:
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"expected a JSON object with 'leds', got {type(data).__name__}")
        if not isinstance(data.get("leds"), list):
            raise ValueError(f"'leds' must be a list of LEDs, got {data.get('leds')!r}")
        leds = tuple(Led.from_dict(d) for d in data["leds"])
    except FileNotFoundError:
        raise CaptureError(f"{path}: no such LED file") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CaptureError(f"{path}: not a valid LED file ({exc})") from None
    sensor = data.get("sensor")
    return LedFile(leds, None if sensor is None else check_sensor_record(sensor, path))
