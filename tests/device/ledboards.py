"""Boards the LED protocol tests run against: the virtual board, and the real firmware in simavr.

Both are driven through the same small interface (url, latched(), reset(), reset_unannounced(), unplug(),
drop_replies(), noise()), so one parametrised suite (test_protocol_boards.py) checks both.
"""

from __future__ import annotations

import atexit
import ctypes.util
import functools
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.device.virtual_board import VirtualBoard

FIRMWARE_DIR = Path(__file__).resolve().parents[2] / "firmware"
FIRMWARE_LEDS = 12
"""LED count of the default firmware build (firmware/Makefile NLEDS)."""
REQUIRE_ENV = "NLIPS_REQUIRE_DEVICE_TOOLS"


def missing_device_tools() -> str | None:
    """Why the firmware cannot be built and emulated here, or None when everything is present."""
    missing = [tool for tool in ("avr-g++", "avr-objcopy", "make", "cc") if shutil.which(tool) is None]
    if not Path("/usr/include/simavr/sim_avr.h").exists():
        missing.append("libsimavr-dev (simavr headers)")
    if ctypes.util.find_library("simavr") is None:
        missing.append("libsimavr")
    if not missing:
        return None
    return f"AVR toolchain or simavr missing ({', '.join(missing)}); bash setup.sh installs them"


def require_device_tools() -> None:
    """Skip with the reason, or fail when NLIPS_REQUIRE_DEVICE_TOOLS=1 (CI must run the firmware tests)."""
    reason = missing_device_tools()
    if reason is None:
        return
    if os.environ.get(REQUIRE_ENV) == "1":
        pytest.fail(f"{reason} ({REQUIRE_ENV}=1 requires the firmware tests to run)")
    pytest.skip(reason)


def build_firmware(build_dir: Path, nleds: int = FIRMWARE_LEDS) -> tuple[Path, Path]:
    """Compile the firmware and the simavr harness into build_dir; returns (elf, harness)."""
    result = subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_DIR), f"BUILD={build_dir}", f"NLEDS={nleds}", "all", "harness"],
        capture_output=True,
        text=True,
    )
    if result.returncode != 0:
        pytest.fail(f"firmware build failed:\n{result.stdout}\n{result.stderr}")
    return build_dir / "nlips-led.elf", build_dir / "simavr-harness"


@functools.cache
def firmware_build(nleds: int = FIRMWARE_LEDS) -> tuple[Path, Path]:
    """build_firmware once per test process (every test module shares it); skips or fails without the tools."""
    require_device_tools()
    build_dir = Path(tempfile.mkdtemp(prefix="nlips-firmware-"))
    atexit.register(shutil.rmtree, build_dir, ignore_errors=True)
    return build_firmware(build_dir, nleds)


class VirtualUnderTest:
    """The in-process virtual board."""

    kind = "virtual"

    def __init__(self, n_leds: int = FIRMWARE_LEDS):
        self.board = VirtualBoard(n_leds)
        self.url, self.n_leds = self.board.url, n_leds

    def latched(self) -> np.ndarray:
        return self.board.latched

    def reset(self) -> None:
        self.board.reset()

    def reset_unannounced(self) -> None:
        """A reset whose boot banner the host never gets (lost on the line): its LEDs dark, its session gone."""
        self.board.reset(banner=False)

    def unplug(self, seconds: float) -> None:
        self.board.unplug(replug_after_s=seconds)

    def drop_replies(self, n: int) -> None:
        self.board.drop_replies(n)

    def noise(self, data: bytes) -> None:
        self.board.inject(data)

    def close(self) -> None:
        pass


class SimavrUnderTest:
    """The compiled firmware on an emulated ATmega328P, its UART on a pseudo-terminal (firmware/simavr)."""

    kind = "simavr"

    def __init__(self, elf: Path, harness: Path, link: Path, n_leds: int = FIRMWARE_LEDS):
        self.url, self.n_leds = str(link), n_leds
        self.proc = subprocess.Popen(
            [str(harness), str(elf), str(link)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        self._expect("READY")

    def _expect(self, prefix: str) -> str:
        # simavr's ELF loader prints its own lines on stdout: skip everything but the answer
        while True:
            line = self.proc.stdout.readline()
            if not line:
                raise RuntimeError(f"simavr harness exited (code {self.proc.poll()})")
            if line.startswith(prefix):
                return line.strip()

    def ask(self, command: str, prefix: str = "OK") -> str:
        self.proc.stdin.write(command + "\n")
        return self._expect(prefix)

    def waveform(self) -> dict:
        """The harness's WS2812 decoding: last latched frame and the bit timing statistics (ns, us)."""
        fields = self.ask("latched", "LATCHED").split()
        stats = dict(f.split("=", 1) for f in fields[2:])
        out = {"rgb": fields[1] if len(fields) > 1 and "=" not in fields[1] else ""}
        for key in ("t0h", "t1h", "tlow"):
            low, high = stats[key].split("-")
            out[key] = (float(low), float(high))
        out["frames"], out["early_acks"] = int(stats["frames"]), int(stats["early_acks"])
        out["ack_gap_us"] = float(stats["ack_gap_us"])
        return out

    def latched(self) -> np.ndarray:
        rgb = self.waveform()["rgb"]
        return np.frombuffer(bytes.fromhex(rgb), np.uint8).reshape(-1, 3).copy()

    def reset(self) -> None:
        self.ask("reset")

    def reset_unannounced(self) -> None:
        """A reset whose boot banner the host never gets (the harness drops it): LEDs dark, session gone."""
        self.ask("drop 1")
        self.ask("reset")

    def unplug(self, seconds: float) -> None:
        self.ask(f"unplug {int(seconds * 1000)}")

    def drop_replies(self, n: int) -> None:
        self.ask(f"drop {n}")

    def pace(self, baudrate: int) -> None:
        """Carry bytes both ways at the pace of an 8N1 line at ``baudrate`` (0: as fast as the pseudo-terminal)."""
        self.ask(f"pace {baudrate}")

    def noise(self, data: bytes) -> None:
        self.ask(f"noise {data.hex()}")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.flush()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def board_under_test(kind: str, folder: Path):
    """The board of ``kind`` ("virtual" or "simavr", its pseudo-terminal in ``folder``) for a parametrised fixture;
    the caller closes it."""
    if kind == "virtual":
        return VirtualUnderTest()
    elf, harness = firmware_build()
    return SimavrUnderTest(elf, harness, folder / "ttyNLIPS")
