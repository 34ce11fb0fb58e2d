"""What the lookup table (``learn.lut.LookupTable.predict``, ``nlips infer TABLE.pt``) pays for a frame's changed
pixels: its answers kept for every bin (the default) against the k-d tree search of each region's filled bins, on a
table of a 640x480 sensor's size (16 levels, 8x8 regions, fitted on synthetic samples that fill ~100,000 bins) and a
contact of 20,000 pixels. Both give the same normals (checked). Usage::

    python benchmarks/bench_lut_predict.py [--pixels 20000] [--repeats 9]
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nlipscalib.learn import lut  # noqa: E402


def table(seed: int = 0) -> tuple[lut.LookupTable, np.ndarray]:
    """A 640x480 table fitted on 400,000 samples of a smooth colour -> normal mapping with noise; and their colours."""
    rng = np.random.default_rng(seed)
    n = 400_000
    pixel = np.stack([rng.integers(0, 640, n), rng.integers(0, 480, n)], -1)
    normal = rng.normal(size=(n, 3))
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    rgb = 0.3 + 0.2 * normal + 0.01 * rng.normal(size=(n, 3))
    return lut.LookupTable.fit(pixel, rgb, normal, np.full((480, 640, 3), 0.3, np.float32)), rgb


def times_ms(t: lut.LookupTable, pixel: np.ndarray, rgb: np.ndarray, repeats: int) -> list[float]:
    out = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        t.predict(pixel, rgb)
        out.append(1e3 * (time.perf_counter() - t0))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pixels", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args()
    t, colours = table()
    rng = np.random.default_rng(1)
    pixel = np.stack([rng.integers(200, 340, args.pixels), rng.integers(160, 300, args.pixels)], -1).astype(np.float32)
    rgb = colours[: args.pixels].astype(np.float32)
    t0 = time.perf_counter()
    dense = t.predict(pixel, rgb)  # the first call makes the answers (the Predictor's warm-up, not a frame)
    build = 1e3 * (time.perf_counter() - t0)
    kept = times_ms(t, pixel, rgb, args.repeats)
    limit, lut.DENSE_ANSWERS = lut.DENSE_ANSWERS, 0
    searched = t.predict(pixel, rgb)
    tree = times_ms(t, pixel, rgb, args.repeats)
    lut.DENSE_ANSWERS = limit
    assert np.array_equal(dense, searched), "the kept answers differ from the search's"
    filled = sum(len(v[0]) for r, v in t.tables.items() if r != -1)
    print(f"table: {t.bins} levels, {t.cells}x{t.cells} regions, {filled} bins filled; {args.pixels} pixels")
    print(f"answers made once: {build:.0f} ms")
    for name, ms in (("kept answers", kept), ("k-d trees", tree)):
        print(f"{name}: median {statistics.median(ms):.2f} ms [{min(ms):.2f}-{max(ms):.2f}]")


if __name__ == "__main__":
    main()
