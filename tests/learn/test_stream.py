"""nlips infer on a stream: a video file, a camera (stand-in), Ctrl-C, and the one-line errors."""

import json
import re

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.imageio import read_png16
from nlipscalib.learn.infer import Predictor

from .conftest import HEIGHT, HELD_OUT, WIDTH

cv2 = pytest.importorskip("cv2")

FRAMES = ("reference", "press_a", HELD_OUT)


def _eight_bit(stored16: np.ndarray) -> np.ndarray:
    """What an 8-bit video keeps of a 16-bit tri-colour frame: (H, W, 3) uint8, RGB."""
    return (stored16 >> 8).astype(np.uint8)


def _video(path, frames, size=None) -> None:
    """A lossless (FFV1) video of tri-colour frames ((H, W, 3) uint8 RGB), optionally resized."""
    h, w = frames[0].shape[:2] if size is None else size[::-1]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), 30, (w, h))
    assert writer.isOpened()
    for rgb in frames:
        bgr = np.ascontiguousarray(rgb[..., ::-1])
        writer.write(bgr if size is None else cv2.resize(bgr, (w, h)))
    writer.release()


@pytest.fixture(scope="module")
def video(twin_presses, tmp_path_factory):
    path = tmp_path_factory.mktemp("stream") / "presses.avi"
    _video(path, [_eight_bit(read_png16(twin_presses / name / "tricolor.png")) for name in FRAMES])
    return path


def test_video_frames_give_what_the_predictor_gives_on_those_frames(trained, twin_presses, video, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(video), "--out", str(out), "--ply"]) == 0
    stdout, printed = capsys.readouterr()  # stdout: the folder the frames went to, alone; the rates on stderr
    assert stdout == f"{out}\n" and "3 frames in" in printed and "frames/s" in printed and "network" in printed
    predictor = Predictor(trained)
    for i, name in enumerate(FRAMES):
        stored = _eight_bit(read_png16(twin_presses / name / "tricolor.png")).astype(np.uint16) << 8
        expected = predictor.predict_stored(stored)
        saved = np.load(out / f"frame_{i:06d}.npz")
        np.testing.assert_allclose(saved["normals"], expected.normals, atol=1e-4)
        np.testing.assert_allclose(saved["depth"], expected.depth, atol=1e-4)
        assert (out / f"frame_{i:06d}_normals.png").is_file()
        assert b"element vertex" in (out / f"frame_{i:06d}.ply").read_bytes()[:300]
    assert expected.changed.sum() > 0  # the held-out press went through the network
    report = json.loads((out / "stream.json").read_text(encoding="utf-8"))
    assert report["frames"] == 3 and report["fps"] > 0 and set(report["median_stage_s"]) >= {"network", "integrate"}
    # what the model is (since s39-lutwords), as a result's report.json says it: a table's has "table" in its place
    assert report["method"] == "nlipsnet" and report["hidden"] == list(predictor.model.hidden) != []
    assert "table" not in report


def test_max_frames_and_every(trained, video, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(video), "--max-frames", "2", "--out", str(out), "--every", "2"]) == 0
    printed = capsys.readouterr().err
    assert "2 frames in" in printed
    assert f"saved: 1 of 2 frames' normals and depth in {out} " in printed  # the summary said nothing of where
    assert sorted(p.name for p in out.glob("*.npz")) == ["frame_000000.npz"]


def test_ctrl_c_ends_a_camera_stream_cleanly(trained, twin_presses, tmp_path, capsys, monkeypatch):
    """A camera stand-in whose 4th read is interrupted (Ctrl-C): 3 frames kept, the summary printed, exit 0."""
    from nlipscalib.device import camera

    frame = read_png16(twin_presses / HELD_OUT / "tricolor.png")

    class InterruptedCamera(camera.FrameSource):
        reads = 0
        shape = frame.shape[:2]

        def read(self):
            self.reads += 1
            if self.reads == 4:
                raise KeyboardInterrupt
            return frame

    monkeypatch.setattr(camera, "open_source", lambda spec, settings=None, tone_curve=None: InterruptedCamera())
    out = tmp_path / "out"
    assert main(["infer", str(trained), "--camera", "0", "--out", str(out)]) == 0
    assert "3 frames in" in capsys.readouterr().err
    assert len(list(out.glob("*.npz"))) == 3


def _camera_that_stops(monkeypatch, frame: np.ndarray, after: int) -> None:
    """``--camera 0`` opens a stand-in that gives ``frame`` ``after`` times, then fails as a live camera that stopped
    sending does (``OpenCVSource._grab``)."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.device import camera

    class StoppingCamera(camera.FrameSource):
        reads = 0
        shape = frame.shape[:2]
        live = True

        def read(self):
            if self.reads == after:
                raise CaptureError("camera 0: no frame (the camera stopped)")
            self.reads += 1
            return frame

    monkeypatch.setattr(camera, "open_source", lambda spec, settings=None, tone_curve=None: StoppingCamera())


def test_a_camera_that_stops_sending_ends_the_stream_with_its_summary_then_one_line(
    trained, twin_presses, tmp_path, capsys, monkeypatch
):
    """A live camera that stopped (unplugged; its driver's read timed out) ended `nlips infer --camera` with the error
    alone: an hours-long stream's count, rate, stage line and stream.json were lost (s29-soak)."""
    _camera_that_stops(monkeypatch, read_png16(twin_presses / HELD_OUT / "tricolor.png"), after=4)
    out = tmp_path / "out"
    assert main(["infer", str(trained), "--camera", "0", "--out", str(out), "--every", "2"]) == 2
    stdout, printed = capsys.readouterr()
    err = printed.strip().splitlines()[-1:]  # after the summary: the error
    assert stdout == f"{out}\n" and "4 frames in" in printed and "frames/s for the predictor alone" in printed
    assert f"saved: 2 of 4 frames' normals and depth in {out} (frame_NNNNNN.npz, _normals.png; stream.json)" in printed
    assert err == ["nlips infer: error: camera 0: no frame (the camera stopped)"]
    assert json.loads((out / "stream.json").read_text(encoding="utf-8"))["frames"] == 4


def test_a_disk_that_fills_ends_the_stream_with_its_summary_then_one_line(
    trained, twin_presses, tmp_path, capsys, monkeypatch
):
    """`nlips infer VIDEO --out DIR` on a disk that fills: the frames saved before it kept whole, their summary, then
    the one line naming the file (no stream.json: the disk has no room for it)."""
    import errno
    import os

    from nlipscalib.core import atomic
    from nlipscalib.device import live

    _camera_that_stops(monkeypatch, read_png16(twin_presses / HELD_OUT / "tricolor.png"), after=100)
    real_save, saved = live.save_npz, []

    def fills_at_the_third(path, arrays, **kw):
        if len(saved) == 2:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        saved.append(path)
        return real_save(path, arrays, **kw)

    def full(path, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(live, "save_npz", fills_at_the_third)
    monkeypatch.setattr(atomic, "write_bytes", full)  # stream.json finds the disk full too
    out = tmp_path / "out"
    assert main(["infer", str(trained), "--camera", "0", "--out", str(out)]) == 2
    printed = capsys.readouterr().err
    err = printed.strip().splitlines()[-1:]  # after the summary: the error
    assert "2 frames in" in printed and f"saved: 2 of 2 frames' normals and depth in {out} (frame_NNNNNN.npz" in printed
    assert "stream.json" not in printed and not (out / "stream.json").exists()
    assert err == [
        f"nlips infer: error: {out / 'frame_000002.npz'}: No space left on device (the disk is full: free space or "
        "choose another --out)"
    ]
    assert sorted(p.name for p in out.glob("*.npz")) == ["frame_000000.npz", "frame_000001.npz"]


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_video_of_another_size_is_refused_in_one_line(trained, twin_presses, tmp_path, capsys):
    small = tmp_path / "small.avi"
    _video(small, [_eight_bit(read_png16(twin_presses / HELD_OUT / "tricolor.png"))], size=(64, 48))
    assert main(["infer", str(trained), str(small)]) != 0
    line = _one_line_error(capsys)
    assert "small.avi" in line and "64x48" in line and f"{WIDTH}x{HEIGHT}" in line


def test_unreadable_video_and_missing_camera_are_named(trained, tmp_path, capsys):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video" * 100)
    assert main(["infer", str(trained), str(bad)]) != 0  # the same line as `--camera FILE` below
    assert _one_line_error(capsys).endswith(
        f"{bad}: OpenCV cannot read it as video or images (another kind of file, damaged, or a missing codec)"
    )
    assert main(["infer", str(trained), "--camera", "/dev/nlips-no-such-camera"]) != 0
    assert "camera /dev/nlips-no-such-camera" in _one_line_error(capsys)
    fake = tmp_path / "fake.png"  # OpenCV opens it, then gives no frame: was "no frame (end of file)"
    fake.write_bytes(b"not an image" * 100)
    assert main(["infer", str(trained), "--camera", str(fake)]) != 0
    assert _one_line_error(capsys).endswith(
        f"{fake}: OpenCV cannot read it as video or images (another kind of file, damaged, or a missing codec)"
    )


def test_a_stream_is_not_mixed_with_other_inputs(trained, twin_presses, video, capsys):
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), str(video)]) != 0
    assert "one at a time" in _one_line_error(capsys)
    assert main(["infer", str(trained)]) != 0
    assert "--camera" in _one_line_error(capsys)


def test_emulated_sensor_streams_through_infer(tmp_path, capsys, caplog):
    """`nlips infer --emulate`: the emulated camera, opened the way `nlips live` opens it; the twin's renders
    before the first frame are said (the stream was silent for them)."""
    import logging

    from nlipscalib.core import load_press
    from nlipscalib.core.sensor_record import sensor_of
    from nlipscalib.learn.dataset import reference_arrays
    from nlipscalib.learn.model import build_net, save_model

    size = ["--emulate", "nlipstac", "--width", "64", "--height", "48"]
    assert main(["capture", *size, "--presses", "0", "--spp", "1", "--out", str(tmp_path / "s")]) == 0
    reference = load_press(tmp_path / "s" / "reference")
    model = save_model(  # an untrained net for this sensor: the stream, not the accuracy, is under test
        tmp_path / "net.pt",
        build_net(hidden=(8, 8), dropout=0.0, width=64, height=48),
        hidden=(8, 8),
        dropout=0.0,
        sensor=sensor_of(reference),
        reference=reference_arrays(reference),
        info={},
    )
    capsys.readouterr()
    args = ["infer", str(model), *size, "--max-frames", "4", "--frames-per-press", "2", "--out", str(tmp_path / "o")]
    caplog.set_level(logging.INFO)
    assert main(args) == 0
    assert "4 frames in" in capsys.readouterr().err
    said = caplog.text  # the undeformed dome and the default script's 3 presses
    assert "rendering the emulated sensor's 4 scripted surfaces (64x48) before the stream ..." in said, said
    first = np.load(tmp_path / "o" / "frame_000000.npz")  # the undeformed gel: reference normals where unchanged
    valid = np.isfinite(reference.reference.depth)
    same = np.all(np.abs(first["normals"] - reference.reference.normals) < 1e-5, axis=-1)
    assert same[valid].mean() > 0.9
    # another size is refused before the twin renders (it said so after ~20 s), naming the model's size
    args = ["infer", str(model), "--emulate", "nlipstac", "--width", "80", "--height", "60", "--max-frames", "1"]
    assert main(args) == 2
    assert "give --width 64 --height 48, or leave both out" in _one_line_error(capsys)
    # the same stream asked for by its board's URL, as nlips live takes it; its size is the model's
    by_port = ["--port", "nlipsemu://17"]
    args = ["infer", str(model), *by_port, "--max-frames", "4", "--frames-per-press", "2", "--out", str(tmp_path / "p")]
    assert main(args) == 0
    assert "4 frames in" in capsys.readouterr().err
    again = np.load(tmp_path / "p" / "frame_000000.npz")
    np.testing.assert_array_equal(again["normals"], first["normals"])


def test_unreadable_video_prints_one_line_in_a_fresh_process(trained, tmp_path):
    """FFmpeg writes its own parse errors straight to the process's stderr (not through Python): only ours shows."""
    import subprocess
    import sys

    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video" * 100)
    run = subprocess.run(
        [sys.executable, "-c", "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"]
        + ["infer", str(trained), str(bad)],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode != 0
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "broken.mp4" in lines[0], run.stderr


def _printed_ms(line: str, step: str) -> float:
    """The milliseconds the stage line printed for ``step`` ("check 31.2 ms")."""
    return float(re.search(rf"\b{step} ([0-9.]+) ms", line).group(1))


def test_the_stage_line_accounts_for_every_step_of_a_frame(trained, twin_presses, tmp_path, capsys, monkeypatch):
    """The exposure check of frames unlike the calibration's (~20 ms of a 640x480 frame) ran outside the stage
    times: `nlips infer`'s stage line said 155 frames/s for an emulated stream measured at 11.6 (s24 live walk).
    Here the check is made slow (a 30 ms sleep in it) on a dimmed stream: the line prints it as a stage, its
    steps add up to its per-frame time, its rate is that time's inverse, and the time is the stream's "predictor"."""
    import time as clock

    from nlipscalib.learn import infer

    dim = tmp_path / "dim.avi"
    _video(dim, [_eight_bit((read_png16(twin_presses / n / "tricolor.png") * 0.5).astype(np.uint16)) for n in FRAMES])
    exposure = infer.Predictor._exposure

    def slow_exposure(self, tricolor, gain=None):
        clock.sleep(0.03)
        return exposure(self, tricolor, gain)

    monkeypatch.setattr(infer.Predictor, "_exposure", slow_exposure)
    out = tmp_path / "out"
    assert main(["infer", str(trained), str(dim), "--out", str(out), "--every", "3"]) == 0
    printed = capsys.readouterr().err
    line = next(s for s in printed.splitlines() if s.startswith("NLiPsNet"))
    stream_line = next(s for s in printed.splitlines() if " frames in " in s)
    recorded = json.loads((out / "stream.json").read_text(encoding="utf-8"))["mean_stage_s"]
    steps = ("linearise", "change", "network", "integrate", "check", "other")
    shown = {step: _printed_ms(line, step) for step in steps}
    for step in steps[:-1]:  # the printed means are the recorded stage times
        assert shown[step] == pytest.approx(1e3 * recorded[step], abs=0.051), (step, line)
    assert shown["check"] >= 30  # the sleep is in the check's stage (a sleep is never shorter than asked)
    per_frame = float(re.search(r"= ([0-9.]+) ms = ([0-9.]+) frames/s", line).group(1))
    rate = float(re.search(r"= ([0-9.]+) ms = ([0-9.]+) frames/s", line).group(2))
    assert per_frame == pytest.approx(sum(shown.values()), abs=0.051 * len(steps))  # the steps add up
    assert per_frame >= 1e3 * recorded["total"] - 0.051  # the predictor's own total is inside the call
    # the rate is the time's inverse: each printed to 0.1, so the rate's own rounding (0.05) and the time's (0.05 ms,
    # 0.05e-3 rate^2 frames/s: 29.4 shown for 34.1 ms = 29.33 in a clean-clone CI run)
    assert rate == pytest.approx(1e3 / per_frame, abs=0.051 + 0.051e-3 * rate**2)
    assert rate < 1e3 / 30  # so it cannot claim more than the slow check allows
    assert per_frame == pytest.approx(_printed_ms(stream_line, "predictor"), abs=0.051)  # the line above's step
    assert "predictor alone, without read and output" in line


def _stage_frame(seconds: dict):
    from nlipscalib.learn.infer import Frame

    return Frame(np.zeros((1, 1, 3)), np.zeros((1, 1)), np.zeros((1, 1, 3)), np.zeros((1, 1), bool), seconds)


def test_stage_times_of_a_long_stream_take_memory_that_does_not_grow_with_its_frames():
    """The summary kept every frame's stage dict (0.42 kB a frame, 46 MB an hour at 30 frames/s): a stream of
    100 times the frames now takes no more room than a short one."""
    import pickle

    from nlipscalib.cli.infer import _StageTimes

    def stages_of(frames: int) -> _StageTimes:
        stages = _StageTimes()
        for i in range(frames):  # 40 distinct times per stage, as a stream's repeat
            network = 0.010 + 0.0001 * (i % 40)
            stages.add(_stage_frame({"network": network, "integrate": 0.002, "total": network + 0.002}))
        return stages

    short, long = stages_of(200), stages_of(20_000)
    assert len(pickle.dumps(long)) < 1.2 * len(pickle.dumps(short))
    assert long.means()["network"] == pytest.approx(0.010 + 0.0001 * 19.5, rel=1e-9)


def test_stage_times_that_vary_continuously_take_memory_fixed_from_the_first_frame():
    """A loaded CPU's stage times vary continuously: the bins were a dict that gained an entry for each new bin a time
    fell in (7,788 after 2,000 frames of a stream, growing for hours, s29-soak); 20,000 frames now take the room of
    200, whatever their times (the ends of STAGE_TIME_RANGE_S counted in its first and last bins)."""
    import pickle

    from nlipscalib.cli.infer import STAGE_MEDIAN_BIN, STAGE_TIME_RANGE_S, _StageTimes

    rng = np.random.default_rng(5)

    def stages_of(frames: int) -> _StageTimes:
        stages = _StageTimes()
        for network in rng.lognormal(np.log(0.01), 1.0, frames):
            stages.add(_stage_frame({"network": network, "total": network + 0.002}))
        return stages

    short, long = stages_of(200), stages_of(20_000)
    assert len(pickle.dumps(long)) <= len(pickle.dumps(short)) + 1000
    outside = _StageTimes()
    for seconds in (STAGE_TIME_RANGE_S[0] / 10, STAGE_TIME_RANGE_S[1] * 10, STAGE_TIME_RANGE_S[1] * 10):
        outside.add(_stage_frame({"network": seconds, "total": seconds}))
    assert outside.medians()["network"] == pytest.approx(STAGE_TIME_RANGE_S[1], rel=STAGE_MEDIAN_BIN)


def test_stage_medians_are_numpys_within_the_bin_width_with_missing_stages_as_zero():
    from nlipscalib.cli.infer import STAGE_MEDIAN_BIN, _StageTimes

    rng = np.random.default_rng(3)
    for frames in (1, 2, 7, 8, 501):
        times = rng.lognormal(np.log(0.02), 0.5, frames)
        checked = np.where(rng.random(frames) < 0.3, times / 10, 0.0)  # a stage some frames lack (GPU's "check")
        stages = _StageTimes()
        for t, c in zip(times, checked):
            stages.add(_stage_frame({"network": t} | ({"check": c} if c else {}) | {"total": t + c}))
        medians, means = stages.medians(), stages.means()
        assert list(medians) == (["network", "check", "total"] if checked.any() else ["network", "total"])
        for name, values in (("network", times), ("check", checked), ("total", times + checked)):
            if name in medians:
                assert medians[name] == pytest.approx(np.median(values), rel=STAGE_MEDIAN_BIN / 2, abs=1e-12)
                assert means[name] == pytest.approx(values.mean(), rel=1e-12)


def test_a_stream_into_a_folder_of_an_earlier_runs_frames_warns_that_they_may_mix(trained, video, tmp_path, caplog):
    """`nlips infer MODEL VIDEO --out DIR` replaced the frames it wrote and left an earlier, longer run's others (an
    older nlipscalib's, another model's) beside them without a word."""
    import logging

    out = tmp_path / "out"
    assert main(["infer", str(trained), str(video), "--max-frames", "3", "--out", str(out)]) == 0
    with caplog.at_level(logging.WARNING):
        assert main(["infer", str(trained), str(video), "--max-frames", "1", "--out", str(out)]) == 0
    warned = [r.getMessage() for r in caplog.records if "earlier run" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{out}: holds 3 frame(s) an earlier run saved"), warned
