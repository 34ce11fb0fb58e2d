"""Shared bits of the benchmark scripts: timing medians and writing a section of RESULTS.md."""

from __future__ import annotations

import datetime
import platform
import re
import statistics
import sys
import time
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")


def machine() -> str:
    """One line describing this machine (the same facts the experiments record)."""
    from nlipscalib.experiments.provenance import machine as machine_facts

    m = machine_facts()
    return f"{m['cpu']}, {m['cores']} cores, Python {platform.python_version()}"


def median_time(fn, repeats: int = 5, warmup: int = 1) -> tuple[float, list[float]]:
    """Median wall time of ``fn()`` in seconds over ``repeats`` runs after ``warmup`` runs."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), times


def twin_presses(folders: list[Path], reference: Path | None) -> tuple[object, list[tuple[Path, object]]]:
    """The undeformed capture (None without one) and each twin press folder's loaded press; exits with one line
    naming a folder without ground truth (gt.npz), which a press the twin did not render lacks."""
    from nlipscalib.core import load_press

    presses = []
    for folder in folders:
        press = load_press(folder)
        if press.ground_truth is None:
            sys.exit(f"{folder}: no ground truth (gt.npz): not a twin's render")
        presses.append((folder, press))
    return (load_press(reference) if reference else None), presses


def write_section(name: str, body: str) -> None:
    """Replace (or append) the section ``## name`` of RESULTS.md, keeping the others."""
    header = f"## {name}"
    stamp = f"_machine: {machine()}; date: {datetime.date.today().isoformat()}; command: `{' '.join(sys.argv)}`_"
    section = f"{header}\n{stamp}\n\n{body.strip()}\n"
    text = (
        RESULTS.read_text(encoding="utf-8")
        if RESULTS.exists()
        else "# Benchmark results\n\nEach section is rewritten by its script.\n"
    )
    pattern = re.compile(rf"^{re.escape(header)}\n.*?(?=^## |\Z)", re.S | re.M)
    text = pattern.sub(lambda _: section + "\n", text) if pattern.search(text) else text.rstrip() + "\n\n" + section
    tmp = RESULTS.with_suffix(".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(RESULTS)
