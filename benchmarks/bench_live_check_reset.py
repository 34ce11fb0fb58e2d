"""What ``nlips live`` pays per frame to ask its LED board whether it reset (``LedController.check_reset``: the
bytes waiting on the port read, nothing sent), on the virtual board and on the firmware in simavr behind a
pseudo-terminal (a real port's ``in_waiting`` is one ioctl too). Needs gcc-avr, avr-libc and simavr for the second
(setup.sh; skipped without). Usage::

    python benchmarks/bench_live_check_reset.py [--calls 5000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nlipscalib.device.controller import LedController  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402
from tests.device.ledboards import SimavrUnderTest, build_firmware, missing_device_tools  # noqa: E402


def per_call_us(url: str, calls: int, repeats: int) -> list[float]:
    """Microseconds per ``check_reset`` call, one value per repeat of ``calls`` calls (wall, perf_counter)."""
    with LedController.open(url) as leds:
        out = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(calls):
                leds.check_reset()
            out.append(1e6 * (time.perf_counter() - t0) / calls)
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=5000)
    ap.add_argument("--repeats", type=int, default=5)
    a = ap.parse_args()
    with VirtualBoard(12) as board:
        times = per_call_us(board.url, a.calls, a.repeats)
    print(f"virtual: median {statistics.median(times):.1f} us [{min(times):.1f}-{max(times):.1f}], n={a.repeats}")
    if (why := missing_device_tools()) is not None:
        print(f"simavr: skipped ({why})")
        return
    with tempfile.TemporaryDirectory() as tmp:
        elf, harness = build_firmware(Path(tmp))
        sim = SimavrUnderTest(elf, harness, Path(tmp) / "ttyNLIPS")
        try:
            times = per_call_us(sim.url, a.calls, a.repeats)
        finally:
            sim.close()
    print(f"simavr pty: median {statistics.median(times):.1f} us [{min(times):.1f}-{max(times):.1f}], n={a.repeats}")


if __name__ == "__main__":
    main()
