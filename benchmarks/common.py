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


def ms_spread(fn, repeats: int, digits: int = 3) -> str:
    """``median [min-max]`` of ``fn()``'s time in ms over ``repeats`` runs after one warm-up (:func:`median_time`)."""
    _, times = median_time(fn, repeats)
    ms = [t * 1e3 for t in times]
    return f"{statistics.median(ms):.{digits}f} [{min(ms):.{digits}f}-{max(ms):.{digits}f}]"


def nlips_process(checkout: Path, args: list[str], tag: str, said: list[str] | None = None) -> tuple[float, float, int]:
    """(wall s, user+sys s, exit status) of one ``python -m nlipscalib ARGS`` process run from ``checkout`` as a
    user's runs: bytecode written (the VM's PYTHONDONTWRITEBYTECODE dropped) under a pycache prefix and a disk cache
    of its own (``/tmp/bench-TAG-pyc``, ``/tmp/bench-TAG-cache``), from the temp folder, its stdout discarded and its
    stderr too unless ``said`` is given (then appended to it: a command's own timing line)."""
    import os
    import resource
    import subprocess
    import tempfile

    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(
        PYTHONPATH=str(checkout), PYTHONPYCACHEPREFIX=f"/tmp/bench-{tag}-pyc", NLIPS_CACHE_DIR=f"/tmp/bench-{tag}-cache"
    )
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "nlipscalib", *args],
        cwd=tempfile.gettempdir(),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL if said is None else subprocess.PIPE,
        text=True,
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if said is not None:
        said.append(proc.stderr)
    return wall, after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime, proc.returncode


def interleaved(sides: list[str], run, pairs: int, what: str) -> dict[str, list[tuple[float, float]]]:
    """Each side's (wall, user+sys) of ``run(side)`` (which returns wall, user+sys, exit status): one warm-up round
    (bytecode caches, the page cache, the disk cache), then ``pairs`` rounds taking the sides in turn, so a load that
    drifts falls on every side alike. SystemExit naming the side and ``what`` when a run fails."""
    times = {side: [] for side in sides}
    for side in sides:
        run(side)
    for _ in range(pairs):
        for side in sides:
            wall, cpu, rc = run(side)
            if rc != 0:
                raise SystemExit(f"{side}: {what}: exit {rc}")
            times[side].append((wall, cpu))
    return times


def timing_rows(times: dict[str, list[tuple[float, float]]], digits: int = 3) -> str:
    """Markdown rows ``| side | wall median [min-max] | user+sys median [min-max] |`` of :func:`interleaved`'s times."""

    def spread(values: list[float]) -> str:
        return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"

    return "\n".join(
        f"| {side} | {spread([w for w, _ in runs])} | {spread([c for _, c in runs])} |" for side, runs in times.items()
    )
