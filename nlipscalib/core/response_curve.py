"""A camera's measured tone curve (``nlips calibrate-camera-response``): its file (docs/formats.md, "Camera response
file"), the checks every copy of it passes, and its name in meta.json (``sensor.camera_response``
"measured:<hash>", the curve beside it in ``sensor.response_curve``).

A curve is the light each encoded value stands for: entry ``k`` of ``N`` (256 for an 8-bit camera, 65536 for a
16-bit table) is the linear light, as a fraction of full scale, of the encoded fraction ``k / (N - 1)`` between
the sensor's black level (0) and white level (1). So it starts at 0, ends at 1 and never falls. A camera whose
red, green and blue responses differ has one such curve per channel: a (3, N) array, R, G, B (response file
version 2, meta.json format_version 3)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .errors import CaptureError

RESPONSE_FORMAT = "nlipscalib.camera_response"
RESPONSE_VERSION = 2
"""The response file's version: 2 added per-channel curves (``response_curve`` a list of three lists, R, G, B). A
file of one curve is still written as version 1 (:func:`write_response_file`), as every reader reads it."""
READ_VERSIONS = (1, RESPONSE_VERSION)
"""The versions :func:`read_response_file` reads."""
MEASURED_PREFIX = "measured:"
"""meta.json's ``sensor.camera_response`` of a measured curve: this prefix and :func:`curve_id` of the curve."""
CURVE_LENGTHS = (256, 65536)
"""Entries a curve may have: one per 8-bit code, or one per 16-bit stored value."""
CURVE_DIP_TOLERANCE = 1e-9
"""How far a stored curve may fall from one entry to the next (fraction of full scale): none, beyond rounding.
The fit makes its curve monotonic (``device.response_fit``); a falling one is a damaged or hand-edited file."""


def curve_id(curve: Sequence | np.ndarray) -> str:
    """The name a measured curve goes by in meta.json and in models: :data:`MEASURED_PREFIX` and the first 12 hex
    digits of the SHA-256 of its float64 values (little-endian; a per-channel curve's R, G and B in turn). Two
    captures share a response only when they share the curve, bit for bit
    (``core.sensor_record.response_mismatch``)."""
    data = np.ascontiguousarray(curve, dtype="<f8").tobytes()
    return MEASURED_PREFIX + hashlib.sha256(data).hexdigest()[:12]


def is_measured(camera_response: str) -> bool:
    """Whether ``camera_response`` names a measured curve (``"measured:<hash>"``), not "linear" or "srgb"."""
    return isinstance(camera_response, str) and camera_response.startswith(MEASURED_PREFIX)


def check_curve(curve: object, name: str | None = None) -> tuple:
    """``curve`` as a tuple of floats (one curve) or of three such tuples (R, G, B), checked: each 256 or 65536
    finite entries from 0 to 1 that never fall, and, when ``name`` is given, the curve that name (:func:`curve_id`)
    was made from.

    Raises
    ------
    ValueError naming what is wrong (the caller names the file).
    """
    lengths = " or ".join(map(str, CURVE_LENGTHS))
    if isinstance(curve, (str, bytes)) or not isinstance(curve, Sequence | np.ndarray):
        raise ValueError(f"response_curve must be a list of {lengths} numbers (or three such lists: R, G, B)")
    try:
        values = np.asarray(curve, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError("response_curve must hold numbers only (or three lists of numbers of one length)") from None
    if values.ndim not in (1, 2) or values.shape[-1] not in CURVE_LENGTHS or values.ndim == 2 and len(values) != 3:
        raise ValueError(f"response_curve must have {lengths} entries (or be three such lists), got {values.shape}")
    channels = values.reshape(-1, values.shape[-1])
    if not np.all(np.isfinite(values)) or (channels[:, 0] != 0.0).any() or (channels[:, -1] != 1.0).any():
        raise ValueError("response_curve must be finite numbers from 0 (black) to 1 (white)")
    for c, channel in enumerate(channels):
        if (np.diff(channel) < -CURVE_DIP_TOLERANCE).any():
            at = int(np.argmax(np.diff(channel) < -CURVE_DIP_TOLERANCE))
            which = f" ({'RGB'[c]})" if values.ndim == 2 else ""
            raise ValueError(f"response_curve{which} falls at entry {at + 1} (a camera's response never does)")
    if name is not None and curve_id(values) != name:
        raise ValueError(f"response_curve is not the curve {name} (its hash is {curve_id(values)}): edited or damaged")
    if values.ndim == 2:
        return tuple(tuple(float(v) for v in channel) for channel in values)
    return tuple(float(v) for v in values)


def per_channel(curve: Sequence | np.ndarray) -> bool:
    """Whether ``curve`` (checked, :func:`check_curve`) is one curve per channel (R, G, B), not one for all."""
    return np.ndim(curve) == 2


def curve_json(curve: Sequence | np.ndarray) -> list:
    """``curve`` as JSON writes and reads it: a list of floats, or three such lists (R, G, B)."""
    if per_channel(curve):
        return [[float(v) for v in channel] for channel in curve]
    return [float(v) for v in curve]


def measured_table(curve: Sequence | np.ndarray, black_level: float, white_level: float) -> np.ndarray:
    """The stored value each stored value of a measured-curve camera stands for in light: (65536,) uint16, or
    (65536, 3) for a per-channel curve (a column per channel, R, G, B), as ``core.sensor_response.tone_curve_table``
    makes for sRGB (black and white levels kept, values above white kept as they are, rounded to whole 16-bit
    steps). Between entries the curve is interpolated linearly: an 8-bit camera's stored values (``DN << 8``) fall
    on its entries exactly."""
    values = np.asarray(curve, dtype=np.float64)
    if values.ndim == 2:
        return np.stack([measured_table(channel, black_level, white_level) for channel in values], axis=1)
    stored = np.arange(65536, dtype=np.float64)
    span = white_level - black_level
    encoded = np.clip((stored - black_level) / span, 0.0, 1.0)
    linear = black_level + span * np.interp(encoded, np.linspace(0.0, 1.0, len(values)), values)
    linear = np.where(stored >= white_level, stored, np.where(stored < black_level, stored, linear))
    return np.clip(np.rint(linear), 0, 65535).astype(np.uint16)


@dataclasses.dataclass(frozen=True)
class MeasuredResponse:
    """A camera response file: the curve and where it came from."""

    curve: tuple
    """Linear light (fraction of full scale) of each encoded fraction ``k / (N - 1)``, N = 256 or 65536: a tuple of
    N floats, or three such tuples (R, G, B) for a camera whose channels respond differently."""
    provenance: dict
    """Camera, date, exposures (ms), LED, fit method, fit residual, monotonic check: as measured, not read back."""

    @property
    def name(self) -> str:
        """meta.json's ``sensor.camera_response`` for this curve (:func:`curve_id`)."""
        return curve_id(self.curve)


def write_response_file(path: str | Path, response: MeasuredResponse) -> Path:
    """Write ``response`` as a camera response file (atomic: a reader sees the old file or the whole new one):
    version 1 for one curve, as before; 2 for a per-channel one (a reader of version 1 only refuses it, rather than
    read three curves as one)."""
    from .atomic import write_text

    doc = {
        "format": RESPONSE_FORMAT,
        "format_version": RESPONSE_VERSION if per_channel(response.curve) else 1,
        "camera_response": response.name,
        "provenance": response.provenance,
        "response_curve": curve_json(response.curve),
    }
    return write_text(path, json.dumps(doc, indent=1) + "\n")


def read_response_file(path: str | Path) -> MeasuredResponse:
    """A camera response file (:func:`write_response_file`), checked (:func:`check_curve`).

    Raises
    ------
    CaptureError -- one line naming the file: missing, not JSON, another format, or a curve that is no response.
    """
    from .formatfile import read_format_json

    path = Path(path)
    if path.is_dir():
        raise CaptureError(f"{path}: a folder, not a camera response file (from `nlips calibrate-camera-response`)")
    doc = read_format_json(
        path,
        RESPONSE_FORMAT,
        READ_VERSIONS,
        required=("camera_response", "response_curve"),
        missing_hint="measure one with `nlips calibrate-camera-response`",
    )
    provenance = doc.get("provenance", {})
    try:
        if not is_measured(doc["camera_response"]):
            raise ValueError(f"camera_response must be {MEASURED_PREFIX}<hash>, got {doc['camera_response']!r}")
        if not isinstance(provenance, dict):
            raise ValueError("provenance must be a mapping")
        curve = check_curve(doc["response_curve"], doc["camera_response"])
        if per_channel(curve) and doc.get("format_version") == 1:
            raise ValueError("response_curve holds three curves, which format_version 1 does not have")
    except ValueError as exc:
        raise CaptureError(f"{path}: not a camera response ({exc})") from None
    return MeasuredResponse(curve, provenance)
