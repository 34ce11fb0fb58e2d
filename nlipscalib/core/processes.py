"""Worker processes a command starts: Ctrl-C kept from them as they start, and ended at once when the command stops.

Why: a terminal sends Ctrl-C to every process of the command. A worker that died of it printed a traceback of its
own, and one whose render it interrupted waited at its exit for the render, abandoned on a thread of its own
(``sim.render.interruptible``), to end: tens of seconds. The command alone handles Ctrl-C; it ends its workers with
SIGTERM, whose handler in each worker releases the worker's claims and removes its half-written temporaries before
the worker exits (:func:`worker_signals`, set by ``sim.dataset_pool._worker_init`` and
``pipeline.workers._worker_signals``).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
from collections.abc import Iterable, Iterator
from types import FrameType
from typing import Protocol

WORKER_GRACE_S = 5.0
"""Seconds a stopped command gives its worker processes to release their claims and exit before killing them.

Why this much: a worker's SIGTERM handler runs within ~0.1 s (its render on a thread of its own) unless its main
thread is inside a long native call of its own (importing Mitsuba, ~1 s on a loaded machine); one still alive after
that is killed, and what it leaves (a dead process's claim and temporary) the next run takes over and removes."""


LOCAL_WORKER_GRACE_S = 1.0
"""Seconds a stopped command gives a Dask local cluster's worker processes, sent SIGTERM, to run their handler and
exit before it kills them (``experiments.runner._end_local_workers``).

Why this short: the handler runs within ~0.2 s, its main thread being the worker's event loop (the task's render on
another thread). Under load a worker was seen not to run it for seconds (its claim left, the run ending only when
its nanny killed it ~4.2 s after Ctrl-C); what a killed worker leaves the command removes on its way out."""


PARENT_POLL_S = 1.0
"""Seconds between a worker's checks that the command that started it still runs (:func:`end_with_parent`).

Why this often: a worker left behind keeps its memory (the solver, Mitsuba) until it notices; a check is one
``kill(pid, 0)`` and a read of ``/proc/PID/stat``, nothing beside a second of a solve or a render."""


class Worker(Protocol):
    """What :func:`end_processes` needs of a process: :class:`multiprocessing.Process` has it."""

    def terminate(self) -> None: ...

    def kill(self) -> None: ...

    def join(self, timeout: float | None = None) -> None: ...

    def is_alive(self) -> bool: ...


def end_processes(workers: Iterable[Worker], grace_s: float = WORKER_GRACE_S) -> None:
    """End ``workers`` now: SIGTERM to each, then SIGKILL to those still alive ``grace_s`` seconds later.

    They are signalled all at once and waited for together, so the whole takes about the slowest one's handler,
    not their sum. Errors (a process already reaped) are ignored: this runs on the way out.
    """
    workers = list(workers)
    for worker in workers:
        with contextlib.suppress(Exception):
            worker.terminate()
    deadline = time.monotonic() + grace_s
    for worker in workers:
        with contextlib.suppress(Exception):
            worker.join(max(0.0, deadline - time.monotonic()))
    for worker in workers:
        with contextlib.suppress(Exception):
            if worker.is_alive():
                worker.kill()
                worker.join(1.0)


def kill_unless_ended(pids: Iterable[int], grace_s: float) -> None:
    """SIGKILL each process of ``pids`` (already sent SIGTERM) still alive ``grace_s`` seconds from now.

    For processes this one did not start itself (no :class:`Worker` handle: a Dask nanny's); a zombie counts as
    ended. Errors (a process gone meanwhile) are ignored: this runs on the way out.
    """
    from .claims import pid_alive

    pids = list(pids)
    deadline = time.monotonic() + grace_s
    while any(pid_alive(pid) for pid in pids) and time.monotonic() < deadline:
        time.sleep(0.02)
    # Windows has no SIGKILL; its os.kill ends the process outright (TerminateProcess) for SIGTERM as well
    kill = getattr(signal, "SIGKILL", signal.SIGTERM)
    for pid in pids:
        if pid_alive(pid):
            with contextlib.suppress(OSError):
                os.kill(pid, kill)


def worker_signals() -> None:
    """In a worker process: Ctrl-C ignored (the command answers it by ending the worker), and SIGTERM releasing the
    worker's claims and removing its half-written temporaries before it exits (:func:`_worker_terminated`).
    Windows' Ctrl-Break, which reaches every process of the console as Ctrl-C does, is ignored as Ctrl-C is (the
    command takes it for Ctrl-C: ``cli._note_interrupts``)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "SIGBREAK"):
        signal.signal(signal.SIGBREAK, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_terminated)


def _worker_terminated(signum: int, frame: FrameType | None) -> None:
    """SIGTERM in a worker: ended with ``os._exit``, as an exception raised in a handler could land inside a
    library's native call."""
    from . import atomic, claims

    claims.release_all()
    atomic.remove_in_progress()
    os._exit(128 + signum)


@contextlib.contextmanager
def sigint_held() -> Iterator[None]:
    """Ctrl-C held back (blocked, not lost) in this thread while worker processes start.

    The threads and processes started meanwhile inherit the block (processes through exec too), so Ctrl-C never
    reaches a worker, which died of it with a traceback of its own, before it has set its own handling (ignored:
    the command stops it); one pressed meanwhile reaches the command when the block ends. Outside the main thread,
    or without ``pthread_sigmask``, nothing is changed.
    """
    if threading.current_thread() is not threading.main_thread() or not hasattr(signal, "pthread_sigmask"):
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def end_with_parent(poll_s: float = PARENT_POLL_S) -> None:
    """In a worker process of a pool: SIGTERM this process once the command that started it is gone.

    Why: a command killed with SIGKILL (the out-of-memory killer, ``kill -9 PID``) cannot end its workers. A pool's
    worker waits for its next task on a queue whose write end it holds itself, so it waited forever, its memory
    kept (and a forkserver, held by the workers, with it); one in the middle of a press published it for nobody.
    On SIGTERM the worker's own handler (``pipeline.workers._worker_signals``, ``sim.dataset_pool._worker_init``,
    set before this call) releases its claims and removes its temporaries, then exits: what it
    was doing is left for the next run, as when the whole process group is killed. The command is
    :func:`multiprocessing.parent_process` (the process that made the pool, also under forkserver, whose workers'
    parent is the fork server); its pid is checked every ``poll_s`` seconds by a daemon thread. Outside a
    multiprocessing child nothing is done.
    """
    import multiprocessing  # here: the command's own start (nlips --help) imports this module

    from .claims import pid_alive

    parent = multiprocessing.parent_process()
    if parent is None or parent.pid is None:
        return

    def watch(pid: int) -> None:
        while pid_alive(pid):
            time.sleep(poll_s)
        _terminate_self()

    threading.Thread(target=watch, args=(parent.pid,), name="parent-watch", daemon=True).start()


def _terminate_self() -> None:
    """SIGTERM this process, from any thread: its handler runs (a worker's releases its claims and temporaries).

    Windows: ``os.kill`` of any signal but Ctrl-C/Ctrl-Break is ``TerminateProcess``, which runs no handler, and a
    signal raised in this thread would wait for the main thread, blocked on the pool's queue, so the handler is
    called here (the workers' handlers end with ``os._exit``, fine from any thread)."""
    handler = signal.getsignal(signal.SIGTERM)
    if sys.platform == "win32" and callable(handler):
        handler(signal.SIGTERM, None)
    os.kill(os.getpid(), signal.SIGTERM)
