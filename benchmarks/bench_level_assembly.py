"""A whole-frame level's normal matrix: the fixed-pattern map (what the whole gel's disk-cached levels use) against
the grid stencil (every other level's), in one process: each one's build, and their assemblies interleaved, wall and
CPU (process time, both cores' work counted).

Why: the disk-cached whole-frame levels keep the fixed pattern, chosen before the grid stencil existed
(solver.operators.OPERATOR_PERSIST_PIXELS); tests/solver/test_reuse.py shows the two assemble the same H there. Whether
the stencil would also be the faster choice on those levels is this script's question (s35-leftovers).

Run: .venv/bin/python benchmarks/bench_level_assembly.py [--width 640 --height 480] [--pairs 7]
Prints a Markdown table; the results are in benchmarks/RESULTS.md (s35-leftovers).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _clocked(fn):
    """(fn(), wall s, process CPU s)."""
    wall, cpu = time.perf_counter(), time.process_time()
    value = fn()
    return value, time.perf_counter() - wall, time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    parser.add_argument("--pairs", type=int, default=7, help="interleaved assembly pairs (default 7)")
    args = parser.parse_args()
    os.environ.setdefault("NLIPS_CACHE_DIR", "off")  # made here, never read from a cache

    import numpy as np

    from nlipscalib.solver import operators

    mask = np.ones((args.height, args.width), bool)
    n = int(mask.sum())
    rng = np.random.default_rng(0)
    blocks = rng.normal(size=(3, 3, n))
    blocks = np.einsum("abn,cbn->acn", blocks, blocks)
    weights = (rng.uniform(0.01, 1.0, n), 0.3)
    ops = operators._make_operators(mask)  # the difference operators; the stencil is made below
    ways = {}
    built = {}
    for name, fixed in (("grid stencil", False), ("fixed-pattern map", True)):
        ways[name], *built[name] = _clocked(lambda fixed=fixed: operators._normal_matrix(ops, mask, fixed=fixed))
    for way in ways.values():
        way.assemble(blocks, weights)  # a first call each: page faults, caches
    times = {name: [] for name in ways}
    for _ in range(args.pairs):
        for name, way in ways.items():
            times[name].append(_clocked(lambda way=way: way.assemble(blocks, weights))[1:])
    print(f"{args.width}x{args.height} whole frame ({n} pixels), load average {os.getloadavg()[0]:.1f}\n")
    print("| assembly | build wall s (CPU s) | assemble wall ms, median [range] | assemble CPU ms, median | n |")
    print("|---|---|---|---|---|")
    for name, rows in times.items():
        walls, cpus = [1e3 * w for w, _ in rows], [1e3 * c for _, c in rows]
        print(
            f"| {name} | {built[name][0]:.2f} ({built[name][1]:.2f}) | {statistics.median(walls):.1f} "
            f"[{min(walls):.1f}-{max(walls):.1f}] | {statistics.median(cpus):.1f} | {len(rows)} |"
        )


if __name__ == "__main__":
    main()
