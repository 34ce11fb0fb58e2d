"""learn.watch.MismatchWatch: a stream's frames unlike the calibration's reference, warned about once, counted once a
minute and at the end."""

import dataclasses
import logging

import numpy as np
import pytest

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


def test_a_short_streams_count_at_its_end_says_the_last_second_not_0_s(caplog):
    """`nlips live --emulate ... --max-frames 5` ended "repeated 4 more times in the last 0 s" (s34-walk)."""
    watch = MismatchWatch(_Predictor(), "camera 0")
    now = [0.0]
    watch.warning.clock = lambda: now[0]
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for frame in range(5):
            now[0] = frame * 0.02
            watch(np.full((2, 2, 3), 2 * FRAME_MISMATCH_FRACTION))
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert "repeated 4 more times in the last second (the latest: camera 0 frame 4;" in lines[1], lines


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


class _PressPredictor(_Predictor):
    """Stands in for learn.infer.Predictor: each stored frame's first pixel is (centre column, centre row, radius)
    of a spherical dent whose normals tilt steeply (warned: ~4 deg/px, the rule 0.4), changed where it is."""

    shape = (60, 80)
    ref_normals = np.zeros((60, 80, 3), np.float32)
    ref_normals[..., 2] = 1.0

    def predict_stored(self, frame: np.ndarray, where: str, in_light: bool = False) -> Frame:
        cx, cy, radius = (float(x) for x in frame[0, 0])
        v, u = np.mgrid[: self.shape[0], : self.shape[1]].astype(np.float32)
        x, y = (u - cx) / (1.2 * radius), (v - cy) / (1.2 * radius)
        inside = x * x + y * y < 1.0 / 1.44
        normals = self.ref_normals.copy()
        normals[inside] = np.stack([x, y, np.sqrt(np.clip(1.0 - x * x - y * y, 0, 1))], -1)[inside]
        zeros = np.zeros(self.shape)
        return Frame(normals, zeros, normals, inside, {})


def _press(cx: float, cy: float, radius: float) -> np.ndarray:
    frame = np.zeros((60, 80, 3))
    frame[0, 0] = cx, cy, radius
    return frame


def _counting(monkeypatch) -> list:
    """Counts the contacts measured (``learn.resolution.measure_contact`` as ``judge_steepness`` calls it)."""
    from nlipscalib.learn import resolution

    calls = []
    measure = resolution.measure_contact

    def counted(*args, **kwargs):
        calls.append(1)
        return measure(*args, **kwargs)

    monkeypatch.setattr(resolution, "measure_contact", counted)
    return calls


def test_a_held_press_is_judged_once_and_every_frame_counts_as_warned(caplog, monkeypatch):
    """The small-contact measure cost 2-4.5 ms of host CPU per pressed 640x480 frame, on every frame of a press held
    still (s29-watchcost): its contact is measured once, and each frame still gets the warning."""
    calls = _counting(monkeypatch)
    watch = MismatchWatch(_PressPredictor(), "camera 0")
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for _ in range(5):
            watch(_press(40, 30, 10))
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert len(calls) == 1 and watch.steepness.judged == 1
    assert watch.steep == 5 and lines[0].startswith("camera 0 frame 0: contact about"), lines
    assert "repeated 4 more times" in lines[1] and "(the latest: camera 0 frame 4;" in lines[1]
    assert lines[-1].startswith("5 of 5 frames had a contact too small or steep")


def test_a_stream_whose_contact_changes_is_judged_again(monkeypatch):
    """A press that moves, grows or is replaced is measured again, with the verdict the still-frame check gives;
    a held one again after ``STREAM_REJUDGE_FRAMES`` frames, and after it was lifted."""
    from nlipscalib.core import tolerances
    from nlipscalib.learn.resolution import StreamSteepness, frame_warning

    calls = _counting(monkeypatch)
    predictor = _PressPredictor()
    check = StreamSteepness(predictor)
    # moved a third of its size, grown by a third, another shallow press (not warned), back
    presses = [(40, 30, 10), (45, 30, 10), (45, 30, 13), (40, 30, 10)]
    frames = [predictor.predict_stored(_press(*p), "f") for p in presses]
    elsewhere = predictor.predict_stored(_press(20, 30, 12), "f")
    frames.insert(3, dataclasses.replace(elsewhere, normals=predictor.ref_normals.copy()))
    said = [check(f, f"f{i}") for i, f in enumerate(frames)]
    assert len(calls) == check.judged == 5
    assert said == [frame_warning(predictor, f, f"f{i}") for i, f in enumerate(frames)]
    assert said[3] is None and all(said[i] for i in (0, 1, 2, 4)), said

    monkeypatch.setattr(tolerances, "STREAM_REJUDGE_FRAMES", 2)
    check, held = StreamSteepness(predictor), frames[0]
    assert all(check(held, "f") for _ in range(7)) and check.judged == 3  # frames 0, 3 and 6
    lifted = dataclasses.replace(held, changed=np.zeros_like(held.changed))
    check = StreamSteepness(predictor)
    assert [bool(check(f, "f")) for f in (held, lifted, held)] == [True, False, True] and check.judged == 2


def test_a_noise_speck_far_from_a_held_press_does_not_make_it_judged_again():
    """The change rule's isolated noise blocks come and go on a held press (sphere1 with its noise doubled: one
    moved the changed pixels' bounding box by 140 px); they move the contact's centroid by a fraction of a pixel."""
    from nlipscalib.learn.resolution import StreamSteepness

    predictor = _PressPredictor()
    check = StreamSteepness(predictor)
    held = predictor.predict_stored(_press(50, 30, 10), "f")
    speck = held.changed.copy()
    speck[2:4, 2:4] = True
    for changed in (held.changed, speck, held.changed):
        check(dataclasses.replace(held, changed=changed), "f")
    assert check.judged == 1


class _SteepeningPredictor(_PressPredictor):
    """As _PressPredictor, the dent's normals tilted ``frame[0, 1, 0]`` times the sphere's (0.05: shallow, not
    warned; 1: ~4 deg/px, warned), its changed pixels the same whatever the tilt."""

    def predict_stored(self, frame: np.ndarray, where: str, in_light: bool = False) -> Frame:
        found = super().predict_stored(frame, where)
        scale = float(frame[0, 1, 0])
        tilted = found.normals.copy()
        tilted[found.changed, :2] *= scale
        tilted[found.changed] /= np.linalg.norm(tilted[found.changed], axis=-1, keepdims=True)
        return dataclasses.replace(found, normals=tilted)


@pytest.mark.parametrize("samples", [1000, 50])  # every pixel of the small dent; every 2nd row and column
def test_a_press_that_steepens_in_place_is_judged_again_at_once(monkeypatch, samples):
    """A press whose normals steepen while its changed pixels keep their count and place kept the last verdict for
    up to ``STREAM_REJUDGE_FRAMES`` frames (30: a second at 30 frames/s): a shallow press turned steep went unwarned
    all that while. Its normals' turn (``contact_bend``) now tells: measured again on its first frame past 3 %,
    and each frame gets the verdict the still-frame check gives; a press held at its tilt is still measured once."""
    from nlipscalib.core import tolerances
    from nlipscalib.learn.resolution import StreamSteepness, bend_step, contact_extent, frame_warning

    monkeypatch.setattr(tolerances, "STREAM_TILT_SAMPLES", samples)
    predictor = _SteepeningPredictor()
    check = StreamSteepness(predictor)

    def press(scale):
        frame = _press(40, 30, 10)
        frame[0, 1, 0] = scale
        return predictor.predict_stored(frame, "f")

    frames = [press(s) for s in (0.05, 0.05, 0.05, 1.0, 1.0, 1.0, 0.05)]
    assert len({int(f.changed.sum()) for f in frames}) == 1  # the same pixels: only the normals tell
    assert bend_step(contact_extent(frames[0].changed)) == (1 if samples == 1000 else 2)
    said = [check(f, f"f{i}") for i, f in enumerate(frames)]
    assert said == [frame_warning(predictor, f, f"f{i}") for i, f in enumerate(frames)]
    assert [bool(s) for s in said] == [False, False, False, True, True, True, False] and check.judged == 3
