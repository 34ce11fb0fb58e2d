"""CPU of the interreflection gather's visibility test (``radiosity._hidden`` inside ``radiosity.gather_grid``) on
a press's own gathers (issue 6, s43-viscost).

Solves PRESS (a press folder, whole frame, default options) in-process on one thread, keeping the arguments of
every ``gather_grid`` call of the solve (one per outer pass), then times each call again REPEATS times with the
test and without it (``time.process_time``, median): the test's cost is the difference. Prints per call the two
medians, the difference and an MD5 of the gathered light with the test, so that two versions of the package (run
this file from each checkout) can be compared bit for bit.

Usage: python benchmarks/bench_visibility.py PRESS [--repeats 5]

Prints only (benchmarks/RESULTS.md, s43-viscost, has the runs).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from pathlib import Path

for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NLIPS_THREADS"):
    os.environ[_name] = "1"  # one thread: the CPU time is the work, not the pool's waiting

import numpy as np  # noqa: E402 -- after the thread counts, which OpenBLAS reads at import

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def gather_calls(press: str) -> list[tuple[tuple, dict]]:
    """The (args, kwargs) of every ``radiosity.gather_grid`` call of PRESS's solve."""
    from nlipscalib.solver import indirect, radiosity
    from nlipscalib.solver.press import solve_press

    calls = []
    plain = radiosity.gather_grid

    def keep(*args, **kwargs):
        calls.append((args, kwargs))
        return plain(*args, **kwargs)

    indirect.radiosity.gather_grid = keep
    try:
        solve_press(press)
    finally:
        indirect.radiosity.gather_grid = plain
    return calls


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("press")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    from nlipscalib.solver import radiosity

    calls = gather_calls(args.press)
    print(f"{args.press}: {len(calls)} gathers ({radiosity.__file__})")
    for n, (a, kw) in enumerate(calls):
        median = {}
        for visibility in (True, False):
            cpu = []
            for _ in range(args.repeats):
                start = time.process_time()
                light = radiosity.gather_grid(*a, **kw, visibility=visibility)
                cpu.append(time.process_time() - start)
            median[visibility] = float(np.median(cpu))
            if visibility:
                md5 = hashlib.md5(light.tobytes()).hexdigest()[:12]
        print(
            f"gather {n}: with the test {1e3 * median[True]:.1f} ms, without {1e3 * median[False]:.1f} ms, "
            f"test {1e3 * (median[True] - median[False]):.1f} ms, md5 {md5}"
        )


if __name__ == "__main__":
    main()
