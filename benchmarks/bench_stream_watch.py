"""What a stream pays per frame for its LED board's watch (``device.live_leds.ResetWatch``, shared by ``nlips live``
and ``nlips infer`` since s38): the board asked for the bytes it sent (``check_reset``) and the frame's level
measured (``frame_level``: is it dark?), against the bare source; and what the one question to the board costs when a
frame reads dark (``state()``, a round trip), on the virtual board and on the firmware in simavr behind a
pseudo-terminal paced at 115200 baud (skipped without gcc-avr, avr-libc and simavr: setup.sh). Usage::

    python benchmarks/bench_stream_watch.py [--reads 500] [--repeats 15] [--size 640x480]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nlipscalib.device.controller import LedController  # noqa: E402
from nlipscalib.device.live_leds import ResetWatch, frame_level  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402
from tests.device.ledboards import SimavrUnderTest, build_firmware, missing_device_tools  # noqa: E402


class Still:
    """A camera stand-in handing out one lit 16-bit frame (no decoding: the watch's own cost is what is timed)."""

    live = True

    def __init__(self, h: int, w: int):
        rng = np.random.default_rng(0)
        self.frame = rng.integers(8000, 30000, (h, w, 3), dtype=np.uint16)
        self.shape = (h, w)

    def read(self) -> np.ndarray:
        return self.frame

    def flush(self) -> None:
        pass


def per_read_us(source, reads: int, repeats: int) -> list[float]:
    """Microseconds per ``source.read()``, one value per repeat of ``reads`` reads (wall, perf_counter)."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(reads):
            source.read()
        out.append(1e6 * (time.perf_counter() - t0) / reads)
    return out


def ask_ms(leds: LedController, repeats: int) -> list[float]:
    """Milliseconds of one ``state()`` round trip, the question a dark frame asks."""
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        leds.state()
        out.append(1e3 * (time.perf_counter() - t0))
    return out


def said(name: str, values: list[float], unit: str) -> str:
    return (
        f"{name}: median {statistics.median(values):.1f} {unit} [{min(values):.1f}-{max(values):.1f}], n={len(values)}"
    )


def board_rows(url: str, still: Still, a: argparse.Namespace, kind: str) -> None:
    with LedController.open(url) as leds:
        leds.set_all(np.full((leds.n_leds, 3), 200, np.uint8))
        print(said(f"{kind}: watched read", per_read_us(ResetWatch(still, leds), a.reads, a.repeats), "us"))
        print(said(f"{kind}: one question (state)", ask_ms(leds, 20), "ms"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reads", type=int, default=500)
    ap.add_argument("--repeats", type=int, default=15)
    ap.add_argument("--size", default="640x480")
    a = ap.parse_args()
    w, h = map(int, a.size.split("x"))
    still = Still(h, w)
    print(said("bare read", per_read_us(still, a.reads, a.repeats), "us"))
    level = [1e6 * t / a.reads for t in _timed(lambda: frame_level(still.frame), a.reads, a.repeats)]
    print(said(f"frame_level {w}x{h}", level, "us"))
    with VirtualBoard(12) as board:
        board_rows(board.url, still, a, "virtual")
    if (why := missing_device_tools()) is not None:
        print(f"simavr: skipped ({why})")
        return
    with tempfile.TemporaryDirectory() as tmp:
        elf, harness = build_firmware(Path(tmp))
        sim = SimavrUnderTest(elf, harness, Path(tmp) / "ttyNLIPS")
        try:
            sim.pace(115200)
            board_rows(sim.url, still, a, "simavr 115200")
        finally:
            sim.close()


def _timed(call, n: int, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(n):
            call()
        out.append(time.perf_counter() - t0)
    return out


if __name__ == "__main__":
    main()
