"""Worker pools of a command killed with SIGKILL (the out-of-memory killer, ``kill -9 PID``): the workers end."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from nlipscalib.core.claims import pid_alive

ROOT = Path(__file__).resolve().parents[1]

SOLVER_POOL = """
import sys
from pathlib import Path
from nlipscalib.pipeline.workers import _solve_in_processes
from tests.processes import claim_mark_and_wait
folder = Path(sys.argv[1])
_solve_in_processes(claim_mark_and_wait, [folder], {folder: folder.name}, 1, False, ())
"""
"""A command's solver pool (``nlips solve DATASET --workers N``: forkserver) running one endless press."""

RENDER_POOL = """
import sys
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path
from nlipscalib.progress import worker_logging
from nlipscalib.sim.dataset_pool import _worker_init
from tests.processes import claim_mark_and_wait
spawn = get_context("spawn")
with ProcessPoolExecutor(1, mp_context=spawn, initializer=_worker_init, initargs=worker_logging()) as pool:
    pool.submit(claim_mark_and_wait, Path(sys.argv[1])).result()
"""
"""``nlips dataset --workers N``'s render pool (spawn, its worker initializer) running one endless task."""


@pytest.mark.parametrize("pool", [SOLVER_POOL, RENDER_POOL], ids=["solve", "dataset"])
def test_a_pools_workers_end_when_the_command_is_killed(tmp_path, pool):
    """They waited forever for their next task (a queue whose write end they hold themselves), their memory kept.

    Every process the command started ends, its resource tracker included, before the test does. The pool's 5 named
    semaphores (its queues' locks and the call queue's size) outlive a process killed with SIGKILL, which runs no
    code: its resource tracker unlinks them once the last process holding its pipe (worker, forkserver) has ended,
    and warns "There appear to be 5 leaked semaphore objects" on the command's stderr. That stderr was pytest's
    own, and the tracker could still run when this test ended: its warning then came out after the suite's last
    test (this file runs last). Piped here and read to its end, the warning stays with this test.
    """
    command = subprocess.Popen([sys.executable, "-c", pool, str(tmp_path)], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    worker, started = None, set()
    try:
        deadline = time.time() + 120
        while worker is None:
            assert command.poll() is None and time.time() < deadline, "the worker never started its task"
            pids = [int(p.name) for p in tmp_path.iterdir() if p.name.isdigit()]
            worker = pids[0] if pids else None
            time.sleep(0.1)
        started = _descendants(command.pid)  # the worker, the forkserver (solve), the resource tracker
        command.send_signal(signal.SIGKILL)
        try:  # the end of the pipe: every process holding the command's stderr has ended (or closed it)
            _, err = command.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            pytest.fail("a process of the command killed with SIGKILL still holds its stderr after 60 s")
        assert not pid_alive(worker), "the worker outlived the command killed with SIGKILL"
        deadline = time.time() + 10  # a process that closed its files may still be ending (state R, no memory)
        while [pid for pid in started if pid_alive(pid)] and time.time() < deadline:
            time.sleep(0.05)
        assert not [pid for pid in started if pid_alive(pid)], "a process of the killed command outlived it"
        assert "Traceback" not in err, err  # the worker's SIGTERM handler ended it cleanly
        assert not (tmp_path / ".claim-held").exists()  # released by its SIGTERM handler, not left stale
    finally:
        command.kill()
        command.wait()
        if worker is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(worker, signal.SIGKILL)
        command.stderr.close()  # what its processes still write goes nowhere, not into pytest's output


def _descendants(pid: int) -> set[int]:
    """The ids of the processes that ``pid`` started, and theirs (Linux: the parents in /proc/PID/stat)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        with contextlib.suppress(OSError, ValueError):  # a process gone meanwhile; /proc's other entries
            stat = (entry / "stat").read_text(encoding="utf-8")
            parents[int(entry.name)] = int(stat[stat.rfind(")") + 2 :].split()[1])  # the name may hold spaces
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def test_a_ctrl_c_while_the_solver_pools_forkserver_imports_is_no_traceback(tmp_path):
    """The forkserver of `nlips solve DATASET --workers N` is in the command's process group and ignored Ctrl-C only
    once its preload was imported (~1 s): a Ctrl-C then printed a KeyboardInterrupt traceback of its imports among
    the command's "interrupted" line, and the forkserver died. Now it starts with Ctrl-C ignored: a SIGINT that
    reaches it while it imports (here sent by a preloaded module to its own process) does nothing."""
    script = (
        "from nlipscalib.pipeline import workers\n"
        "workers.FORKSERVER_PRELOAD = (*workers.FORKSERVER_PRELOAD, 'tests.sigint_on_import')\n"
        "ctx = workers.pool_context()\n"
        "p = ctx.Process(target=print, args=('worker ran',))\n"
        "p.start(); p.join(60)\n"
        "print('exit', p.exitcode)\n"
    )
    root = Path(__file__).resolve().parents[1]
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, cwd=root, timeout=120)
    assert "Traceback" not in run.stderr and "KeyboardInterrupt" not in run.stderr, run.stderr
    assert run.returncode == 0 and "worker ran" in run.stdout and "exit 0" in run.stdout, run.stdout + run.stderr
