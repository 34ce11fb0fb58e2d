"""LED protocol round trips against the firmware in simavr at the real line rate (the harness's ``pace BAUD``).

A pseudo-terminal moves bytes as fast as it can, so a timeout too short for a real 115200-baud line never showed.
This times each command, seen by the host (``LedController``), with the harness unpaced and paced at each rate.
Needs gcc-avr, avr-libc and simavr (setup.sh). Usage::

    python benchmarks/bench_leds_line_rate.py [--leds 12,100] [--rates 0,115200,9600] [--repeats 20]
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
from tests.device.ledboards import SimavrUnderTest, build_firmware  # noqa: E402


def time_commands(leds: LedController, n_leds: int, repeats: int) -> dict[str, list[float]]:
    """Seconds of each of ``repeats`` round trips of SET, ALL, STATE, OFF and HELLO."""
    colours = np.random.default_rng(0).integers(0, 256, (n_leds, 3), dtype=np.uint8)
    commands = {
        "SET": lambda: leds.set_led(3, (255, 0, 17)),
        "ALL": lambda: leds.set_all(colours),
        "STATE": leds.state,
        "OFF": leds.off,
        "HELLO": leds.hello,
    }
    times = {}
    for name, command in commands.items():
        times[name] = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            command()
            times[name].append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--leds", default="12,100", help="LED counts of the firmware builds")
    parser.add_argument("--rates", default="0,115200,9600", help="line rates to pace at, baud (0: unpaced)")
    parser.add_argument("--repeats", type=int, default=20)
    args = parser.parse_args()
    for n_leds in (int(n) for n in args.leds.split(",")):
        with tempfile.TemporaryDirectory(prefix="nlips-bench-") as tmp:
            elf, harness = build_firmware(Path(tmp), n_leds)
            board = SimavrUnderTest(elf, harness, Path(tmp) / "tty", n_leds=n_leds)
            try:
                with LedController.open(board.url, timeout=5.0, retries=0) as leds:
                    for rate in (int(r) for r in args.rates.split(",")):
                        board.pace(rate)
                        times = time_commands(leds, n_leds, args.repeats)
                        cells = [
                            f"{name} {1e3 * statistics.median(t):.1f} [{1e3 * min(t):.1f}-{1e3 * max(t):.1f}] ms"
                            for name, t in times.items()
                        ]
                        print(f"{n_leds} LEDs, {rate or 'unpaced'}: " + "; ".join(cells), flush=True)
            finally:
                board.close()


if __name__ == "__main__":
    main()
