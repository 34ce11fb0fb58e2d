# PYTHON_ARGCOMPLETE_OK (argcomplete's global completion looks for this line: nlipscalib.cli.help.complete_if_asked)
"""The ``nlips`` command: the only place where sim/, device/, solver/ and learn/ are wired together.

Each subcommand lives in its own module here exposing ``register(subparsers)``; that function adds
its parser and sets ``func`` to a callable taking the parsed ``args`` and returning an exit code.
Heavy imports happen inside those callables, so ``nlips --help`` is instant.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import gc
import importlib
import logging
import os
import re
import sys
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import FrameType
from typing import NoReturn

from .. import __version__, progress
from ..core import said_once
from ..core.errors import MissingDependencyError, NlipsError
from ..core.processes import end_processes  # here, not in the signal handler that uses it
from ..progress import one_line
from .help import (
    EXIT_STATUS,
    HelpFormatter,
    Parser,
    VersionAction,
    add_options_of_every_command,
    complete_if_asked,
    examples_text,
    print_help_for_no_command,
)

SUBCOMMAND_MODULES = (
    "render",
    "dataset",
    "demo",
    "solve",
    "calibrate",
    "evaluate",
    "experiment",
    "leds",
    "capture",
    "calibrate_camera",
    "camera_response",
    "live",
    "calibration",
    "train",
    "lut",
    "export",
    "infer",
    "verify",
    "cache",
)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="nlips",
        description="NLiPsCalib: digital twin, NLiPs solver and NLiPsNet for curved tactile sensors.",
        epilog=f"{EXIT_STATUS}\n\nRun `nlips COMMAND --help` for a command's options and examples.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument(
        "--version",
        action=VersionAction,
        version=__version__,
        help="show the version of nlipscalib, Python and the key libraries (for a bug report) and exit",
    )
    loudness = parser.add_mutually_exclusive_group()
    loudness.add_argument(
        "-v",
        "--verbose",
        action="store_true",
        help="show debug logging, and in batches of presses (a folder, `nlips calibrate`, demo, experiments) how each "
        "press was solved (interreflection term, anchoring), which they otherwise leave to --log-file",
    )
    loudness.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="only warnings and errors on stderr: no INFO lines, no progress bars (results still go to stdout, and "
        "--log-file still gets every line)",
    )
    parser.add_argument(
        "--no-progress",
        dest="global_no_progress",
        action="store_true",
        help="no progress bars (they are also off when stderr is not a terminal)",
    )
    parser.add_argument(
        "--log-file", default=None, help="also write every log line and every result line to this file (appended)"
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in SUBCOMMAND_MODULES:
        try:
            module = importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue  # subcommand not built yet
            raise
        module.register(sub)
    for name, command in sub.choices.items():
        add_options_of_every_command(command)
        command.description, command.epilog = plain_text(command.description), plain_text(command.epilog)
        if command.formatter_class is argparse.HelpFormatter:
            command.formatter_class = HelpFormatter  # keeps the examples' lines as typed
        if (examples := examples_text(name)) is not None:
            command.epilog = f"{command.epilog}\n\n{examples}" if command.epilog else examples
        if _names_source_files(command):
            command.epilog = f"{command.epilog}\n\n{SOURCE_NOTE}" if command.epilog else SOURCE_NOTE
    return parser


SOURCE_FILES = re.compile(r"\b(docs|firmware)/")
"""Paths of the checkout a help text may name (docs/formats.md, firmware/README.md)."""
SOURCE_NOTE = (
    "Files under docs/ or firmware/ named here are in the nlipscalib source distribution or repository, not in an "
    "installed wheel."
)
"""Said under a command's help that names such a path: a wheel's user looked for it in vain."""


def _names_source_files(command: argparse.ArgumentParser) -> bool:
    """Whether the command's description, epilog or an option's help names a path of the checkout."""
    texts = [command.description, command.epilog, *(a.help for a in command._actions)]
    return any(SOURCE_FILES.search(t) for t in texts if isinstance(t, str))


_MARKUP = re.compile(r":\w+:`([^`]+)`|``([^`]+)``")
"""reStructuredText inline markup in a module docstring: a role (:func:`name`) or a literal (double backticks)."""


def plain_text(text: str | None) -> str | None:
    """``text`` without reStructuredText inline markup, for ``--help``.

    Why: several commands take their description from their module's docstring, written for the API docs;
    ``--help`` showed its double backticks verbatim. Single backticks (a command to type) are kept.

    Parameters
    ----------
    text : str or None
        A description or epilog.

    Returns
    -------
    str or None
    """
    if text is None:
        return None
    return _MARKUP.sub(lambda m: m.group(1) or m.group(2), text)


def command() -> NoReturn:
    """The ``nlips`` command (console script, ``python -m nlipscalib``): :func:`main` in a process of its own,
    which it ends (:func:`_exit`).

    Only here, not in :func:`main` (which tests and Python programs call in their own process): settings that
    hold for the rest of the process and the processes it starts -- NumPy's arrays on ordinary pages
    (:func:`nlipscalib.core.pages.ordinary_pages_for_command`) --, the imported modules left out of the garbage
    collector's walks (:func:`imports_frozen`) and Ctrl-C or SIGTERM after the work ended (:func:`_after_the_work`)."""
    global _own_process
    from ..__main__ import INTERRUPTED_EARLY
    from ..core.pages import ordinary_pages_for_command

    _own_process = True
    try:
        ordinary_pages_for_command()
        code = _main(None, own_process=True)
    except KeyboardInterrupt:  # before the command set its handlers (arguments read, help modules loaded)
        print(INTERRUPTED_EARLY, file=sys.stderr)
        code = 130
    _exit(code)


def main(argv: Sequence[str] | None = None) -> int:
    return _main(argv, own_process=False)


_own_process = False
"""Whether this process is the ``nlips`` command's own (:func:`command`), not a Python program's that calls
:func:`main`."""


@contextlib.contextmanager
def imports_frozen() -> Iterator[None]:
    """In the command's own process, no garbage collection while the block imports modules, and every object the
    collector tracks at its end -- the modules imported so far, which live as long as the process -- moved out of
    its later walks (:func:`gc.freeze`); in a caller's process (:func:`main`: a test session, a notebook) nothing:
    its objects frozen would never be collected.

    Why: the imports make some 10^5 objects that live as long as the process, and the collector walked them again
    and again, holding the GIL: the collector took 35-40 ms of CPU in ``nlips solve PRESS --roi auto`` on cube1, 9-11
    ms with this (2-core VM, benchmarks/RESULTS.md, s31-cube). Garbage made after the block is collected as before."""
    if not _own_process:
        yield
        return
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        gc.enable()


def _main(argv: Sequence[str] | None, own_process: bool) -> int:
    """Run the command of ``argv``; ``own_process``: the process ends after it (:func:`command`), so its signal
    handlers are not put back but replaced by :func:`_after_the_work`'s."""
    parser = build_parser()
    complete_if_asked(parser)
    if not (sys.argv[1:] if argv is None else argv):
        print_help_for_no_command(parser)
    args = parser.parse_args(argv)
    if args.verbose and args.quiet:  # one before the command, the other after it: argparse's group sees only one
        parser.error("argument -v/--verbose: not allowed with argument -q/--quiet")
    previous = _terminate_cleanly(args.command, args)
    previous_int = _note_interrupts()
    try:
        return _run(args, sys.argv[1:] if argv is None else list(argv))
    finally:
        import signal

        if own_process:
            _after_the_work(args.command)
        else:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
            if previous_int is not None:
                signal.signal(signal.SIGINT, previous_int)
                _ctrl_break_put_back()


def _run(args: argparse.Namespace, argv: Sequence[str] = ()) -> int:
    """Run the parsed command; with ``--log-file``, its file gets a line saying which command started
    (:func:`_log_start`) and one saying how it ended, with its exit status (:func:`_log_end`)."""
    import time

    _expand_home(args)
    started = time.monotonic()
    code: int | None = None
    try:
        progress.configure(
            progress=not (args.global_no_progress or getattr(args, "no_progress", False)),
            verbose=args.verbose,
            log_file=args.log_file,
            quiet=args.quiet,
        )
        _log_start(argv)
        check_output_names(args)
        # a session's fault is warned of once per command (said_once), again by a later command of this process
        from .folders import left_empty_removed

        # a run that fails, is stopped (Ctrl-C, SIGTERM: _end_at_once) or refused leaves no empty output folder made
        ended: dict[str, int] = {}
        with (
            progress.results_to_log_file(),
            said_once.scope(),
            left_empty_removed(_outputs(args), kept=lambda: ended.get("code") == 0),
        ):
            code = ended["code"] = int(args.func(args) or 0)
    except (NlipsError, MissingDependencyError) as exc:
        code = _fail(args, str(exc))
    except OSError as exc:  # disk full, read-only, permission, name too long ...: one line, no traceback
        code = _fail(args, describe_os_error(exc, hasattr(args, "overwrite"), where=_path_of(args)))
    except KeyboardInterrupt:
        code = _interrupted(args)
    except Exception:
        if _INTERRUPTED:  # Ctrl-C inside a native library (Mitsuba/drjit) surfaces as its own exception
            code = _interrupted(args)
        else:
            # the traceback goes to stderr as before (Python prints it); the file gets it too, with the status
            progress.file_log(logging.ERROR, f"nlips {args.command}: unexpected error", exc_info=True)
            _log_end(args.command, 1, time.monotonic() - started)
            raise
    _log_end(args.command, code, time.monotonic() - started)
    return code


def _log_start(argv: Sequence[str]) -> None:
    """The ``--log-file``'s first line of a run: the command line as typed, the version, the process id and the
    working folder (a log read a day later names presses by the paths the command was given, often relative).

    Why: runs append to one file, and nothing said where one run's lines began, what was run, or with which
    version; with two runs writing at once, the process id tells their lines apart (each line carries it)."""
    import shlex

    try:
        where = os.getcwd()
    except OSError:  # the working folder was removed: the line is still written, the command still runs
        where = "a removed folder"
    progress.file_log(
        logging.INFO, f"nlips {__version__} started (pid {os.getpid()}, in {where}): nlips {shlex.join(argv)}"
    )


def _log_end(command: str, code: int, seconds: float) -> None:
    """The ``--log-file``'s last line of a run: its exit status (see ``nlips --help``) and how long it ran."""
    level = logging.INFO if code == 0 else logging.ERROR
    progress.file_log(level, f"nlips {command} ended: exit status {code} after {seconds:.1f} s")


def _expand_home(args: argparse.Namespace) -> None:
    """Expand a leading ``~`` in the command's arguments (``--out=~/res``, a quoted ``'~/presses'``, a path from a
    script), as the shell does for a bare one: the shell leaves ``~`` after ``=`` or inside quotes alone, and the
    command made a folder named ``~`` in the working directory (``./~/res``) where the user meant the home folder.
    Only values that start with ``~`` change (``os.path.expanduser`` leaves them as they are without a home)."""
    for name, value in vars(args).items():
        if isinstance(value, str) and value.startswith("~"):
            setattr(args, name, os.path.expanduser(value))
        elif isinstance(value, list) and any(isinstance(v, str) and v.startswith("~") for v in value):
            setattr(args, name, [os.path.expanduser(v) if isinstance(v, str) else v for v in value])


_INTERRUPTED: list[int] = []
"""SIGINT numbers received while a command ran (see :func:`_note_interrupts`)."""


RESUMABLE = "finished work is kept, run again to resume"
"""What an interrupted or terminated command says it left, unless its arguments say otherwise (:func:`_stopped`)."""


def _stopped(args: argparse.Namespace | None) -> str:
    """The end of the line an interrupted or terminated command prints: :data:`RESUMABLE`, or what a command that
    cannot resume left, chosen from its arguments by the ``stopped`` its parser sets (a line, or a function of
    the arguments giving a line or None): a stream (``nlips live``; ``nlips infer`` from a camera, the emulated
    sensor or a video) cannot continue where it stopped. ``args`` None: :data:`RESUMABLE`."""
    stopped = getattr(args, "stopped", None)
    try:
        line = stopped(args) if callable(stopped) else stopped
    except Exception:  # on the way out (a signal handler): never an error of its own
        line = None
    return line or RESUMABLE


def _interrupted(args: argparse.Namespace) -> int:
    line = f"nlips {args.command}: interrupted; {_stopped(args)}"
    print(line, file=sys.stderr)
    progress.file_log(logging.WARNING, line)
    _SAID_INTERRUPTED.append(args.command)
    return 130


def terminated(args: argparse.Namespace) -> int:
    """A command that ended its own work on SIGTERM (a stream: ``_stream.SigtermEndsStream``) says so as the
    handler of :func:`_terminate_cleanly` would, after its summary; returns 143 (128 + SIGTERM)."""
    import signal

    line = f"nlips {args.command}: terminated; {_stopped(args)}"
    print(line, file=sys.stderr)
    progress.file_log(logging.WARNING, line)
    _SAID_INTERRUPTED.append(args.command)
    return 128 + signal.SIGTERM


_SAID_INTERRUPTED: list[str] = []
"""Commands whose interruption (or termination, :func:`terminated`) this process has reported
(:func:`_interrupted`), for :func:`_after_the_work`."""


def _note_interrupts():
    """Record Ctrl-C, then interrupt as Python does (KeyboardInterrupt). A native library can catch that
    exception and raise its own (drjit: "error while performing a custom differentiable operation"); the
    record lets :func:`_run` still report an interruption, not a traceback. Returns the previous handler.

    Windows' Ctrl-Break (SIGBREAK) is taken for Ctrl-C -- KeyboardInterrupt, the "interrupted" line, exit 130,
    temporaries removed, LEDs off, a stream's summary -- and ignored in the worker processes as Ctrl-C is
    (:func:`nlipscalib.core.processes.worker_signals`). Why: its default ends the process at once with none of
    that, and it is Windows' nearest to SIGTERM, which no other process can send there (``os.kill`` and
    ``taskkill /F`` are ``TerminateProcess``, which no handler sees)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    if signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return None  # ignored (a background job) or handled by the embedding program: leave it so
    _INTERRUPTED.clear()

    def handler(signum: int, frame: FrameType | None) -> None:
        _INTERRUPTED.append(signum)
        signal.default_int_handler(signum, frame)

    ctrl_break = getattr(signal, "SIGBREAK", None)  # Windows only
    if ctrl_break is not None and signal.getsignal(ctrl_break) == signal.SIG_DFL:
        signal.signal(ctrl_break, handler)
    return signal.signal(signal.SIGINT, handler)


def _ctrl_break_put_back() -> None:
    """Ctrl-Break's default put back (Windows) when :func:`main` returns to a Python program that called it."""
    import signal

    ctrl_break = getattr(signal, "SIGBREAK", None)
    if ctrl_break is not None and signal.getsignal(ctrl_break) not in (signal.SIG_IGN, None):
        signal.signal(ctrl_break, signal.SIG_DFL)


def _terminate_cleanly(command: str, args: argparse.Namespace | None = None):
    """On SIGTERM (a scheduler's time limit, `kill`) stop the worker processes, release claims and
    temporaries, then exit 143, saying what is left (:func:`_stopped` of ``args``, the parsed arguments).

    Done in the handler and ended with os._exit rather than by raising: an exception raised at an
    arbitrary point can land inside a native library (Mitsuba, drjit) and abort the process.
    Returns the previous handler.
    """
    import signal
    import threading

    def handler(signum: int, frame: FrameType | None) -> None:
        _end_at_once(f"nlips {command}: terminated; {_stopped(args)}", 143)

    if threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)


AFTER_THE_WORK = "after its work ended; what it wrote is kept"
"""What a command says of a Ctrl-C or SIGTERM that came once its work was done (:func:`_after_the_work`)."""


def _after_the_work(command: str) -> None:
    """Ctrl-C or SIGTERM once the command's work ended (its result line printed), until its process ends: the line
    "nlips COMMAND: interrupted (terminated) after its work ended; what it wrote is kept", exit 130 (143).

    The work's handlers were put back to Python's defaults when :func:`main` returned: Ctrl-C while the process
    exited (a slow library's teardown, e.g. torch's second after ``nlips export`` printed its line) printed an
    "Exception ignored in atexit callback" traceback and exited 0, or killed the process with no line, as SIGTERM
    always did. The status stays the signal's, as for an interrupt during the work: a shell loop or a scheduler
    must still see that the user stopped it; the line says that nothing was lost. Ended with os._exit as
    :func:`_terminate_cleanly` is, for the same reason.
    """
    import signal
    import threading

    interrupted = command in _SAID_INTERRUPTED

    ctrl_break = getattr(signal, "SIGBREAK", None)  # Windows: as Ctrl-C (_note_interrupts)

    def handler(signum: int, frame: FrameType | None) -> None:
        how = "interrupted" if signum in (signal.SIGINT, ctrl_break) else "terminated"
        # after an interruption (its line said what is kept), a second Ctrl-C as the process exits ends it with no
        # other line: "after its work ended" would say the interrupted work had finished
        code = 128 + (signal.SIGINT if signum == ctrl_break else signum)
        _end_at_once(None if interrupted else f"nlips {command}: {how} {AFTER_THE_WORK}", code)

    if threading.current_thread() is threading.main_thread():
        for signum in (signal.SIGINT, signal.SIGTERM, *([ctrl_break] if ctrl_break is not None else [])):
            if signal.getsignal(signum) not in (signal.SIG_IGN, None):  # an ignored Ctrl-C (a background job) stays
                signal.signal(signum, handler)


def _end_at_once(line: str | None, code: int) -> NoReturn:
    """End the process from a signal handler: its worker processes stopped, its claims released and temporaries
    removed, ``line`` on stderr (None: none), exit ``code``."""
    from ..core import atomic, claims

    _release_multiprocessing_resources()  # first: before the workers end (see there)
    _stop_workers()
    claims.release_all()
    atomic.remove_in_progress()
    folders = sys.modules.get(f"{__name__}.folders")
    if folders is not None:  # the output folders the run made and left empty (as Ctrl-C removes them)
        folders.remove_all_left_empty()
    if line is not None:
        print(line, file=sys.stderr)
        progress.file_log(logging.WARNING, f"{line} (exit status {code})")  # os._exit: no end line otherwise
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(code)


def _exit(code: int) -> NoReturn:
    """End the command's process with ``code`` as the interpreter would -- its other non-daemon threads joined, the
    ``atexit`` functions run (logging's flush, multiprocessing's, coverage's), stdout and stderr flushed -- without
    the teardown of its modules that follows.

    Why: Python puts SIGINT and SIGTERM back to their defaults before that teardown, so :func:`_after_the_work`'s
    handlers no longer hold there, and a signal during it (a second for torch and onnxruntime) killed the process
    with no line. The teardown frees nothing a process about to end needs freed; skipping it also ends sooner.

    After Ctrl-C during a render (its line printed), the render left running on a thread of its own
    (:func:`_render_left_running`), the process ends as on SIGTERM instead (:func:`_end_at_once`, no second line):
    drjit's exit function waits for the kernels that run, so the interpreter's exit waited for the render, tens
    of seconds.
    """
    import atexit
    import contextlib
    import threading

    if _render_left_running():
        _end_at_once(None, code)
    shutdown = getattr(threading, "_shutdown", None)
    if shutdown is not None:
        # the interpreter's own first step at exit: the callbacks of threading._register_atexit (which tell
        # concurrent.futures' idle pool threads, e.g. the solver's, to end), then every non-daemon thread joined.
        # Joining those pool threads without the callbacks waited forever.
        shutdown()
    else:  # not CPython: the threads it has, joined
        for thread in threading.enumerate():
            if thread is not threading.current_thread() and not thread.daemon:
                thread.join()
    atexit._run_exitfuncs()  # what the interpreter runs at exit; exceptions in them are printed, as they are there
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):  # a closed pipe (`nlips ... | head`)
            stream.flush()
    os._exit(code)


def _render_left_running() -> bool:
    """Whether a render that Ctrl-C stopped waiting for still runs
    (:func:`nlipscalib.sim.render.interruptible.abandoned_work_running`; False when nothing was rendered)."""
    interruptible = sys.modules.get("nlipscalib.sim.render.interruptible")
    return interruptible is not None and interruptible.abandoned_work_running()


def _stop_workers() -> None:
    """End the command's worker processes (``--workers N`` pools of solve, calibrate, dataset; experiment tasks).

    A plain ``kill PID`` signals this process alone (a scheduler or ``timeout`` signals the whole group): its
    workers, reparented to init, went on publishing results after the "terminated" line and then waited forever
    for tasks. Each gets SIGTERM (its handler releases its claims and temporaries and exits), and SIGKILL if it
    has not ended within :data:`nlipscalib.core.processes.WORKER_GRACE_S` (a long native call of its main thread;
    what it leaves, a dead process's claim and temporary, the next run takes over and removes).
    """
    mp = sys.modules.get("multiprocessing")
    if mp is None:  # no worker was ever started
        return
    runner = sys.modules.get("nlipscalib.experiments.runner")
    if runner is not None:  # a Dask local cluster's nannies would replace each worker ended below
        runner.stop_restarting_workers()
    try:
        workers = mp.active_children()
    except Exception:  # best effort on the way out
        return
    end_processes(workers)


def _release_multiprocessing_resources() -> None:
    """Free what multiprocessing frees at a normal exit, before a terminated process ends with os._exit.

    A worker pool (``nlips solve/calibrate/dataset --workers N``) started with forkserver or spawn
    holds named POSIX semaphores (its queues' locks), registered with multiprocessing's resource
    tracker process and unlinked by finalizers that run at interpreter exit. ``os._exit`` skips those
    finalizers, so the tracker finds the semaphores still registered when this process is gone,
    unlinks them itself and prints "UserWarning: resource_tracker: There appear to be N leaked
    semaphore objects" (two lines) after our one-line message. Running the same finalizers that
    multiprocessing runs first at exit (priority >= 0: unlink and unregister each semaphore, close
    the queues' feeders, neither of which waits for a worker) frees them here, so nothing leaks and
    the tracker has nothing to report. Silencing the tracker instead would hide real leaks.

    Run before the workers are ended, not after: a worker's end makes another thread free its queues -- a Dask
    local cluster's nanny (its event loop thread) lets go of the worker's two queues, whose finalizers then run in
    that thread or in a queue's feeder thread. A finalizer runs once, in the thread that first calls it; one such
    thread between ``sem_unlink`` and the unregistering when ``os._exit`` came left the semaphore registered but
    gone, and the tracker warned in four lines ("1 leaked semaphore objects", "'/mp-...': [Errno 2] No such file
    or directory"): 2 runs in 4 of a terminated ``--scheduler local:2`` at load 8. Run first, in this thread,
    every finalizer is done when the workers end, and later calls elsewhere find nothing to do.
    """
    util = sys.modules.get("multiprocessing.util")
    if util is None:  # no pool was ever made in this process: nothing to free
        return
    try:
        util._run_finalizers(0)
    except Exception:  # best effort on the way out: the tracker still unlinks what is left
        pass


def _path_of(args: argparse.Namespace) -> str | None:
    """The command's output (or input) folder for an error line: the first of --out (``nlips live --save`` too),
    PRESS, PRESSES that is one path (``calibrate-leds`` takes a list of presses and ``capture --presses`` a count:
    neither names one)."""
    for key in ("out", "press", "presses"):
        value = getattr(args, key, None)
        if isinstance(value, str | os.PathLike):
            return os.fspath(value)
    return None


def describe_os_error(
    exc: OSError, overwrite_flag: bool = False, where: str | Path | None = None, option: str = "--out"
) -> str:
    """One line naming the path and the cause of a file-system error: the entry the user asked for, not a
    hidden temporary or claim beside it; ``where`` (the command's output or input) when the error names no
    path (a full disk found while writing); ``option``: the flag naming the output, for the remedy."""
    from ..core.atomic import named_target

    cause = exc.strerror or str(exc)
    in_the_way = f"a file where a folder is needed (choose another {option}, or move the file)"
    if exc.errno == errno.ENOSPC:
        cause += f" (the disk is full: free space or choose another {option})"
    elif exc.errno in (errno.EROFS, errno.EACCES, errno.EPERM):
        cause += " (choose a writable output folder)"
    elif isinstance(exc, FileExistsError) and _file_in_the_way(exc.filename, where):
        cause = in_the_way
    elif exc.errno == errno.ENOTDIR and (blocker := _file_above(exc.filename)) is not None:
        # "OUT/press/nlipsnet: Not a directory" named a path below the file the user gave
        return f"{blocker}: {in_the_way}"
    elif isinstance(exc, FileExistsError) and overwrite_flag:
        cause += " (use --overwrite to replace it)"
    paths = [named_target(p) for p in (exc.filename, exc.filename2) if p is not None]
    if not paths and where is not None:
        paths = [where]
    return f"{' -> '.join(map(str, paths))}: {cause}" if paths else cause


def _file_in_the_way(name: str | Path | None, where: str | Path | None) -> bool:
    """Whether ``name`` is a file at or above the output folder ``where`` (``--out FILE``, ``--out FILE/sub``): a
    folder cannot be made there, and --overwrite would not help."""
    if name is None or where is None or not Path(name).is_file():
        return False
    return Path(where).absolute().is_relative_to(Path(name).absolute())


OUTPUT_OPTIONS = ("out", "report", "figure")
"""The dests of the options naming what a command writes (``--out``, experiment's ``--report``,
calibrate-camera-response's ``--figure``), checked by :func:`check_output_names`."""


def _outputs(args: argparse.Namespace) -> list[str]:
    """The paths the options of :data:`OUTPUT_OPTIONS` name (files or folders), as given."""
    return [os.fspath(v) for dest in OUTPUT_OPTIONS if isinstance(v := getattr(args, dest, None), (str, Path))]


def check_output_names(args: argparse.Namespace) -> None:
    """Refuse, before any work, an output name holding a control character (a line break, a tab): stdout gives each
    result path on one line (:func:`nlipscalib.progress.print_result`), and a script reading it would take one such name
    for two paths; the folder would also be awkward in every shell after."""
    from ..core.errors import ConfigError
    from .options import option

    for dest in OUTPUT_OPTIONS:
        value = getattr(args, dest, None)
        if isinstance(value, (str, Path)) and one_line(str(value)) != str(value):
            raise ConfigError(
                f"{option(dest)} {one_line(str(value))}: a control character (a line break?) in an output's name: "
                "stdout gives each result path on one line, for scripts; choose a name without one"
            )


def _file_above(name: str | Path | None) -> Path | None:
    """The file at or above ``name`` that a path was made through as if it were a folder (ENOTDIR), or None."""
    if name is None:
        return None
    for part in (Path(name), *Path(name).parents):
        if part.is_file():
            return part
    return None


def _fail(args: argparse.Namespace, message: str) -> int:
    message = one_line(message)
    print(f"nlips {args.command}: error: {message}", file=sys.stderr)
    progress.file_log(logging.ERROR, f"nlips {args.command}: {message}")
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
