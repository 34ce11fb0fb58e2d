"""A virtual LED controller speaking the nlips LED protocol, reachable through pyserial as ``nlipsemu://<id>``.

It behaves like the firmware in firmware/ (same parser rules, same replies, same error codes) and adds fault
injection for tests: garbage on the line, dropped, corrupted or half replies, a reset mid-session, unplugging.
Like an Arduino Uno it reboots (and prints its boot banner) when the port is opened. With ``adalight=True`` it
runs stock Adalight instead (docs/protocol.md, "Adalight"): it prints ``Ada`` when it boots, latches every
Adalight frame for its LED count and never answers. Given a ``baudrate`` it runs at that line rate only, as
the firmware does: a port opened at another rate garbles every byte both ways (docs/protocol.md, "Line rate").

Usage::

    board = VirtualBoard(12)
    with LedController.open(board.url) as leds:
        leds.set_led(0, (255, 0, 0))
    board.latched  # (12, 3) uint8, what the LEDs show now
"""

from __future__ import annotations

import errno
import itertools
import threading
import time
import weakref

import numpy as np

from ..core.errors import require
from . import protocol as p

serial = require("serial", "pyserial", "The virtual LED board")

URL_SCHEME = "nlipsemu"
ADALIGHT_MAGIC, ADALIGHT_BANNER = b"Ada", b"Ada\n"
"""Adalight's frame header start and boot greeting (device/adalight.py speaks the host side)."""
_BOARDS: weakref.WeakValueDictionary[str, VirtualBoard] = weakref.WeakValueDictionary()
_IDS = itertools.count(1)


def register_url_scheme() -> None:
    """Let ``serial.serial_for_url`` open ``nlipsemu://`` (handler module: device/protocol_nlipsemu.py)."""
    if __package__ not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(__package__)


register_url_scheme()


def url_board_id(url: str) -> str | None:
    """The board id of an ``nlipsemu://<id>`` URL (may be empty), None for any other URL."""
    prefix = f"{URL_SCHEME}://"
    if not url or not url.lower().startswith(prefix):
        return None
    return url[len(prefix) :].split("?")[0]


def find_board(url: str) -> VirtualBoard | None:
    """The VirtualBoard of this process that ``nlipsemu://<id>`` reaches, or None."""
    board_id = url_board_id(url)
    return None if board_id is None else _BOARDS.get(board_id)


def board_missing(url: str | None) -> bool:
    """True when ``url`` is an ``nlipsemu://`` URL and this process has no board of its id (yet)."""
    return bool(url) and url_board_id(url) is not None and find_board(url) is None


def check_board_url(url: str) -> str:
    """The board id of ``nlipsemu://<id>``; ConfigError (one line) when the URL names no usable id.

    The commands use it before starting a board, so ``nlipsemu://`` or ``nlipsemu://a/b`` is refused as
    the user's input, not as a failing port.
    """
    from ..core.errors import ConfigError

    board_id = url_board_id(url)
    if not board_id or any(c in board_id for c in "/#"):
        raise ConfigError(f"{url}: nlipsemu:// needs a board id without / or #, e.g. nlipsemu://1")
    return board_id


def emulated_sensor_note(url: str, scene: str) -> str:
    """The line ``nlips capture`` / ``nlips live`` print when ``--port nlipsemu://ID`` names no board of this
    process and they start the emulated sensor behind it."""
    return (
        f"{url}: starting the emulated sensor of {scene} in this process (the virtual LED board at this URL and "
        f"the virtual camera it lights), as --emulate {scene} does"
    )


def start_board(url: str, n_leds: int, *, adalight: bool = False, baudrate: int | None = None) -> VirtualBoard | None:
    """Start the virtual board that ``url`` names when it is an ``nlipsemu://<id>`` URL this process lacks.

    Why: a board lives in the process that created it, so ``nlipsemu://1`` typed on a command line reaches
    nothing unless the command itself starts the board (as a real board is there before the command).

    Parameters
    ----------
    url : str
        The port the command was given; any URL but a missing ``nlipsemu://`` board is left alone.
    n_leds : int
        LEDs of the started board (the sensor design's count).
    adalight : bool
        The started board runs stock Adalight.
    baudrate : int, optional
        The started board's line rate (:class:`VirtualBoard`): the commands give the firmware's, so a wrong
        ``--baud`` fails as it would on the real board.

    Returns
    -------
    VirtualBoard or None
        The started board (None: nothing to start). Keep it referenced while its URL is in use: the URL
        table holds boards weakly; :meth:`VirtualBoard.close` frees the id.
    """
    from ..core.errors import check_kind

    check_kind(url, str, "url", "the board's port: a serial port or pyserial URL ('nlipsemu://ID' starts one)")
    if not board_missing(url):
        return None
    return VirtualBoard(n_leds, adalight=adalight, board_id=check_board_url(url), baudrate=baudrate)


class VirtualBoard:
    """An in-process LED controller (firmware twin) with fault injection.

    Parameters
    ----------
    n_leds : int
        Number of LEDs it drives.
    firmware : str
        Version string it reports.
    protocol : int
        Protocol version it reports (change it to test the host's version check).
    reply_delay_s : float
        Time between receiving a command and replying (the WS2812 write and latch), seconds.
    reset_on_open : bool
        Reboot when the port is opened, as an Uno does through DTR.
    adalight : bool
        Run stock Adalight instead of the nlips firmware: greet with ``Ada``, latch each Adalight frame that
        carries ``n_leds`` LEDs (frames for another count are ignored), never answer.
    board_id : str, optional
        The id in its URL (``nlipsemu://<board_id>``); default: the next free number.
    baudrate : int, optional
        The firmware's line rate, baud. A port opened at another rate garbles every byte, as a UART at the
        wrong rate does: the board reads no line (so never answers) and the host reads bytes that form no
        line. None (default): any rate works (an in-process board has no line).
    """

    def __init__(
        self,
        n_leds: int = 12,
        *,
        firmware: str = "1.0.0-virtual",
        protocol: int = p.PROTOCOL_VERSION,
        reply_delay_s: float = 0.0,
        reset_on_open: bool = True,
        adalight: bool = False,
        board_id: str | None = None,
        baudrate: int | None = None,
    ):
        from ..core.errors import check_kind

        check_kind(n_leds, (int, np.integer), "n_leds", "the board's whole number of LEDs")
        check_kind(baudrate, (int, type(None)), "baudrate", "a line rate in baud (115200), or None: any")
        self.n_leds = int(n_leds)
        self.firmware = firmware
        self.protocol = int(protocol)
        self.reply_delay_s = float(reply_delay_s)
        self.reset_on_open = reset_on_open
        self.adalight = bool(adalight)
        self.baudrate = baudrate
        if board_id is None:
            while (board_id := str(next(_IDS))) in _BOARDS:
                pass
        elif not board_id or any(c in board_id for c in "/?#") or board_id in _BOARDS:
            raise ValueError(f"board_id {board_id!r} is empty, holds / ? # or is taken in this process")
        self.id = str(board_id)
        self.url = f"{URL_SCHEME}://{self.id}"
        self.max_line = 6 * self.n_leds + 32
        """Longest accepted command line (bytes between ``>`` and newline), as in the firmware."""
        self.boots = 0
        self.executed: list[str] = []
        """Every command line executed since creation (bodies, for tests)."""
        self._cond = threading.Condition()
        self._out = bytearray()
        self._line: bytearray | None = None
        self._ada = bytearray()
        self._plugged = True
        self._connection: VirtualSerial | None = None
        self._drop = self._corrupt = self._half = self._mute = self._reset_on = 0
        self._pending = np.zeros((self.n_leds, 3), np.uint8)
        self._latched = np.zeros((self.n_leds, 3), np.uint8)
        self._session = False
        _BOARDS[self.id] = self
        self._boot(announce=False)

    def close(self) -> None:
        """Leave this process's URL table: ``nlipsemu://<id>`` reaches nothing now, and the id is free again."""
        if _BOARDS.get(self.id) is self:
            del _BOARDS[self.id]

    def __enter__(self) -> VirtualBoard:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- what the LEDs show ---------------------------------------------------------------------------
    @property
    def latched(self) -> np.ndarray:
        """``(N, 3) uint8``: the colours the LEDs show now (RGB)."""
        with self._cond:
            return self._latched.copy()

    @property
    def session_id(self) -> str:
        return f"{self.boots:04x}"

    # --- fault injection ------------------------------------------------------------------------------
    def inject(self, data: bytes) -> None:
        """Put raw bytes (garbage, a half line) on the line from the board to the host."""
        with self._cond:
            self._out += data
            self._cond.notify_all()

    def drop_replies(self, n: int = 1) -> None:
        """Execute the next ``n`` commands but lose their replies (the host times out)."""
        self._drop += n

    def mute(self, n: int = 1) -> None:
        """Lose the next ``n`` command lines before they are executed (nothing happens, no reply)."""
        self._mute += n

    def reset_on_line(self, n: int = 1) -> None:
        """Reboot as the ``n``-th next command line arrives, that line lost (a brown-out as the board takes it; with
        :meth:`mute` for the lines before it, the banner comes as the host waits for a resend's reply)."""
        self._reset_on = n

    def corrupt_replies(self, n: int = 1) -> None:
        """Flip one character in each of the next ``n`` replies (the host sees a checksum mismatch)."""
        self._corrupt += n

    def half_replies(self, n: int = 1) -> None:
        """Send only the first half of the next ``n`` replies, without newline."""
        self._half += n

    def reset(self, banner: bool = True) -> None:
        """Reboot now (watchdog, brown-out, reset button): LEDs off, session lost, banner printed; ``banner=False``:
        the banner lost on the line (noise, a USB glitch), so the host learns of the reset only from the board's
        NOSESSION (or sees it as a real board still booting would be seen: dark LEDs, nothing said yet)."""
        with self._cond:
            self._boot(announce=banner)

    def unplug(self, replug_after_s: float | None = None) -> None:
        """Pull the USB cable: the open port breaks and cannot be reopened until plug()."""
        with self._cond:
            self._plugged = False
            self._latched[:] = 0
            if self._connection is not None:
                self._connection._broken = True
            self._cond.notify_all()
        if replug_after_s is not None:
            timer = threading.Timer(replug_after_s, self.plug)
            timer.daemon = True
            timer.start()

    def plug(self) -> None:
        """Plug the cable back in (the board powers up and boots)."""
        with self._cond:
            self._plugged = True
            self._boot(announce=False)

    # --- the firmware ---------------------------------------------------------------------------------
    def _boot(self, announce: bool) -> None:
        self.boots += 1
        self._pending[:] = 0
        self._latched[:] = 0
        self._session = False
        self._line = None
        self._ada.clear()
        if announce and self.adalight:
            self._send(ADALIGHT_BANNER, faults=False)
        elif announce:
            self._send(p.frame(p.BANNER_START, "BOOT " + p.encode_info(self._info())), faults=False)

    def _info(self) -> p.BoardInfo:
        return p.BoardInfo(self.firmware, self.protocol, self.n_leds, self.session_id)

    def _receive(self, data: bytes) -> None:
        """Bytes from the host, parsed like the firmware: ``>`` starts a line, newline ends it."""
        if self.adalight:
            self._receive_adalight(data)
            return
        for byte in data:
            if byte == ord(">"):
                self._line = bytearray()
            elif self._line is None:
                continue  # garbage outside a line
            elif byte == ord("\n"):
                line, self._line = bytes(self._line), None
                self._handle_line(line)
            elif len(self._line) <= self.max_line:
                self._line.append(byte)

    def _receive_adalight(self, data: bytes) -> None:
        """Adalight: hunt for ``Ada`` + a header whose checksum holds, then read R, G, B per LED and latch."""
        buf = self._ada
        buf += data
        while True:
            start = buf.find(ADALIGHT_MAGIC)
            if start < 0:
                del buf[: max(0, len(buf) - len(ADALIGHT_MAGIC) + 1)]  # keep what may begin a header
                return
            del buf[:start]
            if len(buf) < 6:
                return
            hi, lo, check = buf[3:6]
            n = (hi << 8 | lo) + 1
            if check != hi ^ lo ^ 0x55 or n != self.n_leds:
                del buf[:1]  # not a header for this strip: keep hunting
                continue
            if len(buf) < 6 + 3 * n:
                return
            self._pending[:] = np.frombuffer(bytes(buf[6 : 6 + 3 * n]), np.uint8).reshape(n, 3)
            del buf[: 6 + 3 * n]
            self._latch()
            self.executed.append(f"Ada {n}")

    def _handle_line(self, line: bytes) -> None:
        if self._reset_on:
            self._reset_on -= 1
            if not self._reset_on:
                self._boot(announce=True)
                return
        if self._mute:
            self._mute -= 1
            return
        seq = line[:2].decode("ascii", "replace")
        if not all(c in "0123456789abcdefABCDEF" for c in seq) or len(seq) != 2:
            seq = p.UNKNOWN_SEQ
        if len(line) > self.max_line:
            reply = f"{seq} E{p.E_LONG} {p.ERROR_NAMES[p.E_LONG]}"
        else:
            try:
                _, body = p.check_frame(b">" + line)
            except p.FrameError:
                reply = f"{seq} E{p.E_CRC} {p.ERROR_NAMES[p.E_CRC]}"
            else:
                reply = self._execute(body if seq != p.UNKNOWN_SEQ else p.UNKNOWN_SEQ + body[2:])
        if self.reply_delay_s:
            self._cond.release()
            try:
                time.sleep(self.reply_delay_s)
            finally:
                self._cond.acquire()
        self._send(p.frame(p.REPLY_START, reply))

    def _execute(self, body: str) -> str:
        seq, rest = body[:2], body[3:]
        tokens = rest.split(" ")
        if seq == p.UNKNOWN_SEQ or body[2:3] != " " or "" in tokens or len(tokens) > 3:
            return _error(seq, p.E_SYNTAX)  # bad sequence field, empty token or too many tokens
        command, *args = tokens
        handler = _COMMANDS.get(command)
        if handler is None:
            return _error(seq, p.E_UNKNOWN)
        if command != "HELLO" and not self._session:
            return _error(seq, p.E_NOSESSION)
        try:
            payload = handler(self, args)
        except _BoardError as exc:
            return _error(seq, exc.code)
        self.executed.append(body)
        return f"{seq} OK" + (f" {payload}" if payload else "")

    def _latch(self) -> None:
        self._latched[:] = self._pending

    def _cmd_hello(self, args: list[str]) -> str:
        _no_args(args)
        self._session = True
        return p.encode_info(self._info())

    def _cmd_set(self, args: list[str], latch: bool = True) -> str:
        if len(args) != 2:
            raise _BoardError(p.E_SYNTAX)
        index, colour = _parse_index(args[0]), _parse_colours(args[1], 1)
        if index >= self.n_leds:
            raise _BoardError(p.E_RANGE)
        self._pending[index] = colour[0]
        if latch:
            self._latch()
        return ""

    def _cmd_put(self, args: list[str]) -> str:
        return self._cmd_set(args, latch=False)

    def _cmd_all(self, args: list[str]) -> str:
        if len(args) != 1:
            raise _BoardError(p.E_SYNTAX)
        if len(args[0]) != 6 * self.n_leds:
            raise _BoardError(p.E_COUNT if len(args[0]) % 6 == 0 else p.E_SYNTAX)
        self._pending[:] = _parse_colours(args[0], self.n_leds)
        self._latch()
        return ""

    def _cmd_off(self, args: list[str]) -> str:
        _no_args(args)
        self._pending[:] = 0
        self._latch()
        return ""

    def _cmd_show(self, args: list[str]) -> str:
        _no_args(args)
        self._latch()
        return ""

    def _cmd_state(self, args: list[str]) -> str:
        _no_args(args)
        return p.encode_colours(self._latched)

    # --- the wire -------------------------------------------------------------------------------------
    def _send(self, line: bytes, faults: bool = True) -> None:
        if faults and self._drop:
            self._drop -= 1
            return
        if faults and self._corrupt:
            self._corrupt -= 1
            i = len(line) // 2
            line = line[:i] + bytes([line[i] ^ 0x01]) + line[i + 1 :]
        if faults and self._half:
            self._half -= 1
            line = line[: len(line) // 2]
        self._out += line
        self._cond.notify_all()


class _BoardError(Exception):
    def __init__(self, code: int):
        self.code = code


def _error(seq: str, code: int) -> str:
    return f"{seq} E{code} {p.ERROR_NAMES[code]}"


def _no_args(args: list[str]) -> None:
    if args:
        raise _BoardError(p.E_SYNTAX)


def _parse_index(text: str) -> int:
    if not text.isdigit() or len(text) > 3:
        raise _BoardError(p.E_SYNTAX)
    return int(text)


def _parse_colours(text: str, n: int) -> np.ndarray:
    try:
        return p.decode_colours(text, n)
    except ValueError:
        raise _BoardError(p.E_SYNTAX) from None


_COMMANDS = {
    "HELLO": VirtualBoard._cmd_hello,
    "SET": VirtualBoard._cmd_set,
    "PUT": VirtualBoard._cmd_put,
    "ALL": VirtualBoard._cmd_all,
    "OFF": VirtualBoard._cmd_off,
    "SHOW": VirtualBoard._cmd_show,
    "STATE": VirtualBoard._cmd_state,
}


class VirtualSerial(serial.SerialBase):
    """pyserial port class for ``nlipsemu://<id>`` (found through serial.protocol_handler_packages)."""

    def open(self) -> None:
        if self.is_open:
            raise serial.SerialException("Port is already open.")
        board = self._board_for(self.portstr)
        with board._cond:
            if not board._plugged:
                raise serial.SerialException(errno.ENOENT, f"could not open port {self.portstr}: board unplugged")
            if board._connection is not None and not board._connection._broken:
                raise serial.SerialException(errno.EBUSY, f"could not open port {self.portstr}: port busy")
            self._board, self._broken = board, False
            board._connection = self
            board._out.clear()
            if board.reset_on_open:
                board._boot(announce=True)
        self.is_open = True

    @staticmethod
    def _board_for(url: str) -> VirtualBoard:
        board_id = url_board_id(url)
        if board_id is None:
            raise serial.SerialException(f"expected {URL_SCHEME}://<id>, got {url!r}")
        board = _BOARDS.get(board_id)
        if board is None:
            raise serial.SerialException(
                errno.ENOENT,
                f"could not open port {url}: no such virtual board in this process (keep a reference to the "
                "VirtualBoard while you use its url)",
            )
        return board

    def close(self) -> None:
        if self.is_open:
            with self._board._cond:
                if self._board._connection is self:
                    self._board._connection = None
                self._board._cond.notify_all()
        self.is_open = False

    def _reconfigure_port(self):
        pass

    def _check(self):
        if not self.is_open:
            raise serial.PortNotOpenError()
        if self._broken:
            raise serial.SerialException(errno.EIO, "device disconnected (virtual board unplugged)")

    @property
    def in_waiting(self) -> int:
        self._check()
        return len(self._board._out)

    def read(self, size: int = 1) -> bytes:
        self._check()
        board = self._board
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with board._cond:
            while len(board._out) < size:
                self._check()
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                board._cond.wait(remaining)
            self._check()
            data = bytes(board._out[:size])
            del board._out[:size]
        return _garbled(data) if self._rate_mismatch() else data

    def write(self, data: bytes | bytearray | memoryview) -> int:
        self._check()
        data = bytes(data)
        if self._rate_mismatch():  # the board's UART reads framing errors: no line start, nothing executed
            return len(data)
        with self._board._cond:
            self._board._receive(data)
        return len(data)

    def _rate_mismatch(self) -> bool:
        """True when the board runs at a fixed rate and this port is opened at another one."""
        return self._board.baudrate is not None and self.baudrate != self._board.baudrate

    def reset_input_buffer(self) -> None:
        self._check()
        with self._board._cond:
            self._board._out.clear()

    def reset_output_buffer(self) -> None:
        self._check()

    def flush(self) -> None:
        self._check()


def _garbled(data: bytes) -> bytes:
    """What a UART at another rate makes of ``data``: as many bytes, none a start marker or a newline.

    Why deterministic: tests then see the same thing every run (a real mismatch yields framing errors and
    bytes that depend on the two rates); setting the high bit keeps every byte outside printable ASCII."""
    return bytes(b | 0x80 for b in data)
