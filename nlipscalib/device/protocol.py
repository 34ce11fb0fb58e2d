"""The nlips LED line protocol, version 1: pure encoding and decoding, no I/O (specification: docs/protocol.md).

Host to board: ``>SS CMD ARGS*CCCC\\n``; board to host: ``<SS STATUS PAYLOAD*CCCC\\n``; boot banner:
``!BOOT fw=.. proto=.. leds=.. sid=..*CCCC\\n``. ``SS`` is a two-digit hex sequence number, ``CCCC`` the
CRC-16/XMODEM (``binascii.crc_hqx`` with initial value 0, avr-libc's ``_crc_xmodem_update`` on the board) of
the bytes between the start marker and ``*``. Colours travel as ``RRGGBB`` hex, LED indices as decimal,
0-based.
"""

from __future__ import annotations

import binascii
import dataclasses

import numpy as np
from numpy.typing import ArrayLike

PROTOCOL_VERSION = 1
"""The protocol version this host speaks (the board's ``proto=`` must match)."""
MAX_LEDS = 255
"""Most LEDs a board may report (``leds=``): the firmware counts its LEDs in a byte (firmware/src/main.cpp), so
a count of 0 or above this is a corrupted or foreign board description, not a sensor."""

COMMAND_START = b">"
REPLY_START = b"<"
BANNER_START = b"!"
UNKNOWN_SEQ = "--"
"""Sequence field of a reply to a line whose sequence number could not be read."""

ERROR_NAMES = {
    1: "CRC",
    2: "SYNTAX",
    3: "UNKNOWN",
    4: "RANGE",
    5: "COUNT",
    6: "LONG",
    7: "NOSESSION",
}
"""Board error codes (``E<n> NAME``), documented in docs/protocol.md."""

ERROR_MEANINGS = {
    1: "checksum mismatch: the line was corrupted on the way and was not executed",
    2: "malformed line (missing field, bad hex or decimal number)",
    3: "unknown command",
    4: "LED index out of range",
    5: "wrong number of colours for ALL",
    6: "line longer than the board's buffer",
    7: "no HELLO since the board booted: the board was reset",
}

E_CRC, E_SYNTAX, E_UNKNOWN, E_RANGE, E_COUNT, E_LONG, E_NOSESSION = range(1, 8)


def crc16(data: bytes) -> int:
    """CRC-16/XMODEM (polynomial 0x1021, initial value 0) of ``data``."""
    return binascii.crc_hqx(data, 0)


def frame(start: bytes, body: str) -> bytes:
    """A complete line: start marker, body, ``*``, CRC of the body (4 lowercase hex digits), newline."""
    raw = body.encode("ascii")
    return start + raw + b"*" + f"{crc16(raw):04x}".encode() + b"\n"


def encode_command(seq: int, command: str, *args: str | int) -> bytes:
    """Encode one host command line, e.g. ``encode_command(3, "SET", 2, "ff0000")``."""
    if not 0 <= seq <= 0xFF:
        raise ValueError(f"sequence number {seq} outside 0..255")
    body = " ".join([f"{seq:02x}", command, *(str(a) for a in args)])
    return frame(COMMAND_START, body)


def encode_colour(rgb: ArrayLike) -> str:
    """``(r, g, b)`` 0..255 -> ``"rrggbb"``."""
    r, g, b = (int(c) for c in rgb)
    return f"{r:02x}{g:02x}{b:02x}"


def encode_colours(colours: np.ndarray) -> str:
    """``(N, 3) uint8`` -> ``"rrggbb" * N``."""
    return np.ascontiguousarray(colours, dtype=np.uint8).tobytes().hex()


def decode_colours(text: str, n_leds: int) -> np.ndarray:
    """``"rrggbb" * N`` -> ``(N, 3) uint8``; ValueError when the length or the hex is wrong."""
    if len(text) != 6 * n_leds:
        raise ValueError(f"expected {n_leds} colours ({6 * n_leds} hex digits), got {len(text)} digits")
    return np.frombuffer(bytes.fromhex(text), dtype=np.uint8).reshape(n_leds, 3).copy()


class FrameError(ValueError):
    """A line that is not a valid protocol line (bad marker, missing checksum, checksum mismatch)."""


class ChecksumError(FrameError):
    """A well-formed protocol line (start marker, ``*`` and four hex digits) whose checksum does not match its
    body: noise on the line, or a device speaking another protocol with the same markers (not a line rate: a
    UART at another rate makes no such line)."""


def check_frame(line: bytes) -> tuple[bytes, str]:
    """Split a received line (newline removed) into its start marker and verified body.

    Bytes before the last start marker are discarded (garbage, or the rest of a half line), so a line
    that follows noise still decodes.

    Raises
    ------
    FrameError
        No start marker, no checksum, or a checksum that does not match.
    """
    line = line.rstrip(b"\r")
    start = max(line.rfind(m) for m in (COMMAND_START, REPLY_START, BANNER_START))
    if start < 0:
        raise FrameError(f"no start marker in {line[:40]!r}")
    marker, rest = line[start : start + 1], line[start + 1 :]
    body, star, crc_text = rest.rpartition(b"*")
    if not star or len(crc_text) != 4:
        raise FrameError(f"no checksum in {line[:40]!r}")
    try:
        expected = int(crc_text, 16)
        text = body.decode("ascii")
    except (ValueError, UnicodeDecodeError) as exc:
        raise FrameError(f"unreadable line {line[:40]!r}") from exc
    if crc16(body) != expected:
        raise ChecksumError(f"checksum mismatch in {line[:40]!r}")
    return marker, text


@dataclasses.dataclass(frozen=True)
class Reply:
    """One decoded board reply."""

    seq: str
    """Two hex digits echoing the command's sequence number, or ``--`` when the board could not read it."""
    error: int
    """0 for ``OK``, else the error code (see ERROR_NAMES)."""
    payload: str
    """Everything after the status (``""`` when none)."""

    @property
    def ok(self) -> bool:
        return self.error == 0


def decode_reply(body: str) -> Reply:
    """Decode a verified reply body ``SS OK payload`` or ``SS E<n> NAME``."""
    fields = body.split(" ", 2)
    if len(fields) < 2 or len(fields[0]) != 2:
        raise FrameError(f"malformed reply {body[:40]!r}")
    seq, status = fields[0], fields[1]
    payload = fields[2] if len(fields) > 2 else ""
    if status == "OK":
        return Reply(seq, 0, payload)
    if status.startswith("E") and status[1:].isdigit():
        return Reply(seq, int(status[1:]), payload)
    raise FrameError(f"unknown reply status {status!r}")


@dataclasses.dataclass(frozen=True)
class BoardInfo:
    """What HELLO (or the boot banner) says about the board."""

    firmware: str
    """Firmware version, e.g. ``1.0.0``."""
    protocol: int
    """Protocol version the firmware speaks."""
    n_leds: int
    """Number of LEDs the firmware drives."""
    session_id: str
    """Boot identifier (hex) that changes each time the board boots."""


def decode_info(payload: str) -> BoardInfo:
    """Decode ``fw=1.0.0 proto=1 leds=12 sid=002a`` (HELLO payload or banner after ``BOOT``).

    Raises
    ------
    FrameError
        A field missing or unreadable, or an LED count outside 1..MAX_LEDS.
    """
    fields = dict(tok.split("=", 1) for tok in payload.split() if "=" in tok)
    try:
        info = BoardInfo(fields["fw"], int(fields["proto"]), int(fields["leds"]), fields["sid"])
    except (KeyError, ValueError) as exc:
        raise FrameError(f"malformed board description {payload[:60]!r}") from exc
    if not 1 <= info.n_leds <= MAX_LEDS:
        raise FrameError(f"LED count {fields['leds'][:20]} out of range (1..{MAX_LEDS}) in {payload[:60]!r}")
    return info


def encode_info(info: BoardInfo) -> str:
    """Inverse of decode_info (used by the virtual board)."""
    return f"fw={info.firmware} proto={info.protocol} leds={info.n_leds} sid={info.session_id}"
