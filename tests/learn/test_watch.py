"""learn.watch.MismatchWatch: a stream's frames unlike the calibration's reference, warned about once, counted once a
minute and at the end."""

import logging

import numpy as np

from nlipscalib.core.tolerances import FRAME_MISMATCH_FRACTION
from nlipscalib.learn.infer import Frame
from nlipscalib.learn.watch import MismatchWatch


class _Predictor:
    """Stands in for learn.infer.Predictor: each stored frame's first value is the frame's mismatch."""

    full_frame = False
    model = type("Model", (), {"info": {}})()
    ref_normals = np.zeros((2, 2, 3))

    def predict_stored(self, frame: np.ndarray, where: str, in_light: bool = False) -> Frame:
        zeros = np.zeros((2, 2))
        mismatch = float(frame.flat[0])
        return Frame(
            zeros[..., None].repeat(3, -1),
            zeros,
            zeros[..., None].repeat(3, -1),
            zeros > 0,
            {},
            brightness=0.5,
            mismatch=mismatch,
        )


def test_a_stream_unlike_the_reference_is_warned_about_once_and_counted(caplog):
    watch = MismatchWatch(_Predictor(), "camera 0")
    off, like = 2 * FRAME_MISMATCH_FRACTION, 0.0
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for value in (like, off, off, like, off):
            watch(np.full((2, 2, 3), value))
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 3, lines  # one warning in full, its repeats counted, the count at the stream's end
    assert "camera 0 frame 1" in lines[0] and "0.5 times as bright" in lines[0]
    assert "repeated 2 more times" in lines[1] and "(the latest: camera 0 frame 4;" in lines[1]
    assert lines[2].startswith("3 of 5 frames differed")


def test_a_fault_that_comes_back_hours_later_is_said_again_once_a_minute_at_most(caplog):
    """A stream warned once for the whole day: a fault at 09:00 hid another at 15:00 until the stream ended."""
    watch = MismatchWatch(_Predictor(), "camera 0")
    now = [0.0]
    watch.warning.clock = lambda: now[0]
    off, like = 2 * FRAME_MISMATCH_FRACTION, 0.0
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        watch(np.full((2, 2, 3), off))  # 09:00: said in full
        for hour in range(1, 7):
            now[0] = 3600.0 * hour
            watch(np.full((2, 2, 3), like))
        for frame in range(30 * 120):  # 15:00: two minutes of faulty frames at 30 frames/s
            now[0] = 6 * 3600.0 + frame / 30
            watch(np.full((2, 2, 3), off))
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert len(lines) == 5, lines  # in full at 09:00 and again at 15:00, one count a minute (2), the end's count
    assert "camera 0 frame 0:" in lines[0] and "camera 0 frame 7:" in lines[1]
    assert "repeated 1801 more times in the last 60 s" in lines[2] and "repeated 1798 more times" in lines[3]
    assert lines[4].startswith("3601 of 3607 frames differed")


def test_a_stream_like_the_reference_says_nothing(caplog):
    watch = MismatchWatch(_Predictor(), "camera 0")
    with caplog.at_level(logging.WARNING):
        for _ in range(3):
            watch(np.zeros((2, 2, 3)))
        watch.report()
    assert watch.frames == 3 and not caplog.records


class _DriftingPredictor(_Predictor):
    """Stands in for learn.infer.Predictor: each stored frame's first value is its red over the reference's."""

    def predict_stored(self, frame: np.ndarray, where: str, in_light: bool = False) -> Frame:
        zeros = np.zeros((2, 2))
        return Frame(
            zeros[..., None].repeat(3, -1),
            zeros,
            zeros[..., None].repeat(3, -1),
            zeros > 0,
            {},
            channels=(float(frame.flat[0]), 1.0, 1.0),
        )


def test_a_streams_summary_counts_the_frames_whose_colours_drifted(caplog):
    """An aged LED group's frames (drift_warning, under the 4 % mismatch) were warned about, never counted."""
    watch = MismatchWatch(_DriftingPredictor(), "camera 0")
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for red in (1.0, 0.9, 0.9, 1.0, 0.95):
            watch(np.full((2, 2, 3), red))
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert "camera 0 frame 1: the undeformed gel is red 0.90" in lines[0]
    assert lines[-1].startswith("3 of 5 frames had colours that drifted from the calibration's reference")
    assert "--reference FRAME" in lines[-1] and not any("differed" in line for line in lines)
