"""A stream left running (s29-soak): memory, threads and open files stay bounded over many frames, and a stream that
ends on an error (a camera that stopped sending, a full disk) prints what it streamed before its one error line.

Long runs are benchmarks/bench_soak.py's; these are CI-sized: a few thousand frames of a tiny image."""

from __future__ import annotations

import errno
import os
import sys
import threading
import tracemalloc

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.device import camera, live  # noqa: E402
from nlipscalib.device.camera import FrameSource  # noqa: E402
from nlipscalib.device.live import LiveStats, ReadAhead, SaveSink, stream  # noqa: E402

from .fakes import flat_predictor  # noqa: E402

SHAPE = (12, 16)


class LoopingCamera(FrameSource):
    """A camera stand-in: a few frames in turn, for ever, or until ``stops_after`` reads (then the error a live camera
    that stopped sending gives: ``OpenCVSource._grab``'s)."""

    def __init__(self, stops_after: int | None = None) -> None:
        self.frames = [np.full(SHAPE + (3,), 1000 * (k + 1), np.uint16) for k in range(3)]
        self.reads, self.stops_after = 0, stops_after

    @property
    def shape(self) -> tuple[int, int]:
        return SHAPE

    def read(self) -> np.ndarray:
        if self.reads == self.stops_after:
            raise CaptureError("camera 0: no frame (the camera stopped)")
        self.reads += 1
        return self.frames[self.reads % 3]


def _open_fds() -> set[str]:
    """Open file descriptors of this process (Linux; empty where /proc is missing)."""
    return set(os.listdir("/proc/self/fd")) if os.path.isdir("/proc/self/fd") else set()


def test_a_long_stream_keeps_its_memory_threads_and_open_files_bounded(tmp_path):
    """Frames 500 to 4000 of a stream saving every 500th frame add no memory that grows with the frames (the stats,
    the sinks, the read-ahead queue), and leave no thread running nor file open that was not there before (others'
    may end meanwhile: a thread an earlier test left)."""
    threads, fds = set(threading.enumerate()), _open_fds()
    sink = SaveSink(tmp_path / "out", every=500)
    predict = flat_predictor(SHAPE)
    tracemalloc.start()
    try:
        with ReadAhead(LoopingCamera(), workers=2) as source:
            stats = LiveStats()
            stream(source, predict, [sink], max_frames=500, report=None, stats=stats)
            before = tracemalloc.take_snapshot()
            stream(source, predict, [sink], max_frames=4000, report=None, stats=stats)
            after = tracemalloc.take_snapshot()
    finally:
        tracemalloc.stop()
    grown = sum(d.size_diff for d in after.compare_to(before, "filename"))
    assert stats.frames == 4000
    assert grown < 64_000, f"{grown} bytes more after 3500 frames"  # 3500 frames of 1 byte each would be 3.5 kB
    assert len(list((tmp_path / "out").glob("*.npz"))) == 8
    assert set(threading.enumerate()) <= threads
    assert _open_fds() <= fds


def test_stream_counts_into_the_stats_it_is_given_until_an_error_ends_it():
    stats = LiveStats()
    with pytest.raises(CaptureError, match="the camera stopped"):
        stream(LoopingCamera(stops_after=3), flat_predictor(SHAPE), [], report=None, stats=stats)
    assert stats.frames == 3 and stats.seconds > 0


def _live(tmp_path, source: FrameSource, monkeypatch, *args: str) -> int:
    monkeypatch.setattr(camera, "open_source", lambda spec, settings=None, tone_curve=None: source)
    argv = ["live", "--camera", "0", "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    return main(argv + ["--out", str(tmp_path / "out"), *args])


def test_a_camera_that_stops_sending_ends_live_with_its_summary_then_one_line(tmp_path, capsys, monkeypatch):
    """`nlips live` from a camera that stopped (unplugged, its driver's read timed out) said only the error: the
    count and rate of an hours-long stream were lost, where a damaged frame of a recording kept them."""
    assert _live(tmp_path, LoopingCamera(stops_after=5), monkeypatch, "--every", "2") == 2
    out, err = capsys.readouterr()  # stdout: the maps' folder alone; the summary, then the error, on stderr
    assert out == f"{tmp_path / 'out'}\n"
    assert "5 frames in" in err and f"saved: 3 of 5 frames' normals and depth in {tmp_path / 'out'} " in err
    assert err.strip().splitlines()[-1] == "nlips live: error: camera 0: no frame (the camera stopped)"
    assert err.count("nlips live: error") == 1
    assert len(list((tmp_path / "out").glob("*.npz"))) == 3


def test_a_disk_that_fills_ends_live_with_its_summary_then_one_line_the_frames_before_kept_whole(
    tmp_path, capsys, monkeypatch
):
    real_save, saved = live.save_npz, []

    def fills_at_the_fourth(path, arrays, **kw):
        if len(saved) == 3:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        saved.append(path)
        return real_save(path, arrays, **kw)

    monkeypatch.setattr(live, "save_npz", fills_at_the_fourth)
    assert _live(tmp_path, LoopingCamera(), monkeypatch, "--max-frames", "100") == 2
    out, err = capsys.readouterr()
    assert "3 frames in" in err and "saved: 3 of 3 frames'" in err and out == f"{tmp_path / 'out'}\n"
    lines = [line for line in err.strip().splitlines() if line.startswith("nlips ")]
    assert (
        len(lines) == 1
        and err.strip().splitlines()[-1] == lines[0]
        and "No space left on device (the disk is full" in lines[0]
    ), lines
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == [
        f"frame_{k:06d}{ext}" for k in range(3) for ext in (".npz", "_normals.png")
    ]  # the fourth frame's picture removed with its arrays: no half frame, no temporary


@pytest.mark.skipif(sys.platform == "win32", reason="one os.write per line is the POSIX path")
def test_a_log_file_on_a_full_disk_costs_one_line_not_a_traceback_per_line(tmp_path, capsys, monkeypatch):
    """Once the --log-file's disk was full, logging printed a 30-line "--- Logging error ---" traceback for every line
    (a stream's counted warning each minute, its summary), burying the command's own lines; now one line says the
    log's lines are lost, and the file says how many when it can be written again."""
    import logging

    from nlipscalib import progress

    log_file = tmp_path / "nlips.log"
    handler = progress.AppendFileHandler(log_file)
    handler.setFormatter(logging.Formatter("%(levelname)s %(message)s"))
    real_write, full = os.write, [True]

    def write(fd, data):
        if full[0] and fd == handler._fd:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write)
    logger = logging.getLogger("tests.soak")
    logger.addHandler(handler)
    logger.propagate = False
    try:
        for k in range(50):
            logger.warning("frame %d unlike the reference", k)
        full[0] = False  # space freed
        logger.warning("frame 50 unlike the reference")
    finally:
        logger.removeHandler(handler)
        handler.close()
    err = capsys.readouterr().err
    assert err == f"nlips: --log-file {log_file}: No space left on device; its lines are lost until it can be written\n"
    assert log_file.read_text(encoding="utf-8").splitlines() == [
        "WARNING 50 log line(s) lost here (not written)",
        "WARNING frame 50 unlike the reference",
    ]


def test_an_image_sequence_keeps_no_path_per_frame(tmp_path):
    """SequenceSource listed a Path per frame, 0.66 kB each: a 150,000-frame recording's stream held ~50 MB of names;
    now each name is made when its frame is read (the files past the first need only exist to be counted)."""
    from nlipscalib.device.camera import SequenceSource

    cv2.imwrite(str(tmp_path / "img_00000.png"), np.full(SHAPE + (3,), 1000, np.uint16))
    for k in range(1, 5000):
        (tmp_path / f"img_{k:05d}.png").touch()
    tracemalloc.start()
    try:
        source = SequenceSource(str(tmp_path / "img_%05d.png"))
        held, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert len(source.files) == 5000 and source.files[-1] == tmp_path / "img_04999.png"
    assert held < 200_000, f"{held} bytes for 5000 frames' names"  # a Path each: 3.3 MB
    assert source.read().shape == SHAPE + (3,)
