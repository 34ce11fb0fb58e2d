"""``nlips live``: stream tri-colour frames into a trained NLiPsNet; show or save normal and depth maps.

Sources: a camera (with the LED board lit in the tri-colour pattern), a folder or video of recorded
tri-colour frames, or the emulated sensor (``--emulate SCENE``: the twin pressing its scripted presses
in turn; ``--port nlipsemu://ID`` without ``--camera`` is the emulated nlipstac sensor with its board at
that URL). The emulated stream is its script once, looped while a window shows it.

The predictor is pluggable: ``--model FILE`` loads an NLiPsNet from ``nlips train``;
``--predictor module:function`` loads any other one, ``function(camera_shape)`` returning a callable
that maps a stored frame ((H, W, 3) uint16) to ``nlipscalib.device.live.LiveResult``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from typing import TYPE_CHECKING, TypeAlias

from ._stream import (
    SigtermEndsStream,
    add_device_arguments,
    add_source_arguments,
    check_emulated_sensor,
    check_output_arguments,
    check_source_arguments,
    emulate_behind_port,
    nlipsnet_predictor,
    open_frames,
    running_rate_report,
    saved_line,
    size_emulator_for,
)

if TYPE_CHECKING:  # named in hints only: numpy and the device loop are imported when a stream runs
    import numpy as np

    from ..device.live import LiveResult, LiveStats

    Predict: TypeAlias = Callable[[np.ndarray], LiveResult]
    """A stream's predictor: a stored frame ((H, W, 3) uint16) -> its LiveResult (normals, depth)."""

STOPPED = "the stream stopped (a live stream does not resume; maps already saved with --out are kept)"
"""What ``nlips live`` interrupted or terminated says it left (``cli._stopped``), not "run again to resume": a live
stream cannot continue where it stopped."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "live",
        help="live normal and depth maps from tri-colour frames (NLiPsNet)",
        description="Stream tri-colour frames (a camera with the LED board lighting the tri-colour pattern, a video "
        "or image folder, or --emulate SCENE) through NLiPsNet (--model) or your own --predictor: normals, depth "
        "integrated on the dome, frames per second; shown in a window (on a display, with an OpenCV built with a GUI: "
        "opencv-python in place of the opencv-python-headless installed with nlipscalib), and/or saved with --out. "
        "Warns when the frames stop looking like the model's calibration.",
    )
    p.add_argument("--model", help="NLiPsNet model file from `nlips train`")
    p.add_argument(
        "--predictor", help=f"other predictor, module:function: a {PREDICTOR_USAGE} (nlipscalib.device.live)"
    )
    p.add_argument(
        "--backend",
        default="auto",
        choices=("auto", "torch", "onnx", "onnx-int8"),
        help="network runtime (default auto: onnxruntime when MODEL.onnx is beside the model, else PyTorch; an "
        ".onnx that is not the model's own export is refused)",
    )
    p.add_argument("--threads", type=int, default=0, help="network CPU threads (0: the library's default)")
    add_device_arguments(p)
    add_source_arguments(p, camera_default="0")
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
    """What a stream's frames are named after in messages: the emulated sensor, a camera, or the file read."""
    if args.emulate:
        return "emulated sensor"
    camera = args.camera if args.camera is not None else getattr(args, "default_camera", None)
    return f"camera {camera}" if str(camera).isdigit() or str(camera).startswith("/dev/") else str(camera)


PREDICTOR_USAGE = "function(camera_shape) returning a callable: stored frame -> LiveResult"
"""What --predictor names, as its help and its errors say it (the help pointed to the README, not in a wheel)."""


def _plugged(spec: str, shape: tuple[int, int]) -> tuple[Predict, None]:
    from ..core.errors import ConfigError

    module, _, name = spec.partition(":")
    try:
        factory = getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError, ValueError) as exc:
        raise ConfigError(f"--predictor {spec}: cannot load it ({exc}); give module:function") from None
    usage = PREDICTOR_USAGE
    if not callable(factory):
        raise ConfigError(f"--predictor {spec}: {type(factory).__name__} is not callable; give a {usage}")
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
    from ..core.errors import ConfigError, NlipsError
    from ..report.live import window_problem

    if bool(args.model) == bool(args.predictor):
        raise ConfigError("give exactly one of --model FILE (NLiPsNet) or --predictor module:function")
    emulate_behind_port(args)
    check_source_arguments(args)
    check_output_arguments(args, args.out)
    if args.max_frames is not None:
        check_count("--max-frames", args.max_frames, minimum=1)
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
            _summarise(done["stats"], done["predict"], args)
            raise
        _summarise(done["stats"], done["predict"], args)
    if term.received:  # `kill`: the summary above, then the "terminated" line and 143, as scripts expect
        from . import terminated

        return terminated(args)
    return 0


def _run_stream(args: argparse.Namespace, no_window: str | None, done: dict, term: SigtermEndsStream) -> None:
    """Open the source, the predictor and the sinks, and stream; ``no_window``: why no window shows the maps (None:
    one does); ``done`` gets ``stats`` (counted into as the frames go: what was streamed when an error ends it) and
    ``predict`` as the frames start; ``term``: armed as the frames start, SIGTERM then ends the stream as Ctrl-C
    does."""
    import contextlib

    from ..device.live import LiveStats, SaveSink, StopLive, stream
    from ..report.live import NormalMapPng, WindowSink

    with contextlib.ExitStack() as stack:
        if args.model:  # before the source: the emulated sensor then renders at the model's image size
            predict, reference_depth = _nlipsnet(args)
            size_emulator_for(args, predict.predictor.shape)
            check_emulated_sensor(args, predict.predictor.model.sensor, predict.predictor.model.reference["depth"])
        window = no_window is None
        # a model's camera response decides whether the camera is asked for gamma 1.0; a plugged predictor's: linear
        response = predict.predictor.camera_response if args.model else "linear"
        source, before_frame = open_frames(args, stack, loop=window, camera_response=response)
        if not args.model:
            predict, reference_depth = _plugged(args.predictor, source.shape)
        sinks = []
        if args.out:
            sinks.append(SaveSink(args.out, args.every, pictures=NormalMapPng()))
        if window:
            sinks.append(WindowSink(StopLive, reference_depth))
        elif not args.out:
            print(f"{no_window}: maps are not shown; use --out DIR to keep them", file=sys.stderr)
        done["stats"], done["predict"] = LiveStats(), predict
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


def _summarise(stats: LiveStats, predict: Predict, args: argparse.Namespace) -> None:
    """The stream's summary line (stdout), where --out put its maps, and how many frames differed from the
    calibration (a warning)."""
    print(stats.summary())
    if args.out and stats.frames:
        print(saved_line(args.out, stats.frames, args.every))
    watch = sys.modules.get("nlipscalib.learn.watch")  # not imported: an NLiPsNet-free stream, nothing to report
    if watch is not None and isinstance(predict, watch.MismatchWatch):
        predict.report()
