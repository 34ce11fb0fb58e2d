"""``nlips leds``: check and drive the LED controller from the command line (virtual board and simavr firmware)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.device.virtual_board import VirtualBoard

from .ledboards import SimavrUnderTest, firmware_build

CLI = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
"""The nlips command in a fresh process."""


def test_leds_test_on_the_virtual_board(capsys):
    assert main(["leds", "virtual:3", "test", "--dwell", "0"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in out] == ["LED 1", "LED 2", "LED 3", "all red", "all green", "all blue", "ok"]
    assert out[-1].startswith("ok: 6 steps")


def test_leds_info_and_bad_input(capsys):
    assert main(["leds", "virtual:5", "info"]) == 0
    assert "protocol 1, 5 LEDs" in capsys.readouterr().out
    assert main(["leds", "virtual", "set", "1", "2", "3"]) == 2
    err = capsys.readouterr().err
    assert err == "nlips leds: error: set takes 4 numbers, got 3\n"  # one line, no usage block
    assert main(["leds", "virtual:many", "info"]) == 2
    assert "virtual:N needs an LED count" in capsys.readouterr().err
    assert main(["leds", "virtual", "all", "1", "2", "256"]) == 2
    assert "colour values must be 0..255, got 1 2 256" in capsys.readouterr().err
    assert main(["leds", "virtual", "test", "--level", "300"]) == 2
    assert "--level must be 0..255, got 300" in capsys.readouterr().err


def test_changes_are_confirmed_on_one_line(capsys):
    """set, all and off printed nothing on success."""
    board = VirtualBoard(3)
    assert main(["leds", board.url, "set", "3", "255", "255", "255"]) == 0
    assert capsys.readouterr().out == "LED 3 set to 255 255 255\n"
    assert main(["leds", board.url, "all", "1", "2", "3"]) == 0
    assert capsys.readouterr().out == "all 3 LEDs set to 1 2 3\n"
    assert main(["leds", board.url, "off"]) == 0
    assert capsys.readouterr().out == "all 3 LEDs off\n"
    ada = VirtualBoard(2, adalight=True)
    assert main(["leds", ada.url, "set", "2", "4", "5", "6", "--adalight", "2"]) == 0
    assert capsys.readouterr().out == "LED 2 set to 4 5 6 (sent; Adalight does not acknowledge)\n"


def test_errors_name_the_port_as_typed(capsys):
    """`virtual` starts a board at nlipsemu://N: the message named that URL, which the user never typed."""
    assert main(["leds", "virtual", "info", "--baud", "9600", "--timeout", "0.05"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips leds: error: virtual: no answer to HELLO") and err.count("\n") == 1
    assert "nlipsemu" not in err
    assert main(["leds", "virtual:3", "info", "--baud", "9600", "--timeout", "0.05"]) == 2
    assert capsys.readouterr().err.startswith("nlips leds: error: virtual:3: no answer to HELLO")


def test_loop_url_is_named_a_loopback(capsys):
    assert main(["leds", "loop://", "info", "--timeout", "0.05"]) == 2
    err = capsys.readouterr().err
    assert "loop://: no answer to HELLO" in err and "the port echoes what is sent (a loopback, no board on it)" in err
    assert "firmware flashed" not in err and err.count("\n") == 1


def test_leds_are_numbered_from_1_as_in_capture_files(capsys):
    """LED 1 is led_01.png, the protocol's index 0 (docs/conventions.md, docs/protocol.md)."""
    board = VirtualBoard(4, reset_on_open=False)  # keeps its LEDs from one command to the next
    assert main(["leds", board.url, "set", "1", "10", "20", "30"]) == 0
    assert main(["leds", board.url, "set", "4", "1", "2", "3"]) == 0
    assert board.latched.tolist() == [[10, 20, 30], [0, 0, 0], [0, 0, 0], [1, 2, 3]]
    assert capsys.readouterr().out.splitlines() == ["LED 1 set to 10 20 30", "LED 4 set to 1 2 3"]
    assert main(["leds", board.url, "state"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == ["LED 1: 10 20 30", "LED 2: 0 0 0", "LED 3: 0 0 0", "LED 4: 1 2 3"]
    assert main(["leds", "virtual:4", "set", "5", "1", "1", "1"]) == 2
    assert capsys.readouterr().err == "nlips leds: error: set: there is no LED 5: the board has 4 LEDs (1..4)\n"
    assert main(["leds", board.url, "set", "0", "1", "1", "1"]) == 2
    assert "LEDs are numbered from 1" in capsys.readouterr().err
    assert board.latched.tolist() == [[10, 20, 30], [0, 0, 0], [0, 0, 0], [1, 2, 3]]  # nothing changed


def test_nlipsemu_url_from_the_cli(capsys):
    """nlipsemu://ID: this process's board of that id, or one started for the command."""
    assert main(["leds", "nlipsemu://cli-test", "info"]) == 0
    assert "protocol 1, 12 LEDs" in capsys.readouterr().out
    board = VirtualBoard(3)  # a board of this process: the command drives it
    assert main(["leds", board.url, "all", "7", "8", "9"]) == 0
    assert board.latched.tolist() == [[7, 8, 9]] * 3
    assert main(["leds", "nlipsemu://", "info"]) == 2
    assert "nlipsemu:// needs a board id" in capsys.readouterr().err


def test_nlipsemu_url_from_the_installed_command(tmp_path):
    """The command as a user types it: a fresh process, nothing registered beforehand."""
    result = subprocess.run(
        [sys.executable, "-c", CLI, "leds", "nlipsemu://1", "test", "--dwell", "0"],
        capture_output=True,
        text=True,
        timeout=60,
        env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])},
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines()[0].startswith("LED 1: lit") and "ok: 15 steps" in result.stdout


def test_unknown_nlipsemu_board_says_what_the_url_reaches():
    from nlipscalib.device.controller import LedController, PortNotFoundError

    with pytest.raises(PortNotFoundError, match="no virtual board with this id in this process") as info:
        LedController.open("nlipsemu://no-such-board", timeout=0.1)
    assert "plugged in" not in str(info.value)


def test_a_started_board_not_kept_is_gone_and_the_line_says_to_keep_it():
    """docs/api.md's way to try the LED examples without hardware: `start_board(url, n)` whose board was not kept
    is garbage-collected (the process holds boards weakly), and the line said only "create it first"."""
    import gc

    from nlipscalib.device.controller import LedController, PortNotFoundError
    from nlipscalib.device.virtual_board import start_board

    board = start_board("nlipsemu://kept", 4)
    with LedController.open("nlipsemu://kept", timeout=1.0) as leds:
        assert leds.n_leds == 4
    start_board("nlipsemu://not-kept", 4)
    gc.collect()
    with pytest.raises(PortNotFoundError, match="create it first and keep it, e.g. board = virtual_board.start_board"):
        LedController.open("nlipsemu://not-kept", timeout=0.1)
    board.close()


def test_adalight_on_the_virtual_board(capsys, caplog):
    """--adalight with the virtual board: it runs Adalight (greets with Ada, latches frames), no banner wait."""
    assert main(["leds", "virtual", "test", "--adalight", "4", "--dwell", "0"]) == 0
    assert "banner" not in caplog.text  # it greeted: no 3 s wait for a banner that never comes, then a warning
    out = capsys.readouterr().out.splitlines()
    sent = " (sent; Adalight does not acknowledge)"
    assert out[:5] == [f"LED {k}{sent}" for k in range(1, 5)] + [f"all red{sent}"]
    board = VirtualBoard(3, adalight=True)
    assert main(["leds", board.url, "set", "2", "1", "2", "3", "--adalight", "3"]) == 0
    assert board.latched.tolist() == [[0, 0, 0], [1, 2, 3], [0, 0, 0]]
    assert main(["leds", "virtual:4", "info", "--adalight", "3"]) == 2
    assert "virtual:4 has 4 LEDs but --adalight says 3" in capsys.readouterr().err


def test_virtual_adalight_board_reads_frames_like_the_sketch(caplog):
    """Garbage, a bad checksum and a frame for another LED count are skipped; split writes are joined."""
    from nlipscalib.device.adalight import AdalightController, adalight_frame

    board = VirtualBoard(2, adalight=True)
    with AdalightController.open(board.url, 2, settle_s=0.0, boot_timeout=1.0) as leds:
        leds.set_all([[1, 2, 3], [4, 5, 6]])
        assert board.latched.tolist() == [[1, 2, 3], [4, 5, 6]]
        port = leds._port
        port.write(b"xxAda\x00\x01\x00" + bytes(6))  # checksum wrong: ignored
        port.write(adalight_frame(np.full((3, 3), 9, np.uint8)))  # 3 LEDs: not this strip's frame
        frame = adalight_frame(np.array([[7, 7, 7], [8, 8, 8]], np.uint8))
        port.write(frame[:4])
        assert board.latched.tolist() == [[1, 2, 3], [4, 5, 6]]
        port.write(frame[4:])
        assert board.latched.tolist() == [[7, 7, 7], [8, 8, 8]]
    assert "banner" not in caplog.text


def test_missing_port_is_one_line(capsys):
    assert main(["leds", "/dev/ttyNLIPS_none", "info"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips leds: error: /dev/ttyNLIPS_none: no such serial port") and "Traceback" not in err


def test_leds_commands_on_the_firmware(tmp_path, capsys):
    board = SimavrUnderTest(*firmware_build(), tmp_path / "tty")
    try:
        assert main(["leds", board.url, "set", "3", "10", "20", "30"]) == 0  # LED 3: protocol index 2
        assert board.latched()[2].tolist() == [10, 20, 30]
        assert main(["leds", board.url, "state"]) == 0
        assert "LED 3: 10 20 30" in capsys.readouterr().out
        assert main(["leds", board.url, "all", "5", "6", "7"]) == 0
        assert board.latched().tolist() == [[5, 6, 7]] * 12
        assert main(["leds", board.url, "test", "--dwell", "0", "--level", "9"]) == 0
        assert capsys.readouterr().out.splitlines()[-1].startswith("ok: 15 steps")
        assert board.latched().sum() == 0  # the test ends with the LEDs off
    finally:
        board.close()


def test_a_path_that_is_not_a_serial_port_is_one_line(tmp_path, capsys):
    """/dev/null or a folder: it said "could not open the port: Could not configure port: (25, 'Inappropriate
    ioctl for device')"."""
    for path in ("/dev/null", str(tmp_path)):
        assert main(["leds", path, "info"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"nlips leds: error: {path}: not a serial port") and err.count("\n") == 1, err


def test_baud_reaches_the_board_and_a_board_at_another_rate_is_one_line(capsys):
    """A board whose firmware runs at 57600 baud: driven with --baud 57600; at the default 115200 every byte is
    garbled both ways (the virtual board's UART), and the command says so in one line naming both rates."""
    board = VirtualBoard(3, baudrate=57600)
    assert main(["leds", board.url, "all", "1", "2", "3", "--baud", "57600"]) == 0
    assert board.latched.tolist() == [[1, 2, 3]] * 3
    capsys.readouterr()
    executed = list(board.executed)
    assert main(["leds", board.url, "off", "--timeout", "0.05"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err  # no resend warnings before it
    assert "no answer to HELLO" in err and "form no protocol line" in err
    assert "The port is at 115200 baud, the nlips LED firmware's rate; a board at another rate needs --baud" in err
    assert board.executed == executed  # the board read no line (it rebooted on the open, as an Uno does)
    assert main(["leds", "virtual:2", "info", "--baud", "9600", "--timeout", "0.05"]) == 2  # a virtual board: 115200
    assert "The port is at 9600 baud but the nlips LED firmware runs at 115200 (--baud)" in capsys.readouterr().err


def test_baud_sets_the_rate_of_a_serial_device():
    """--baud reaches the serial device itself (a pseudo-terminal stands in for /dev/ttyACM0 and keeps the rate
    the driver set); nothing answers on it, which the one-line error says."""
    import pty
    import termios

    master, slave = pty.openpty()
    try:
        path = os.ttyname(slave)
        result = subprocess.run(  # the installed command's way: its own process, its one line on stderr
            [sys.executable, "-c", CLI, "leds", path, "info", "--baud", "57600", "--timeout", "0.05"],
            capture_output=True,
            text=True,
            timeout=60,
            env=os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])},
        )
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        assert f"{path}: no answer to HELLO" in result.stderr and "nothing came back" in result.stderr
        assert "The port is at 57600 baud but the nlips LED firmware runs at 115200" in result.stderr
        ispeed, ospeed = termios.tcgetattr(slave)[4:6]
        assert ispeed == ospeed == termios.B57600
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("rate", ["abc", "0", "-9600", "12345", "9600.5"])
def test_a_baud_rate_pyserial_does_not_know_is_one_line(capsys, rate):
    board = VirtualBoard(2)
    assert main(["leds", board.url, "all", "1", "1", "1", f"--baud={rate}"]) == 2
    err = capsys.readouterr().err
    assert (
        err.startswith("nlips leds: error: --baud: must be a standard serial rate, one of 50, 75,")
        and err.count("\n") == 1
    ), err
    assert f"(the nlips LED firmware runs at 115200), got '{rate}'" in err
    assert board.latched.sum() == 0 and not board.executed  # refused before the port was opened


def test_adalight_test_and_state_claim_nothing_they_cannot_check(capsys, caplog):
    """`test --adalight` printed "LED k: lit" and "ok: 15 steps" with no board at all (loop://, a silent port), and
    `state --adalight` printed "LED 1: 0 0 0" as if read back; Adalight acknowledges nothing and reports no state."""
    import logging

    caplog.set_level(logging.WARNING)
    assert main(["leds", "loop://", "test", "--adalight", "3", "--dwell", "0"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "LED 1 (sent; Adalight does not acknowledge)" and len(out) == 7
    assert out[-1].startswith("sent: 6 steps; Adalight does not acknowledge, so nothing was checked")
    assert not any("lit" in line.split(";")[0] or line.startswith("ok") for line in out)
    assert main(["leds", "loop://", "state", "--adalight", "3"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips leds: error: state: an Adalight board cannot report what its LEDs show")
    assert err.count("\n") == 1


def test_adalight_warnings_name_the_port_as_typed(capsys, caplog):
    """`nlips leds virtual test --adalight 12 --baud 9600` warned about `nlipsemu://1`, a URL the user never typed."""
    import logging

    caplog.set_level(logging.WARNING)
    assert main(["leds", "virtual", "off", "--adalight", "2", "--baud", "9600"]) == 0
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert warnings and all(w.startswith("virtual: ") for w in warnings), warnings
    assert "nlipsemu://" not in caplog.text


def test_ctrl_c_during_leds_test_switches_the_leds_off_and_promises_no_resume(capsys, monkeypatch):
    """It ended "interrupted; finished work is kept, run again to resume", as if a test went on where it stopped."""
    import time

    board = VirtualBoard(3)
    real_sleep = time.sleep

    def ctrl_c_at_the_dwell(seconds):
        if seconds == 0.125:  # the test's dwell after LED 2 lit; other sleeps (the board's, pyserial's) run
            if board.latched[1].any():
                raise KeyboardInterrupt
        real_sleep(seconds)

    monkeypatch.setattr(time, "sleep", ctrl_c_at_the_dwell)
    assert main(["leds", board.url, "test", "--dwell", "0.125"]) == 130
    out, err = capsys.readouterr()
    assert out.splitlines()[-1].startswith("LED 2: lit")
    assert err.strip().splitlines()[-1] == (
        "nlips leds: interrupted; the test stopped and switched the LEDs off; a test does not resume (run it again "
        "from LED 1)"
    )
    assert not board.latched.any()


def test_an_interrupted_leds_command_or_tone_curve_measurement_promises_no_resume():
    from nlipscalib import cli

    parser = cli.build_parser()
    for argv in (["leds", "virtual", "set", "1", "9", "9", "9"], ["calibrate-camera-response", "--out", "c.json"]):
        line = cli._stopped(parser.parse_args(argv))
        assert "run again to resume" not in line and line.startswith("nothing"), (argv, line)


def test_a_board_that_resets_during_leds_test_is_one_line_naming_the_step(capsys, monkeypatch):
    """It ended with the driver's "... retake any frame captured since the previous command", a capture's advice,
    where a board resetting as its LEDs light is most often browning out."""
    from nlipscalib.device import virtual_board

    board, seen = VirtualBoard(3), []
    real = virtual_board._COMMANDS["ALL"]

    def all_command(b, args):
        seen.append(1)
        if len(seen) == 4:  # the first "all" step: the board reboots instead of lighting it
            b.reset()
            return None
        return real(b, args)

    monkeypatch.setitem(virtual_board._COMMANDS, "ALL", all_command)
    assert main(["leds", board.url, "test", "--dwell", "0"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("WARNING")]
    assert err == [
        f"nlips leds: error: {board.url}: the board reset as the test lit all red (it printed its boot banner): a "
        "board that resets as its LEDs light is often browning out (the LEDs powered from the board's 5 V, or a "
        "supply too weak: firmware/README.md, Wiring, in the nlipscalib source distribution or repository); run the "
        "test again (a lower --level draws less)"
    ]
    assert not board.latched.any()  # and the test left them dark
