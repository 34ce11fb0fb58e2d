"""The compiled firmware in simavr: WS2812 bit timing on the pin, acknowledgement after the latch, sizes.

Needs gcc-avr, avr-libc and simavr (setup.sh); skips without them, fails when NLIPS_REQUIRE_DEVICE_TOOLS=1.
"""

import signal
import subprocess

import numpy as np
import pytest

from nlipscalib.device.controller import LedController

from . import ledboards
from .ledboards import SimavrUnderTest, firmware_build

# WS2812B timing windows, ns: the intersection of the original datasheet (T0H 400+-150, T1H 800+-150) and
# the V5 one (T0H 220-380, T1H 580-1000); low times from 450 ns up to a few us are read as data.
T0H_NS = (250, 380)
T1H_NS = (650, 950)
TLOW_NS = (450, 5000)
LATCH_US = 280  # V5 reset time (older parts: 50 us)


@pytest.fixture
def simavr(tmp_path):
    board = SimavrUnderTest(*firmware_build(), tmp_path / "tty")
    yield board
    board.close()


def test_ws2812_waveform_meets_the_datasheet_and_acks_follow_the_latch(simavr):
    with LedController.open(simavr.url, timeout=0.5) as leds:
        pattern = np.array([[0x00, 0xFF, 0xAA], [0x55, 0x0F, 0xF0]] * (leds.n_leds // 2), np.uint8)
        leds.set_all(pattern)
        leds.set_led(1, (0x81, 0x42, 0x24))
        pattern[1] = (0x81, 0x42, 0x24)
        wave = simavr.waveform()
    # the pin carried exactly these colours (decoded from edges, GRB on the wire -> RGB)
    np.testing.assert_array_equal(simavr.latched(), pattern)
    assert wave["frames"] >= 3  # boot (all off), set_all, set_led
    assert T0H_NS[0] <= wave["t0h"][0] <= wave["t0h"][1] <= T0H_NS[1]
    assert T1H_NS[0] <= wave["t1h"][0] <= wave["t1h"][1] <= T1H_NS[1]
    assert TLOW_NS[0] <= wave["tlow"][0] <= wave["tlow"][1] <= TLOW_NS[1]
    # no reply byte left the UART while a frame was still being sent or had not latched yet
    assert wave["early_acks"] == 0
    assert wave["ack_gap_us"] >= LATCH_US


def test_firmware_for_24_leds_fits_and_reports_its_count(tmp_path):
    elf, harness = firmware_build(24)
    sizes = subprocess.run(["avr-size", str(elf)], capture_output=True, text=True, check=True).stdout
    text, data, bss = (int(v) for v in sizes.splitlines()[1].split()[:3])
    assert text + data <= 32 * 1024 - 512  # flash, leaving the Uno's optiboot bootloader its 512 bytes
    assert data + bss <= 2048 - 512  # SRAM, leaving room for the stack
    board = SimavrUnderTest(elf, harness, tmp_path / "tty24", n_leds=24)
    try:
        with LedController.open(board.url, timeout=0.5) as leds:
            assert leds.n_leds == 24
            leds.set_led(23, (1, 2, 3))
            assert board.latched()[23].tolist() == [1, 2, 3]
    finally:
        board.close()


def test_missing_tools_skip_or_fail_on_request(monkeypatch):
    monkeypatch.setattr(ledboards, "missing_device_tools", lambda: "AVR toolchain missing (avr-g++)")
    monkeypatch.delenv(ledboards.REQUIRE_ENV, raising=False)
    with pytest.raises(pytest.skip.Exception, match="avr-g\\+\\+"):
        ledboards.require_device_tools()
    monkeypatch.setenv(ledboards.REQUIRE_ENV, "1")
    with pytest.raises(pytest.fail.Exception, match="NLIPS_REQUIRE_DEVICE_TOOLS=1"):
        ledboards.require_device_tools()


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_the_harness_stopped_by_ctrl_c_or_sigterm_removes_its_link(tmp_path, signum):
    """Ctrl-C of `build/simavr-harness ... /tmp/ttyNLIPS` (firmware/README.md: run in a terminal of its own) killed
    it and left the link pointing at a pseudo-terminal number the system hands to the next terminal opened, where
    `nlips leds /tmp/ttyNLIPS` would then write."""
    elf, harness = firmware_build()
    link = tmp_path / "ttyNLIPS"
    board = SimavrUnderTest(elf, harness, link)
    try:
        assert link.is_symlink()
        board.proc.send_signal(signum)
        assert board.proc.wait(5) == 0
        assert not link.is_symlink() and not link.exists()
    finally:
        board.close()
