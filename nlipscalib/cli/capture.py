"""``nlips capture``: a capture session on the real sensor (LED board + camera) or on the emulated one.

Real sensor::

    nlips capture --port /dev/ttyACM0 --camera 0 --design nlipstac --camera-calibration camera.json --out session1

Emulated sensor (the twin behind the virtual LED board and a virtual camera; no hardware)::

    nlips capture --emulate nlipstac --presses 3 --out session1
    nlips capture --port nlipsemu://1 --presses 3 --out session1     # the same, the board named by its URL

``--port nlipsemu://ID`` names a virtual LED board, which lives in the process that starts it. When this
process has none of that id the command starts one: without ``--camera`` it is the emulated sensor of
``--design`` (its board at that URL, and the virtual camera it lights: a virtual board lights no real
camera), with ``--camera`` only the board (recorded frames, the host driver exercised).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import sys
import time
from typing import TYPE_CHECKING

from ..core.errors import DeviceError
from ..core.shell_words import shell_word
from ..progress import bars_enabled, print_result, say
from .camera_response import TONE_CURVE_CHOICES
from .capture_checks import response_slope_of
from .leds import add_baud_argument, check_baud
from .options import fill_defaults, option, typed

if TYPE_CHECKING:  # named in hints only: imported when a session runs
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from ..core.camera import Camera
    from ..core.errors import CaptureError
    from ..core.leds import Led
    from ..core.response_curve import MeasuredResponse
    from ..core.sensor import SensorDesign
    from ..core.sensor_response import SensorResponse
    from .leds import LedBoard

DEFAULTS = {
    "presses": 10,
    "exposure_ms": 10.0,
    "gain": 0.0,
    "white_balance": 5000.0,
    "black_level": 0.0,
    "camera_response": "linear",
    "average": 1,
    "seed": 0,
}
"""Real defaults of the options whose presence is checked (the sensor they belong to; --presses against a press
script). argparse leaves them None, so one typed at its default value still counts as given; :func:`check_options`
fills them in (cli/options.py). --camera stays None when not given (camera 0 is chosen where it is opened):
whether one was given also decides what --port nlipsemu://ID starts."""


CAMERA_RESPONSES = ("linear", "srgb")
"""``core.sensor_response.CAMERA_RESPONSES`` (a test keeps them equal): --camera-response's names; any other value
is a response file (``nlips calibrate-camera-response``)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "capture",
        help="capture a session of presses (undeformed reference first) from the sensor or its emulator",
        description="Capture the undeformed reference, then each press: tri-colour, dark, one image per LED, and "
        "the tri-colour again to detect movement (a press that moved is retaken), in the capture format the twin "
        "writes. Prompts the operator before each press (--yes for scripts); run again after an interruption and "
        "it continues. Real sensor: --port and --camera (fixed exposure, gain and white balance; raw, linear frames: "
        "a webcam's gamma set to linear first, or its sRGB curve declared with --camera-response srgb, another "
        "curve with the FILE `nlips calibrate-camera-response` measures, docs/formats.md, Cameras); --emulate SCENE: "
        "the same path through the LED driver, a virtual board and a camera showing the twin's renders.",
    )
    p.add_argument("--out", required=True, help="session folder (reference/, press_0001/, ...); resumes if present")
    p.add_argument("--presses", type=int, help="presses after the reference (default 10; with --script: its presses)")
    src = p.add_argument_group("real sensor")
    src.add_argument(
        "--port",
        help="LED controller: serial port or pyserial URL (/dev/ttyACM0, COM3, socket://...); nlipsemu://ID: a "
        "virtual board, with the emulated camera of --design unless --camera is given",
    )
    src.add_argument("--adalight", type=int, metavar="N", help="the LED board runs stock Adalight with N LEDs")
    add_baud_argument(src)
    # default None, not "0": whether a camera was given decides what --port nlipsemu://ID starts
    src.add_argument("--camera", help="camera index, device path, folder of images or video (default 0)")
    src.add_argument("--design", default=None, help="sensor design: scene file or shipped name (default nlipstac)")
    src.add_argument("--camera-calibration", help="camera JSON from `nlips calibrate-camera` (default: the design's)")
    src.add_argument("--leds", help="LED JSON from `nlips calibrate-leds` (default: the design's LED ring)")
    src.add_argument("--exposure-ms", type=float, help="fixed exposure, ms (default 10)")
    src.add_argument("--gain", type=float, help="fixed analogue gain, camera units (default 0)")
    src.add_argument("--white-balance", type=float, help="fixed white balance, kelvin (default 5000)")
    src.add_argument("--black-level", type=float, help="camera black level in its own DN (default 0)")
    src.add_argument(
        "--camera-response",
        metavar="{linear,srgb,FILE}",
        help="how the camera's values relate to light (default linear: its gamma is asked to be 1.0, a refusal "
        "printed); srgb: a camera that cannot turn its tone curve off, recorded in meta.json and undone when the "
        "capture is loaded; FILE: its curve measured by `nlips calibrate-camera-response`, recorded and undone "
        "alike (docs/formats.md, Cameras). With --emulate: what the emulated camera's frames are declared as",
    )
    src.add_argument(
        "--flush",
        type=int,
        default=2,
        help="frames dropped after each LED change (default 2); raise it when the capture warns that an LED image "
        "repeats the one before (the camera's frames lag the LEDs)",
    )
    src.add_argument("--average", type=int, help="frames averaged per image (default 1)")
    emu = p.add_argument_group("emulated sensor")
    emu.add_argument("--emulate", metavar="SCENE", help="run against the emulated sensor of this scene (no hardware)")
    emu.add_argument("--script", help="press script (TOML/YAML [[press]] tables); default: sphere presses")
    emu.add_argument("--move-press", type=int, help="make this press (1-based) move during its sequence")
    emu.add_argument("--width", type=int, help="emulated image width, pixels (default: the scene's camera)")
    emu.add_argument("--height", type=int, help="emulated image height, pixels (default: the scene's camera)")
    emu.add_argument("--spp", type=int, help="emulated render samples per pixel (default: the scene's [render] spp)")
    emu.add_argument("--seed", type=int, help="emulated sensor noise seed (default 0)")
    emu.add_argument(
        "--emulate-tone-curve",
        choices=TONE_CURVE_CHOICES,
        help="the tone curve the emulated camera encodes its frames with (default none: linear); declare it with "
        "--camera-response (srgb, or the FILE `nlips calibrate-camera-response --emulate` measured)",
    )
    ses = p.add_argument_group("session")
    ses.add_argument(
        "--tricolor-level",
        type=int,
        help="LED drive of the tri-colour frame, 1-255 (default 255; --emulate: the drive giving the scene's "
        "tri-colour exposure, nlipstac 99)",
    )
    ses.add_argument(
        "--movement-threshold",
        type=float,
        default=0.02,
        help="pixel change counted as movement, a fraction of full scale in (0, 1) (default 0.02)",
    )
    ses.add_argument(
        "--max-retakes", type=int, default=3, help="retakes of a moving press before giving up (default 3)"
    )
    ses.add_argument("--yes", action="store_true", help="do not wait for Enter at the prompts (scripts)")
    p.set_defaults(func=run, stopped=stopped_line)


REAL_SENSOR_OPTIONS = (
    "port",
    "adalight",
    "baud",
    "camera",
    "design",
    "camera_calibration",
    "leds",
    "exposure_ms",
    "gain",
    "white_balance",
    "black_level",
    "average",
)
"""Options that set up the real sensor; the emulated one takes all of this from its scene file."""
DEFAULT_DESIGN = "nlipstac"
"""The design (and emulated scene) when --design is not given."""
EMULATED_SENSOR_OPTIONS = ("script", "move_press", "width", "height", "spp", "seed", "emulate_tone_curve")
"""Options of the emulated sensor alone."""
WHY_NOT_EMULATED = {
    "camera_calibration": "the emulated camera is the scene's [camera] section (its size: --width/--height; "
    "other intrinsics: a scene file)",
    "leds": "the emulated LEDs are the scene's [leds] section (explicit positions: a scene file); calibrate the "
    "captured LEDs afterwards with `nlips calibrate-leds`",
    "port": "the emulated sensor has its own virtual LED board",
    "adalight": "the emulated sensor's virtual LED board runs the nlips firmware",
    "baud": "the emulated sensor's virtual LED board is in this process, with no serial line",
    "camera": "the emulated sensor has its own virtual camera",
    "design": "the scene given to --emulate is the design",
}


def emulate_behind_port(args: argparse.Namespace) -> None:
    """Turn ``--port nlipsemu://ID`` without ``--camera`` into the emulated sensor of ``--design``.

    Why: the URL names a virtual board, which exists only inside the process that starts it, and a virtual
    board lights no real camera; the user asking for it from the command line means the emulated sensor,
    its board reachable at that URL. Sets ``args.emulate`` (the design's scene), ``args.board_id`` and
    ``args.emulated_port`` (the URL, for messages); ``--port`` and ``--design`` are then consumed. Nothing
    changes for a board this process already has, for ``--emulate`` or when ``--camera`` is given.
    """
    from ..device.virtual_board import board_missing, check_board_url

    args.board_id = args.emulated_port = None
    if args.emulate or args.camera is not None or not board_missing(args.port):
        return
    args.board_id = check_board_url(args.port)
    args.emulate, args.emulated_port = args.design or DEFAULT_DESIGN, args.port
    args.port = args.design = None


def _emulated_how(args: argparse.Namespace) -> str:
    """How the user asked for the emulated sensor, for messages."""
    if getattr(args, "emulated_port", None):
        return f"--port {args.emulated_port} and no --camera (the emulated sensor of {args.emulate})"
    return "--emulate"


def check_options(args: argparse.Namespace) -> None:
    """Refuse, in one line, options the chosen sensor would not use and numbers out of range (ConfigError);
    then fill in the defaults of :data:`DEFAULTS`.

    An option counts as given when it was typed, also at its default value (``--seed 0`` without
    ``--emulate`` is refused like ``--seed 1``)."""
    for dest in typed(args, (*REAL_SENSOR_OPTIONS, *EMULATED_SENSOR_OPTIONS)):
        if args.emulate and dest in REAL_SENSOR_OPTIONS:
            why = WHY_NOT_EMULATED.get(
                dest, f"it sets up the real sensor; the emulated one takes it from {args.emulate}"
            )
            raise _usage(f"{option(dest)} is not used with {_emulated_how(args)}: {why}; drop {option(dest)}")
        if not args.emulate and dest in EMULATED_SENSOR_OPTIONS:
            raise _usage(
                f"{option(dest)} is only used with --emulate SCENE (the emulated sensor; or --port nlipsemu://ID "
                "without --camera)"
            )
    if args.script and args.move_press is not None:
        raise _usage(
            "--move-press is not used with --script: a press of the script moves when its [[press]] table "
            "has a `moved` table"
        )
    fill_defaults(args, DEFAULTS)
    args.measured = declared_response(args.camera_response)
    if not args.emulate:
        args.baud = check_baud(args)
    _at_least(args, "presses", 0, "presses after the reference")
    if args.move_press is not None and not 1 <= args.move_press <= args.presses:
        raise _usage(
            f"--move-press must be a press of the session, 1..{args.presses} (--presses {args.presses}), "
            f"got {args.move_press}"
            if args.presses
            else f"--move-press {args.move_press}: the session has no press to move (--presses 0)"
        )
    from ..core.sensor import MAX_IMAGE_SIDE, MIN_IMAGE_SIDE

    for dest in ("width", "height"):
        value = getattr(args, dest)
        if value is not None and not MIN_IMAGE_SIDE <= value <= MAX_IMAGE_SIDE:
            raise _usage(f"{option(dest)} must be {MIN_IMAGE_SIDE}..{MAX_IMAGE_SIDE} pixels, got {value}")
    _at_least(args, "spp", 1, "samples per pixel")
    _at_least(args, "seed", 0, "a noise seed")
    _at_least(args, "adalight", 1, "the strip's LED count")
    _at_least(args, "flush", 0, "frames dropped after each LED change")
    _at_least(args, "average", 1, "frames averaged per image")
    _at_least(args, "max_retakes", 0, "retakes of a moving press")
    if args.tricolor_level is not None and not 1 <= args.tricolor_level <= 255:
        raise _usage(f"--tricolor-level must be an LED drive 1..255, got {args.tricolor_level}")
    if not 0 < args.movement_threshold < 1:
        raise _usage(
            f"--movement-threshold must be a fraction of full scale in (0, 1), got {args.movement_threshold:g}"
        )
    for dest, lo, what in (("exposure_ms", 0.0, "ms"), ("white_balance", 0.0, "kelvin")):
        value = getattr(args, dest)
        if not (value > lo and math.isfinite(value)):
            raise _usage(f"{option(dest)} must be > 0 {what}, got {value:g}")
    for dest in ("gain", "black_level"):
        value = getattr(args, dest)
        if not (value >= 0 and math.isfinite(value)):
            raise _usage(f"{option(dest)} must be >= 0, got {value:g}")


def declared_response(value: str) -> MeasuredResponse | None:
    """The measured response ``--camera-response`` names (``core.response_curve.MeasuredResponse``), None for
    "linear" and "srgb"; a file that is not one is one line naming it (CaptureError)."""
    if value in CAMERA_RESPONSES:
        return None
    from ..core.response_curve import read_response_file

    return read_response_file(value)


def response_provenance(args: argparse.Namespace) -> dict:
    """What meta.json's ``provenance`` records of a measured response (``provenance.camera_response``: the file
    given and how the curve was measured: camera, date, exposures, fit residual); {} for "linear" and "srgb" (their
    captures' provenance as before). The curve itself is in ``sensor.response_curve``."""
    if args.measured is None:
        return {}
    return {
        "camera_response": {"file": str(args.camera_response), "name": args.measured.name, **args.measured.provenance}
    }


def check_black_level(args: argparse.Namespace) -> None:
    """ConfigError when a measured response was measured from another black level than ``--black-level``: its curve
    spans black to white, so its entries would stand for other values."""
    measured_black = (args.measured.provenance if args.measured else {}).get("black_level_dn")
    if measured_black is not None and not math.isclose(float(measured_black), args.black_level):
        raise _usage(
            f"--camera-response {args.camera_response}: measured with the camera's black level at {measured_black:g} "
            f"DN, --black-level is {args.black_level:g}: give the same, or measure the curve again "
            "(`nlips calibrate-camera-response --black-level`)"
        )


def sensor_response_of(args: argparse.Namespace, **levels: float) -> SensorResponse:
    """The ``core.SensorResponse`` a capture declares: ``levels`` (bit depth, black and white levels, exposure,
    gain) and ``--camera-response``, a measured curve's name and table for a response file."""
    from ..core.sensor_response import SensorResponse

    measured = args.measured
    if measured is None:
        return SensorResponse(**levels, camera_response=args.camera_response)
    return SensorResponse(**levels, camera_response=measured.name, response_curve=measured.curve)


def _at_least(args: argparse.Namespace, dest: str, minimum: int, what: str) -> None:
    value = getattr(args, dest)
    if value is not None and value < minimum:
        raise _usage(f"{option(dest)} must be >= {minimum} ({what}), got {value}")


def _session_config(args: argparse.Namespace, tricolor_level: int | None):
    from ..device.session import SessionConfig

    level = args.tricolor_level or tricolor_level or 255  # check_options refused 0
    return SessionConfig(
        presses=args.presses,
        tricolor_level=level,
        movement_threshold=args.movement_threshold,
        max_retakes=args.max_retakes,
    )


def _run_emulated(args: argparse.Namespace):
    from ..device.session import check_resumable, run_session
    from ..emulator import default_script, load_script, open_emulated_sensor
    from ..sim.scene import load_scene
    from .options import check_size_pair

    scene = load_scene(args.emulate)
    check_size_pair(args.width, args.height, (scene.camera.width, scene.camera.height))
    camera = {k: v for k, v in {"width": args.width, "height": args.height}.items() if v}
    scene = scene.replace(camera=camera, render={"spp": args.spp} if args.spp else {})
    script = load_script(args.script) if args.script else default_script(args.presses, args.move_press)
    if args.script and typed(args, ["presses"]) and args.presses != len(script):  # --presses 10 too
        raise _usage(f"--presses {args.presses}: the script {args.script} has {len(script)} presses; drop --presses")
    args.presses = len(script)
    board_id = getattr(args, "board_id", None)
    if board_id is not None:
        from ..device.virtual_board import emulated_sensor_note

        print(emulated_sensor_note(args.emulated_port, args.emulate), file=sys.stderr)
    base = scene.noise.response()
    response = sensor_response_of(
        args, **{k: getattr(base, k) for k in ("bit_depth", "black_level", "white_level", "exposure_ms", "gain")}
    )
    with open_emulated_sensor(
        scene,
        script,
        seed=args.seed,
        flush_frames=args.flush,
        board_id=board_id,
        tone_curve=args.emulate_tone_curve,
        response=response,
        echo=say,  # the scripted operator's instructions: a session's info lines, on stderr (stdout: the folder)
    ) as sensor:
        sensor.rig.provenance.update(response_provenance(args))
        sensor.rig.response_slope = response_slope_of(sensor.rig)
        cfg = _session_config(args, sensor.tricolor_level)
        check_resumable(sensor.rig, args.out, cfg)  # before the renders, which a refusal would throw away
        sensor.prerender(progress=bars_enabled())
        return run_session(sensor.rig, args.out, cfg, sensor.operator, progress=bars_enabled())


def _run_device(args: argparse.Namespace):
    from ..core.dome import reference_surface
    from ..core.sensor_response import white_level_of
    from ..device.camera import CameraSettings, open_source
    from ..device.lights_out import lights_out_on_exit
    from ..device.port import BAUD_RATE
    from ..device.session import Operator, Rig, run_session
    from ..device.virtual_board import start_board

    if not args.port:
        raise _usage(
            "give the LED controller's --port (or --emulate SCENE, or --port nlipsemu://1, to run without hardware)"
        )
    check_black_level(args)
    design = _design(args.design)
    camera = _calibrated_camera(args.camera_calibration) or design.camera_model()
    leds = _leds(args, camera, design) or design.led_models()
    camera_spec = args.camera if args.camera is not None else "0"
    # --port nlipsemu://ID with --camera: only the board is virtual; held here, as its URL reaches it while it lives
    board = start_board(args.port, args.adalight or len(leds), adalight=args.adalight is not None, baudrate=BAUD_RATE)
    settings = CameraSettings(
        exposure_ms=args.exposure_ms,
        gain=args.gain,
        white_balance_k=args.white_balance,
        width=camera.width,
        height=camera.height,
        flush_frames=args.flush,
        average=args.average,
        linear_gamma=args.camera_response == "linear",  # a declared curve is the camera's own: left as it is
    )
    held = board if board is not None else contextlib.nullcontext()  # closing the board frees its id
    status = None
    with (
        _reset_after_the_session(args.port, lambda: status),
        held,
        open_leds(args.port, args.adalight, args.baud) as controller,
        lights_out_on_exit(controller),  # also when the session is stopped (Ctrl-C, SIGTERM) mid-press
        open_source(camera_spec, settings, reported=_session_refusals(args.out, camera_spec)) as source,
    ):
        shift = 16 - source.bit_depth
        response = sensor_response_of(
            args,
            bit_depth=source.bit_depth,
            black_level=float(args.black_level) * (1 << shift),
            white_level=float(white_level_of(source.bit_depth)),
            exposure_ms=args.exposure_ms,
            gain=args.gain,
        )
        rig = Rig(
            controller=controller,
            source=source,
            camera=camera,
            leds=leds,
            response=response,
            reference=reference_surface(design, camera),
            design=dataclasses.asdict(design),
            provenance={
                "device": {"port": args.port, "firmware": str(controller.firmware), "camera": str(camera_spec)},
                "camera_refused": list(source.refused),
                "camera_gamma": source.gamma,
                "design": args.design or DEFAULT_DESIGN,
            }
            | response_provenance(args),
            source_name=f"camera {camera_spec}" if str(camera_spec).isdigit() else str(camera_spec),
            leds_origin=f"the LED file {args.leds}" if args.leds else f"the design {args.design or DEFAULT_DESIGN}",
            camera_origin=f"the camera calibration {args.camera_calibration}"
            if args.camera_calibration
            else f"the camera of the design {args.design or DEFAULT_DESIGN} (no --camera-calibration)",
        )
        rig.response_slope = response_slope_of(rig)  # the reference's tone-curve check: the solve's
        interactive = not args.yes and sys.stdin.isatty()
        operator = Operator(interactive=interactive, echo=_tell_operator if interactive else say)
        status = run_session(rig, args.out, _session_config(args, None), operator, progress=bars_enabled())
    return status


@contextlib.contextmanager
def _reset_after_the_session(port: str, status: Callable[[], dict | None]) -> Iterator[None]:
    """A board reset found by the LEDs' OFF as the session closes (``lights_out_on_exit``), once ``status()`` holds
    the finished session's record: said in one warning (:func:`nlipscalib.device.session.reset_after_the_session`),
    and the session ends as captured, exit 0. A reset before that (every attempt at a press cut short) goes on.

    Why: it exited 2 with the driver's "... retake any frame captured since the previous command" though every
    folder was kept and none could be retaken: each press ends with an acknowledged OFF after its last frame, which a
    board rebooted before it cannot give (it answers nothing but HELLO), so a reset found later darkened no frame."""
    from ..device.errors import BoardResetError
    from ..device.session import reset_after_the_session

    try:
        yield
    except BoardResetError as exc:
        done = status()
        if done is None:
            raise
        import logging

        logging.getLogger(__name__).warning("%s", reset_after_the_session(port, exc, len(done)))


def _tell_operator(line: str) -> None:
    """An instruction to the person at the sensor waiting on it (``Press 1 captured: release.``): on stderr, even with
    ``--quiet`` (it is no info line), and in the ``--log-file``; stdout holds the session's folder alone."""
    import logging

    from ..progress import file_log

    print(line, file=sys.stderr, flush=True)
    file_log(logging.INFO, line)


def open_leds(port: str, adalight: int | None = None, baudrate: int | None = None) -> LedBoard:
    """The LED controller on ``port`` at ``baudrate`` (default the firmware's, 115200): the nlips firmware, or a
    stock Adalight board with ``adalight`` LEDs (no acknowledgement: it waits a settle delay after each frame
    instead, and the camera flushes)."""
    from ..device.controller import LedController
    from ..device.port import BAUD_RATE

    baudrate = BAUD_RATE if baudrate is None else baudrate
    if adalight is not None:
        from ..device.adalight import AdalightController

        return AdalightController.open(port, adalight, baudrate=baudrate)
    return LedController.open(port, baudrate=baudrate)


def _usage(message: str):
    from ..core.errors import ConfigError

    return ConfigError(message)


def _design(name: str | None) -> SensorDesign:
    from ..sim.scene import load_scene  # the scene file's dome/camera/leds sections are the design

    return load_scene(name).design


def _calibrated_camera(path: str | None) -> Camera | None:
    if not path:
        return None
    import json
    from pathlib import Path

    from ..core.camera import Camera
    from ..core.errors import ConfigError

    made_by = "the JSON file from `nlips calibrate-camera`"
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such camera calibration file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: a folder, not a camera calibration file ({made_by})") from None
    except ValueError as exc:  # not JSON, not UTF-8
        raise ConfigError(f"{path}: not a camera calibration file ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("camera"), dict):  # a list, an LED file, ...
        raise ConfigError(f"{path}: not a camera calibration file (no 'camera' block; {made_by} has one)")
    try:
        return Camera.from_dict(doc["camera"])
    except (ValueError, KeyError, TypeError) as exc:
        raise ConfigError(f"{path}: not a camera calibration file ({exc})") from None


def _session_refusals(out: str, camera_spec: str) -> tuple[str, ...]:
    """The camera refusals a resumed session said when it started (its reference's meta.json
    ``provenance.camera_refused``, when taken with the camera ``camera_spec``): not said again at each capture
    (``device.camera.report_refusals``); () for a new session or a record that cannot be read."""
    from pathlib import Path

    from ..core.errors import CaptureError
    from ..core.press_meta import REFERENCE_FOLDER, read_meta

    try:
        provenance = read_meta(Path(out) / REFERENCE_FOLDER).get("provenance")
    except (CaptureError, OSError, ValueError):
        return ()
    if not isinstance(provenance, dict) or (provenance.get("device") or {}).get("camera") != str(camera_spec):
        return ()
    refused = provenance.get("camera_refused")
    return tuple(line for line in refused if isinstance(line, str)) if isinstance(refused, list) else ()


def _leds(args: argparse.Namespace, camera: Camera, design: SensorDesign) -> tuple[Led, ...] | None:
    """The LEDs of ``--leds FILE`` (None without it), refused in one line when the file was calibrated on
    another sensor than the one captured here: the design's LEDs with ``camera`` (the same check as
    ``nlips solve --leds``: :func:`nlipscalib.core.sensor_record.leds_file_mismatch`). A file that records no
    sensor (written before 2026-12-04) and whose LEDs are far from the design's is warned about, as solve does."""
    if not args.leds:
        return None
    import logging

    from ..core.errors import CaptureError
    from ..core.ledfile import read_led_file
    from ..core.leds import led_geometry_mismatch
    from ..core.sensor_record import describe_sensor, leds_file_mismatch

    led_file = read_led_file(args.leds)
    sensor = describe_sensor(camera, design.led_models())
    what = f"the design {args.design or DEFAULT_DESIGN}" + (
        f" with the camera of {args.camera_calibration}" if args.camera_calibration else ""
    )
    if led_file.sensor is not None:
        why = leds_file_mismatch(led_file.sensor, led_file.leds, sensor)
        if why:
            raise CaptureError(
                f"{args.leds}: calibrated on another sensor than the one captured here, {what} ({why}); give the "
                "LED file calibrated on this sensor's reference (`nlips calibrate-leds SESSION/reference`), or drop "
                "--leds"
            )
    elif far := led_geometry_mismatch(
        sensor["led_positions"],
        sensor["led_directions"],
        [led.position for led in led_file.leds],
        [led.direction for led in led_file.leds],
    ):
        logging.getLogger(__name__).warning(
            "%s: records no sensor to check against %s, and its LEDs differ from the design's (%s): make sure they "
            "are a calibration of this sensor (a new `nlips calibrate-leds` records the sensor)",
            args.leds,
            what,
            far,
        )
    return led_file.leds


def stopped_line(args: argparse.Namespace) -> str:
    """What a capture stopped by Ctrl-C or SIGTERM says it left (the end of the command's "interrupted;" or
    "terminated;" line, :func:`nlipscalib.cli._stopped`): the session's folders captured whole, the folder a
    run again starts with.

    Why: a stopped capture printed only "finished work is kept, run again to resume", with no session line: the
    operator, one press in a dozen, did not know how far the session got. Read from the folder (each press is
    written whole, atomically), so the line is right whichever moment the signal came at."""
    from ..device.session import REFERENCE_NAME, captured_folders, press_name

    presses = args.presses if args.presses is not None else DEFAULTS["presses"]  # None: stopped before the options
    done = captured_folders(args.out, presses)
    names = ", ".join(done) if len(done) <= 3 else f"{done[0]}, {done[1]} ... {done[-1]}"
    names_all = [REFERENCE_NAME, *map(press_name, range(1, presses + 1))]
    missing = next((name for name in names_all if name not in done), None)
    resume = f"run again to resume from {missing}" if missing else "all kept, nothing left to capture"
    return f"session {args.out}: {len(done)} of {presses + 1} folders captured ({names or 'none'}); {resume}"


def with_session_line(exc: DeviceError | CaptureError, args: argparse.Namespace) -> DeviceError | CaptureError:
    """A board, port or camera error (or a press that kept moving) that stopped a session with folders already
    captured, with the session line a Ctrl-C prints (:func:`stopped_line`): what is kept and the folder the same
    command, run again, starts with.

    Why: a board unplugged (or gone silent) at press 5 of 10 ended with "the board disconnected ... and did not
    come back within 5 s" alone; the operator did not know that the four presses were kept and that the same
    command resumes at press_0005, once the board is back, and started the session again in a new folder. A camera
    that stopped sending (or a folder of frames that ran out) said only "camera 0: no frame (the camera stopped)"
    until s40."""
    from ..core.errors import CaptureError
    from ..device.session import captured_folders

    presses = args.presses if args.presses is not None else DEFAULTS["presses"]
    if not captured_folders(args.out, presses):  # nothing kept: the error alone says what to fix
        return exc
    kind = DeviceError if isinstance(exc, DeviceError) else CaptureError
    return kind(f"{exc}; {stopped_line(args)}")


def _warn_beyond(out: Path, status: dict) -> list[str]:
    """Warn about press folders in the session ``out`` that this run did not capture or keep (a run with fewer
    ``--presses`` than an earlier one); returns their names.

    Why: ``nlips capture --presses 2`` on a session of 4 said "3 folders" and nothing of press_0003 and press_0004,
    which ``nlips calibrate`` and ``nlips solve`` of the folder still take (``nlips dataset`` says the same of a press
    its spec no longer names)."""
    from ..core.press_folders import find_presses

    extra = sorted(p.name for p in find_presses(out) if p.parent == out and p.name not in status)
    if extra:
        shown = ", ".join(extra[:3]) + (f" and {len(extra) - 3} more" if len(extra) > 3 else "")
        them = "it" if len(extra) == 1 else "them"
        are = "is" if len(extra) == 1 else "are"
        say(
            f"{out}: {shown}, captured by an earlier run with more --presses, {are} kept: `nlips calibrate` and "
            f"`nlips solve` of the folder still use {them} (remove {them}, or capture into a new folder)",
            warning=True,
        )
    return extra


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..device.session import PressNotCaptured, claim_session
    from .folders import check_not_in_press

    emulate_behind_port(args)
    check_options(args)
    check_not_in_press(Path(args.out), "capture the session")  # before the sensor (or its emulator) starts
    t0 = time.perf_counter()
    with claim_session(args.out):  # another capture writing the folder: refused before the sensor starts
        try:
            status = _run_emulated(args) if args.emulate else _run_device(args)
        except (DeviceError, PressNotCaptured) as exc:
            raise with_session_line(exc, args) from exc
    for name, rec in status.items():
        if rec == "kept":
            say(f"{name}: kept (already captured)")
        else:
            say(f"{name}: captured in {rec['seconds']:.2f} s, {rec['attempts']} attempt(s)")
    print_result(args.out)  # stdout: the session's folder alone (scripts); what it holds and the next steps on stderr
    say(f"session {args.out}: {len(status)} folders in {time.perf_counter() - t0:.1f} s")
    _warn_beyond(Path(args.out), status)
    # the next steps of the sensor's calibration, as `nlips calibrate` and `nlips train` name theirs
    reference = Path(args.out) / "reference"
    say(
        f"next: nlips calibrate-leds {shell_word(reference)} --out leds.json (the sensor's LEDs), then nlips calibrate "
        f"{shell_word(args.out)} --leds leds.json (NLiPsNet's training data)"
    )
    return 0
