"""Solver speed and accuracy on exact-data presses (analytic dome + dent, project forward model).

Run: .venv/bin/python benchmarks/bench_solver.py [--repeats 3]
Writes/updates the "bench_solver" section of benchmarks/RESULTS.md (machine, command, median, date, load).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.solver import evaluate, solve_press  # noqa: E402
from tests.solver import synth  # noqa: E402

RESULTS = Path(__file__).with_name("RESULTS.md")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backends", default="numpy,torch")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for kind in ("sphere", "cube"):
            press = load_press(synth.make_press(Path(tmp) / kind, kind, size=(640, 480)))
            gt = press.ground_truth
            rows_c, cols_c = np.nonzero(gt.contact)
            cy, cx = int(rows_c.mean()), int(cols_c.mean())
            roi = (min(max(cx - 80, 0), 480), min(max(cy - 80, 0), 320), 160, 160)
            for backend in args.backends.split(","):
                for label, r in (("full 640x480", None), ("ROI 160x160", roi)):
                    times, res = [], None
                    for _ in range(args.repeats):
                        t = time.perf_counter()
                        res = solve_press(press, roi=r, backend=backend)
                        times.append(time.perf_counter() - t)
                    s = evaluate(res, gt)
                    rows.append((kind, label, backend, float(np.median(times)), s["all"]["aae_deg"],
                                 s["contact"]["aae_deg"], s["all"]["depth_rmse_mm"]))
                    print(rows[-1], flush=True)
    load = os.getloadavg()
    lines = [
        "<!-- bench_solver:start -->",
        "## bench_solver (NLiPs solver, exact-data presses, 12 LEDs)",
        "",
        f"- date: {datetime.datetime.now().isoformat(timespec='seconds')}",
        f"- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, load avg {load[0]:.2f}"
        " (other agents share the cores)",
        f"- command: `.venv/bin/python benchmarks/bench_solver.py --repeats {args.repeats}`",
        "",
        "| press | size | backend | median s | AAE all (deg) | AAE contact (deg) | depth RMSE (mm) |",
        "|---|---|---|---|---|---|---|",
    ]
    lines += [f"| {k} | {lab} | {b} | {t:.2f} | {a:.3f} | {c:.3f} | {d:.4f} |" for k, lab, b, t, a, c, d in rows]
    lines.append("<!-- bench_solver:end -->")
    section = "\n".join(lines) + "\n"
    text = RESULTS.read_text() if RESULTS.is_file() else "# Benchmark results\n\n"
    pattern = re.compile(r"<!-- bench_solver:start -->.*?<!-- bench_solver:end -->\n?", re.S)
    text = pattern.sub(section, text) if pattern.search(text) else text + "\n" + section
    RESULTS.write_text(text)


if __name__ == "__main__":
    main()
