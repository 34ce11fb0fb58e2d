"""Live streaming: frames through a pluggable predictor into sinks; frame rate; saved maps."""

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.device.camera import FolderSource, FrameSource, SequenceSource  # noqa: E402
from nlipscalib.device.live import ReadAhead, StopLive, stream  # noqa: E402

from .fakes import flat_predictor  # noqa: E402


@pytest.fixture
def frames(tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(5):
        cv2.imwrite(str(folder / f"f{k:02d}.png"), np.full((12, 16, 3), 1000 * (k + 1), np.uint16))
    return folder


def test_stream_runs_every_frame_until_the_input_ends(frames):
    seen = []
    stats = stream(FolderSource(frames), flat_predictor((12, 16)), [lambda i, f, r: seen.append(r.depth[0, 0])])
    assert stats.frames == 5 and stats.fps > 0
    np.testing.assert_allclose(seen, [1, 2, 3, 4, 5])
    assert "5 frames" in stats.summary()
    # named for what they time: a video has no camera, and infer's "network" stage is a part of the predictor's call
    assert "(per frame: read " in stats.summary() and ", predictor " in stats.summary()


def test_stream_stops_at_max_frames_or_when_a_sink_says_so(frames):
    assert stream(FolderSource(frames), flat_predictor((12, 16)), [], max_frames=2, report=None).frames == 2

    def stop_at_third(i, frame, result):
        if i == 2:
            raise StopLive

    assert stream(FolderSource(frames), flat_predictor((12, 16)), [stop_at_third], report=None).frames == 2


def test_stream_asks_stop_before_each_frame_and_finishes_the_frame_under_way(frames):
    """``stop`` (the CLI's SIGTERM flag) is read before a frame, never inside one: the frame under way reaches every
    sink, the next is not read."""
    seen, stop_now = [], []

    def sink(i, frame, result):
        seen.append(i)
        if i == 1:
            stop_now.append(True)  # as if SIGTERM came while frame 1 was inferred

    stats = stream(FolderSource(frames), flat_predictor((12, 16)), [sink], report=None, stop=lambda: bool(stop_now))
    assert stats.frames == 2 and seen == [0, 1]


def test_each_frames_steps_cover_its_whole_loop_step_the_press_change_and_the_rate_line_included(frames):
    """The emulator's change of press before each read, and the running rate's line, ran outside the timed steps;
    each is made slow (a sleep) here: read and output count them, and the steps add up to no more than the wall."""
    import time

    predict = flat_predictor((12, 16))
    stats = stream(
        FolderSource(frames),
        predict,
        [],
        max_frames=3,
        before_frame=lambda index: time.sleep(0.02),
        report=lambda line: time.sleep(0.02),
        report_every_s=0.0,
    )
    assert stats.frames == 3
    assert stats.read_s >= 3 * 0.02 and stats.output_s >= 3 * 0.02  # a sleep is never shorter than asked
    assert stats.read_s + stats.predict_s + stats.output_s <= stats.seconds


def test_read_ahead_gives_the_same_frames_in_order_and_ends_with_the_source(frames):
    seen = []
    with ReadAhead(FolderSource(frames)) as source:
        assert source.shape == (12, 16)
        stats = stream(source, flat_predictor((12, 16)), [lambda i, f, r: seen.append(r.depth[0, 0])], report=None)
    assert stats.frames == 5
    np.testing.assert_allclose(seen, [1, 2, 3, 4, 5])


def test_read_ahead_decodes_the_next_frame_while_the_caller_works():
    import threading

    class Counting:
        shape = (12, 16)

        def __init__(self):
            self.reads = 0
            self.second = threading.Event()

        def read(self):
            self.reads += 1
            if self.reads == 2:
                self.second.set()
            return self.reads

    src = Counting()
    with ReadAhead(src) as ahead:
        assert ahead.read() == 1
        # the caller has not asked for frame 2 yet, but the worker reads it now (and nothing beyond it)
        assert src.second.wait(timeout=30)
        assert src.reads == 2
        assert ahead.read() == 2


def test_read_ahead_decodes_image_files_on_several_threads_in_order(tmp_path):
    import threading

    for k in range(9):
        cv2.imwrite(str(tmp_path / f"img_{k:04d}.png"), np.full((12, 16, 3), 1000 * (k + 1), np.uint16))
    (tmp_path / "img_0006.png").write_bytes(b"damaged")  # the stream must end there, after frames 0-5

    class Watched(SequenceSource):
        def __init__(self, pattern):
            super().__init__(pattern)
            self.threads, self.lock = set(), threading.Lock()
            self.both = threading.Barrier(2, timeout=30)

        def frame_at(self, index):
            with self.lock:
                self.threads.add(threading.get_ident())
            if index < 2:  # frames 0 and 1 each wait for the other: only two threads decoding at once pass
                self.both.wait()
            return super().frame_at(index)

    src = Watched(str(tmp_path / "img_%04d.png"))
    seen = []
    with ReadAhead(src, workers=3) as ahead:
        with pytest.raises(CaptureError, match="img_0006.png: not a readable image"):
            while True:
                seen.append(int(ahead.read()[0, 0, 0]))
    assert seen == [1000 * (k + 1) for k in range(6)]
    assert len(src.threads) >= 2


def test_live_cli_saves_maps_with_a_plugged_predictor(frames, tmp_path, capsys):
    out = tmp_path / "maps"
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor"]
    assert main(args + ["--out", str(out), "--every", "2", "--no-window"]) == 0
    said = capsys.readouterr()  # stdout: the maps' folder alone (as `nlips infer`); the rates and where, on stderr
    assert said.out == f"{out}\n"
    printed = said.err
    assert "5 frames in" in printed and f"saved: 3 of 5 frames' normals and depth in {out} " in printed
    assert sorted(p.name for p in out.iterdir()) == [
        f"frame_{k:06d}{ext}" for k in (0, 2, 4) for ext in (".npz", "_normals.png")
    ]
    saved = np.load(out / "frame_000002.npz")
    assert saved["depth"][0, 0] == pytest.approx(3.0) and saved["normals"][0, 0, 2] == -1
    normals_png = cv2.imread(str(out / "frame_000000_normals.png"))
    assert tuple(normals_png[0, 0]) == (255, 127, 127)  # BGR of the camera-facing blue
    assert main(["live", "--camera", str(frames)]) == 2  # no predictor: one clear error


def test_live_quiet_prints_its_folder_alone(frames, tmp_path, capsys):
    """`nlips live --out DIR` printed its frame rates and where the maps went on stdout; now stdout is DIR alone (as
    `nlips infer`'s stream), and --quiet leaves those lines out of stderr."""
    out = tmp_path / "maps"
    args = ["-q", "live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*args, "--out", str(out)]) == 0
    assert capsys.readouterr() == (f"{out}\n", "")
    assert len(list(out.glob("*.npz"))) == 5


def test_live_takes_infers_names_for_its_output_and_frame_limit_and_its_own_as_aliases(frames, tmp_path, capsys):
    """`nlips live` had --save DIR / --frames N where `nlips infer` (and every other command, for --out) has
    --out DIR / --max-frames N; the old names stay accepted, and the help says which is which."""
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    for out_flag, limit_flag in (("--out", "--max-frames"), ("--save", "--frames")):
        out = tmp_path / out_flag.strip("-")
        assert main([*args, out_flag, str(out), limit_flag, "2"]) == 0
        assert "2 frames in" in capsys.readouterr().err
        assert sorted(p.name for p in out.glob("*.npz")) == ["frame_000000.npz", "frame_000001.npz"]
    live, infer = _help("live", capsys), _help("infer", capsys)
    assert "--max-frames N, --frames N" in live and "--frames: its former name" in live
    assert "--out DIR, --save DIR" in live and "--save: its former name" in live
    assert "--max-frames" in infer and "--out" in infer and "--save" not in infer


def test_live_names_a_file_given_for_its_folder_with_out_either_way(frames, tmp_path, capsys):
    """`nlips live --save FILE` said "FILE: File exists"; the remedy names --out, the option's name now."""
    a_file = tmp_path / "a file"
    a_file.write_text("notes", encoding="utf-8")
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    for flag in ("--out", "--save"):
        assert main([*args, flag, str(a_file)]) == 2
        line = _one_line(capsys.readouterr().err)
        assert line.endswith(f"{a_file}: a file where a folder is needed (choose another --out, or move the file)")


def _help(command: str, capsys) -> str:
    with pytest.raises(SystemExit):
        main([command, "--help"])
    return " ".join(capsys.readouterr().out.split())


def _one_line(err: str, *needles: str) -> str:
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize(
    "spec, problem",
    [
        ("os:getcwd", "camera shape"),  # takes no argument
        ("os:sep", "not callable"),  # a string
        ("builtins:str", "not a callable"),  # returns a string
        ("tests.device.fakes:two_argument_predictor", "failed on a frame"),
        ("tests.device.fakes:tuple_predictor", "not a LiveResult"),
    ],
)
def test_live_names_a_predictor_that_cannot_predict(frames, tmp_path, capsys, spec, problem):
    args = ["live", "--camera", str(frames), "--predictor", spec, "--max-frames", "1", "--no-window"]
    assert main([*args, "--out", str(tmp_path / "maps")]) == 2
    _one_line(capsys.readouterr().err, f"--predictor {spec}", problem)
    assert not list((tmp_path / "maps").glob("frame_*"))


def test_live_without_a_window_nor_save_says_why_nothing_is_shown(frames, capsys):
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--max-frames", "1"]
    assert main([*args, "--no-window"]) == 0
    err = capsys.readouterr().err
    assert "--no-window: maps are not shown; use --out DIR" in err and "no display" not in err  # it said no display


@pytest.mark.parametrize(
    "option", [("--every", "0"), ("--threads", "-1"), ("--max-frames", "0"), ("--frames-per-press", "0")]
)
def test_live_refuses_out_of_range_options_before_streaming(frames, tmp_path, capsys, option):
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*args, "--out", str(tmp_path / "maps"), *option]) == 2
    _one_line(capsys.readouterr().err, option[0])
    assert not (tmp_path / "maps").exists()  # refused before anything was written


@pytest.mark.parametrize(
    "command, option, message",
    [
        # flags of a camera stream with --emulate, typed at their default values too
        (["live"], ("--tricolor-level", "255"), "--tricolor-level is not used with --emulate"),
        (["live"], ("--exposure-ms", "10"), "--exposure-ms is not used with --emulate"),
        (["live"], ("--camera", "0"), "--camera is not used with --emulate"),
        (["live"], ("--port", "loop://"), "--port is not used with --emulate"),
        (["infer", "model.pt"], ("--tricolor-level", "255"), "--tricolor-level is not used with --emulate"),
        (["live"], ("--frames-per-press", "0"), "--frames-per-press: must be an integer >= 1"),
    ],
)
def test_stream_flags_the_emulated_sensor_does_not_use_are_refused(tmp_path, capsys, command, option, message):
    args = [*command, "--emulate", "nlipstac", "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    if command[0] == "infer":
        args = [*command, "--emulate", "nlipstac"]
    assert main([*args, *option]) == 2
    _one_line(capsys.readouterr().err, message)


def test_stream_flags_refused_with_an_emulated_port_name_the_port(capsys):
    args = ["live", "--port", "nlipsemu://live-flags", "--predictor", "tests.device.fakes:flat_predictor"]
    assert main([*args, "--no-window", "--exposure-ms", "10"]) == 2
    _one_line(capsys.readouterr().err, "--exposure-ms is not used with --port nlipsemu://live-flags and no --camera")


@pytest.mark.parametrize(
    "option, message",
    [
        (("--tricolor-level", "100"), "--tricolor-level describes the LED board: give its --port too"),
        (("--exposure-ms", "5"), "--exposure-ms sets a live camera's exposure"),
    ],
)
def test_camera_flags_a_recording_does_not_use_are_refused(frames, tmp_path, capsys, option, message):
    """A folder of recorded frames has no exposure to set and no board to light: the flags did nothing, unsaid."""
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*args, *option]) == 2
    _one_line(capsys.readouterr().err, message)


def test_every_without_a_folder_to_save_in_is_warned_about(frames, capsys, caplog):
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*args, "--every", "2", "--max-frames", "2"]) == 0
    assert "--every without an output folder" in caplog.text


@pytest.mark.parametrize("option", [("--frames-per-press", "10"), ("--script", "s.toml"), ("--width", "64")])
def test_emulated_stream_flags_are_refused_without_emulate(frames, tmp_path, capsys, option):
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*args, "--out", str(tmp_path / "maps"), *option]) == 2
    _one_line(capsys.readouterr().err, f"{option[0]} is only used with --emulate SCENE")
    assert not (tmp_path / "maps").exists()
    assert main(["infer", "model.pt", str(frames), *option]) == 2
    _one_line(capsys.readouterr().err, f"{option[0]} is only used with --emulate SCENE")


def test_live_lights_the_led_board_at_the_rate_of_baud(frames, capsys):
    """--baud reaches the LED port of a stream (nlips infer --port opens it the same way): a board at 57600 baud
    is lit and switched off at the end; at the default rate the stream stops before its first frame, in one line."""
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(12, baudrate=57600)
    args = ["live", "--camera", str(frames), "--port", board.url, "--predictor", "tests.device.fakes:flat_predictor"]
    args += ["--no-window", "--max-frames", "1"]
    assert main([*args, "--baud", "57600"]) == 0
    assert [body.split(" ")[1] for body in board.executed] == ["HELLO", "ALL", "OFF"]  # lit, then dark at the end
    capsys.readouterr()
    assert main(args) == 2
    _one_line(capsys.readouterr().err, f"{board.url}: no answer to HELLO", "The port is at 115200 baud")
    assert len(board.executed) == 3


FLAT = "tests.device.fakes:flat_predictor"


@pytest.mark.parametrize(
    "args, message",
    [
        (["live", "--camera", "{frames}", "--predictor", FLAT, "--baud", "9600"], "give its --port too"),
        (["infer", "model.pt", "--camera", "{frames}", "--baud", "9600"], "--baud describes the LED board"),
        (["infer", "model.pt", "--camera", "0", "--port", "loop://", "--baud", "1234"], "--baud: must be a standard"),
        (["live", "--emulate", "nlipstac", "--predictor", FLAT, "--baud", "9600"], "--baud is not used with --emulate"),
        (["infer", "model.pt", "{frames}", "--port", "loop://"], "--port is not used with press folders or image"),
        (["infer", "model.pt", "{frames}", "--adalight", "12"], "--adalight is not used with press folders or image"),
    ],
)
def test_a_baud_rate_without_a_board_or_off_the_standard_set_is_one_line(frames, capsys, args, message):
    assert main([a.format(frames=frames) for a in args] + (["--no-window"] if args[0] == "live" else [])) == 2
    _one_line(capsys.readouterr().err, message)


def test_a_damaged_frame_ends_a_stream_with_its_error_the_end_of_the_input_cleanly(frames):
    (frames / "f02.png").write_bytes(b"damaged")
    seen = []
    with pytest.raises(CaptureError, match="f02.png: not a readable image"):
        stream(FolderSource(frames), flat_predictor((12, 16)), [lambda i, f, r: seen.append(i)], report=None)
    assert seen == [0, 1]


def test_a_frame_of_another_size_is_named_in_width_x_height(frames, tmp_path, capsys):
    """`frames/f04.png: size (24, 32) differs from (12, 16)` gave numpy (H, W) tuples; infer says "image is WxH"."""
    cv2.imwrite(str(frames / "f03.png"), np.full((24, 32, 3), 1000, np.uint16))
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main(args) == 2
    err = capsys.readouterr().err.splitlines()[-1]
    assert (
        err == f"nlips live: error: {frames / 'f03.png'}: image is 32x24, the stream's first frame (f00.png) is 16x12"
    )


def test_live_names_an_opencv_without_a_gui_not_a_missing_display(frames, capsys, monkeypatch):
    # opencv-python-headless on a desktop: a display is there, OpenCV cannot open a window (it said "no display")
    def no_gui(*args):
        raise cv2.error("The function is not implemented")

    monkeypatch.setenv("DISPLAY", ":0")
    monkeypatch.setattr(cv2, "namedWindow", no_gui)
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--max-frames", "1"]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "this OpenCV has no GUI (opencv-python-headless): maps are not shown" in err and "no display" not in err


def _reports(monkeypatch) -> list:
    """The ``report`` each stream of ``nlips live`` is given (None: quiet)."""
    import nlipscalib.device.live as live

    given, real = [], live.stream

    def recording(*args, **kwargs):
        given.append(kwargs.get("report"))
        return real(*args, **kwargs)

    monkeypatch.setattr(live, "stream", recording)
    return given


@pytest.mark.parametrize(
    "terminal, flags, shown", [(False, [], False), (True, [], True), (True, ["--no-progress"], False)]
)
def test_live_prints_its_running_frame_rate_on_a_terminal_only(frames, monkeypatch, terminal, flags, shown):
    # a "27.1 fps" line every second went into logs and pipes, and --no-progress did not quiet it
    import sys

    given = _reports(monkeypatch)
    monkeypatch.setattr(sys.stderr, "isatty", lambda: terminal)
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*flags, *args]) == 0
    assert len(given) == 1 and (given[0] is not None) == shown


def test_live_help_says_a_window_needs_an_opencv_with_a_gui(capsys):
    # the package installs opencv-python-headless: "shown in a window" never happened on an ordinary install
    assert "with an OpenCV built with a GUI: opencv-python in place of the opencv-python-headless" in _help(
        "live", capsys
    )


@pytest.mark.parametrize(
    ("predictor", "flag", "gamma_1", "said"),
    [
        ("flat_predictor", [], True, True),
        ("srgb_predictor", [], False, False),
        ("flat_predictor", ["--camera-response", "srgb"], False, False),
        ("srgb_predictor", ["--camera-response", "srgb"], False, False),
        ("flat_predictor", ["--camera-response", "linear"], True, False),
    ],
)
def test_a_plugged_predictor_streams_a_camera_with_the_response_it_declares(
    frames, monkeypatch, caplog, predictor, flag, gamma_1, said
):
    """`nlips live --predictor` asked every camera for gamma 1.0 (a plugged predictor has no model file to record
    its calibration's camera response): the function's ``camera_response``, or ``--camera-response``, is honoured
    (sRGB: the camera's curve left on); with neither, linear as before, said once."""
    import logging

    from nlipscalib.device import camera

    asked = []

    def opened(spec, settings, tone_curve=None):
        asked.append((spec, settings.linear_gamma, tone_curve))
        return FolderSource(frames)  # stands in for camera 0

    monkeypatch.setattr(camera, "open_source", opened)
    argv = ["live", "--camera", "0", "--predictor", f"tests.device.fakes:{predictor}", "--no-window"]
    with caplog.at_level(logging.INFO, logger="nlipscalib.cli.live"):
        assert main([*argv, *flag, "--max-frames", "2"]) == 0
    assert asked == [("0", gamma_1, None)]  # the frames as the camera encodes them: the predictor's to undo
    lines = [r.getMessage() for r in caplog.records if "declares no camera response" in r.getMessage()]
    assert len(lines) == (1 if said else 0) and all("gamma 1.0" in line for line in lines)


def test_a_declared_response_that_is_unknown_or_contradicted_is_one_line(frames, capsys):
    argv = ["live", "--camera", str(frames), "--no-window", "--max-frames", "1", "--predictor"]
    assert main([*argv, "tests.device.fakes:gamma_predictor"]) == 2
    assert "camera_response must be one of 'linear', 'srgb', got 'gamma 2.2'" in capsys.readouterr().err
    assert main([*argv, "tests.device.fakes:srgb_predictor", "--camera-response", "linear"]) == 2
    assert "declares camera_response 'srgb'; drop --camera-response" in capsys.readouterr().err
    model = ["live", "--camera", str(frames), "--model", "m.pt", "--camera-response", "srgb"]
    assert main(model) == 2 and "--camera-response is for --predictor" in capsys.readouterr().err
    emulated = ["live", "--emulate", "nlipstac", "--predictor", "tests.device.fakes:srgb_predictor", "--no-window"]
    assert main(emulated) == 2 and "the emulated sensor's frames are linear" in capsys.readouterr().err


def test_a_plugged_predictor_may_name_a_measured_response_file(frames, monkeypatch, tmp_path, capsys):
    """`--camera-response FILE` (`nlips calibrate-camera-response`): the camera keeps its curve (no gamma 1.0 asked)
    and the predictor gets the frames as encoded, as with srgb; a damaged file is one line naming it."""
    from nlipscalib.core.response_curve import MeasuredResponse, write_response_file
    from nlipscalib.device import camera

    asked = []

    def opened(spec, settings, tone_curve=None):
        asked.append((settings.linear_gamma, tone_curve))
        return FolderSource(frames)  # stands in for camera 0

    monkeypatch.setattr(camera, "open_source", opened)
    curve = tuple(float(v) for v in np.linspace(0, 1, 256) ** 2.2)
    path = write_response_file(tmp_path / "curve.json", MeasuredResponse(curve, {}))
    argv = ["live", "--camera", "0", "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    assert main([*argv, "--camera-response", str(path), "--max-frames", "2"]) == 0
    assert asked == [(False, None)]
    capsys.readouterr()
    (tmp_path / "bad.json").write_text("{", encoding="utf-8")
    assert main([*argv, "--camera-response", str(tmp_path / "bad.json"), "--max-frames", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{tmp_path / 'bad.json'}: not valid JSON" in err[0], err


def test_live_into_a_folder_of_an_earlier_runs_frames_warns_that_they_may_mix(frames, tmp_path, capsys, caplog):
    """`nlips live --out DIR` (after an upgrade, or with another model) replaced the frames it wrote and left an
    earlier, longer run's others beside them without a word: one folder of two runs' maps."""
    import logging

    out = tmp_path / "maps"
    args = ["live", "--camera", str(frames), "--predictor", "tests.device.fakes:flat_predictor", "--no-window"]
    with caplog.at_level(logging.WARNING):
        assert main([*args, "--out", str(out)]) == 0
        assert not [r for r in caplog.records if "earlier run" in r.getMessage()]  # a new folder: nothing to say
        assert main([*args, "--out", str(out), "--max-frames", "2"]) == 0
    warned = [r.getMessage() for r in caplog.records if "earlier run" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{out}: holds 5 frame(s) an earlier run saved"), warned
    assert "frame_000000.npz" in warned[0] and "another --out" in warned[0]


def test_a_second_stream_into_the_folder_a_live_stream_saves_into_is_refused(frames, tmp_path, capsys, monkeypatch):
    """Two streams into one --out (`nlips live`, `nlips infer` of a video or camera) both exited 0, each replacing the
    other's frame_NNNNNN files and saying "saved: N of N frames": a folder of two streams' frames. Now a stream holds
    its folder from start to end (core.claims.held_for, as `nlips solve` holds its results): a second one, a
    process of its own started while the first saves its frames, is refused in one line naming the folder and the
    first's process, and writes nothing; the first saves every frame. A killed stream's hold does not block."""
    import json
    import os

    from nlipscalib.core.claims import HOST

    from ..core.test_atomic import _dead_pid
    from . import fakes

    out = tmp_path / "maps"
    live = ["live", "--camera", str(frames), "--no-window", "--out", str(out)]
    monkeypatch.setattr(fakes, "SECOND_STREAM", {"argv": [*live, "--predictor", "tests.device.fakes:flat_predictor"]})
    assert main([*live, "--predictor", "tests.device.fakes:predictor_running_a_second_stream"]) == 0
    assert "saved: 5 of 5 frames" in capsys.readouterr().err
    lines = fakes.SECOND_STREAM["err"].strip().splitlines()
    assert fakes.SECOND_STREAM["code"] == 2 and len(lines) == 1, lines
    assert f"{out}: another run (nlips live, process {os.getpid()} on {HOST}) is saving into it" in lines[0]
    assert sorted(p.name for p in out.glob("*.npz")) == [f"frame_{k:06d}.npz" for k in range(5)]
    assert not list(tmp_path.glob(".claim-*"))

    killed = tmp_path / ".claim-maps~run~0123456789abcdef~k9"  # a stream killed while it saved
    killed.write_text(json.dumps({"host": HOST, "pid": _dead_pid(), "token": "k9"}), encoding="utf-8")
    assert main([*live, "--predictor", "tests.device.fakes:flat_predictor"]) == 0
    assert "saved: 5 of 5 frames" in capsys.readouterr().err and not killed.exists()


class _BufferedCamera(FrameSource):
    """A live camera (``live``) looking at a LED board: each frame's green value is the board's latched green sum,
    delivered two reads late (the frame grabbed at opening and the driver's buffered one), as a webcam's."""

    live = True
    flush_frames = 2

    def __init__(self, board):
        self.board = board
        self.pipeline = [self._exposed(), self._exposed()]  # exposed at opening: the LEDs not lit yet

    @property
    def shape(self):
        return (12, 16)

    def _exposed(self):
        return np.full((12, 16, 3), 10 * int(self.board.latched[:, 1].sum()), np.uint16)

    def read(self):
        self.pipeline.append(self._exposed())
        return self.pipeline.pop(0)


def test_a_live_cameras_stale_frames_from_before_the_leds_were_lit_are_not_streamed(tmp_path, monkeypatch, capsys):
    """`nlips live --camera 0 --port URL` (`nlips infer` too: the same cli._stream.open_frames) lit the tri-colour
    LEDs after opening the camera and streamed its first frames as they came: the frame grabbed at opening and the
    driver's buffered one, both exposed before the LEDs were lit (dark frames: the mismatch warning at frame 0 of
    every stream). They are flushed once."""
    from nlipscalib.device import camera
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(12)
    monkeypatch.setattr(camera, "open_source", lambda spec, settings, tone_curve=None: _BufferedCamera(board))
    maps = tmp_path / "maps"
    args = ["live", "--camera", "0", "--port", board.url, "--predictor", "tests.device.fakes:flat_predictor"]
    args += ["--no-window", "--max-frames", "3", "--save", str(maps)]
    assert main(args) == 0, capsys.readouterr().err
    depth = [float(np.load(f)["depth"].mean()) for f in sorted(maps.glob("frame_*.npz"))]
    assert len(depth) == 3 and min(depth) > 0, depth  # every frame lit
