"""Host driver for the nlips LED controller (protocol: docs/protocol.md, firmware: firmware/).

Every call returns only after the board acknowledged that the LEDs latched the new colours, so a camera
frame grabbed afterwards shows the new light. Lines are checked (CRC-16) and numbered; a lost or corrupted
line is resent, garbage and half lines are skipped, an unplugged board is reopened, a rebooted board is
detected (boot banner, or a board that lost its session).

Usage::

    with LedController.open("/dev/ttyACM0") as leds:      # or loop://, socket://host:port, nlipsemu://1
        leds.set_led(3, (255, 255, 255))
        leds.set_all(np.zeros((leds.n_leds, 3), np.uint8))

The port is opened by :mod:`.port`, the errors are in :mod:`.errors`, switching the LEDs off on the way out is
:mod:`.lights_out`; their public names are importable from here too.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike

from ..core.errors import NUMBER, ConfigError, DeviceError, ShapeError, check_kind, check_whole
from . import protocol as p
from .errors import (
    UNPLUGGED_REASON,
    BoardError,
    BoardResetError,
    DeviceDisconnectedError,
    DeviceTimeoutError,
    LedIndexError,
    PortBusyError,
    PortNotFoundError,
    PortPermissionError,
    ProtocolVersionError,
    WrongDeviceError,
)
from .lights_out import LIGHTS_OUT_TIMEOUT_S, lights_out_on_exit, off_quietly
from .port import BAUD_RATE, _serial, check_baudrate, open_port, wire_seconds

__all__ = [
    "BAUD_RATE",
    "LIGHTS_OUT_TIMEOUT_S",
    "BoardError",
    "BoardResetError",
    "DeviceDisconnectedError",
    "DeviceTimeoutError",
    "LedController",
    "LedIndexError",
    "PortBusyError",
    "PortNotFoundError",
    "PortPermissionError",
    "ProtocolVersionError",
    "WrongDeviceError",
    "check_baudrate",
    "lights_out_on_exit",
    "off_quietly",
    "open_port",
]

log = logging.getLogger(__name__)

SUPPORTED_FIRMWARE_MAJOR = 1
"""Firmware major version this driver works with (the firmware in firmware/ reports 1.x.y)."""
FIRMWARE_GUIDE = "firmware/README.md in the nlipscalib source distribution or repository"
"""Where flashing the nlips LED firmware is explained, as messages name it: the firmware and its guide come with
the sdist and the repository, not with an installed wheel, where a bare "firmware/README.md" is found nowhere."""
MAX_RX_BUFFER = 8192
REPLY_BYTES = 64
"""Longest reply but STATE's (HELLO's: ``<01 OK fw=1.0.0 proto=1 leds=12 sid=0001*e6aa``, 46 bytes, with room for a
longer version), bytes: with the command line, the line time added to the reply timeout."""
STATE_REPLY_BYTES = 16
"""STATE's reply besides its 6 hex digits per LED (``<SS OK `` and ``*CCCC``, newline), bytes."""


class LedController:
    """A session with the nlips LED firmware (or the virtual board). Create with LedController.open().

    Attributes
    ----------
    n_leds : int
        Number of LEDs the board drives.
    firmware : str
        Firmware version the board reported.
    info : protocol.BoardInfo
        Everything HELLO reported (firmware, protocol, LED count, session id).
    acknowledged : bool
        True: each call returns after the board confirmed the LEDs latched (no settle delay needed).
    resets, reconnects, resends : int
        How often the board rebooted, the port was reopened, a line was sent again.
    """

    acknowledged = True

    def __init__(self, url: str, *, timeout: float, retries: int, reconnect_s: float, on_reset: str, baudrate: int):
        if on_reset not in ("raise", "restore"):
            raise ValueError(f"on_reset must be 'raise' or 'restore', got {on_reset!r}")
        self.url, self.timeout, self.retries = url, float(timeout), int(retries)
        self.reconnect_s, self.on_reset, self.baudrate = float(reconnect_s), on_reset, baudrate
        self.resets = self.reconnects = self.resends = 0
        self._port = None
        self._rx = bytearray()
        self._seq = 0
        self._lock = threading.RLock()
        self._reset_seen = False
        self._foreign: list[bytes] = []
        self._unreadable = 0
        """Bytes received since HELLO was last sent that formed no protocol line (for the no-answer message)."""
        self._sent = b""
        """The last line written, without its newline: a line that comes back equal to it is an echo."""
        self._echoes = 0
        """Lines received since HELLO was last sent that were the line sent (a loopback, for the no-answer message)."""
        self._bad_checksums = 0
        """Well-formed protocol lines received since HELLO was last sent whose checksum failed (for the no-answer
        message: noise, or another protocol with the same markers; never a line rate)."""
        self._checksum_failures = 0
        """The same, counted over the whole session (an exchange compares it before and after)."""
        self.info: p.BoardInfo | None = None
        self._shown = self._staged = None

    # --- opening --------------------------------------------------------------------------------------
    @classmethod
    def open(
        cls,
        url: str,
        *,
        timeout: float = 1.0,
        retries: int = 3,
        reconnect_s: float = 5.0,
        on_reset: str = "raise",
        baudrate: int = BAUD_RATE,
        expected_leds: int | None = None,
    ) -> LedController:
        """Open the port, say HELLO, check the firmware and protocol versions.

        Parameters
        ----------
        url : str
            Serial device (``/dev/ttyACM0``, ``COM3``) or pyserial URL (``loop://``, ``socket://host:port``,
            ``nlipsemu://<id>`` for device.virtual_board.VirtualBoard).
        timeout : float
            Seconds to wait for each reply before sending the line again, s.
        retries : int
            How many times a line is sent again (timeout, corrupted line) before giving up.
        reconnect_s : float
            How long to wait for an unplugged board to come back, s.
        on_reset : {"raise", "restore"}
            When the board rebooted mid-session the driver always re-opens the session and restores the last
            acknowledged colours; "raise" then raises BoardResetError (frames taken meanwhile may be wrong),
            "restore" carries on silently (a warning is logged).
        baudrate : int
            Line speed; the firmware uses 115200.
        expected_leds : int, optional
            Fail unless the board drives exactly this many LEDs (the sensor design's count).
        """
        _check_timing(timeout, retries, reconnect_s)
        baudrate = check_baudrate(baudrate, f"{url}: baudrate")  # an int from here on (the messages compare it)
        ctrl = cls(url, timeout=timeout, retries=retries, reconnect_s=reconnect_s, on_reset=on_reset, baudrate=baudrate)
        ctrl._port = open_port(url, baudrate=baudrate, write_timeout=timeout)
        try:
            ctrl._start_session()
            if expected_leds is not None and ctrl.n_leds != expected_leds:
                raise DeviceError(f"{url}: the board drives {ctrl.n_leds} LEDs but {expected_leds} are expected")
        except BaseException:
            ctrl.close()
            raise
        return ctrl

    def _start_session(self) -> None:
        info = self._hello()
        if self.info is not None and (info.n_leds, info.protocol) != (self.info.n_leds, self.info.protocol):
            raise WrongDeviceError(f"{self.url}: a different board answered after reconnecting ({info})")
        self.info = info
        if self._shown is None:
            self._shown = np.zeros((info.n_leds, 3), np.uint8)
            self._staged = self._shown.copy()
        self._reset_seen = False

    def _hello(self) -> p.BoardInfo:
        self._unreadable = self._echoes = self._bad_checksums = 0
        try:
            reply = self._exchange("HELLO", session=False)
        except DeviceTimeoutError:
            raise self._no_hello_error() from None
        try:
            info = p.decode_info(reply.payload)
        except p.FrameError as exc:
            raise WrongDeviceError(f"{self.url}: unexpected HELLO answer: {exc}") from None
        _check_versions(self.url, info)
        return info

    def _no_hello_error(self) -> DeviceError:
        heard = _quoted(list(dict.fromkeys(self._foreign))[-3:])  # a banner printed over and over: once
        if any(line.startswith(b"Ada") for line in self._foreign):
            return WrongDeviceError(
                f"{self.url}: this board prints 'Ada': it runs Adalight firmware, not the nlips LED firmware. "
                "Drive it with nlipscalib.device.adalight.AdalightController, or flash the nlips LED firmware "
                f"({FIRMWARE_GUIDE})"
            )
        tries = f"{self.url}: no answer to HELLO after {self.retries + 1} tries of {self.timeout:g} s"
        if self._echoes and not heard:  # loop:// or a wire from TX to RX: the line rate cannot be the cause
            return DeviceTimeoutError(
                f"{tries}: the port echoes what is sent (a loopback, no board on it); give the LED board's port "
                "(/dev/ttyACM0, COM3, ...)"
            )
        unreadable = self._unreadable + len(self._rx)  # with the half line left over
        if heard:
            return DeviceTimeoutError(
                f'{tries}. It printed "{heard}". Is the nlips LED firmware flashed ({FIRMWARE_GUIDE})? '
                f"{_rate_hint(self.baudrate)}"
            )
        if self._bad_checksums:  # protocol lines, so the line rate is right; each is answered by a resend at once
            return DeviceTimeoutError(
                f"{self.url}: no valid answer to HELLO in {self.retries + 1} tries: it answered, but "
                f"{self._bad_checksums} of its lines failed the checksum (CRC-16): noise on the line (a loose or "
                "long unshielded USB cable), or a device speaking another protocol with the same line markers"
            )
        if unreadable:  # what a UART at another rate makes of the boot banner and the replies
            return DeviceTimeoutError(
                f"{tries}: it sent {unreadable} bytes that form no protocol line, as a board running at another "
                f"line rate does. {_rate_hint(self.baudrate)}"
            )
        return DeviceTimeoutError(
            f"{tries}: nothing came back. Is the nlips LED firmware flashed ({FIRMWARE_GUIDE}) and the board on "
            f"this port? {_rate_hint(self.baudrate)}"
        )

    # --- public API -----------------------------------------------------------------------------------
    @property
    def n_leds(self) -> int:
        return self.info.n_leds

    @property
    def firmware(self) -> str:
        return self.info.firmware

    @property
    def session_id(self) -> str:
        return self.info.session_id

    def set_led(self, index: int, rgb: ArrayLike, *, show: bool = True) -> None:
        """Set LED ``index`` (0-based) to ``rgb`` (3 ints 0..255); latched unless ``show=False`` (staged)."""
        index = self._check_index(index)
        colour = _check_colours(np.asarray(rgb).reshape(1, 3), 1)[0]

        def stage(staged: np.ndarray) -> None:
            staged[index] = colour

        self._command("SET" if show else "PUT", index, p.encode_colour(colour), stage=stage, latch=show)

    def set_all(self, colours: ArrayLike) -> None:
        """Set and latch every LED in one frame. ``colours : (N, 3) uint8, RGB``."""
        colours = _check_colours(colours, self.n_leds)

        def stage(staged: np.ndarray) -> None:
            staged[:] = colours

        self._command("ALL", p.encode_colours(colours), stage=stage, latch=True)

    def off(self) -> None:
        """Switch every LED off (latched)."""
        self._command("OFF", stage=lambda staged: staged.fill(0), latch=True)

    def show(self) -> None:
        """Latch the colours staged with ``set_led(..., show=False)``."""
        self._command("SHOW", latch=True)

    def state(self) -> np.ndarray:
        """``(N, 3) uint8``: the colours the LEDs show now, as the board reports them."""
        reply = self._command("STATE")
        try:
            return p.decode_colours(reply.payload, self.n_leds)
        except ValueError as exc:
            raise DeviceError(f"{self.url}: malformed STATE answer: {exc}") from None

    def hello(self) -> p.BoardInfo:
        """Ask the board for its description again (also a cheap liveness check)."""
        with self._lock:
            if self._port is None:
                raise DeviceError(f"{self.url}: the LED controller is closed")
            return self._hello()

    def check_reset(self) -> None:
        """Read what the board sent since the last command, sending nothing; a boot banner there (or a port that
        failed and came back) is handled as a command handles it: the LEDs restored, then BoardResetError unless
        ``on_reset="restore"``. A stream asks it at every frame: 1-3 us a call behind a pseudo-terminal (the firmware in
        simavr; benchmarks/RESULTS.md, s37-resetleft).

        Why: a stream that lights the LEDs once (``nlips live``) sends no command while it runs, so a board that
        reset went unnoticed until the LEDs were switched off at its end, its frames dark meanwhile."""
        with self._lock:
            if self._port is None:
                raise DeviceError(f"{self.url}: the LED controller is closed")
            try:
                self._drain()
            except (_serial().SerialException, OSError) as exc:
                self._reconnect(exc)
                self._after_reset(UNPLUGGED_REASON)
                return
            if self._reset_seen:
                self._after_reset("it printed its boot banner")

    def close(self) -> None:
        """Close the port (the LEDs keep their colours)."""
        if self._port is not None:
            try:
                self._port.close()
            finally:
                self._port = None

    def __enter__(self) -> LedController:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"LedController({self.url!r}, n_leds={self.info.n_leds if self.info else '?'})"

    def _check_index(self, index: int) -> int:
        return _check_index(index, self.n_leds)

    # --- transactions ---------------------------------------------------------------------------------
    def _command(
        self, command: str, *args: object, stage: Callable[[np.ndarray], None] | None = None, latch: bool = False
    ) -> p.Reply:
        """Exchange one command; once acknowledged, apply ``stage`` to the host's copy of the staged colours
        and, when the command latched, copy them to the shown colours (what a reset restores)."""
        with self._lock:
            if self._port is None:
                raise DeviceError(f"{self.url}: the LED controller is closed")
            reply = self._exchange(command, *args)
            if stage is not None:
                stage(self._staged)
            if latch:
                self._shown[:] = self._staged
            return reply

    def _exchange(self, command: str, *args, session: bool = True, again: bool = False) -> p.Reply:
        """Send one command and wait for its reply: resend on timeout or corruption, reopen after unplug.

        A reset that ends the last try is said as the reset it is (BoardResetError, or with ``on_reset="restore"``
        the command sent once more, ``again``, on the new session), never as "no valid answer".
        """
        self._seq = seq = (self._seq + 1) & 0xFF
        failures_before = self._checksum_failures
        line = p.encode_command(seq, command, *args)
        ended_by_reset = False
        for attempt in range(self.retries + 1):
            ended_by_reset = False
            # a boot banner ended the last try: the reset is said below, not as a lost reply
            if attempt and not (session and self._reset_seen):
                self.resends += 1
                # HELLO is resent while an Uno sits in its bootloader after the open: expected, so not a warning
                level = logging.WARNING if session else logging.DEBUG
                log.log(level, "%s: sending %s again (%d/%d)", self.url, command, attempt, self.retries)
            try:
                self._drain()
                if session and self._reset_seen:
                    self._after_reset("it printed its boot banner")
                self._sent = line.rstrip(b"\n")
                self._port.write(line)
                reply = self._await_reply(f"{seq:02x}", session, self._line_time(command, line))
            except _serial().SerialTimeoutException:
                continue
            except (_serial().SerialException, OSError) as exc:
                if not session:
                    raise DeviceDisconnectedError(f"{self.url}: the port failed during HELLO: {exc}") from None
                self._reconnect(exc)
                self._after_reset(UNPLUGGED_REASON)
                ended_by_reset = True
                continue
            if reply is None or reply.seq == p.UNKNOWN_SEQ or reply.error == p.E_CRC:
                continue
            if reply.error == p.E_NOSESSION and session:
                self._after_reset("it no longer knows the session")
                ended_by_reset = True
                continue
            if reply.error:
                raise self._board_error(command, args, reply)
            return reply
        if session and self._reset_seen:
            # its boot banner came as the last try waited: a reset, not a lost reply (it said "no valid answer to
            # SET after 3 tries", where a banner one try earlier said "board reset detected"; s37)
            self._after_reset("it printed its boot banner")  # raises unless on_reset="restore"
            ended_by_reset = True
        if ended_by_reset and not again:  # on_reset="restore": the LEDs are back; the command has not been obeyed
            return self._exchange(command, *args, again=True)
        tries = self.retries + 1
        corrupt = self._checksum_failures - failures_before
        if corrupt >= tries:  # each answered by a resend at once: the tries did not last the timeout
            raise DeviceTimeoutError(
                f"{self.url}: no valid answer to {command} in {tries} tries: every reply failed its checksum "
                "(CRC-16): noise on the line (a loose or long unshielded USB cable), or a device speaking another "
                "protocol with the same line markers"
            )
        failed = f" ({corrupt} of them answered with a reply that failed its checksum)" if corrupt else ""
        raise DeviceTimeoutError(
            f"{self.url}: no valid answer to {command} after {tries} tries of {self.timeout:g} s each{failed}"
        )

    def _board_error(self, command: str, args: tuple, reply: p.Reply) -> DeviceError:
        name = p.ERROR_NAMES.get(reply.error, "?")
        meaning = p.ERROR_MEANINGS.get(reply.error, "unknown error code")
        if reply.error == p.E_RANGE:
            return LedIndexError(f"{self.url}: LED index {args[0]} out of range (board: {meaning})")
        return BoardError(f"{self.url}: the board refused {command}: E{reply.error} {name}: {meaning}", reply.error)

    def _line_time(self, command: str, line: bytes) -> float:
        """Time the command and its longest reply take on the line at the port's rate, s.

        Why: the reply timeout held no line time, so at a slow rate (``--baud 1200``, or 100 LEDs at 4800) ALL
        and STATE were resent before their reply could arrive, and failed (firmware in simavr, the line paced)."""
        reply = STATE_REPLY_BYTES + 6 * self.info.n_leds if command == "STATE" else REPLY_BYTES
        return wire_seconds(len(line) + reply, self.baudrate)

    def _await_reply(self, seq: str, in_session: bool, line_time: float) -> p.Reply | None:
        """The reply carrying ``seq``, or None on timeout (``timeout`` after the line time ``line_time``, s), a
        corrupted reply or a boot banner mid-session."""
        deadline = time.monotonic() + line_time + self.timeout
        while (line := self._read_line(deadline)) is not None:
            kind, value = self._classify(line)
            if kind == "corrupt" or (kind == "banner" and in_session):
                return None  # a rebooted board answers a session command only with E7: handle the reset now
            if kind == "reply" and value.seq in (seq, p.UNKNOWN_SEQ):
                return value
            if kind == "reply":
                log.debug("%s: ignoring a late reply %r", self.url, line)
        return None

    def _drain(self) -> None:
        """Read what arrived between commands (a boot banner would be there) and drop stale lines."""
        while self._port.in_waiting:
            self._rx += self._port.read(self._port.in_waiting)
        while (nl := self._rx.find(b"\n")) >= 0:
            line = bytes(self._rx[:nl])
            del self._rx[: nl + 1]
            self._classify(line)

    def _read_line(self, deadline: float) -> bytes | None:
        while (nl := self._rx.find(b"\n")) < 0:
            if time.monotonic() >= deadline:
                return None
            self._rx += self._port.read(max(1, self._port.in_waiting))
            if len(self._rx) > MAX_RX_BUFFER:  # a flood of garbage without newlines
                self._unreadable += len(self._rx) - MAX_RX_BUFFER
                del self._rx[:-MAX_RX_BUFFER]
        line = bytes(self._rx[:nl])
        del self._rx[: nl + 1]
        return line

    def _classify(self, line: bytes):
        """("reply", Reply) | ("banner", BoardInfo) | ("corrupt", None) | ("garbage", None)."""
        if self._sent and line.rstrip(b"\r") == self._sent:
            self._echoes += 1
            return "garbage", None
        try:
            marker, body = p.check_frame(line)
        except p.FrameError as exc:
            self._unreadable += len(line) + 1
            if isinstance(exc, p.ChecksumError):
                self._bad_checksums += 1
                self._checksum_failures += 1
            if b"<" in line or b"!" in line:
                log.debug("%s: corrupted line %r", self.url, line)
                return "corrupt", None
            text = line.strip()
            if text and text.isascii() and text.decode().isprintable():  # another firmware's text ("Ada")
                self._foreign = [*self._foreign[-9:], text]
            return "garbage", None
        if marker == p.BANNER_START and body.startswith("BOOT"):
            try:
                info = p.decode_info(body[4:])
            except p.FrameError as exc:  # its checksum held: not noise but a board describing itself wrongly
                raise WrongDeviceError(
                    f"{self.url}: unexpected boot banner: {exc}. Is the nlips LED firmware of this version flashed "
                    f"({FIRMWARE_GUIDE})?"
                ) from None
            log.debug("%s: board booted (session %s)", self.url, info.session_id)
            self._reset_seen = True
            return "banner", info
        if marker == p.REPLY_START:
            try:
                return "reply", p.decode_reply(body)
            except p.FrameError:
                return "corrupt", None
        return "garbage", None

    # --- recovery -------------------------------------------------------------------------------------
    def _reconnect(self, cause: Exception) -> None:
        log.warning("%s: port failed (%s); waiting up to %g s for it to come back", self.url, cause, self.reconnect_s)
        self.close()
        self._rx.clear()
        deadline = time.monotonic() + self.reconnect_s
        while True:
            try:
                self._port = open_port(self.url, baudrate=self.baudrate, write_timeout=self.timeout)
                self.reconnects += 1
                return
            except (PortNotFoundError, PortBusyError, DeviceError) as exc:
                if isinstance(exc, PortPermissionError) or time.monotonic() >= deadline:
                    raise DeviceDisconnectedError(
                        f"{self.url}: the board disconnected ({cause}) and did not come back within "
                        f"{self.reconnect_s:g} s: {exc}"
                    ) from None
                time.sleep(0.1)

    def _after_reset(self, reason: str) -> None:
        """Re-open the session and restore the last acknowledged colours; raise unless on_reset='restore'."""
        self.resets += 1
        log.warning("%s: board reset detected (%s); restoring the LEDs", self.url, reason)
        self._start_session()
        shown = self._shown.copy()
        self._exchange("ALL", p.encode_colours(shown), session=False)
        self._staged[:] = shown
        if self.on_reset == "raise":
            raise BoardResetError(
                f"{self.url}: board reset detected ({reason}). The LEDs were dark meanwhile and have been restored "
                "to the last acknowledged colours; retake any frame captured since the previous command",
                reason,
            )


QUOTED_CHARS = 60
"""Most characters of another firmware's text quoted in a no-answer message."""


def _quoted(lines: list[bytes]) -> str:
    """Text lines another firmware printed, as one plain string (not a bytes repr) of at most QUOTED_CHARS
    characters, lines separated by `` | ``; bytes that are not ASCII become U+FFFD."""
    text = " | ".join(line.decode("ascii", errors="replace") for line in lines)
    return text if len(text) <= QUOTED_CHARS else text[: QUOTED_CHARS - 3] + "..."


def _rate_hint(baudrate: int) -> str:
    """The sentence on line rates that ends a no-answer message (docs/protocol.md, "Line rate")."""
    if baudrate != BAUD_RATE:
        return f"The port is at {baudrate} baud but the nlips LED firmware runs at {BAUD_RATE} (--baud)."
    return f"The port is at {BAUD_RATE} baud, the nlips LED firmware's rate; a board at another rate needs --baud."


def _check_timing(timeout: object, retries: object, reconnect_s: object) -> None:
    """An NlipsError naming :meth:`LedController.open`'s ``timeout``, ``retries`` or ``reconnect_s`` when it is of
    another kind or out of range, before the port is opened. Why: ``timeout="1"`` failed inside pyserial ("'<' not
    supported between instances of 'str' and 'int'") (s38-apikinds)."""
    for name, value in (("timeout", timeout), ("reconnect_s", reconnect_s)):
        check_kind(value, NUMBER, name, "a number of seconds")
        if not value > 0:
            raise ConfigError(f"{name} must be > 0 seconds, got {value}")
    check_whole(retries, "retries", minimum=0)


def _check_versions(url: str, info: p.BoardInfo) -> None:
    if info.protocol != p.PROTOCOL_VERSION:
        raise ProtocolVersionError(
            f"{url}: the board speaks LED protocol {info.protocol}, this nlipscalib speaks {p.PROTOCOL_VERSION}: "
            f"flash the firmware of this version ({FIRMWARE_GUIDE}) or update nlipscalib"
        )
    major = info.firmware.split(".", 1)[0]
    if not major.isdigit() or int(major) != SUPPORTED_FIRMWARE_MAJOR:
        raise ProtocolVersionError(
            f"{url}: firmware {info.firmware} is not a {SUPPORTED_FIRMWARE_MAJOR}.x nlips LED firmware: "
            f"flash the nlips LED firmware of this version of nlipscalib ({FIRMWARE_GUIDE})"
        )


def _check_index(index: int, n_leds: int) -> int:
    if not 0 <= int(index) < n_leds:
        raise LedIndexError(f"LED index {index} out of range: there are {n_leds} LEDs (0..{n_leds - 1})")
    return int(index)


def _check_colours(colours: ArrayLike, n_leds: int) -> np.ndarray:
    """``(n_leds, 3)`` integers 0..255 -> uint8 array; ShapeError otherwise."""
    arr = np.asarray(colours)
    if arr.shape != (n_leds, 3):
        raise ShapeError(f"LED colours must have shape ({n_leds}, 3), got {arr.shape}")
    if arr.dtype != np.uint8:
        if not np.issubdtype(arr.dtype, np.integer) or arr.min() < 0 or arr.max() > 255:
            raise ShapeError(f"LED colours must be integers 0..255 (uint8), got {arr.dtype} {arr.min()}..{arr.max()}")
        arr = arr.astype(np.uint8)
    return arr
