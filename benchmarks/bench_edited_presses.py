"""What the readers' comparison of a press with its checksums.json costs (core.press_checksums.check_unchanged, and
``nlips train``'s CalibrationDataset.changed_presses): in process, and in whole commands against another checkout.

In process: ``check_unchanged`` on the press folders given (a stat per recorded file, one JSON read a press), and
``changed_presses`` on ``--dataset``.

Whole commands (``--cmd``, repeated for several): the process wall and user+sys CPU of ``nlips CMD`` run from this
checkout and from ``--against`` (``git worktree add --detach DIR REV``), alternating, ``--pairs`` times after one
warm-up each. ``{side}`` in a command is replaced by ``now`` or ``before`` (each side its own folder where the
command writes). Every process runs with its own ``PYTHONPATH``, bytecode cache and ``NLIPS_CACHE_DIR``, without
``PYTHONDONTWRITEBYTECODE``.

Run: .venv/bin/python benchmarks/bench_edited_presses.py [PRESS...] [--dataset CALIB] [--repeats 9]
     [--cmd "solve /tmp/x-{side}/sphere1 --roi auto --overwrite" --against CHECKOUT --pairs 7]
Prints Markdown tables; the results are in benchmarks/RESULTS.md (s34-checksums).
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import interleaved as interleaved_runs  # noqa: E402
from common import ms_spread, nlips_process, timing_rows  # noqa: E402


def in_process(presses: list[Path], dataset: Path | None, repeats: int) -> None:
    from nlipscalib.core.press_checksums import check_unchanged

    print("| what | ms (median [range]) |\n|---|---|")
    if presses:
        spread = ms_spread(lambda: check_unchanged(presses), repeats, 3)
        print(f"| check_unchanged, {len(presses)} press folder(s) | {spread} |")
    if dataset is not None:
        from nlipscalib.learn.dataset import CalibrationDataset

        data = CalibrationDataset(dataset)
        label = f"changed_presses, {len(data.entries)} presses + reference"
        print(f"| {label} | {ms_spread(data.changed_presses, repeats, 3)} |")


def interleaved(commands: list[str], against: Path, pairs: int) -> None:
    checkouts = {"now": ROOT, "before": against}
    for command in commands:

        def run(side: str, command: str = command) -> tuple[float, float, int]:
            argv = [*shlex.split(command.replace("{side}", side)), "--no-progress"]
            return nlips_process(checkouts[side], argv, f"edited-{side}")

        times = interleaved_runs(list(checkouts), run, pairs, f"nlips {command}")
        print(f"\n`nlips {command}` (n={pairs}, interleaved)\n\n| side | wall s | user+sys s |\n|---|---|---|")
        print(timing_rows(times, 3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("presses", nargs="*", type=Path, help="press folders for check_unchanged")
    parser.add_argument("--dataset", type=Path, help="a calibration dataset for changed_presses")
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--cmd", action="append", default=[], help="an nlips command line ({side}: now / before)")
    parser.add_argument("--against", type=Path, help="the other checkout")
    parser.add_argument("--pairs", type=int, default=7)
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()}")
    if args.presses or args.dataset:
        in_process(args.presses, args.dataset, args.repeats)
    if args.cmd:
        interleaved(args.cmd, args.against, args.pairs)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
