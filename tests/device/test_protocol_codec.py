"""Known answers for the pure protocol codec (nlipscalib.device.protocol)."""

import numpy as np
import pytest

from nlipscalib.device import protocol as p


def reference_crc16_xmodem(data: bytes) -> int:
    """Bit-by-bit CRC-16/XMODEM (poly 0x1021, init 0, no reflection), independent of binascii."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


def test_crc_is_crc16_xmodem():
    assert p.crc16(b"123456789") == 0x31C3  # the catalogued check value of CRC-16/XMODEM
    for text in (b"", b"01 HELLO", b"7f ALL " + b"ab" * 72):
        assert p.crc16(text) == reference_crc16_xmodem(text)


def test_command_line_layout():
    line = p.encode_command(3, "SET", 2, "ff0000")
    body = b"03 SET 2 ff0000"
    assert line == b">" + body + b"*" + f"{reference_crc16_xmodem(body):04x}".encode() + b"\n"
    with pytest.raises(ValueError):
        p.encode_command(256, "OFF")


def test_check_frame_verifies_and_resynchronises():
    reply = p.frame(p.REPLY_START, "05 OK")
    assert p.check_frame(reply.rstrip(b"\n")) == (b"<", "05 OK")
    # garbage and the remains of a half line before the start marker are ignored
    assert p.check_frame(b"\x00\xffjunk<04 O" + reply.rstrip(b"\n")) == (b"<", "05 OK")
    assert p.check_frame(reply.rstrip(b"\n") + b"\r") == (b"<", "05 OK")
    corrupted = reply.replace(b"OK", b"OJ").rstrip(b"\n")
    for bad in (corrupted, b"05 OK*1234", b"<05 OK", b"<05 OK*12", b"<05 OK*zzzz"):
        with pytest.raises(p.FrameError):
            p.check_frame(bad)


def test_decode_reply_and_info():
    assert p.decode_reply("0a OK") == p.Reply("0a", 0, "")
    assert p.decode_reply("0a OK 00ff00") == p.Reply("0a", 0, "00ff00")
    assert p.decode_reply("-- E1 CRC") == p.Reply("--", 1, "CRC")
    assert not p.decode_reply("0b E4 RANGE").ok
    for bad in ("0a", "0a MAYBE", "abc OK"):
        with pytest.raises(p.FrameError):
            p.decode_reply(bad)
    info = p.decode_info("fw=1.2.3 proto=1 leds=12 sid=00a3")
    assert info == p.BoardInfo("1.2.3", 1, 12, "00a3")
    assert p.decode_info(p.encode_info(info)) == info
    with pytest.raises(p.FrameError):
        p.decode_info("fw=1.2.3 leds=12")


def test_colours_round_trip():
    colours = np.array([[255, 0, 16], [1, 2, 3]], np.uint8)
    assert p.encode_colours(colours) == "ff0010010203"
    assert p.encode_colour((255, 0, 16)) == "ff0010"
    np.testing.assert_array_equal(p.decode_colours("ff0010010203", 2), colours)
    with pytest.raises(ValueError):
        p.decode_colours("ff0010", 2)


def test_every_error_code_is_named_and_explained():
    assert set(p.ERROR_NAMES) == set(p.ERROR_MEANINGS) == set(range(1, 8))
