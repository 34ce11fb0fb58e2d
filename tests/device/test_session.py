"""Capture sessions with a fake LED controller and camera: frames, movement retakes, resumption."""

import numpy as np
import pytest

from nlipscalib.core import Camera, Led, SensorResponse, load_press, tricolor_groups
from nlipscalib.core.errors import CaptureError
from nlipscalib.device.session import (
    Operator,
    Rig,
    SessionConfig,
    capture_press,
    frame_sequence,
    run_session,
)

from .fakes import FakeController, LitSource

N_LEDS, H, W = 6, 12, 16


def _rig(noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    images = rng.uniform(0.05, 0.15, size=(N_LEDS, H, W, 3)).astype(np.float32)
    controller = FakeController(N_LEDS)
    leds = tuple(Led((np.cos(a) * 5, np.sin(a) * 5, 0.0)) for a in np.linspace(0, 6, N_LEDS))
    rig = Rig(
        controller=controller,
        source=LitSource(controller, images, noise=noise, seed=seed),
        camera=Camera.from_fov(W, H, 90.0),
        leds=leds,
        response=SensorResponse(bit_depth=16, black_level=256.0, white_level=65256.0),
    )
    return rig, images


def _quiet():
    lines = []
    return Operator(interactive=False, echo=lines.append), lines


def test_frame_sequence_order_and_colours():
    seq = frame_sequence(N_LEDS, SessionConfig(white_level=200, tricolor_level=100))
    names = [n for n, _ in seq]
    assert names == ["tricolor", "dark"] + [f"led_{i:02d}" for i in range(1, N_LEDS + 1)] + ["check"]
    tri = seq[0][1]
    np.testing.assert_array_equal(tri.argmax(axis=1), tricolor_groups(N_LEDS))
    assert tri.max() == 100 and seq[1][1].max() == 0
    led3 = seq[4][1]
    assert led3[2].tolist() == [200, 200, 200] and led3.sum() == 600


def test_press_holds_each_led_alone_and_the_tricolor(tmp_path):
    rig, images = _rig()
    op, _ = _quiet()
    rec = capture_press(rig, tmp_path / "p", SessionConfig(), op, index=1)
    assert rec["attempts"] == 1
    p = load_press(tmp_path / "p")
    lin = p.linear(p.led_images)
    np.testing.assert_allclose(lin, images * 65000 / 65000, atol=2e-5)
    tri = np.einsum("lhwc,lc->hwc", images, np.eye(3)[tricolor_groups(N_LEDS)])
    np.testing.assert_allclose(p.linear(p.tricolor), tri, atol=2e-5)
    assert np.all(p.dark == 256)
    assert rig.controller.latched.sum() == 0  # LEDs off afterwards
    assert p.meta["provenance"]["source"] == "device"


def test_movement_is_retaken_then_refused(tmp_path):
    rig, images = _rig(noise=0.002)
    op, lines = _quiet()
    moved = images.copy()
    moved[:, 2:8, 3:9] *= 1.5  # the object moved: a patch changes brightness
    rig.source.change_at = (4, moved)  # mid-sequence of the first attempt
    rec = capture_press(rig, tmp_path / "p", SessionConfig(), op, index=2)
    assert rec["attempts"] == 2 and rec["moved"][0] > 0.1 and rec["moved"][1] == 0
    assert any("moved" in line for line in lines)
    kept = load_press(tmp_path / "p")
    np.testing.assert_allclose(kept.linear(kept.led_images), moved, atol=0.01)

    class Shaky(LitSource):
        def read(self):
            self.images = self.images * 1.05  # never holds still
            return super().read()

    rig.source = Shaky(rig.controller, images)
    # it said "or raise movement_threshold", a name the command line does not have
    with pytest.raises(CaptureError, match=r"kept moving .*\(`nlips capture --movement-threshold`, .*: 0\.02\)$"):
        capture_press(rig, tmp_path / "q", SessionConfig(max_retakes=1), op, index=3)
    assert not (tmp_path / "q").exists()


@pytest.mark.parametrize("interactive", [False, True])
def test_a_retake_is_said_once_to_the_operator_and_kept_in_the_log_file(tmp_path, monkeypatch, capsys, interactive):
    """A press that moved was reported twice: a WARNING log line and the operator's line. Now only the operator's
    line says it (printed, or the prompt at the terminal), and --log-file still gets it."""
    import sys

    from nlipscalib import progress

    rig, images = _rig()
    moved = images.copy()
    moved[:, 2:8, 3:9] *= 1.5
    rig.source.change_at = (4, moved)
    monkeypatch.setattr("builtins.input", lambda: "")  # Enter, at once
    for stream in (sys.stdin, sys.stdout):  # a terminal's: the prompt still goes to stderr, past stdout's log copy
        monkeypatch.setattr(stream, "isatty", lambda: True, raising=False)
    log = tmp_path / "run.log"
    progress.configure(progress=False, log_file=log)
    try:
        with progress.results_to_log_file():
            capture_press(rig, tmp_path / "p", SessionConfig(), Operator(interactive=interactive), index=2)
    finally:
        progress.configure(progress=True)  # closes the file
    said = "Press 2: the object moved"
    captured = capsys.readouterr()
    shown = captured.err.split("[Enter] ") if interactive else captured.out.splitlines()
    assert not interactive or captured.out == ""  # stdout holds result paths alone, never a prompt
    assert sum(said in line for line in shown) == 1
    logged = [
        line.split(" ", 3)[3] for line in log.read_text(encoding="utf-8").splitlines() if "changed" in line
    ]  # past "[pid]"
    assert len(logged) == 1 and logged[0].startswith(f"INFO nlipscalib: {said} (") and "retaking" in logged[0]


def test_noise_alone_is_not_movement(tmp_path):
    rig, _ = _rig(noise=0.01)  # 1% of full scale per pixel, like a real sensor at mid range
    rec = capture_press(rig, tmp_path / "p", SessionConfig(), _quiet()[0])
    assert rec["attempts"] == 1


def test_session_resumes_after_interruption(tmp_path):
    rig, _ = _rig()
    op, lines = _quiet()

    class Interrupted(Operator):
        def press(self, index, total):
            if index == 2:
                raise KeyboardInterrupt
            super().press(index, total)

    with pytest.raises(KeyboardInterrupt):
        run_session(rig, tmp_path / "s", SessionConfig(presses=3), Interrupted(echo=lines.append))
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["press_0001", "reference", "session.json"]
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=3), op)
    assert status["reference"] == "kept" and status["press_0001"] == "kept"
    assert status["press_0002"]["attempts"] == 1 and status["press_0003"]["attempts"] == 1
    assert lines.index("Do not touch the sensor: capturing the undeformed reference.") < lines.index(
        "Press 1/3: press the object now, hold still."
    )


def test_resume_refuses_another_camera(tmp_path):
    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=0), _quiet()[0])
    rig.camera = Camera.from_fov(W, H, 120.0)
    with pytest.raises(CaptureError, match=r"another camera or LED count \(camera fx = 7\.639, the session 10\.19\)"):
        run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])


def test_resume_into_a_folder_of_another_sensors_presses_is_refused_naming_the_press(tmp_path):
    """`nlips capture --emulate nlipstac` into a folder of fingertip presses from `nlips dataset` (no session.json)
    kept them, captured nlipstac presses beside them and exited 0; session.json records no LED ring or dome."""
    import dataclasses

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    (tmp_path / "s" / "session.json").unlink()  # a dataset's folder has none
    other = dataclasses.replace(rig, leds=tuple(Led(np.add(led.position, (0.0, 0.0, 2.0))) for led in rig.leds))
    with pytest.raises(CaptureError) as err:
        run_session(other, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert str(err.value).startswith(f"{tmp_path / 's' / 'reference'}: captured with another sensor than the one")
    assert "LED 1 is 2.00 mm" in str(err.value) and "new --out folder" in str(err.value)
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["press_0001", "reference"]
    assert run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])["press_0001"] == "kept"


def test_resume_with_another_dome_and_the_same_camera_and_leds_is_refused(tmp_path):
    """The camera and LED ring alone let another dome's presses pass: the dome each press records is compared."""
    import dataclasses

    rig, _ = _rig()
    rig.design = {"dome": {"shape": "hemisphere", "radius": 15.0, "height": 15.0}}
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    (tmp_path / "s" / "session.json").unlink()
    lower = dataclasses.replace(rig, design={"dome": {"shape": "hemisphere", "radius": 15.0, "height": 12.0}})
    with pytest.raises(
        CaptureError, match=r"reference: captured with another sensor .*\(dome\.height: 15\.0 -> 12\.0\)"
    ):
        run_session(lower, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])


def test_resume_refuses_other_capture_settings_and_names_the_change(tmp_path):
    """A resumed session with another LED level or exposure would mix two kinds of image in one calibration
    (seen: a tri-colour frame 3x darker from press 5 on, taken silently); the same settings resume."""
    import dataclasses

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    with pytest.raises(CaptureError, match=r"other settings \(tricolor_level: 255 -> 30\)"):
        run_session(rig, tmp_path / "s", SessionConfig(presses=2, tricolor_level=30), _quiet()[0])
    rig.response = dataclasses.replace(rig.response, exposure_ms=rig.response.exposure_ms * 2)
    with pytest.raises(CaptureError, match="exposure_ms"):
        run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["press_0001", "reference", "session.json"]
    rig.response = dataclasses.replace(rig.response, exposure_ms=rig.response.exposure_ms / 2)
    assert run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])["press_0002"]["attempts"] == 1


def test_an_emulated_session_begun_before_the_scenes_declared_their_led_size_resumes(tmp_path):
    """`nlips capture --emulate nlipstac` of an upgraded nlipscalib refused to resume a session begun before the
    shipped scenes declared leds.emitter_diameter ("other settings (scene.leds.emitter_diameter: None -> 3.6)"),
    a field no render reads; another scene field still refuses."""
    rig, _ = _rig()
    scene = {"name": "nlipstac", "leds": {"count": N_LEDS, "ring_radius": 9.0}, "render": {"bounces": 0}}
    rig.provenance = {"scene": scene}
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    rig.provenance = {"scene": scene | {"leds": scene["leds"] | {"emitter_diameter": 3.6}}}
    assert run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])["press_0002"]["attempts"] == 1
    rig.provenance = {"scene": scene | {"render": {"bounces": 1}}}
    with pytest.raises(CaptureError, match=r"other settings \(scene\.render\.bounces: 0 -> 1\)"):
        run_session(rig, tmp_path / "s", SessionConfig(presses=3), _quiet()[0])


def test_a_damaged_session_description_says_how_to_resume(tmp_path):
    """A truncated session.json named the file and the problem but not what to do about it; removing it
    resumes the session (its presses kept), recording the settings again."""
    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    path = tmp_path / "s" / "session.json"
    path.write_text(path.read_text(encoding="utf-8")[:20], encoding="utf-8")
    with pytest.raises(CaptureError) as err:
        run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    message = str(err.value)
    assert message.startswith(f"{path}: unreadable session description") and "\n" not in message
    assert "remove or rename session.json and run again" in message and "new --out folder" in message
    path.unlink()
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert status["press_0001"] == "kept" and status["press_0002"]["attempts"] == 1


def test_resume_captures_again_a_press_whose_files_are_gone(tmp_path, caplog):
    """A captured press whose LED image was deleted was reported "kept (already captured)"."""
    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    (tmp_path / "s" / "press_0001" / "led_02.png").unlink()
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    assert status["reference"] == "kept" and status["press_0001"]["attempts"] == 1
    assert "press_0001: led_02.png missing; capturing it again" in caplog.text
    assert (tmp_path / "s" / "press_0001" / "led_02.png").is_file()


def test_resume_captures_again_a_press_whose_files_are_empty_or_cut_short(tmp_path, caplog):
    """Writes are atomic but not synced: a power cut soon after a press was captured can leave its files empty or
    cut short, and the press was "kept" at every resume (the solve then failed on the image). Now it is captured
    again, and the warning names each file's state."""
    from nlipscalib.core.file_checks import file_problem

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    press = tmp_path / "s" / "press_0001"
    (press / "led_01.png").write_bytes(b"")
    (press / "led_02.png").write_bytes((press / "led_02.png").read_bytes()[:100])
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    assert status["reference"] == "kept" and status["press_0001"]["attempts"] == 1
    said = "press_0001: led_01.png empty, led_02.png cut short (no PNG end chunk); capturing it again"
    assert said in caplog.text
    assert file_problem(press / "led_01.png") is None and file_problem(press / "led_02.png") is None


def test_resume_captures_again_a_press_with_another_image_copied_over_one(tmp_path, caplog):
    """Another whole image copied over a captured one (a user tidying up, a copy gone wrong) is whole at its ends:
    the press was "kept" at every resume, and calibrated on the wrong image. Its size is not the one the press's
    checksums.json records: it is captured again, the warning naming the file."""
    from nlipscalib.core.imageio import write_png16
    from nlipscalib.core.press_checksums import read_checksums

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    press = tmp_path / "s" / "press_0001"
    shape = load_press(press).led_images.shape[1:]
    other = write_png16(tmp_path / "other.png", np.zeros(shape, np.uint16)).read_bytes()  # a dark frame, say
    assert len(other) != read_checksums(press)["led_03.png"]["bytes"]
    (press / "led_03.png").write_bytes(other)
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert status["reference"] == "kept" and status["press_0002"] == "kept"
    assert status["press_0001"]["attempts"] == 1
    said = f"press_0001: led_03.png changed since it was written ({len(other)} bytes, checksums.json records"
    assert said in caplog.text and "capturing it again" in caplog.text
    assert (press / "led_03.png").stat().st_size == read_checksums(press)["led_03.png"]["bytes"]


def test_resume_captures_again_a_press_whose_meta_json_is_cut_short(tmp_path, caplog):
    """A session's press folder is the session's own capture: its meta.json cut short by a power cut (or emptied)
    is captured again on resume, as a torn image is, not a stop or a kept press."""
    from nlipscalib.core.press_meta import read_meta

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    meta = tmp_path / "s" / "press_0001" / "meta.json"
    meta.write_bytes(meta.read_bytes()[:200])
    (tmp_path / "s" / "press_0002" / "meta.json").write_bytes(b"")
    status = run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert status["reference"] == "kept"
    assert status["press_0001"]["attempts"] == 1 and status["press_0002"]["attempts"] == 1
    assert "press_0001: meta.json: not valid JSON (" in caplog.text and "capturing it again" in caplog.text
    assert read_meta(meta.parent)["images"] and read_meta(meta.parent.with_name("press_0002"))["images"]


def test_rig_check_names_the_mismatch():
    rig, _ = _rig()
    rig.controller = FakeController(N_LEDS + 1)
    with pytest.raises(CaptureError, match="7 LEDs"):
        rig.check()


def test_board_reset_mid_press_is_retaken(tmp_path, caplog):
    """A reset of the real virtual board during a press (detected by the host driver) makes the press retake; it is
    said twice, each once: the driver's warning with its cause, and the operator's line."""
    import logging

    caplog.set_level(logging.WARNING)
    from nlipscalib.device.controller import LedController
    from nlipscalib.device.virtual_board import VirtualBoard

    rig, images = _rig()
    board = VirtualBoard(N_LEDS)
    with LedController.open(board.url) as controller:
        rig.controller = controller

        class ResetOnce(LitSource):
            def read(self):
                if self.reads == 6:
                    board.reset()  # the LEDs go dark while the sixth frame is read
                return super().read()

        rig.source = ResetOnce(board, images)
        op, lines = _quiet()
        rec = capture_press(rig, tmp_path / "p", SessionConfig(), op, index=1)
    assert rec["attempts"] == 2 and rec["moved"][0] is None and rec["moved"][1] == 0
    assert sum("LED board reset" in line for line in lines) == 1
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1 and "board reset detected" in warnings[0], warnings
    p = load_press(tmp_path / "p")
    np.testing.assert_allclose(p.linear(p.led_images), images, atol=2e-5)


def test_interactive_operator_waits_for_enter_and_stops_on_eof(monkeypatch, capsys):
    answers = iter(["", EOFError])

    def fake_input(*prompt):
        assert not prompt  # a prompt given to input() goes to stdout when stdout is no terminal
        answer = next(answers)
        if answer is EOFError:
            raise EOFError
        return answer

    monkeypatch.setattr("builtins.input", fake_input)
    op = Operator(interactive=True)
    op.press(1, 2)  # returns after Enter
    assert capsys.readouterr().err == "Press 1/2: press the object now, hold still. [Enter] "
    with pytest.raises(KeyboardInterrupt):
        op.press(2, 2)
    assert capsys.readouterr().out == ""


def test_a_board_lost_mid_press_is_the_error_reported_not_the_clean_ups(tmp_path):
    """The clean-up's lights-off replaced the error in flight: an unplugged board that did not come back was
    reported as "the LED controller is closed" (the reconnect had closed it)."""
    from nlipscalib.device.controller import DeviceDisconnectedError, LedController
    from nlipscalib.device.virtual_board import VirtualBoard

    rig, images = _rig()
    board = VirtualBoard(N_LEDS)
    with LedController.open(board.url, reconnect_s=0.2) as controller:
        rig.controller = controller

        class UnpluggedMidPress(LitSource):
            def read(self):
                if self.reads == 4:
                    board.unplug()  # and never plugged back
                return super().read()

        rig.source = UnpluggedMidPress(board, images)
        with pytest.raises(DeviceDisconnectedError, match=r"the board disconnected \(.*\) and did not come back"):
            capture_press(rig, tmp_path / "p", SessionConfig(), _quiet()[0], index=1)
    assert not (tmp_path / "p").exists()


def test_a_board_silent_mid_press_is_named_by_the_command_that_failed(tmp_path):
    """A board that stops answering: the error named OFF (the clean-up's), after waiting its tries a second time;
    now ALL, the command that failed, and the clean-up is one short try; the controller keeps its settings.

    The tries are counted, not timed (a wall-clock bound failed on a loaded machine)."""
    from nlipscalib.device.controller import DeviceTimeoutError, LedController
    from nlipscalib.device.virtual_board import VirtualBoard

    rig, images = _rig()
    board = VirtualBoard(N_LEDS)
    with LedController.open(board.url, timeout=0.2, retries=3) as controller:
        rig.controller = controller
        tries = []  # (command, how many times it was sent) of each exchange with the board
        exchange = controller._exchange

        def counted(command, *args, **kwargs):
            before = controller.resends
            try:
                return exchange(command, *args, **kwargs)
            finally:
                tries.append((command, controller.resends - before + 1))

        controller._exchange = counted

        class SilentMidPress(LitSource):
            def read(self):
                if self.reads == 4:
                    board.mute(10**6)  # every line from now on is lost
                return super().read()

        rig.source = SilentMidPress(board, images)
        with pytest.raises(DeviceTimeoutError) as info:
            capture_press(rig, tmp_path / "p", SessionConfig(), _quiet()[0], index=1)
        assert (controller.timeout, controller.retries, controller.reconnect_s) == (0.2, 3, 5.0)
    assert str(info.value) == f"{board.url}: no valid answer to ALL after 4 tries of 0.2 s each"
    assert tries[-2:] == [("ALL", 4), ("OFF", 1)]  # the tries of ALL and one short try of OFF (was 4 + 4 tries)


def test_on_a_terminal_the_operators_lines_start_their_own_line_not_the_bars(tmp_path, monkeypatch):
    """The session's bar leaves the cursor at its end, so on a terminal each prompt was written onto the bar's
    line ("capture:  33%|###   | 1/3 [00:00<00:01, 1.56press/s]Press 1/2: press the object now, hold still.").
    Now the bar is cleared while the operator's line is written, and drawn again below it."""
    import io
    import sys

    class Terminal(io.StringIO):  # stdout and stderr on one screen, as a terminal shows them
        def isatty(self):
            return True

    from nlipscalib import progress

    screen = Terminal()
    monkeypatch.setattr(progress, "_enabled", True)  # as a command without --no-progress sets it
    monkeypatch.setattr(sys, "stdout", screen)
    monkeypatch.setattr(sys, "stderr", screen)
    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=2), Operator(interactive=False), progress=True)
    monkeypatch.undo()
    shown = [line.rsplit("\r", 1)[-1] for line in screen.getvalue().split("\n")]  # what stays on each line
    said = [line for line in shown if "Press " in line or "Do not touch" in line]
    assert len(said) == 5 and all(line.startswith(("Press ", "Do not touch")) for line in said), said
    assert "capture:" in screen.getvalue()  # the bar was drawn


def test_resume_with_another_emulated_tone_curve_is_refused_naming_the_option(tmp_path):
    """`nlips capture --emulate nlipstac --emulate-tone-curve gamma2.2` resumed without the option (or with another)
    captured the new presses' frames linear beside gamma-encoded ones, said nowhere: the curve was not in
    session.json. A session recorded without it (linear, or begun before the emulator had curves) resumes linear."""
    import json

    rig, _ = _rig()
    rig.provenance = {"device": "emulator", "tone_curve": "gamma2.2"}
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    rig.provenance = {"device": "emulator"}
    with pytest.raises(CaptureError) as err:
        run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    message = str(err.value)
    assert "\n" not in message and message.startswith(str(tmp_path / "s" / "session.json"))
    assert (
        "--emulate-tone-curve gamma2.2 (this run: none)" in message
        and "resume it with --emulate-tone-curve gamma2.2" in message
    )
    rig.provenance = {"device": "emulator", "tone_curve": "s-curve"}
    with pytest.raises(CaptureError, match=r"--emulate-tone-curve gamma2\.2 \(this run: s-curve\)"):
        run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["press_0001", "reference", "session.json"]
    rig.provenance = {"device": "emulator", "tone_curve": "gamma2.2"}
    assert run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])["press_0002"]["attempts"] == 1
    # a session recorded before the curve was (no such key; or no settings at all, before 2026-12-04): linear
    path = tmp_path / "s" / "session.json"
    record = json.loads(path.read_text(encoding="utf-8"))
    for old in (
        {**record, "settings": {k: v for k, v in record["settings"].items() if k != "emulated_tone_curve"}},
        {k: v for k, v in record.items() if k != "settings"},
    ):
        path.write_text(json.dumps(old), encoding="utf-8")
        with pytest.raises(CaptureError, match=r"--emulate-tone-curve none \(this run: gamma2\.2\); resume it with no"):
            run_session(rig, tmp_path / "s", SessionConfig(presses=3), _quiet()[0])
        rig.provenance = {"device": "emulator"}
        assert run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])["press_0002"] == "kept"
        rig.provenance = {"device": "emulator", "tone_curve": "gamma2.2"}


def test_an_emulated_session_resumed_by_other_twin_code_says_its_earlier_presses_were_made_otherwise(tmp_path, caplog):
    """An emulated session begun before an upgrade took today's render of a new press beside its old reference and
    presses, said nowhere (the presses recorded no twin code). Now each emulated press records the twin code and
    render libraries, and a resume that captures beside presses of other ones (or of none) warns, naming them."""
    import logging

    rig, _ = _rig()
    libraries = {"mitsuba": "3.6.0", "drjit": "1.0.0"}
    rig.provenance = {"device": "emulator"}  # captured before 2026-12-06: no code recorded
    run_session(rig, tmp_path / "old", SessionConfig(presses=1), _quiet()[0])
    rig.provenance = {"device": "emulator", "code": "a" * 32, "libraries": libraries}
    with caplog.at_level(logging.WARNING, logger="nlipscalib.device.session"):
        run_session(rig, tmp_path / "old", SessionConfig(presses=2), _quiet()[0])
    assert (
        f"{tmp_path / 'old'}: reference, press_0001 were captured by the emulated sensor with other twin code or "
        "render libraries (twin code unrecorded: an older nlipscalib captured it); kept" in caplog.text
    )
    assert load_press(tmp_path / "old" / "press_0002").meta["provenance"]["code"] == "a" * 32
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="nlipscalib.device.session"):
        run_session(rig, tmp_path / "old", SessionConfig(presses=2), _quiet()[0])  # nothing to capture: nothing mixed
        run_session(rig, tmp_path / "new", SessionConfig(presses=1), _quiet()[0])
        run_session(rig, tmp_path / "new", SessionConfig(presses=2), _quiet()[0])  # the same code: silent
    assert "other twin code" not in caplog.text
    rig.provenance = {"device": "emulator", "code": "b" * 32, "libraries": libraries | {"mitsuba": "3.7.0"}}
    with caplog.at_level(logging.WARNING, logger="nlipscalib.device.session"):
        run_session(rig, tmp_path / "new", SessionConfig(presses=3), _quiet()[0])
    assert "new: reference, press_0001, press_0002 were captured" in caplog.text
    assert "(other code of sim/ or core/, mitsuba 3.6.0 (now 3.7.0))" in caplog.text
    caplog.clear()
    device, _ = _rig()  # a device records no twin code: its presses are never said to be made otherwise
    with caplog.at_level(logging.WARNING, logger="nlipscalib.device.session"):
        run_session(device, tmp_path / "device", SessionConfig(presses=1), _quiet()[0])
        run_session(device, tmp_path / "device", SessionConfig(presses=2), _quiet()[0])
    assert "other twin code" not in caplog.text


def test_a_capture_into_a_folder_of_the_twins_renders_is_refused_naming_the_render(tmp_path):
    """`nlips capture --emulate nlipstac --out RENDERS` into a folder of `nlips render` presses of the same sensor
    kept every render as "already captured", wrote session.json around them and exited 0."""
    import json

    rig, _ = _rig()
    run_session(rig, tmp_path / "s", SessionConfig(presses=1), _quiet()[0])
    (tmp_path / "s" / "session.json").unlink()  # a folder of renders has none
    meta_path = tmp_path / "s" / "press_0001" / "meta.json"
    meta = json.loads(meta_path.read_text(encoding="utf-8"))
    meta_path.write_text(json.dumps(meta | {"provenance": meta["provenance"] | {"source": "sim"}}), encoding="utf-8")
    with pytest.raises(CaptureError) as err:
        run_session(rig, tmp_path / "s", SessionConfig(presses=2), _quiet()[0])
    assert str(err.value).startswith(f"{tmp_path / 's' / 'press_0001'}: a press rendered by the twin")
    assert "new --out folder" in str(err.value)
    assert sorted(p.name for p in (tmp_path / "s").iterdir()) == ["press_0001", "reference"]
