"""Solver speed and accuracy: exact-data presses (analytic dome + dent, the project's forward model) and,
when the digital twin is installed, a rendered press (Mitsuba, noise on).

Each case is a full 640x480 solve (the whole visible gel) and a 160x160 region of interest centred on
the contact, 12 LEDs, default SolverOptions. Times are medians of ``--repeats`` runs after one warm-up,
wall clock and process CPU time (the 2 cores are shared with other work: CPU time is the steadier
number) of ``solve_press`` in this process, next to the process wall and CPU of the command a user runs
(``nlips solve PRESS [--roi x0 y0 w h] --overwrite``: imports, loading, solving, saving, figures).

Run: .venv/bin/python benchmarks/bench_solver.py [--repeats 3] [--backends numpy,torch]
Writes the "bench_solver" section of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bench_command import run_process  # noqa: E402
from common import median_time, write_section  # noqa: E402

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.metrics import evaluate  # noqa: E402
from nlipscalib.solver import solve_press  # noqa: E402
from tests.solver import synth  # noqa: E402

ROI_SIZE = 160


def presses(tmp: Path) -> list[tuple[str, Path]]:
    """(label, folder) of every press to time: exact-data sphere and cube, and a twin render if possible."""
    out = [(f"exact {kind}", synth.make_press(tmp / kind, kind, size=(640, 480))) for kind in ("sphere", "cube")]
    try:
        from nlipscalib.sim.indent import IndenterConfig, PressConfig
        from nlipscalib.sim.press import render_press
        from nlipscalib.sim.scene import load_scene
    except ImportError as exc:  # the twin needs Mitsuba
        print(f"twin press skipped: {exc}", flush=True)
        return out
    press = PressConfig(IndenterConfig("sphere", 6.0), polar_deg=15.0, azimuth_deg=30.0, depth=1.0)
    folder = tmp / "twin"
    render_press(load_scene(), press, folder, seed=1, overwrite=True)
    out.append(("twin sphere", folder))
    return out


def contact_roi(press) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) of a ROI_SIZE square centred on the ground-truth contact, inside the image."""
    rows, cols = np.nonzero(press.ground_truth.contact)
    H, W = press.camera.shape
    x0 = int(np.clip(cols.mean() - ROI_SIZE // 2, 0, W - ROI_SIZE))
    y0 = int(np.clip(rows.mean() - ROI_SIZE // 2, 0, H - ROI_SIZE))
    return x0, y0, ROI_SIZE, ROI_SIZE


def time_case(press, roi, backend: str, repeats: int) -> dict:
    """Median wall and CPU seconds of one solve, and its accuracy against the ground truth."""
    result = {}

    def run():
        c = time.process_time()
        result["res"] = solve_press(press, roi=roi, backend=backend)
        result.setdefault("cpu", []).append(time.process_time() - c)

    wall, _ = median_time(run, repeats=repeats, warmup=1)
    res = result["res"]
    scores = evaluate(res, press.ground_truth)
    finest = res.report["levels"][-1]
    return {
        "wall": wall,
        "cpu": float(np.median(result["cpu"][1:])),  # the first entry is the warm-up
        "aae": scores["all"]["aae_deg"],
        "aae_contact": scores["contact"]["aae_deg"],
        "rmse": scores["all"]["depth_rmse_mm"],
        "iters": sum(lv["iterations"] for lv in res.report["levels"]),
        "finest_iters": finest["iterations"],
    }


def time_command(folder: Path, roi, backend: str, repeats: int) -> dict:
    """Median process wall and CPU seconds of ``nlips solve folder`` (one warm-up run first)."""
    extra = [] if roi is None else ["--roi", *(str(v) for v in roi)]
    args = ["solve", str(folder), "--overwrite", "--no-progress", "--backend", backend, *extra]
    walls, cpu = [], []
    for _ in range(repeats + 1):
        walls.append(run_process(args, cpu))
    return {"process_wall": float(np.median(walls[1:])), "process_cpu": float(np.median(cpu[1:]))}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--backends", default="numpy")
    args = ap.parse_args()
    load_before = os.getloadavg()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for label, folder in presses(Path(tmp)):
            press = load_press(folder)
            for backend in args.backends.split(","):
                for size, roi in (("full 640x480", None), (f"ROI {ROI_SIZE}x{ROI_SIZE}", contact_roi(press))):
                    r = time_case(press, roi, backend, args.repeats)
                    r.update(time_command(folder, roi, backend, args.repeats))
                    rows.append((label, size, backend, r))
                    print(label, size, backend, {k: round(v, 4) for k, v in r.items()}, flush=True)
    load_after = os.getloadavg()
    lines = [
        f"12 LEDs, default SolverOptions; median of {args.repeats} runs after a warm-up. "
        f"Load average before {load_before[0]:.2f}, after {load_after[0]:.2f} (2 cores, shared).",
        "Goals (issue 6, process wall of `nlips solve` on 2 cores): whole 640x480 frame <= 4 s, auto ROI <= 1.5 s.",
        "",
        "| press | size | backend | solve_press wall s | solve_press CPU s | `nlips solve` process wall s "
        "| `nlips solve` process CPU s | iterations (finest) | AAE all (deg) | AAE contact (deg) | depth RMSE (mm) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for label, size, backend, r in rows:
        lines.append(
            f"| {label} | {size} | {backend} | {r['wall']:.2f} | {r['cpu']:.2f} | {r['process_wall']:.2f} "
            f"| {r['process_cpu']:.2f} | {r['iters']} ({r['finest_iters']}) "
            f"| {r['aae']:.3f} | {r['aae_contact']:.3f} | {r['rmse']:.4f} |"
        )
    write_section("bench_solver", "\n".join(lines))


if __name__ == "__main__":
    main()
