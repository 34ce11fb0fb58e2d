"""Live reconstruction: tri-colour frames from a frame source through a predictor into a window or files.

The LEDs stay lit in the tri-colour pattern, so frames stream without flushing. The predictor is
pluggable: any callable taking a stored frame ((H, W, 3) uint16) and returning a :class:`LiveResult`
(``nlips live`` plugs in a trained NLiPsNet). Outputs are sinks, callables given each frame and its result:
:class:`SaveSink` keeps the arrays in a folder. This module draws nothing: the pictures (an OpenCV window, PNG
normal maps) are report/live.py's, and the CLI passes them in.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Protocol

import numpy as np

from ..core.atomic import write_by_name
from ..core.errors import NUMBER, PATH, ConfigError, ShapeError, check_kind, check_whole
from ..core.imageio import save_npz
from .camera import EndOfFrames


class FrameReader(Protocol):
    """What :func:`stream` and :class:`ReadAhead` read frames from: a :class:`.camera.FrameSource`, a ReadAhead, or a
    wrapper of either."""

    @property
    def shape(self) -> tuple[int, int]: ...

    def read(self) -> np.ndarray: ...


@dataclasses.dataclass
class LiveResult:
    """What the predictor gives for one frame."""

    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, toward the camera; zero off the gel."""
    depth: np.ndarray
    """(H, W) float32, mm, camera-frame z; NaN off the gel."""


@dataclasses.dataclass
class LiveStats:
    """Frame rate and where the time went."""

    frames: int = 0
    seconds: float = 0.0
    """Wall time of the whole loop, s."""
    read_s: float = 0.0
    """Time spent waiting for frames, s."""
    predict_s: float = 0.0
    """Time spent in the predictor, s."""
    output_s: float = 0.0
    """Time spent showing, saving or printing the running rate, s (read, predict and output cover each frame's
    whole loop step; the wall time adds only the start and the read that found the end)."""
    dropped: int = 0
    """Frames read but not streamed: read while the LED board had reset, its LEDs dark
    (:class:`~nlipscalib.device.live_leds.ResetWatch` counts them here); their reading time is in ``read_s``."""

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """The stream's line: frames, wall time, frame rate, and the mean time per frame of each step.

        The steps are named for what they time: "read" (a camera, a video's or a file's decoding), "predictor" (the
        whole predictor's call). They were "camera" and "network": a video has no camera, and ``nlips infer``'s next
        line has a "network" stage that is only a part of that call (13 ms of 23)."""
        n = max(self.frames, 1)
        dropped = f"; {self.dropped} more dropped, read while the LED board had reset" if self.dropped else ""
        return (
            f"{self.frames} frames in {self.seconds:.2f} s: {self.fps:.1f} fps "
            f"(per frame: read {1e3 * self.read_s / n:.1f} ms, predictor {1e3 * self.predict_s / n:.1f} ms, "
            f"output {1e3 * self.output_s / n:.1f} ms){dropped}"
        )


class ReadAhead:
    """A recorded frame source (video, image sequence, folder) that decodes the next frames while the caller
    works on this one; frames and errors come in the source's order.

    Why: decoding a 640x480 frame takes about as long as a small NLiPsNet's frame; OpenCV releases the GIL
    while it decodes, so the two overlap. A video decodes in order, one frame ahead on one worker thread. Image
    files (a source with ``frame_at(index)``: a folder, an image sequence) are decoded by ``workers`` threads
    at once, ``2 * workers`` frames ahead: a GPU infers a 640x480 frame in 2-4 ms, where one core decodes a 16-bit
    PNG in about 10 ms (benchmarks/RESULTS.md). Not for a live camera (it would hand out a frame one period old) nor
    for the emulator (its press changes before each read).

    Parameters
    ----------
    source : a frame source (``read()``, ``shape``), optionally with ``frame_at(index)`` and ``position``
    workers : decoding threads for image files (default :func:`decoding_workers`); a video uses one
    """

    def __init__(self, source: FrameReader, workers: int | None = None):
        from collections import deque
        from concurrent.futures import ThreadPoolExecutor

        self.source = source
        self.shape = source.shape
        # the curve its frames were undone with as they were converted: a stream asks it of the source it is given
        # (``MismatchWatch.in_light``), which is this one when a recording is read ahead; None: frames as stored
        self.tone_curve = getattr(source, "tone_curve", None)
        self._indexed = callable(getattr(source, "frame_at", None))
        n = max(1, int(workers or decoding_workers())) if self._indexed else 1
        self._ahead = 2 * n if self._indexed else 1
        self._index = getattr(source, "position", 0)
        self._pool = ThreadPoolExecutor(n, thread_name_prefix="nlips-read-ahead")
        self._queue = deque()

    def _submit(self) -> None:
        if self._indexed:  # any worker may decode any frame: each one reads its own file
            self._queue.append(self._pool.submit(self.source.frame_at, self._index))
            self._index += 1
        else:
            self._queue.append(self._pool.submit(self.source.read))

    def read(self) -> np.ndarray:
        while len(self._queue) < 1 + self._ahead:
            self._submit()
        return self._queue.popleft().result()  # re-raises the source's error (its end) for the frame that had it

    def close(self) -> None:
        for pending in self._queue:
            pending.cancel()
        self._pool.shutdown(wait=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def decoding_workers() -> int:
    """Threads :class:`ReadAhead` decodes image files with: the usable cores but one (the predictor's), at
    most 4 (four kept a 640x480 GPU stream fed at ~240-270 frames/s on an H200 host; two gave ~140), at least 1."""
    from ..core.cpus import usable_cores

    return max(1, min(4, usable_cores() - 1))


class StopLive(Exception):
    """Raised by a sink to end the stream (the window was closed, q pressed)."""


def stream(
    source: FrameReader,
    predict: Callable[[np.ndarray], LiveResult],
    sinks: Iterable[Callable[[int, np.ndarray, LiveResult], None]],
    *,
    max_frames: int | None = None,
    before_frame: Callable[[int], None] | None = None,
    report: Callable[[str], None] | None = print,
    report_every_s: float = 1.0,
    stop: Callable[[], bool] | None = None,
    stats: LiveStats | None = None,
) -> LiveStats:
    """Run frames through the predictor into the sinks until ``max_frames``, the end of the input, a sink stops,
    Ctrl-C, or ``stop()`` says so.

    Parameters
    ----------
    source : FrameSource (``read``)
    predict : stored frame (H, W, 3) uint16 -> LiveResult
    sinks : callables (frame index, stored frame, result)
    max_frames : stop after this many frames (None: until the source ends or Ctrl-C)
    before_frame : called with the frame index before each read (the emulator changes the press there)
    report : where the running frame rate goes (once per ``report_every_s``), None for quiet
    stop : asked before each frame; True ends the stream there, the frame before it done and saved whole (the CLI
        passes a SIGTERM flag: ``cli._stream.SigtermEndsStream``)
    stats : counted into in place (default: a new LiveStats), its ``seconds`` set however the stream ends: a caller
        that passes its own still has the frames done when the stream raises (a camera that stopped, a full disk),
        for the summary it prints before the error line

    Returns
    -------
    LiveStats -- ``stats``
    """
    for name, value, method, what in (
        ("source", source, "read", "a frame source (open_source(CAMERA))"),
        ("predict", predict, "__call__", "a predictor of stored frames (a MismatchWatch, predictor.predict_stored)"),
    ):  # "'str' object has no attribute 'read'" came from inside the loop
        if not callable(getattr(value, method, None)):
            raise ShapeError(f"{name} must be {what}, got {type(value).__name__}")
    if isinstance(sinks, (str, bytes)) or not isinstance(sinks, Iterable):
        raise ShapeError(f"sinks must be a list of sinks (SaveSink(folder), callables), got {type(sinks).__name__}")
    sinks = list(sinks)
    if max_frames is not None:  # -1 or 2.5 streamed until Ctrl-C, "10" failed in Python's "<" (s38-apikinds)
        check_whole(max_frames, "max_frames", minimum=0)
    check_kind(report_every_s, NUMBER, "report_every_s", "a number of seconds")
    stats = LiveStats() if stats is None else stats
    t_start = last_report = time.perf_counter()
    frames_at_report = 0
    try:
        while (max_frames is None or stats.frames < max_frames) and not (stop is not None and stop()):
            t0 = time.perf_counter()  # "read" counts the emulator's change of press before it: a step of each frame
            if before_frame is not None:
                before_frame(stats.frames)
            try:
                frame = source.read()
            except EndOfFrames:
                if max_frames is None:
                    break  # end of a recorded input (a damaged frame is an error: it goes out)
                raise
            t1 = time.perf_counter()
            result = predict(frame)
            t2 = time.perf_counter()
            for sink in sinks:
                sink(stats.frames, frame, result)
            stats.frames += 1
            t3 = time.perf_counter()
            if report is not None and t3 - last_report >= report_every_s:
                report(f"{(stats.frames - frames_at_report) / (t3 - last_report):.1f} fps")
                last_report, frames_at_report = t3, stats.frames
            stats.read_s += t1 - t0
            stats.predict_s += t2 - t1
            stats.output_s += time.perf_counter() - t2  # the running rate's line is output too
    except (StopLive, KeyboardInterrupt):
        pass
    finally:  # an error too: the frames before it were streamed, in this much time
        stats.seconds = time.perf_counter() - t_start
    return stats


SAVED_FRAMES = "frame_" + "[0-9]" * 6 + ".npz"
"""Glob of the arrays :class:`SaveSink` writes, a file a frame (``frame_NNNNNN.npz``: normals, depth): what ``nlips live
--out`` and ``nlips infer STREAM --out`` leave, without the input each was made from."""


class SaveSink:
    """Every ``every``-th frame's arrays (npz: normals, depth), after its pictures when ``pictures`` is given.

    Parameters
    ----------
    folder : where ``frame_NNNNNN.npz`` go (made when missing)
    every : keep frames 0, every, 2 * every, ...
    pictures : ``pictures(stem, result)`` writes the frame's pictures beside its arrays (``stem``: the folder and
        ``frame_NNNNNN``), e.g. ``report.live.NormalMapPng``; the CLI passes it in: device/ draws nothing
    """

    def __init__(
        self,
        folder: str | Path,
        every: int = 1,
        pictures: Callable[[Path, LiveResult], None] | None = None,
    ):
        check_kind(folder, PATH, "folder", "the folder the frames are saved in (str or Path)")
        if isinstance(every, bool) or not isinstance(every, int) or every < 1:
            raise ConfigError(f"every must be an integer >= 1 (1: every frame), got {every!r}")
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.every = every
        self.pictures = pictures

    def __call__(self, index: int, frame: np.ndarray, result: LiveResult) -> None:
        if index % self.every:
            return
        stem = self.folder / f"frame_{index:06d}"
        try:
            if self.pictures is not None:
                self.pictures(stem, result)
            arrays = {"normals": result.normals.astype(np.float32), "depth": result.depth.astype(np.float32)}
            # a temporary of this process's own (streams into one folder never share one), removed on SIGTERM;
            # "auto": dense float maps stored, not deflated (112 of a 640x480 frame's 134 ms of saving, for 14 % less)
            write_by_name(stem.with_suffix(".npz"), lambda tmp: save_npz(tmp, arrays, compress="auto"))
        except BaseException:
            # a frame is kept whole or not at all: Ctrl-C (or a full disk) between its picture and its arrays left
            # frame_N_normals.png without frame_N.npz, where the summary counts the frames saved before frame N
            for written in (*self.folder.glob(f"{stem.name}.*"), *self.folder.glob(f"{stem.name}_*")):
                written.unlink(missing_ok=True)
            raise
