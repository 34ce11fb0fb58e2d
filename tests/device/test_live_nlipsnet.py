"""`nlips live --emulate --model` and `nlips infer` streams: an NLiPsNet model file on the emulated sensor, a camera
stand-in or recorded frames, with the LED board watched for resets."""

import json
import logging

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("torch")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402

ARGS = ["--emulate", "nlipstac", "--width", "64", "--height", "48"]


def _untrained_model(reference_press, path, brightness: float = 1.0):
    """A model file for this sensor with an untrained network: enough to test the streaming path.

    ``brightness`` scales the calibration's reference frame: the sensor's frames are then 1/brightness as
    bright as the calibration's, as after a change of exposure."""
    from nlipscalib.core.sensor_record import sensor_of
    from nlipscalib.learn.dataset import reference_arrays
    from nlipscalib.learn.model import build_net, save_model

    net = build_net(hidden=(16, 16), dropout=0.0, width=64, height=48)
    sensor, reference = sensor_of(reference_press), reference_arrays(reference_press)
    reference["tricolor"] = reference["tricolor"] * np.float32(brightness)
    return save_model(path, net, hidden=(16, 16), dropout=0.0, sensor=sensor, reference=reference, info={})


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The emulated sensor's undeformed capture (what a calibration's reference is)."""
    folder = tmp_path_factory.mktemp("live_nlipsnet") / "s"
    assert main(["capture", *ARGS, "--presses", "0", "--spp", "1", "--out", str(folder)]) == 0
    return load_press(folder / "reference")


def test_live_streams_the_emulated_sensor_through_nlipsnet(reference, tmp_path, capsys, caplog):
    import logging

    caplog.set_level(logging.WARNING)
    model = _untrained_model(reference, tmp_path / "net.pt")
    maps = tmp_path / "maps"
    args = ["live", *ARGS, "--model", str(model), "--frames", "6", "--frames-per-press", "3", "--save", str(maps)]
    assert main(args) == 0
    summary = capsys.readouterr().err
    assert "6 frames in" in summary and "fps" in summary
    assert "differs from the calibration's reference" not in caplog.text  # frames of the calibrated sensor
    first = np.load(maps / "frame_000001.npz")  # the undeformed gel: the reference normals where nothing changed
    valid = np.isfinite(reference.reference.depth)
    same = np.all(np.abs(first["normals"] - reference.reference.normals) < 1e-5, axis=-1)
    assert same[valid].mean() > 0.9
    assert len(list(maps.glob("*_normals.png"))) == 6


@pytest.mark.parametrize("path", [[], ["--full-frame"]])
def test_live_warns_once_when_frames_differ_from_the_calibration_everywhere(reference, tmp_path, capsys, caplog, path):
    """``nlips infer`` warned about frames unlike the calibration's reference over the whole gel (another exposure,
    BGR stored as RGB); ``nlips live`` showed the undeformed dome without a word. Now: once per stream, and the
    count at the end; the whole-frame path (torch, any device) measures the same figure."""
    import logging

    caplog.set_level(logging.WARNING)
    model = _untrained_model(reference, tmp_path / "net.pt", brightness=3.0)  # frames 1/3 as bright
    assert main(["live", *ARGS, "--model", str(model), "--frames", "4", "--no-window", *path]) == 0
    assert "4 frames in" in capsys.readouterr().err
    warned = [r.getMessage() for r in caplog.records if "differs from the calibration's reference" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith("emulated sensor frame 0: ") and "times as bright" in warned[0]
    assert "4 of 4 frames differed from the calibration's reference" in caplog.text


@pytest.mark.parametrize("command", ["live", "infer"])
def test_a_model_of_another_sensor_is_refused_on_the_emulated_sensor(reference, tmp_path, capsys, command):
    """`nlips live --emulate oblate` with a model calibrated on nlipstac streamed with a brightness warning only,
    exit 0; `nlips infer` refuses presses of another sensor. Now the same check refuses the scene, before rendering."""
    model = _untrained_model(reference, tmp_path / "net.pt")
    args = (
        ["live", "--model", str(model), "--frames", "2", "--no-window"] if command == "live" else ["infer", str(model)]
    )
    assert main([*args, "--emulate", "fingertip"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(
        f"nlips {command}: error: --emulate fingertip: the emulated sensor of fingertip is another sensor than the "
        f"model {model} was calibrated for ("
    )
    assert err.count("\n") == 1, err
    assert main([*args, "--emulate", "nlipstac", "--frames-per-press", "1"]) == 0  # its own sensor streams


@pytest.mark.parametrize("command", ["live", "infer"])
def test_a_scene_of_another_dome_with_the_models_camera_and_leds_is_refused(reference, tmp_path, capsys, command):
    """The lab-2 walk: a user's copy of a scene with its dome changed alone (camera, LED ring as they were) passed
    the camera and LED check and streamed with a brightness warning, exit 0. The undeformed surface is compared
    too (the design's, as the emulator renders it, against the model's calibration reference)."""
    from nlipscalib.core.sensor import SCENES_DIR

    model = _untrained_model(reference, tmp_path / "net.pt")
    scene = tmp_path / "mine.toml"
    text = (SCENES_DIR / "nlipstac.toml").read_text(encoding="utf-8")
    assert "radius = 15.0" in text
    scene.write_text(
        text.replace("radius = 15.0", "radius = 14.0", 1), encoding="utf-8"
    )  # the dome's; the LED ring is ring_radius
    args = (
        ["live", "--model", str(model), "--frames", "2", "--no-window"] if command == "live" else ["infer", str(model)]
    )
    assert main([*args, "--emulate", str(scene), "--width", "64", "--height", "48"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nlips {command}: error: --emulate {scene}: the emulated sensor of {scene} is another ")
    assert "undeformed surfaces" in err and "mm apart (median)" in err and err.count("\n") == 1, err


def test_infer_keeps_its_summary_and_report_when_the_board_is_lost_before_the_lights_off(
    reference, tmp_path, capsys, monkeypatch
):
    """`nlips infer --camera FRAMES --port PORT` whose board is pulled mid-stream: the final lights-off failed and
    its error replaced the summary and stream.json of the frames inferred. Now they come first, then one line. Since
    s38 the board is watched at every frame of a folder too (its frames were decoded past the watch), so the stream
    ends at the read after the unplug, as `nlips live`'s does (tests/device/test_lights_out.py): 1 frame, not 3."""
    import cv2

    from nlipscalib.device.controller import LedController
    from nlipscalib.device.virtual_board import VirtualBoard
    from nlipscalib.learn.infer import Predictor

    model = _untrained_model(reference, tmp_path / "net.pt")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k}.png"), np.ascontiguousarray(reference.tricolor[..., ::-1]))
    board = VirtualBoard(12)
    real_open, real_predict = LedController.open.__func__, Predictor.predict_stored
    monkeypatch.setattr(  # the command waits 5 s for an unplugged board to come back
        LedController, "open", classmethod(lambda cls, url, **kw: real_open(cls, url, **{**kw, "reconnect_s": 0.3}))
    )
    monkeypatch.setattr(
        Predictor, "predict_stored", lambda self, *a, **k: (board.unplug(), real_predict(self, *a, **k))[1]
    )
    out = tmp_path / "out"
    assert main(["infer", str(model), "--camera", str(frames), "--port", board.url, "--out", str(out)]) == 2
    captured = capsys.readouterr()  # the summary (on stderr since 2026-12-06: stdout holds the --out folder), then
    said = captured.err.splitlines()  # the error, last
    assert any(line.startswith("1 frames in ") for line in said), said
    lines = [line for line in said if line.startswith("nlips ")]
    assert (
        said[-1] == lines[0]
        and len(lines) == 1
        and lines[0].startswith(f"nlips infer: error: {board.url}: the board disconnected (")
    ), lines
    assert (out / "stream.json").is_file() and len(list(out.glob("frame_*.npz"))) == 1


def _infer_watched(monkeypatch, reset_on_call=None):
    """Record the level of every frame ``nlips infer`` hands NLiPsNet (and reset ``reset_on_call = (board, k)``'s
    board as it takes its k-th frame, after the read that asked the board)."""
    from nlipscalib.device.live_leds import frame_level
    from nlipscalib.learn.infer import Predictor

    levels, real_predict = [], Predictor.predict_stored

    def predict(self, frame, *args, **kwargs):
        levels.append(frame_level(frame))
        if reset_on_call is not None and len(levels) == reset_on_call[1]:
            reset_on_call[0].reset()
        return real_predict(self, frame, *args, **kwargs)

    monkeypatch.setattr(Predictor, "predict_stored", predict)
    return levels


@pytest.mark.parametrize("announced", [True, False])
def test_infer_from_a_camera_watches_the_board_as_live_does(
    reference, tmp_path, capsys, monkeypatch, caplog, announced
):
    """`nlips infer --camera N --port PORT` shares `nlips live`'s watch: a board reset mid-stream (its banner seen,
    or lost and found by the dark frames) is one warning, the pattern relit, no dark frame inferred, the dropped
    ones counted in the summary, exit 0."""

    from nlipscalib.device import camera as device_camera

    from .test_live_board_reset import LivePinCamera, VirtualUnder

    model = _untrained_model(reference, tmp_path / "net.pt")
    board = VirtualUnder()

    def reset(reads: int) -> bool:
        if reads == 4:
            board.board.reset(banner=announced)
        return False

    camera = LivePinCamera(board, reset)
    monkeypatch.setattr(device_camera, "open_source", lambda *args, **kwargs: camera)
    levels = _infer_watched(monkeypatch)
    out = tmp_path / "out"
    args = ["infer", str(model), "--camera", "0", "--port", board.url, "--max-frames", "6", "--out", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    reason = "it printed its boot banner" if announced else "it no longer knows the session"
    ours = [r.getMessage() for r in caplog.records if "reset during the stream" in r.getMessage()]
    assert len(ours) == 1 and ours[0].startswith(f"{board.url}: the LED board reset during the stream ({reason})")
    (summary,) = [line for line in err.splitlines() if line.startswith("6 frames in")]
    assert summary.endswith("; 1 more dropped, read while the LED board had reset"), summary
    assert len(levels) == 6 and min(levels) > 0.5 * max(levels), levels  # no dark frame reached the network
    assert len(list(out.glob("frame_*.npz"))) == 6 and not board.latched().any()
    assert json.loads((out / "stream.json").read_text(encoding="utf-8"))["dropped"] == 1


def test_infer_from_recorded_frames_with_a_port_keeps_every_frame_through_a_reset(
    reference, tmp_path, capsys, monkeypatch, caplog
):
    """`nlips infer --camera FOLDER --port PORT`: the folder's frames were decoded ahead on threads straight from
    their files, past the watch, so a reset was found only by the LEDs' OFF at the end: the driver's "... restored
    to the last acknowledged colours; retake any frame captured since the previous command", exit 2. Now the board
    is watched at every frame: relit with one warning, and the recorded frames (not lit by it) all kept, exit 0."""
    import cv2

    from nlipscalib.device.virtual_board import VirtualBoard

    model = _untrained_model(reference, tmp_path / "net.pt")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(3):
        cv2.imwrite(str(frames / f"{k}.png"), np.ascontiguousarray(reference.tricolor[..., ::-1]))
    board = VirtualBoard(12)
    levels = _infer_watched(monkeypatch, (board, 1))
    out = tmp_path / "out"
    assert main(["infer", str(model), "--camera", str(frames), "--port", board.url, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert (
        f"{board.url}: the LED board reset during the stream (it printed its boot banner); the tri-colour pattern is "
        "lit again (the recorded frames are all kept: it does not light them)"
    ) in caplog.text, caplog.text
    assert len(levels) == 3 and len(list(out.glob("frame_*.npz"))) == 3 and "dropped" not in err
    assert not board.latched.any()


def test_infer_says_a_reset_found_as_the_stream_ended_as_live_says_it(reference, tmp_path, capsys, monkeypatch, caplog):
    """Found by the LEDs' OFF after the last frame, `nlips infer` said the driver's "... have been restored to the
    last acknowledged colours; retake any frame captured since the previous command": the LEDs were off, and no
    frame was to be retaken. Then (s38) what happened and what became of the frames, after the summary, exit 2; now
    that line as a warning, exit 0: every frame is kept, as through a reset found during the stream."""
    from nlipscalib.device import camera as device_camera

    from .test_live_board_reset import LivePinCamera, VirtualUnder

    caplog.set_level(logging.WARNING)
    model = _untrained_model(reference, tmp_path / "net.pt")
    board = VirtualUnder()
    camera = LivePinCamera(board, lambda reads: False)
    monkeypatch.setattr(device_camera, "open_source", lambda *args, **kwargs: camera)
    _infer_watched(monkeypatch, (board, 4))
    out = tmp_path / "out"
    args = ["infer", str(model), "--camera", "0", "--port", board.url, "--max-frames", "4", "--out", str(out)]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "error" not in err and "Traceback" not in err, err
    assert any(line.startswith("4 frames in ") for line in err.splitlines()), err
    warnings = [r.getMessage() for r in caplog.records if "as the stream ended" in r.getMessage()]
    assert warnings == [
        f"{board.url}: the LED board reset as the stream ended, after its last frame (it printed its boot banner; "
        "found as the LEDs were switched off): its 4 frames were each read with the board found lit and none dark, "
        "and are kept; the LEDs are off. A board that resets as its LEDs light is often browning out (the LEDs "
        "powered from the board's 5 V, or a supply too weak: firmware/README.md, Wiring, in the nlipscalib source "
        "distribution or repository)"
    ], warnings
    assert len(list(out.glob("frame_*.npz"))) == 4
    assert (out / "stream.json").is_file() and not board.latched().any()
