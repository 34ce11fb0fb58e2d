"""Every thread one ``nlips`` command starts: its name, what it runs, when it starts and ends, and its CPU.

Why: a heartbeat, a progress monitor or a poller that wakes needlessly costs CPU the solve could use on a 2-core
machine; this names each thread and its cost, so such a claim can be checked (s32-threads, benchmarks/RESULTS.md).
Python threads are timed from the inside (``time.thread_time`` around ``Thread._bootstrap_inner``, which every thread
runs, tqdm's ``TMonitor`` too, whatever its ``run``); threads the interpreter never sees (OpenBLAS's, Dr.Jit's
nanothread pool) are read from ``/proc/self/task`` at exit (Linux only), with their voluntary context switches
(a thread that wakes on a timer has many). The command runs in this process, as the ``nlips`` script runs it.

Usage::

    PYTHONPATH=. python benchmarks/bench_threads.py [--out FILE] -- -q --no-progress solve PRESS --roi auto
"""

from __future__ import annotations

import argparse
import atexit
import os
import sys
import threading
import time

_T0 = time.monotonic()
_TICK = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
_threads: list[dict] = []
"""One record per Python thread started: name, target, native id, start and end (s from start), cpu (s)."""


def _instrument() -> None:
    """Wrap ``Thread._bootstrap_inner`` so each thread's own CPU time is taken when it ends."""
    bootstrap = threading.Thread._bootstrap_inner

    def timed(self: threading.Thread) -> None:
        target = getattr(self, "_target", None)
        record = {
            "name": self.name,
            "runs": getattr(target, "__qualname__", repr(target)) if target else type(self).run.__qualname__,
            "tid": threading.get_native_id(),
            "start": time.monotonic() - _T0,
        }
        _threads.append(record)
        cpu0 = time.thread_time()
        try:
            bootstrap(self)
        finally:
            record.update(cpu=time.thread_time() - cpu0, end=time.monotonic() - _T0)

    threading.Thread._bootstrap_inner = timed


def _task(tid: int) -> tuple[float, int] | None:
    """CPU (s, user + system) and voluntary context switches of thread ``tid`` of this process, or None if gone."""
    try:
        with open(f"/proc/self/task/{tid}/stat", encoding="utf-8", errors="replace") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        with open(f"/proc/self/task/{tid}/status", encoding="utf-8", errors="replace") as f:
            switches = int(f.read().split("voluntary_ctxt_switches:")[1].split()[0])
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _TICK, switches


def _report(out: str) -> None:
    """Write one line per thread, then the process's totals."""
    lines, known = [], {r["tid"] for r in _threads}
    for r in _threads:
        if "cpu" in r:
            lines.append(f"{r['name'][:30]:30s} {r['runs'][:46]:46s} {r['start']:7.2f} {r['end']:7.2f} {r['cpu']:7.3f}")
        else:  # a daemon thread still running: its CPU so far, from the kernel
            cpu = (_task(r["tid"]) or (float("nan"), 0))[0]
            lines.append(f"{r['name'][:30]:30s} {r['runs'][:46]:46s} {r['start']:7.2f} {'alive':>7s} {cpu:7.3f}")
    main = threading.main_thread().native_id
    native = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else []
    for tid in sorted(set(native) - known - {main}):
        seen = _task(tid)
        if seen:
            lines.append(
                f"{'(native, not Python)':30s} {f'{seen[1]} voluntary switches':46s} {'':7s} {'alive':>7s} "
                f"{seen[0]:7.3f}"
            )
    user, system = os.times()[:2]
    main_cpu = (_task(main) or (float("nan"), 0))[0]
    head = f"{'thread':30s} {'runs':46s} {'start':>7s} {'end':>7s} {'cpu s':>7s}"
    tail = f"main thread {main_cpu:.3f} s CPU; process {user + system:.3f} s; wall {time.monotonic() - _T0:.2f} s"
    with open(out, "w", encoding="utf-8") if out != "-" else sys.stderr as stream:
        print("\n".join([head, *lines, tail]), file=stream)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="-", help="file for the table (default: stderr)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- then the nlips command's arguments")
    args = parser.parse_args()
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the nlips command's arguments after --")
    _instrument()
    atexit.register(_report, args.out)  # after the command's own exit work (pools joined, bars closed)
    sys.argv = ["nlips", *command]
    from nlipscalib.__main__ import command as nlips  # the console script's entry, its environment settings too

    nlips()


if __name__ == "__main__":
    main()
