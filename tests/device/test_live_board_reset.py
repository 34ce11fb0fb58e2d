"""`nlips live` when the LED board reboots mid-stream (a brown-out, the watchdog, the reset button), run as a user
runs it: a camera that sees what the board's LEDs show, the virtual board and the firmware in simavr (its MCU reset
by the harness; skipped without gcc-avr, avr-libc and simavr, failed when NLIPS_REQUIRE_DEVICE_TOOLS=1).

What the user must see: one warning, the tri-colour pattern relit and the stream going on, no map saved from a frame
read as the reset was found; a board that resets at every frame ends the stream in one line (exit 2), the maps saved
before it kept; the LEDs dark once the command ends, whatever happened.
"""

from __future__ import annotations

import logging

import numpy as np
import pytest

pytest.importorskip("cv2")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.device import camera as device_camera  # noqa: E402
from nlipscalib.device.controller import BoardResetError, LedController  # noqa: E402
from nlipscalib.device.lights_out import lights_out_on_exit  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402
from tests.processes import wait_until  # noqa: E402

from .fakes import errors_only, flat_predictor  # noqa: E402
from .ledboards import board_under_test  # noqa: E402
from .test_capture_board_reset import PinCamera  # noqa: E402

FRAMES = 8
RESET_AFTER = {}
"""``board``: what :func:`resetting_predictor` resets as it infers frame ``frame`` (1-based), after its read."""


@pytest.fixture(params=["virtual", "simavr"])
def led_board(request, tmp_path):
    under_test = board_under_test(request.param, tmp_path)
    yield under_test
    under_test.close()


def resetting_predictor(shape):
    """:func:`~tests.device.fakes.flat_predictor` that resets ``RESET_AFTER["board"]`` as it infers frame
    ``RESET_AFTER["frame"]``: after the read that asked the board, so found only by what comes next."""
    predict, calls = flat_predictor(shape), [0]

    def resetting(frame):
        calls[0] += 1
        if calls[0] == RESET_AFTER["frame"]:
            RESET_AFTER["board"].reset()
        return predict(frame)

    return resetting


class LivePinCamera(PinCamera):
    """:class:`PinCamera` as a live camera (its stale frames flushed once the pattern is lit)."""

    live = True

    def flush(self):
        pass


def live(board, camera, tmp_path, monkeypatch, predictor: str = "tests.device.fakes:flat_predictor") -> int:
    monkeypatch.setattr(device_camera, "open_source", lambda *args, **kwargs: camera)
    args = ["live", "--camera", "pin", "--port", board.url, "--predictor", predictor]
    return main([*args, "--no-window", "--max-frames", str(FRAMES), "--out", str(tmp_path / "maps")])


def saved_depths(tmp_path) -> list[float]:
    """Each saved map's depth (flat_predictor: the frame's mean green value / 1000), frame by frame."""
    return [float(np.load(f)["depth"].mean()) for f in sorted((tmp_path / "maps").glob("frame_*.npz"))]


def test_a_board_reset_mid_stream_is_one_warning_the_pattern_relit_and_no_dark_map_saved(
    tmp_path, capsys, monkeypatch, caplog
):
    """The stream went on with the LEDs dark and saved dark maps for every later frame; its end's OFF found the
    reset, the driver relit the pattern and raised its capture advice ("... retake any frame captured since the
    previous command"), exit 2 after "saved: 8 of 8 frames", and the LEDs were left lit."""
    caplog.set_level(logging.WARNING)
    board = VirtualUnder()  # its banner at once: found by the next read (the firmware's comes later, at its pace)
    camera = LivePinCamera(board, lambda reads: reads == 4)
    assert live(board, camera, tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    assert errors_only(err) == [line for line in err.splitlines() if line.startswith(("8 frames in", "saved: 8 of 8"))]
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    ours = [w for w in warnings if "reset during the stream" in w]
    assert len(ours) == 1 and "the tri-colour pattern is lit again" in ours[0] and "browning out" in ours[0], warnings
    depths = saved_depths(tmp_path)
    assert len(depths) == FRAMES and np.ptp(depths) < 1e-3 * depths[0], depths  # every map of a lit frame
    assert wait_until(lambda: not board.latched().any()), "the LEDs are dark once the stream ended"


def test_a_board_reset_at_the_last_frame_is_one_warning_exit_0_and_the_leds_left_dark(
    led_board, tmp_path, capsys, monkeypatch, caplog
):
    """Found by the LEDs' OFF at the end: it said the driver's "... retake any frame captured since the previous
    command", and the LEDs were left lit in the pattern the driver had restored; then (s37) "the maps of its last
    frames may show the LEDs dark", which the watch for dark frames now rules out (s38); until s40 it said the line
    below as an error, exit 2, though every frame was kept as one before a reset found during the stream is (exit 0)."""
    caplog.set_level(logging.WARNING)
    board = led_board
    camera = LivePinCamera(board, lambda reads: False)
    monkeypatch.setitem(RESET_AFTER, "board", board)
    monkeypatch.setitem(RESET_AFTER, "frame", FRAMES)
    predictor = "tests.device.test_live_board_reset:resetting_predictor"
    assert live(board, camera, tmp_path, monkeypatch, predictor) == 0
    err = capsys.readouterr().err
    assert "error" not in err and "Traceback" not in err, err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert warnings[-1].startswith(
        f"{board.url}: the LED board reset as the stream ended, after its last frame ("
    ) and warnings[-1].endswith(
        f"; found as the LEDs were switched off): its {FRAMES} frames were each read with the board found lit and "
        "none dark, and are kept; the LEDs are off. A board that resets as its LEDs light is often browning out (the "
        "LEDs powered from the board's 5 V, or a supply too weak: firmware/README.md, Wiring, in the nlipscalib source "
        "distribution or repository)"
    ), warnings
    assert f"{FRAMES} frames in" in err
    assert len(saved_depths(tmp_path)) == FRAMES  # every frame's maps kept
    assert wait_until(lambda: not board.latched().any()), "the LEDs are dark once the stream ended"


def test_a_board_that_resets_at_every_frame_ends_the_stream_in_one_line(tmp_path, capsys, monkeypatch):
    board = VirtualUnder()
    camera = LivePinCamera(board, lambda reads: reads >= 4)
    assert live(board, camera, tmp_path, monkeypatch) == 2
    err = capsys.readouterr().err
    assert errors_only(err)[-1] == (
        f"nlips live: error: {board.url}: the LED board reset at each of 3 frames in a row, so the stream stopped: a "
        "board that resets as its LEDs light is often browning out (the LEDs powered from the board's 5 V, or a "
        "supply too weak: firmware/README.md, Wiring, in the nlipscalib source distribution or repository)"
    )
    assert "3 frames in" in err and "Traceback" not in err
    assert len(saved_depths(tmp_path)) == 3  # the maps before it kept
    assert not board.latched().any()


def test_lights_out_switches_the_leds_off_when_the_off_finds_a_reset():
    """The driver relit the last colours as the OFF found the reset, and raised: the LEDs were left lit."""
    with VirtualBoard(12) as vboard, LedController.open(vboard.url, timeout=0.5) as leds:
        with pytest.raises(BoardResetError, match="board reset detected"):
            with lights_out_on_exit(leds):
                leds.set_all(np.full((12, 3), 200, np.uint8))
                vboard.reset()
        assert not vboard.latched.any()


class VirtualUnder:
    """The virtual board as the tests of test_capture_board_reset.py drive it (``latched()``, ``reset()``)."""

    def __init__(self):
        self.board = VirtualBoard(12)
        self.url, self.n_leds = self.board.url, 12

    def latched(self):
        return self.board.latched

    def reset(self):
        self.board.reset()


def test_a_reset_whose_banner_never_comes_is_found_by_its_dark_frames_and_they_are_dropped(
    led_board, tmp_path, capsys, monkeypatch, caplog
):
    """A reset whose boot banner is lost on the line (or has not come yet: a board still booting) darkens the frames
    while the board says nothing: the stream saved a dark map for every later frame, silently, until the LEDs' OFF at
    the end found the lost session (exit 2). Now the first dark frame makes the watch ask the board (NOSESSION): the
    pattern relit, the dark frames dropped and counted in the summary, exit 0."""
    caplog.set_level(logging.WARNING)
    board = led_board

    def reset_unannounced(reads: int) -> bool:
        if reads == 4:
            board.reset_unannounced()
        return False

    camera = LivePinCamera(board, reset_unannounced)
    assert live(board, camera, tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    ours = [w for w in warnings if "reset during the stream" in w]
    assert len(ours) == 1 and "(it no longer knows the session)" in ours[0], warnings
    assert "the frames read while its LEDs were dark dropped (counted in the summary)" in ours[0]
    (summary,) = [line for line in err.splitlines() if line.startswith(f"{FRAMES} frames in")]
    assert summary.endswith(" more dropped, read while the LED board had reset"), summary
    depths = saved_depths(tmp_path)
    assert len(depths) == FRAMES and np.ptp(depths) < 1e-3 * depths[0], depths  # every map of a lit frame
    assert wait_until(lambda: not board.latched().any()), "the LEDs are dark once the stream ended"


class DarkLeds:
    """A board whose LEDs' supply is off from the 4th read: it answers, holds the pattern, and lights nothing."""

    def __init__(self, board):
        self.board, self.url, self.n_leds, self.reads = board, board.url, board.n_leds, 0

    def latched(self):
        return self.board.latched() * (self.reads < 4)

    def reset(self):
        self.board.reset()


def test_dark_frames_from_a_board_that_did_not_reset_are_streamed_with_one_warning(
    tmp_path, capsys, monkeypatch, caplog
):
    """The watch asks the board once when frames go dark; a board that holds the pattern lit did not reset: the
    frames are streamed (nothing dropped) and the user is told once to look at the LEDs' supply."""
    caplog.set_level(logging.WARNING)
    board = DarkLeds(VirtualUnder())

    def count(reads: int) -> bool:
        board.reads = reads
        return False

    assert live(board, LivePinCamera(board, count), tmp_path, monkeypatch) == 0
    err = capsys.readouterr().err
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    assert not any("reset" in w for w in warnings), warnings
    (dark,) = [w for w in warnings if "frames read dark" in w]
    assert dark.endswith(
        "while the LED board holds the tri-colour pattern lit, so they are streamed: is the LEDs' "
        "supply on and their cable seated?"
    ), dark
    assert "dropped" not in err and len(saved_depths(tmp_path)) == FRAMES
