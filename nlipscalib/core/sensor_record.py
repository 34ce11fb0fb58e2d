"""What a calibration is valid for: the sensor's camera, image size, LED grouping and LED geometry.

A calibration dataset, every model trained on it and every LED file from ``nlips calibrate-leds`` carry
this description; a capture (or a bare image) from another sensor is refused with a message saying what
differs. In core because both consumers read it: learn/ (datasets, models) and the solve pipeline (LED
files).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import TYPE_CHECKING

from .errors import PATH, CaptureError, check_kind
from .leds import Leds, led_geometry_mismatch, tricolor_groups
from .response_curve import curve_json
from .tolerances import SAME_DISTORTION_ABS, SAME_INTRINSICS_ABS_PX, SAME_INTRINSICS_RTOL, SAME_SURFACE_MM

if TYPE_CHECKING:  # names in hints only: this module imports the camera where it checks one
    import numpy as np

    from .camera import Camera
    from .capture import Press
    from .sensor_response import SensorResponse

log = logging.getLogger(__name__)


def sensor_of(press: Press) -> dict:
    """The sensor description of a capture (``core.Press``): :func:`describe_sensor` of its optics."""
    return describe_sensor(press.camera, press.leds, press.response)


def describe_sensor(camera: Camera, leds: Leds, response: SensorResponse | None = None) -> dict:
    """Camera, LED count, tri-colour groups, sensor levels, camera response ("camera_response", only when not
    linear: :func:`camera_response_of`) and LED geometry (positions, mm, and directions, camera frame) of a sensor:
    what a calibration dataset and a model are valid for.

    ``response`` None (a sensor about to be captured, its camera not yet opened): no sensor levels, which
    :func:`sensor_mismatch` does not compare; such a description is for comparing only, not for storing."""
    n = len(leds)
    levels = {}
    if response is not None:
        levels = {"black_level": float(response.black_level), "white_level": float(response.white_level)}
        if response.camera_response != "linear":  # absent when linear: the records of linear sensors as before
            levels["camera_response"] = response.camera_response
        if response.response_curve is not None:  # a measured curve: the table itself, as a model must undo it
            levels["response_curve"] = curve_json(response.response_curve)
    return {
        "camera": camera.to_dict(),
        "n_leds": n,
        "tricolor_groups": [int(g) for g in tricolor_groups(n)],
        **levels,
        "led_positions": [[float(v) for v in led.position] for led in leds],
        "led_directions": [[float(v) for v in led.direction] for led in leds],
    }


def response_table_of(sensor: dict) -> np.ndarray | None:
    """The table undoing the tone curve a sensor description records (``core.sensor_response.tone_curve_table``
    of its :func:`camera_response_of`, its levels and, for a measured one, its ``response_curve``); None when
    linear."""
    from .sensor_response import tone_curve_table

    return tone_curve_table(
        camera_response_of(sensor), sensor["black_level"], sensor["white_level"], sensor.get("response_curve")
    )


def camera_response_of(sensor: dict) -> str:
    """The camera response (``core.sensor_response.CAMERA_RESPONSES``, or a measured curve's "measured:<hash>",
    its curve in ``response_curve``) a sensor description records: what the
    frames of its captures, and a model's stills and streams, are encoded with; "linear" when it records none (a
    linear camera, or a file written before responses were recorded, 2026-12-06)."""
    return sensor.get("camera_response", "linear")


def response_mismatch(expected: dict, actual: dict, expected_as: str = "the calibration's") -> str | None:
    """Why a capture of ``actual`` does not belong in a calibration of ``expected`` for its camera response alone
    (:func:`camera_response_of`), or None when they share one. Not part of :func:`sensor_mismatch`: a capture of
    either response is linearised by its own declaration and solves (or infers) alike; only a calibration must
    have one, as its model linearises stills and streams, which declare nothing, with the one it records."""
    ours, theirs = camera_response_of(actual), camera_response_of(expected)
    if ours == theirs:
        return None
    return (
        f"camera response {ours} (meta.json sensor.camera_response), {expected_as} {theirs}: a calibration's "
        "undeformed capture and presses must share one, which its model records and undoes on the stills and "
        "streams it infers; calibrate the presses of each response apart (or recapture)"
    )


def sensor_mismatch(expected: dict, actual: dict, expected_as: str = "calibrated for") -> str | None:
    """Why ``actual`` is not the sensor ``expected`` describes, or None when they match.

    ``expected_as`` introduces the expected value in the reason ("16 LEDs in groups [...], calibrated for 12"
    for a model or dataset; a capture compared with a capture names it: ``"ref/ has"``)."""
    ce, ca, was = expected["camera"], actual["camera"], expected_as
    if (ce["width"], ce["height"]) != (ca["width"], ca["height"]):
        return f"image size {ca['width']}x{ca['height']}, {was} {ce['width']}x{ce['height']}"
    if ce["model"] != ca["model"]:
        return f"lens model {ca['model']!r}, {was} {ce['model']!r}"
    for key in ("fx", "fy", "cx", "cy"):
        if not math.isclose(ce[key], ca[key], rel_tol=SAME_INTRINSICS_RTOL, abs_tol=SAME_INTRINSICS_ABS_PX):
            return f"camera {key} = {ca[key]:.4g}, {was} {ce[key]:.4g}"
    if any(not math.isclose(a, b, abs_tol=SAME_DISTORTION_ABS) for a, b in zip(ce["dist"], ca["dist"])):
        return f"lens distortion {ca['dist']}, {was} {ce['dist']}"
    if expected["n_leds"] != actual["n_leds"] or expected["tricolor_groups"] != actual["tricolor_groups"]:
        return f"{actual['n_leds']} LEDs in groups {actual['tricolor_groups']}, {was} {expected['n_leds']}"
    if "led_positions" in expected and "led_positions" in actual:  # models made before they were recorded: no check
        return led_geometry_mismatch(
            expected["led_positions"], expected["led_directions"], actual["led_positions"], actual["led_directions"]
        )
    return None


def surface_mismatch(expected_depth: np.ndarray, actual_depth: np.ndarray) -> str | None:
    """Why two captures' undeformed surfaces are not one sensor's, or None when they agree.

    Parameters
    ----------
    expected_depth, actual_depth : (H, W) float array, mm, NaN off the gel
        The undeformed gel surface's z, camera frame (reference.npz, or a model's calibration reference),
        on one camera (same shape).

    Why: the camera and LED ring alone let a capture of another dome pass (a user's design with the dome 4 mm
    lower: a model of the original inferred it with a warning, 16 deg and 3.3 mm off). The median distance
    over the pixels both show, against :data:`~nlipscalib.core.tolerances.SAME_SURFACE_MM`.
    """
    import numpy as np

    a, b = np.asarray(expected_depth, float), np.asarray(actual_depth, float)
    if a.shape != b.shape:
        return f"undeformed surfaces of {b.shape[1]}x{b.shape[0]} and {a.shape[1]}x{a.shape[0]} pixels"
    both = np.isfinite(a) & np.isfinite(b)
    if not both.any():
        return "their undeformed surfaces share no pixel"
    gap = float(np.median(np.abs(a[both] - b[both])))
    if gap > SAME_SURFACE_MM:
        return f"undeformed surfaces {gap:.2f} mm apart (median)"
    return None


CAPTURE_SETTINGS_UNRECORDED = ("name", "camera")
"""Twin scene keys a capture's settings leave out: the name (a copy of a scene under another name renders the same
images) and the camera (:func:`describe_sensor` holds it, and :func:`sensor_mismatch` compares it)."""
RENDER_KEYS_UNRECORDED = ("variant", "threads", "seed")
"""Twin render keys left out: the same images whichever Mitsuba variant or thread count, and every press its own
noise seed."""


def capture_settings(meta: dict) -> dict:
    """What decides a capture's brightness and noise beside its sensor (:func:`describe_sensor`), from its meta.json:
    the camera's exposure and gain, a device session's LED levels, and a twin's scene settings (render samples and
    bounces, sensor noise and exposure, coating, LED ring and package, camera effects, gel optics, dome).

    A model records its calibration presses' settings (:func:`common_settings`), so that ``nlips infer`` of a press
    taken otherwise names what differs (a twin press rendered with other bounces was blamed on the exposure). Not
    the reference's: it may be rendered at more samples per pixel than the presses (the experiments', 64). Values
    absent from ``meta`` are None."""
    sensor = meta.get("sensor") if isinstance(meta.get("sensor"), dict) else {}
    prov = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    settings = {
        "exposure_ms": sensor.get("exposure_ms"),
        "gain": sensor.get("gain"),
        "white_level": prov.get("white_level"),  # a device session's LED drive levels
        "tricolor_level": prov.get("tricolor_level"),
    }
    scene = prov.get("scene")
    if isinstance(scene, dict):
        scene = {k: v for k, v in scene.items() if k not in CAPTURE_SETTINGS_UNRECORDED}
        if isinstance(scene.get("render"), dict):
            scene["render"] = {k: v for k, v in scene["render"].items() if k not in RENDER_KEYS_UNRECORDED}
        settings["scene"] = scene
    return settings


def camera_position_of(meta: dict) -> tuple[float, float, float] | None:
    """The camera's position in the dome frame (mm, docs/conventions.md) a capture's meta.json records: a device
    capture's ``design`` or a twin's (or the emulator's) ``provenance.scene``; None when neither records it."""
    from .config import is_finite_number

    prov = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    for holder in (meta.get("design"), prov.get("scene")):
        camera = holder.get("camera") if isinstance(holder, dict) else None
        position = camera.get("position") if isinstance(camera, dict) else None
        if isinstance(position, list | tuple) and len(position) == 3 and all(is_finite_number(v) for v in position):
            return (float(position[0]), float(position[1]), float(position[2]))
    return None


def common_settings(settings: list[dict]) -> dict:
    """The (nested) keys whose values all of ``settings`` share, with those values: what a set of captures (a
    calibration's presses) was taken with alike; a key on which they differ, or that one lacks, is left out."""
    if not settings:
        return {}
    common = {}
    for key, value in settings[0].items():
        values = [s.get(key) for s in settings if isinstance(s, dict)]
        if len(values) == len(settings) and all(isinstance(v, dict) for v in values):
            common[key] = common_settings(values)
        elif all(v == value for v in values) and all(key in s for s in settings):
            common[key] = value
    return common


def setting_differences(old: object, new: object, where: str = "", recorded_only: bool = False) -> list[str]:
    """'key: old -> new' of every (dotted) key where two JSON values differ, in key order; empty when equal.
    ``recorded_only``: only the keys ``old`` holds (a record of what its captures shared leaves out the rest)."""
    if isinstance(old, dict) and isinstance(new, dict):
        changes = []
        for key in sorted(set(old) if recorded_only else set(old) | set(new), key=str):
            where_key = f"{where}.{key}" if where else str(key)
            changes += setting_differences(old.get(key), new.get(key), where_key, recorded_only)
        return changes
    return [] if old == new else [f"{where or 'value'}: {old!r} -> {new!r}"]


def leds_file_mismatch(recorded: dict, file_leds: Leds, actual: dict) -> str | None:
    """Why an LED file from ``nlips calibrate-leds`` was calibrated on another sensor than ``actual``, or None.

    Parameters
    ----------
    recorded : dict
        The sensor the file records (:func:`describe_sensor` of the capture it was calibrated from).
    file_leds : sequence of Led
        The file's calibrated LEDs.
    actual : dict
        :func:`describe_sensor` of the sensor the file is about to be used with: a capture being solved
        (``nlips solve --leds``), or the design and camera of a capture being taken (``nlips capture --leds``).

    When ``actual``'s LEDs are the file's (within SAME_LED_MM / SAME_LED_DEG), ``actual`` was captured with
    these calibrated LEDs (``nlips capture --leds FILE`` records them, not the design the file recorded), so
    only the camera and the LED count and grouping are compared; otherwise the whole sensor, its design LED
    geometry too.
    """
    far = led_geometry_mismatch(
        [led.position for led in file_leds],
        [led.direction for led in file_leds],
        actual["led_positions"],
        actual["led_directions"],
    )
    if not far:
        recorded = {k: v for k, v in recorded.items() if k not in ("led_positions", "led_directions")}
    return sensor_mismatch(recorded, actual)


def check_sensor(expected: dict, actual: dict, where: str | Path) -> None:
    """Raise CaptureError naming ``where`` when ``actual`` is another sensor than ``expected``."""
    check_kind(expected, dict, "expected", "a sensor description (predictor.model.sensor)")
    check_kind(actual, dict, "actual", "a sensor description (load_tricolor(folder)[1], describe_sensor(...))")
    check_kind(where, PATH, "where", "what the sensor is of, for the message: a press folder's path or a name")
    why = sensor_mismatch(expected, actual)
    if why:
        raise CaptureError(f"{where}: captured with another sensor than the model was calibrated for ({why})")


def check_sensor_record(sensor: object, where: str | Path, remedy: str = "") -> dict:
    """``sensor`` as read back from a file (index.json, a model file), checked to be a sensor description.

    Such files are written by this package, but a hand edit or another tool's file would otherwise fail
    later, deep inside inference, as a KeyError or TypeError. Returns ``sensor``. A file written before
    the LED geometry was recorded (2026-12-03) is accepted with a warning naming ``where``, that a capture
    of another LED ring cannot be refused, and ``remedy`` (how to make the file again).

    Raises
    ------
    CaptureError naming ``where`` and what is wrong.
    """
    import numpy as np

    from .camera import Camera
    from .config import is_finite_number
    from .errors import ConfigError
    from .response_curve import check_curve, is_measured
    from .sensor_response import CAMERA_RESPONSES, known_response

    try:
        if not isinstance(sensor, dict):
            raise TypeError(f"expected a mapping, got {type(sensor).__name__}")
        camera = sensor["camera"]
        if not isinstance(camera, dict):
            raise TypeError(f"camera: expected a mapping, got {type(camera).__name__}")
        Camera.from_dict(camera)
        for key in ("width", "height"):
            if isinstance(camera[key], bool) or not isinstance(camera[key], int) or camera[key] < 1:
                raise ValueError(f"camera.{key} must be a whole number >= 1, got {camera[key]!r}")
        n = sensor["n_leds"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise ValueError(f"n_leds must be a whole number >= 1, got {n!r}")
        if not isinstance(sensor["tricolor_groups"], list) or len(sensor["tricolor_groups"]) != n:
            raise ValueError(f"tricolor_groups must list one group per LED ({n})")
        for key in ("black_level", "white_level"):  # float("x") would name the value, not the key
            if not is_finite_number(sensor[key]):
                raise ValueError(f"{key} must be a finite number, got {sensor[key]!r}")
        if not known_response(camera_response_of(sensor)):  # inference would undo no curve, or a wrong one
            raise ValueError(
                f"camera_response must be one of {', '.join(map(repr, CAMERA_RESPONSES))} or measured:<hash>, got "
                f"{sensor['camera_response']!r}"
            )
        if is_measured(camera_response_of(sensor)):  # its table, undone on every still and stream
            check_curve(sensor.get("response_curve"), camera_response_of(sensor))
        for key in ("led_positions", "led_directions"):  # absent in files made before they were recorded
            if key in sensor and np.asarray(sensor[key], dtype=float).shape != (n, 3):
                raise ValueError(f"{key} must be {n} (x, y, z) triples")
        sensor_mismatch(sensor, sensor)  # every field a comparison with a capture reads
    except KeyError as exc:
        raise CaptureError(f"{where}: 'sensor' is not a sensor description (missing key {exc})") from None
    except (TypeError, ValueError, ConfigError, CaptureError) as exc:
        raise CaptureError(f"{where}: 'sensor' is not a sensor description ({exc})") from None
    if "led_positions" not in sensor or "led_directions" not in sensor:
        # silently accepting it would let a capture of another LED ring (same camera, same LED count) through
        log.warning(
            "%s: records no LED geometry (made before 2026-12-03, or from a dataset made then), so the LED "
            "positions and directions of a capture cannot be checked against the calibrated sensor%s",
            where,
            f"; {remedy}" if remedy else "",
        )
    return sensor
