"""Adalight framing, byte for byte against the published description, and the ack-less controller.

Published frame (Adafruit LEDstream / Adalight-FastLED): "Ada", LED count - 1 as high and low byte,
checksum = high ^ low ^ 0x55, then R, G, B per LED; the board prints "Ada\\n" when it boots.
"""

import os
import threading
import time
import types

import numpy as np
import pytest

from nlipscalib.core.errors import ShapeError
from nlipscalib.device.adalight import AdalightController, adalight_frame, adalight_header
from nlipscalib.device.controller import DeviceDisconnectedError, LedIndexError


def parse_adalight_stream(stream: bytes) -> list[np.ndarray]:
    """Read frames as the Adalight-FastLED sketch does: hunt for "Ada", check the checksum, read 3N bytes."""
    frames, i = [], 0
    while (i := stream.find(b"Ada", i)) >= 0 and i + 6 <= len(stream):
        hi, lo, chk = stream[i + 3 : i + 6]
        if chk != hi ^ lo ^ 0x55:
            i += 1
            continue
        n = (hi << 8 | lo) + 1
        data = stream[i + 6 : i + 6 + 3 * n]
        if len(data) < 3 * n:
            break
        frames.append(np.frombuffer(data, np.uint8).reshape(n, 3))
        i += 6 + 3 * n
    return frames


def test_header_bytes():
    assert adalight_header(1) == b"Ada\x00\x00\x55"
    assert adalight_header(3) == b"Ada\x00\x02\x57"  # 0x00 ^ 0x02 ^ 0x55
    assert adalight_header(256) == b"Ada\x00\xff\xaa"
    assert adalight_header(300) == b"Ada\x01\x2b\x7f"  # 299 = 0x012b; 0x01 ^ 0x2b ^ 0x55 = 0x7f
    with pytest.raises(ValueError):
        adalight_header(0)


def test_frame_bytes():
    colours = np.array([[255, 0, 0], [0, 128, 1], [2, 3, 255]], np.uint8)
    assert adalight_frame(colours) == bytes.fromhex("416461 00 02 57 ff0000 008001 0203ff".replace(" ", ""))


def test_controller_writes_exact_frames(tmp_path):
    with AdalightController.open("loop://", 3, settle_s=0.0, boot_timeout=0) as leds:
        assert not leds.acknowledged
        leds.set_led(1, (10, 20, 30))
        leds.set_led(2, (1, 2, 3), show=False)  # staged only: nothing sent
        leds.show()
        leds.off()
        leds.set_all(np.full((3, 3), 7))
        sent = leds._port.read(leds._port.in_waiting)
        np.testing.assert_array_equal(leds.state(), 7)
        with pytest.raises(LedIndexError):
            leds.set_led(3, (1, 1, 1))
        with pytest.raises(ShapeError):
            leds.set_all(np.zeros((2, 3), np.uint8))
    frames = parse_adalight_stream(sent)
    assert len(sent) == 4 * (6 + 9)  # four frames, nothing else on the line
    assert [f.tolist() for f in frames] == [
        [[0, 0, 0], [10, 20, 30], [0, 0, 0]],
        [[0, 0, 0], [10, 20, 30], [1, 2, 3]],
        [[0, 0, 0]] * 3,
        [[7, 7, 7]] * 3,
    ]


def test_settle_delay_covers_transmission_and_ws2812_write(monkeypatch):
    """After each frame the driver waits for its transmission, the strip's write and the settle delay (the board
    never acknowledges): the wait it asks for is checked, not a clock."""
    from nlipscalib.device import adalight

    slept = []
    monkeypatch.setattr(adalight, "time", types.SimpleNamespace(**{**vars(time), "sleep": slept.append}))
    with AdalightController.open("loop://", 100, settle_s=0.01, boot_timeout=0) as leds:
        expected = (6 + 300) * 10 / 115200 + 100 * 30e-6  # 26.6 ms line + 3 ms WS2812
        assert leds.frame_time_s() == pytest.approx(expected)
        leds.off()
    assert slept == [pytest.approx(expected + 0.01)]


def test_open_waits_for_the_boot_banner(caplog):
    """open() waits for the banner of a board that resets, and only until it comes. No clock: the banner comes after
    an event the test sets, and the wait it must end would last ten minutes (the test's guard is one)."""
    master, slave = os.openpty()
    banner_sent, opened, received = threading.Event(), [], []

    def boot():  # the board resets when the port opens and greets after its bootloader
        time.sleep(0.2)
        banner_sent.set()
        os.write(master, b"Ada\n")

    def open_and_set():
        with AdalightController.open(os.ttyname(slave), 2, settle_s=0.0, boot_timeout=600.0) as leds:
            opened.append(banner_sent.is_set())
            leds.set_led(0, (1, 2, 3))
            received.append(os.read(master, 100))

    board, host = (threading.Thread(target=f, daemon=True) for f in (boot, open_and_set))
    board.start()
    host.start()
    try:
        host.join(60.0)  # a guard, not the claim
        assert not host.is_alive(), "open() still waits 60 s after the banner came"
        assert opened == [True]  # it returned once the banner had come, not before
        assert "banner" not in caplog.text  # ... on seeing it: the wait did not run out
        assert received == [b"Ada\x00\x01\x54" + bytes([1, 2, 3, 0, 0, 0])]
    finally:
        board.join()
        os.close(master)
        os.close(slave)


def test_missing_banner_only_warns(caplog):
    with AdalightController.open("loop://", 2, settle_s=0.0, boot_timeout=0.1) as leds:
        leds.off()
    assert "no 'Ada' banner" in caplog.text


def test_a_garbled_banner_asks_for_the_sketch_line_rate(caplog):
    """An Adalight board at another rate than the port's: its banner arrives as bytes that are no banner, and the
    warning names the port's rate and --baud (the board itself ignores the garbled frames, silently)."""
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(2, adalight=True, baudrate=500000)
    with AdalightController.open(board.url, 2, settle_s=0.0, boot_timeout=0.1) as leds:
        leds.set_all(np.full((2, 3), 9, np.uint8))
    assert "4 bytes but no 'Ada' banner within 0.1 s: is the sketch's line rate 115200 baud (--baud)?" in caplog.text
    assert board.latched.sum() == 0
    # the rate as text (a config file's): checked and made an int, which the settle delay divides by
    with AdalightController.open(board.url, 2, settle_s=0.0, boot_timeout=0.1, baudrate="500000") as leds:
        leds.set_all(np.full((2, 3), 9, np.uint8))
    assert board.latched.tolist() == [[9, 9, 9]] * 2


class PtyPort:
    """A serial port at a fixed path (a symlink to a pseudo-terminal) that can be unplugged and plugged back."""

    def __init__(self, link):
        self.link = link
        self.plug()

    def plug(self):
        self.master, self.slave = os.openpty()
        if os.path.lexists(self.link):
            os.unlink(self.link)
        os.symlink(os.ttyname(self.slave), self.link)

    def unplug(self):
        os.unlink(self.link)
        os.close(self.master)
        os.close(self.slave)

    def received(self, n: int, timeout: float = 2.0) -> bytes:
        data, deadline = b"", time.monotonic() + timeout
        while len(data) < n and time.monotonic() < deadline:
            data += os.read(self.master, n - len(data))
        return data


def test_unplug_and_reconnect_resends_the_frame(tmp_path):
    port = PtyPort(tmp_path / "ttyADA")
    with AdalightController.open(str(port.link), 2, settle_s=0.0, boot_timeout=0, reconnect_s=3.0) as leds:
        leds.set_led(0, (1, 2, 3))
        assert port.received(12) == b"Ada\x00\x01\x54" + bytes([1, 2, 3, 0, 0, 0])
        port.unplug()
        threading.Timer(0.2, port.plug).start()
        leds.set_led(1, (4, 5, 6))  # the write fails, the port comes back, the whole frame goes to the new board
        assert leds.reconnects == 1
        assert port.received(12) == b"Ada\x00\x01\x54" + bytes([1, 2, 3, 4, 5, 6])
        port.unplug()
        leds.reconnect_s = 0.2
        with pytest.raises(DeviceDisconnectedError, match="did not come back within 0.2 s"):
            leds.off()


def test_adalight_on_a_board_running_the_nlips_firmware_is_one_line_naming_it(capsys):
    """`--adalight` on a board flashed with firmware/ waited 3 s, warned "no 'Ada' banner: is the sketch's line
    rate ...?" and sent frames the firmware ignores: a capture took its frames with the LEDs dark."""
    from nlipscalib.cli import main
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(12)  # the nlips protocol; prints its boot banner when the port opens, as an Uno does
    assert main(["leds", board.url, "test", "--adalight", "12", "--dwell", "0"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.strip() == (
        f"nlips leds: error: {board.url}: the board runs the nlips LED firmware (BOOT fw=1.0.0-virtual proto=1 "
        f"leds=12 sid={board.session_id}), not Adalight: drop --adalight (the nlips protocol acknowledges every "
        "change and reads the LEDs back)"
    )


@pytest.mark.parametrize("kind", ["virtual", "simavr"])
def test_adalight_on_the_nlips_firmware_that_printed_no_banner_is_refused_by_its_hello_answer(kind, tmp_path):
    """A board that does not reset when its port opens (the simavr harness, an Uno whose DTR stayed up) prints no
    banner: `--adalight` on the nlips firmware there only warned "no 'Ada' banner" and sent frames it ignores."""
    from nlipscalib.device.controller import LedController
    from nlipscalib.device.errors import WrongDeviceError
    from nlipscalib.device.virtual_board import VirtualBoard

    from .ledboards import SimavrUnderTest, firmware_build

    if kind == "virtual":
        board = VirtualBoard(12, reset_on_open=False)
        url, close = board.url, lambda: None
    else:
        board = SimavrUnderTest(*firmware_build(), tmp_path / "ttyNLIPS")
        url, close = board.url, board.close
        LedController.open(url).close()  # its boot banner, waiting in the pseudo-terminal, read: none comes again
    try:
        with pytest.raises(WrongDeviceError) as refused:
            AdalightController.open(url, 12, settle_s=0.0, boot_timeout=0.1)
    finally:
        close()
    message = str(refused.value)
    assert message.startswith(f"{url}: the board runs the nlips LED firmware (fw=1.0.0"), message
    assert message.endswith(
        ", its answer to HELLO), not Adalight: drop --adalight (the nlips protocol acknowledges every change and reads "
        "the LEDs back)"
    ), message


def test_an_adalight_board_without_a_banner_skips_the_hello_and_takes_its_frames(caplog):
    """The nlips HELLO sent when no banner came holds no 'Ada' header: the sketch skips it, as it skips noise."""
    from nlipscalib.device.virtual_board import VirtualBoard

    board = VirtualBoard(2, adalight=True, reset_on_open=False)
    with AdalightController.open(board.url, 2, settle_s=0.0, boot_timeout=0.1) as leds:
        leds.set_all(np.full((2, 3), 7, np.uint8))
    assert "no 'Ada' banner within 0.1 s" in caplog.text
    assert board.latched.tolist() == [[7, 7, 7]] * 2
