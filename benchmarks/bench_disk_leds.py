"""What ``nlips solve --leds FILE --led-model disks`` costs against points: whole-process runs, interleaved.

Each round runs, in turn, every arm: this tree's ``--led-model points`` and ``disks`` and, with ``--before DIR`` (a
checkout of another revision, e.g. ``git worktree add --detach DIR REV``), that tree's two. Each arm is its own
process (``python -m nlipscalib solve PRESS --leds FILE --led-model M --out OUT --overwrite --no-figures -q``) with
its own bytecode folder and disk cache (kept over the rounds, as a user's are), the tree on ``PYTHONPATH``. The first
round is a warm-up and not counted. Per arm: the medians [ranges] of the process's wall and user+sys CPU, the solver's
own timer (``report.json`` ``seconds``), per round the ratio of each arm to the same tree's points, and the contact's
AAE / depth RMSE of its last solve.

Usage: python benchmarks/bench_disk_leds.py PRESS LEDS.json [--before DIR] [--rounds 5] [--near-idle] [--work DIR]

Prints only (benchmarks/RESULTS.md, s33-diskfast, has the runs).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parents[1]


def _run(
    tree: Path, press: str, leds: str, model: str, work: Path, name: str, near_idle: bool = False
) -> tuple[float, float, float]:
    """(wall s, user+sys s, the solver's own s) of one ``nlips solve`` process of ``tree``; ``near_idle``: in a
    session of its own whose autogroup is at nice -20 (root; benchmarks/RESULTS.md, s32-cubespeed: on a machine loaded
    by others the process then gets the cores as on an idle one)."""
    env = dict(os.environ, PYTHONPATH=str(tree), PYTHONPYCACHEPREFIX=str(work / f"pyc-{name}"))
    env["NLIPS_CACHE_DIR"] = str(work / f"cache-{name}")
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # a user's bytecode is written once and read after
    out = work / f"out-{name}"
    args = [sys.executable, "-m", "nlipscalib", "solve", press, "--leds", leds, "--led-model", model]
    if near_idle:
        args = ["setsid", "bash", "-c", 'echo -20 > /proc/self/autogroup && exec "$@"', "bash", *args]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    wall = time.perf_counter()
    quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}  # its warnings are the same every round
    subprocess.run(
        [*args, "--out", str(out), "--overwrite", "--no-figures", "-q"], env=env, cwd=tree, check=True, **quiet
    )
    wall = time.perf_counter() - wall
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    seconds = json.loads((out / "report.json").read_text(encoding="utf-8"))["seconds"]
    return wall, cpu, float(seconds)


def _scores(press: str, out: Path) -> str:
    """The contact's AAE (deg) / depth RMSE (mm) of the solve in ``out`` (``nlips eval``'s figures; the press needs
    its gt.npz)."""
    from nlipscalib.core import load_press
    from nlipscalib.core.metrics import evaluate
    from nlipscalib.core.reconstruction import load_reconstruction

    truth = load_press(press).ground_truth
    contact = evaluate(load_reconstruction(out, truth.depth.shape), truth)["contact"]
    return f"{contact['aae_deg']:.3f} / {contact['depth_rmse_mm']:.4f}"


def _summary(values: np.ndarray) -> str:
    return f"{np.median(values):.3f} [{values.min():.3f}-{values.max():.3f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("press")
    ap.add_argument("leds")
    ap.add_argument("--before", type=Path, help="another revision's checkout, run as two more arms")
    ap.add_argument("--rounds", type=int, default=5, help="counted rounds (one warm-up round more)")
    ap.add_argument("--near-idle", action="store_true", help="each process at autogroup nice -20 (root)")
    ap.add_argument("--work", type=Path, help="folder for the outputs, bytecode and caches (default: a temporary one)")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="bench-disk-leds-"))
    trees = {"this": HERE, **({"before": args.before.resolve()} if args.before else {})}
    arms = [(tree, model) for tree in trees for model in ("points", "disks")]
    times = {arm: [] for arm in arms}
    for round_ in range(args.rounds + 1):
        for tree, model in arms:
            row = _run(
                trees[tree],
                str(Path(args.press).resolve()),
                str(Path(args.leds).resolve()),
                model,
                work,
                f"{tree}-{model}",
                args.near_idle,
            )
            if round_:
                times[tree, model].append(row)
    for (tree, model), rows in times.items():
        rows = np.array(rows)
        ratio = rows / np.array(times[tree, "points"])
        print(
            f"{tree:6s} {model:6s} n={len(rows)} wall {_summary(rows[:, 0])} s, user+sys {_summary(rows[:, 1])} s, "
            f"solver {_summary(rows[:, 2])} s; per round / points: wall {_summary(ratio[:, 0])}, "
            f"user+sys {_summary(ratio[:, 1])}, solver {_summary(ratio[:, 2])}; contact AAE / RMSE "
            f"{_scores(args.press, work / f'out-{tree}-{model}')}"
        )


if __name__ == "__main__":
    main()
