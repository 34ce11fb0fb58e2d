"""`nlips capture` when the LED board reboots mid-capture (a brown-out, the watchdog, the reset button), end to end:
the compiled firmware in simavr (its MCU reset by the harness) and the virtual board, a camera that sees what the
board's LEDs show (the WS2812 pin decoded by the harness), the command run as a user runs it.

What the user must see: the press retaken after one reset, its images those of the lit LEDs (no dark frame kept);
after a reset at every attempt one line naming the press and the likely cause, exit 2, no press folder written, and
the same command run again resumes at that press. The simavr cases need gcc-avr, avr-libc and simavr (setup.sh);
without them they skip, or fail when NLIPS_REQUIRE_DEVICE_TOOLS=1.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.device import camera as device_camera  # noqa: E402
from nlipscalib.device.camera import FrameSource  # noqa: E402

from .fakes import errors_only  # noqa: E402
from .ledboards import VirtualUnderTest, board_under_test  # noqa: E402
from .test_capture_device import SEQUENCE, H, W, camera_file  # noqa: E402

BLACK = 256
"""The pin camera's black level, stored 16-bit values (``--black-level``)."""
GAIN = 65000
"""Stored value of the pin camera per unit of light above its black level (full scale 65535: 16-bit frames)."""


@pytest.fixture(params=["virtual", "simavr"])
def board(request, tmp_path):
    under_test = board_under_test(request.param, tmp_path)
    yield under_test
    under_test.close()


FAULTS = {
    "reset": lambda board: board.reset(),  # brown-out, watchdog, reset button: the port stays
    "unplug": lambda board: board.unplug(0.3),  # the USB link drops with the power and comes back
}
"""How the board reboots mid-capture."""
REASONS = {"reset": "it printed its boot banner", "unplug": "the board was unplugged and came back"}
"""``BoardResetError.reason`` of each fault."""


class PinCamera(FrameSource):
    """Frames lit by what the board's LEDs show now: a fixed image per LED, weighted by the latched colours.

    ``reset_at(reads)`` is asked before each frame is read; true reboots the board there by ``fault`` (its LEDs go
    dark as the camera exposes)."""

    bit_depth = 16

    def __init__(self, board, reset_at, fault: str = "reset"):
        self.board, self.reset_at, self.fault, self.reads = board, reset_at, fault, 0
        rng = np.random.default_rng(0)
        self.images = rng.uniform(0.02, 0.06, (board.n_leds, H, W, 3)).astype(np.float32)

    @property
    def shape(self):
        return H, W

    def read(self):
        self.reads += 1
        if self.reset_at(self.reads):
            FAULTS[self.fault](self.board)
        weights = self.board.latched().astype(np.float32) / 255
        light = np.einsum("lhwc,lc->hwc", self.images, weights)
        return np.clip(np.rint(light * GAIN + BLACK), 0, 65535).astype(np.uint16)


def lit(camera: PinCamera) -> np.ndarray:
    """The LED images each LED at full drive gives, linear (fraction of the 16-bit range above the black level)."""
    return camera.images * GAIN / (65535 - BLACK)


def capture(board, camera, tmp_path, monkeypatch) -> int:
    monkeypatch.setattr(device_camera, "open_source", lambda *args, **kwargs: camera)
    args = ["capture", "--port", board.url, "--camera", "pin", "--camera-calibration", str(camera_file(tmp_path))]
    args += ["--black-level", str(BLACK), "--yes", "--presses", "2", "--max-retakes", "1", "--out", str(tmp_path / "s")]
    return main(args)


@pytest.mark.parametrize("fault", FAULTS)
def test_a_board_reset_mid_press_retakes_it_with_the_leds_lit(board, fault, tmp_path, capsys, monkeypatch, caplog):
    """Said as a lost reply too on the firmware ("sending ALL again (1/3)" before "board reset detected"): its boot
    banner came while the host waited for the reply to the next command, and that try was counted as a resend."""
    caplog.set_level(logging.WARNING)
    camera = PinCamera(board, lambda reads: reads == SEQUENCE + 6, fault)  # press 1, as LED 4 is read
    assert capture(board, camera, tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert f"board reset detected ({REASONS[fault]})" in warnings[-1], warnings
    assert len(warnings) == (1 if fault == "reset" else 2), warnings
    assert fault == "reset" or "port failed" in warnings[0], warnings
    assert err.count("Press 1: the LED board reset; hold still, retaking.") == 1, err
    assert "press_0001: captured in" in err and "2 attempt(s)" in err
    press = load_press(tmp_path / "s" / "press_0001")
    np.testing.assert_allclose(press.linear(press.led_images), lit(camera), atol=2e-5)  # no dark frame kept


@pytest.mark.parametrize("fault", FAULTS)
def test_a_board_reset_at_every_attempt_is_one_line_and_the_same_command_resumes(
    board, fault, tmp_path, capsys, monkeypatch
):
    """Ended with the driver's advice to its caller, "... restored to the last acknowledged colours; retake any
    frame captured since the previous command", after the capture had retaken the press."""
    camera = PinCamera(board, lambda reads: reads > SEQUENCE and (reads - SEQUENCE) % 7 == 0, fault)
    out = tmp_path / "s"
    assert capture(board, camera, tmp_path, monkeypatch) == 2
    (line,) = errors_only(capsys.readouterr().err)
    cable = ", or its USB cable is loose" if fault == "unplug" else ""
    assert line == (
        f"nlips capture: error: {board.url}: the LED board reset during each of the 2 attempts at press_0001 "
        f"({REASONS[fault]}), so it was not written: a board that resets as its LEDs light is often browning out (the "
        "LEDs powered from the board's 5 V, or a supply too weak: firmware/README.md, Wiring, in the nlipscalib "
        f"source distribution or repository){cable}; session {out}: 1 of 3 folders captured (reference); run again "
        "to resume from press_0001"
    )
    assert sorted(p.name for p in out.iterdir()) == ["reference", "session.json"]  # no half-written press
    camera.reset_at = lambda reads: False  # the supply fixed
    assert capture(board, camera, tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    assert "reference: kept" in err and "press_0001: captured" in err and "press_0002: captured" in err
    press = load_press(out / "press_0001")
    np.testing.assert_allclose(press.linear(press.led_images), lit(camera), atol=2e-5)


def test_a_board_reset_whose_banner_comes_on_the_last_resend_retakes_the_press(tmp_path, capsys, monkeypatch, caplog):
    """Stopped the capture with "...: no valid answer to ALL after 4 tries of 1 s each" (exit 2): the board's
    replies were lost until it rebooted as the last resend arrived, and its banner ended that try's wait with no try
    left to handle it (virtual board: the reset placed on the command's fourth line, the driver's last try)."""
    caplog.set_level(logging.WARNING)
    board = VirtualUnderTest()

    def lost_then_reset(reads: int) -> bool:
        if reads == SEQUENCE + 6:  # press 1, as LED 4 is read: the next command's 3 tries lost, the 4th a reboot
            board.board.mute(3)
            board.board.reset_on_line(4)
        return False

    camera = PinCamera(board, lost_then_reset)
    assert capture(board, camera, tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert "board reset detected (it printed its boot banner)" in warnings[-1], warnings
    assert err.count("Press 1: the LED board reset; hold still, retaking.") == 1, err
    assert "press_0001: captured in" in err and "2 attempt(s)" in err
    press = load_press(tmp_path / "s" / "press_0001")
    np.testing.assert_allclose(press.linear(press.led_images), lit(camera), atol=2e-5)


@pytest.mark.parametrize("fault", FAULTS)
def test_a_board_reset_after_the_last_press_keeps_the_session_and_exits_0(
    board, fault, tmp_path, capsys, monkeypatch, caplog
):
    """Exited 2 with the driver's "... retake any frame captured since the previous command" and the session line
    "3 of 3 folders captured ...; all kept, nothing left to capture": the reset came after the last press's LEDs-off
    was acknowledged (a rebooted board answers no command but HELLO, so a reset before it would have been found
    there and the press retaken), so it darkened no frame; the session's own OFF found it as the command ended."""
    from nlipscalib.device.session import Operator

    caplog.set_level(logging.WARNING)
    release = Operator.release

    def released(self, index):
        release(self, index)
        if index == 2:  # the last press written whole: the board reboots before the session's LEDs-off
            FAULTS[fault](board)

    monkeypatch.setattr(Operator, "release", released)
    camera = PinCamera(board, lambda reads: False)
    out = tmp_path / "s"
    assert capture(board, camera, tmp_path, monkeypatch) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [str(out)]
    assert "error" not in captured.err, captured.err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings[-1] == (
        f"{board.url}: the LED board reset after the session's last press was captured ({REASONS[fault]}; found as "
        "the LEDs were switched off at the end): every frame was read before that press's LEDs-off was acknowledged, "
        "so none was taken with the LEDs dark and all 3 folders are kept; the LEDs are off. A board that resets as "
        "its LEDs light is often browning out (the LEDs powered from the board's 5 V, or a supply too weak: "
        "firmware/README.md, Wiring, in the nlipscalib source distribution or repository)"
        + (", or its USB cable is loose" if fault == "unplug" else "")
    ), warnings
    assert "press_0002: captured in" in captured.err
    assert not board.latched().any()  # the LEDs left dark
    for name in ("reference", "press_0001", "press_0002"):
        press = load_press(out / name)
        np.testing.assert_allclose(press.linear(press.led_images), lit(camera), atol=2e-5)
