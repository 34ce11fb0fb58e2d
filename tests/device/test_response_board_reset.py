"""``nlips calibrate-camera-response --port`` when the LED board reboots during its bracket (a brown-out as the LED
lights, the watchdog, the reset button, the USB link lost with the power), end to end on the virtual board and the
compiled firmware in simavr (its MCU reset by the harness), a stand-in webcam that sees the gel lit by what the
board's LEDs show, the command run as a user runs it.

What the user must see: the frame a reset may have darkened taken again once the LEDs are lit again, the curve the
one an undisturbed bracket gives; a reset at every attempt at a frame: one line naming the frame and the likely
cause, exit 2, nothing written, the LEDs dark, the same command run again gives the curve; a reset after the last
frame, found by the closing LEDs-off: one warning, the curve written, exit 0. Until s40 each ended with the driver's
"... retake any frame captured since the previous command", exit 2, nothing written. The simavr cases need gcc-avr,
avr-libc and simavr (setup.sh); without them they skip, or fail when NLIPS_REQUIRE_DEVICE_TOOLS=1.
"""

from __future__ import annotations

import logging

import cv2
import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.response_curve import read_response_file

from .fakes import errors_only
from .ledboards import VirtualUnderTest, board_under_test
from .test_response_bracket import BOARDS, Webcam

FAULTS = {
    "reset": lambda board: board.reset(),  # brown-out, watchdog, reset button: the port stays
    "unplug": lambda board: board.unplug(0.3),  # the USB link drops with the power and comes back
}
REASONS = {"reset": "it printed its boot banner", "unplug": "the board was unplugged and came back"}
"""``BoardResetError.reason`` of each fault."""
FLUSH = 4
"""Frames the camera drops after each exposure change (the command's default): a frame taken is FLUSH + 1 reads."""
READS = {"bracket": 1 + 3 * (FLUSH + 1), "pair": 1 + 21 * (FLUSH + 1)}
"""The camera's read at which a reset darkens a frame (after the one read as the camera opens): the bracket's 3rd
exposure (1 ms), or the additivity check's frame of LEDs 1+2 lit together (after the 15 exposures, the dark frame,
and the check's dark, LED 1, 2, 7 frames)."""
NAMED = {"bracket": "the 1 ms frame with LED 1 lit", "pair": "the 8 ms frame with LEDs 1+2 lit"}


@pytest.fixture(params=["virtual", "simavr"])
def board(request, tmp_path):
    under_test = board_under_test(request.param, tmp_path)
    yield under_test
    under_test.close()


class SeenBoard:
    """What the stand-in webcam sees of the board under test (``latched``, one read a frame): ``fault`` done to the
    board at the reads ``reset_at`` says (before the frame is lit, so that frame shows its LEDs dark)."""

    def __init__(self, board, reset_at=lambda reads: False, fault: str = "reset"):
        self.board, self.reset_at, self.fault, self.reads = board, reset_at, fault, 0

    @property
    def latched(self) -> np.ndarray:
        self.reads += 1
        if self.reset_at(self.reads):
            FAULTS[self.fault](self.board)
        return self.board.latched()


def _calibrate(board, seen: SeenBoard, out, monkeypatch, released=None) -> int:
    """The command with camera 0 a :class:`Webcam` lit by ``seen``; ``released``, called as the camera is released
    (after the bracket's last frame, before the closing LEDs-off)."""

    class Released(Webcam):
        def release(self):
            if released is not None:
                released()

    monkeypatch.setattr(cv2, "VideoCapture", lambda *a, **k: Released())
    BOARDS.append(seen)
    try:
        return main(["calibrate-camera-response", "--port", board.url, "--camera", "0", "--out", str(out)])
    finally:
        BOARDS.remove(seen)


def _curve(out) -> np.ndarray:
    return np.asarray(read_response_file(out).curve)


@pytest.fixture(scope="module")
def undisturbed(tmp_path_factory):
    """The curve of a bracket no reset touched (the virtual board)."""
    out = tmp_path_factory.mktemp("undisturbed") / "r.json"
    board = VirtualUnderTest()
    with pytest.MonkeyPatch.context() as monkeypatch:
        assert _calibrate(board, SeenBoard(board), out, monkeypatch) == 0
    board.board.close()
    return _curve(out)


@pytest.mark.parametrize("fault", FAULTS)
@pytest.mark.parametrize("where", READS)
def test_a_board_reset_during_the_bracket_retakes_the_frame_with_the_led_lit(
    board, fault, where, undisturbed, tmp_path, capsys, monkeypatch, caplog
):
    caplog.set_level(logging.WARNING)
    seen = SeenBoard(board, lambda reads: reads == READS[where], fault)
    out = tmp_path / "r.json"
    assert _calibrate(board, seen, out, monkeypatch) == 0
    err = capsys.readouterr().err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert f"board reset detected ({REASONS[fault]})" in warnings[-1], warnings
    assert err.count(f"{board.url}: the LED board reset") == 1, err
    assert (
        f"{board.url}: the LED board reset ({REASONS[fault]}) as {NAMED[where]} was taken: the LEDs are set again "
        "and it is taken again"
    ) in err
    np.testing.assert_array_equal(_curve(out), undisturbed)  # no dark frame kept: the undisturbed bracket's curve
    assert not board.latched().any()  # the LEDs left dark


def test_a_reset_whose_banner_is_lost_is_found_by_the_board_and_the_frame_retaken(
    undisturbed, tmp_path, capsys, monkeypatch
):
    """A board whose boot banner never reached the host (noise, a USB glitch) or is still to come (its
    bootloader): its NOSESSION answer to the STATE after the frame finds it."""
    board = VirtualUnderTest()
    seen = SeenBoard(board, lambda reads: reads == READS["bracket"])
    seen.fault = "unannounced"
    FAULTS["unannounced"] = lambda b: b.reset_unannounced()
    try:
        assert _calibrate(board, seen, tmp_path / "r.json", monkeypatch) == 0
    finally:
        del FAULTS["unannounced"]
    err = capsys.readouterr().err
    assert f"{board.url}: the LED board reset (it no longer knows the session) as {NAMED['bracket']}" in err, err
    np.testing.assert_array_equal(_curve(tmp_path / "r.json"), undisturbed)


def test_a_board_reset_as_the_leds_change_between_frames_sends_the_change_again(
    undisturbed, tmp_path, capsys, monkeypatch
):
    """A reboot as the line lighting LEDs 1+7 arrives (after the frame of LEDs 1+2 was answered for by the board):
    the driver relights LEDs 1+2 and raises; no frame is retaken, the change is sent again (virtual board: the reset
    placed on a command line)."""
    board = VirtualUnderTest()
    seen = SeenBoard(board, lambda reads: reads == READS["pair"])
    seen.fault = "on the next change"
    FAULTS["on the next change"] = lambda b: b.board.reset_on_line(2)  # after the STATE: the ALL of LEDs 1+7
    try:
        assert _calibrate(board, seen, tmp_path / "r.json", monkeypatch) == 0
    finally:
        del FAULTS["on the next change"]
    err = capsys.readouterr().err
    assert (
        f"{board.url}: the LED board reset (it printed its boot banner) at the LEDs' change to LEDs 1+7 lit: sent "
        "again (no frame was read since the board last answered)"
    ) in err, err
    assert err.count("the LED board reset") == 1, err
    np.testing.assert_array_equal(_curve(tmp_path / "r.json"), undisturbed)


@pytest.mark.parametrize("fault", FAULTS)
def test_a_board_reset_at_every_attempt_is_one_line_and_the_same_command_runs_again(
    board, fault, undisturbed, tmp_path, capsys, monkeypatch
):
    """Three attempts at the 1 ms frame, each cut short: the board in a boot loop as its LED lights."""
    first = READS["bracket"]
    seen = SeenBoard(board, lambda reads: reads in (first, first + FLUSH + 1, first + 2 * (FLUSH + 1)), fault)
    out = tmp_path / "r.json"
    assert _calibrate(board, seen, out, monkeypatch) == 2
    *retakes, line = errors_only(capsys.readouterr().err)
    assert len(retakes) == 2 and all(f"as {NAMED['bracket']} was taken" in r for r in retakes), retakes
    cable = ", or its USB cable is loose" if fault == "unplug" else ""
    assert line == (
        f"nlips calibrate-camera-response: error: {board.url}: the LED board reset at each of 3 attempts at "
        f"{NAMED['bracket']} ({REASONS[fault]}), so the bracket stopped: a board that resets as its LEDs light is "
        "often browning out (the LEDs powered from the board's 5 V, or a supply too weak: firmware/README.md, Wiring, "
        f"in the nlipscalib source distribution or repository){cable}; nothing was written (a tone curve is measured "
        "from the whole bracket): run it again"
    )
    assert not out.exists() and not out.with_suffix(".png").exists()
    assert not board.latched().any()  # the LEDs left dark
    seen.reset_at = lambda reads: False  # the supply fixed
    assert _calibrate(board, seen, out, monkeypatch) == 0
    np.testing.assert_array_equal(_curve(out), undisturbed)


@pytest.mark.parametrize("fault", FAULTS)
def test_a_board_reset_after_the_last_frame_is_a_warning_and_the_curve_is_written(
    board, fault, undisturbed, tmp_path, capsys, monkeypatch, caplog
):
    """The board reboots as the camera is released, after every frame was taken and answered for: the closing
    LEDs-off finds it."""
    caplog.set_level(logging.WARNING)
    out = tmp_path / "r.json"
    assert _calibrate(board, SeenBoard(board), out, monkeypatch, released=lambda: FAULTS[fault](board)) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [str(out)]
    assert "error" not in captured.err, captured.err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings[-1] == (
        f"{board.url}: the LED board reset after the bracket's last frame ({REASONS[fault]}; found as the LEDs were "
        "switched off at the end): each frame was kept once the board answered after it was read, so none was taken "
        "with the LEDs dark and the curve is fitted from them all; the LEDs are off. A board that resets as its LEDs "
        "light is often browning out (the LEDs powered from the board's 5 V, or a supply too weak: "
        "firmware/README.md, Wiring, in the nlipscalib source distribution or repository)"
        + (", or its USB cable is loose" if fault == "unplug" else "")
    ), warnings
    np.testing.assert_array_equal(_curve(out), undisturbed)
    assert not board.latched().any()  # the LEDs left dark


EMULATED = ["calibrate-camera-response", "--emulate", "nlipstac", "--width", "64", "--height", "48", "--spp", "1"]
EMULATED_READS = 3
"""The emulated camera's reads a frame: its flush of 2, then the frame (``open_emulated_sensor``'s defaults)."""


def _emulated(tmp_path, monkeypatch, reset_at=lambda reads: False) -> int:
    """``nlips calibrate-camera-response --emulate`` with its in-process board reset before the camera's reads
    ``reset_at`` says (from 1): the twin is rendered lit by what the board latched, so those frames are dark."""
    pytest.importorskip("mitsuba")
    from nlipscalib import emulator

    real = emulator.open_emulated_sensor

    def opened(*args, **kwargs):
        sensor = real(*args, **kwargs)
        read, reads = sensor.camera.read, [0]

        def resetting():
            reads[0] += 1
            if reset_at(reads[0]):
                sensor.board.reset()
            return read()

        monkeypatch.setattr(sensor.camera, "read", resetting)
        return sensor

    monkeypatch.setattr(emulator, "open_emulated_sensor", opened)
    return main([*EMULATED, "--out", str(tmp_path / "r.json")])


@pytest.fixture(scope="module")
def emulated_undisturbed(tmp_path_factory):
    out = tmp_path_factory.mktemp("emulated")
    with pytest.MonkeyPatch.context() as monkeypatch:
        assert _emulated(out, monkeypatch) == 0
    return _curve(out / "r.json")


def test_a_reset_of_the_emulated_sensors_board_during_the_bracket_is_watched_as_a_real_boards(
    emulated_undisturbed, tmp_path, capsys, monkeypatch
):
    """`--emulate` was not watched (s40): its board's reset before the 1 ms frame went unseen, the frame kept dark
    (the twin renders what the board latched) and the curve fitted through it. Now as with --port: the frame taken
    again with the LED lit, the curve the undisturbed bracket's up to the retaken frames' own noise."""
    first = 2 * EMULATED_READS + 1  # the 3rd exposure's (1 ms) first read
    assert _emulated(tmp_path, monkeypatch, lambda reads: reads == first) == 0
    err = capsys.readouterr().err
    retakes = [line for line in err.splitlines() if "the LED board reset" in line]
    assert len(retakes) == 1 and retakes[0].endswith(
        "the LED board reset (it printed its boot banner) as the 1 ms frame with LED 1 lit was taken: the LEDs are "
        "set again and it is taken again"
    ), err
    assert np.abs(_curve(tmp_path / "r.json") - emulated_undisturbed).max() < 0.01


def test_a_reset_of_the_emulated_sensors_board_at_every_attempt_stops_the_bracket_in_one_line(
    tmp_path, capsys, monkeypatch
):
    """A board in a boot loop as its LED lights, emulated: the device's line, exit 2, nothing written."""
    first = 2 * EMULATED_READS + 1
    at = (first, first + EMULATED_READS, first + 2 * EMULATED_READS)
    assert _emulated(tmp_path, monkeypatch, lambda reads: reads in at) == 2
    *retakes, line = errors_only(capsys.readouterr().err)
    assert len(retakes) == 2 and all("as the 1 ms frame with LED 1 lit was taken" in r for r in retakes), retakes
    assert line.startswith("nlips calibrate-camera-response: error: nlipsemu://") and line.endswith(
        ": the LED board reset at each of 3 attempts at the 1 ms frame with LED 1 lit (it printed its boot banner), "
        "so the bracket stopped: a board that resets as its LEDs light is often browning out (the LEDs powered from "
        "the board's 5 V, or a supply too weak: firmware/README.md, Wiring, in the nlipscalib source distribution or "
        "repository); nothing was written (a tone curve is measured from the whole bracket): run it again"
    ), line
    assert not (tmp_path / "r.json").exists()
