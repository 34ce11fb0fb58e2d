"""learn.watch.MismatchWatch: a stream's frames unlike the calibration's reference, warned about once, counted."""

import logging

import numpy as np

from nlipscalib.core.tolerances import FRAME_MISMATCH_FRACTION
from nlipscalib.learn.infer import Frame
from nlipscalib.learn.watch import MismatchWatch


class _Predictor:
    """Stands in for learn.infer.Predictor: each stored frame's first value is the frame's mismatch."""

    def predict_stored(self, frame: np.ndarray, where: str) -> Frame:
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
    assert len(lines) == 2, lines  # one warning for the stream, one count at its end
    assert "camera 0 frame 1" in lines[0] and "0.5 times as bright" in lines[0]
    assert lines[1].startswith("3 of 5 frames differed")


def test_a_stream_like_the_reference_says_nothing(caplog):
    watch = MismatchWatch(_Predictor(), "camera 0")
    with caplog.at_level(logging.WARNING):
        for _ in range(3):
            watch(np.zeros((2, 2, 3)))
        watch.report()
    assert watch.frames == 3 and not caplog.records
