"""Frame sources: folders of 8/16-bit images, video files, camera settings read back, flushing, averaging."""

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.device.camera import (  # noqa: E402
    CameraSettings,
    FolderSource,
    OpenCVSource,
    SequenceSource,
    apply_settings,
    open_source,
    to_stored,
)


def test_folder_keeps_16_bit_and_rgb_order(tmp_path):
    frames = [np.full((6, 8, 3), [1000 * k, 2000, 3000], np.uint16) for k in range(1, 4)]
    for k, f in enumerate(frames):
        cv2.imwrite(str(tmp_path / f"img_{k:03d}.png"), f[..., ::-1])  # OpenCV writes BGR
    src = open_source(str(tmp_path))
    assert isinstance(src, FolderSource) and src.bit_depth == 16 and src.shape == (6, 8)
    for f in frames:
        np.testing.assert_array_equal(src.capture(), f)  # file sources never flush
    with pytest.raises(CaptureError, match="ran out of images"):
        src.read()


def test_8_bit_and_grey_frames_scale_to_16_bit():
    grey = np.array([[0, 1], [128, 255]], np.uint8)
    out, bits = to_stored(grey)
    assert bits == 8 and out.shape == (2, 2, 3) and out[1, 1, 0] == 255 << 8
    with pytest.raises(CaptureError, match="unsupported"):
        to_stored(np.zeros((2, 2), np.float32))


def test_folder_averages_frames(tmp_path):
    for k, v in enumerate([100, 200, 400, 500]):
        cv2.imwrite(str(tmp_path / f"{k}.png"), np.full((4, 4, 3), v, np.uint16))
    src = FolderSource(tmp_path, average=2)
    assert src.capture()[0, 0, 0] == 150 and src.capture()[0, 0, 0] == 450


def test_video_file_is_read_frame_by_frame(tmp_path):
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (32, 24))
    for v in (40, 120, 200):
        writer.write(np.full((24, 32, 3), v, np.uint8))
    writer.release()
    src = open_source(str(path), CameraSettings(flush_frames=5))
    assert isinstance(src, OpenCVSource) and src.shape == (24, 32) and src.bit_depth == 8
    levels = [int(src.capture()[12, 16, 1]) >> 8 for _ in range(3)]  # no flushing on files
    assert np.allclose(levels, [40, 120, 200], atol=3)
    with pytest.raises(CaptureError, match="no frame"):
        src.capture()
    src.close()
    with pytest.raises(CaptureError, match="does not exist"):
        open_source(str(tmp_path / "missing.avi"))


def test_a_recording_skips_to_a_frame_forward_and_back_and_knows_itself(tmp_path):
    """What a resumed capture asks of a recorded camera (``device.recording_resume``): frame ``index`` next, the
    frames read so far, and which recording it is (its path and first frame)."""
    import shutil

    from nlipscalib.device.camera import EndOfFrames

    folder, path = tmp_path / "frames", tmp_path / "clip.avi"
    folder.mkdir()
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (32, 24))
    for k, v in enumerate((40, 80, 120, 160, 200)):
        cv2.imwrite(str(folder / f"{k}.png"), np.full((24, 32, 3), v, np.uint8))
        writer.write(np.full((24, 32, 3), v, np.uint8))
    writer.release()
    for spec in (folder, path):
        src = open_source(str(spec))
        assert src.frames_consumed == 0 and src.recording.path == str(spec.resolve()) and src.recording.frames == 5
        src.read()
        assert src.frames_consumed == 1
        for index in (3, 1, 4, 0):
            src.skip_to(index)
            assert src.frames_consumed == index
            assert abs((int(src.read()[12, 16, 1]) >> 8) - 40 * (index + 1)) <= 3, (spec, index)
            assert src.frames_consumed == index + 1
        with pytest.raises(EndOfFrames, match="holds 5 frames, no frame 6"):
            src.skip_to(5)
        src.close()
    shutil.copytree(folder, tmp_path / "copy")
    (tmp_path / "copy" / "0.png").unlink()
    ours, copied, again = FolderSource(folder), FolderSource(tmp_path / "copy"), FolderSource(folder)
    assert ours.recording == again.recording and ours.recording.first_frame != copied.recording.first_frame
    with open_source(str(path)) as one, open_source(str(path)) as other:
        assert one.recording == other.recording


def test_sequence_patterns_are_one_integer_field():
    from nlipscalib.device.camera import is_sequence_pattern

    for good in ("img_%04d.png", "f%d.tif", "50%%_a%02d.png", "%3d.png"):
        assert is_sequence_pattern(good), good
    for bad in ("img.png", "x_%s.png", "x_%d_%d.png", "a%.0sb.png", "x_%f.png", "50%.png"):
        assert not is_sequence_pattern(bad), bad


@pytest.mark.parametrize("first", [0, 1])
def test_an_image_sequence_reads_as_opencv_reads_it(tmp_path, first):
    """Known answer: OpenCV's own image-sequence reader (from 0, or 1 without a 0; up to the first gap)."""
    for k in range(first, first + 4):
        cv2.imwrite(str(tmp_path / f"img_{k:04d}.png"), np.full((6, 8, 3), [100 * k, 2000, 3000], np.uint16))
    cv2.imwrite(str(tmp_path / "img_0009.png"), np.zeros((6, 8, 3), np.uint16))  # after the gap: not in it
    pattern = str(tmp_path / "img_%04d.png")
    src = open_source(pattern)
    assert isinstance(src, SequenceSource) and src.bit_depth == 16 and len(src.files) == 4
    cap = cv2.VideoCapture(pattern)
    opencv = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        opencv.append(to_stored(frame)[0])
    cap.release()
    ours = [src.read() for _ in range(len(src.files))]
    # OpenCV's sequence reader rounds 16-bit files to 8 bits; this source keeps their 16
    assert len(ours) == len(opencv) == 4
    for a, b in zip(ours, opencv):
        assert np.all(np.abs(a / 256.0 - (b >> 8)) <= 0.5)
    np.testing.assert_array_equal(src.frame_at(2), ours[2])  # any frame, in any order
    with pytest.raises(CaptureError, match="ran out of images after 4 frames"):
        src.read()


def test_a_bad_image_sequence_is_one_line(tmp_path):
    with pytest.raises(CaptureError, match=r"no image of the sequence \(.*img_0000.png nor .*img_0001.png exists\)"):
        open_source(str(tmp_path / "img_%04d.png"))
    (tmp_path / "x_5.png").write_bytes(b"")
    (tmp_path / "ab.png").write_bytes(b"")
    # %s and the like would name files too ("a%.0sb.png": ab.png for every index, a sequence without end)
    for bad in ("x_%s%d.png", "x_%s.png", "a%.0sb.png", "x_%d_%d.png", "x_%f.png"):
        with pytest.raises(CaptureError, match="not an image-sequence pattern .* nor an existing file"):
            open_source(str(tmp_path / bad))
    (tmp_path / "y_0.png").write_bytes(b"not a png")
    with pytest.raises(CaptureError, match="y_0.png: not a readable image"):
        open_source(str(tmp_path / "y_%d.png"))
    # a file whose name holds a % is that file, not a pattern
    named = tmp_path / "press 50%.png"
    cv2.imwrite(str(named), np.zeros((4, 4, 3), np.uint16))
    assert not isinstance(open_source(str(named)), SequenceSource)


def test_a_live_camera_that_stops_is_an_error_a_video_that_ends_is_not(tmp_path):
    from nlipscalib.device.camera import EndOfFrames

    class Stopped:
        def read(self):
            return False, None

    camera = object.__new__(OpenCVSource)  # a camera that has stopped (unplugged), without opening one
    camera.device, camera.live, camera.cap, camera._first = 0, True, Stopped(), None
    with pytest.raises(CaptureError, match="camera 0: no frame \\(the camera stopped\\)") as stopped:
        camera.read()
    assert not isinstance(stopped.value, EndOfFrames)
    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (32, 24))
    writer.write(np.full((24, 32, 3), 90, np.uint8))
    writer.release()
    video = open_source(str(path))
    video.read()
    with pytest.raises(EndOfFrames, match="end of file"):
        video.read()
    video.close()


def test_a_video_cut_short_of_its_declared_frames_is_an_error_after_its_frames(tmp_path):
    """A video copied or recorded only in part (its container declaring 21 frames, 9 decodable) ended as a whole
    recording does: `nlips infer VIDEO` and `nlips live --camera VIDEO` inferred 9 frames and exited 0, saying
    nothing. Now the frames read are handed out, then one error naming the file and both counts."""
    from nlipscalib.device.camera import EndOfFrames

    path = tmp_path / "clip.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (160, 120))
    noise = np.random.default_rng(0)
    for _ in range(21):  # noisy frames: each compresses to about the same size
        writer.write(noise.integers(0, 256, (120, 160, 3), dtype=np.uint8))
    writer.release()
    whole = open_source(str(path))
    assert whole.declared_frames == 21
    for _ in range(21):
        whole.read()
    with pytest.raises(EndOfFrames):
        whole.read()
    whole.close()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    video = open_source(str(cut))
    read = 0
    with pytest.raises(CaptureError, match=r"cut\.avi: the video ends after \d+ of the 21 frames") as ended:
        while True:
            video.read()
            read += 1
    assert not isinstance(ended.value, EndOfFrames) and 0 < read < 21
    assert f"after {read} of the 21" in str(ended.value)
    video.close()


@pytest.mark.parametrize(
    ("read", "declared", "short"),
    [(9, 21, True), (19, 21, False), (18, 21, True), (950, 1000, False), (949, 1000, True), (5, None, False)],
)
def test_an_estimated_frame_count_a_few_frames_off_is_not_a_truncation(read, declared, short):
    from nlipscalib.device.camera import cut_short

    assert cut_short(read, declared) is short


class FakeCap:
    """A camera that accepts some properties and ignores or clamps others."""

    def __init__(self, refuses):
        self.props, self.refuses = {}, refuses

    def getBackendName(self):
        return "V4L2"

    def set(self, prop, value):
        if prop in self.refuses:
            return self.refuses[prop] is not None and not self.props.setdefault(prop, self.refuses[prop])
        self.props[prop] = value
        return True

    def get(self, prop):
        return self.props.get(prop, self.refuses.get(prop) or 0.0)


def test_settings_are_read_back_and_refusals_reported():
    cap = FakeCap({cv2.CAP_PROP_AUTO_WB: None, cv2.CAP_PROP_EXPOSURE: 156.0})  # WB ignored, exposure clamped
    refused = apply_settings(cap, CameraSettings(exposure_ms=20.0, gain=1.0, white_balance_k=4500))
    assert cap.props[cv2.CAP_PROP_BUFFERSIZE] == 1 and cap.props[cv2.CAP_PROP_AUTO_EXPOSURE] == 1
    assert cap.props[cv2.CAP_PROP_GAIN] == 1.0 and cap.props[cv2.CAP_PROP_WB_TEMPERATURE] == 4500
    assert len(refused) == 2
    assert any(r.startswith("auto white balance off") for r in refused)
    assert any(r.startswith("exposure: asked 200") and "156" in r for r in refused)  # V4L2: 100 us units


@pytest.mark.parametrize("command", ["capture", "live"])
def test_a_camera_that_is_not_there_is_one_line_without_opencv_warnings(command, tmp_path, capfd):
    """OpenCV printed its own "[ WARN:0@0.02] global cap_v4l.cpp:915 open VIDEOIO(V4L2:/dev/video97): can't open
    camera by index" lines (two) before ours; and a file it cannot decode was called a busy camera."""
    from nlipscalib.cli import main
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(12)
    (tmp_path / "garbage.avi").write_text("not a video", encoding="utf-8")
    args = {
        "capture": ["capture", "--port", board.url, "--yes", "--out", str(tmp_path / "s"), "--camera"],
        "live": ["live", "--predictor", "tests.device.fakes:flat_predictor", "--no-window", "--camera"],
    }[command]
    assert main(args + ["97"]) == 2
    err = capfd.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips {command}: error: camera 97: no such camera ("), err
    assert "/dev/video97 does not exist" in err[0]
    assert main(args + [str(tmp_path / "garbage.avi")]) == 2
    err = capfd.readouterr().err.splitlines()
    assert err == [
        f"nlips {command}: error: {tmp_path / 'garbage.avi'}: OpenCV cannot read it as video or images (another "
        "kind of file, damaged, or a missing codec)"
    ]
    assert not (tmp_path / "s").exists()  # nothing captured


def test_opencv_is_silent_while_a_camera_opens_and_as_before_after(monkeypatch, caplog):
    """OpenCV 4.8 (the lowest supported) logs a missing camera index as an error of its own ("[ERROR:0@0.07] global
    obsensor_uvc_stream_channel.cpp:156 getStreamChannelGroup Camera index out of range"), which errors-only let
    through before our line: the open runs silent. With -v (DEBUG) OpenCV's lines stay, for a camera that will
    not open."""
    import logging

    from nlipscalib.device import camera

    opencv_log = getattr(getattr(cv2, "utils", None), "logging", None) or cv2  # 4.8: cv2.getLogLevel
    levels = []

    class NotThere:  # what OpenCV opens for a missing index, noting its log level as it logs
        def __init__(self, device):
            levels.append(opencv_log.getLogLevel())

        def isOpened(self):  # noqa: N802 - OpenCV's name
            return False

    monkeypatch.setattr(cv2, "VideoCapture", NotThere)
    before = opencv_log.getLogLevel()
    for verbose, expected in ((False, camera.OPENCV_SILENT), (True, before)):
        caplog.set_level(logging.DEBUG if verbose else logging.INFO, logger=camera.__name__)
        with pytest.raises(CaptureError, match="camera 97: no such camera"):
            camera.open_source("97")
        assert levels[-1] == expected and opencv_log.getLogLevel() == before, verbose


def test_a_file_opencv_opens_but_gives_no_frame_is_named_unreadable(tmp_path):
    """A file with an image's name but not an image: OpenCV opens it, then gives no frame; that was called
    "camera FILE: no frame (end of file)". In its own process: FFmpeg's log level (which keeps its "Invalid PNG
    signature" line off stderr) is read once, when a process first loads FFmpeg, perhaps by an earlier test here."""
    import subprocess
    import sys
    from pathlib import Path

    fake = tmp_path / "fake.png"
    fake.write_text("not an image", encoding="utf-8")
    argv = ["live", "--predictor", "tests.device.fakes:flat_predictor", "--no-window", "--camera", str(fake)]
    root = Path(__file__).resolve().parents[2]
    done = subprocess.run([sys.executable, "-m", "nlipscalib", *argv], capture_output=True, text=True, cwd=root)
    assert done.returncode == 2
    assert done.stderr.splitlines() == [
        f"nlips live: error: {fake}: OpenCV cannot read it as video or images (another kind of file, damaged, or "
        "a missing codec)"
    ]


def test_gamma_is_asked_linear_and_a_refusal_names_the_declaration():
    """Many UVC webcams cannot switch gamma off: the capture asks for gamma 1.0 (UVC hundredths) and says when the
    camera keeps its own; with a declared tone curve (``--camera-response srgb``) the camera's gamma is left alone."""
    from nlipscalib.device.camera import UVC_LINEAR_GAMMA, reported_gamma

    cap = FakeCap({})
    assert apply_settings(cap, CameraSettings()) == [] and cap.props[cv2.CAP_PROP_GAMMA] == UVC_LINEAR_GAMMA == 100
    assert reported_gamma(cap) == 100.0

    stuck = FakeCap({cv2.CAP_PROP_GAMMA: 300.0})  # the camera keeps its gamma 3.0
    refused = apply_settings(stuck, CameraSettings())
    assert refused == ["gamma 1.0 (linear; else declare --camera-response srgb): asked 100, camera reports 300"]

    declared = FakeCap({})
    assert apply_settings(declared, CameraSettings(linear_gamma=False)) == []
    assert cv2.CAP_PROP_GAMMA not in declared.props and reported_gamma(declared) is None  # no control: None


def test_a_camera_without_a_gamma_control_is_said_so_once_per_camera_and_session(caplog, tmp_path):
    """A webcam without a gamma control read "camera refused: gamma 1.0 ...: asked 100, camera reports 0" at every
    capture (and twice: the source's warning and the capture's line). Now its own line, said once per camera in a
    process, and not again when a resumed session recorded it in its captures."""
    import json
    import logging

    from nlipscalib.cli.capture import _session_refusals
    from nlipscalib.device.camera import NO_GAMMA_CONTROL, report_refusals

    none = FakeCap({cv2.CAP_PROP_GAMMA: None})  # set() refused, get() 0: OpenCV's answer for a missing control
    assert apply_settings(none, CameraSettings()) == [NO_GAMMA_CONTROL]
    assert "no gamma control" in NO_GAMMA_CONTROL and "--camera-response srgb" in NO_GAMMA_CONTROL

    caplog.set_level(logging.WARNING, logger="nlipscalib.device.camera")
    for _ in range(3):
        report_refusals("/dev/video-test-7", [NO_GAMMA_CONTROL])
    said = [r.getMessage() for r in caplog.records]
    assert said == [f"camera /dev/video-test-7 refused {NO_GAMMA_CONTROL}"]
    report_refusals("/dev/video-test-8", [NO_GAMMA_CONTROL], reported=[NO_GAMMA_CONTROL])  # the session said it
    assert len(caplog.records) == 1

    from tests.solver import synth

    session = tmp_path / "session"
    synth.make_press(session / "reference", kind="none", size=(32, 24))  # a whole press folder: meta.json is read
    meta_path = session / "reference" / "meta.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta["provenance"] = {"device": {"camera": "3"}, "camera_refused": [NO_GAMMA_CONTROL]}  # as a capture records it
    meta_path.write_text(json.dumps(meta), encoding="utf-8")
    assert _session_refusals(str(session), "3") == (NO_GAMMA_CONTROL,)
    assert _session_refusals(str(session), "4") == ()  # another camera: its refusals are its own
    assert _session_refusals(str(tmp_path / "new"), "3") == ()


@pytest.mark.parametrize("response", ["linear", "srgb"])
def test_a_stream_asks_for_gamma_1_only_for_a_linear_model(monkeypatch, response):
    """An sRGB model was calibrated on frames with the camera's curve on, and undoes it on the stream's frames:
    its stream leaves the camera's gamma as it is, a linear model's asks for 1.0."""
    import argparse
    import contextlib

    from nlipscalib.cli._stream import open_frames
    from nlipscalib.device import camera

    asked = []

    def opened(spec, settings, tone_curve=None):
        asked.append(settings)
        return contextlib.nullcontext()

    monkeypatch.setattr(camera, "open_source", opened)
    args = argparse.Namespace(emulate=None, camera="0", port=None, exposure_ms=10.0)
    with contextlib.ExitStack() as stack:
        open_frames(args, stack, camera_response=response)
    assert [s.linear_gamma for s in asked] == [response == "linear"]


def test_an_eight_bit_frames_curve_is_undone_in_one_lookup_bit_for_bit():
    """``to_stored`` with a tone curve: an 8-bit frame's shift and curve in one 256-entry lookup give, for every
    value, what the 65536-entry table gives on the shifted frame, which is the exact inverse sRGB curve rounded to
    whole 16-bit steps; a 16-bit frame gets the table itself; grey and BGRA frames as before, and the caller's frame
    untouched."""
    from nlipscalib.core.sensor_response import eight_bit_table, srgb_to_linear, tone_curve_table, undo_tone_curve
    from nlipscalib.device.camera import to_stored

    black, white = 512.0, 65280.0
    table = tone_curve_table("srgb", black, white)
    values = np.arange(256, dtype=np.uint16) << 8
    exact = black + (white - black) * srgb_to_linear((values - black) / (white - black))
    exact = np.where(values >= white, values, exact)
    assert np.array_equal(eight_bit_table(table), np.clip(np.rint(exact), 0, 65535).astype(np.uint16))
    assert np.array_equal(eight_bit_table(None), values)

    rng = np.random.default_rng(3)
    bgr = rng.integers(0, 256, (6, 256, 3), dtype=np.uint8)
    bgr[0, :, 0] = np.arange(256, dtype=np.uint8)  # every value
    for frame in (bgr, bgr[..., 0], np.dstack([bgr, bgr[..., :1]]), bgr[::-1, ::2]):
        given = frame.copy()
        shifted, bits = to_stored(frame)
        undone, bits_undone = to_stored(frame, tone_curve=table)
        assert bits == bits_undone == 8 and undone.dtype == np.uint16 and undone.shape == shifted.shape
        assert np.array_equal(undone, undo_tone_curve(shifted.copy(), table))
        assert np.array_equal(frame, given)
    deep = rng.integers(0, 65536, (6, 256, 3), dtype=np.uint16)
    undone, bits = to_stored(deep, tone_curve=table)
    assert bits == 16 and np.array_equal(undone, table[deep[..., ::-1]])
    assert np.array_equal(to_stored(deep)[0], deep[..., ::-1])
    for shape in ((6, 8, 1), (6, 8, 2), (6,)):  # refused as before (OpenCV's grey is (H, W))
        with pytest.raises(CaptureError, match=r"unsupported image shape"):
            to_stored(np.zeros(shape, np.uint8), tone_curve=table)


@pytest.mark.parametrize("exposure_ms", [0.0, -1.0, float("nan")])
def test_camera_settings_refuse_an_exposure_that_is_not_positive(exposure_ms):
    """`CameraSettings(exposure_ms=-1)` was taken and sent to the camera's driver as it was (the commands check their
    option; a script's settings were not)."""
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.device.camera import CameraSettings

    with pytest.raises(ConfigError, match="camera settings need exposure_ms > 0"):
        CameraSettings(exposure_ms=exposure_ms)
    assert CameraSettings(exposure_ms=None).exposure_ms is None  # the camera's own
