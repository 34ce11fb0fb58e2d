"""Running tasks: in this process, in local worker processes, or on a Dask cluster; stage by stage.

Results never travel back through the executor: each task writes its JSON into the shared output
folder, and the runner only learns "done" or "failed". That is what makes a sweep resumable and
lets a worker die: Dask re-runs a dead worker's task elsewhere (``allowed-failures``), the local
pool is rebuilt and the unfinished tasks re-submitted.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from pathlib import Path

from ..errors import ConfigError, MissingDependencyError
from .tasks import Task, execute, load_result

log = logging.getLogger(__name__)
MAX_ATTEMPTS = 3
"""A task whose worker died this many times is given up (reported as failed)."""


@dataclasses.dataclass
class RunStatus:
    done: list[str] = dataclasses.field(default_factory=list)
    """Tasks run now."""
    skipped: list[str] = dataclasses.field(default_factory=list)
    """Tasks already done on disk."""
    failed: dict[str, str] = dataclasses.field(default_factory=dict)
    """Task id -> reason."""


def run_tasks(
    tasks: list[Task],
    out: Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    keep_presses: bool = False,
    progress: bool = True,
) -> RunStatus:
    """Run every task not yet done, stage by stage (references, calibrations, presses).

    Parameters
    ----------
    workers : local worker processes (1 = in this process); ignored with ``scheduler``
    scheduler : None (local), "local:N" (start a Dask LocalCluster of N single-threaded worker
        processes) or the address of a running Dask scheduler ("tcp://host:8786")
    """
    out = Path(out)
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    status = RunStatus()
    todo = []
    for t in tasks:
        if load_result(out, t) is not None:
            status.skipped.append(t.id)
        else:
            todo.append(t)
    bar = _bar(len(tasks), len(status.skipped), progress)
    with _backend(scheduler, workers) as backend:
        for stage in sorted({t.stage for t in todo}):
            backend([t for t in todo if t.stage == stage], out, keep_presses, status, bar)
    bar.close()
    return status


def _bar(total: int, initial: int, progress: bool):
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, unit="task", disable=not (progress and sys.stderr.isatty()))


def _record(status: RunStatus, task_id: str, outcome: str, bar) -> None:
    if outcome == "done":
        status.done.append(task_id)
    else:
        status.failed[task_id] = outcome.removeprefix("failed: ")
        log.warning("%s: %s", task_id, outcome)
    bar.update(1)


class _backend:
    """Context manager giving ``run(tasks, out, keep, status, bar)`` for the chosen executor."""

    def __init__(self, scheduler: str | None, workers: int):
        self.scheduler, self.workers = scheduler, max(1, int(workers))
        self.client = self.cluster = None

    def __enter__(self):
        if self.scheduler is None:
            return self._local
        try:
            from distributed import Client, LocalCluster
        except ModuleNotFoundError:
            raise MissingDependencyError(
                "--scheduler needs dask.distributed: pip install 'nlipscalib[cluster]'"
            ) from None
        if self.scheduler.startswith("local:"):
            n = _count(self.scheduler.removeprefix("local:"))
            self.cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            self.client = Client(self.cluster)
            self.threads = max(1, (os.cpu_count() or 1) // n)
        else:
            self.client = Client(self.scheduler, timeout="30s")
            self.threads = 0  # a remote worker renders with all its cores
        return self._dask

    def __exit__(self, *exc):
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    def _local(self, tasks, out, keep, status, bar):
        threads = max(1, (os.cpu_count() or 1) // self.workers)
        if self.workers == 1 or len(tasks) == 1:
            for t in tasks:
                _record(status, t.id, execute(t, out, threads, keep), bar)
            return
        attempts = dict.fromkeys((t.id for t in tasks), 0)
        pending = list(tasks)
        while pending:
            for t in pending:
                attempts[t.id] += 1
            pending = self._local_pool(pending, out, keep, threads, status, bar)
            for t in [t for t in pending if attempts[t.id] >= MAX_ATTEMPTS]:
                _record(status, t.id, "failed: its worker process died repeatedly", bar)
                pending.remove(t)

    def _local_pool(self, tasks, out, keep, threads, status, bar) -> list[Task]:
        """Run tasks in a fresh pool; returns those whose worker died (a broken pool) to run again."""
        unfinished = {t.id: t for t in tasks}
        with ProcessPoolExecutor(min(self.workers, len(tasks)), mp_context=get_context("spawn")) as pool:
            futures = {pool.submit(execute, t, str(out), threads, keep): t for t in tasks}
            try:
                for fut in as_completed(futures):
                    t = futures[fut]
                    _record(status, t.id, fut.result(), bar)
                    del unfinished[t.id]
            except BrokenProcessPool:
                log.warning("a worker process died; re-running its unfinished tasks in a new pool")
        again = []
        for t in unfinished.values():  # finished before the pool broke, or lost with it
            if load_result(out, t) is not None:
                _record(status, t.id, "done", bar)
            else:
                again.append(t)
        return again

    def _dask(self, tasks, out, keep, status, bar):
        from distributed import as_completed as dask_completed

        futures = {
            self.client.submit(execute, t, str(out), self.threads, keep, key=f"{t.id}-{t.hash}", pure=False): t
            for t in tasks
        }
        for fut in dask_completed(futures):
            t = futures[fut]
            try:
                outcome = fut.result()
            except Exception as exc:  # KilledWorker after too many deaths, lost scheduler, ...
                outcome = f"failed: {type(exc).__name__}: {exc}"
            _record(status, t.id, outcome, bar)


def _count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"--scheduler local:N needs a worker count N >= 1, got {text!r}")
    return n
