"""LED controller round trips: how long one acknowledged LED change takes (virtual board, firmware in simavr).

Also the wire-time estimate for a real Uno at 115200 baud and the whole-process wall time of
``nlips leds PORT test --dwell 0``. Usage: python benchmarks/bench_leds.py [--repeats 50]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import median_time, write_section  # noqa: E402

from nlipscalib.device import protocol as p  # noqa: E402
from nlipscalib.device.controller import BAUD_RATE, LedController  # noqa: E402
from nlipscalib.device.virtual_board import VirtualBoard  # noqa: E402

N_LEDS = 12
LATCH_S = 300e-6
WS2812_S_PER_LED = 30e-6


def wire_estimate(command: bytes, reply_bytes: int) -> float:
    """Seconds on a real board: both lines at 10 bits per byte, the WS2812 frame, the latch."""
    return (len(command) + reply_bytes) * 10 / BAUD_RATE + N_LEDS * WS2812_S_PER_LED + LATCH_S


def time_commands(url: str, repeats: int) -> dict[str, float]:
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (repeats + 1, N_LEDS, 3), dtype=np.uint8)
    with LedController.open(url, timeout=2.0) as leds:
        counter = iter(range(10**9))
        out = {
            "SET": median_time(lambda: leds.set_led(next(counter) % N_LEDS, (255, 255, 255)), repeats)[0],
            "ALL": median_time(lambda: leds.set_all(frames[next(counter) % len(frames)]), repeats)[0],
            "STATE": median_time(leds.state, repeats)[0],
            "OFF": median_time(leds.off, repeats)[0],
        }
    return out


def cli_wall_time(url: str) -> float:
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-c", "import sys; from nlipscalib.cli import command; sys.exit(command())"]
        + ["leds", url, "test", "--dwell", "0"],
        check=True,
        capture_output=True,
        env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])},
    )
    return time.perf_counter() - start


def simavr_board(tmp: Path):
    firmware = Path(__file__).resolve().parents[1] / "firmware"
    subprocess.run(["make", "-s", "-C", str(firmware), f"BUILD={tmp}", "all", "harness"], check=True)
    link = tmp / "tty"
    proc = subprocess.Popen(
        [str(tmp / "simavr-harness"), str(tmp / "nlips-led.elf"), str(link)],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    while not proc.stdout.readline().startswith("READY"):
        pass
    return proc, str(link)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=50)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    virtual = VirtualBoard(N_LEDS)  # keep a reference: the registry behind nlipsemu:// is weak
    rows = {"virtual board": time_commands(virtual.url, args.repeats)}
    with tempfile.TemporaryDirectory() as tmp:
        proc, url = simavr_board(Path(tmp))
        try:
            rows["firmware in simavr"] = time_commands(url, args.repeats)
            cli_simavr = cli_wall_time(url)
        finally:
            proc.communicate("quit\n", timeout=10)
    cli_virtual = cli_wall_time("virtual")
    load_after = os.getloadavg()[0]
    colours = p.encode_colours(np.zeros((N_LEDS, 3), np.uint8))
    estimate = {
        "SET": wire_estimate(p.encode_command(1, "SET", 11, "ffffff"), 12),
        "ALL": wire_estimate(p.encode_command(1, "ALL", colours), 12),
        "STATE": wire_estimate(p.encode_command(1, "STATE"), 13 + 6 * N_LEDS) - N_LEDS * WS2812_S_PER_LED - LATCH_S,
        "OFF": wire_estimate(p.encode_command(1, "OFF"), 12),
    }
    lines = [
        f"{N_LEDS} LEDs, median of {args.repeats} acknowledged commands (ms). Load average before: "
        f"{load_before:.2f}, after: {load_after:.2f} (machine shared with other jobs).",
        "",
        "| board | SET | ALL | STATE | OFF |",
        "|---|---|---|---|---|",
    ]
    for name, times in rows.items():
        cells = " | ".join(f"{times[k] * 1e3:.2f}" for k in ("SET", "ALL", "STATE", "OFF"))
        lines.append(f"| {name} | {cells} |")
    lines.append(
        "| real Uno, estimate (115200 baud wire time + WS2812 + 0.3 ms latch) | "
        + " | ".join(f"{estimate[k] * 1e3:.2f}" for k in ("SET", "ALL", "STATE", "OFF"))
        + " |"
    )
    lines += [
        "",
        f"Whole process `nlips leds PORT test --dwell 0` (15 changes, each checked with STATE, Python start "
        f"included): virtual board {cli_virtual:.2f} s, firmware in simavr {cli_simavr:.2f} s.",
        "",
        "simavr clocks UART bytes at the simulated baud rate, but its time is simulated cycles (the harness does "
        "not pace it to the wall clock), so its times are of the same order as a real board's, not a measurement "
        "of one; the pty and the loaded machine add the rest. A capture needs one "
        "acknowledged ALL per image: about 10 ms of LED time per frame, small next to a 33 ms camera frame.",
    ]
    write_section("LED controller round trips (bench_leds.py)", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
