"""``nlips infer MODEL INPUT...``: normals, depth on the dome and point clouds from tri-colour frames with NLiPsNet
(or a lookup table from ``nlips lut``, run alike: PRESS/lut/ in place of PRESS/nlipsnet/).

Inputs are press folders (PRESS/nlipsnet/ in the reconstruction format), tri-colour PNG files or folders
of them, or a stream: a video file, an image-sequence pattern, a live camera (``--camera``), the
emulated sensor (``--emulate``) or a folder watched for frames as they land (``--watch``, device/watch_folder.py).
Streams are opened and run exactly as ``nlips live`` runs them
(cli/_stream.py's source flags, device/live.py's loop): the running frame rate goes to stderr once per
second on a terminal, Ctrl-C ends the stream cleanly with its summary, and ``--out`` keeps every ``--every``-th
frame's normal map (PNG), arrays (npz: normals, depth) and, with ``--ply``, its point cloud. A press's or frame's
result gets ``nlips solve``'s figures beside it (``--figures``, default maps: normals.png, depth.png, error.png
with ground truth). Presses and frames resume instead: a result made from the same input with the same model
file and options is kept (its report's ``provenance.key``, :func:`still_provenance`), any other is inferred
again, ``--overwrite`` infers all; a re-run whose results are all kept says so at once, without loading the
model (:func:`_settings_before_loading`).
"""

from __future__ import annotations

import argparse
import contextlib
import logging
from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
from typing import TYPE_CHECKING

from ._stream import (
    SigtermEndsStream,
    add_device_arguments,
    add_source_arguments,
    check_output_arguments,
    check_source_arguments,
    emulate_behind_port,
    held_stream_folder,
    saved_line,
)
from ._watch import add_watch_arguments, check_watch_arguments
from .options import add_allow_edited, option, typed

if TYPE_CHECKING:  # named in hints only: torch, OpenCV and the device loop are imported when frames are inferred
    from pathlib import Path

    import numpy as np

    from ..core.claims import Owner
    from ..core.surface_files import GroundTruth
    from ..device.live import FrameReader, LiveStats
    from ..learn.infer import Frame, Predictor
    from ..learn.watch import MismatchWatch

    StillInput = tuple[str, Callable[[Predictor], np.ndarray], Path | None, Path]
    """(name, loader(predictor) -> linear frame, press folder or None, source path): one still input."""

log = logging.getLogger(__name__)

STILL_SUFFIXES = (".png", ".tif", ".tiff", ".pgm", ".ppm", ".jpg", ".jpeg", ".bmp")
"""Files taken as single tri-colour frames (any case; device.camera.IMAGE_SUFFIXES, what a folder source reads);
any other file is opened as a video."""
ERROR_FIGURE = ", error.png with ground truth"
"""The error map in :data:`FIGURE_FILES`' lists: drawn for a press with ground truth only, never for a frame."""
FIGURE_FILES = {
    "none": "",
    "maps": f", normals.png, depth.png{ERROR_FIGURE}",
    "full": f", normals.png, depth.png{ERROR_FIGURE}, summary.png",
}
"""What the line saying where the results are lists of each ``--figures`` level's files."""
FIGURES_DEFAULT = "maps"
"""Figures beside a press's or frame's result when --figures is not given: the maps, as ``nlips solve`` writes."""
STILLS_WARNED_IN_FULL = 3
"""Inputs of ``nlips infer`` (frames, presses) unlike the calibration's reference that are warned about in full,
each naming its file; later ones are counted (``progress.RepeatedWarning``; each with -v)."""
WATCHED = "watched"
"""What :func:`_stream_input` returns for ``--watch FOLDER``."""
STREAM_STOPPED = "the stream stopped (a stream does not resume; frames already saved with --out are kept)"
"""What ``nlips infer`` of a stream, interrupted or terminated, says it left (:func:`stopped`)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "infer",
        help="NLiPsNet (or lookup-table) normals + depth (+ PLY) from tri-colour frames: presses, PNG frames, a "
        "video or a camera",
        description="Run a trained NLiPsNet on press folders (writes PRESS/nlipsnet/ in the reconstruction format; "
        "a lookup table from `nlips lut`, PRESS/lut/), "
        "on tri-colour frames stored as images (a file, several, or a folder of frames: 16-bit PNG as captured, or "
        "8-bit PNG/JPEG/TIFF/BMP with a warning that they are coarser, read as RGB like a video's frames), "
        "or on a stream: a video file, "
        "an image-sequence pattern (frames/img_%04d.png), a camera (--camera 0) or the emulated sensor "
        "(--emulate SCENE). Only pixels that differ from the calibration's reference frame go through the "
        "network (or table); depth integrates the normals on the dome. Prints frames per second and where the time "
        "goes. "
        "A press's or frame's result made from the same input with the same model file and options is kept (a "
        "re-run resumes; the summary counts them); others are inferred again, and the log says what changed.",
    )
    p.add_argument(
        "model",
        help="model file (.pt) from `nlips train`, or a lookup table's from `nlips lut` (its presses' results go to "
        "PRESS/lut, beside PRESS/nlipsnet)",
    )
    p.add_argument(
        "inputs",
        nargs="*",
        default=[],  # not "required" (argparse's word for a bare nargs="*"): --camera / --emulate stand in for them
        help="press folder(s), a folder of presses, image file(s) (PNG, JPEG, TIFF, ...), a folder of them, or one "
        "video file or image-sequence pattern",
    )
    add_source_arguments(p, camera_default=None)
    p.add_argument(
        "--backend",
        choices=("auto", "torch", "onnx", "onnx-int8"),
        default="auto",
        help="network runtime (default auto: onnxruntime when MODEL.onnx is beside the model, MODEL.frame.onnx "
        "with --full-frame, else PyTorch; one of another model (left from before a retrain) is skipped with a warning, "
        "and refused by --backend onnx; onnx-int8: "
        "dynamic int8 quantisation, faster for large nets, ~0.05 deg)",
    )
    p.add_argument("--out", help="output folder (frames and streams: required to save results; presses: PRESS/)")
    p.add_argument("--ply", action="store_true", help="also write a PLY point cloud per frame")
    p.add_argument("--mesh", action="store_true", help="PLY with grid triangles (implies --ply)")
    p.add_argument(
        "--no-depth",
        action="store_true",
        help="normals only: the integration is skipped, and the depth (and --ply points) saved are the undeformed "
        "dome's",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="presses and frames: infer again even where an identical result exists (by default a result made "
        "from the same input with the same model file and options is kept, so an interrupted run resumes)",
    )
    p.add_argument(
        "--threads", type=int, default=0, help="CPU threads for the network (default 0: all this process may use)"
    )
    add_device_arguments(p)
    p.add_argument(
        "--reference",
        metavar="FRAME",
        help="an undeformed capture of the sensor taken now (a press folder, or a 16-bit tri-colour PNG as "
        "captured): frames are brought back to the calibration's light first, so LEDs that dimmed with age, a "
        "drifted exposure or gain and a scuffed coating need no new training (the warning about them says when); "
        "with --device and --full-frame too (applied on the device)",
    )
    p.add_argument(
        "--force-reference",
        action="store_true",
        help="use --reference FRAME even when it looks pressed (refused by default: a frame whose colours changed "
        "in one patch as a contact changes them would carry its dent into every frame; dimmed LEDs, another "
        "exposure or a scuffed coating are not refused)",
    )
    p.add_argument(
        "--figures",
        choices=("none", "maps", "full"),
        help="presses and frames: figures beside each result, as `nlips solve` writes them: maps (PNG normal map, "
        "depth map with a colour bar in mm and, for a press with ground truth, the error map; fast; default), full "
        "(plus a matplotlib summary sheet), none. A stream keeps its frames' normal maps (--out)",
    )
    p.add_argument("--no-figures", dest="figures", action="store_const", const="none", help="same as --figures none")
    add_watch_arguments(p)
    p.add_argument("--max-frames", type=int, help="stream: stop after this many frames (default: its end or Ctrl-C)")
    p.add_argument("--every", type=int, help="stream with --out: keep every N-th frame (default 1)")
    add_allow_edited(p, "infer the tri-colour frame of")
    p.set_defaults(func=run, stopped=stopped)


def stopped(args: argparse.Namespace) -> str | None:
    """What ``nlips infer`` says it left when interrupted or terminated (``cli._stopped``): :data:`STREAM_STOPPED`
    for a stream (a camera, the emulated sensor, ``--port nlipsemu://ID`` alone, a video or an image sequence),
    which run again starts over; None (finished work is kept, run again to resume) for presses and frames."""
    from ..device.virtual_board import url_board_id

    if args.camera is not None or args.emulate or args.watch:  # --port nlipsemu://ID alone sets emulate in run
        return STREAM_STOPPED
    if not args.inputs and url_board_id(args.port) is not None:  # ... and before
        return STREAM_STOPPED
    return STREAM_STOPPED if _stream_input(args) is not None else None


def run(args: argparse.Namespace) -> int:
    from ..core.config import check_count
    from ..core.errors import ConfigError

    if not args.inputs and not args.watch:
        emulate_behind_port(args)  # --port nlipsemu://ID alone: the emulated sensor, as nlips live streams it
    stream_input = _stream_input(args)
    if stream_input is None and not args.inputs:
        raise ConfigError(
            "give inputs (presses, PNG frames or a video), --camera SPEC, --emulate SCENE, --watch FOLDER or --port "
            "nlipsemu://ID"
        )
    check_watch_arguments(args)  # --existing / --poll alone, the folder missing: one line before the model loads
    if args.max_frames is not None:
        check_count("--max-frames", args.max_frames, minimum=1)
    if stream_input is None:  # only a stream lights the LED board, or has frames to count or skip
        for dest in typed(args, ("port", "adalight", "baud", "tricolor_level")):
            raise ConfigError(
                f"{option(dest)} is not used with press folders or image files (they are read as captured); it "
                "lights the LED board while a camera streams (--camera)"
            )
        for dest in typed(args, ("max_frames", "every")):
            raise ConfigError(
                f"{option(dest)} is for a stream (a video, --camera, --emulate): press folders and image files "
                "are each inferred once; drop it"
            )
        args.figures = args.figures or FIGURES_DEFAULT
    else:
        if args.overwrite:  # a stream always starts over: there is nothing the flag would change
            raise ConfigError(
                "--overwrite is for press folders and image frames (their identical results are kept otherwise); a "
                "stream does not resume: it writes its frames anew on every run"
            )
        if args.figures is not None:  # its per-frame pictures are the normal maps SaveSink keeps
            raise ConfigError(
                "--figures is for press folders and image files: a stream with --out keeps every --every-th "
                "frame's normal map (PNG) beside its arrays; drop it"
            )
    if args.force_reference and not args.reference:
        raise ConfigError(
            "--force-reference is for --reference FRAME (an undeformed frame that looks pressed); drop it"
        )
    check_source_arguments(args)
    check_output_arguments(args, args.out)
    if args.reference and not args.allow_edited:  # a press folder's frame as the undeformed one: checked as the inputs
        from pathlib import Path

        from ..core.press_folders import is_press_folder

        if is_press_folder(Path(args.reference)):
            _check_presses_unchanged([Path(args.reference)])
    if stream_input is not None:
        return _run_stream(args, stream_input)
    from ..learn.model import model_method

    # PRESS/nlipsnet for a network, PRESS/lut for a lookup table (`nlips lut`): both results of a press side by side
    args.result_dir = model_method(args.model)
    return _run_stills(args)


# ---------------------------------------------------------------------- streams
def _stream_input(args: argparse.Namespace):
    """What to stream from ("emulated", a camera spec or a video path), or None for still frames and presses."""
    from pathlib import Path

    from ..core.errors import ConfigError

    videos = [
        i
        for i in args.inputs
        if ("%" in i and not Path(i).exists())  # a pattern, not a file whose name holds a % ("press 50%.png")
        or (Path(i).is_file() and Path(i).suffix.lower() not in STILL_SUFFIXES)
    ]
    chosen = [x for x in (args.emulate and "emulated", args.camera, args.watch and WATCHED, *videos) if x]
    if len(chosen) > 1 or (chosen and len(args.inputs) > len(videos)):
        raise ConfigError(
            "a stream (a video, --camera, --emulate or --watch) is inferred on its own: give one at a time"
        )
    return chosen[0] if chosen else None


def _check_video(path: str) -> None:
    """One line naming the file when OpenCV cannot decode it (OpenCV itself would only say 'camera ...')."""
    import os
    from pathlib import Path

    from ..core.errors import CaptureError, require
    from ..core.imageio import opencv_path

    # FFmpeg prints its own parse errors ("moov atom not found") to stderr at OpenCV's default level; the
    # one-line error below names the file instead. Read once, when OpenCV first loads its FFmpeg backend.
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "-8")
    cv2 = require("cv2", "opencv-python-headless", "Reading a video")
    if "%" in path and not Path(path).exists():  # an image sequence: opened now, before the model loads
        from ..device.camera import open_source

        open_source(path).close()
        return
    if not Path(path).is_file():
        raise CaptureError(f"{path}: no such video file")
    cap = cv2.VideoCapture(opencv_path(path))
    try:
        if not cap.isOpened() or not cap.grab():
            from ..device.camera import unreadable_file

            raise CaptureError(unreadable_file(path))
    finally:
        cap.release()


def _run_stream(args: argparse.Namespace, what: str) -> int:
    import pathlib

    from ..core.errors import require
    from ._stream import check_emulated_sensor, nlipsnet_predictor, size_emulator_for, warn_earlier_frames

    cv2 = require("cv2", "opencv-python-headless", "Reading a video or camera")
    # our one-line errors say it better; opencv-python-headless 4.8 has no cv2.utils.logging, only cv2.setLogLevel
    opencv_log = getattr(cv2.utils, "logging", None)
    if opencv_log is not None:
        opencv_log.setLogLevel(opencv_log.LOG_LEVEL_ERROR)
    else:
        cv2.setLogLevel(2)  # OpenCV's LOG_LEVEL_ERROR
    video = what not in ("emulated", args.camera, WATCHED)
    if video:
        _check_video(what)
        args.camera = what
    name = {"emulated": "emulated sensor", WATCHED: args.watch}.get(what, what if video else f"camera {what}")
    with held_stream_folder(args.out, "nlips infer"):  # another stream into --out: refused before the model loads
        predictor = nlipsnet_predictor(args, depth=not args.no_depth)
        if args.out:
            warn_earlier_frames(pathlib.Path(args.out))
        size_emulator_for(args, predictor.shape)
        check_emulated_sensor(args, predictor.model.sensor, predictor.model.reference["depth"])
        with SigtermEndsStream() as term:
            code = _stream_and_finish(args, name, predictor, term)
    if term.received:  # `kill`: the summary and stream.json above, then the "terminated" line and 143
        from . import terminated

        return terminated(args)
    return code


def _stream_and_finish(args: argparse.Namespace, name: str, predictor: Predictor, term: SigtermEndsStream) -> int:
    """Stream the frames of ``args``'s source through ``predictor`` (``term``: armed as the frames start), then its
    summary lines and stream.json (:func:`_finish_stream`); returns 0, or raises the stream's error after them."""
    import contextlib
    import time

    from ..core.errors import CaptureError, NlipsError
    from ..device.live import LiveStats, SaveSink, stream
    from ..learn.watch import MismatchWatch
    from ..report.live import NormalMapPng
    from . import _watch
    from ._stream import open_frames, reset_at_the_end, running_rate_report
    from ._watch import WatchedFilesSink, frame_files, say_skipped

    stats, watch, stages, cpu0, watching = LiveStats(), None, None, None, False
    try:
        # a board reset found as the LEDs are switched off after the frames: said as nlips live says it
        with reset_at_the_end(args.port, stats) as ended, contextlib.ExitStack() as stack:
            # the model's tone curve undone as each frame is converted (an 8-bit frame's in one 256-entry lookup,
            # on ReadAhead's threads for files), not again by the predictor
            source, before_frame = open_frames(
                args,
                stack,
                camera_response=predictor.camera_response,
                tone_curve=predictor.tone_curve,
                stats=stats,
                read_ahead=True,
                shape=predictor.shape,
                stop=term,
            )
            in_light = getattr(source, "tone_curve", None) is not None  # the emulated sensor: linear frames
            if tuple(source.shape) != predictor.shape:
                (h, w), (mh, mw) = source.shape, predictor.shape
                raise CaptureError(
                    f"{name}: frames are {w}x{h}, the model {args.model} was calibrated for {mw}x{mh} images"
                )
            watching = args.watch is not None  # waits for files to land: never ends, reads none ahead
            if not args.emulate and not watching and not getattr(source, "live", False):  # a video, ...: it ends
                source = _EndsCleanly(source)  # decoded ahead on threads (open_frames's read_ahead)
            stages = _StageTimes()
            sinks = []
            if args.out:
                sinks.append(SaveSink(args.out, args.every, pictures=NormalMapPng()))
                if args.ply or args.mesh:
                    sinks.append(_PlySink(args.out, args.every, args.mesh))
                if watching:
                    sinks.append(
                        stack.enter_context(contextlib.closing(WatchedFilesSink(args.out, args.every, source)))
                    )
            elif args.ply or args.mesh:
                log.warning("--ply without --out: no point clouds are written")

            watch = MismatchWatch(
                predictor, name, in_light=in_light, frame_name=frame_files(source) if watching else None
            )
            if watching:
                _watch.say_watching(source, args.existing)

            def predict(frame: np.ndarray) -> Frame:
                return stages.add(watch(frame))

            ended["lit_by_board"] = getattr(source, "lit_by_board", False)
            term.arm()
            cpu0 = time.process_time()
            stream(
                source,
                predict,
                sinks,
                max_frames=args.max_frames,
                before_frame=before_frame,
                report=running_rate_report(),
                stop=term,
                stats=stats,
            )
            cpu = time.process_time() - cpu0
            ended["streamed"] = True
    except (NlipsError, OSError):
        if not stats.frames or watch is None:
            raise
        # frames were inferred and saved before it (a live camera that stopped sending, a full disk, the LED board
        # unplugged or failing as the stream closed): their summary comes before the one error line (exit 2), as
        # for a damaged frame of a recording; a stream of hours lost its count and rate, and stream.json
        cpu = time.process_time() - cpu0
        _finish_stream(args, name, predictor, stats, stages, cpu, watch, after_error=True)
        raise
    _finish_stream(args, name, predictor, stats, stages, cpu, watch)
    if watching:
        say_skipped(source)
    if getattr(source, "failure", None) is not None:  # a damaged frame: after what came before it, one line
        raise CaptureError(f"{source.failure} (the stream stopped there, after {stats.frames} frames)")
    return 0


def _finish_stream(
    args: argparse.Namespace,
    name: str,
    predictor: Predictor,
    stats: LiveStats,
    stages: _StageTimes,
    cpu: float,
    watch: MismatchWatch,
    after_error: bool = False,
) -> None:
    """A stream's summary lines, its mismatch count and (with --out) its stream.json. ``after_error``: the stream
    ended on an error, whose line follows; stream.json is then left out when it cannot be written (the disk that
    filled), not made a second error."""
    from ..progress import print_result, say

    say(stats.summary())  # stderr: the rates; stdout: where the frames went (below), alone
    say(stages.summary(predictor, cpu, stats, args.no_depth))
    watch.report()
    if args.out and stats.frames:
        reported = "; stream.json"
        try:
            _write_stream_report(args.out, name, predictor, stats, stages, cpu)
        except OSError:
            if not after_error:
                raise
            reported = ""
        ply = ", .ply" if args.ply or args.mesh else ""
        print_result(args.out)
        say(saved_line(args.out, stats.frames, args.every, f"{ply}{reported}"))


class _EndsCleanly:
    """A recorded stream (video, image sequence) whose end ends the stream, even before --max-frames; a frame
    that cannot be read (a damaged file) ends it too, and is kept in ``failure`` to be raised after the summary
    (the frames before it are inferred and saved)."""

    def __init__(self, source: FrameReader) -> None:
        self.source = source
        self.shape = source.shape
        self.failure = None

    def read(self):
        from ..core.errors import CaptureError
        from ..device.camera import EndOfFrames
        from ..device.live import StopLive

        try:
            return self.source.read()
        except EndOfFrames:
            raise StopLive from None
        except CaptureError as exc:
            self.failure = exc
            raise StopLive from None


STAGE_MEDIAN_BIN = 1e-3
"""Relative width of the bins a stream's stage-time medians are counted in (:class:`_StageTimes`): a median is
its bin's geometric centre, within 0.05 % of the exact one (the stage line prints 0.1 ms of 10-50 ms)."""
STAGE_TIME_RANGE_S = (1e-6, 1e3)
"""Stage times the bins cover, s: a shorter one counts in the first bin, a longer one in the last (a frame's stage
of more than 1000 s is no stream)."""


class _StageTimes:
    """Each stage's running time (:attr:`learn.infer.Frame.seconds`) over a stream, for its summary: exact sums
    (the means) and log-binned counts (the medians, :data:`STAGE_MEDIAN_BIN`), in memory fixed from the first frame.

    Why: it kept every frame's stage dict for the medians, 0.42 kB a frame (tracemalloc): 46 MB an hour at 30
    frames/s (benchmarks/RESULTS.md, "s25-soak"). Its bins then were a dict that gained an entry for each new bin a
    time fell in: a stream's times vary continuously (load, contacts), so on a loaded CPU it held 7,788 entries after
    2,000 frames (0.65 kB a frame) and went on growing for hours, up to ~10 MB (s29-soak). Now each stage counts into
    one array over :data:`STAGE_TIME_RANGE_S` (20,734 bins, 166 kB)."""

    def __init__(self) -> None:
        self.frames = 0
        self.sums: dict[str, float] = {}
        """Each stage's total time, s, in the order the stages first came ("total" among them)."""
        self.counts: dict[str, np.ndarray] = {}
        """Each stage's frames per log bin ((n,) int64, bin :func:`_time_bin`); frames with 0 s or without the stage
        are not counted (the medians take them as 0 s)."""

    def add(self, frame: Frame) -> Frame:
        import numpy as np

        for name, seconds in frame.seconds.items():
            self.sums[name] = self.sums.get(name, 0.0) + seconds
            if seconds > 0:
                bins = self.counts.get(name)
                if bins is None:
                    bins = self.counts[name] = np.zeros(_time_bin(STAGE_TIME_RANGE_S[1]) + 1, np.int64)
                bins[_time_bin(seconds)] += 1
        self.frames += 1
        return frame

    def medians(self) -> dict:
        """Each stage's median time per frame, s (0 in a frame that had no such stage), within
        :data:`STAGE_MEDIAN_BIN` of the exact median (inside :data:`STAGE_TIME_RANGE_S`)."""
        return {k: _binned_median(self.counts.get(k), self.frames) for k in self._names()}

    def means(self) -> dict:
        """Each stage's mean time per frame, s (0 in a frame that had no such stage)."""
        n = max(self.frames, 1)
        return {k: self.sums.get(k, 0.0) / n for k in self._names()}

    def _names(self) -> list[str]:
        """Every stage any frame had, in their order, "total" last."""
        names = [k for k in self.sums if k != "total"]
        return names + ["total"] if self.frames else []

    def summary(self, predictor: Predictor, cpu_s: float, stats: LiveStats, no_depth: bool) -> str:
        """The predictor's line: the mean time of each of its steps per frame, and the frame rate they add up to.

        Means, not medians: they add up (a check that runs on some frames only is in the rate), and "other" (the
        call's time outside the predictor's steps: the mismatch watch) makes them the stream's "predictor" time of
        the line before, so the rate is the predictor's call alone, without reading and output."""
        mean = self.means()
        if not mean or not stats.frames:
            return "no frames"
        where = f"{predictor.backend}{'' if predictor.device is None else f' on {predictor.device}'}"
        steps = {k: v for k, v in mean.items() if k != "total"}
        call = stats.predict_s / stats.frames
        steps["other"] = max(call - sum(steps.values()), 0.0)
        per_frame = sum(steps.values())  # the call's mean time (its steps' sum, were "other" ever negative)
        # a table's "network" stage (its key in stream.json and report.json) is its lookup: said so
        said = {"network": "table lookup"} if predictor.model.table is not None else {}
        times = ", ".join(f"{said.get(k, k)} {1e3 * v:.1f} ms" for k, v in steps.items())
        rate = f"{1 / per_frame:.1f}" if per_frame > 0 else "inf"
        return (
            f"{predictor.model.describe()} ({where}), mean per frame: {times} = {1e3 * per_frame:.1f} ms = {rate} "
            f"frames/s for the predictor alone, without read and output (normals{'' if no_depth else ' + depth'}); "
            f"process CPU {1e3 * cpu_s / stats.frames:.1f} ms/frame"
        )


def _time_bin(seconds: float) -> int:
    """The log bin of a stage time > 0 (:data:`STAGE_MEDIAN_BIN` wide, relative, from the start of
    :data:`STAGE_TIME_RANGE_S`; a time outside the range in its first or last bin)."""
    import math

    low, high = STAGE_TIME_RANGE_S
    seconds = min(max(seconds, low), high)
    return math.floor(math.log(seconds / low) / math.log1p(STAGE_MEDIAN_BIN))


def _binned_median(bins: np.ndarray | None, frames: int) -> float:
    """The median of ``frames`` stage times counted in ``bins`` (:func:`_time_bin`; frames not counted had no such
    stage, or 0 s: 0 s), each bin taken at its geometric centre; the two middle ones' mean for an even count, as
    numpy.median."""
    import math

    import numpy as np

    if not frames:
        return 0.0
    cumulative = np.cumsum(bins) if bins is not None else np.zeros(1, np.int64)
    zeros = frames - int(cumulative[-1])
    step = math.log1p(STAGE_MEDIAN_BIN)
    values = []
    for rank in sorted({(frames - 1) // 2, frames // 2}):
        if rank < zeros:
            values.append(0.0)
        else:
            k = int(np.searchsorted(cumulative, rank - zeros, side="right"))
            values.append(STAGE_TIME_RANGE_S[0] * math.exp((k + 0.5) * step))
    return (values[0] + values[-1]) / 2


class _PlySink:
    """Every ``every``-th frame's point cloud (PLY, with normals; grid triangles with ``mesh``)."""

    def __init__(self, folder: str | Path, every: int, mesh: bool) -> None:
        from pathlib import Path

        self.folder, self.every, self.mesh = Path(folder), max(int(every), 1), mesh

    def __call__(self, index: int, frame: np.ndarray, result: Frame) -> None:
        from ..learn.ply import write_ply

        if index % self.every == 0:
            write_ply(self.folder / f"frame_{index:06d}.ply", result.points, result.normals, mesh=self.mesh)


def _write_stream_report(
    out: str | Path, name: str, predictor: Predictor, stats: LiveStats, stages: _StageTimes, cpu_s: float
) -> None:
    import json
    import os
    from pathlib import Path

    from ..core.atomic import write_bytes
    from ..learn.infer import model_shape

    report = {
        "input": name,
        "model": str(predictor.model.path.resolve()),
        # what the model is, as a result's report.json says it: "nlipsnet" and its hidden layers, or "lut" and its
        # table; a stream.json from before s39-lutwords has no "method" and "hidden" [] for a table
        "method": predictor.model.method,
        "backend": predictor.backend,
        **model_shape(predictor.model),
        "frames": stats.frames,
        "dropped": stats.dropped,  # read while the LED board had reset (device.live_leds.ResetWatch)
        "wall_s": stats.seconds,
        "fps": stats.fps,
        "median_stage_s": stages.medians(),
        "mean_stage_s": stages.means(),
        "cpu_s_per_frame": cpu_s / stats.frames,
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,  # none on Windows
    }
    write_bytes(Path(out) / "stream.json", json.dumps(report, indent=2).encode())


# ---------------------------------------------------------------------- presses and still frames
def _run_stills(args: argparse.Namespace) -> int:
    """Infer the presses and frames of ``args``, their result folders held for this run's model and options until
    it ends (:func:`_hold_results`)."""
    with contextlib.ExitStack() as run_hold:
        return _infer_stills(args, run_hold)


def _infer_stills(args: argparse.Namespace, run_hold: contextlib.ExitStack) -> int:
    import time

    from ..core.errors import CaptureError
    from ..core.tolerances import FRAME_MISMATCH_FRACTION
    from ..learn.infer import REFRESH_REMEDY, capture_changes, mismatch_warning
    from ..learn.resolution import frame_warning
    from ..progress import RepeatedWarning, say, track
    from ._stream import nlipsnet_predictor

    t_start = time.perf_counter()
    frames = list(_frames(args.inputs))
    if not args.allow_edited:  # another frame copied over a press's: one line now, not the wrong frame inferred
        _check_presses_unchanged([press_folder for _, _, press_folder, _ in frames if press_folder is not None])
    saved = _check_destinations(args, frames)
    early = _settings_before_loading(args)
    if early is not None:  # a run of another model is refused before its model loads (and before a re-run says kept)
        _hold_results(run_hold, args, saved, early)
    looked = _look_before_loading(args, frames, early) if early is not None else {}
    if sum(is_kept for _, is_kept in looked.values()) == len(frames):
        # a finished run again: said at once, without loading the model (torch or onnxruntime: seconds)
        _print_folders(saved)
        say(_stills_summary(args, None, [], len(frames), time.perf_counter() - t_start))
        say(_where_saved(saved, {folder for folder, _ in saved}, bool(args.ply or args.mesh), args.figures))
        return 0
    _check_writable(args, saved, looked)  # a read-only --out: one line now, not once the model loaded
    predictor = nlipsnet_predictor(args, depth=not args.no_depth)
    if predictor.model.method != getattr(args, "result_dir", predictor.model.method):
        raise CaptureError(f"{args.model}: replaced by another kind of model while it was read; run again")
    if not args.out and any(press_folder is None for _, _, press_folder, _ in frames):
        # said once the model loaded: before, a missing or damaged model's one error line came after it
        log.warning("image frames without --out: their results are not written (give --out DIR to keep them)")
    settings = output_settings(args, predictor)
    if settings != early:  # the model file replaced since it was read above: what was looked at is looked at again
        looked = {}
        run_hold.close()  # (none held on a GPU or with --full-frame: only the loaded model tells the settings)
        _hold_results(run_hold, args, saved, settings)
    inner, kept, failed = [], set(), {}
    # a folder of frames all taken otherwise logged the same long warning for each: the first 3, then counted
    unlike = RepeatedWarning(log, "an input unlike the calibration's reference", first=STILLS_WARNED_IN_FULL)
    drifted = 0  # of those: like the reference over the gel, colours drifted (learn.infer.drift_warning)
    steep = RepeatedWarning(log, "a contact too small or steep for the calibration", first=STILLS_WARNED_IN_FULL)
    # a bar on a terminal (a folder of 300 frames ran 10 s without a sign of life); quiet elsewhere (progress)
    for name, load, press_folder, source in track(frames, enabled=len(frames) > 1, desc="inferring", unit="frame"):
        folder = _destination(args, name, press_folder)
        with contextlib.ExitStack() as held:  # the claim on its result folder, while it is inferred and saved
            try:
                provenance, is_kept = looked.get(folder, (None, False))
                if folder is not None and folder not in looked and not args.overwrite and _has_entries(folder):
                    provenance = still_provenance(settings, input_identity(press_folder, source))
                    is_kept = _kept(folder, provenance, args.figures)
                if is_kept:
                    kept.add(folder)
                    continue
                frame = load(predictor)  # first: a bad input is its one line, before a claim makes --out
                if folder is not None:
                    provenance = provenance or still_provenance(settings, input_identity(press_folder, source))
                    if _inferred_elsewhere(folder, held, provenance, args.figures):
                        kept.add(folder)
                        continue
            except CaptureError as exc:
                if len(frames) == 1:
                    raise
                # a damaged or foreign input of many: said, and the others inferred, as `nlips solve DATASET` goes on
                # (the first one stopped the whole run, leaving every input after it undone)
                log.error("%s", exc)
                failed[source] = (folder, str(exc))
                continue
            result = predictor.predict(frame)
            changes = capture_changes(predictor.model, press_folder) if press_folder is not None else []
            if why := mismatch_warning(result, source, changes):
                unlike(why, str(source))
                drifted += result.mismatch <= FRAME_MISMATCH_FRACTION  # like the reference, its colours drifted
            elif why := frame_warning(predictor, result, source):
                steep(why, str(source))
            inner.append(result.seconds["total"])
            if folder is not None:
                identity = getattr(load, "identity", None)  # an image frame's, taken as it was decoded
                _save(args, predictor, result, name, folder, provenance, press_folder, source, identity)
    unlike.flush()
    steep.flush()
    if steep.count > STILLS_WARNED_IN_FULL:
        log.warning(
            "%d of %d inputs had a contact too small or steep for the calibration (see the warnings above): their "
            "normals there are smoothed",
            steep.count,
            len(frames),
        )
    if unlike.count > STILLS_WARNED_IN_FULL and unlike.count > drifted:
        log.warning(
            "%d of %d inputs differed from the calibration's reference over most of the gel (see the warnings "
            "above): their results are unreliable",
            unlike.count - drifted,
            len(frames),
        )
    if unlike.count > STILLS_WARNED_IN_FULL and drifted:  # they were counted as differing over most of the gel
        log.warning(
            "%d of %d inputs had colours that drifted from the calibration's reference (see the warnings above): "
            "their results drift by degrees; %s",
            drifted,
            len(frames),
            REFRESH_REMEDY,
        )
    not_written = {folder for folder, _ in failed.values()}
    written = [(folder, press) for folder, press in saved if folder not in not_written]
    _print_folders(written)
    say(_stills_summary(args, predictor, inner, len(kept), time.perf_counter() - t_start))
    if written:
        say(_where_saved(written, kept, bool(args.ply or args.mesh), args.figures))
    if failed:
        rest = "run again once fixed: the rest is kept"
        say(f"failed: {len(failed)} of {len(frames)} input(s), not inferred ({rest})", warning=True)
        for source, (_, why) in failed.items():  # the error names its file mostly: said once
            say(f"  {why}" if why.startswith(f"{source}:") else f"  {source}: {why}", warning=True)
        return 1
    return 0


def _check_presses_unchanged(presses: Sequence[Path]) -> None:
    """CaptureError in one line (:func:`nlipscalib.core.press_checksums.check_unchanged`) when a file a press's
    inference reads (its tri-colour and dark frames, its reference surface) is not the size its checksums.json
    records: a stat per file and the press's meta.json, no image read. Not its ground truth: read for the error
    map only, whose damage costs that figure alone (:func:`_ground_truth_reader`).

    Why: `nlips solve`, `calibrate` and `train` refused such a press (s34-checksums); `nlips infer` inferred another
    session's tri-colour frame copied over a press's without a word, and its result kept the press's name."""
    from ..core.errors import CaptureError
    from ..core.press_checksums import check_unchanged
    from ..core.press_meta import read_meta

    def read(folder: Path) -> list[str]:
        try:
            meta = read_meta(folder)
        except CaptureError:  # said by the press's loader, naming it (a batch goes on with the others)
            return []
        images = meta.get("images") if isinstance(meta.get("images"), dict) else {}
        return [str(name) for name in (images.get("tricolor"), images.get("dark"), meta.get("reference")) if name]

    check_unchanged(list(presses), names=read)


def _settings_before_loading(args: argparse.Namespace) -> dict | None:
    """:func:`output_settings` as the model of ``args`` will give them, found without loading it (no torch, no
    onnxruntime); None where only the loaded model can tell: on a GPU or with --full-frame (torch names the
    device), or when the model is no file (its load names the problem)."""
    from pathlib import Path

    from ..learn.infer import onnx_backend, resolved_backend
    from ..learn.onnx_export import file_digest

    if args.device != "cpu" or args.full_frame or not Path(args.model).is_file():
        return None
    digest = file_digest(args.model)
    backend = onnx_backend(args.backend, args.onnx, flag=True)
    return _settings(args, digest, resolved_backend(args.model, backend, digest=digest, onnx=args.onnx), "cpu", False)


def _look_before_loading(
    args: argparse.Namespace, frames: Sequence[StillInput], settings: dict
) -> dict[Path, tuple[dict, bool]]:
    """{result folder: (provenance, kept)} of the inputs, in order, up to the first one to infer (then the model
    is loaded anyway, and each of the others is looked at as it comes): every input when a re-run finds all its
    results kept (:func:`_kept`). Empty with --overwrite, or when the first input has no result to keep."""
    from ..core.errors import CaptureError

    looked = {}
    for name, _, press_folder, source in frames:
        folder = _destination(args, name, press_folder)
        if folder is None or args.overwrite or not _has_entries(folder):
            break
        try:
            provenance = still_provenance(settings, input_identity(press_folder, source))
        except CaptureError:  # a damaged input: said by the loop over the inputs, with the model loaded
            break
        looked[folder] = (provenance, _kept(folder, provenance, args.figures))
        if not looked[folder][1]:
            break
    return looked


def _print_folders(saved: Sequence[tuple[Path, bool]]) -> None:
    """stdout: each result folder of ``saved`` ((folder, whether a press's)), one a line, alone (for scripts); the
    summary and where they are in words go to stderr (:func:`nlipscalib.progress.say`)."""
    from ..progress import print_result

    for folder, _ in saved:
        print_result(folder)


def _where_saved(saved: Sequence[tuple[Path, bool]], kept: Collection[Path], ply: bool, figures: str = "none") -> str:
    """Where the stills' results are (a new user looked for them after the frame-rate line): one folder each.

    ``saved``: (result folder, whether it is a press's) of every input with a result folder; frames' and
    presses' are said apart when both are there (a frame's is OUT/FRAME, a press's OUT/PRESS/nlipsnet or
    PRESS/nlipsnet). ``kept``: those of them left as they were (identical results): the line counts them apart
    from the ones written (it said "saved" of a re-run that wrote nothing)."""
    frames = [folder for folder, press in saved if not press]
    presses = [folder for folder, press in saved if press]
    if frames and presses:
        where = f": {len(frames)} for frames in {_where(frames)}, {len(presses)} for presses in {_where(presses, True)}"
    else:
        where = f" in {_where(frames or presses, not frames)}"
    figure_files = FIGURE_FILES[figures]
    if not presses:  # a frame has no ground truth, so no error map: the line listed error.png for frames too
        figure_files = figure_files.replace(ERROR_FIGURE, "")
    files = "result.npz, report.json" + (", points.ply" if ply else "") + figure_files
    # a frame's result has no ground truth beside it: eval scores it against the press it shows, named with --result
    # (frames alone said "nlips eval scores them", and `nlips eval OUT` then refused the folder)
    from ..core.shell_words import shell_word

    one_frame = f"nlips eval PRESS --result {shell_word(frames[0])}" if frames else ""
    if not frames:
        scores = f"{_press_eval(presses[0])} scores them"
    elif presses:
        scores = f"{_press_eval(presses[0])} scores the presses'; a frame's against the press it shows: {one_frame}"
    else:
        scores = f"no ground truth: score one against the press it shows with {one_frame}"
    written = len(saved) - len(kept)
    if not kept:
        counts = f"saved: {written} result folder(s)"
    elif not written:
        counts = f"kept: {len(kept)} result folder(s) as they were (nothing written)"
    else:
        counts = f"saved: {written} result folder(s), kept {len(kept)} as they were; all {len(saved)}"
    return f"{counts}{where} ({files}; {scores})"


def _press_eval(result: Path) -> str:
    """The `nlips eval` that scores a press's result folder ``result`` (PRESS/nlipsnet, PRESS/lut, or under --out
    OUT/PRESS/<method>). Why: the line said "nlips eval scores them", and `nlips eval PRESSES` as typed scores the
    NLiPs results, not the network's or table's, without a word."""
    from ..core.shell_words import shell_word

    if (result.parent / "meta.json").is_file():  # beside the press's own captures
        return f"nlips eval PRESS --method {result.name}"
    return f"nlips eval PRESSES --result {shell_word(result.parent.parent)}"


def _where(folders: Sequence[Path], presses: bool = False) -> str:
    """The folder that holds ``folders`` (frames' result folders), a press's result folder itself (one press), else
    where each press keeps its. A press's result is PRESS/nlipsnet (or OUT/PRESS/nlipsnet): naming the folder above
    it ("in OUT/press/") sent ``nlips eval PRESS --result OUT/press`` to "no reconstruction there"."""
    if presses and len(folders) == 1:
        return f"{folders[0]}/"
    parents = {f.parent for f in folders}
    return f"{folders[0].parent}/" if len(parents) == 1 else f"each press's {folders[0].name}/ (e.g. {folders[0]})"


def _stills_summary(
    args: argparse.Namespace, predictor: Predictor | None, seconds: Sequence[float], kept: int, wall_s: float
) -> str:
    """The stills' one summary line: frames inferred (and kept), and the frame rate of the inferred ones only
    (a kept result took no inference time; counting it would overstate the rate). ``predictor``: None when every
    result was kept (the model was not loaded)."""
    import numpy as np

    n = len(seconds)
    counts = f"{n} frame(s)"
    if kept:
        counts += f" inferred, {kept} kept (identical results; --overwrite infers them again)"
    if not n:
        return f"{counts}; whole command {wall_s:.1f} s"
    med = float(np.median(seconds))
    over = f" over the {n} inferred" if kept else ""
    return (
        f"{counts}, {_model_words(predictor)}: "
        f"median {med * 1000:.1f} ms/frame = {1 / med:.1f} frames/s{over} "
        f"(normals{'' if args.no_depth else ' + depth'}); whole command {wall_s:.1f} s"
    )


def _model_words(predictor: Predictor) -> str:
    """ "onnx, net 64-64-64" of a network, "lookup table 16 levels, 8x8 regions" of a table (its runtime is its own)."""
    if predictor.model.table is not None:
        return predictor.model.describe()
    return f"{predictor.backend}, net {'-'.join(map(str, predictor.model.hidden))}"


def _frames(inputs: Iterable[str]) -> Iterator[StillInput]:
    """(name, loader(predictor) -> linear frame, press folder or None, source path) for every input, in order."""
    from pathlib import Path

    from ..core.errors import CaptureError
    from ..core.press_folders import find_presses, is_incomplete_press, is_press_folder
    from ..core.press_meta import META_FILE, REFERENCE_FOLDER
    from ..core.reconstruction import is_reconstruction_dir
    from ..learn.dataset import INDEX_FILE, SENSOR_FILE

    eight_bit = _EightBitNotice()
    for item in inputs:
        path = Path(item)
        if path.is_file():
            yield path.stem, _image_loader(path, eight_bit), None, path
        elif path.is_dir() and (presses := find_presses(path)):
            if len(presses) > 1 or presses[0] != path:  # a folder of presses: its reference/ is no press (as solve)
                presses = [p for p in presses if p != path / REFERENCE_FOLDER] or presses
            for folder in presses:
                yield folder.name, _press_loader(folder), folder, folder
        elif path.is_dir():
            if (path / INDEX_FILE).is_file() and (path / SENSOR_FILE).is_file():  # its coverage.png is no frame
                raise CaptureError(
                    f"{path}: a calibration dataset (`nlips calibrate`), not presses or frames: infer the presses it "
                    f"was made from (e.g. {path.parent}), or give the dataset to `nlips train`"
                )
            if is_reconstruction_dir(path):  # its normals.png and depth.png are figures, no frames (s34-walk)
                press = f" ({path.parent})" if is_press_folder(path.parent) else ""
                raise CaptureError(
                    f"{path}: a reconstruction folder (result.npz: a solve's or an inference's maps), not presses or "
                    f"frames: infer the press it was made from{press}"
                )
            images = sorted(p for p in path.iterdir() if p.is_file() and p.suffix.lower() in STILL_SUFFIXES)
            if not images:
                raise CaptureError(f"{path}: no press folders and no image frames ({', '.join(STILL_SUFFIXES)}) in it")
            # A press's dark and LED images are no frames; a tri-colour frame kept under the press's name
            # (frames/tricolor.png, copied from a press) is one, so tricolor.png alone is inferred
            if is_incomplete_press(path) and any(p.name == "dark.png" or p.name.startswith("led_") for p in images):
                raise CaptureError(
                    f"{path}: looks like a press folder (dark.png, led_*.png) without its {META_FILE}: an "
                    "incomplete capture; capture it again (its dark and LED images are not tri-colour frames)"
                )
            others = sorted(p.name for p in path.iterdir() if p.is_file() and p not in images)
            if others:  # said, so a frame saved under an unexpected suffix is not silently missing
                shown = ", ".join(others[:5]) + (f" and {len(others) - 5} more" if len(others) > 5 else "")
                log.info("%s: %d file(s) that are not image frames skipped: %s", path, len(others), shown)
            stems = [image.stem for image in images]
            for image in images:  # frame.png and frame.jpg side by side: each keeps its own result folder
                name = image.stem if stems.count(image.stem) == 1 else image.name
                yield name, _image_loader(image, eight_bit), None, image
        else:
            raise CaptureError(f"{path}: no such file or folder")


class _EightBitNotice:
    """Says once per command that 8-bit frames were scaled up (and JPEG's loss), not once per frame."""

    def __init__(self) -> None:
        self.said = False

    def __call__(self, path: Path) -> None:
        if self.said:
            return
        self.said = True
        lossy = path.suffix.lower() in (".jpg", ".jpeg")
        log.warning(
            "%s: an 8-bit image%s: taken as the top 8 bits of the sensor's 16-bit values (as a video's frames "
            "are); the model was calibrated on 16-bit captures, so its colours are coarser than the training "
            "samples'%s. Save the camera's frames as 16-bit PNG for the full accuracy",
            path,
            " (JPEG, lossy)" if lossy else "",
            " and JPEG compression changes them further" if lossy else "",
        )


def _image_loader(path: Path, eight_bit: Callable[[Path], None] | None) -> Callable[[Predictor], np.ndarray]:
    def load(predictor: Predictor) -> np.ndarray:
        from ..core.press_identity import frame_identity
        from ..learn.seen import IDENTITIES_KEY

        # the model's tone curve undone as the image is converted: an 8-bit one's in one 256-entry lookup
        stored = read_still(path, eight_bit, predictor.tone_curve)
        if predictor.tone_curve is None and predictor.model.info.get(IDENTITIES_KEY):
            # the stored values as decoded are the frame's identity (report trained_on): hashed here (~2 ms at
            # 640x480), not decoded a second time when the result is saved (~12 ms a frame)
            load.identity = frame_identity(stored)
        return predictor.linear(stored, path, in_light=True)

    return load


def read_still(
    path: str | Path, eight_bit: Callable[[Path], None] | None = None, tone_curve: np.ndarray | None = None
) -> np.ndarray:
    """A tri-colour frame stored as an image file, as stored 16-bit RGB values ((H, W, 3) uint16).

    The capture format (16-bit PNG) or any image OpenCV reads (8 or 16 bits, BGR or BGRA as OpenCV returns
    it), converted as a camera's or a video's frames are (``device.camera.to_stored``: 8-bit values shifted up
    by 8 bits; ``tone_curve``, a camera's tone-curve table, undone on the way). ``eight_bit(path)`` is called for
    an 8-bit image. A grey image is refused: it is no tri-colour frame.
    """
    from pathlib import Path

    from ..core.errors import CaptureError
    from ..core.imageio import _check_png_ends as check_png_ends
    from ..core.imageio import read_image
    from ..device.camera import to_stored

    path = Path(path)
    if path.suffix.lower() == ".png":
        check_png_ends(path)  # a truncated PNG is named as such, before libpng prints its own error line
    raw = read_image(path)
    if raw is None:
        raise CaptureError(f"{path}: not a readable image")
    channels = raw.shape[2] if raw.ndim == 3 else 1
    if channels not in (3, 4):
        raise CaptureError(f"{path}: a tri-colour frame must have 3 colour channels, found {channels}")
    image, bits = to_stored(raw, str(path), tone_curve)
    if bits == 8 and eight_bit is not None:
        eight_bit(path)
    return image


def _press_loader(folder: Path) -> Callable[[Predictor], np.ndarray]:
    def load(predictor: Predictor) -> np.ndarray:
        from ..core.capture import read_optics
        from ..core.errors import CaptureError
        from ..core.sensor_record import check_sensor, surface_mismatch
        from ..learn.infer import load_tricolor

        frame, sensor = load_tricolor(folder)
        check_sensor(predictor.model.sensor, sensor, folder)
        # camera and LEDs alike, the dome may still be another (a design of one's own with another height): the
        # model's normals and depth are then meaningless, so refused as another sensor, not only warned about
        reference = read_optics(folder).reference
        if reference is not None and (why := surface_mismatch(predictor.model.reference["depth"], reference.depth)):
            raise CaptureError(f"{folder}: captured with another sensor than the model was calibrated for ({why})")
        return frame

    return load


def _destination(args: argparse.Namespace, name: str, press_folder: Path | None) -> Path | None:
    """The result folder of one input: PRESS/nlipsnet, OUT/PRESS/nlipsnet or OUT/FRAME; None for a frame
    without --out."""
    from pathlib import Path

    from ..core.reconstruction import reconstruction_dir
    from ..learn.infer import RESULT_DIR

    if press_folder is not None:
        method = getattr(args, "result_dir", None) or RESULT_DIR  # a lookup table's: lut (:func:`run`)
        return Path(args.out) / name / method if args.out else reconstruction_dir(press_folder, method=method)
    return Path(args.out) / name if args.out else None


def _check_destinations(args: argparse.Namespace, frames: Sequence[StillInput]) -> list[tuple[Path, bool]]:
    """(result folder, whether it is a press's) of each input that has one, in order; one line, before any
    inference, when two inputs would write one result folder (the last would win) or one inside the other's (a
    frame and a press of one name under one --out: OUT/X and OUT/X/nlipsnet), or when a destination holds
    something else than a result (a result replaces its folder whole) or nests with one."""
    from ..core.errors import ConfigError
    from ..core.reconstruction import check_replaceable

    seen = {}
    for name, _, press_folder, source in frames:
        folder = _destination(args, name, press_folder)
        if folder is None:
            continue
        if seen.setdefault(folder, (source, press_folder is None))[0] != source:
            raise ConfigError(
                f"{seen[folder][0]} and {source} would both be written to {folder}: infer them into separate --out "
                "folders (or rename one)"
            )
    # refused, not given other paths: a result's folder stays the one its input alone names, whatever else is
    # on the command line, so a re-run resumes it and `nlips eval PRESS --result OUT` finds it
    for folder, (source, _) in seen.items():
        if outer := next((p for p in folder.parents if p in seen), None):
            raise ConfigError(
                f"{seen[outer][0]} and {source} would be written one inside the other ({folder} inside {outer}: a "
                "frame and a press of one name): infer them into separate --out folders (or rename one)"
            )
    for folder, (source, frame) in seen.items():
        _check_not_nested(folder, frame, source)
        check_replaceable(folder, method=getattr(args, "result_dir", None) or "nlipsnet")
    return [(folder, not frame) for folder, (_, frame) in seen.items()]


def _check_not_nested(folder: Path, frame: bool, source: Path) -> None:
    """One line naming ``source`` when an earlier run's result and its result ``folder`` would nest: ``folder``
    inside a result (a press's OUT/X/nlipsnet in a frame's OUT/X), or a ``frame``'s folder holding a press's."""
    from ..core.errors import ConfigError
    from ..core.reconstruction import is_reconstruction_dir

    if is_reconstruction_dir(folder.parent):
        raise ConfigError(
            f"{source}: its result {folder} would lie inside the result folder {folder.parent}: choose another "
            "--out (or move that result away)"
        )
    inner = next((folder / m for m in ("nlipsnet", "lut") if is_reconstruction_dir(folder / m)), None)
    if frame and inner is not None:
        raise ConfigError(
            f"{source}: its result would replace {folder}, which holds a press's result ({inner}): "
            "choose another --out (or move that result away)"
        )


def output_settings(args: argparse.Namespace, predictor: Predictor) -> dict:
    """What, besides its input, decides a still's saved result (report ``provenance.settings``, docs/formats.md).

    The model by its content (``model_digest``, the first 16 hex digits of the .pt's SHA-256: a copy elsewhere is the
    same model, a retrained one at the same path is not; its reference frame is inside it), the runtime that
    ran it (``backend`` as resolved from auto, ``device``, ``full_frame``: their numbers differ slightly), ``depth``
    (False with --no-depth) and ``ply`` (null, "points" or "mesh": the files written). ``--threads`` changes only
    the speed, so it is not recorded.
    """
    return _settings(
        args, predictor.model.digest, predictor.backend, str(predictor.device or "cpu"), bool(predictor.full_frame)
    )


def _settings(args: argparse.Namespace, model_digest: str, backend: str, device: str, full_frame: bool) -> dict:
    """:func:`output_settings` of a model known by its digest and resolved runtime, ``device`` and ``full_frame``."""
    settings = {
        "model_digest": model_digest,
        "backend": backend,
        "device": device,
        "full_frame": full_frame,
        "depth": not args.no_depth,
        "ply": "mesh" if args.mesh else "points" if args.ply else None,
    }
    if getattr(args, "reference", None):  # recorded only when given: results made without one keep their key
        settings["reference_digest"] = reference_digest(args.reference)
    return settings


def reference_digest(path: str | Path) -> str:
    """The digest of a ``--reference`` capture's bytes (a press folder's tri-colour and dark images, or the image
    file): a result made against another refreshed reference is not kept."""
    from pathlib import Path

    from ..core.errors import CaptureError
    from ..core.press_meta import read_meta
    from ..learn.onnx_export import bytes_digest

    path = Path(path)
    if not path.exists():
        raise CaptureError(f"--reference {path}: no such press folder or image file")
    if not path.is_dir():
        return bytes_digest(path.read_bytes())
    images = read_meta(path)["images"]
    return bytes_digest(b"".join((path / images[key]).read_bytes() for key in ("tricolor", "dark")))


def still_provenance(settings: dict, inputs: dict) -> dict:
    """What made a still's result (report ``provenance``): ``settings`` (:func:`output_settings`), ``inputs``
    (:func:`input_identity`), the software version, the code's fingerprint, the versions of the libraries that ran
    the model (core.libraries.INFER_LIBRARIES of the settings' backend), and ``key``, the SHA-256 (hex) of them: a
    result whose key equals a new request's is kept (:func:`_kept`)."""
    from .. import __version__
    from ..core.code_version import code_fingerprint
    from ..core.libraries import INFER_LIBRARIES, library_versions
    from ..core.reconstruction import provenance_key

    names = INFER_LIBRARIES.get(settings["backend"], ("numpy",))
    if settings.get("full_frame") and "torch" not in names:  # the full-frame graph's normals, integrated by PyTorch
        names = (*names, "torch")
    libraries = library_versions(names)
    key = provenance_key(settings, inputs, libraries)
    code = code_fingerprint()
    return {
        "key": key,
        "software_version": __version__,
        "code": code,
        "libraries": libraries,
        "settings": settings,
        "inputs": inputs,
    }


def _check_writable(
    args: argparse.Namespace, saved: Sequence[tuple[Path, bool]], looked: dict[Path, tuple[dict, bool]]
) -> None:
    """OSError naming the folder (one line from the CLI) when a result this run must write cannot be written: --out,
    or without it a press's own result folder, on a read-only disk or without permission
    (:func:`nlipscalib.core.atomic.check_can_make`: nothing is made). Results that may be kept (a folder with
    entries not looked at yet; ``looked``: :func:`_look_before_loading`'s) are not probed: a finished run's results
    on read-only media are still re-checked.

    Why: the model loaded and the first input was read (a stream's first frame inferred) before the first result
    folder found the disk read-only."""
    from ..core.atomic import check_can_make

    def to_write(folder: Path) -> bool:
        return not looked[folder][1] if folder in looked else not _has_entries(folder)

    if args.out:  # every result inside it: one probe (of the folder, not of each of its frames)
        if any(to_write(folder) for folder, _ in saved):
            check_can_make(args.out)
        return
    for folder, _ in saved:
        if to_write(folder):
            check_can_make(folder)


def _has_entries(folder: Path) -> bool:
    """Whether ``folder`` or an interrupted write of it is there: only then is there something to keep or to say
    (elsewhere the input is identified after it is read, so a broken one is named as reading it names it)."""
    return folder.exists() or _interrupted_write(folder)


def _interrupted_write(folder: Path) -> bool:
    """Whether a temporary entry of ``folder`` (core.atomic's ``.tmp-NAME~host~pid~*``) lies beside it.

    Its name is split as core.atomic splits it, so ``.tmp-frame-2~...`` (the write of frame-2) is not frame's."""
    import glob

    from ..core.atomic import OWNER_SEP, TMP_PREFIX

    beside = folder.parent.glob(glob.escape(f"{TMP_PREFIX}{folder.name}{OWNER_SEP}") + "*")
    return any(p.name[len(TMP_PREFIX) :].rsplit(OWNER_SEP, 3)[0] == folder.name for p in beside)


def _hold_results(
    held: contextlib.ExitStack, args: argparse.Namespace, saved: Iterable[tuple[Path, bool]], settings: dict
) -> None:
    """Hold this run's outputs for its model and options (``settings``, :func:`output_settings`) in ``held`` until
    the run ends, together with every run of the same ones, as ``nlips solve`` holds its results
    (cli._stream.hold_output): each press's result folder (``PRESS/nlipsnet``, ``OUT/PRESS/nlipsnet``), and the
    --out folder of frames' results (``OUT/FRAME``) as one (a hold per frame read the whole folder per frame).

    Raises ConfigError, one line naming the folder, what differs and the other process, when a live run of another
    model or options (or a stream) holds one; what was held before it is released, nothing is written. Why: two
    runs of two models into one --out both exited 0, each publishing over the other press by press (one run said
    "saved: 6 result folders" and none held its results). Taken in one order (sorted), each in one short step,
    and never waited for: two runs arriving at once cannot each hold what the other needs (the first to reach the
    first output they share goes on, the other is refused there). Runs of the same model and options share the
    outputs and split the work (:func:`_inferred_elsewhere`)."""
    from pathlib import Path

    from ._stream import hold_output

    record = {"model": str(Path(args.model).resolve()), "provenance": still_provenance(settings, {})}
    for target in sorted({folder if is_press else folder.parent for folder, is_press in saved}):
        refusal = lambda other, target=target: _held_elsewhere(target, other, record)  # noqa: E731
        hold_output(held, target, record["provenance"]["key"], refusal, record)


def _held_elsewhere(folder: Path, other: Owner, record: dict) -> str:
    """The refusal of an output ``folder`` that ``other``, a live run of another model or options, holds."""
    from ._stream import STREAM_COMMAND

    theirs = other.note if isinstance(other.note, dict) else {}
    if STREAM_COMMAND in theirs:  # a stream's --out
        doing = f"another run ({theirs[STREAM_COMMAND]}, {other.who}) is saving into it"
    else:
        differs = "; ".join(_what_changed(theirs, record)) if "provenance" in theirs else "other settings"
        doing = (
            f"another run is inferring into it with {differs.replace('another model', 'its model', 1)} ({other.who})"
        )
    return f"{folder}: {doing}; left to it: run again once it has ended, or infer into another --out"


def _inferred_elsewhere(folder: Path, held: contextlib.ExitStack, provenance: dict, figures: str) -> bool:
    """Take the claim on the result ``folder`` (core.claims; entered into ``held``, released once its result is
    saved) and return False: this run infers it. While another live process holds it, wait for that one (saying
    so), then return True when it left a result to keep (:func:`_kept`: the same input, model and options) -- else
    (it failed, was killed, or made another model's result) take the claim and infer it here.

    Why: three ``nlips infer`` runs into one folder at once each inferred the presses the others were inferring
    and published over one another (whole folders, the last one's left: never a mix, but work done twice); now
    one infers a press, the others wait for it and keep its result, as ``nlips solve`` and ``nlips train`` do. A
    folder that cannot hold a claim file (read-only media) is not held: the save that follows says why."""
    from ..core.claims import UNKNOWN_OWNER, claim, holder, wait_for_release

    while True:
        with contextlib.ExitStack() as attempt:
            try:
                mine = attempt.enter_context(claim(folder))
            except OSError as exc:
                log.debug("%s: not claimed (%s)", folder, exc.strerror or exc)
                return False
            if mine:
                held.enter_context(attempt.pop_all())
                return False
        who = (holder(folder) or UNKNOWN_OWNER).who
        wait_for_release(folder, lambda who=who: log.info("%s: being inferred by %s; waiting for it", folder, who))
        if _kept(folder, provenance, figures):
            log.info("%s: inferred by %s meanwhile (the same input, model and options); kept", folder, who)
            return True


def _kept(folder: Path, provenance: dict, figures: str) -> bool:
    """Whether ``folder`` holds a whole result made with ``provenance``'s key (then it is kept, not inferred again).

    Not when a write of it was interrupted beside it (inferring it again publishes a result and removes the
    leftover, core.atomic), when it is damaged (every array read and checked, as ``nlips solve`` checks a result it
    keeps: a warning), when it lacks the points.ply its settings name (removed since) or the ``figures`` asked
    now, or holds one empty or cut short (made with --figures none, by an older nlipscalib, a power cut: inferring
    again costs a fraction of a second once the model is loaded), or when its key differs (:func:`_save` says what
    changed as it replaces it)."""
    from ..core.reconstruction import read_report, reconstruction_problem
    from ..report import figures_problem

    if _interrupted_write(folder):
        log.info("%s: an interrupted write of it lies beside it; inferring it again", folder)
        return False
    if not folder.is_dir() or not any(folder.iterdir()):
        return False
    if (problem := reconstruction_problem(folder, verify=True)) is not None:
        log.warning("%s; inferring it again", problem)
        return False
    old = read_report(folder).get("provenance")
    if not isinstance(old, dict) or old.get("key") != provenance["key"]:
        return False
    if provenance["settings"]["ply"] and not (folder / "points.ply").is_file():
        log.info("%s: its points.ply is missing; inferring it again", folder)
        return False
    if (problem := figures_problem(folder, figures)) is not None:
        log.info("%s: its figures (--figures %s): %s; inferring it again", folder, figures, problem)
        return False
    log.debug("%s: identical result exists, kept (--overwrite infers it again)", folder)
    return True


def _save(
    args: argparse.Namespace,
    predictor: Predictor,
    result: Frame,
    name: str,
    folder: Path,
    provenance: dict,
    press_folder: Path | None,
    source: Path,
    identity: dict | None = None,
) -> None:
    """Write ``result`` into ``folder`` (with its points.ply and figures when asked), recording ``provenance``;
    ``source``: the image file of a frame (a press's: its folder), whose identity by content is compared with the
    presses the model learnt from (report ``trained_on``, :func:`_content_identity`); ``identity``: that identity
    when the frame's loader took it already.

    The figures are ``nlips solve``'s (report.reconstruction, ``args.figures``): the normal map, the depth map as
    the indentation from the model's undeformed dome and, for a press with ground truth (a twin's gt.npz), the
    error map."""
    from ..core.reconstruction import save_reconstruction
    from ..learn.infer import to_reconstruction
    from ..learn.ply import write_ply
    from ..report import write_reconstruction_figures

    identity = identity or _content_identity(predictor.model.info, press_folder, source)
    reconstruction = to_reconstruction(result, predictor, name, provenance, identity)
    _say_judged_by_meta(args.model, predictor.model.info, identity, reconstruction.report, press_folder)

    def extra(tmp: Path) -> None:
        # written into the temporary folder, so the result is published with its points.ply and figures or not at
        # all: a reader never sees a folder that lacks them, and a failed write (a full disk) publishes nothing
        if args.ply or args.mesh:
            write_ply(tmp / "points.ply", result.points, result.normals, mesh=args.mesh)
        reference = predictor.model.reference["depth"]  # the press's own, checked equal on loading it
        truth = _ground_truth_reader(press_folder) if press_folder is not None else None
        write_reconstruction_figures(tmp, reconstruction, truth, args.figures, reference, name)

    _say_what_is_replaced(folder, reconstruction.report)
    save_reconstruction(reconstruction, folder, overwrite=True, extra_files=extra)


def _ground_truth_reader(press_folder: Path) -> Callable[[], GroundTruth | None]:
    """What reads the press's ground truth for its error map, on the figures' thread (a damaged gt.npz costs the
    error map only, with one warning: the inference reads none, as in ``nlips solve``)."""

    def read() -> GroundTruth | None:
        from ..core.capture import read_ground_truth

        return read_ground_truth(press_folder)

    return read


def _say_what_is_replaced(folder: Path, report: dict) -> None:
    """Log what made the result in ``folder`` differently from the ``report`` about to replace it (another model,
    options, input or nlipscalib), so that a user comparing models or options does not lose it unseen."""
    from ..core.errors import CaptureError
    from ..core.reconstruction import read_report

    try:
        old = read_report(folder)
    except CaptureError:  # none there, or not readable: nothing of value is replaced
        return
    if changes := _what_changed(old, report):
        log.info("%s: replacing the result of %s", folder, "; ".join(changes))


def _what_changed(old: dict, new: dict) -> list[str]:
    """What differs between the report ``old`` and ``new`` in what made them (empty: nothing, or only the model
    file's path while its content is the same)."""
    record, made = old.get("provenance"), new["provenance"]
    record = record if isinstance(record, dict) else {}
    settings = record.get("settings") if isinstance(record.get("settings"), dict) else None
    if settings is None:  # an older nlipscalib's result: the model's path is all it records of what made it
        # a relative path (754bd8b's records) was relative to a working folder no record names: the same model given
        # the same way was said to be "another model (model/m.pt)"
        import os.path

        was = old.get("model")
        known = isinstance(was, str) and os.path.isabs(was)
        other = [f"another model ({was})"] if known and was != new["model"] else []
        return other + ["an older nlipscalib (it records no options)"]
    if record.get("key") == made["key"]:
        return []
    changes = []
    if settings.get("model_digest") != made["settings"]["model_digest"]:
        changes.append(f"another model ({old.get('model')})")
    options = [
        f"{k} {settings.get(k)!r}, now {v!r}"
        for k, v in made["settings"].items()
        if k != "model_digest" and settings.get(k) != v
    ]
    if options:
        changes.append(f"other options ({', '.join(options)})")
    inputs = record.get("inputs") if isinstance(record.get("inputs"), dict) else {}
    if inputs != made["inputs"]:
        changes.append("another input (the press's files or the frame's file changed since)")
    if record.get("software_version") != made["software_version"]:
        changes.append(f"nlipscalib {record.get('software_version')} (now {made['software_version']})")
    if record.get("code") != made["code"]:
        changes.append("another nlipscalib code" if "code" in record else "an nlipscalib that recorded no code")
    libraries = record.get("libraries")
    if not isinstance(libraries, dict):
        if "code" in record:  # (one that recorded no code is named so above)
            changes.append("an nlipscalib that recorded no library versions")
    else:
        text = lambda v: "not installed" if v is None else v  # noqa: E731
        # a library the earlier result's backend did not run (torch after onnx) is not in its record, and was not
        # missing: the backend named above says what changed ("torch not installed (now 2.13.0)" was said)
        changes += [
            f"{k} {text(libraries[k])} (now {text(v)})"
            for k, v in made["libraries"].items()
            if k in libraries and libraries[k] != v
        ]
    return changes or ["a record that differs"]


def _content_identity(info: dict, press_folder: Path | None, source: Path) -> dict | None:
    """The input's identity by content (:mod:`nlipscalib.core.press_identity`) when the model records those of the
    presses it learnt from (``info.press_identities``), for report ``trained_on``: a press folder's record, or an image
    frame's pixels as stored values (:func:`read_still`, no tone curve undone: as a press's tri-colour PNG is
    decoded); None when the model records none (nothing to compare with: no file hashed) or the input cannot be read
    again (said by its load)."""
    from ..core.errors import CaptureError
    from ..core.press_identity import frame_identity, press_identity
    from ..learn.seen import IDENTITIES_KEY

    if not info.get(IDENTITIES_KEY):
        return None
    try:
        return press_identity(press_folder) if press_folder is not None else frame_identity(read_still(source))
    except (CaptureError, OSError, ValueError):
        return None


def _say_judged_by_meta(model: str, info: dict, identity: dict | None, report: dict, press_folder: Path | None) -> None:
    """Say once (a warning) that a press counted unseen was judged by the older rule, meta.json's bytes too
    (:func:`nlipscalib.learn.seen.judged_by_meta`: a model trained before 2026-12-08, or on a dataset built before
    it): a copy of a press the model learnt from whose meta.json differs (another render's times) counts so too."""
    from ..core import said_once
    from ..learn.seen import TRAINED_ON_KEY, UNSEEN, judged_by_meta

    if press_folder is None or report.get(TRAINED_ON_KEY) != UNSEEN or not judged_by_meta(info, identity):
        return
    if said_once.first_time(f"judged by meta.json: {model}"):
        log.warning(
            "%s: records the presses it learnt from by their meta.json's bytes too (trained before 2026-12-08, or on "
            "a dataset built before it), so a copy of one of them whose meta.json differs (rendered or copied "
            "elsewhere: other times) counts as unseen (report.json trained_on); run `nlips calibrate` on its presses "
            "again and train into another --out to record them by their images",
            model,
        )


def input_identity(press_folder: Path | None, source: Path) -> dict:
    """What an NLiPsNet result records of its input (report ``provenance.inputs``, docs/formats.md), so that
    ``nlips eval PRESS --result`` can tell a result of PRESS from one of another capture.

    A press: ``{"press": ...}``, the identity NLiPs records (``pipeline.capture_identity``: meta.json and every
    image). An image frame: ``{"frame": ...}``, :func:`frame_identity` of the file (equal to a press's when the
    file is that press's tri-colour image)."""
    if press_folder is not None:
        from ..pipeline import capture_identity

        return {"press": capture_identity(press_folder)}
    return {"frame": frame_identity(source)}


def frame_identity(path: str | Path) -> str:
    """SHA-256 (hex) of an image file's bytes: the identity of a tri-colour frame stored as a file."""
    import hashlib
    from pathlib import Path

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
