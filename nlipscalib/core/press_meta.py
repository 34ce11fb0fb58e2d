"""A press folder's names and its meta.json: the file names the capture format fixes (docs/formats.md), meta.json
read and checked (:func:`read_meta`), the camera, LEDs and sensor response it records (:func:`parse_optics`) and
the files it lists (:func:`listed_files`, :func:`existing_file`)."""

from __future__ import annotations

from pathlib import Path, PurePosixPath

from .camera import Camera
from .errors import CaptureError
from .formatfile import read_format_json
from .leds import Led
from .sensor_response import SensorResponse

FORMAT_NAME = "nlipscalib.press"
FORMAT_VERSION = 3
"""The press format's version: 2 added meta.json's ``sensor.camera_response`` (a tone curve the loader undoes), 3 a
measured curve per channel (``sensor.response_curve`` three lists, R, G, B). Captures without a tone curve are
still written as version 1, those with one curve for all channels as 2 (:func:`.capture.write_press`)."""
READ_VERSIONS = (1, 2, FORMAT_VERSION)
"""The versions :func:`read_meta` reads."""
META_FILE = "meta.json"
GT_FILE = "gt.npz"
REFERENCE_FILE = "reference.npz"
REFERENCE_FOLDER = "reference"
"""A folder of presses (a twin dataset, a capture session) keeps the capture of its undeformed dome here."""


def led_frame_name(index: int) -> str:
    """Name of LED ``index``'s (0-based) frame: led_01 for the first LED (a capture's frame, its image's stem)."""
    return f"led_{index + 1:02d}"


def led_image_name(index: int) -> str:
    """File name of LED ``index`` (0-based) image: led_01.png for the first LED."""
    return f"{led_frame_name(index)}.png"


def read_meta(folder: str | Path) -> dict:
    """Read and check the top level of a press folder's meta.json."""
    folder = Path(folder)
    path = folder / META_FILE
    if folder.exists() and not folder.is_dir():
        raise CaptureError(f"{folder}: a file, not a press folder")
    if not folder.is_dir():
        raise CaptureError(f"{folder}: not a press folder (no such directory)")
    meta = read_format_json(
        path,
        FORMAT_NAME,
        READ_VERSIONS,
        required=("camera", "leds", "sensor", "images"),
        missing_hint=f"{folder} is not a complete press folder",
    )
    _check_file_names(meta, path)
    _check_units(meta, path)
    return meta


SOURCE_TWIN = "sim"
"""meta.json ``provenance.source`` of a press the twin rendered (``nlips render``, ``nlips dataset``)."""
SOURCE_SENSOR = "device"
"""meta.json ``provenance.source`` of a press captured on a sensor (``nlips capture``: the real one or its emulator)."""


def press_source(folder: str | Path) -> str | None:
    """What made the press folder ``folder``: its meta.json ``provenance.source`` (:data:`SOURCE_TWIN`,
    :data:`SOURCE_SENSOR`), or None where meta.json is missing, unreadable or records none.

    Read leniently (only that key): it decides which command may write over or around a folder, before (and
    whatever) the folder's other checks say."""
    import json

    try:
        provenance = json.loads((Path(folder) / META_FILE).read_text(encoding="utf-8")).get("provenance")
    except (OSError, ValueError, AttributeError):
        return None
    source = provenance.get("source") if isinstance(provenance, dict) else None
    return source if isinstance(source, str) else None


ORIGIN_TWIN = "a twin render (nlips render, nlips dataset)"
ORIGIN_EMULATED = "a capture of the emulated sensor (nlips capture --emulate)"
ORIGIN_SENSOR = "a capture of a sensor (nlips capture)"
EMULATOR_DEVICE = "emulator"
"""meta.json ``provenance.device`` of a press the emulated sensor captured (a real sensor's names its port)."""


def capture_origin(meta: dict) -> str | None:
    """What made a press, in words, from its meta.json (:func:`read_meta`): :data:`ORIGIN_TWIN`,
    :data:`ORIGIN_EMULATED` or :data:`ORIGIN_SENSOR`; None where ``provenance.source`` is missing or unknown (a
    capture written by other software, or by hand: nothing is said of it)."""
    provenance = meta.get("provenance")
    if not isinstance(provenance, dict):
        return None
    source = provenance.get("source")
    if source == SOURCE_TWIN:
        return ORIGIN_TWIN
    if source == SOURCE_SENSOR:
        return ORIGIN_EMULATED if provenance.get("device") == EMULATOR_DEVICE else ORIGIN_SENSOR
    return None


def image_size(folder: str | Path) -> tuple[int, int]:
    """(width, height) in pixels of a press folder's images, from its meta.json (:func:`read_meta`'s errors)."""
    camera = Camera.from_dict(read_meta(folder)["camera"])
    return camera.width, camera.height


def _check_units(meta: dict, path: Path) -> None:
    """CaptureError when meta.json declares units or a frame other than the format's (millimetres, the camera
    frame): its numbers would be read as such and solve to a wrong result without a word. Both keys are optional."""
    units = meta.get("units", "mm")
    if units != "mm":
        raise CaptureError(f"{path}: 'units' is {units!r}; captures are in millimetres ('mm'): convert the file")
    frame = meta.get("frame", "camera")
    if not (isinstance(frame, str) and frame.startswith("camera")):
        raise CaptureError(f"{path}: 'frame' is {frame!r}; captures are in the camera frame ('camera')")


def _check_file_names(meta: dict, path: Path) -> None:
    """CaptureError naming the key of meta.json whose file name is not a string (every reader joins them to the
    folder, and the capture's identity hashes them before the press is loaded: else a TypeError traceback)."""
    images = meta["images"]
    if not isinstance(images, dict):
        raise CaptureError(f"{path}: 'images' must be a mapping of image names, got {type(images).__name__}")
    for key in ("dark", "leds", "tricolor"):
        if key not in images:
            raise CaptureError(f"{path}: missing key 'images.{key}'")
    for key in ("dark", "tricolor"):
        _check_name(images[key], f"images.{key}", path)
    if not isinstance(images["leds"], list):
        raise CaptureError(f"{path}: 'images.leds' must be a list of file names, got {images['leds']!r}")
    for i, name in enumerate(images["leds"]):
        _check_name(name, f"images.leds[{i}]", path)
    for key in ("reference", "ground_truth"):  # optional files: null or absent when there is none
        if meta.get(key) is not None:
            _check_name(meta[key], key, path)


def _check_name(name: object, key: str, path: Path) -> None:
    """CaptureError unless ``name`` is the bare name of a file in the press folder.

    Why: a press folder may come from elsewhere (e-mail, a USB stick); a name that is a path (``/home/me/x.png``,
    ``../../other_press/led_01.png``) would make the product read a file outside the folder the user named, and a
    control character (a newline) in it would forge lines of the command's messages (docs/formats.md, "Files from
    others")."""
    if not isinstance(name, str) or not name:
        raise CaptureError(f"{path}: '{key}' must be a file name, got {name!r}")
    if name != PurePosixPath(name).name or name in (".", "..") or not name.isprintable():
        raise CaptureError(f"{path}: '{key}' must be the name of a file in the press folder, got {name!r}")


def listed_files(meta: dict) -> list[str]:
    """The files a press folder's meta.json lists: its images (dark, tri-colour, one per LED) and, when it
    records them, its reference and ground-truth arrays (KeyError/TypeError when ``images`` is malformed)."""
    images = meta["images"]
    names = [images["dark"], images["tricolor"], *images["leds"]]
    names += [meta[key] for key in ("reference", "ground_truth") if meta.get(key)]
    return [str(name) for name in names]


def parse_optics(meta: dict, path: Path) -> tuple[Camera, list[Led], SensorResponse]:
    """(camera, LEDs, sensor response) of a press's meta.json (``read_meta``); CaptureError naming ``path``."""
    try:
        camera = Camera.from_dict(meta["camera"])
        if not isinstance(meta["leds"], list):
            raise ValueError(f"'leds' must be a list of LEDs, got {meta['leds']!r}")
        leds = [_led(d, i) for i, d in enumerate(meta["leds"])]
        if not isinstance(meta["sensor"], dict):
            raise ValueError(f"'sensor' must be a mapping of sensor levels, got {meta['sensor']!r}")
        response = SensorResponse(**meta["sensor"])
    except (TypeError, ValueError) as exc:
        raise CaptureError(f"{path}: {exc}") from None
    if not leds:
        raise CaptureError(f"{path}: 'leds' is empty")
    return camera, leds, response


def _led(entry: object, index: int) -> Led:
    """LED ``index`` of meta.json's ``leds``; a bad value names its place (``leds[3]``) as well as its key."""
    try:
        return Led.from_dict(entry)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"leds[{index}]: {exc}") from None


def existing_file(folder: Path, name: str) -> Path:
    """``folder / name``, a file meta.json lists; CaptureError naming it when it is missing."""
    path = folder / name
    if not path.is_file():
        raise CaptureError(f"{path}: listed in {META_FILE} but missing")
    return path
