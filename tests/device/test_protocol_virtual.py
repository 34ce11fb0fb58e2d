"""Fault injection of the virtual board (the shared suite in test_protocol_boards.py covers the rest)."""

import time
import types

import pytest

from nlipscalib.device.controller import LedController, PortNotFoundError
from nlipscalib.device.virtual_board import VirtualBoard


@pytest.fixture
def board_and_leds():
    board = VirtualBoard(4)
    with LedController.open(board.url, timeout=0.2, retries=2) as leds:
        yield board, leds


@pytest.mark.parametrize("fault", ["corrupt_replies", "half_replies", "mute"])
def test_a_damaged_or_lost_line_costs_one_resend(board_and_leds, fault):
    board, leds = board_and_leds
    before = len(board.executed)
    getattr(board, fault)(1)
    leds.set_led(2, (4, 5, 6))
    assert leds.resends == 1
    assert board.latched[2].tolist() == [4, 5, 6]
    # a lost command line was executed once; a damaged reply's command twice (all commands are idempotent)
    assert len(board.executed) - before == (1 if fault == "mute" else 2)


def test_reply_comes_after_the_board_delay(monkeypatch):
    """A board that answers late: it waits its delay before the reply, and the controller waits for that reply
    (within its timeout) rather than failing. The board's wait is recorded, not clocked."""
    from nlipscalib.device import virtual_board

    slept = []

    def sleep(seconds: float) -> None:
        slept.append(seconds)
        time.sleep(seconds)

    board = VirtualBoard(2, reply_delay_s=0.05)
    with LedController.open(board.url, timeout=1.0) as leds:
        monkeypatch.setattr(virtual_board, "time", types.SimpleNamespace(**{**vars(time), "sleep": sleep}))
        before = len(board.executed)
        leds.off()
        assert [body.split()[1:] for body in board.executed[before:]] == [["OFF"]]  # executed once: no retry
    assert slept == [0.05]  # its one reply came after the delay


def test_unplugged_board_cannot_be_opened():
    board = VirtualBoard(2)
    board.unplug()
    with pytest.raises(PortNotFoundError, match="no such serial port"):
        LedController.open(board.url, timeout=0.1)
    board.plug()
    with LedController.open(board.url, timeout=0.5) as leds:
        assert leds.n_leds == 2
