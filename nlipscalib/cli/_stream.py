"""The stream plumbing shared by ``nlips live`` and ``nlips infer`` (one way to open and run a stream): the source
flags and their checks, the frame source (a camera with the LED board lit in the tri-colour pattern, a recording,
or the emulated sensor), the NLiPsNet predictor and its calibration-mismatch watch.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from .leds import add_baud_argument, check_baud
from .options import check_size_pair, fill_defaults, option, typed

if TYPE_CHECKING:  # named in hints only: imported when a stream is opened
    from pathlib import Path

    import numpy as np

    from ..core.claims import Owner
    from ..device.camera import FrameSource
    from ..device.errors import BoardResetError
    from ..device.live import LiveStats
    from ..device.live_leds import ResetWatch
    from ..learn.infer import Predictor
    from .leds import LedBoard

log = logging.getLogger(__name__)

SOURCE_DEFAULTS = {"tricolor_level": 255, "exposure_ms": 10.0, "frames_per_press": 10}
"""Real defaults of the source flags whose presence is checked (argparse leaves them None, so one typed at its
default value still counts as given; cli/options.py)."""
CAMERA_SOURCE_OPTIONS = ("port", "adalight", "baud", "camera", "tricolor_level", "exposure_ms")
"""Source flags of a camera stream: the emulated sensor has its own camera and LED board."""
EMULATED_SOURCE_OPTIONS = ("script", "frames_per_press", "width", "height")
"""Source flags of the emulated sensor alone."""


def add_source_arguments(p: argparse.ArgumentParser, camera_default: str | None) -> None:
    """The frame-source flags shared by ``nlips live`` and ``nlips infer`` (one way to open a stream).

    The flags whose presence is checked have no argparse default (:func:`check_source_arguments` fills in
    :data:`SOURCE_DEFAULTS`; ``--camera`` stays None when not given and ``camera_default`` is opened then)."""
    default = f" (default {camera_default})" if camera_default else ""
    what = "camera index, device path, folder of frames or video"
    # parsed as None when not given (open_frames falls back to default_camera): whether a camera was given
    # decides what --port nlipsemu://ID starts, and --emulate refuses one
    p.add_argument("--camera", help=what + default)
    p.set_defaults(default_camera=camera_default)
    p.add_argument(
        "--port",
        help="LED controller port/URL: lit in the tri-colour pattern while streaming (nlipsemu://ID: a virtual "
        "board, started here when this process has none)",
    )
    p.add_argument("--adalight", type=int, metavar="N", help="the LED board runs stock Adalight with N LEDs")
    add_baud_argument(p)
    p.add_argument("--tricolor-level", type=int, help="LED drive of the tri-colour pattern, 1-255 (default 255)")
    p.add_argument("--exposure-ms", type=float, help="fixed exposure of a live camera, ms (default 10)")
    p.add_argument("--emulate", metavar="SCENE", help="stream from the emulated sensor of this scene")
    p.add_argument(
        "--script",
        help="emulated press script (TOML/YAML [[press]] tables); default: the undeformed dome, then 3 presses",
    )
    p.add_argument("--frames-per-press", type=int, help="emulated frames per scripted press (default 10)")
    p.add_argument(
        "--width", type=int, help="emulated image width, pixels (default: the model's images', else the scene's camera)"
    )
    p.add_argument(
        "--height",
        type=int,
        help="emulated image height, pixels (default: the model's images', else the scene's camera)",
    )


def emulate_behind_port(args: argparse.Namespace, scene: str | None = None) -> None:
    """``--port nlipsemu://ID`` without ``--camera`` and ``--emulate``: stream from the emulated sensor.

    Why: the URL names a virtual board, which exists only inside the process that starts it, and a virtual
    board lights no real camera; asked for from the command line it means the emulated sensor (``scene``,
    default the nlipstac design) with its board at that URL. Sets ``args.emulate``, ``args.board_id`` and
    ``args.emulated_port`` (the URL, for the note the stream prints) and consumes ``--port``. Nothing changes
    for a board this process already has.
    """
    from ..device.virtual_board import board_missing, check_board_url
    from .capture import DEFAULT_DESIGN

    if args.emulate or args.camera is not None or not board_missing(args.port):
        return
    args.board_id = check_board_url(args.port)
    args.emulate, args.emulated_port, args.port = scene or DEFAULT_DESIGN, args.port, None


def check_source_arguments(args: argparse.Namespace) -> None:
    """One line naming the option when a flag of :func:`add_source_arguments` is out of range, or is not
    used by the chosen source (the real sensor's with ``--emulate``, the emulator's without it); then the
    defaults of :data:`SOURCE_DEFAULTS` are filled in.

    A flag counts as given when it was typed, also at its default value (``--tricolor-level 255`` with
    ``--emulate`` is refused like ``--tricolor-level 100``: the emulated sensor lights its own board).
    """
    from ..core.config import check_count
    from ..core.errors import ConfigError

    port = getattr(args, "emulated_port", None)  # set by emulate_behind_port: name what the user typed
    how = f"--port {port} and no --camera (the emulated sensor of {args.emulate})" if port else "--emulate"
    for dest in typed(args, CAMERA_SOURCE_OPTIONS):
        if args.emulate:
            raise ConfigError(
                f"{option(dest)} is not used with {how}: the emulated sensor has its own virtual LED board and "
                f"camera; drop {option(dest)}"
            )
    for dest in typed(args, EMULATED_SOURCE_OPTIONS):
        if not args.emulate:
            raise ConfigError(
                f"{option(dest)} is only used with --emulate SCENE (the emulated sensor; or --port nlipsemu://ID "
                "without --camera)"
            )
    for dest in typed(args, ("adalight", "baud", "tricolor_level")):
        if not args.port:
            raise ConfigError(f"{option(dest)} describes the LED board: give its --port too (or drop {option(dest)})")
    if typed(args, ("exposure_ms",)) and not args.emulate and not live_camera(args):
        raise ConfigError(
            "--exposure-ms sets a live camera's exposure (--camera N or /dev/videoN); recorded frames keep theirs: "
            "drop --exposure-ms"
        )
    fill_defaults(args, SOURCE_DEFAULTS)
    if args.port:  # only then: pyserial is not needed to infer on files
        args.baud = check_baud(args)
    check_count("--frames-per-press", args.frames_per_press, minimum=1)
    if not 1 <= args.tricolor_level <= 255:
        raise ConfigError(f"--tricolor-level must be 1-255, got {args.tricolor_level}")
    if not args.exposure_ms > 0:
        raise ConfigError(f"--exposure-ms must be > 0, got {args.exposure_ms}")
    for dest in ("adalight", "width", "height"):
        if getattr(args, dest) is not None:
            check_count(option(dest), getattr(args, dest), minimum=1)


def live_camera(args: argparse.Namespace) -> bool:
    """Whether the stream's camera is a device (a number or /dev/...), not a recording (file, folder, pattern) nor a
    watched folder (``--watch``: ``nlips live``'s default camera is not opened then)."""
    if getattr(args, "watch", None):
        return False
    camera = args.camera if args.camera is not None else getattr(args, "default_camera", None)
    return camera is not None and (str(camera).isdigit() or str(camera).startswith("/dev/"))


def check_output_arguments(args: argparse.Namespace, out: str | None) -> None:
    """``--every`` >= 1 (0 would keep every frame), and said to do nothing without ``out`` (the output folder
    flag's value); ``--threads`` >= 0 (0: the default); ``out`` not a press folder. Shared with infer."""
    from pathlib import Path

    from ..core.config import check_count
    from ..core.errors import ConfigError
    from ..core.press_folders import is_press_folder
    from ..core.press_meta import META_FILE

    if out and is_press_folder(Path(out)):
        # the frames' results went in among its images, exit 0 (`nlips capture`, `dataset` and `demo` refuse it too)
        raise ConfigError(
            f"{out}: is a press folder (it has {META_FILE}); write the results into another folder (a press's own "
            "result goes to PRESS/nlipsnet, a lookup table's to PRESS/lut, when no --out is given)"
        )
    fill_defaults(args, {"every": 1})
    check_count("--every", args.every, minimum=1)
    check_count("--threads", args.threads, minimum=0)
    if typed(args, ("every",)) and not out:  # after the checks: a refused value's error line comes alone
        log.warning("--every without an output folder: no frames are kept")


def hold_output(
    stack: contextlib.ExitStack, out: str | Path, key: str, refusal: Callable[[Owner], str], note: dict
) -> None:
    """Hold the output folder ``out`` for ``key`` in ``stack`` until it closes, together with every run holding it
    for the same key (core.claims.held_for, as ``nlips solve`` holds its results: ``.claim-OUT~run~KEY~TOKEN``
    beside it, a killed run's going stale); ``out`` itself is not made. Raises ConfigError with ``refusal(holder)``
    when a live run of another key holds it. Used by ``nlips infer`` (its results, for its model and options) and
    by the streams' ``--out`` (:func:`held_stream_folder`)."""
    import os

    from ..core.claims import RUN_HOLD, held_for
    from .folders import remove_if_left_empty

    folder = Path(os.path.abspath(out))  # "--out ." has no name to hold beside
    remove_if_left_empty(stack, [folder.parent])  # a run ending before it writes leaves no folder made for the claim
    stack.enter_context(held_for(folder.with_name(folder.name + RUN_HOLD), key, refusal, note=note))


STREAM_COMMAND = "command"
"""The field of a hold's note (:func:`hold_output`) naming the command holding the folder ("nlips live")."""


@contextlib.contextmanager
def held_stream_folder(out: str | None, command: str):
    """Hold a stream's output folder ``out`` (``nlips live --out``, ``nlips infer STREAM --out``) for this run alone
    while the block runs (:func:`hold_output`); nothing without ``out``.

    Raises ConfigError, one line naming the folder and the other process, when another live run holds it. Why: two
    streams into one folder each replaced the other's ``frame_NNNNNN`` files, both exiting 0 and each saying
    "saved: N of N frames": a folder of two streams' frames, none whole. A stream's frames are numbered from 0 at
    every run, so no two streams share a folder (each holds it under a key of its own). OSError naming the folder
    when it cannot be written (a read-only disk: :func:`nlipscalib.core.atomic.check_can_make`), before the model
    loads."""
    import secrets

    from ..core.atomic import check_can_make

    if not out:
        yield
        return
    refusal = lambda other: (  # noqa: E731
        f"{out}: another run ({(other.note or {}).get(STREAM_COMMAND, 'nlips')}, {other.who}) is saving into it; "
        "left to it: save into another --out, or run again once it has ended"
    )
    with contextlib.ExitStack() as stack:  # a key of this run's alone: any other live run is refused
        hold_output(stack, out, secrets.token_hex(8), refusal, {STREAM_COMMAND: command})
        check_can_make(out)  # a read-only disk: one line now, not once a frame was inferred
        yield


def warn_earlier_frames(out: Path) -> None:
    """Warn when a stream's output folder ``out`` holds frames an earlier run saved (``frame_NNNNNN.npz``, of this
    nlipscalib or an older one): ``nlips live --out`` and ``nlips infer`` of a stream ``--out``.

    Why: a run replaces the frames it writes and leaves the others; after a shorter run (or one of another model,
    or after an upgrade) the folder mixed the two runs' maps without a word, its frame files alike."""
    from ..device.live import SAVED_FRAMES

    if not out.is_dir():
        return
    earlier = sorted(out.glob(SAVED_FRAMES))
    if earlier:
        log.warning(
            "%s: holds %d frame(s) an earlier run saved (%s, ...): this run replaces those it writes and leaves the "
            "rest, so the folder may mix two runs; give another --out to keep them apart",
            out,
            len(earlier),
            earlier[0].name,
        )


def open_frames(
    args: argparse.Namespace,
    stack: contextlib.ExitStack,
    loop: bool = False,
    camera_response: str = "linear",
    tone_curve: np.ndarray | None = None,
    stats: LiveStats | None = None,
    read_ahead: bool = False,
    shape: tuple[int, int] | None = None,
    stop: Callable[[], bool] | None = None,
) -> tuple[FrameSource, Callable[[int], None] | None]:
    """(source, before_frame) for the flags of :func:`add_source_arguments`; closed by ``stack`` (an ExitStack).
    ``camera_response``: the model's (``Predictor.camera_response``); a live camera is asked for gamma 1.0 only
    when "linear", else its own curve is left on, as the calibration's captures had it and the model undoes it.
    ``tone_curve``: that curve's table (``Predictor.tone_curve``), undone on each camera or file frame as it is
    converted (``device.camera.to_stored``: an 8-bit frame in one 256-entry lookup; the source's ``tone_curve``
    says so, and the predictor is then told its frames are in light: ``MismatchWatch.in_light``). ``shape``: (H, W)
    of the model's frames, which a watched folder's files must have (``--watch``: there is no first frame to go by);
    ``stop``: asked while a watched folder waits for its next file (SIGTERM's flag: ``SigtermEndsStream``).
    A watched folder is read on the stream's thread, each file as it lands, never ahead (``read_ahead`` or not): a
    reader thread a file ahead gained no frame rate and no latency (benchmarks/RESULTS.md, s39-livewatch); its
    ``current`` (the file of the frame read last) is the returned source's (``cli._watch.frame_files``).

    The emulated sensor when ``--emulate``, a watched folder (``device.watch_folder``) when ``--watch``, else
    ``--camera`` (camera, folder or video) with the LED board
    at ``--port`` lit in the tri-colour pattern (``nlipsemu://ID``: a virtual board of that id, started here
    when this process has none).

    The emulated sensor's stream is its script once (the undeformed dome, then each press, for
    ``--frames-per-press`` frames each) and then ends, as a recording does; it loops when ``loop`` (a window
    shows it: until q) or a frame limit (``--max-frames``) asks for more.

    The LED board (``--port``, the emulated sensor's own) is watched at every frame read
    (:class:`nlipscalib.device.live_leds.ResetWatch`): a reset relit and said, the frames read while its LEDs were
    dark dropped and counted in ``stats.dropped`` (a recording's frames, not lit by it, all kept). ``read_ahead``: a
    recording is decoded ahead on threads (``device.live.ReadAhead``), inside the watch, so each frame handed out is
    watched in this thread.
    """
    from ..device.camera import CameraSettings, open_source

    if args.emulate:
        return _emulated_source(args, stack, loop=loop or args.max_frames is not None, stats=stats)
    watching = bool(getattr(args, "watch", None))
    if watching:  # `nlips live --watch FOLDER`, `nlips infer MODEL --watch FOLDER`
        from ._watch import open_watched_folder

        source = stack.enter_context(open_watched_folder(args, shape, tone_curve, stop))  # read as each file lands
    else:
        camera = args.camera if args.camera is not None else getattr(args, "default_camera", None)
        settings = CameraSettings(exposure_ms=args.exposure_ms, linear_gamma=camera_response == "linear")
        source = stack.enter_context(open_source(camera, settings, tone_curve=tone_curve))
    # a watched folder's files, like a recording's, were not lit by this board at the moment they were read
    live = getattr(source, "live", False)
    if read_ahead and not live and not watching:  # a video, sequence or folder: decoded while the frame before is
        from ..device.live import ReadAhead  # inferred

        source = stack.enter_context(ReadAhead(source))
    if args.port:
        from ..device.lights_out import lights_out_on_exit
        from ..device.port import BAUD_RATE
        from ..device.virtual_board import start_board
        from .capture import DEFAULT_DESIGN, open_leds

        n_leds = args.adalight or _design_leds(DEFAULT_DESIGN)
        board = start_board(args.port, n_leds, adalight=args.adalight is not None, baudrate=BAUD_RATE)
        if board is not None:
            stack.enter_context(board)  # held while the stream runs: its URL reaches it while it lives
        controller = stack.enter_context(open_leds(args.port, args.adalight, args.baud))
        # dark again when the stream ends (its end, q, Ctrl-C, SIGTERM, an error): nothing drives them afterwards
        _light_tricolor(stack.enter_context(lights_out_on_exit(controller)), args.tricolor_level)
        if callable(getattr(controller, "check_reset", None)):  # Adalight says nothing of a reset
            from ..device.live_leds import ResetWatch

            # a reset relit at once, not found by the OFF at the end; a recording's frames were not lit by it
            source = ResetWatch(source, controller, lit_by_board=live, stats=stats)
    if live:
        # a camera's first frames are stale: the one grabbed at opening (OpenCVSource's probe) and the driver's
        # buffered one show the LEDs before the tri-colour pattern was lit (dark: "a frame unlike the calibration's
        # reference") or the gel seconds ago; dropped once here, never during the stream (the LEDs stay lit)
        source.flush()
    return source, None


@contextlib.contextmanager
def reset_at_the_end(port: str | None, stats: LiveStats) -> Iterator[dict]:
    """Word a board reset found as the stream's LED board is switched off (``lights_out_on_exit`` closing with the
    source, after the frames) for ``nlips live`` and ``nlips infer`` alike: the block sets ``["streamed"] = True``
    in the dict it gets once its frames are streamed, and ``["lit_by_board"]`` from its source; a BoardResetError
    after that is one warning (:func:`reset_at_the_end_note`) and the stream ends as streamed, exit 0; one before it
    goes on as it came (the watch's own line during the stream, the driver's as the LEDs were lit).

    Why a warning, not an error: every frame was handed on by the watch, read with the board found lit and none dark
    (a camera's), or was a recording's, not lit by the board, exactly as a reset found during the stream leaves them
    (exit 0 there); the same reset a frame later exited 2 (s38) though nothing was lost and nothing could be retaken.
    Before s38 the driver's line ("... have been restored to the last acknowledged colours; retake any frame
    captured since the previous command") was said, false there (the LEDs were switched off again)."""
    from ..device.errors import BoardResetError

    state = {"streamed": False, "lit_by_board": False}
    try:
        yield state
    except BoardResetError as exc:
        if not state["streamed"]:
            raise
        log.warning("%s", reset_at_the_end_note(port, exc, stats, state["lit_by_board"]))


def reset_at_the_end_note(port: str | None, exc: BoardResetError, stats: LiveStats, lit_by_board: bool) -> str:
    """The warning of a reset found by the LEDs' OFF after the stream's last frame (:func:`reset_at_the_end`): what
    happened, what became of the frames, that the LEDs are off, and the likely cause. ``lit_by_board``: the frames
    show the board's light (a camera, watched for dark frames); else a recording's, not lit by it."""
    from ..device.errors import BROWN_OUT_ADVICE

    frames = f"{stats.frames} frame{'s' if stats.frames != 1 else ''}"
    if lit_by_board:
        kept = f"its {frames} were each read with the board found lit and none dark, and are kept"
    else:
        kept = f"its {frames} are recorded ones, not lit by the board, and are kept"
    return (
        f"{port}: the LED board reset as the stream ended, after its last frame ({exc.reason}; found as the LEDs "
        f"were switched off): {kept}; the LEDs are off. {BROWN_OUT_ADVICE[0].upper()}{BROWN_OUT_ADVICE[1:]}"
    )


def size_emulator_for(args: argparse.Namespace, shape: tuple[int, int]) -> None:
    """The emulated sensor (``--emulate``) renders at a model's image size ``shape`` (H, W) unless ``--width`` /
    ``--height`` say otherwise; a size that differs is refused now, not after rendering the script (~20 s)."""
    from ..core.errors import ConfigError

    if not args.emulate:
        return
    h, w = shape
    if (args.width or w, args.height or h) != (w, h):
        given = " ".join(f"--{k} {v}" for k, v in (("width", args.width), ("height", args.height)) if v is not None)
        raise ConfigError(
            f"{given}: the model {args.model} was calibrated for {w}x{h} images; give --width {w} --height {h}, "
            "or leave both out"
        )
    args.width, args.height = w, h  # one side typed, at the model's: the other is the model's too, not the scene's


def check_emulated_sensor(args: argparse.Namespace, sensor: dict, reference_depth: np.ndarray | None = None) -> None:
    """Refuse ``--emulate SCENE`` when its sensor (camera at the size streamed, LEDs, undeformed dome) is not the one
    the model was calibrated for (``sensor``, the model's record; ``reference_depth``, (H, W) float mm, its
    calibration's undeformed surface), as ``nlips infer`` refuses presses of another sensor (the same checks:
    :func:`nlipscalib.core.sensor_record.sensor_mismatch` and ``surface_mismatch``). Called after
    :func:`size_emulator_for`, before anything is rendered.

    Why: the emulated scene's geometry is known, yet only the brightness heuristic (`learn.watch.MismatchWatch`) spoke,
    and a scene of similar brightness streamed another sensor's frames through the model without a word; a scene of
    another dome with the model's camera and LEDs (a copy of fingertip.toml with another height) still did.
    """
    from ..core.dome import reference_surface
    from ..core.errors import CaptureError
    from ..core.sensor_record import camera_response_of, describe_sensor, sensor_mismatch, surface_mismatch
    from ..sim.scene import load_scene

    if not args.emulate:
        return
    scene = load_scene(args.emulate)
    scene = scene.replace(camera={k: v for k, v in {"width": args.width, "height": args.height}.items() if v})
    why = sensor_mismatch(sensor, describe_sensor(scene.camera_model(), scene.led_models(), scene.noise.response()))
    if not why and reference_depth is not None:
        why = surface_mismatch(reference_depth, reference_surface(scene.design).depth)
    if not why and (response := camera_response_of(sensor)) != "linear":  # emulated frames are linear
        why = f"its frames are linear, the model's calibration declared the camera response {response}"
    if why:
        raise CaptureError(
            f"--emulate {args.emulate}: the emulated sensor of {args.emulate} is another sensor than the model "
            f"{args.model} was calibrated for ({why}); stream the scene the model was calibrated on"
        )


def _design_leds(name: str) -> int:
    from ..sim.scene import load_scene

    return len(load_scene(name).led_models())


def add_device_arguments(p: argparse.ArgumentParser) -> None:
    """``--device``, ``--full-frame`` and ``--onnx``, shared by ``nlips infer`` and ``nlips live``."""
    p.add_argument(
        "--device",
        default="cpu",
        help="where frames are inferred: cpu (default) or cuda / cuda:N: every step on that GPU with PyTorch "
        "(the same change rule and results as on the CPU; ~210-350 frames/s at 640x480 on an H100, the paper's "
        "net to a 64-64-64 one)",
    )
    p.add_argument(
        "--full-frame",
        action="store_true",
        help="the network's normals on every gel pixel and depth over the whole gel, not only where the frame "
        "changed (meant for a GPU: on a CPU about 10x slower than the default; there the normals come from "
        "MODEL.frame.onnx, `nlips export MODEL --full-frame`, when it is beside the model or with --backend onnx; "
        "not for a lookup table, which runs on the changed pixels)",
    )
    p.add_argument(
        "--onnx",
        metavar="FILE",
        help="the ONNX file to run, written elsewhere by `nlips export MODEL --out FILE` (default: MODEL.onnx beside "
        "the model, which --backend auto looks for; MODEL.frame.onnx with --full-frame); checked to be the model's "
        "before it runs, refused in one line if not",
    )


def nlipsnet_predictor(args: argparse.Namespace, depth: bool = True) -> Predictor:
    """The NLiPsNet or lookup table of ``args.model`` (``--backend``, ``--threads``, ``--device``, ``--full-frame``)
    for a stream or still frames; its ``predict_stored`` maps a stored frame ((H, W, 3) uint16) to a result with
    ``normals`` and ``depth`` (what the live sinks show)."""
    from ..core.errors import ConfigError

    try:
        from ..learn.infer import Predictor, onnx_backend, predictor_device
    except ModuleNotFoundError:
        raise ConfigError(
            "--model needs nlipscalib.learn.infer (NLiPsNet and lookup tables), which this installation lacks"
        ) from None
    backend = onnx_backend(args.backend, args.onnx, args.device, args.full_frame, flag=True)
    predictor_device(args.device, backend, args.full_frame, flag=True)  # worded with the flags, not keywords
    predictor = Predictor(
        args.model,
        backend=backend,
        threads=args.threads,
        depth=depth,
        device=args.device,
        full_frame=args.full_frame,
        onnx=args.onnx,
    )
    if getattr(args, "reference", None):  # `nlips infer --reference FRAME`: an aged sensor, refreshed
        reference = refreshed_reference(predictor, args.reference)
        check_undeformed_frame(predictor, reference, args.reference, force=getattr(args, "force_reference", False))
        predictor.refresh(reference)
    return predictor


def check_undeformed_frame(predictor: Predictor, frame: np.ndarray, path: str | Path, force: bool = False) -> None:
    """Refuse ``--reference``'s frame ((H, W, 3) float32, linear) in one line naming it when it shows a press
    (:func:`nlipscalib.learn.reference_press.press_in_frame` against the calibration's reference frame the model
    carries); with ``force`` (``--force-reference``) a warning, and it is used.

    Why refused, not warned: the refresh built on it carries the dent into every frame of the run, and every result
    saved from them is judged against it, silently; the remedy (another frame with nothing on the gel) takes
    seconds. No clean frame was refused on the twin, the emulated camera, aged LEDs or a scuff (s34-inferref)."""
    from ..core.errors import CaptureError
    from ..learn.reference_press import LedShares, press_in_frame

    leds = LedShares.of_model(predictor.model.sensor, predictor.model.reference)
    found = press_in_frame(predictor.ref_tricolor, frame, predictor.valid, leds)
    if found is None:
        return
    x, y, w, h = found.box
    what = (
        f"--reference {path}: shows a press ({found.share:.1%} of the gel, pixels x {x}-{x + w - 1}, y {y}-{y + h - 1},"
        " changed in colour from the calibration's reference as a contact changes it, not as dimmed LEDs, another "
        "exposure or a scuffed coating do): every frame would be judged against its dent"
    )
    if force:
        log.warning("%s; used anyway (--force-reference)", what)
        return
    raise CaptureError(
        f"{what}; take the undeformed frame again with nothing touching the gel, or give --force-reference to use "
        "it anyway"
    )


def refreshed_reference(predictor: Predictor, path: str | Path) -> np.ndarray:
    """(H, W, 3) float32, linear: ``--reference``'s undeformed frame, a press folder's tri-colour frame or a 16-bit
    tri-colour PNG (linearised with the model's dark frame); a bad one is one CaptureError naming it."""
    from pathlib import Path

    from ..core.errors import CaptureError
    from ..core.imageio import read_png16
    from ..learn.infer import load_tricolor

    path = Path(path)
    if path.is_dir():
        frame, _ = load_tricolor(path)
        if frame.shape != predictor.shape + (3,):
            h, w = predictor.shape
            raise CaptureError(f"--reference {path}: image is {frame.shape[1]}x{frame.shape[0]}, the model's {w}x{h}")
        return frame
    if not path.is_file():
        raise CaptureError(f"--reference {path}: no such press folder or image file")
    return predictor.linear(read_png16(path), f"--reference {path}")


def _emulated_source(
    args: argparse.Namespace, stack: contextlib.ExitStack, loop: bool, stats: LiveStats | None = None
) -> tuple[ResetWatch, Callable[[int], None]]:
    from ..emulator import EmulatedCamera, ScriptedStream, TwinRenders, default_script, load_script, tricolor_level
    from ..sim.scene import load_scene

    scene = load_scene(args.emulate)
    check_size_pair(args.width, args.height, (scene.camera.width, scene.camera.height))
    scene = scene.replace(camera={k: v for k, v in {"width": args.width, "height": args.height}.items() if v})
    script = load_script(args.script) if args.script else default_script(3)
    from ..device.controller import LedController
    from ..device.virtual_board import VirtualBoard

    board_id = getattr(args, "board_id", None)
    if board_id is not None:
        from ..device.virtual_board import emulated_sensor_note

        print(emulated_sensor_note(args.emulated_port, args.emulate), file=sys.stderr)
    board = stack.enter_context(VirtualBoard(len(scene.led_models()), board_id=board_id))
    controller = stack.enter_context(LedController.open(board.url))
    renders = TwinRenders(scene)
    camera = EmulatedCamera(renders, lambda: board.latched, flush_frames=0)
    _light_tricolor(controller, tricolor_level(renders))
    surfaces = [None] + [s.press for s in script]
    from ..progress import working

    # render now, so the frame rate measures the stream, not the twin; said, as the stream was silent for the
    # seconds (640x480: tens of seconds on a loaded 2-core CPU) before its first frame
    size = f"{scene.camera.width}x{scene.camera.height}"
    with working(f"rendering the emulated sensor's {len(surfaces)} scripted surfaces ({size}) before the stream"):
        for surface in surfaces:
            renders.images(surface)
    from ..device.live_leds import ResetWatch

    script = ScriptedStream(camera, surfaces, args.frames_per_press, loop)
    # its board is watched as a real one is (a reset injected through its nlipsemu:// URL darkens the twin's frames)
    return ResetWatch(camera, controller, lit_by_board=True, stats=stats), script


class SigtermEndsStream:
    """SIGTERM during a stream (``kill``, ``timeout``, systemd, a job scheduler) ends it as Ctrl-C does: the frame
    being inferred finished and saved whole, the summary printed and written (``stream.json``), then exit 143
    (:func:`nlipscalib.cli.terminated`: the command's "terminated" line, the code scripts test).

    Why: the command's own SIGTERM handler (``cli._terminate_cleanly``) ends the process at once, so a stream stopped
    with ``kill`` lost its frame count, rate, stage line and ``stream.json``; labs stop hours-long streams that way.
    Only a flag is set in the handler, read by ``device.live.stream`` before each frame (its ``stop``): no exception
    lands inside the network's runtime or a write. Armed (:meth:`arm`) just before the frames flow, so a SIGTERM
    while the model loads or the emulator renders its script still ends the process at once; held until the
    summary is out (the ``with`` block; with an LED board, whose lights-off handler was installed before it and is
    put back as the source closes, the command's handler is back a few milliseconds before the summary). A second
    SIGTERM goes to the handler before, which ends the process at once (a read that never returns: a camera that
    stopped sending).

    Use: ``with SigtermEndsStream() as term:`` ... ``term.arm()``; ``stream(..., stop=term)`` ...; the summary; then
    ``if term.received: return cli.terminated(args)``.
    """

    def __init__(self) -> None:
        self.received = False
        """Whether SIGTERM came while armed."""
        self._armed = False
        self._previous = self._handler = None

    def __call__(self) -> bool:
        return self.received

    def arm(self) -> None:
        import signal
        import threading

        if threading.current_thread() is not threading.main_thread() or self._armed:
            return  # signals reach the main thread only: a stream run elsewhere keeps the handler it has

        def handler(signum: int, frame: object) -> None:
            if self.received and callable(self._previous):
                self._previous(signum, frame)  # the second: at once
            self.received = True

        self._previous = signal.signal(signal.SIGTERM, handler)
        self._handler, self._armed = handler, True

    def __enter__(self) -> SigtermEndsStream:
        return self

    def __exit__(self, *exc: object) -> None:
        import signal

        # only while this one is still in place: a handler armed before it and put back since (the LED board's
        # lights-off, device.lights_out, closed with the stream) has put back the one before both, and restoring
        # ours would bring that stale lights-off back
        if self._armed and signal.getsignal(signal.SIGTERM) is self._handler:
            signal.signal(signal.SIGTERM, self._previous if self._previous is not None else signal.SIG_DFL)
        self._armed = False


def running_rate_report() -> Callable[[str], None] | None:
    """Where a stream's running frame rate goes (``device.live.stream``'s ``report``, once per second): stderr on
    a terminal, None (quiet) in a log or pipe and with ``--no-progress``, as for progress bars
    (:func:`nlipscalib.progress.bars_enabled`).

    Why: ``nlips live`` printed a "27.1 fps" line every second into non-TTY logs (``nlips infer`` checked only
    for a terminal, and ignored ``--no-progress``); the summary line says the rate once the stream ends."""
    from ..progress import bars_enabled

    return (lambda line: print(line, file=sys.stderr)) if bars_enabled() else None


def saved_line(folder: str, frames: int, every: int, extra: str = "") -> str:
    """Where a stream's saved maps went (``nlips live --out``, ``nlips infer ... --out``), said after its summary:
    the summary gave frame rates only, and a new user looked for the results. ``extra``: more files named."""
    kept = -(-frames // every)  # frames 0, every, 2 * every, ... (device.live.SaveSink)
    return f"saved: {kept} of {frames} frames' normals and depth in {folder} (frame_NNNNNN.npz, _normals.png{extra})"


def _light_tricolor(controller: LedBoard, level: int) -> None:
    import numpy as np

    from ..core.leds import tricolor_colors

    controller.set_all((tricolor_colors(controller.n_leds) * level).astype(np.uint8))
