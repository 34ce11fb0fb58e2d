"""The LED protocol, end to end, against the virtual board AND the compiled firmware running in simavr.

Every command, every error code, lost and corrupted lines, garbage and half lines in both directions, a reset
mid-session, unplugging and reconnecting. The simavr cases need gcc-avr, avr-libc and simavr (setup.sh);
without them they skip, or fail when NLIPS_REQUIRE_DEVICE_TOOLS=1.
"""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.device import protocol as p
from nlipscalib.device.controller import (
    BoardResetError,
    DeviceDisconnectedError,
    DeviceTimeoutError,
    LedController,
    LedIndexError,
    PortBusyError,
    open_port,
)
from nlipscalib.device.port import BAUD_RATE
from tests.processes import wait_until

from .ledboards import SimavrUnderTest, VirtualUnderTest, firmware_build

TIMEOUT = 0.5  # s; generous enough for a loaded CI machine, short enough for fast timeout tests


@pytest.fixture(params=["virtual", "simavr", "simavr-115200"])
def board(request, tmp_path):
    """The virtual board, the firmware in simavr as fast as its pseudo-terminal goes, and the firmware with its
    bytes carried at the pace of the real line (115200 baud): a timeout too short for the line shows only there."""
    if request.param == "virtual":
        under_test = VirtualUnderTest()
    else:
        elf, harness = firmware_build()
        under_test = SimavrUnderTest(elf, harness, tmp_path / "ttyNLIPS")
        if request.param == "simavr-115200":
            under_test.pace(BAUD_RATE)
    yield under_test
    under_test.close()


@pytest.fixture
def leds(board):
    with LedController.open(board.url, timeout=TIMEOUT, retries=2, reconnect_s=3.0) as ctrl:
        yield ctrl


def colours(seed: int, n: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (n, 3), dtype=np.uint8)


# --- every command ------------------------------------------------------------------------------------------
def test_hello_describes_the_board(leds, board):
    assert leds.n_leds == board.n_leds
    assert leds.info.protocol == p.PROTOCOL_VERSION
    assert leds.firmware.startswith("1.")
    assert len(leds.session_id) == 4
    assert leds.hello() == leds.info


def test_set_led_is_latched_when_the_call_returns(leds, board):
    leds.set_led(3, (255, 0, 17))
    shown = board.latched()  # read right away: the acknowledgement came after the latch
    expected = np.zeros((board.n_leds, 3), np.uint8)
    expected[3] = (255, 0, 17)
    np.testing.assert_array_equal(shown, expected)


def test_set_all_state_and_off(leds, board):
    frame = colours(1, board.n_leds)
    leds.set_all(frame)
    np.testing.assert_array_equal(board.latched(), frame)
    np.testing.assert_array_equal(leds.state(), frame)
    leds.off()
    np.testing.assert_array_equal(board.latched(), 0)
    np.testing.assert_array_equal(leds.state(), 0)


def test_staged_leds_show_only_on_show(leds, board):
    leds.set_led(0, (10, 20, 30))
    leds.set_led(1, (1, 2, 3), show=False)
    leds.set_led(2, (4, 5, 6), show=False)
    assert board.latched()[1:3].sum() == 0
    np.testing.assert_array_equal(leds.state()[:3], [[10, 20, 30], [0, 0, 0], [0, 0, 0]])
    leds.show()
    np.testing.assert_array_equal(board.latched()[:3], [[10, 20, 30], [1, 2, 3], [4, 5, 6]])


def test_led_index_out_of_range(leds, board):
    with pytest.raises(LedIndexError, match=f"0..{board.n_leds - 1}"):
        leds.set_led(board.n_leds, (1, 1, 1))
    with pytest.raises(LedIndexError, match="out of range"):  # the board's own check (E4)
        leds._command("SET", board.n_leds + 5, "010101")


# --- error codes, on the raw line -----------------------------------------------------------------------------
def raw_exchange(port, line: bytes, timeout: float = 2.0) -> p.Reply:
    """Send one raw line, return the first valid reply (boot banners skipped)."""
    port.write(line)
    buffer = bytearray()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        buffer += port.read(max(1, port.in_waiting))
        while b"\n" in buffer:
            raw, _, rest = bytes(buffer).partition(b"\n")
            buffer = bytearray(rest)
            try:
                marker, body = p.check_frame(raw)
            except p.FrameError:  # e.g. the rest of a boot banner whose start the port open flushed
                continue
            if marker == p.REPLY_START:
                return p.decode_reply(body)
    raise AssertionError(f"no reply to {line!r}")


def test_every_error_code(board):
    n = board.n_leds
    port = open_port(board.url)
    try:
        assert raw_exchange(port, p.encode_command(1, "SHOW")).error == p.E_NOSESSION  # no HELLO yet
        assert raw_exchange(port, p.encode_command(2, "HELLO")).ok
        good = p.encode_command(3, "SET", 0, "ffffff")
        corrupted = good.replace(b"ffffff", b"fffeff")
        assert raw_exchange(port, corrupted) == p.Reply("03", p.E_CRC, "CRC")
        assert board.latched().sum() == 0, "a corrupted line must not be executed"
        assert raw_exchange(port, p.encode_command(4, "SET", 0, "fffff")).error == p.E_SYNTAX
        assert raw_exchange(port, p.encode_command(5, "SET", "x", "ffffff")).error == p.E_SYNTAX
        assert raw_exchange(port, p.encode_command(6, "BLINK")).error == p.E_UNKNOWN
        assert raw_exchange(port, p.encode_command(7, "SET", n, "ffffff")).error == p.E_RANGE
        assert raw_exchange(port, p.encode_command(8, "ALL", "00" * 3 * (n - 1))).error == p.E_COUNT
        assert raw_exchange(port, p.encode_command(9, "ALL", "00" * 3 * (n + 20))).error == p.E_LONG
        assert raw_exchange(port, b">zz HELLO*0000\n").seq == p.UNKNOWN_SEQ
        assert raw_exchange(port, p.frame(b">", "zz HELLO")) == p.Reply("--", p.E_SYNTAX, "SYNTAX")
        assert raw_exchange(port, p.encode_command(10, "OFF", "")).error == p.E_SYNTAX  # trailing space
        assert raw_exchange(port, p.encode_command(11, "SET", "", 0, "ffffff")).error == p.E_SYNTAX  # double
        assert raw_exchange(port, p.encode_command(12, "SET", 0, "ffffff", "x")).error == p.E_SYNTAX
        assert raw_exchange(port, good).ok
        assert board.latched()[0].tolist() == [255, 255, 255]
    finally:
        port.close()


# --- lost lines, garbage, half lines -------------------------------------------------------------------------
def test_lost_reply_is_resent(leds, board):
    board.drop_replies(1)
    leds.set_led(5, (9, 8, 7))
    assert leds.resends >= 1
    assert board.latched()[5].tolist() == [9, 8, 7]


def test_board_that_stays_silent_times_out(leds, board):
    board.drop_replies(leds.retries + 1)
    with pytest.raises(DeviceTimeoutError, match="no valid answer to OFF"):
        leds.off()
    leds.set_led(0, (1, 2, 3))  # the next command works again
    assert board.latched()[0].tolist() == [1, 2, 3]


SLOW_BAUD = 1200
"""A line rate at which ALL and STATE of the 12-LED firmware (98 bytes there and back, 0.82 s) outlast TIMEOUT."""


def test_a_slow_line_has_its_line_time_on_top_of_the_reply_timeout(tmp_path):
    """At a slow line rate (``--baud 1200``; 100 LEDs at 4800 alike) ALL and STATE were sent again before their reply
    could arrive, and with no retry failed: the timeout held no time for the line (the firmware in simavr, paced)."""
    elf, harness = firmware_build()
    board = SimavrUnderTest(elf, harness, tmp_path / "ttyNLIPS")
    try:
        board.pace(SLOW_BAUD)
        shown = colours(7, board.n_leds)
        with LedController.open(board.url, timeout=TIMEOUT, retries=0, baudrate=SLOW_BAUD) as leds:
            leds.set_all(shown)
            np.testing.assert_array_equal(leds.state(), shown)
            assert leds.resends == 0
        # the line is paced: a host that takes it for a fast one (115200) times out on it
        with pytest.raises(DeviceTimeoutError, match="no answer to HELLO"):
            LedController.open(board.url, timeout=0.1, retries=0).close()
    finally:
        board.close()


def test_garbage_and_half_lines_from_the_board_are_skipped(board):
    # no retries allowed: the reply must be found behind the garbage, not obtained by asking again
    with LedController.open(board.url, timeout=2.0, retries=0) as leds:
        board.noise(b"\x00\xff\xfenoise\r\n<1")  # garbage, then the start of a reply that never ends
        leds.set_led(1, (50, 60, 70))
        board.noise(b"junk<42 OK")  # another half line, then the STATE reply
        np.testing.assert_array_equal(leds.state()[1], [50, 60, 70])


def test_a_corrupted_reply_is_asked_again(leds, board):
    leds.set_led(1, (50, 60, 70))
    board.noise(b"<ff OK*0000\n")  # a reply with a bad checksum: it could have been ours
    np.testing.assert_array_equal(leds.state()[1], [50, 60, 70])
    assert 0 <= leds.resends <= 1


def test_garbage_and_half_lines_to_the_board_are_dropped(leds, board):
    leds._port.write(b"\x00\x7fjunk without start\n")
    leds._port.write(p.encode_command(0x55, "SET", 2, "ffffff")[:12])  # a half command, never finished
    leds.set_led(4, (3, 3, 3))  # its '>' starts a fresh line: the half command is dropped
    shown = board.latched()
    assert shown[2].tolist() == [0, 0, 0]
    assert shown[4].tolist() == [3, 3, 3]


# --- reset, unplug ----------------------------------------------------------------------------------------------
def test_reset_mid_session_is_detected_and_the_leds_restored(leds, board):
    frame = colours(2, board.n_leds)
    leds.set_all(frame)
    old_session = leds.session_id
    board.reset()
    assert wait_until(lambda: board.latched().sum() == 0), "a reset switches the LEDs off"
    with pytest.raises(BoardResetError, match="board reset detected"):
        leds.set_led(0, (1, 1, 1))
    np.testing.assert_array_equal(board.latched(), frame)  # restored to the last acknowledged colours
    assert leds.resets == 1
    assert leds.session_id != old_session  # the boot counter (EEPROM on the firmware) moved on
    leds.set_led(0, (1, 1, 1))
    assert board.latched()[0].tolist() == [1, 1, 1]


def test_reset_with_restore_policy_carries_on(board):
    with LedController.open(board.url, timeout=TIMEOUT, on_reset="restore") as leds:
        leds.set_led(7, (7, 7, 7))
        board.reset()
        assert wait_until(lambda: board.latched().sum() == 0)
        leds.set_led(8, (8, 8, 8))
        assert leds.resets == 1
        assert board.latched()[7:9].tolist() == [[7, 7, 7], [8, 8, 8]]


@pytest.mark.parametrize("on_reset", ["raise", "restore"])
def test_a_reset_whose_banner_comes_on_the_last_try_is_said_as_a_reset(on_reset):
    """It said "no valid answer to SET after 3 tries of 0.5 s each": the boot banner ended the last try's wait and
    the loop ran out of tries before the reset was handled (virtual board: the reset placed on the last line)."""
    from nlipscalib.device.virtual_board import VirtualBoard

    with (
        VirtualBoard(12) as board,
        LedController.open(board.url, timeout=TIMEOUT, retries=2, on_reset=on_reset) as leds,
    ):
        frame = colours(3, board.n_leds)
        leds.set_all(frame)
        board.mute(2)  # the first two tries lost ...
        board.reset_on_line(3)  # ... and the board reboots as the last one arrives
        if on_reset == "raise":
            with pytest.raises(BoardResetError, match=r"board reset detected \(it printed its boot banner\)"):
                leds.set_led(0, (1, 1, 1))
            np.testing.assert_array_equal(board.latched, frame)  # restored to the last acknowledged colours
        else:  # restored, then the command obeyed on the new session
            leds.set_led(0, (1, 1, 1))
            np.testing.assert_array_equal(board.latched, np.concatenate([[[1, 1, 1]], frame[1:]]).astype(np.uint8))
        assert leds.resets == 1


def test_unplug_and_reconnect(leds, board):
    leds.set_led(0, (11, 12, 13))
    board.unplug(0.3)
    with pytest.raises(BoardResetError, match="unplugged"):
        leds.set_led(1, (21, 22, 23))
    assert leds.reconnects == 1
    assert board.latched()[0].tolist() == [11, 12, 13]
    leds.set_led(1, (21, 22, 23))
    assert board.latched()[:2].tolist() == [[11, 12, 13], [21, 22, 23]]


def test_unplugged_for_good(board):
    with LedController.open(board.url, timeout=TIMEOUT, reconnect_s=0.3) as leds:
        board.unplug(30.0)
        with pytest.raises(DeviceDisconnectedError, match="did not come back within 0.3 s"):
            leds.off()


def test_a_second_program_cannot_open_the_port(leds, board):
    with pytest.raises(PortBusyError, match="busy"):
        LedController.open(board.url, timeout=TIMEOUT)


# --- docs/protocol.md: its example session and its numbers, against both boards and the firmware source ----------
PROTOCOL_MD = Path(__file__).resolve().parents[2] / "docs" / "protocol.md"
FIRMWARE_SRC = Path(__file__).resolve().parents[2] / "firmware" / "src"


def example_session() -> list[tuple[str, bytes]]:
    """docs/protocol.md's recorded session: ("->" host line | "<-" board line, the line with its newline)."""
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    block = text[text.index("Example session") :].split("```")[1]
    return [(ln[:2], ln[3:].encode() + b"\n") for ln in block.splitlines() if ln[:2] in ("->", "<-")]


def read_line(port, timeout: float = 2.0) -> bytes:
    """The next whole line from the board (with its newline)."""
    line = bytearray()
    deadline = time.monotonic() + timeout
    while not line.endswith(b"\n") and time.monotonic() < deadline:
        line += port.read(1)
    return bytes(line)


def test_the_documented_example_session_is_what_the_board_answers(board):
    """A lab writes its own host from docs/protocol.md: the page's session is replayed line by line and every reply
    must be the page's, byte for byte (the HELLO answer but its firmware version and boot counter, which are the
    board's own); every line of the page carries a CRC that holds."""
    session = example_session()
    assert [d for d, _ in session] == ["<-", "->", "<-", "->", "<-", "->", "<-", "->", "<-"]
    for _, line in session:
        assert p.frame(line[:1], p.check_frame(line[:-1])[1]) == line, line  # the CRCs are real
    port = open_port(board.url)
    try:
        time.sleep(0.2)  # a booting board's banner, if any, then dropped: the page's HELLO comes first
        port.reset_input_buffer()
        for (_, sent), (_, expected) in zip(session[1::2], session[2::2]):
            port.write(sent)
            got = read_line(port)
            while got.startswith(p.BANNER_START):
                got = read_line(port)
            if b"HELLO" in sent:
                info = p.decode_info(p.decode_reply(p.check_frame(got[:-1])[1]).payload)
                assert (info.firmware[:2], info.protocol, info.n_leds) == ("1.", 1, 12), got
            else:
                assert got == expected, sent
    finally:
        port.close()


def test_an_led_index_of_at_most_three_digits_and_hex_in_either_case(board):
    """docs/protocol.md, "Line format": the board reads an index of up to three decimal digits (leading zeros
    allowed) and hex digits in upper or lower case; it writes lower case."""
    port = open_port(board.url)
    try:
        assert raw_exchange(port, p.encode_command(1, "HELLO")).ok
        assert raw_exchange(port, p.encode_command(2, "SET", "002", "A0B0C0")) == p.Reply("02", 0, "")
        assert raw_exchange(port, p.encode_command(3, "SET", "0002", "a0b0c0")).error == p.E_SYNTAX
        assert raw_exchange(port, p.encode_command(4, "STATE")).payload[12:18] == "a0b0c0"
    finally:
        port.close()


def test_the_numbers_protocol_md_gives_are_the_firmware_s():
    """Line length, rate, latch and version, read from firmware/src, and the error table against protocol.py."""
    text = PROTOCOL_MD.read_text(encoding="utf-8")
    main_cpp = (FIRMWARE_SRC / "main.cpp").read_text(encoding="utf-8")
    assert "#define MAX_LINE (6 * NLEDS + 32)" in main_cpp and "`6 × LEDs + 32` bytes" in text
    n = 12
    all_line = p.encode_command(0xFF, "ALL", "00" * 3 * n)
    assert len(all_line) - 2 == 6 * n + 12 and "`6 × LEDs + 12`" in text  # without '>' and the newline
    assert (
        "#define UART_BAUD 115200UL" in (FIRMWARE_SRC / "uart.h").read_text(encoding="utf-8")
        and "UART 115200 baud" in text
    )
    assert "_delay_us(300)" in (FIRMWARE_SRC / "ws2812.cpp").read_text(encoding="utf-8") and "low for 300 µs" in text
    assert '#define FW_VERSION "1.' in main_cpp and '#define PROTOCOL_VERSION "1"' in main_cpp
    rows = re.findall(r"^\| `E(\d)` \| `([A-Z]+)` \|", text, re.M)
    assert {int(c): name for c, name in rows} == p.ERROR_NAMES
    names = re.search(r"ERROR_NAMES\[\] = \{(.*?)\};", main_cpp).group(1)
    assert re.findall(r'"([A-Z]*)"', names) == [""] + [p.ERROR_NAMES[c] for c in sorted(p.ERROR_NAMES)]
    assert f"{p.crc16(b'123456789'):04x}" == "31c3" and "`123456789` = `31c3`" in text
