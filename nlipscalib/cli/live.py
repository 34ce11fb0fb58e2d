"""``nlips live``: stream tri-colour frames into a trained NLiPsNet or a lookup table; show or save normal and depth
maps.

Sources: a camera (with the LED board lit in the tri-colour pattern), a folder or video of recorded
tri-colour frames, a folder watched for frames as they land (``--watch FOLDER``: a capture program's, cli/_watch.py),
or the emulated sensor (``--emulate SCENE``: the twin pressing its scripted presses
in turn; ``--port nlipsemu://ID`` without ``--camera`` is the emulated nlipstac sensor with its board at
that URL). The emulated stream is its script once, looped while a window shows it.

The predictor is pluggable: ``--model FILE`` loads an NLiPsNet from ``nlips train``;
``--predictor module:function`` loads any other one, ``function(camera_shape)`` returning a callable
that maps a stored frame ((H, W, 3) uint16) to ``nlipscalib.device.live.LiveResult``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, TypeAlias

from ._stream import (
    SigtermEndsStream,
    add_device_arguments,
    add_source_arguments,
    check_emulated_sensor,
    check_output_arguments,
    check_source_arguments,
    emulate_behind_port,
    held_stream_folder,
    nlipsnet_predictor,
    open_frames,
    reset_at_the_end,
    running_rate_report,
    saved_line,
    size_emulator_for,
    warn_earlier_frames,
)
from ._watch import add_watch_arguments, check_watch_arguments
from .capture import CAMERA_RESPONSES

if TYPE_CHECKING:  # named in hints only: numpy and the device loop are imported when a stream runs
    import numpy as np

    from ..device.live import LiveResult, LiveStats

    Predict: TypeAlias = Callable[[np.ndarray], LiveResult]
    """A stream's predictor: a stored frame ((H, W, 3) uint16) -> its LiveResult (normals, depth)."""

log = logging.getLogger(__name__)

STOPPED = "the stream stopped (a live stream does not resume; maps already saved with --out are kept)"
"""What ``nlips live`` interrupted or terminated says it left (``cli._stopped``), not "run again to resume": a live
stream cannot continue where it stopped."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "live",
        help="live normal and depth maps from tri-colour frames (NLiPsNet, or a lookup table)",
        description="Stream tri-colour frames (a camera with the LED board lighting the tri-colour pattern, a video "
        "or image folder, a folder watched for frames as they land (--watch FOLDER), or --emulate SCENE) through a "
        "model file (--model: NLiPsNet from `nlips train`, or a lookup table from `nlips lut`) or your own "
        "--predictor: normals, depth integrated on the dome, frames per second; shown in a window (on a display, with "
        "an OpenCV built with a GUI: opencv-python in place of the opencv-python-headless installed with nlipscalib), "
        "and/or saved with --out. Warns when the frames stop looking like the model's calibration.",
    )
    p.add_argument("--model", help="NLiPsNet model file from `nlips train` (or a lookup table from `nlips lut`)")
    p.add_argument(
        "--predictor", help=f"other predictor, module:function: a {PREDICTOR_USAGE} (nlipscalib.device.live)"
    )
    p.add_argument(
        "--camera-response",
        metavar="{" + ",".join(CAMERA_RESPONSES) + ",FILE}",
        help="with --predictor: the camera's tone curve the predictor was made for (default: the predictor's own "
        "camera_response attribute, else linear); a live camera is asked for gamma 1.0 only when linear, srgb leaves "
        "its curve on, as a measured curve (FILE from `nlips calibrate-camera-response`) does. --model: the model "
        "records its calibration's",
    )
    p.add_argument(
        "--backend",
        default="auto",
        choices=("auto", "torch", "onnx", "onnx-int8"),
        help="network runtime (default auto: onnxruntime when MODEL.onnx is beside the model, MODEL.frame.onnx "
        "with --full-frame, else PyTorch; one of another model (left from before a retrain) is skipped with a warning, "
        "and refused by --backend onnx; a lookup table "
        "runs on NumPy: leave it at auto)",
    )
    p.add_argument(
        "--threads", type=int, default=0, help="CPU threads for the network (default 0: all this process may use)"
    )
    add_device_arguments(p)
    add_source_arguments(p, camera_default="0")
    add_watch_arguments(p)
    # the names of `nlips infer` (and, for --out, of every other command); the first names stay accepted
    p.add_argument(
        "--max-frames",
        "--frames",
        dest="max_frames",
        type=int,
        metavar="N",
        help="stop after N frames (default: until the input ends, q in the window or Ctrl-C; the emulated "
        "sensor's input is its script once, looped while a window shows it); --frames: its former name",
    )
    p.add_argument(
        "--out",
        "--save",
        dest="out",
        metavar="DIR",
        help="folder for every frame's normal map (PNG) and arrays (npz); --save: its former name",
    )
    p.add_argument("--every", type=int, help="with --out: keep every N-th frame (default 1)")
    p.add_argument("--no-window", action="store_true", help="do not open a window even if a display is present")
    p.set_defaults(func=run, stopped=STOPPED)


def _nlipsnet(args: argparse.Namespace):
    from ..learn.watch import MismatchWatch

    predictor = nlipsnet_predictor(args)
    return MismatchWatch(predictor, source_name(args)), predictor.ref_depth.astype("float32")


def source_name(args: argparse.Namespace) -> str:
    """What a stream's frames are named after in messages: the emulated sensor, a camera, the file read, or the
    watched folder (each frame then named by its file: ``cli._watch.frame_files``)."""
    if args.emulate:
        return "emulated sensor"
    if args.watch:
        return args.watch
    camera = args.camera if args.camera is not None else getattr(args, "default_camera", None)
    return f"camera {camera}" if str(camera).isdigit() or str(camera).startswith("/dev/") else str(camera)


PREDICTOR_USAGE = "function(camera_shape) returning a callable: stored frame -> LiveResult"
"""What --predictor names, as its help and its errors say it (the help pointed to the README, not in a wheel)."""


def _factory(spec: str) -> Callable:
    """The object ``--predictor module:function`` names (imported, not called); ConfigError naming it."""
    from ..core.errors import ConfigError

    module, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ConfigError(f"--predictor {spec}: cannot load it ({exc}); give module:function") from None


RESPONSE_ATTRIBUTE = "camera_response"
"""The attribute of a ``--predictor`` function that declares the camera response it was made for (one of
``core.sensor_response.CAMERA_RESPONSES``, or a measured curve's name "measured:<hash>"), as a model file records its
calibration's."""


def plugged_response(args: argparse.Namespace, factory: object) -> str:
    """The camera response a ``--predictor`` stream asks the camera for (``open_frames``): ``--camera-response``,
    else the function's :data:`RESPONSE_ATTRIBUTE`, else "linear", said once for a live camera (it is then asked
    for gamma 1.0). One line naming the option for a bad declaration or two that disagree.

    Why: a plugged predictor has no model file to record the response its maker calibrated it on; asking a camera
    whose sRGB frames it was made for to turn its gamma off would feed it other colours, silently."""
    from ..core.errors import ConfigError
    from ..core.response_curve import read_response_file
    from ..core.sensor_response import CAMERA_RESPONSES, known_response
    from ._stream import live_camera

    declared = getattr(factory, RESPONSE_ATTRIBUTE, None)
    spec = args.predictor
    if declared is not None and not known_response(declared):
        raise ConfigError(
            f"--predictor {spec}: its {RESPONSE_ATTRIBUTE} must be one of {', '.join(map(repr, CAMERA_RESPONSES))}, "
            f"got {declared!r} (or a measured curve's name, measured:<hash>)"
        )
    given = args.camera_response
    if given and given not in CAMERA_RESPONSES:  # a response file: the curve's name, as a predictor declares it
        given = read_response_file(given).name
    if given and declared and given != declared:
        raise ConfigError(
            f"--camera-response {given}: --predictor {spec} declares {RESPONSE_ATTRIBUTE} {declared!r}; drop "
            "--camera-response or give the same"
        )
    response = given or declared
    if args.emulate and response not in (None, "linear"):
        how = "--camera-response" if given else f"--predictor {spec}"
        raise ConfigError(
            f"{how}: declares the camera response {response}, but the emulated sensor's frames are linear; stream "
            "a camera with that curve, or drop the declaration"
        )
    if response is None:
        response = "linear"
        if not args.emulate and live_camera(args):
            log.info(
                "--predictor %s declares no camera response (a %s attribute, or --camera-response): the camera is "
                "asked for gamma 1.0 and its frames are taken as linear; a predictor made for a camera's sRGB frames: "
                "--camera-response srgb",
                spec,
                RESPONSE_ATTRIBUTE,
            )
    return response


def _plugged(spec: str, shape: tuple[int, int] | None, factory: object) -> tuple[Predict, None]:
    """The ``--predictor`` of ``factory`` for frames of ``shape`` (H, W); None (a watched folder without a model:
    its first file sets the size) makes it at the first frame."""
    from ..core.errors import ConfigError

    usage = PREDICTOR_USAGE
    if not callable(factory):
        raise ConfigError(f"--predictor {spec}: {type(factory).__name__} is not callable; give a {usage}")
    if shape is None:
        made: list[Predict] = []

        def at_first_frame(frame: np.ndarray) -> LiveResult:
            if not made:
                made.append(_plugged(spec, frame.shape[:2], factory)[0])
            return made[0](frame)

        return at_first_frame, None
    try:
        predict = factory(shape)
    except TypeError as exc:
        problem = f"calling it with the camera shape failed ({exc})"
        raise ConfigError(f"--predictor {spec}: {problem}; give a {usage}") from None
    if not callable(predict):
        raise ConfigError(f"--predictor {spec}: returned a {type(predict).__name__}, not a callable; give a {usage}")
    return _checked_first_call(spec, predict), None


def _checked_first_call(spec: str, predict: Predict) -> Predict:
    """``predict``, its first call's TypeError or a result without normals and depth made a ConfigError naming
    --predictor (later calls run unchecked: the check costs nothing per frame)."""
    from ..core.errors import ConfigError

    checked = False

    def first(frame: np.ndarray) -> LiveResult:
        nonlocal checked
        if checked:
            return predict(frame)
        try:
            result = predict(frame)
        except TypeError as exc:
            raise ConfigError(f"--predictor {spec}: its predictor failed on a frame ({exc})") from None
        if not (hasattr(result, "normals") and hasattr(result, "depth")):
            raise ConfigError(
                f"--predictor {spec}: its predictor returned a {type(result).__name__}, not a LiveResult "
                "(normals, depth)"
            )
        checked = True
        return result

    return first


def run(args: argparse.Namespace) -> int:
    from ..core.config import check_count
    from ..core.errors import ConfigError

    if bool(args.model) == bool(args.predictor):
        raise ConfigError(
            "give exactly one of --model FILE (NLiPsNet's or a lookup table's) or --predictor module:function"
        )
    if args.model and args.camera_response:
        raise ConfigError(
            f"--camera-response is for --predictor: the model {args.model} records its calibration's camera "
            "response; drop --camera-response"
        )
    if args.predictor and args.onnx:
        raise ConfigError(f"--onnx is for --model (its network's ONNX file); {args.predictor} runs itself: drop it")
    if not args.watch:  # beside a watched folder, --port nlipsemu://ID is the board alone (as with --camera)
        emulate_behind_port(args)
    check_watch_arguments(args)  # --watch beside another source, its folder missing: before the model loads
    check_source_arguments(args)
    check_output_arguments(args, args.out)
    if args.max_frames is not None:
        check_count("--max-frames", args.max_frames, minimum=1)
    with held_stream_folder(args.out, "nlips live"):  # another stream saving into --out: refused (one line)
        if args.out:
            warn_earlier_frames(Path(args.out))
        return _run_held(args)


def _run_held(args: argparse.Namespace) -> int:
    """:func:`run` once its arguments are checked and its --out folder held."""
    from ..core.errors import NlipsError
    from ..report.live import window_problem

    no_window = "--no-window" if args.no_window else window_problem()
    done = {}
    with SigtermEndsStream() as term:
        try:
            _run_stream(args, no_window, done, term)
        except (NlipsError, OSError):
            if "stats" not in done or not done["stats"].frames:
                raise
            # frames were streamed before it (a camera that stopped sending, a damaged recorded frame, a full disk,
            # the LED board unplugged or failing as the stream closed): their summary comes before the one error
            # line (exit 2); an hours-long stream lost its count and rate
            _summarise(done["stats"], done["predict"], args, done.get("watched"))
            raise
        _summarise(done["stats"], done["predict"], args, done.get("watched"))
    if term.received:  # `kill`: the summary above, then the "terminated" line and 143, as scripts expect
        from . import terminated

        return terminated(args)
    return 0


def _run_stream(args: argparse.Namespace, no_window: str | None, done: dict, term: SigtermEndsStream) -> None:
    """Open the source, the predictor and the sinks, and stream; ``no_window``: why no window shows the maps (None:
    one does); ``done`` gets ``stats`` (counted into as the frames go: what was streamed when an error ends it) and
    ``predict`` as the frames start; ``term``: armed as the frames start, SIGTERM then ends the stream as Ctrl-C
    does. A board reset found as the LEDs are switched off after the frames: :func:`._stream.reset_at_the_end`."""
    from ..device.live import LiveStats

    done["stats"] = LiveStats()
    with reset_at_the_end(args.port, done["stats"]) as ended:
        _open_and_stream(args, no_window, done, term, ended)


def _open_and_stream(
    args: argparse.Namespace, no_window: str | None, done: dict, term: SigtermEndsStream, ended: dict
) -> None:
    """:func:`_run_stream`'s work; ``ended["streamed"]`` set once the frames are streamed (an error after it comes
    from closing the source and the LED board), ``ended["lit_by_board"]`` from the source."""
    import contextlib

    from ..device.live import SaveSink, StopLive, stream
    from ..report.live import NormalMapPng, WindowSink
    from . import _watch
    from ._watch import WatchedFilesSink, frame_files

    with contextlib.ExitStack() as stack:
        if args.model:  # before the source: the emulated sensor then renders at the model's image size
            predict, reference_depth = _nlipsnet(args)
            size_emulator_for(args, predict.predictor.shape)
            check_emulated_sensor(args, predict.predictor.model.sensor, predict.predictor.model.reference["depth"])
        window = no_window is None
        if args.model:  # the model's camera response: the camera asked for gamma 1.0 only when linear
            tone_curve = predict.predictor.tone_curve  # undone as each frame is converted, not again by the model
            source, before_frame = open_frames(
                args,
                stack,
                loop=window,
                camera_response=predict.predictor.camera_response,
                tone_curve=tone_curve,
                stats=done["stats"],
                shape=predict.predictor.shape,  # a watched folder's files must have the model's size
                stop=term,
            )
            predict.in_light = getattr(source, "tone_curve", None) is not None
            if args.watch:  # its warnings name each frame's file, which a user can open
                predict.frame_name = frame_files(source)
        else:
            factory = _factory(args.predictor)
            response = plugged_response(args, factory)
            source, before_frame = open_frames(
                args, stack, loop=window, camera_response=response, stats=done["stats"], stop=term
            )
            predict, reference_depth = _plugged(args.predictor, source.shape, factory)
        sinks = []
        if args.out:
            sinks.append(SaveSink(args.out, args.every, pictures=NormalMapPng()))
            if args.watch:  # the frames land in no order their names tell: OUT/frames.tsv names each one's file
                sinks.append(stack.enter_context(contextlib.closing(WatchedFilesSink(args.out, args.every, source))))
        if window:
            sinks.append(WindowSink(StopLive, reference_depth))
        elif not args.out:
            print(f"{no_window}: maps are not shown; use --out DIR to keep them", file=sys.stderr)
        done["predict"] = predict
        ended["lit_by_board"] = getattr(source, "lit_by_board", False)
        if args.watch:
            done["watched"] = source
            _watch.say_watching(done["watched"], args.existing)
        term.arm()
        stream(
            source,
            predict,
            sinks,
            max_frames=args.max_frames,
            before_frame=before_frame,
            report=running_rate_report(),
            stop=term,
            stats=done["stats"],
        )
        ended["streamed"] = True


def _summarise(stats: LiveStats, predict: Predict, args: argparse.Namespace, watched: object = None) -> None:
    """The stream's summary line (stderr), where --out put its maps (its folder alone on stdout, as ``nlips infer``
    says it), how many frames differed from the calibration (a warning), and how many files a watched folder
    (``watched``) skipped."""
    from ..progress import print_result, say
    from ._watch import say_skipped

    say(stats.summary())
    if args.out and stats.frames:
        print_result(args.out)
        say(saved_line(args.out, stats.frames, args.every))
    watch = sys.modules.get("nlipscalib.learn.watch")  # not imported: an NLiPsNet-free stream, nothing to report
    if watch is not None and isinstance(predict, watch.MismatchWatch):
        predict.report()
    say_skipped(watched)
