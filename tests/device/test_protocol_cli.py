"""``nlips leds``: check and drive the LED controller from the command line (virtual board and simavr firmware)."""

import pytest

from nlipscalib.cli import main

from .ledboards import SimavrUnderTest, firmware_build


def test_leds_test_on_the_virtual_board(capsys):
    assert main(["leds", "virtual:3", "test", "--dwell", "0"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert [line.split(":")[0] for line in out] == ["LED 0", "LED 1", "LED 2", "all red", "all green", "all blue", "ok"]
    assert out[-1].startswith("ok: 6 steps")


def test_leds_info_and_bad_input(capsys):
    assert main(["leds", "virtual:5", "info"]) == 0
    assert "protocol 1, 5 LEDs" in capsys.readouterr().out
    with pytest.raises(SystemExit) as exit_info:
        main(["leds", "virtual", "set", "1", "2", "3"])
    assert exit_info.value.code == 2
    assert "set takes 4 numbers" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["leds", "virtual:many", "info"])
    assert "virtual:N needs an LED count" in capsys.readouterr().err


def test_missing_port_is_one_line(capsys):
    assert main(["leds", "/dev/ttyNLIPS_none", "info"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("nlips leds: error: /dev/ttyNLIPS_none: no such serial port") and "Traceback" not in err


def test_leds_commands_on_the_firmware(tmp_path, capsys):
    board = SimavrUnderTest(*firmware_build(), tmp_path / "tty")
    try:
        assert main(["leds", board.url, "set", "2", "10", "20", "30"]) == 0
        assert board.latched()[2].tolist() == [10, 20, 30]
        assert main(["leds", board.url, "state"]) == 0
        assert "LED 2: 10 20 30" in capsys.readouterr().out
        assert main(["leds", board.url, "all", "5", "6", "7"]) == 0
        assert board.latched().tolist() == [[5, 6, 7]] * 12
        assert main(["leds", board.url, "test", "--dwell", "0", "--level", "9"]) == 0
        assert capsys.readouterr().out.splitlines()[-1].startswith("ok: 15 steps")
        assert board.latched().sum() == 0  # the test ends with the LEDs off
    finally:
        board.close()
