"""How many LEDs the firmware holds: the ATmega328P's 2 KB of RAM, not the protocol's byte-wide count.

Built for 100 LEDs the firmware used to link and then crash on its first ALL (the frame's colours on the stack
ran past the RAM, simavr: "Invalid read address ... out of ram"); built for 101-113 it linked too. Needs gcc-avr,
avr-libc and simavr (setup.sh); without them these skip, or fail when NLIPS_REQUIRE_DEVICE_TOOLS=1.
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import numpy as np

from nlipscalib.device import protocol as p
from nlipscalib.device.controller import open_port

from .ledboards import FIRMWARE_DIR, SimavrUnderTest, firmware_build, require_device_tools
from .test_protocol_boards import raw_exchange

REPO = Path(__file__).resolve().parents[2]
MOST_LEDS = 100
"""The firmware's NLEDS_MAX (firmware/src/main.cpp), read back below so that the docs and the code agree."""


def test_the_largest_build_takes_whole_frames(tmp_path):
    """Three random ALL frames on the 100-LED build: STATE and the WS2812 pin show each one, and a frame with a
    bad digit leaves the staged colours alone (ALL parses into the wire buffer, which the latch rewrites)."""
    elf, harness = firmware_build(MOST_LEDS)
    board = SimavrUnderTest(elf, harness, tmp_path / "ttyNLIPS", MOST_LEDS)
    port = open_port(board.url)
    try:
        hello = raw_exchange(port, p.encode_command(1, "HELLO"))
        assert f"leds={MOST_LEDS} " in hello.payload
        rng = np.random.default_rng(MOST_LEDS)
        for seq in range(2, 5):
            frame = rng.integers(0, 256, (MOST_LEDS, 3), dtype=np.uint8)
            assert raw_exchange(port, p.encode_command(seq, "ALL", frame.tobytes().hex())).ok
            assert raw_exchange(port, p.encode_command(0x10 + seq, "STATE")).payload == frame.tobytes().hex()
            np.testing.assert_array_equal(board.latched(), frame)
        assert raw_exchange(port, p.encode_command(0x20, "PUT", "7", "010203")).ok
        bad = raw_exchange(port, p.encode_command(0x21, "ALL", "zz" * 3 * MOST_LEDS))  # the right length, not hex
        assert bad.error == p.E_SYNTAX
        assert raw_exchange(port, p.encode_command(0x22, "SHOW")).ok
        expected = frame.copy()
        expected[7] = (1, 2, 3)
        np.testing.assert_array_equal(board.latched(), expected)
    finally:
        port.close()
        board.close()


def test_a_build_with_more_leds_than_the_ram_holds_is_refused_with_the_reason(tmp_path):
    require_device_tools()
    result = subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_DIR), f"BUILD={tmp_path}", f"NLEDS={MOST_LEDS + 1}", "all"],
        capture_output=True,
        text=True,
    )
    assert result.returncode != 0
    assert f"NLEDS must be 1..{MOST_LEDS} on the ATmega328P" in result.stderr
    assert not (tmp_path / "nlips-led.elf").exists()


def test_the_docs_give_the_firmware_s_limit():
    main_cpp = (FIRMWARE_DIR / "src" / "main.cpp").read_text(encoding="utf-8")
    assert re.search(r"^#define NLEDS_MAX (\d+)$", main_cpp, re.M).group(1) == str(MOST_LEDS)
    protocol_md = (REPO / "docs" / "protocol.md").read_text(encoding="utf-8")
    readme = (FIRMWARE_DIR / "README.md").read_text(encoding="utf-8")
    assert f"1..{MOST_LEDS} on the ATmega328P" in protocol_md
    assert f"NLEDS=1..{MOST_LEDS}" in readme
