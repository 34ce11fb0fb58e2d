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
    """They waited forever for their next task (a queue whose write end they hold themselves), their memory kept."""
    command = subprocess.Popen([sys.executable, "-c", pool, str(tmp_path)], cwd=ROOT)
    worker = None
    try:
        deadline = time.time() + 120
        while worker is None:
            assert command.poll() is None and time.time() < deadline, "the worker never started its task"
            pids = [int(p.name) for p in tmp_path.iterdir() if p.name.isdigit()]
            worker = pids[0] if pids else None
            time.sleep(0.1)
        command.send_signal(signal.SIGKILL)
        command.wait(timeout=10)
        deadline = time.time() + 30
        while pid_alive(worker) and time.time() < deadline:
            time.sleep(0.1)
        assert not pid_alive(worker), "the worker outlived the command killed with SIGKILL"
        assert not (tmp_path / ".claim-held").exists()  # released by its SIGTERM handler, not left stale
    finally:
        command.kill()
        command.wait()
        if worker is not None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(worker, signal.SIGKILL)
