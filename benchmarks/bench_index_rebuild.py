"""A calibration dataset built again over unchanged samples: the whole build (what `nlips calibrate` runs after its
solves, ``learn.dataset.build_dataset``) as a fresh process, alternating between this checkout and another, and
index.json's writing alone in this process.

Why: ``write_index`` read every sample file for its SHA-256 on every build (Q2 full's 74 shards, 127 MB); since
s43-pressid it takes the digest from the index.json it replaces where the file's stat is the one recorded there.
`nlips calibrate` itself is not timed: any change to core/ or learn/ makes it solve every press again (the results'
code fingerprint), hours at 640x480; the build after the solves is the part this changes.

Each checkout builds its own copy of the dataset first (untimed), then the re-builds alternate (``--pairs``), each
process run from a temporary folder with ``PYTHONPATH`` set to its checkout. Reported: median [range] wall and
user+sys seconds of each side; then, in this process, ``write_index`` on this checkout's dataset with its recorded
stats (every digest reused) and without (every file read), CPU ms median [range] over ``--repeats``.

Run: .venv/bin/python benchmarks/bench_index_rebuild.py --presses DIR --before CHECKOUT --work DIR [--pairs 5]
(DIR: press folders solved with NLiPs, PRESS/nlips, and DIR/reference.) Prints its tables (benchmarks/RESULTS.md
holds the run's numbers).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

BUILD = """
import logging, sys
from pathlib import Path
logging.basicConfig(level=logging.WARNING)
from nlipscalib.learn.dataset import build_dataset
root, out = Path(sys.argv[1]), Path(sys.argv[2])
folders = sorted(p for p in root.iterdir() if p.is_dir() and p.name not in ('reference', 'calibration'))
build_dataset(folders, root / 'reference', out, progress=False)
"""


def run_build(root: Path, presses: Path, out: Path) -> tuple[float, float]:
    """(wall s, user+sys s) of one build of ``out`` from ``presses`` by the checkout ``root``, as a fresh process."""
    env = dict(os.environ, PYTHONPATH=str(root))
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as cwd:
        subprocess.run([sys.executable, "-c", BUILD, str(presses), str(out)], env=env, cwd=cwd, check=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def summary(values: list[float]) -> str:
    return f"{statistics.median(values):.2f} [{min(values):.2f}-{max(values):.2f}]"


def time_write_index(dataset: Path, repeats: int) -> dict[str, list[float]]:
    """CPU ms of ``write_index`` on ``dataset`` (this checkout): with its recorded stats, and with them removed."""
    sys.path.insert(0, str(ROOT))
    from nlipscalib.learn.dataset import INDEX_FILE, SamplingConfig, write_index

    index = json.loads((dataset / INDEX_FILE).read_text(encoding="utf-8"))
    cfg = SamplingConfig(**{k: v for k, v in index["sampling"].items()})
    entries = [{k: v for k, v in e.items() if k != "shard"} for e in index["presses"]]
    args = (dataset, index["sensor"], cfg, entries, index["reference"])
    kwargs = {k: index.get(k) for k in ("capture", "reference_files", "tricolor")}
    times: dict[str, list[float]] = {"stats recorded (reused)": [], "no stats (every file read)": []}
    for _ in range(repeats):
        for case in times:
            if case.startswith("no stats"):
                now = json.loads((dataset / INDEX_FILE).read_text(encoding="utf-8"))
                for record in [now.get("sensor_file"), *(e.get("shard") for e in now["presses"])]:
                    (record or {}).pop("stat", None)
                (dataset / INDEX_FILE).write_text(json.dumps(now), encoding="utf-8")
            t = time.process_time()
            write_index(*args, **kwargs)
            times[case].append(1000 * (time.process_time() - t))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presses", type=Path, required=True)
    parser.add_argument("--before", type=Path, required=True, help="the other checkout")
    parser.add_argument("--work", type=Path, required=True, help="where each side's dataset is built")
    parser.add_argument("--pairs", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    sides = {"after": ROOT, "before": args.before.resolve()}
    for name, root in sides.items():  # each side's own dataset, built once (untimed)
        run_build(root, args.presses, args.work / name)
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in sides}
    print("load before:", os.getloadavg())
    for i in range(args.pairs):
        order = list(sides) if i % 2 == 0 else list(reversed(sides))
        for name in order:
            times[name].append(run_build(sides[name], args.presses, args.work / name))
    print("load after:", os.getloadavg())
    print("| checkout | wall s | user+sys s |\n|---|---|---|")
    for name, runs in times.items():
        print(f"| {name} | {summary([w for w, _ in runs])} | {summary([c for _, c in runs])} |")
    print("\n| write_index | CPU ms |\n|---|---|")
    for case, values in time_write_index(args.work / "after", args.repeats).items():
        print(f"| {case} | {summary(values)} |")


if __name__ == "__main__":
    main()
