"""Progress bars and logging for long commands: one switch for the whole ``nlips`` run.

Bars (tqdm) go to stderr only when it is a terminal or a Jupyter notebook's (an IPython kernel's stream, drawn
under the cell), and ``--no-progress`` was not given, so log files and CI output never fill with carriage-return
bars. ``--log-file`` copies every log line to a file. ``--quiet`` leaves stderr to warnings and errors (and draws
no bar); the log file still gets every line.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
import re
import sys
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:  # named in hints only: tqdm is imported when a bar is made
    from tqdm import tqdm

_enabled = True
_log_file: str | None = None
"""The ``log_file`` of the last :func:`configure` (handed to worker processes by :func:`worker_logging`)."""
_quiet = False
"""``--quiet`` of the last :func:`configure`: stderr shows WARNING and above only (handed to worker processes by
:func:`worker_logging`)."""
PRESS_DETAIL = {"press_line": 2}
"""``extra`` of a log record saying how one press was solved (the interreflection term's and the anchoring's
decisions): on stderr for a single press (``nlips solve PRESS``); in batches of presses only with ``-v``."""
PRESS_SUMMARY = {"press_line": 1}
"""``extra`` of a press's one summary line (pixels reconstructed, solver time, where it was saved): on stderr for a
single press and per press of a batch (``nlips solve FOLDER``, ``nlips calibrate``); not in experiments, whose task
bar and report say it (``-v`` shows it there)."""
FILE_ONLY = {"file_only": True}
"""``extra`` of a long run's periodic log line (a training's epoch): in the ``--log-file`` always, on stderr only with
``-v``. Why: a terminal's bar shows the same, and 200 such lines would bury a job's stderr; but the file of a
three-hour training held nothing between its start and its end, so a crash left no trace of how far it got."""
SINGLE, BATCH, EXPERIMENT = 2, 1, 0
"""What :func:`press_lines` shows on stderr: every press line, the summaries only, none (the ``press_line``
values of :data:`PRESS_DETAIL` and :data:`PRESS_SUMMARY` up to it)."""
_press_lines = SINGLE
"""What :func:`press_lines` last chose (handed to worker processes by :func:`worker_logging`)."""
FILE_FORMAT = "%(asctime)s [%(process)d] %(levelname)s %(name)s: %(message)s"
"""A log file's line: when, which process (two runs appending to one file, a run's worker processes), how grave,
where from, what."""
STDERR_FORMAT = "%(levelname)s %(message)s"


def configure(
    *, progress: bool = True, verbose: bool = False, log_file: str | Path | None = None, quiet: bool = False
) -> None:
    """Set up logging (stderr, plus ``log_file`` when given) and the global progress switch.

    ``quiet`` (``nlips --quiet``): stderr gets warnings and errors only, and no bar; the log file's lines are not
    lessened (its level stays INFO, or DEBUG with ``verbose``). Handlers already on the root logger (an embedding
    application's, pytest's) are kept; only the file handler this function added before is replaced.
    """
    global _enabled, _quiet
    _enabled = progress and not quiet
    _quiet = quiet
    press_lines(SINGLE)  # until the command says it solves a batch
    _setup(logging.DEBUG if verbose else logging.INFO, log_file)


def press_lines(shown: int) -> None:
    """Which per-press log lines reach stderr from now on, in this process and the workers it starts later:
    :data:`SINGLE` (all: one press, the user wants to know what was decided), :data:`BATCH` (one summary line per
    press) or :data:`EXPERIMENT` (none). Why: a batch logged three INFO lines per solved press, some 430 lines for
    ``nlips experiment q1 --size full``, burying its warnings. ``-v`` shows them all; the ``--log-file`` gets
    them all in any case."""
    global _press_lines
    _press_lines = shown


def worker_logging() -> tuple[int, str | None, int, bool]:
    """``initargs`` for :func:`configure_worker` as a pool's ``initializer``: this process's level, log file,
    :func:`press_lines` and ``--quiet``."""
    return logging.getLogger().getEffectiveLevel(), _log_file, _press_lines, _quiet


def configure_worker(
    level: int, log_file: str | None = None, shown_press_lines: int = SINGLE, quiet: bool = False
) -> None:
    """In a worker process (spawn, forkserver): log like the parent, to stderr and to its ``--log-file``, with
    the parent's :func:`press_lines` and ``--quiet``.

    Bars stay off: the parent draws the only one.
    """
    global _enabled, _quiet
    _enabled = False
    _quiet = quiet
    press_lines(shown_press_lines)
    _setup(level, log_file)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, AboveTheBarsHandler):
            handler.blank_first = True  # the parent's bar may be on the terminal's line


def _setup(level: int, log_file: str | Path | None) -> None:
    global _log_file
    root = logging.getLogger()
    root.setLevel(level)
    for handler in [h for h in root.handlers if getattr(h, _OURS, False)]:
        root.removeHandler(handler)
        handler.close()
    if not root.handlers:
        stderr = AboveTheBarsHandler(sys.stderr)
        stderr.addFilter(_shown_on_stderr)
        stderr.addFilter(_debug_of_ours)
        _add(root, stderr, STDERR_FORMAT)
    _log_file = None
    if log_file:
        from .cli.folders import names_a_folder

        if names_a_folder(log_file):  # os.open said only "out: Is a directory", naming no option
            from .core.errors import ConfigError

            raise ConfigError(
                f"--log-file {log_file}: a folder; give the file to append the log to (e.g. "
                f"{Path(log_file) / 'nlips.log'})"
            )
        Path(log_file).parent.mkdir(parents=True, exist_ok=True)
        file = AppendFileHandler(log_file)
        file.addFilter(_debug_of_ours)
        _add(root, file, FILE_FORMAT)
        _log_file = str(Path(log_file).absolute())


class AboveTheBarsHandler(logging.StreamHandler):
    """stderr's log handler: a line logged while a bar is drawn on the same terminal lands on its own line, with the
    bar drawn again below it (:func:`above_the_bars`).

    Why: a bar leaves the cursor at its end, so ``nlips -v solve FOLDER --workers 1`` wrote its first INFO line onto
    the bar's ("presses:   0%|    | 0/3 [00:00<?, ?press/s]INFO ..."), as did every bar's user logging under it
    (dataset, calibrate, experiment, train).

    In a worker process (:func:`configure_worker`) the bar is the parent's, out of reach: a worker writing to a
    terminal starts each line by blanking the terminal's line (:func:`_blank_line`), where the parent's bar may be,
    and the parent draws its bar again at its next update."""

    blank_first = False
    """Whether each line starts by blanking the terminal's line (a worker's, whose parent may have a bar there)."""

    def emit(self, record: logging.LogRecord) -> None:
        with above_the_bars(self.stream):
            super().emit(record)

    def format(self, record: logging.LogRecord) -> str:
        line = super().format(record)
        if self.blank_first and _is_a_terminal(self.stream):  # in the line's one write: a parent's draw can't split it
            return _blank_line(self.stream) + line
        return line


def _is_a_terminal(stream: object) -> bool:
    try:
        return bool(stream.isatty())  # type: ignore[attr-defined]
    except Exception:  # closed, or not a file
        return False


def _blank_line(stream: object) -> str:
    """A carriage return, spaces across the terminal ``stream`` shows on, a carriage return: blanks a line on any
    terminal (no escape codes, which an old Windows console prints as they are).

    The width is the stream's own terminal's: ``shutil.get_terminal_size`` asks stdout's, 80 columns when stdout is
    redirected (``nlips solve FOLDER > summary.txt``), which left the end of a wider bar after a short line."""
    import shutil

    try:
        columns = os.get_terminal_size(stream.fileno()).columns  # type: ignore[attr-defined]
    except (AttributeError, OSError, ValueError):  # no descriptor (a test's stream), not a terminal's, closed
        columns = shutil.get_terminal_size().columns
    return "\r" + " " * max(columns - 1, 0) + "\r"


@contextlib.contextmanager
def above_the_bars(stream: object = None, *, wait_for_lock: bool = True) -> Iterator[None]:
    """While active, the live bars drawn to ``stream`` (stderr when None; stdout's too, as both show on one
    terminal) are cleared from the screen, so what the block writes starts on a clean line; they are drawn again
    below it on the way out (tqdm's ``external_write_mode``, the library's own way of writing around its bars).

    ``wait_for_lock=False``: without taking tqdm's write lock, for a block that may wait a long time (an operator's
    ``input()``). The lock is waited for :data:`BAR_LOCK_WAIT_S` at most. Nothing happens (tqdm is not even
    imported) while no bar of the process is live."""
    tqdm_module = sys.modules.get("tqdm")
    bars = getattr(getattr(tqdm_module, "tqdm", None), "_instances", None)
    if not bars:  # no bar made yet in this process (a worker's, a command without one): nothing to clear
        yield
        return
    bar_class = tqdm_module.tqdm  # type: ignore[union-attr]
    taken = _take_within(bar_class.get_lock(), BAR_LOCK_WAIT_S) if wait_for_lock else []
    try:
        with bar_class.external_write_mode(file=stream or sys.stderr, nolock=True):  # the lock, if had, is held here
            yield
    finally:
        for part in reversed(taken):
            part.release()


BAR_LOCK_WAIT_S = 1.0
"""Longest wait (s) for tqdm's write lock before a log line clears the bars without it. Why: a draw interrupted by
Ctrl-C keeps that lock held for good (tqdm 4.70.1's ``refresh`` releases it in no ``finally``: s27-floors,
benchmarks/RESULTS.md), so any other thread's log line (a claim's heartbeat) waited on it forever. A draw takes
milliseconds; without the lock, a draw of another thread at that instant can at worst put the line after a bar."""


def _take_within(lock: Any, wait_s: float) -> list:
    """The parts of tqdm's write lock (a ``TqdmDefaultWriteLock``: the process's and the threads' locks, taken in
    that order), all taken within ``wait_s`` each, or none (an empty list, nothing held)."""
    taken: list = []
    for part in getattr(lock, "locks", [lock]):
        if not part.acquire(timeout=wait_s):
            for held in reversed(taken):
                held.release()
            return []
        taken.append(part)
    return taken


def _debug_of_ours(record: logging.LogRecord) -> bool:
    """Whether a record is shown: any at INFO and above, DEBUG ones of nlipscalib's loggers only.

    Why: ``-v`` sets the root logger to DEBUG, and the libraries' debug lines came with ours: a one-minute
    ``nlips -v --log-file F train`` wrote 2,200 lines, 2,191 of them matplotlib's font scoring ("findfont:
    score(FontEntry(...))"), burying the run's own three."""
    return record.levelno >= logging.INFO or record.name == "nlipscalib" or record.name.startswith("nlipscalib.")


class AppendFileHandler(logging.Handler):
    """Appends every record to a file with one ``os.write`` on an ``O_APPEND`` descriptor.

    The parent and its worker processes all append to the same ``--log-file``: with ``O_APPEND`` the
    kernel moves to the end of the file and writes in one step, so one process's line never
    overwrites or splits another's (a ``logging.FileHandler`` writes through a buffer, which splits a
    record longer than the buffer, e.g. a long traceback, into several writes that can interleave).
    Nothing to set up in the parent (no queue, no listener thread), and a worker that dies has
    written its lines already. (On NFS, appends from several machines are not atomic; one machine's
    processes are fine.)

    Windows has no such append: its C runtime emulates ``O_APPEND`` by moving to the end and then writing, two
    steps, so two processes can both move to the same end and the second line overwrites the first. There
    (:data:`APPENDS_INTERLEAVE`) every write holds an exclusive lock on ``PATH.lock`` (filelock: the
    system's own file lock, released by the system when a process dies holding it; the file is removed on
    release). A lock that cannot be had within :data:`LOG_LOCK_WAIT_S` (a folder where no lock file can be made)
    does not cost the line: it is written unlocked.
    """

    def __init__(self, path: str | Path):
        super().__init__()
        self.path = str(path)
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | getattr(os, "O_CLOEXEC", 0)
        self._fd: int | None = os.open(self.path, flags, 0o666)
        self._append_lock = _append_lock(self.path) if APPENDS_INTERLEAVE else None
        self.lost = 0
        """Lines not written since the last one that was (the disk full, the file's disk gone)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            data = (self.format(record) + "\n").encode("utf-8", "backslashreplace")
        except Exception:
            self.handleError(record)  # a record that cannot be formatted: a bug of its caller, shown as logging does
            return
        try:
            if self.lost:  # written again (space freed): say in the file what is missing before this line
                data = self._lost_line(record).encode("utf-8", "backslashreplace") + data
            self._append(data)
        except OSError as exc:
            self._lose(exc)
            return
        except Exception:  # never out of a handler: shown as logging shows it
            self.handleError(record)
            return
        self.lost = 0

    def _append(self, data: bytes) -> None:
        with self._whole_append():
            while data and self._fd is not None:
                data = data[os.write(self._fd, data) :]  # a regular file takes it whole unless the disk is full

    def _lose(self, exc: OSError) -> None:
        """A line that could not be written: said once on stderr, in one line, then counted (:attr:`lost`).

        Why: ``logging.Handler.handleError`` printed a 30-line "--- Logging error ---" traceback on stderr for every
        line once the log's disk was full, for as long as the command ran (a stream's counted warning each minute,
        its summary lines), and the command's own errors drowned in them; the command's work and its output
        elsewhere go on."""
        if not self._said_lost:
            self._said_lost = True
            stream = sys.stderr
            if stream is not None:  # pythonw: no stderr
                cause = exc.strerror or str(exc)
                stream.write(f"nlips: --log-file {self.path}: {cause}; its lines are lost until it can be written\n")
        self.lost += 1

    _said_lost = False
    """Whether the loss of lines was said on stderr (once per handler: a disk that fills again is not said twice)."""

    def _lost_line(self, record: logging.LogRecord) -> str:
        """The log line counting the lines lost before ``record`` (in the file's format, at WARNING)."""
        lost = logging.LogRecord(
            record.name, logging.WARNING, __file__, 0, f"{self.lost} log line(s) lost here (not written)", None, None
        )
        return self.format(lost) + "\n"

    @contextlib.contextmanager
    def _whole_append(self) -> Iterator[None]:
        """The log's lock held (where appends interleave), or nothing (where the system appends whole)."""
        lock = self._append_lock
        if lock is None:
            yield
            return
        try:
            lock.acquire(timeout=LOG_LOCK_WAIT_S, poll_interval=LOG_LOCK_POLL_S)
        except Exception:  # no lock file there (a read-only folder), or held too long: the line still goes in
            lock = None
        try:
            yield
        finally:
            if lock is not None:
                lock.release()

    def close(self) -> None:
        with self.lock:
            if self._fd is not None:
                os.close(self._fd)
                self._fd = None
        super().close()


APPENDS_INTERLEAVE = sys.platform == "win32"
"""Whether appends of several processes to one file can overwrite each other (Windows: :class:`AppendFileHandler`)."""
LOG_LOCK_WAIT_S = 5.0
"""Longest wait (s) for the log file's lock before the line is written without it."""
LOG_LOCK_POLL_S = 0.001
"""How often (s) a process waiting for the log file's lock tries again (filelock's 0.05 s default would hold a
worker back 50 ms whenever two log at once)."""


def _append_lock(path: str) -> Any:
    """The lock every process appending to the log ``path`` takes around each line (a ``filelock.FileLock``)."""
    import filelock  # here: only where appends interleave

    return filelock.FileLock(path + ".lock")


_OURS = "_nlips_handler"


def file_log(level: int, message: str, exc_info: bool = False) -> None:
    """Record ``message`` in the log file only (for lines already printed on the terminal); ``exc_info``: with the
    traceback of the exception being handled."""
    record = logging.LogRecord("nlipscalib", level, __file__, 0, message, None, sys.exc_info() if exc_info else None)
    for handler in logging.getLogger().handlers:
        if getattr(handler, _OURS, False) and isinstance(handler, AppendFileHandler):
            handler.handle(record)


def say(line: str, *, warning: bool = False) -> None:
    """A command's closing line for the person at the terminal (counts, coverage, the next step): on stderr as
    typed, without a level's word, unless ``--quiet`` (a ``warning``, e.g. the presses that failed, is said even
    then), and in the ``--log-file`` at INFO (WARNING).

    Why not stdout: stdout holds a command's result paths alone, one a line, for scripts
    (``model=$(nlips train DS --out m.pt)``); why not a log record: ``INFO`` before a summary line read as noise."""
    if warning or not _quiet:
        print(line, file=sys.stderr)
    file_log(logging.WARNING if warning else logging.INFO, line)


def print_result(path: str | Path) -> None:
    """stdout: one path the command made or found done (a press folder, a dataset, a model, a report), alone on
    its line, so that a script reads each line as one path (``press=$(nlips render --out p1 -q)``); what it is and
    how it went is said on stderr (:func:`say`).

    A name holding a control character (a line break: a press folder received from elsewhere) is written with
    it escaped (:func:`one_line`, a newline as ``\\n``), with one warning saying so: printed as it is, it would
    be two lines, two paths to a script. Output names given with ``--out`` are refused with one before any work
    (:func:`nlipscalib.cli.check_output_names`)."""
    shown = one_line(str(path))
    if shown != str(path):
        logging.getLogger(__name__).warning(
            "%s: a control character (a line break) in the name: written on stdout with it escaped", shown
        )
    print(shown)


def ask(prompt: str) -> str:
    """Wait for the person at the terminal to answer ``prompt`` (Enter); the line typed, without its newline.

    The prompt goes to stderr, written here, and never to stdout. Why: ``input(prompt)`` writes it to stdout
    whenever stdout is not a terminal, so ``session=$(nlips capture --port ...)`` at a terminal read the operator's
    instructions ("Do not touch the sensor: ... [Enter] ") into the variable ahead of the session's folder, and a
    script got no path it could use. stdout holds result paths alone (:func:`print_result`); ``input()`` without a
    prompt writes nothing there. Raises EOFError when stdin is closed (Ctrl-D), as ``input`` does."""
    if sys.stderr is not None:
        sys.stderr.write(prompt)
        sys.stderr.flush()
    return input()


_CONTROL = re.compile(r"[\x00-\x1f\x7f]")
"""Control characters: a line break among them, which would split a printed name or error over two lines."""


def one_line(message: str) -> str:
    """``message`` with its control characters written as escapes (a newline as ``\\n``): the line stays one line.

    Why: error lines and result paths name files, and a file or folder name from elsewhere (a press folder received
    in an archive, a name in its meta.json) may hold a newline: printed as it is, it forged lines of the command's
    output, such as ``nlips solve: done`` (docs/formats.md, "Files from others")."""
    return _CONTROL.sub(lambda m: repr(m.group())[1:-1], message)


@contextlib.contextmanager
def results_to_log_file() -> Iterator[None]:
    """While active, every line printed on stdout (a command's results: summaries, tables, scores) also goes
    to the ``--log-file``, at INFO (a cluster job's log then holds the outcome, not only the warnings).
    Nothing changes without a log file."""
    if _log_file is None or sys.stdout is None:  # no file, or no stdout (fd 1 closed: print writes nothing)
        yield
        return
    real = sys.stdout
    tee = _LinesToLog(real)
    sys.stdout = tee
    try:
        yield
    finally:
        tee.flush_partial()
        if sys.stdout is tee:
            sys.stdout = real


class _LinesToLog(io.TextIOBase):
    """A text stream that writes through to ``real`` and hands each finished line to :func:`file_log`."""

    def __init__(self, real: TextIO) -> None:
        self.real, self._partial = real, ""

    def write(self, text: str) -> int:
        self.real.write(text)
        *lines, self._partial = (self._partial + text).split("\n")
        for line in lines:
            if line.strip():
                file_log(logging.INFO, line)
        return len(text)

    def flush(self) -> None:
        self.real.flush()

    def flush_partial(self) -> None:
        if self._partial.strip():
            file_log(logging.INFO, self._partial)
        self._partial = ""

    def isatty(self) -> bool:
        return self.real.isatty()

    @property
    def encoding(self):
        return self.real.encoding

    @property
    def errors(self):
        return self.real.errors

    def __getattr__(self, name: str) -> Any:  # buffer, errors, ...: the real stream's
        return getattr(self.real, name)

    def fileno(self) -> int:
        return self.real.fileno()


REPEAT_SUMMARY_S = 60.0
"""Seconds between the lines of :class:`RepeatedWarning` that count a warning's repeats."""


class RepeatedWarning:
    """A warning that can come for every one of many inputs (each frame of a stream or of a folder): the first
    ``first`` in full, each later one at DEBUG only (``-v``), and at most one WARNING line per ``every_s`` counting
    them, "... repeated 1800 more times in the last 60 s (the latest: camera 0 frame 5399)"; one that comes after
    ``every_s`` without any is in full again (a fault that came back). :meth:`flush` counts the ones not yet
    counted (at the end of the run).

    Why: ``nlips infer`` of a folder of frames taken at another exposure logged the same 500-character warning for
    every frame (30 frames: 30 warnings; a 15 frames/s recording: 54,000 an hour), on stderr and in the
    ``--log-file``, while a stream said it once for the whole day, missing a fault that came back hours later.

    Parameters
    ----------
    logger : logging.Logger
        The logger the lines go to.
    what : str
        The warning in a few words, for the counting line ("a frame unlike the calibration's reference").
    first : int
        How many are logged in full.
    every_s : float
        Seconds between counting lines, :data:`REPEAT_SUMMARY_S` unless given.
    clock : callable
        Seconds now (``time.monotonic``; a test's own).
    """

    def __init__(
        self,
        logger: logging.Logger,
        what: str,
        first: int = 1,
        every_s: float = REPEAT_SUMMARY_S,
        clock: Callable[[], float] | None = None,
    ) -> None:
        import time

        self.logger, self.what, self.first, self.every_s = logger, what, first, every_s
        self.clock = clock or time.monotonic
        self.count = 0
        """How many times the warning came (the full ones included)."""
        self._held, self._since, self._latest, self._last = 0, 0.0, "", 0.0

    def __call__(self, message: str, where: str) -> None:
        """The warning ``message`` about the input ``where`` (a frame's name, for the counting line)."""
        self.count += 1
        now, last = self.clock(), self._last
        self._last = now
        if self.count <= self.first or (not self._held and now - last >= self.every_s):
            self.logger.warning("%s", message)  # one of the first, or the first after a quiet minute: in full
            return
        self.logger.debug("%s", message)
        if not self._held:
            self._since = now
        self._held, self._latest = self._held + 1, where
        if now - self._since >= self.every_s:
            self.flush()

    def flush(self) -> None:
        """Count the repeats not counted yet (nothing when there are none)."""
        if not self._held:
            return
        seconds = self.clock() - self._since
        # a short stream's count at its end: "in the last 0 s" read as no time at all
        span = f"{seconds:.0f} s" if seconds >= 1 else "second"
        self.logger.warning(
            "%s: repeated %d more time%s in the last %s (the latest: %s; -v logs each)",
            self.what,
            self._held,
            "" if self._held == 1 else "s",
            span,
            self._latest,
        )
        self._held = 0


def _shown_on_stderr(record: logging.LogRecord) -> bool:
    """Whether a record goes to stderr: any but a per-press line beyond :func:`press_lines` and a :data:`FILE_ONLY`
    line, unless ``-v``; with ``--quiet``, warnings and errors only."""
    if _quiet:
        return record.levelno >= logging.WARNING
    verbose = logging.getLogger().getEffectiveLevel() <= logging.DEBUG
    if getattr(record, "file_only", False):
        return verbose
    line = getattr(record, "press_line", None)
    return line is None or line <= _press_lines or verbose


def _add(root: logging.Logger, handler: logging.Handler, fmt: str) -> None:
    handler.setFormatter(logging.Formatter(fmt))
    setattr(handler, _OURS, True)
    root.addHandler(handler)


def bars_enabled(requested: bool = True) -> bool:
    """Whether a bar would be drawn: requested, not switched off globally, and stderr is shown to a person as
    it is written: a terminal, or a notebook's (:func:`shown_under_a_notebook_cell`)."""
    stderr = sys.stderr
    return bool(
        requested and _enabled and stderr is not None and (stderr.isatty() or shown_under_a_notebook_cell(stderr))
    )


def shown_under_a_notebook_cell(stream: object) -> bool:
    """Whether ``stream`` is a Jupyter kernel's output stream (ipykernel's ``OutStream``, or a subclass: Spyder's,
    VS Code's notebooks run ipykernel too), whose text the notebook draws under the running cell.

    Why: such a stream is not a terminal (``isatty()`` is False), so a notebook user saw no bar for a minutes-long
    ``solve`` or ``train``, yet its front end redraws a carriage-return line in place, as a terminal does, so the
    plain tqdm bar shows right there, with no widget library (tqdm's notebook widget needs ipywidgets, which is
    not a dependency). Looked up by the stream's class, not by ``ipykernel`` being imported: stderr redirected to
    a file inside a notebook (``contextlib.redirect_stderr``) stays quiet, like a log file."""
    return any(cls.__module__.split(".")[0] == "ipykernel" for cls in type(stream).__mro__)


def progress_bar(total: int | None = None, *, enabled: bool = True, first_draw: bool = True, **kwargs: Any) -> tqdm:
    """A tqdm bar (usable as a context manager), silent unless :func:`bars_enabled`.

    Parameters
    ----------
    total : number of steps (None when unknown)
    enabled : the caller's own switch (e.g. a function's ``progress`` argument)
    first_draw : draw its first line now (:func:`_drawn`); False for a line with nothing to say before its first
        step (the solver's, drawn with its first level's description), which the caller then draws in its own
        ``try`` that closes the bar
    kwargs : passed to tqdm (desc, unit, initial, ...)
    """
    from tqdm import tqdm  # the plain bar, as every other bar of the package: see shown_under_a_notebook_cell

    bar = tqdm(total=total, disable=not bars_enabled(enabled), delay=UNDRAWN_DELAY_S, **_sized(kwargs))
    return _drawn(bar) if first_draw else bar


def track(iterable: Iterable, *, enabled: bool = True, **kwargs: Any) -> tqdm:
    """Iterate with a progress bar (see :func:`progress_bar`)."""
    from tqdm import tqdm

    return _drawn(tqdm(iterable, disable=not bars_enabled(enabled), delay=UNDRAWN_DELAY_S, **_sized(kwargs)))


UNSIZED_TERMINAL = (80, 24)
"""Columns and rows of the bars on a terminal that reports no size (0 x 0: a pty made by ``script``, some ``docker
exec -t`` and CI runners), where tqdm took -1 x -1 and drew no bar or line at all (each one past the last row)."""


def _sized(kwargs: dict[str, Any]) -> dict[str, Any]:
    """tqdm's ``kwargs`` with ``ncols`` and ``nrows`` of :data:`UNSIZED_TERMINAL` where stderr is a terminal of no
    size."""
    try:
        size = os.get_terminal_size(sys.stderr.fileno())
    except (AttributeError, OSError, ValueError):  # not a terminal (a file, a notebook's stream), closed
        return kwargs
    if size.columns > 0 and size.lines > 0:
        return kwargs
    return {"ncols": UNSIZED_TERMINAL[0], "nrows": UNSIZED_TERMINAL[1]} | kwargs


UNDRAWN_DELAY_S = 1e-9
"""tqdm's ``delay`` for the package's bars (these and the solver's line): any above 0 keeps tqdm's constructor from
drawing the bar (:func:`_drawn` draws it; the solver's first level does), this small, no update is held back."""


def _drawn(bar: tqdm) -> tqdm:
    """Draw a bar made with :data:`UNDRAWN_DELAY_S` at once (its ``0/N`` line), closing it if that draw is stopped.

    Why: tqdm's constructor registers a bar before its first draw; a Ctrl-C landing in that write (a notebook's
    stop button, in the kernel's send) left a bar open that nobody held, and every later bar of the kernel nested
    under it, a new line per update. Drawn here instead, under tqdm's lock taken with ``with`` (its own
    ``refresh`` would keep the lock held by an interrupted write)."""
    try:
        if not bar.disable:
            with bar.get_lock():
                bar.refresh(nolock=True)
    except BaseException:
        bar.close()
        raise
    bar.delay = 0  # drawn: updates and close (its final line) now treat it as tqdm treats a bar its constructor drew
    return bar


class working:  # noqa: N801 - used like a function: ``with working("rendering"):``
    """Show that an opaque step (one long library call) is alive: a ticking elapsed-time line.

    On a terminal: ``rendering: 00:12`` refreshed twice a second. Otherwise one log line when the step
    starts and one with its duration when it ends.
    """

    def __init__(self, desc: str, *, enabled: bool = True):
        self.desc, self.enabled = desc, bars_enabled(enabled)

    def __enter__(self):
        import threading
        import time

        self.t0 = time.perf_counter()
        if not self.enabled:
            logging.getLogger("nlipscalib").info("%s ...", self.desc)
            return self
        from tqdm import tqdm

        line = _sized({"desc": self.desc, "bar_format": "{desc}: {elapsed}"})
        self.bar = _drawn(tqdm(total=None, delay=UNDRAWN_DELAY_S, **line))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._tick, daemon=True)
        self._thread.start()
        return self

    def _tick(self) -> None:
        while not self._stop.wait(0.5):
            self.bar.refresh()

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:  # never swallows the exception
        import time

        seconds = time.perf_counter() - self.t0
        if self.enabled:
            self._stop.set()
            self._thread.join()
            self.bar.close()
        elif exc_type is None:
            logging.getLogger("nlipscalib").info("%s done in %.1f s", self.desc, seconds)
