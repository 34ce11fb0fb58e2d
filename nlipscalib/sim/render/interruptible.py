"""Long native calls (a Mitsuba render, its ground-truth trace) on a thread of their own, so that Ctrl-C and SIGTERM
are answered at once.

Why: Python runs a signal handler in the main thread alone, and only when that thread is back in the interpreter.
One Mitsuba render in drjit's LLVM backend (tracing, compiling and running its kernel) held it for tens of seconds:
``nlips render`` at 640x480, 16 spp, one bounce ended 30-40 s after Ctrl-C or SIGTERM, ``nlips experiment`` ~100 s.
Neither library stops a kernel that runs (Mitsuba's Ctrl-C handler cancels its scalar render loop, not a drjit
kernel). With the work on another thread the main thread only waits, and wakes often enough to run the handlers: the
command's SIGTERM handler ends the process at once (``os._exit``), and Ctrl-C's KeyboardInterrupt unwinds the caller
(its temporaries removed and claims released as usual) while the abandoned work goes on; ``nlips`` then ends its
process without waiting for it (:func:`abandoned_work_running`).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TypeVar

T = TypeVar("T")

POLL_S = 0.1
"""Seconds between two looks of the waiting main thread at the signals that came in.

Why a poll and not one blocking wait: the kernel may deliver a signal to any thread of the process (one of drjit's
workers), and then the main thread's wait is not interrupted; Python only notes the signal, and its handler runs
when the main thread next runs bytecode. A look costs microseconds; 0.1 s is well within the ~1 s a user waits.
"""


_ABANDONED: list[threading.Event] = []
"""The end (set when it ends) of each work that :func:`call_interruptibly` stopped waiting for
(see :func:`abandoned_work_running`)."""


def abandoned_work_running() -> bool:
    """Whether work that :func:`call_interruptibly` stopped waiting for (Ctrl-C) still runs.

    Why it matters: drjit's exit function (``atexit``) waits for the kernels that run, helping to run them, so a
    process that ends as the interpreter does (``nlips``'s ``cli._exit`` too) would wait for the abandoned render
    after all; it must end without its exit functions instead.
    """
    return not all(done.is_set() for done in _ABANDONED)


def call_interruptibly(work: Callable[[], T]) -> T:
    """``work()``, run on a thread of its own while the main thread waits, handling signals every :data:`POLL_S`.

    Its result is returned and its exception raised here, as if it had run here. Called from another thread than
    the main one (a Dask worker's, a pool's) it simply runs here: signals are not handled there anyway.

    When a signal handler raises in the main thread (Ctrl-C: KeyboardInterrupt) that exception leaves this call at
    once and ``work`` goes on alone, its result dropped. ``nlips`` then ends its process without waiting for it
    (:func:`abandoned_work_running`); a Python program goes on, and its exit waits for the work to end (the thread
    is not a daemon: drjit's teardown under a render that still ran aborted the interpreter). ``work`` must
    therefore write no file of its own: results are written by the caller, after this returns.

    Parameters
    ----------
    work : callable of no arguments

    Returns
    -------
    What ``work`` returned.
    """
    if threading.current_thread() is not threading.main_thread():
        return work()
    outcome: list[tuple[bool, object]] = []
    done = threading.Event()

    def run() -> None:
        try:
            outcome.append((True, work()))
        except BaseException as exc:  # handed to the waiting thread, which raises it
            outcome.append((False, exc))
        finally:
            done.set()

    # waited for by an Event, not Thread.join: a KeyboardInterrupt inside join (Python 3.11) marks the thread as
    # ended while it runs (the bpo-45274 fix releases the running thread's lock), and it would seem to have ended
    threading.Thread(target=run, name="nlips-render").start()
    try:
        while not done.wait(POLL_S):
            pass
    except BaseException:  # a signal handler's exception (Ctrl-C): the work is left running
        _ABANDONED.append(done)
        raise
    finished, value = outcome.pop()
    if not finished:
        raise value
    return value
