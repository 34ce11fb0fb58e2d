"""Clear errors from the LED controller: missing port, permission, busy, versions, wrong device, bad input."""

import errno
import os
import threading
import time

import numpy as np
import pytest
import serial

from nlipscalib.device import controller as c
from nlipscalib.device.virtual_board import VirtualBoard
from nlipscalib.errors import ConfigError, DeviceError, NlipsError, ShapeError


def test_missing_port_names_it():
    with pytest.raises(c.PortNotFoundError, match=r"/dev/ttyNLIPS_missing: no such serial port \(is the board"):
        c.LedController.open("/dev/ttyNLIPS_missing")


def test_unknown_url_scheme():
    with pytest.raises(c.PortNotFoundError, match="not known"):
        c.LedController.open("nosuchscheme://x")


def test_permission_denied_says_how_to_fix_it():
    exc = serial.SerialException(errno.EACCES, "could not open port /dev/ttyACM0: [Errno 13] Permission denied")
    error = c._open_error("/dev/ttyACM0", exc)
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
    with pytest.raises(c.ProtocolVersionError, match="firmware 2.0.0"):
        c.LedController.open(board.url, timeout=0.2)


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
