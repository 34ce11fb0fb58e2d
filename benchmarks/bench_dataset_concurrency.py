"""Cost of concurrency safety: one claim (acquire + release), and `nlips dataset` from 1 vs 2 processes.

Usage: PYTHONPATH=. python benchmarks/bench_dataset_concurrency.py [--presses 8]
Writes the section "dataset concurrency (bench_dataset_concurrency.py)" of RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one
from common import median_time, write_section  # noqa: E402

from nlipscalib.core.claims import claim  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SPEC = """
scene = "nlipstac"
seed = 1
reference = false
[render]
spp = 1
[camera]
width = 160
height = 120
[random]
count = {count}
indenters = [{{ kind = "sphere", size = 4.0 }}]
polar_deg = [0.0, 20.0]
depth = [0.5, 1.0]
"""


def _claim_once(folder: Path) -> None:
    with claim(folder / "item") as mine:
        assert mine


def _dataset_wall(spec: Path, out: Path, processes: int) -> float:
    code = "import sys; from nlipscalib.cli import command; sys.exit(command())"
    cmd = [sys.executable, "-c", code, "--no-progress", "dataset", str(spec), "--out", str(out), "--workers", "1"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    procs = [
        subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL) for _ in range(processes)
    ]
    assert all(p.wait() == 0 for p in procs)
    return time.perf_counter() - t0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--presses", type=int, default=8)
    args = parser.parse_args()
    load_before = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        claim_s, _ = median_time(lambda: _claim_once(tmp), repeats=50, warmup=5)
        spec = tmp / "spec.toml"
        spec.write_text(SPEC.format(count=args.presses), encoding="utf-8")
        one = _dataset_wall(spec, tmp / "one", 1)
        two = _dataset_wall(spec, tmp / "two", 2)
        recheck = _dataset_wall(spec, tmp / "two", 1)
    load_after = os.getloadavg()[0]
    body = f"""
{args.presses} presses at 160x120, spp 1, `--workers 1` per process; whole-process wall time of the user's command(s).
Load average before: {load_before:.2f}, after: {load_after:.2f} (2 cores shared with other sessions: contended).

| measurement | time |
|---|---|
| one claim: acquire + heartbeat thread + release (median of 50, local disk) | {claim_s * 1e3:.2f} ms |
| `nlips dataset`, 1 process | {one:.1f} s |
| `nlips dataset`, 2 processes on the same folder (until both exit) | {two:.1f} s |
| re-check of the finished dataset (nothing to render) | {recheck:.1f} s |
"""
    write_section("dataset concurrency (bench_dataset_concurrency.py)", body)
    print(body)


if __name__ == "__main__":
    main()
