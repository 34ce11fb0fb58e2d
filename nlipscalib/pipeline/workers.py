"""Solver processes: a pool solving presses in parallel, and the signal handling of its workers (Ctrl-C left to
the parent; on SIGTERM a worker releases its claims and temporaries first)."""

from __future__ import annotations

import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import said_once
from ..core.cpus import threads_per_worker
from ..core.processes import end_with_parent
from .status import BROKEN

if TYPE_CHECKING:  # the flag's type in hints only: made by the pool's multiprocessing context
    import multiprocessing.context
    from ctypes import c_byte

log = logging.getLogger(__package__)  # the package's one logger: log files keep naming "nlipscalib.pipeline"


def _solve_in_processes(
    status_of: Callable[..., str],
    folders: Sequence[Path],
    names: dict[Path, str],
    workers: int,
    progress: bool,
    args: tuple,
) -> dict[Path, str]:
    """``status_of(folder, *args)`` of each of ``folders`` (a press's status), in up to ``workers`` processes.

    ``status_of`` is passed in, not imported, so this module does not depend on the solving one that calls it; it
    must be a module-level function (it is pickled by name). A bar counts the presses when ``progress``.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from ..core.main_guard import check_main_guarded
    from ..progress import progress_bar, worker_logging

    check_main_guarded(f"solving presses in {workers} processes (workers={workers})")

    # forkserver: workers start from a clean process with the solver imported once, not from a fork of
    # a caller that may hold threads (claims' heartbeats, progress monitors) or a multi-threaded BLAS; SciPy's
    # sparse modules with it, which the solver's modules import only where they use them (as the solver's import
    # did before: pyamg preloaded too measured no faster, 4 presses on 2 workers, benchmarks/RESULTS.md s21-imp)
    ctx = pool_context()
    statuses = {}
    # set on Ctrl-C: the presses the pool has already moved into its call queue (workers + 1 of them), which no
    # cancel reaches, return NOT_STARTED instead of being solved (a 6-press set on 2 workers solved all 4 it had
    # not finished after "the others are not started"); handing out one press at a time instead measured 6 % more
    # wall (4.49 against 4.23 s, 6 presses of 160x120 on 2 workers, one A/B at load 3.7).
    # A byte in shared memory, no lock (one writer): no named semaphores for the exit to free, as an Event has
    stop = ctx.RawValue("b", 0)
    count = min(workers, len(folders))
    # a session's fault (swapped LED images, aged LEDs) is warned of once per command, not once per worker
    with (
        said_once.shared_between_processes() as said,
        ProcessPoolExecutor(
            max_workers=count,
            mp_context=ctx,
            initializer=_worker_init,
            initargs=(*worker_logging(), stop, threads_per_worker(count), said),
        ) as pool,
    ):
        futures = {pool.submit(_unless_stopped, status_of, f, *args): f for f in folders}
        bar = progress_bar(len(futures), enabled=progress, desc="presses", unit="press")
        try:
            for done in as_completed(futures):
                folder = futures[done]
                try:
                    statuses[folder] = done.result()
                except BrokenProcessPool:
                    # a worker was killed (SIGKILL, the out-of-memory killer): the pool ends every other
                    # worker (they release their claims, _worker_signals) and fails every press not done
                    if not any(s == BROKEN for s in statuses.values()):
                        log.error("a solver process was killed; the presses not finished are left for the next run")
                    statuses[folder] = BROKEN
                bar.set_postfix_str(names[folder], refresh=False)
                bar.update()
        except BaseException as exc:  # Ctrl-C, a bug: queued presses never start, running ones finish
            if isinstance(exc, KeyboardInterrupt):  # the workers ignore Ctrl-C (_worker_signals)
                log.warning("interrupted: the presses being solved are finished, the others are not started")
            stop.value = 1
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        finally:
            bar.close()
    return statuses


FORKSERVER_PRELOAD = ("nlipscalib.pipeline", "nlipscalib.solver", "scipy.sparse.linalg")
"""Modules the forkserver imports once for every solver process it starts (:func:`pool_context`)."""


def pool_context() -> multiprocessing.context.BaseContext:
    """The multiprocessing context of a solver pool: forkserver (preloading :data:`FORKSERVER_PRELOAD`) where there
    is one, else spawn; the forkserver is started here, with Ctrl-C ignored.

    Why ignored: the forkserver is a process of the command's group, so a Ctrl-C reaches it too; it ignores Ctrl-C
    only once its preload is imported (~1 s, more under load), and a Ctrl-C before that printed a KeyboardInterrupt
    traceback of its imports among the command's one "interrupted" line (`nlips solve DATASET --workers 2`,
    Ctrl-C 2 s after the start). Started with SIGINT ignored, it inherits the disposition through its exec, and so
    do the workers it forks (which leave Ctrl-C to the command anyway, :func:`_worker_init`). The command's own
    handler is put back at once: the start is a fork and exec, milliseconds in which a Ctrl-C is dropped."""
    import multiprocessing
    import signal
    import threading

    methods = multiprocessing.get_all_start_methods()
    if "forkserver" not in methods:
        return multiprocessing.get_context("spawn")
    from multiprocessing import forkserver

    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    if threading.current_thread() is not threading.main_thread():  # only the main thread may set a handler
        return ctx
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        forkserver.ensure_running()
    finally:
        signal.signal(signal.SIGINT, previous)
    return ctx


NOT_STARTED = "not started: the batch was interrupted"
"""What a press handed to a worker returns when the batch was stopped (Ctrl-C) before the worker began it."""
_STOP: c_byte | None = None
"""This worker's batch's stop flag (a shared byte the parent sets to 1 on Ctrl-C; :func:`_worker_init`)."""


def _unless_stopped(status_of: Callable[..., str], folder: Path, *args: object) -> str:
    """``status_of(folder, *args)``, or :data:`NOT_STARTED` once the parent has set the batch's stop flag."""
    if _STOP is not None and _STOP.value:
        return NOT_STARTED
    return status_of(folder, *args)


def _worker_init(
    log_level: int,
    log_file: str | None,
    press_lines: int,
    quiet: bool,
    stop: c_byte | None,
    thread_count: int = 1,
    said: str | None = None,
) -> None:
    """Log like the parent (stderr and its ``--log-file``); ``thread_count`` threads for the solver's pool and
    OpenCV's (the cores shared out among the workers, :func:`~nlipscalib.core.cpus.threads_per_worker`: one a worker
    where there are as many workers as cores, so cores are not oversubscribed); the solver limits BLAS itself;
    ``press_lines``, ``quiet``: the parent's (progress.press_lines, ``--quiet``); ``stop``: the batch's stop flag
    (:func:`_unless_stopped`); ``said``: the folder in which the batch's processes say a session's warning once
    (:func:`~nlipscalib.core.said_once.share`)."""
    from ..progress import configure_worker

    said_once.share(said)

    global _STOP
    _STOP = stop
    configure_worker(log_level, log_file, press_lines, quiet)
    _worker_signals()
    end_with_parent()  # a command killed with SIGKILL cannot end this worker: it ends itself
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    thread_count = max(1, int(thread_count))
    from ..solver import threads

    threads.set_workers(thread_count)
    try:
        import cv2

        cv2.setNumThreads(thread_count)
    except ImportError:  # pragma: no cover - OpenCV is a core dependency
        pass


def _worker_signals() -> None:
    """Leave Ctrl-C to the parent; on SIGTERM release this worker's claims and temporaries, then exit.

    Ctrl-C in a terminal reaches every process of the command. A worker waiting for its next press
    dies of it with a traceback (concurrent.futures catches it only around a press), the pool counts
    as broken and kills the other workers in the middle of their presses, leaving their claims
    behind. Ignored here, the parent alone stops the batch: queued presses are cancelled, running
    ones finish and release their claims (:func:`_solve_in_processes`).

    SIGTERM (a scheduler's time limit, ``kill`` of the process group) would end a worker at once,
    leaving its claim and its half-written ``.tmp-nlips~...`` folder for the next run to clean; the
    handler removes both first, as ``nlips`` itself does (cli._terminate_cleanly). It runs when the
    current native call (a sparse solve) returns, and ends the process with ``os._exit``: an
    exception raised there could land inside a library.
    """
    from ..core.processes import worker_signals

    worker_signals()
