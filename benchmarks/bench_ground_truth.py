"""CPU of reading a press's ground truth (gt.npz) as its readers read it.

Run:  PYTHONPATH=. python benchmarks/bench_ground_truth.py [PRESS ...] [--repeats 15]

Two readers: a score (``nlips eval``: :meth:`GroundTruth.load` and the depth, normals, valid and contact masks it
reads) and an error map (``nlips infer``/``solve``'s error.png: :func:`read_ground_truth`, which checks the surface,
and the contact mask). Process CPU per read (``time.process_time``, steadier than wall time on a shared machine),
median and range over ``--repeats`` reads after one warm-up read (the file in the page cache).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's package, not an installed one

from nlipscalib.core.capture import read_ground_truth  # noqa: E402
from nlipscalib.core.press_meta import read_meta  # noqa: E402
from nlipscalib.core.surface_files import GroundTruth  # noqa: E402


def score_read(press: Path) -> tuple:
    meta = read_meta(press)
    gt = GroundTruth.load(press / meta["ground_truth"], (meta["camera"]["height"], meta["camera"]["width"]))
    return gt.valid, gt.contact, gt.normals, gt.depth


def error_map_read(press: Path) -> tuple:
    gt = read_ground_truth(press)
    return gt.normals, gt.valid, gt.contact


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("presses", nargs="*", type=Path, default=[Path("/tmp/keep/coin1")])
    parser.add_argument("--repeats", type=int, default=15)
    args = parser.parse_args()
    for press in args.presses:
        for name, read in (("score", score_read), ("error map", error_map_read)):
            read(press)
            cpu = []
            for _ in range(args.repeats):
                start = time.process_time()
                read(press)
                cpu.append(time.process_time() - start)
            ms = [1000 * c for c in cpu]
            print(f"{press.name} {name}: CPU median {statistics.median(ms):.1f} ms [{min(ms):.1f}-{max(ms):.1f}]")


if __name__ == "__main__":
    main()
