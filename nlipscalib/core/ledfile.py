"""The LED file (docs/formats.md "LED file"): calibrated LEDs and the sensor they were calibrated on.

Written by ``nlips calibrate-leds``, read by ``nlips solve|calibrate|capture --leds FILE``. In core with the
other formats: the pipeline, the CLI and the device capture read it, the solver only gets its LEDs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import NamedTuple

import numpy as np

from .atomic import write_json
from .errors import PATH, CaptureError, check_kind
from .leds import Led, Leds
from .sensor_record import check_sensor_record


def save_leds(path: str | Path, leds: Leds, extra: dict | None = None) -> Path:
    """Write an LED file atomically: {"leds": [Led.to_dict() ...], ...extra}; ``extra`` holds the calibration's
    other keys (``sensor``, ``quality``, ...). Returns ``path``."""
    check_kind(path, PATH, "path", "the LED file's path (str or Path)")
    check_kind(leds, (list, tuple), "leds", "a list of Led (calibrate_leds(...).leds, read_led_file(path).leds)")
    for i, led in enumerate(leds):
        check_kind(led, Led, f"leds[{i}]", "an Led (nlipscalib.core.leds.Led)")
    check_kind(extra, (dict, type(None)), "extra", "a dict of the file's other keys, or None")
    return write_json(path, {"leds": [led.to_dict() for led in leds]} | (extra or {}))


LED_FILE_BYTES_PER_LED = 2 << 10
"""An LED file's share per LED (its values, uncertainties, fit quality, disk emitters and sensor record, JSON
indented): 12 LEDs took 13.8 KB as points, 19.5 KB with disks (the design's size, by default, or ``--led-diameter``;
1.15-1.6 KB per LED; 160x120 reference of the default twin, 2026-12-05; 13.9 / 19.6 KB with ``led_model``, s29;
21.1 KB with disks and ``light_level``, s32)."""
LED_FILE_BYTES_BASE = 8 << 10
"""An LED file's share whatever its LEDs: gauge, albedo, each capture's interreflection model (~0.5 KB), warnings,
and the disk's block a file takes beyond its bytes (4 KiB)."""


def led_file_bytes(n_leds: int, n_captures: int = 1) -> int:
    """Room an LED file of ``n_leds`` LEDs calibrated from ``n_captures`` captures takes on the disk (bytes, an
    upper bound: ~1.5x the files measured), for the up-front free-space check of ``nlips calibrate-leds``."""
    return LED_FILE_BYTES_BASE + n_leds * LED_FILE_BYTES_PER_LED + n_captures * (1 << 10)


class LedFile(NamedTuple):
    """An LED file as read back: its LEDs and the sensor they were calibrated on."""

    leds: tuple[Led, ...]
    """The calibrated LEDs, in the capture's order."""
    sensor: dict | None
    """The capture's sensor description (:func:`nlipscalib.core.sensor_record.describe_sensor`: camera,
    LED count and design geometry); None in files written before it was recorded (2026-12-04)."""
    not_fitted: tuple[int, ...] = ()
    """The LEDs (0-based) the calibration could not fit and kept at their starting values (the file's
    ``not_fitted``: their image was a stale copy in every capture); empty when all were fitted."""
    emitters: tuple[Led, ...] = ()
    """The same LEDs fitted as disks (the file's ``emitters``: centres, axes, profiles), for a solve that models
    them so (``nlips solve --led-model disks``); empty when the calibration fitted none."""
    emitter_radius: float = 0.0
    """mm: the disks' radius (``emitters.radius_mm``); 0 without emitters."""
    light_level: dict | None = None
    """How bright the LEDs lit the gel in the captures calibrated (the file's ``light_level``:
    :func:`nlipscalib.core.led_change.light_level`); None in files written before it was recorded (2026-12-06)."""


LED_FILE_HINT = "give the .json from `nlips calibrate-leds`"
"""What an error about a file given as an LED file says to give instead."""

OTHER_FORMATS = {
    "nlipscalib.press": "a press's meta.json",
    "nlipscalib.reconstruction": "a reconstruction's report.json",
    "nlipscalib.calibration": "a calibration dataset's index.json",
    "nlipscalib.camera_response": "a camera response file",
    "nlipscalib.checksums": "a press's checksums.json",
}
"""The workbench's JSON files that carry a ``format`` (an LED file has none), by what a user calls them: given as
an LED file, a press's meta.json (which lists its design's LEDs too) read on to "'sensor' is not a sensor
description (missing key 'camera')", naming nothing of the mix-up."""


def _other_format(name: str) -> str:
    """What a JSON file of format ``name`` is, in a user's words."""
    return OTHER_FORMATS.get(name, f"a file of format {name!r}")


def read_led_file(path: str | Path) -> LedFile:
    """Read an LED file from ``nlips calibrate-leds`` (CaptureError naming it when missing or malformed)."""
    check_kind(path, PATH, "path", "the LED file's path (str or Path)")
    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(data, dict):
            raise ValueError(f"expected a JSON object with 'leds', got {type(data).__name__}")
        if isinstance(data.get("format"), str):  # an LED file has none: a press's meta.json also lists 'leds'
            raise CaptureError(f"{path}: {_other_format(data['format'])}, not an LED file: {LED_FILE_HINT}")
        if not isinstance(data.get("leds"), list):
            raise ValueError(f"'leds' must be a list of LEDs, got {data.get('leds')!r}")
        leds = tuple(Led.from_dict(d) for d in data["leds"])
        disks = data.get("emitters") or {}
        emitters = tuple(Led.from_dict(d) for d in disks.get("leds", ()))
        radius = float(disks.get("radius_mm", 0.0)) if emitters else 0.0
        if emitters and (len(emitters) != len(leds) or not radius > 0):
            raise ValueError(f"'emitters' must hold {len(leds)} LEDs and a radius_mm > 0")
    except CaptureError:  # said in full above: a NlipsError is a ValueError, not to be wrapped below
        raise
    except FileNotFoundError:
        raise CaptureError(f"{path}: no such LED file") from None
    except IsADirectoryError:
        raise CaptureError(f"{path}: a folder, not an LED file (the .json from `nlips calibrate-leds`)") from None
    except UnicodeDecodeError:  # a binary file (a model .pt, an image): the decoder's byte offsets tell a user nothing
        raise CaptureError(f"{path}: not an LED file (binary, not JSON): {LED_FILE_HINT}") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise CaptureError(f"{path}: not a valid LED file ({exc})") from None
    sensor = data.get("sensor")
    return LedFile(
        leds,
        None if sensor is None else check_sensor_record(sensor, path),
        _not_fitted(data, path, len(leds)),
        emitters,
        radius,
        _light_level(data, path, len(leds)),
    )


def _light_level(data: dict, path: Path, n_leds: int) -> dict | None:
    """The file's ``light_level``, checked (CaptureError naming the file when malformed); None when it has none."""
    level = data.get("light_level")
    if level is None:
        return None
    try:
        medians = np.asarray(level["gel_median"], dtype=float)
        exposure, gain = float(level["exposure_ms"]), float(level["gain"])
    except (KeyError, TypeError, ValueError) as exc:
        raise CaptureError(f"{path}: not a valid LED file ('light_level': {exc})") from None
    if medians.shape != (n_leds, 3) or not np.all(np.isfinite(medians)):
        raise CaptureError(f"{path}: not a valid LED file ('light_level.gel_median' must hold {n_leds} x 3 numbers)")
    return {"gel_median": medians.tolist(), "exposure_ms": exposure, "gain": gain}


def _not_fitted(data: dict, path: Path, n_leds: int) -> tuple[int, ...]:
    """The file's ``not_fitted`` LEDs (0-based), checked: CaptureError naming the file when malformed."""
    held = data.get("not_fitted", [])
    if not isinstance(held, list) or not all(isinstance(i, int) and 0 <= i < n_leds for i in held):
        raise CaptureError(f"{path}: not a valid LED file ('not_fitted' must list LED indices 0-{n_leds - 1})")
    return tuple(held)
