"""The cost per frame of undoing a measured camera response against the sRGB curve's (the same lookups: the 8-bit
frame's 256-entry ``cv2.LUT`` in ``device.camera.to_stored``, the 16-bit frame's ``np.take`` in ``undo_tone_curve``),
timed interleaved, and the error of the curve ``nlips calibrate-camera-response --emulate`` recovers.

Run::

    PYTHONPATH=. python benchmarks/bench_response.py [--pairs 7] [--size 160x120] [--no-fit]
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from nlipscalib.core.response_curve import curve_id, read_response_file
from nlipscalib.core.sensor_response import tone_curve_table, undo_tone_curve
from nlipscalib.device.camera import to_stored
from nlipscalib.emulator import EMULATED_TONE_CURVES

REPEATS = 50
"""Frames converted per timing (the median per frame is reported)."""


def _per_frame(convert, frame: np.ndarray) -> float:
    t0 = time.perf_counter()
    for _ in range(REPEATS):
        convert(frame)
    return (time.perf_counter() - t0) / REPEATS * 1000.0


def lookup_costs(pairs: int) -> dict[str, list[float]]:
    """ms per 640x480 frame of each conversion, ``pairs`` interleaved rounds."""
    rng = np.random.default_rng(0)
    eight = rng.integers(0, 256, (480, 640, 3), dtype=np.uint8)
    sixteen = rng.integers(0, 65536, (480, 640, 3), dtype=np.uint16)
    curve = tuple(float(v) for v in np.linspace(0, 1, 256) ** 2.2)
    tables = {
        "srgb": tone_curve_table("srgb", 0.0, 65280.0),
        "measured": tone_curve_table(curve_id(curve), 0.0, 65280.0, curve),
    }
    times: dict[str, list[float]] = {}
    builders = {
        "srgb": lambda: tone_curve_table("srgb", 0.0, 65280.0),
        "measured": lambda: tone_curve_table(curve_id(curve), 0.0, 65280.0, curve),
    }
    for _ in range(pairs):
        for name, table in tables.items():
            times.setdefault(f"table {name} (once a load)", []).append(
                _per_frame(lambda _f, b=builders[name]: b(), None)
            )
            times.setdefault(f"8-bit {name}", []).append(_per_frame(lambda f, t=table: to_stored(f, "bench", t), eight))
            times.setdefault(f"16-bit {name}", []).append(
                _per_frame(lambda f, t=table: undo_tone_curve(f.copy(), t), sixteen)
            )
    return times


def fit_errors(size: str) -> None:
    """Whole-process wall of the command and the recovered curve's error, per emulated curve."""
    width, height = size.split("x")
    grid = np.linspace(0, 1, 400001, dtype=np.float32)
    with tempfile.TemporaryDirectory() as tmp:
        for name, encode in EMULATED_TONE_CURVES.items():
            out = Path(tmp) / f"{name}.json"
            cmd = [sys.executable, "-m", "nlipscalib", "--no-progress", "calibrate-camera-response", "--emulate"]
            cmd += ["nlipstac", "--emulate-tone-curve", name, "--width", width, "--height", height, "--spp", "4"]
            t0 = time.perf_counter()
            subprocess.run([*cmd, "--out", str(out)], check=True, capture_output=True)
            wall = time.perf_counter() - t0
            # every curve takes (..., 3) values (rgb-gammas: a gamma per channel); the truth per channel, (3, 256)
            encoded = encode(np.repeat(grid[:, None], 3, axis=1)).astype(np.float64)
            codes = np.arange(256) / 255
            truth = np.stack([np.interp(codes, encoded[:, c], grid.astype(np.float64)) for c in range(3)])
            response = read_response_file(out)
            error = np.abs(np.broadcast_to(np.asarray(response.curve), (3, 256)) - truth).max(axis=0)
            print(
                f"{name}: max error codes 10-250 {error[10:251].max():.4f}, all codes {error.max():.4f} of full "
                f"scale; fit residual {response.provenance['fit_residual']:.4f}; command wall {wall:.2f} s"
            )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--pairs", type=int, default=7)
    p.add_argument("--size", default="160x120")
    p.add_argument("--no-fit", action="store_true")
    args = p.parse_args()
    for name, values in lookup_costs(args.pairs).items():
        spread = f"[{min(values):.3f}-{max(values):.3f}]"
        print(f"{name}: {statistics.median(values):.3f} ms each {spread}, n={len(values)}")
    if not args.no_fit:
        fit_errors(args.size)


if __name__ == "__main__":
    main()
