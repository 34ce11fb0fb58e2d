"""`nlips capture --emulate`: the whole hardware path (virtual LED board, host driver, session) from the CLI."""

import json

import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import find_presses, load_press  # noqa: E402
from nlipscalib.sim.press import render_identity  # noqa: E402


def test_emulated_session_from_the_cli_resumes(tmp_path, capsys, caplog):
    args = ["capture", "--emulate", "nlipstac", "--width", "64", "--height", "48", "--spp", "1", "--out"]
    assert main(args + [str(tmp_path / "s"), "--presses", "1", "--move-press", "1"]) == 0
    said = capsys.readouterr()  # stdout: the session's folder alone (`session=$(nlips capture ...)`); the rest, stderr
    assert said.out == f"{tmp_path / 's'}\n"
    out = said.err
    assert "press_0001: captured" in out and "2 attempt(s)" in out
    # the press that moved is said once, by the operator's line (it was a WARNING log line too)
    assert sum("Press 1: the object moved" in line for line in out.splitlines()) == 1
    assert "pixels changed" not in caplog.text
    # the session's next steps, as `nlips calibrate` and `nlips train` end (an operator had to find them in the README)
    reference = tmp_path / "s" / "reference"
    assert out.splitlines()[-1] == (
        f"next: nlips calibrate-leds {reference} --out leds.json (the sensor's LEDs), then nlips calibrate "
        f"{tmp_path / 's'} --leds leds.json (NLiPsNet's training data)"
    )
    assert main(args + [str(tmp_path / "s"), "--presses", "2"]) == 0
    out = capsys.readouterr().err
    assert "reference: kept" in out and "press_0001: kept" in out and "press_0002: captured" in out
    presses = find_presses(tmp_path / "s")
    assert [p.name for p in presses] == ["press_0001", "press_0002", "reference"]
    p = load_press(presses[0])
    assert p.reference is not None and p.led_images.shape == (12, 48, 64, 3)
    assert p.meta["provenance"]["device"] == "emulator" and p.meta["provenance"]["attempts"] == 2
    # the twin that rendered it, as a rendered press records it: a resume after an upgrade tells (test_session.py)
    assert {k: p.meta["provenance"][k] for k in ("code", "libraries")} == render_identity()
    assert json.loads((tmp_path / "s" / "session.json").read_text(encoding="utf-8"))["n_leds"] == 12
    # run again with fewer --presses: press_0002 stays, and `nlips calibrate` of the folder takes it (s34-walk: this
    # run said "2 folders" and nothing of it)
    assert main(args + [str(tmp_path / "s"), "--presses", "1"]) == 0
    out = capsys.readouterr().err
    assert (
        "press_0002: " not in out
        and (
            f"{tmp_path / 's'}: press_0002, captured by an earlier run with more --presses, is kept: `nlips calibrate` "
            "and `nlips solve` of the folder still use it (remove it, or capture into a new folder)"
        )
        in out.splitlines()
    )


def test_an_emulated_session_resumed_with_another_tone_curve_is_one_line_exit_2(tmp_path, capsys):
    """Its frames were encoded with gamma 2.2; resumed without --emulate-tone-curve the new press's were linear,
    said nowhere. The refusal names the option and what to give; the session is left as it was."""
    args = ["capture", "--emulate", "nlipstac", "--width", "64", "--height", "48", "--spp", "1", "--yes"]
    out = tmp_path / "s"
    assert main([*args, "--out", str(out), "--presses", "0", "--emulate-tone-curve", "gamma2.2"]) == 0
    record = json.loads((out / "session.json").read_text(encoding="utf-8"))
    assert record["settings"]["emulated_tone_curve"] == "gamma2.2"
    capsys.readouterr()
    assert main([*args, "--out", str(out), "--presses", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--emulate-tone-curve gamma2.2 (this run: none)" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["reference", "session.json"]


def test_an_emulated_capture_into_a_folder_of_twin_renders_is_refused_before_it_renders(tmp_path, capsys, monkeypatch):
    """`nlips capture --emulate nlipstac --out RENDERS` (a folder of `nlips render` presses) kept the renders as
    captured presses; refused now, and before the emulator renders its script (the refusals of run_session came
    after 20 s of renders at 160x120)."""
    from nlipscalib import emulator
    from nlipscalib.core.press_meta import SOURCE_TWIN

    args = ["capture", "--emulate", "nlipstac", "--width", "64", "--height", "48", "--spp", "1", "--yes"]
    out = tmp_path / "s"
    assert main([*args, "--out", str(out), "--presses", "0"]) == 0
    (out / "session.json").unlink()  # a folder of renders has none
    meta = json.loads((out / "reference" / "meta.json").read_text(encoding="utf-8"))
    meta["provenance"]["source"] = SOURCE_TWIN
    (out / "reference" / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    capsys.readouterr()
    monkeypatch.setattr(emulator.EmulatedSensor, "prerender", lambda *a, **k: pytest.fail("rendered, then refused"))
    assert main([*args, "--out", str(out), "--presses", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{out / 'reference'}: a press rendered by the twin" in err[0], err
    assert sorted(p.name for p in out.iterdir()) == ["reference"]


def test_device_path_without_port_is_one_clear_error(tmp_path, capsys):
    assert main(["capture", "--out", str(tmp_path / "s")]) == 2
    assert "--port" in capsys.readouterr().err


def test_device_path_with_virtual_board_and_recorded_frames(tmp_path, capsys):
    """The real-sensor wiring: LED port, camera (a folder of frames), design, calibrated camera JSON."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2 * 15):  # reference + one press, 15 images each; the check frame repeats the first
        value = 100 + (k % 15) * (k % 15 != 14)
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), value, np.uint8))
    board = VirtualBoard(12)
    args = [
        "capture",
        "--port",
        board.url,
        "--camera",
        str(frames),
        "--design",
        "nlipstac",
        "--yes",
        "--black-level",
        "101",
    ]
    args += ["--camera-calibration", str(tmp_path / "camera.json"), "--presses", "1", "--out", str(tmp_path / "s")]
    assert main(args) == 0
    assert "press_0001: captured" in capsys.readouterr().err
    p = load_press(tmp_path / "s" / "press_0001")
    assert p.camera == camera and p.response.bit_depth == 8 and p.response.white_level == 255 << 8
    assert p.meta["provenance"]["device"]["firmware"] and np.isfinite(p.reference.depth).all()
    # frames 15..29 in capture order: tri-colour, dark, LED 1..12, check
    assert p.tricolor[0, 0, 0] == 100 << 8 and p.dark[0, 0, 0] == 101 << 8 and p.led_images[11, 0, 0, 0] == 113 << 8
    assert board.latched.sum() == 0
    # the design travels with the press: the interreflection term models the dome beyond the view from it
    from nlipscalib.solver.indirect import design_of

    dome, camera_position = design_of(p)
    assert dome.radius == 15.0 and camera_position.tolist() == [0.0, 0.0, -3.0]


def test_a_camera_response_declared_at_capture_is_recorded_and_undone_at_load(tmp_path, capsys):
    """`nlips capture --camera-response srgb`: meta.json records the curve (format_version 2) and what the camera
    reported for its gamma; the press loads linear in the light. The same frames undeclared load as stored."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.core.sensor_response import srgb_to_linear
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2 * 15):  # the dark frame at the black level, 0 (one above it is refused: a pedestal)
        value = 0 if k % 15 == 1 else 100 + (k % 15) * (k % 15 != 14)
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), value, np.uint8))
    for declared in ("srgb", None):
        board = VirtualBoard(12)
        out = tmp_path / f"s-{declared}"
        args = ["capture", "--port", board.url, "--camera", str(frames), "--design", "nlipstac", "--yes"]
        args += ["--camera-calibration", str(tmp_path / "camera.json"), "--presses", "1", "--out", str(out)]
        args += ["--camera-response", declared] if declared else []
        assert main(args) == 0, capsys.readouterr().err
        meta = json.loads((out / "press_0001" / "meta.json").read_text(encoding="utf-8"))
        p = load_press(out / "press_0001")
        assert "camera_gamma" in meta["provenance"] and meta["provenance"]["camera_gamma"] is None  # frames: none
        if declared:
            assert meta["format_version"] == 2 and meta["sensor"]["camera_response"] == "srgb"
            assert p.tricolor[0, 0, 0] == round(srgb_to_linear(100 / 255) * (255 << 8))
        else:
            assert meta["format_version"] == 1 and "camera_response" not in meta["sensor"]
            assert p.tricolor[0, 0, 0] == 100 << 8


def test_a_second_capture_into_a_session_being_captured_is_refused_before_it_captures(tmp_path, capsys):
    """Two captures started into one folder each captured what the other had not published yet: the session
    mixed both runs' presses under one reference, and the run that lost a press's rename failed with
    "FOLDER/press_0002: already exists". Now the folder is held by the capture writing it: another is one line
    naming the holder, before its sensor starts, and nothing is written; once the holder ends, a run captures."""
    import os

    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.core.claims import claim
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(2 * 15):
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), 100 + (k % 15) * (k % 15 != 14), np.uint8))
    board = VirtualBoard(12)
    out = tmp_path / "s"
    args = [
        "capture",
        "--port",
        board.url,
        "--camera",
        str(frames),
        "--design",
        "nlipstac",
        "--yes",
        "--black-level",
        "101",
        "--presses",
    ]
    args += ["1", "--camera-calibration", str(tmp_path / "camera.json"), "--out", str(out)]
    with claim(out) as held:  # the capture already at work there (this process: it is alive)
        assert held
        assert main(args) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{out}: another capture is writing this session (process {os.getpid()} on " in err[0]
        assert not out.exists() and board.latched.sum() == 0
    assert main(args) == 0
    assert "press_0001: captured" in capsys.readouterr().err
    assert sorted(p.name for p in out.iterdir()) == ["press_0001", "reference", "session.json"]
    assert not (tmp_path / ".claim-s").exists()  # released


@pytest.mark.parametrize(
    "extra, message",
    [
        (
            ["--emulate", "nlipstac", "--presses", "1", "--move-press", "5"],
            "--move-press must be a press of the session, 1..1 (--presses 1), got 5",
        ),
        (
            ["--emulate", "nlipstac", "--presses", "3", "--move-press", "0"],
            "--move-press must be a press of the session, 1..3",
        ),
        (["--emulate", "nlipstac", "--presses", "0", "--move-press", "1"], "the session has no press to move"),
        (["--emulate", "nlipstac", "--presses", "-1"], "--presses must be >= 0"),
        (["--emulate", "nlipstac", "--width", "4"], "--width must be 8..16384 pixels, got 4"),
        (["--emulate", "nlipstac", "--height", "0"], "--height must be 8..16384 pixels, got 0"),
        (["--emulate", "nlipstac", "--height", "120"], "--height 120 without --width: the images would be 640x120"),
        (["--port", "nlipsemu://7", "--width", "160"], "give both, e.g. --width 160 --height 120"),
        (["--emulate", "nlipstac", "--spp", "0"], "--spp must be >= 1"),
        (["--emulate", "nlipstac", "--seed", "-3"], "--seed must be >= 0"),
        (["--emulate", "nlipstac", "--flush", "-1"], "--flush must be >= 0"),
        (["--emulate", "nlipstac", "--max-retakes", "-1"], "--max-retakes must be >= 0"),
        (["--emulate", "nlipstac", "--tricolor-level", "0"], "--tricolor-level must be an LED drive 1..255, got 0"),
        (["--emulate", "nlipstac", "--tricolor-level", "256"], "--tricolor-level must be an LED drive 1..255"),
        (["--emulate", "nlipstac", "--movement-threshold", "0"], "--movement-threshold must be a fraction"),
        (["--emulate", "nlipstac", "--movement-threshold", "nan"], "--movement-threshold must be a fraction"),
        (["--port", "loop://", "--average", "0"], "--average must be >= 1"),
        (["--port", "loop://", "--adalight", "0"], "--adalight must be >= 1"),
        (["--port", "loop://", "--exposure-ms", "0"], "--exposure-ms must be > 0 ms"),
        (["--port", "loop://", "--white-balance", "-5"], "--white-balance must be > 0 kelvin"),
        (["--port", "loop://", "--gain", "-1"], "--gain must be >= 0"),
        (["--port", "loop://", "--black-level", "inf"], "--black-level must be >= 0"),
        (["--port", "loop://", "--baud", "0"], "--baud: must be a standard serial rate, one of 50, 75,"),
        (["--port", "loop://", "--baud", "250000"], "(the nlips LED firmware runs at 115200), got '250000'"),
    ],
)
def test_numeric_options_out_of_range_are_one_line(tmp_path, capsys, extra, message):
    assert main(["capture", "--out", str(tmp_path / "s"), *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips capture: error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "s").exists()  # refused before anything was captured


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--camera-calibration", "{cam}"], "--camera-calibration is not used with --emulate: the emulated camera"),
        (["--leds", "{leds}"], "--leds is not used with --emulate: the emulated LEDs"),
        (["--port", "loop://"], "--port is not used with --emulate"),
        (["--baud", "115200"], "--baud is not used with --emulate: the emulated sensor's virtual LED board is in"),
        (["--exposure-ms", "5"], "--exposure-ms is not used with --emulate"),
        (["--design", "fingertip"], "--design is not used with --emulate"),
        # typed at their default values: still given, still refused
        (["--exposure-ms", "10"], "--exposure-ms is not used with --emulate"),
        (["--camera", "0"], "--camera is not used with --emulate"),
        (["--gain", "0"], "--gain is not used with --emulate"),
        (["--white-balance", "5000"], "--white-balance is not used with --emulate"),
        (["--average", "1"], "--average is not used with --emulate"),
    ],
)
def test_real_sensor_options_are_refused_with_emulate(tmp_path, capsys, extra, message):
    """The emulated sensor is its scene file: a camera calibration or LED file (even garbage) is not ignored."""
    from nlipscalib.core import Camera

    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "cam.json").write_text("garbage{", encoding="utf-8")
    (bad / "leds_malformed.json").write_text('{"leds": "twelve"}', encoding="utf-8")
    extra = [a.format(cam=bad / "cam.json", leds=bad / "leds_malformed.json") for a in extra]
    out = ["--out", str(tmp_path / "s"), "--presses", "1"]
    assert main(["capture", "--emulate", "nlipstac", *out, *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    # a valid 320x240 calibration is refused just the same: the capture would come out in the scene's size
    good = tmp_path / "cam320.json"
    good.write_text(
        json.dumps({"camera": Camera.from_fov(320, 240, 100.0, "fisheye", (0.0,) * 4).to_dict()}), encoding="utf-8"
    )
    assert main(["capture", "--emulate", "nlipstac", *out, "--camera-calibration", str(good)]) == 2
    assert "--camera-calibration is not used with --emulate" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()


def test_emulator_options_are_refused_without_emulate(tmp_path, capsys):
    for extra in (["--move-press", "1"], ["--width", "64"], ["--script", "s.toml"], ["--spp", "4"], ["--seed", "0"]):
        assert main(["capture", "--port", "loop://", "--out", str(tmp_path / "s"), *extra]) == 2
        assert f"{extra[0]} is only used with --emulate SCENE" in capsys.readouterr().err


def test_script_and_move_press_or_other_press_count_are_refused(tmp_path, capsys):
    script = tmp_path / "script.toml"
    script.write_text(
        "[[press]]\npolar_deg = 10.0\ndepth = 1.0\n\n[[press]]\npolar_deg = 20.0\ndepth = 1.0\n", encoding="utf-8"
    )
    args = ["capture", "--emulate", "nlipstac", "--script", str(script), "--out", str(tmp_path / "s")]
    assert main(args + ["--move-press", "1"]) == 2
    assert "--move-press is not used with --script" in capsys.readouterr().err
    assert main(args + ["--presses", "3"]) == 2
    err = capsys.readouterr().err
    assert "--presses 3: the script" in err and "has 2 presses" in err
    # --presses typed at its default value (10) is given too, not taken for "no --presses"
    assert main(args + ["--presses", "10"]) == 2
    err = capsys.readouterr().err
    assert "--presses 10: the script" in err and "has 2 presses" in err and err.count("\n") == 1


SMALL = ["--width", "64", "--height", "48", "--spp", "1"]


def test_nlipsemu_port_from_a_fresh_process_captures_on_the_emulated_sensor(tmp_path):
    """The command as a user types it: no board exists in the new process, so the command starts the emulated
    sensor with its board at that URL; the capture validates with the loader."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    import numpy as np

    code = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    out = tmp_path / "s"
    result = subprocess.run(
        [sys.executable, "-c", code, "capture", "--port", "nlipsemu://1", *SMALL, "--presses", "1", "--out", str(out)],
        capture_output=True,
        text=True,
        stdin=subprocess.DEVNULL,  # no terminal: the session must not wait for Enter
        timeout=300,
        env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert result.returncode == 0, result.stderr
    assert "nlipsemu://1: starting the emulated sensor of nlipstac" in result.stderr
    assert "Traceback" not in result.stderr and "press_0001: captured" in result.stderr
    p = load_press(out / "press_0001")
    assert p.led_images.shape == (12, 48, 64, 3) and p.reference is not None
    assert p.meta["provenance"]["device"] == "emulator"
    # each LED lights the gel: its image is brighter than the dark frame
    assert all(img.mean() > p.dark.mean() + 100 for img in p.led_images.astype(np.float64))


def test_nlipsemu_port_is_the_emulated_sensor_of_the_design(tmp_path, capsys):
    """In process with no board of that id: the same session as --emulate DESIGN (same frames, bit for bit),
    resumable, and the board is gone afterwards (the id is free again)."""
    import numpy as np

    from nlipscalib.device.virtual_board import find_board

    url = "nlipsemu://capture-cli"
    port = ["capture", "--port", url, "--design", "nlipstac", *SMALL, "--presses", "1"]
    assert main([*port, "--out", str(tmp_path / "port")]) == 0
    captured = capsys.readouterr()
    assert (
        captured.err.startswith(f"{url}: starting the emulated sensor of nlipstac")
        and captured.out == f"{tmp_path / 'port'}\n"
    )
    assert captured.err.count("starting the emulated sensor") == 1
    assert find_board(url) is None
    assert main(["capture", "--emulate", "nlipstac", *SMALL, "--presses", "1", "--out", str(tmp_path / "emu")]) == 0
    capsys.readouterr()
    a, b = load_press(tmp_path / "port" / "press_0001"), load_press(tmp_path / "emu" / "press_0001")
    np.testing.assert_array_equal(a.led_images, b.led_images)
    np.testing.assert_array_equal(a.tricolor, b.tricolor)
    assert a.camera == b.camera and a.leds == b.leds
    # run again with one press more: it resumes
    assert main([*port[:-1], "2", "--out", str(tmp_path / "port")]) == 0
    out = capsys.readouterr().err
    assert "press_0001: kept" in out and "press_0002: captured" in out
    assert [p.name for p in find_presses(tmp_path / "port")] == ["press_0001", "press_0002", "reference"]


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--port", "nlipsemu://"], "nlipsemu://: nlipsemu:// needs a board id"),
        (["--port", "nlipsemu://a/b"], "nlipsemu:// needs a board id without / or #"),
        (
            ["--port", "nlipsemu://3", "--exposure-ms", "5"],
            "--exposure-ms is not used with --port nlipsemu://3 and no --camera (the emulated sensor of nlipstac)",
        ),
        (["--port", "nlipsemu://3", "--camera-calibration", "cam.json"], "--camera-calibration is not used with"),
        (["--port", "nlipsemu://3", "--adalight", "12"], "virtual LED board runs the nlips firmware"),
        (["--port", "nlipsemu://3", "--design", "no-such-design"], "no-such-design"),
        (["--port", "/dev/ttyACM0", "--width", "64"], "--width is only used with --emulate SCENE"),
        (["--emulate", "nlipstac", "--camera", "0"], "--camera is not used with --emulate"),
    ],
)
def test_nlipsemu_port_mistakes_are_one_line(tmp_path, capsys, extra, message):
    assert main(["capture", "--out", str(tmp_path / "s"), "--presses", "1", *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips capture: error: ") and message in err and err.count("\n") == 1, err
    assert not (tmp_path / "s").exists()


def test_nlipsemu_port_with_a_camera_starts_the_board_alone(tmp_path, capsys):
    """--camera given: only the LED board is virtual (started with the design's LED count, closed after)."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import find_board

    camera = tmp_path / "camera.json"  # small frames
    camera.write_text(
        json.dumps({"camera": Camera.from_fov(64, 48, 100.0, "fisheye", (0.0,) * 4).to_dict()}), encoding="utf-8"
    )
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(15):  # the reference alone: tri-colour, dark, LED 1..12, check (= the first)
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), 50 + k * (k != 14), np.uint8))
    url = "nlipsemu://capture-board"
    args = [
        "capture",
        "--port",
        url,
        "--camera",
        str(frames),
        "--camera-calibration",
        str(camera),
        "--black-level",
        "51",
    ]
    assert main([*args, "--presses", "0", "--out", str(tmp_path / "s")]) == 0
    captured = capsys.readouterr()
    assert "reference: captured" in captured.err and "emulated" not in captured.err
    p = load_press(tmp_path / "s" / "reference")
    assert p.meta["provenance"]["device"]["port"] == url and p.led_images.shape[0] == 12
    assert p.dark[0, 0, 0] == 51 << 8 and p.led_images[11, 0, 0, 0] == 63 << 8
    assert find_board(url) is None


def test_capture_drives_the_led_board_at_the_rate_of_baud(tmp_path, capsys):
    """--baud reaches the LED port: a board whose firmware runs at 57600 baud captures the reference with --baud
    57600; at the default 115200 it reads no line and the capture stops in one line naming the rates."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = tmp_path / "camera.json"
    camera.write_text(
        json.dumps({"camera": Camera.from_fov(64, 48, 100.0, "fisheye", (0.0,) * 4).to_dict()}), encoding="utf-8"
    )
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(15):  # the reference alone: tri-colour, dark, LED 1..12, check (= the first)
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), 50 + k * (k != 14), np.uint8))
    board = VirtualBoard(12, baudrate=57600)
    args = [
        "capture",
        "--port",
        board.url,
        "--camera",
        str(frames),
        "--camera-calibration",
        str(camera),
        "--yes",
        "--black-level",
        "51",
    ]
    args += ["--presses", "0"]
    assert main([*args, "--out", str(tmp_path / "s"), "--baud", "57600"]) == 0
    assert "reference: captured" in capsys.readouterr().err
    assert load_press(tmp_path / "s" / "reference").led_images.shape[0] == 12
    assert main([*args, "--out", str(tmp_path / "t")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no answer to HELLO" in err and "The port is at 115200 baud" in err, err


def test_help_names_the_tricolor_level_an_emulated_session_records(capsys):
    """`--tricolor-level` said "(default 255)", but an --emulate session records the emulator's drive."""
    from nlipscalib.emulator import tricolor_level
    from nlipscalib.sim.press import scene_exposure
    from nlipscalib.sim.scene import load_scene

    with pytest.raises(SystemExit):
        main(["capture", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    scene = load_scene("nlipstac")
    renders = type("Renders", (), {"scene": scene, "exposure": scene_exposure(scene)})
    assert f"--emulate: the drive giving the scene's tri-colour exposure, nlipstac {tricolor_level(renders)})" in text
    assert "1-255 (default 255;" in text


@pytest.mark.parametrize("board_leds, design_leds", [(16, 12), (12, 16)])
def test_a_board_with_another_led_count_than_the_design_is_one_line_naming_both_ways_out(
    tmp_path, capsys, board_leds, design_leds
):
    """A 16-LED ring with the 12-LED firmware (or the reverse): refused before anything is captured, naming where
    the design's count comes from and the firmware build that matches it."""
    import cv2
    import numpy as np

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import VirtualBoard
    from nlipscalib.sim.scene import SCENES_DIR

    design = tmp_path / f"ring{design_leds}.toml"
    design.write_text(
        (SCENES_DIR / "nlipstac.toml").read_text(encoding="utf-8").replace("count = 12", f"count = {design_leds}"),
        encoding="utf-8",
    )
    camera = tmp_path / "camera.json"
    camera.write_text(
        json.dumps({"camera": Camera.from_fov(64, 48, 100.0, "fisheye", (0.0,) * 4).to_dict()}), encoding="utf-8"
    )
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in range(design_leds + 3):
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), 50 + k, np.uint8))
    board = VirtualBoard(board_leds)
    args = ["capture", "--port", board.url, "--camera", str(frames), "--camera-calibration", str(camera), "--yes"]
    assert main([*args, "--design", str(design), "--presses", "1", "--out", str(tmp_path / "s")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("nlips capture: error: the LED board has "), err
    assert f"has {board_leds} LEDs but the design {design} has {design_leds}" in err
    assert f"`make NLEDS={design_leds}`" in err and f"--adalight {design_leds}" in err
    assert not (tmp_path / "s").exists() and board.latched.sum() == 0


STOP_AFTER_PRESS_1 = """
import sys, time
from pathlib import Path
from nlipscalib.cli import main
from nlipscalib.device import session

capture_press = session.capture_press

def held_after_press_1(rig, folder, *args, **kwargs):  # press_0001 written whole, then the session waits
    record = capture_press(rig, folder, *args, **kwargs)
    if Path(folder).name == "press_0001":
        Path(sys.argv[1]).touch()
        time.sleep(60)
    return record

session.capture_press = held_after_press_1
sys.exit(main(sys.argv[2:]))
"""
"""A capture that stops after its first press until a signal comes (the file ``argv[1]`` says it got there)."""

STOPPED_LINE = "session {out}: 2 of 4 folders captured (reference, press_0001); run again to resume from press_0002"


def test_a_capture_stopped_by_sigterm_prints_its_session_line_and_exits_143(tmp_path):
    """SIGTERM (a scheduler, `kill`) ended `nlips capture` with "finished work is kept" and no session line: the
    operator did not know how far the session got. The line names what was captured and where a run again starts."""
    import os
    import signal
    import sys
    from pathlib import Path

    from tests.processes import terminate_once_started

    out, started = tmp_path / "s", tmp_path / "started"
    argv = [sys.executable, "-c", STOP_AFTER_PRESS_1, str(started), "capture", "--emulate", "nlipstac", *SMALL]
    env = os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    code, _, err = terminate_once_started([*argv, "--presses", "3", "--out", str(out)], started, env, wait=240)
    assert started.exists(), err
    assert code == 128 + signal.SIGTERM, err
    assert err.strip().splitlines()[-1] == f"nlips capture: terminated; {STOPPED_LINE.format(out=out)}"
    assert (out / "session.json").is_file() and [p.name for p in find_presses(out)] == ["press_0001", "reference"]


def test_a_capture_stopped_by_ctrl_c_prints_its_session_line(tmp_path, capsys, monkeypatch):
    from nlipscalib.device import session

    capture_press = session.capture_press

    def interrupted_after_press_1(rig, folder, *args, **kwargs):
        record = capture_press(rig, folder, *args, **kwargs)
        if folder.name == "press_0001":
            raise KeyboardInterrupt
        return record

    monkeypatch.setattr(session, "capture_press", interrupted_after_press_1)
    out = tmp_path / "s"
    assert main(["capture", "--emulate", "nlipstac", *SMALL, "--presses", "3", "--out", str(out)]) == 130
    assert capsys.readouterr().err.strip().splitlines()[-1] == (
        f"nlips capture: interrupted; {STOPPED_LINE.format(out=out)}"
    )
    monkeypatch.undo()  # a run again resumes where the line said
    assert main(["capture", "--emulate", "nlipstac", *SMALL, "--presses", "3", "--out", str(out)]) == 0
    assert "press_0001: kept" in capsys.readouterr().err
