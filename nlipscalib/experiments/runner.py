"""Running tasks: in this process, in local worker processes, or on a Dask cluster; stage by stage.

Results never travel back through the executor: each task writes its JSON into the shared output
folder, and the runner only learns "done" or "failed" (on Dask, with the log records the task emitted:
:mod:`.task_logs`). That is what makes a sweep resumable and
lets a worker die: Dask re-runs a dead worker's task elsewhere (``allowed-failures``), the local
pool is rebuilt and the unfinished tasks re-submitted.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import signal
import threading
from multiprocessing import get_context
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.cpus import usable_cores
from ..core.errors import ConfigError, MissingDependencyError
from ..core.processes import LOCAL_WORKER_GRACE_S, end_processes, kill_unless_ended, sigint_held
from .task_logs import PACKAGE, LiveLogs, replay, run_logged
from .tasks import (
    NO_SPACE,
    REUSED,
    Task,
    clean_leftovers,
    execute,
    finished_result,
    made_difference,
    result_files_problem,
    stored_result,
)

if TYPE_CHECKING:  # named in hints only: tqdm is imported where a bar is made, dask only with --scheduler
    from multiprocessing.context import SpawnProcess
    from multiprocessing.queues import Queue

    from distributed import Worker
    from distributed.diagnostics.plugin import WorkerPlugin
    from tqdm import tqdm

log = logging.getLogger(__name__)
MAX_ATTEMPTS = 3
"""A task whose worker died this many times is given up (reported as failed)."""
PARENT_POLL_S = 1.0
"""An idle local worker checks this often (seconds) that the command that started it still runs."""


@dataclasses.dataclass
class RunStatus:
    done: list[str] = dataclasses.field(default_factory=list)
    """Tasks run now."""
    skipped: list[str] = dataclasses.field(default_factory=list)
    """Tasks already done on disk, or done by another run sharing the folder meanwhile."""
    failed: dict[str, str] = dataclasses.field(default_factory=dict)
    """Task id -> reason."""
    no_space: bool = False
    """A task failed on a full disk (or quota): no other task is started, running ones finish or fail."""


def run_tasks(
    tasks: list[Task],
    out: Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    keep_presses: bool = False,
    progress: bool = True,
    name: str = "",
) -> RunStatus:
    """Run every task not yet done, stage by stage (references, calibrations, presses).

    Parameters
    ----------
    workers : local worker processes (1 = in this process); ignored with ``scheduler``
    scheduler : None (local), "local:N" (start a Dask LocalCluster of N single-threaded worker
        processes) or the address of a running Dask scheduler ("tcp://host:8786")
    name : the experiment's, on its progress bar ("q2 tasks"; ``nlips experiment all`` draws one bar each)
    """
    out = Path(out)
    (out / "tasks").mkdir(parents=True, exist_ok=True)
    clean_leftovers(out)  # a killed run's claim beside a task it finished: that task is skipped below
    status = RunStatus()
    todo = []
    elsewhere: dict[str, str] = {}  # task id -> what made its finished result otherwise
    for t in tasks:
        result = stored_result(out, t)
        problem = result_files_problem(out, t, result) if result is not None else None
        if result is not None and problem is None:
            status.skipped.append(t.id)
            continue
        if problem is not None:  # said once here: execute() re-checks it quietly (load_result)
            log.warning("%s; running %s again", problem, t.id)
        elif (old := finished_result(out, t)) is not None:
            elsewhere[t.id] = made_difference(t, old)
        todo.append(t)
    if elsewhere:  # one line for the lot, not one per task: an upgrade re-runs them all
        log.warning(
            "%s: %d of %d tasks made by other code or libraries (%s): re-running them (--keep-old keeps them)",
            out,
            len(elsewhere),
            len(tasks),
            "; ".join(sorted(set(elsewhere.values()))),
        )
    bar = _bar(len(tasks), len(status.skipped), progress, f"{name} tasks" if name else "tasks")
    try:
        with _backend(scheduler, workers) as backend:
            for stage in sorted({t.stage for t in todo}):
                if status.no_space:
                    break
                staged = [t for t in todo if t.stage == stage]
                backend(staged, out, keep_presses, status, bar)
                _refuse_other_workers(staged, out, status)  # before the next stage builds on them
    finally:
        # on a failure or Ctrl-C too: a notebook keeps the ended frames, and a bar left open nests the next one
        bar.close()
        if check_scheduler(scheduler) is not None:
            # a LocalCluster closed mid-task (Ctrl-C) kills its busy workers (SIGKILL after Dask's grace): each
            # left its task's claim, which no one else would remove until the next run
            clean_leftovers(out)
    return status


def _refuse_other_workers(tasks: list[Task], out: Path, status: RunStatus) -> None:
    """Count as failed a task "done" whose result a worker of other code or libraries made (a remote Dask worker
    with another installation): its result records that worker's ``made_with``, which this command does not take,
    so its evaluations would be missing from the tables without a word."""
    by_id = {t.id: t for t in tasks}
    for task_id in list(status.done):
        task = by_id.get(task_id)
        result = finished_result(out, task) if task is not None else None
        if result is not None and stored_result(out, task) is None:
            status.done.remove(task_id)
            status.failed[task_id] = (
                f"made by a worker of other code or libraries ({made_difference(task, result)}): install this "
                "nlipscalib and its libraries on the workers"
            )
            log.warning("%s: %s", task_id, status.failed[task_id])


def _bar(total: int, initial: int, progress: bool, desc: str) -> tqdm:
    from ..progress import progress_bar

    return progress_bar(total, enabled=progress, initial=initial, desc=desc, unit="task")


def _record(status: RunStatus, task_id: str, outcome: str, bar: tqdm) -> None:
    if outcome == "done":
        status.done.append(task_id)
    elif outcome == REUSED:  # another run sharing the folder did it while this one waited
        status.skipped.append(task_id)
    elif outcome.startswith(NO_SPACE):
        status.failed[task_id] = outcome.removeprefix(NO_SPACE)
        status.no_space = True
        log.warning("%s: failed: %s", task_id, status.failed[task_id])
    else:
        status.failed[task_id] = outcome.removeprefix("failed: ")
        log.warning("%s: %s", task_id, outcome)
    bar.update(1)


class _backend:
    """Context manager giving ``run(tasks, out, keep, status, bar)`` for the chosen executor."""

    def __init__(self, scheduler: str | None, workers: int):
        self.scheduler, self.workers = scheduler, max(1, int(workers))
        self.client = self.cluster = None
        self.cluster_workers = 0
        """The local cluster's worker processes (``local:N``), or 0 for a remote cluster's."""
        self._levels: dict[str, int] = {}  # dask.distributed's log levels before this run quieted them

    def __enter__(self):
        if self.scheduler is None:
            return self._local
        try:
            from distributed import Client, LocalCluster
        except ModuleNotFoundError:
            raise MissingDependencyError(
                "--scheduler needs dask.distributed: pip install 'nlipscalib[cluster]'"
            ) from None
        self._levels = _quiet_distributed()  # imported above: its import set its own level, INFO
        try:
            self._connect(Client, LocalCluster)
        except BaseException as exc:  # Ctrl-C as the cluster started included: what was started is closed
            self.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self._dask

    def _connect(self, client: type, local_cluster: type) -> None:
        n = check_scheduler(self.scheduler)
        if n is not None:
            # the scheduler's HTTP pages (no dashboard: dashboard_address None) on a free port of this machine only,
            # not on 8787, which another run or a user's dashboard may hold
            local = {"dashboard_address": LOCAL_HTTP}
            with sigint_held():  # its worker processes never see Ctrl-C; one pressed meanwhile comes after
                self.cluster = local_cluster(
                    n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None, scheduler_kwargs=local
                )
            _LOCAL_CLUSTERS.append(self.cluster)
            self.client = client(self.cluster)
            self.client.register_plugin(_quiet_workers())  # only our own workers: a shared cluster's stay as they are
            self.cluster_workers = n  # each task's share of the cores is set per stage (_await)
        else:
            try:
                self.client = client(self.scheduler, timeout="30s")
            except (OSError, TimeoutError) as exc:
                raise ConfigError(f"--scheduler {self.scheduler}: cannot reach the Dask scheduler ({exc})") from None
            self.cluster_workers = 0  # a remote cluster's: each renders with all of its own cores
        self.client.register_plugin(_main_thread_imports())  # also on workers that join later

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        if exc_type is not None and issubclass(exc_type, KeyboardInterrupt) and self.cluster is not None:
            # Ctrl-C: the workers are ended mid-render; distributed's errors and warnings about that (a worker
            # still alive, killed; a nanny's cancelled close) are of the stop the user asked for
            _quiet_distributed(logging.CRITICAL)
            _end_local_workers(self.cluster)
        try:
            if self.client is not None:
                self.client.close()
            if self.cluster is not None:
                self.cluster.close()
        finally:
            if self.cluster in _LOCAL_CLUSTERS:
                _LOCAL_CLUSTERS.remove(self.cluster)
            _restore_levels(self._levels)

    def _local(self, tasks: list[Task], out: Path, keep: bool, status: RunStatus, bar: tqdm) -> None:
        # the cores shared by the processes this stage runs, not by --workers: a stage of fewer tasks (q1's one
        # reference, then its one calibration) rendered on cores/N threads in this process, the rest idle
        running = min(self.workers, len(tasks))
        threads = max(1, usable_cores() // running)
        if running == 1:
            for t in tasks:
                if status.no_space:
                    return
                _record(status, t.id, execute(t, out, threads, keep), bar)
            return
        _WorkerSlots(running, str(out), threads, keep).run(tasks, status, bar)

    def _dask(self, tasks: list[Task], out: Path, keep: bool, status: RunStatus, bar: tqdm) -> None:
        level = logging.getLogger(PACKAGE).getEffectiveLevel()  # of the records the tasks carry back (task_logs)
        live = LiveLogs(self.client)  # each task's records logged as they come, a killed worker's too
        try:
            self._await(tasks, out, keep, status, bar, level, live)
        finally:
            live.close()

    def _await(
        self, tasks: list[Task], out: Path, keep: bool, status: RunStatus, bar: tqdm, level: int, live: LiveLogs
    ) -> None:
        from distributed import as_completed as dask_completed

        # a local cluster's share of this machine's cores for each of the stage's tasks at a time (as _local);
        # a remote cluster's workers (0) keep all of their own
        local = self.cluster_workers
        threads = max(1, usable_cores() // min(local, len(tasks))) if local > 0 else 0
        futures = {
            self.client.submit(
                _execute_on_dask_worker,
                t,
                str(out),
                threads,
                keep,
                level,
                live.for_task(t.id),
                key=f"{t.id}-{t.hash}",
                pure=False,
            ): t
            for t in tasks
        }
        for fut in dask_completed(futures):
            t = futures[fut]
            if fut.cancelled():
                continue
            try:
                outcome, records = fut.result()
            except Exception as exc:  # KilledWorker after too many deaths, lost scheduler, ...
                outcome = f"failed: {type(exc).__name__}: {exc}"
            else:
                replay(records, t.id, live)  # those not logged live, before the task's outcome line
            was_full = status.no_space
            _record(status, t.id, outcome, bar)
            if status.no_space and not was_full:
                # start no other task; the ones the workers run finish or fail (recorded as they come)
                running = {key for keys in self.client.processing().values() for key in keys}
                self.client.cancel([f for f in futures if not f.done() and f.key not in running])


class _WorkerSlots:
    """N long-lived worker processes, one task each at a time; a worker that dies costs only its task.

    (A ProcessPoolExecutor whose worker dies breaks as a whole and kills the siblings' tasks too.)
    The dead worker is replaced and its task re-run, up to ``MAX_ATTEMPTS`` times.
    """

    def __init__(self, n: int, out: str, threads: int, keep: bool):
        from ..progress import worker_logging

        self.ctx = get_context("spawn")
        self.n, self.args = n, (out, threads, keep, worker_logging())
        self.results = self.ctx.Queue()

    def _start(self, slot: int) -> tuple[SpawnProcess, Queue]:
        inbox = self.ctx.Queue()
        proc = self.ctx.Process(target=_worker_loop, args=(slot, inbox, self.results, *self.args), daemon=True)
        with _sigint_ignored():  # inherited through exec: the worker ignores Ctrl-C from its first instruction
            proc.start()
        return proc, inbox

    def run(self, tasks: list[Task], status: RunStatus, bar: tqdm) -> None:
        queue, attempts = list(tasks), dict.fromkeys((t.id for t in tasks), 0)
        slots = [self._start(i) for i in range(self.n)]
        busy: dict[int, Task] = {}  # slot -> task
        finished = False
        try:
            while queue or busy:
                if status.no_space:  # the tasks under way finish or fail; no other starts
                    queue.clear()
                for i in range(self.n):
                    if i not in busy and queue:
                        busy[i] = queue.pop(0)
                        attempts[busy[i].id] += 1
                        slots[i][1].put(busy[i])
                self._collect(busy, status, bar)
                for i, task in list(busy.items()):
                    if not slots[i][0].is_alive():  # died mid-task: replace it, re-run only its task
                        log.warning("worker running %s died; re-running that task", task.id)
                        del busy[i]
                        slots[i] = self._start(i)
                        if attempts[task.id] < MAX_ATTEMPTS:
                            queue.insert(0, task)
                        else:
                            _record(status, task.id, "failed: its worker process died repeatedly", bar)
            finished = True
        finally:
            self._stop(slots, finished)

    @staticmethod
    def _stop(slots: list[tuple[SpawnProcess, Queue]], finished: bool) -> None:
        """End the workers: idle ones when all is done; on Ctrl-C (or an error here) at once, with SIGTERM, which
        makes a worker release its claim and remove its temporaries first (``pipeline.workers._worker_signals``),
        then SIGKILL for one that has not ended within the grace (:func:`nlipscalib.core.processes.end_processes`;
        its claim is stale at once, being ours)."""
        if not finished:
            end_processes(proc for proc, _ in slots)
            return
        for _, inbox in slots:
            inbox.put(None)
        for proc, _ in slots:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.kill()

    def _collect(self, busy: dict[int, Task], status: RunStatus, bar: tqdm) -> None:
        import queue as queue_mod

        try:
            slot, task_id, outcome = self.results.get(timeout=0.5)
        except queue_mod.Empty:
            return
        if busy.get(slot) is not None and busy[slot].id == task_id:
            del busy[slot]
            _record(status, task_id, outcome, bar)


def _worker_loop(
    slot: int,
    inbox: Queue,
    results: Queue,
    out: str,
    threads: int,
    keep: bool,
    logging_args: tuple[int, str | None] | None = None,
) -> None:
    """Body of a local worker process: run tasks from ``inbox`` until it gets None (logging like the parent,
    to its ``--log-file`` too)."""
    from ..pipeline.workers import _worker_signals

    _worker_signals()  # Ctrl-C is the parent's to handle; SIGTERM releases this worker's claim first
    if logging_args is not None:
        from ..progress import configure_worker

        configure_worker(*logging_args)
    import os
    import queue

    from ..solver import threads as solver_threads

    # the worker's share of the cores for its solves too, as for its renders (each took every usable core: N
    # workers ran N x cores solver threads)
    solver_threads.set_workers(threads)
    parent = os.getppid()
    while True:
        try:
            task = inbox.get(timeout=PARENT_POLL_S)
        except queue.Empty:
            if os.getppid() != parent:  # the command ended without telling us (`kill PID`: it exits at once)
                return
            continue
        if task is None:
            return
        results.put((slot, task.id, execute(task, out, threads, keep)))


def _execute_on_dask_worker(
    task: Task, out: str, threads: int, keep: bool, level: int, live: tuple[str, str, str] | None = None
) -> tuple[str, dict]:
    """:func:`.tasks.execute` on a Dask worker, and the records of ``level`` and above it logged, for
    :func:`.task_logs.replay` in the command (:func:`.task_logs.run_logged`). A local cluster's worker (``threads``
    > 0: its share of this machine's cores) solves on that share, as it renders: its N workers each solved on every
    core (N x cores solver threads), as the local pool's did before :func:`_worker_loop` set its share. A remote
    worker (0) keeps all of its own cores."""
    if threads > 0:
        from ..solver import threads as solver_threads

        solver_threads.set_workers(threads)
    return run_logged(execute, level, task, out, threads, keep, live=live)


def import_native_libraries() -> None:
    """Import the native libraries that must first be loaded in a process's main thread.

    pymeshlab (the indentation's mesh subdivision, ``sim.indent._subdivide``) first imported in another thread
    -- a Dask worker runs every task in one -- corrupts the heap: the process aborts when it exits ("malloc_
    consolidate(): unaligned fastbin chunk detected", the worker "killed by signal 6"). Imported in the main
    thread first, later use from any thread is fine.
    """
    with contextlib.suppress(ImportError):  # without it the twin cannot render presses: nothing to protect
        import pymeshlab  # noqa: F401


LOCAL_HTTP = "127.0.0.1:0"
"""Where a local cluster's scheduler serves its HTTP pages (always started; the dashboard is not): a free port of
the loopback interface."""
DISTRIBUTED_LOGGERS = ("distributed", "distributed.client")
"""Loggers of dask.distributed set to WARNING in this process unless -v: its import sets "distributed" to INFO, so a
local cluster printed ~40 lines of its own start and stop (and its "dashboard at" link)."""


def _quiet_distributed(level: int = logging.WARNING) -> dict[str, int]:
    """Raise dask.distributed's loggers of this process to ``level`` unless -v (this process logs DEBUG); returns
    their levels before, for :func:`_restore_levels`."""
    loggers = {name: logging.getLogger(name) for name in DISTRIBUTED_LOGGERS}
    before = {name: logger.level for name, logger in loggers.items()}
    if not logging.getLogger().isEnabledFor(logging.DEBUG):
        for logger in loggers.values():
            logger.setLevel(max(level, logger.level))
    return before


def _restore_levels(levels: dict[str, int]) -> None:
    for name, level in levels.items():
        logging.getLogger(name).setLevel(level)


SHUTDOWN_RACE = "Scheduler was unaware of this worker"
"""The start of the warning a local cluster's worker logs when its heartbeat reaches the scheduler after the
scheduler let it go: as the cluster closes (Ctrl-C), a race distributed itself calls common, not news."""


def _quiet_workers() -> WorkerPlugin:
    """A Dask worker plugin for a local cluster's workers (run in each worker's main thread): the signals of the
    command's own worker processes (``pipeline.workers._worker_signals``: Ctrl-C left to the command; SIGTERM, which
    the command sends its workers as it is terminated, releases the worker's claims and temporaries first, where
    the worker died at once and left them for the next run), and, unless -v, none of distributed's lines about
    the cluster closing under a task (Ctrl-C): "Async instruction for <Task ...> ended with CancelledError" (its
    worker state machine's only warning, logged only as a worker closes) and :data:`SHUTDOWN_RACE`. Errors still
    show."""
    from distributed.diagnostics.plugin import WorkerPlugin

    verbose = logging.getLogger().isEnabledFor(logging.DEBUG)

    class QuietWorkers(WorkerPlugin):
        name = "nlipscalib-quiet-workers"

        def setup(self, worker: Worker) -> None:
            from ..pipeline.workers import _worker_signals

            _worker_signals()
            if not verbose:
                logging.getLogger("distributed.worker.state_machine").setLevel(logging.ERROR)
                logging.getLogger("distributed.worker").addFilter(
                    lambda record: not record.getMessage().startswith(SHUTDOWN_RACE)
                )

    return QuietWorkers()


_LOCAL_CLUSTERS: list = []
"""The Dask local clusters this process runs now (:class:`_backend`), for :func:`stop_restarting_workers`."""


def stop_restarting_workers() -> None:
    """Keep this process's local clusters from replacing a worker process that ends, for a command about to end
    (``cli._end_at_once``, on SIGTERM) before it terminates its worker processes.

    A local cluster's nanny starts a new worker process when one ends while the cluster runs: terminated with the
    command, each was replaced at once, and the new ones failed to start (a traceback each) once the command had
    gone. Marked closing, as closing the cluster would mark them (which a signal handler cannot wait for), the
    nannies let their workers end. Without a local cluster (``--workers N``, a remote scheduler) nothing is done, nor
    dask.distributed imported: that import, ~0.8 s of the terminated command's end, came before its workers got
    their SIGTERM.
    """
    if not _LOCAL_CLUSTERS:
        return
    from distributed.core import Status

    if not logging.getLogger().isEnabledFor(logging.DEBUG):
        # the nannies' watchers then log the ends of the workers the command terminates ("process N exit status
        # was already read, will report exitcode 255"): news of our own doing, not the user's (-v shows them)
        for name in ("distributed.process", "distributed.nanny"):
            logging.getLogger(name).setLevel(logging.ERROR)
    for cluster in list(_LOCAL_CLUSTERS):
        for nanny in list(getattr(cluster, "workers", {}).values()):
            with contextlib.suppress(Exception):  # on the way out: best effort
                nanny.status = Status.closing


def _end_local_workers(cluster: object) -> None:
    """Ctrl-C: end each worker process of a local cluster now, with SIGTERM (its handler, run at once in its main
    thread, releases its claims and temporaries and exits: ``pipeline.workers._worker_signals``), its nanny first
    told to start no other; closing the cluster then finds them ended.

    Why: closing the cluster asked each worker to close, which waited for the task it ran (a render, on a thread
    that cannot be stopped) until its nanny's grace ran out and it killed the worker: ~4 s after Ctrl-C at 320x240.
    A worker that has not ended :data:`LOCAL_WORKER_GRACE_S` after its SIGTERM is killed (under load one was seen not
    to run its handler for seconds): its claim, left, the command removes on its way out.
    """
    import os

    signalled = []
    for nanny in list(getattr(cluster, "workers", {}).values()):
        with contextlib.suppress(Exception):  # on the way out: best effort (a worker that already ended)
            nanny.close_gracefully(reason="nlips-interrupted")  # its status only: no replacement for the worker
            pid = nanny.process.pid if nanny.process is not None else None
            if pid is not None:
                os.kill(pid, signal.SIGTERM)
                signalled.append(pid)
    kill_unless_ended(signalled, LOCAL_WORKER_GRACE_S)


def _main_thread_imports() -> WorkerPlugin:
    """A Dask worker plugin running :func:`import_native_libraries` in each worker's main (event loop) thread."""
    from distributed.diagnostics.plugin import WorkerPlugin

    class MainThreadImports(WorkerPlugin):
        name = "nlipscalib-main-thread-imports"

        def setup(self, worker: Worker) -> None:
            import_native_libraries()

    return MainThreadImports()


@contextlib.contextmanager
def _sigint_ignored():
    """Ctrl-C ignored while a worker process starts: it inherits that and never dies of it with a traceback
    of its own (a terminal sends Ctrl-C to every process of the command; the parent alone stops the run)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def check_scheduler(scheduler: str | None) -> int | None:
    """The form of ``--scheduler``, checked before any work (``--plan`` included; nothing is contacted).

    Returns
    -------
    N of "local:N"; None for no scheduler or a scheduler's address ("tcp://host:8786")
    """
    if scheduler is None:
        return None
    if scheduler.startswith("local:"):
        return _count(scheduler.removeprefix("local:"))
    if "://" not in scheduler:
        raise ConfigError(f"--scheduler {scheduler!r}: give tcp://HOST:PORT or local:N")
    return None


def _count(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"--scheduler local:N needs a worker count N >= 1, got {text!r}")
    return n
