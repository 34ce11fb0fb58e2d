"""Clear errors from the LED controller: missing port, permission, busy, versions, wrong device, bad input."""

import errno
import os
import threading
import time

import numpy as np
import pytest
import serial

from nlipscalib.core.errors import ConfigError, DeviceError, NlipsError, ShapeError
from nlipscalib.device import controller as c
from nlipscalib.device import port
from nlipscalib.device.virtual_board import VirtualBoard


def test_missing_port_names_it():
    with pytest.raises(c.PortNotFoundError, match=r"/dev/ttyNLIPS_missing: no such serial port \(is the board"):
        c.LedController.open("/dev/ttyNLIPS_missing")


def test_unknown_url_scheme():
    with pytest.raises(c.PortNotFoundError, match="not known"):
        c.LedController.open("nosuchscheme://x")


def test_permission_denied_says_how_to_fix_it():
    exc = serial.SerialException(errno.EACCES, "could not open port /dev/ttyACM0: [Errno 13] Permission denied")
    error = port._open_error("/dev/ttyACM0", exc)
    assert isinstance(error, c.PortPermissionError)
    assert "usermod -aG dialout" in str(error)


@pytest.mark.skipif(os.geteuid() == 0, reason="root may open any device")
def test_permission_denied_on_a_real_device():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    mode = os.stat(path).st_mode
    try:
        os.chmod(path, 0)
        with pytest.raises(c.PortPermissionError, match="dialout"):
            c.LedController.open(path)
    finally:
        os.chmod(path, mode)
        os.close(master)
        os.close(slave)


def test_errors_are_workbench_errors():
    assert issubclass(c.BoardResetError, DeviceError) and issubclass(DeviceError, NlipsError)


def test_wrong_protocol_version():
    board = VirtualBoard(4, protocol=2)
    with pytest.raises(c.ProtocolVersionError, match="speaks LED protocol 2, this nlipscalib speaks 1"):
        c.LedController.open(board.url, timeout=0.2)


def test_wrong_firmware_version():
    board = VirtualBoard(4, firmware="2.0.0")
    with pytest.raises(c.ProtocolVersionError, match="firmware 2.0.0") as raised:
        c.LedController.open(board.url, timeout=0.2)
    # it said "(firmware/README.md)": an installed wheel has no firmware/ to look in
    assert str(raised.value).endswith("(firmware/README.md in the nlipscalib source distribution or repository)")


def test_wrong_led_count():
    board = VirtualBoard(4)
    with pytest.raises(DeviceError, match="drives 4 LEDs but 12 are expected"):
        c.LedController.open(board.url, timeout=0.2, expected_leds=12)


def test_silent_port_times_out_with_a_hint():
    master, slave = os.openpty()  # a port nothing answers on (loop:// echoes: a test of its own)
    try:
        with pytest.raises(c.DeviceTimeoutError, match="no answer to HELLO after 2 tries.*firmware"):
            c.LedController.open(os.ttyname(slave), timeout=0.1, retries=1)
    finally:
        os.close(master)
        os.close(slave)


def test_a_loopback_is_told_from_a_silent_port():
    """loop:// sends every line back: "nothing came back" and the firmware hint were wrong for it."""
    with pytest.raises(c.DeviceTimeoutError) as info:
        c.LedController.open("loop://", timeout=0.05, retries=1, baudrate=57600)
    message = str(info.value)
    assert message.startswith("loop://: no answer to HELLO after 2 tries of 0.05 s: the port echoes what is sent ")
    assert "(a loopback, no board on it)" in message
    assert "nothing came back" not in message and "firmware" not in message and "baud" not in message


def test_an_adalight_board_is_recognised():
    master, slave = os.openpty()
    stop = threading.Event()

    def adalight_banner():  # what Adalight firmware prints, over and over, until a frame arrives
        while not stop.is_set():
            os.write(master, b"Ada\n")
            time.sleep(0.02)

    thread = threading.Thread(target=adalight_banner, daemon=True)
    thread.start()
    try:
        with pytest.raises(c.WrongDeviceError, match="Adalight.*AdalightController"):
            c.LedController.open(os.ttyname(slave), timeout=0.1, retries=1)
    finally:
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)


def test_bad_colours_are_refused_before_sending():
    board = VirtualBoard(3)
    with c.LedController.open(board.url, timeout=0.2) as leds:
        with pytest.raises(ShapeError, match=r"shape \(3, 3\)"):
            leds.set_all(np.zeros((4, 3), np.uint8))
        with pytest.raises(ShapeError, match="0..255"):
            leds.set_all(np.full((3, 3), 300))
        with pytest.raises(ShapeError):
            leds.set_led(0, (1.5, 0, 0))
        leds.set_all(np.full((3, 3), 200))  # plain ints 0..255 are fine
        assert board.latched.min() == 200
    with pytest.raises(DeviceError, match="closed"):
        leds.off()


def test_a_board_at_another_line_rate_is_told_from_a_silent_one():
    """Bytes that form no line (what a UART at another rate makes of the board's banner and replies) say so, with
    the rates; a silent port says nothing came back; text lines from other firmware are quoted."""
    board = VirtualBoard(2, baudrate=57600)
    with pytest.raises(c.DeviceTimeoutError, match=r"sent \d+ bytes that form no protocol line.*115200 baud, the"):
        c.LedController.open(board.url, timeout=0.05, retries=0)
    master, slave = os.openpty()  # a port nothing answers on
    try:
        with pytest.raises(c.DeviceTimeoutError, match="nothing came back.*at 57600 baud but the nlips LED firmware"):
            c.LedController.open(os.ttyname(slave), timeout=0.05, retries=0, baudrate=57600)
    finally:
        os.close(master)
        os.close(slave)
    master, slave = os.openpty()
    stop = threading.Event()

    def garbage():  # framing errors with newlines among them: lines, but no text
        while not stop.is_set():
            os.write(master, bytes(range(0x80, 0x100)) + b"\n\xfe\xff\n")
            time.sleep(0.01)

    thread = threading.Thread(target=garbage, daemon=True)
    thread.start()
    try:
        with pytest.raises(c.DeviceTimeoutError, match="form no protocol line") as info:
            c.LedController.open(os.ttyname(slave), timeout=0.05, retries=0)
        assert "It printed" not in str(info.value)
    finally:
        stop.set()
        thread.join()
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("rate", [0, -1, 12345, 9600.5, True, "fast"])
def test_a_rate_off_the_standard_set_is_refused_before_the_port_opens(rate):
    """pyserial's own message for baudrate=0 read like a bad port name ("use a device such as /dev/ttyACM0")."""
    board = VirtualBoard(2)
    with pytest.raises(ConfigError, match=rf"{board.url}: baudrate: must be a standard serial rate.*got {rate!r}"):
        c.LedController.open(board.url, baudrate=rate)
    assert not board.executed
    assert c.check_baudrate("57600", "--baud") == 57600


@pytest.mark.parametrize(
    "payload, message",
    [
        ("fw=1.0.0 proto=1 leds=-3 sid=0001", "LED count -3 out of range (1..255)"),
        ("fw=1.0.0 proto=1 leds=0 sid=0001", "LED count 0 out of range (1..255)"),
        ("fw=1.0.0 proto=1 leds=99999999999999999999 sid=0001", "LED count 99999999999999999999 out of range"),
        ("fw=1.0.0 proto=1 leds=x sid=zz", "malformed board description"),
    ],
)
def test_a_hello_with_a_bad_led_count_is_one_line_naming_the_port(capsys, payload, message):
    """leds=-3 and a 20-digit count ended in a numpy traceback (negative dimensions, maximum dimension exceeded),
    leds=0 was accepted as a board with no LEDs."""
    from nlipscalib.cli import main

    from .fakes import PtyBoard, hello_then, protocol_line

    with PtyBoard(hello_then(lambda seq: protocol_line(f"{seq} OK"), payload)) as board:
        assert main(["leds", board.url, "info", "--timeout", "0.2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nlips leds: error: {board.url}: unexpected HELLO answer: ") and message in err
    assert err.count("\n") == 1


def test_decode_info_checks_the_led_count():
    from nlipscalib.device import protocol as p

    assert p.decode_info("fw=1.0.0 proto=1 leds=255 sid=0001").n_leds == p.MAX_LEDS == 255
    for count in ("0", "256", "-1"):
        with pytest.raises(p.FrameError, match=f"LED count {count} out of range"):
            p.decode_info(f"fw=1.0.0 proto=1 leds={count} sid=0001")


def test_a_boot_banner_with_bad_fields_is_one_line_naming_the_port(capsys):
    """A banner whose checksum holds but whose fields do not parse raised protocol.FrameError (not a DeviceError):
    a traceback, exit 1."""
    from nlipscalib.cli import main

    from .fakes import PtyBoard, hello_then, protocol_line

    def banner_then_ok(seq):
        return protocol_line("BOOT fw=1.0.0 proto=1 leds=x sid=zz", start="!") + protocol_line(f"{seq} OK")

    with PtyBoard(hello_then(banner_then_ok)) as board:
        assert main(["leds", board.url, "test", "--dwell", "0", "--timeout", "0.2"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"nlips leds: error: {board.url}: unexpected boot banner: malformed board description")
    assert err.count("\n") == 1 and "Traceback" not in err


def test_replies_that_fail_their_checksum_are_named_so_not_a_line_rate():
    """Every reply with a wrong CRC was blamed on the line rate ("bytes that form no protocol line, as a board
    running at another line rate does") after "4 tries of 1 s" that lasted 0.4 s together."""
    from .fakes import PtyBoard, protocol_line

    def bad_crc(seq, command):
        return protocol_line(f"{seq} OK fw=1.0.0 proto=1 leds=12 sid=0001", crc="0000")

    with PtyBoard(bad_crc) as board, pytest.raises(c.DeviceTimeoutError) as info:
        c.LedController.open(board.url, timeout=1.0, retries=3)
    message = str(info.value)
    assert message.startswith(f"{board.url}: no valid answer to HELLO in 4 tries: it answered, but 4 of its lines ")
    assert "failed the checksum (CRC-16): noise on the line" in message and "another protocol" in message
    assert "line rate" not in message and "tries of 1 s" not in message


def test_replies_that_fail_their_checksum_mid_session_say_so():
    from .fakes import PtyBoard, hello_then, protocol_line

    with PtyBoard(hello_then(lambda seq: protocol_line(f"{seq} OK", crc="0000"))) as board:
        with (
            c.LedController.open(board.url, timeout=1.0, retries=2) as leds,
            pytest.raises(c.DeviceTimeoutError) as info,
        ):
            leds.off()
    assert str(info.value) == (
        f"{board.url}: no valid answer to OFF in 3 tries: every reply failed its checksum (CRC-16): noise on the "
        "line (a loose or long unshielded USB cable), or a device speaking another protocol with the same line markers"
    )


def test_another_firmwares_text_is_quoted_as_text():
    """It was quoted as a Python bytes repr, each line cut at 30 bytes: b'> Welcome to FooBar firmware v | ...'."""
    from .fakes import PtyBoard

    with PtyBoard(lambda seq, command: b"Welcome to FooBar firmware v2.3 (c) 2024 FooBar Inc.\r\n") as board:
        with pytest.raises(c.DeviceTimeoutError) as info:
            c.LedController.open(board.url, timeout=0.1, retries=1)
    message = str(info.value)
    assert 'It printed "Welcome to FooBar firmware v2.3 (c) 2024 FooBar Inc.". Is the nlips' in message, message
    assert "b'" not in message
    assert c._quoted([b"x" * 100]) == "x" * 57 + "..." and c._quoted([b"caf\xe9"]) == "caf\ufffd"
