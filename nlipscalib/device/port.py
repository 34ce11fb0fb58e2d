"""Opening the LED board's serial port or URL (``/dev/ttyACM0``, ``COM3``, ``loop://``, ``socket://``,
``nlipsemu://ID``) for both drivers, with one clear error per way it fails, and the line rate."""

from __future__ import annotations

import errno
from typing import TYPE_CHECKING

from ..core.errors import ConfigError, DeviceError, require
from .errors import PortBusyError, PortNotFoundError, PortPermissionError

if TYPE_CHECKING:  # pyserial is imported where it is used (``_serial``): named for the hints only
    import serial

BAUD_RATE = 115200
"""Line rate of the nlips LED firmware (firmware/src/uart.h) and of Adalight-FastLED, baud; the default of
every command that opens the LED port (``--baud``)."""
BITS_PER_BYTE = 10
"""Bits a byte takes on an 8N1 line (start, 8 data, stop)."""
READ_SLICE_S = 0.02
"""Longest single blocking read, so deadlines are checked often."""
NETWORK_SCHEMES = ("socket://", "rfc2217://")
"""URL schemes of an LED board behind a network serial server; its refusal names the server, not a cable."""


def wire_seconds(n_bytes: int, baudrate: int) -> float:
    """Time ``n_bytes`` take on an 8N1 serial line at ``baudrate`` (baud), s."""
    return n_bytes * BITS_PER_BYTE / baudrate


def _serial():
    serial = require("serial", "pyserial", "The LED controller")
    if "nlipscalib.device" not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append("nlipscalib.device")  # nlipsemu:// (virtual board)
    return serial


def check_baudrate(baudrate: int | str, where: str = "baudrate") -> int:
    """``baudrate`` as an int when it is one of pyserial's standard rates (``serial.SerialBase.BAUDRATES``).

    Why: pyserial refuses a non-positive rate with a ValueError that reads like a bad port name, and a
    non-standard one fails differently per platform (some only when the port opens); a rate outside the
    standard set is a typo far more often than a board's real setting.

    Parameters
    ----------
    baudrate : int or str
        Line rate, baud (the command line passes the text typed after ``--baud``).
    where : str
        What to name in the message (``--baud``, ``/dev/ttyACM0: baudrate``).

    Raises
    ------
    ConfigError
        One line naming ``where``, the standard rates and the firmware's.
    """
    rates = _serial().SerialBase.BAUDRATES
    try:
        value = int(str(baudrate).strip())  # str(): 9600.5 is refused, not truncated
    except ValueError:
        value = None
    if isinstance(baudrate, bool) or value not in rates:
        raise ConfigError(
            f"{where}: must be a standard serial rate, one of {', '.join(map(str, rates))} "
            f"(the nlips LED firmware runs at {BAUD_RATE}), got {baudrate!r}"
        )
    return value


def open_port(url: str, *, baudrate: int = BAUD_RATE, write_timeout: float = 1.0) -> serial.SerialBase:
    """Open ``url`` with ``serial.serial_for_url`` at ``baudrate``, turning failures into one clear error.

    Raises
    ------
    PortNotFoundError, PortPermissionError, PortBusyError, DeviceError
    ConfigError
        ``baudrate`` is not a standard rate (:func:`check_baudrate`).
    """
    serial = _serial()
    baudrate = check_baudrate(baudrate, f"{url}: baudrate")
    try:
        port = serial.serial_for_url(
            url, baudrate=baudrate, timeout=READ_SLICE_S, write_timeout=write_timeout, exclusive=True
        )
        _keep_dtr_after_close(port)
        return port
    except ValueError as exc:  # unknown URL scheme or bad settings
        raise PortNotFoundError(
            f"{url}: {exc} (use a device such as /dev/ttyACM0 or COM3, or loop://, socket://HOST:PORT, nlipsemu://ID)"
        ) from None
    except serial.SerialException as exc:
        raise _open_error(url, exc) from None


def _keep_dtr_after_close(port: serial.SerialBase) -> None:
    """Clear HUPCL on a POSIX serial port, so DTR stays up when the port closes.

    Why: an Arduino Uno resets on DTR's rising edge, and a USB serial port drops DTR on close (HUPCL is the
    kernel's default), so every ``nlips leds`` command reset the board and found its LEDs dark: ``set`` then
    ``state`` reported nothing lit. With DTR kept up the next open finds it up and the board keeps its LEDs and
    session; the first open after plugging in still resets it (HELLO is resent until the bootloader is done).
    Other ports (``loop://``, ``socket://``, ``nlipsemu://``, Windows) have no such flag and are left alone."""
    fd = getattr(port, "fd", None)
    try:
        import termios
    except ImportError:  # Windows
        return
    if not isinstance(fd, int):
        return
    try:
        attrs = termios.tcgetattr(fd)
        if attrs[2] & termios.HUPCL:
            attrs[2] &= ~termios.HUPCL
            termios.tcsetattr(fd, termios.TCSANOW, attrs)
    except (OSError, termios.error):  # not a terminal device: nothing to keep
        return


def _open_error(url: str, exc: Exception) -> DeviceError:
    code = getattr(exc, "errno", None)
    if code in (errno.EACCES, errno.EPERM):
        return PortPermissionError(
            f"{url}: permission denied. Add yourself to the group that owns the port "
            "(Debian/Ubuntu: sudo usermod -aG dialout $USER; Arch: uucp), then log out and back in"
        )
    if code in (errno.EBUSY, errno.EAGAIN) or "lock" in str(exc).lower():
        return PortBusyError(f"{url}: port busy: another program has it open (an Arduino serial monitor?)")
    if "no such virtual board" in str(exc):
        return PortNotFoundError(
            f"{url}: no virtual board with this id in this process (nlipsemu://ID reaches a VirtualBoard of the "
            "same Python process: create it first and keep it, e.g. board = virtual_board.start_board(url, n_leds), "
            "as the process holds boards weakly; the nlips commands start theirs)"
        )
    if code in (errno.ENOTTY, errno.EISDIR) or "Inappropriate ioctl" in str(exc) or "Is a directory" in str(exc):
        return PortNotFoundError(
            f"{url}: not a serial port (boards appear as /dev/ttyACM0, /dev/ttyUSB0, COM3). {_ports_present()}"
        )
    if code == errno.ENOENT or "no such" in str(exc).lower():
        return PortNotFoundError(f"{url}: no such serial port (is the board plugged in?). {_ports_present()}")
    if url.startswith(NETWORK_SCHEMES):
        # pyserial says "Could not open port URL: [Errno 111] Connection refused": the URL twice, no way out
        reason = str(exc).removeprefix(f"Could not open port {url}: ")
        return DeviceError(
            f"{url}: could not connect ({reason}): is the serial server (ser2net, an RFC 2217 server, esp-link) "
            "running at this host and port, and reachable from here?"
        )
    return DeviceError(f"{url}: could not open the port: {exc}")


def _ports_present() -> str:
    try:
        from serial.tools import list_ports

        names = sorted(port.device for port in list_ports.comports())
    except Exception:  # noqa: BLE001 - listing is only a hint
        return ""
    return f"Serial ports present: {', '.join(names)}" if names else "No serial ports are present."
