"""A Dask task's log records, carried back with its outcome and logged in the command that submitted it.

Why: a Dask worker logs into its own process. A remote scheduler's workers kept the tasks' warnings ("LED 7: image
dark ...") in their own logs, on other machines, where the user who ran ``nlips experiment --scheduler tcp://...``
never saw them. ``Client.forward_logging`` would send every worker's records to every client of the scheduler: on
a cluster a lab shares, another member's run's warnings would land in this run's log. So each task collects the
records of ``nlipscalib``'s loggers that it emits (:func:`run_logged`, on the worker), returns them with its
outcome as plain dicts, and the command logs them again (:func:`replay`) with the task's name and worker:
"[press_0003 on tcp://10.0.0.5:40123] LED 7: image dark ...", with the record's own time, level, logger and
process id, through this process's handlers (stderr as ``-v`` and :func:`nlipscalib.progress.press_lines` say,
the ``--log-file``). A local cluster's workers (``--scheduler local:N``) work the same way.

Which records are a task's: those emitted in the task's thread, and in any thread started with a copy of its
context (:mod:`contextvars`; the solver's pool, :func:`nlipscalib.solver.threads.map_items`, runs each item in the
caller's). A record from another thread (one the task started without its context: the operators' or the contact
side's single helper thread, a read-ahead thread) is the task's when it is the only task its worker process runs
now: always on a local cluster (one thread per worker) and on a remote worker running one task at a time. On a
remote worker running several tasks at once such a record is no task's: it stays in the worker's own log only.

Live: a task's records also travel as they are emitted (:class:`LiveLogs`), as Dask events (``Worker.log_event``)
on a topic of this command's own, to which only this command's client subscribes (``Client.subscribe_topic``), and
are logged at once. Why: the carried records came only when the task ended; a worker killed mid-task (out of
memory, a pre-empted node) took them with it, and its last lines were the ones a lab needed. Each record is logged
once: by whichever of its live event and the task's outcome comes first (a record is known by its task attempt's id
and its number). ``Client.forward_logging`` or ``distributed.print``/``warn`` would be the library's own way, but
they go to every client of the scheduler (above). Both mechanisms exist in dask.distributed 2024.1 (pyproject's
floor) as in 2026.8.
"""

from __future__ import annotations

import contextlib
import contextvars
import dataclasses
import logging
import threading
import uuid
from collections.abc import Callable, Iterator
from typing import Any

MAX_RECORDS = 100
"""Records a task carries back at most (the first ones); the rest are counted (a ``-v`` run's debug lines, a
fault repeated for every LED)."""
PACKAGE = "nlipscalib"
"""The logger whose records (its children's included) a task carries back; the libraries' stay on the worker."""
TOPIC_PREFIX = "nlipscalib-task-logs-"
"""The start of a command's Dask event topic (:class:`LiveLogs`); a random part makes it the command's own."""
REPLAYED = "nlipscalib_task_log"
"""Attribute marking a record this module logged for a task (:func:`_log_item`): never a task's own. Why: a worker
in the command's process (``LocalCluster(processes=False)``) running a lone task took the live line, logged on the
client's thread, for one of the task's, and sent it again, prefixed twice."""
EXTRA_KEYS = ("press_line", "file_only")
"""Attributes of a record (``extra``) that the command's handlers read (:mod:`nlipscalib.progress`)."""

log = logging.getLogger(__name__)


@dataclasses.dataclass
class TaskLog:
    """The records one task emitted so far, on its worker."""

    level: int
    """The least level kept (the command's: DEBUG with ``-v``, else INFO)."""
    records: list[dict] = dataclasses.field(default_factory=list)
    """The first :data:`MAX_RECORDS`, as :func:`_as_dict` gives them."""
    more: int = 0
    """Records left out after those."""
    more_warnings: int = 0
    """Of ``more``, those of level WARNING or above."""
    send: Callable[[str, dict], None] | None = None
    """Sends a kept record (with :attr:`attempt`) to the command as it is made (:class:`LiveLogs`); None: it
    travels with the outcome only."""
    attempt: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex)
    """This run of the task (Dask re-runs a dead worker's task): with a record's number, what tells the command
    that the outcome carries a record it already logged live."""

    def add(self, record: logging.LogRecord) -> None:
        if record.levelno < self.level:
            return
        if len(self.records) < MAX_RECORDS:
            item = _as_dict(record)
            item["seq"] = len(self.records)
            self.records.append(item)
            if self.send is not None:
                with contextlib.suppress(Exception):  # a worker closing: the record still travels with the outcome
                    self.send(self.attempt, item)
            return
        self.more += 1
        self.more_warnings += record.levelno >= logging.WARNING

    def carried(self, worker: str) -> dict:
        """What travels back with the outcome (plain types: any serializer takes it)."""
        return {
            "worker": worker,
            "attempt": self.attempt,
            "records": self.records,
            "more": self.more,
            "more_warnings": self.more_warnings,
        }


_current: contextvars.ContextVar[TaskLog | None] = contextvars.ContextVar("nlipscalib_task_log", default=None)
_active: list[TaskLog] = []
"""The tasks this process runs now (a Dask worker may run several, one per thread)."""
_lock = threading.Lock()
_level_before: int = logging.NOTSET
"""The package logger's level before the first of :data:`_active` lowered it."""


class _ToItsTask(logging.Handler):
    """On the package logger while tasks run: each record to the task it belongs to (module docstring)."""

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, REPLAYED, False):
            return
        task = _current.get()
        if task is None:
            with _lock:
                task = _active[0] if len(_active) == 1 else None
        if task is not None:
            task.add(record)


_handler = _ToItsTask()


@contextlib.contextmanager
def captured(level: int, send: Callable[[str, dict], None] | None = None) -> Iterator[TaskLog]:
    """Collect the package's records of ``level`` and above emitted by the calling task (module docstring).

    The package logger's level is lowered to ``level`` meanwhile (a worker's root logger is at WARNING: the
    tasks' INFO lines were never made); records still reach the worker's own handlers as before. The handler also
    keeps Python's last-resort print of warnings on the worker's stderr off: on a local cluster, that stderr is
    the command's terminal, which would show each warning twice.
    """
    global _level_before
    task = TaskLog(level, send=send)
    package = logging.getLogger(PACKAGE)
    with _lock:
        if not _active:
            _level_before = package.level
            package.addHandler(_handler)
        _active.append(task)
        if package.getEffectiveLevel() > level:
            package.setLevel(level)
    token = _current.set(task)
    try:
        yield task
    finally:
        _current.reset(token)
        with _lock:
            _active.remove(task)
            if not _active:
                package.removeHandler(_handler)
                package.setLevel(_level_before)


def run_logged(fn: Callable[..., Any], level: int, *args: Any, live: tuple[str, str] | None = None) -> tuple[Any, dict]:
    """``fn(*args)`` on a Dask worker, and the log records it emitted (:meth:`TaskLog.carried`), for
    :func:`replay`; with ``live`` (:meth:`LiveLogs.for_task`), each record is also sent to the command as it is
    made. An exception of ``fn`` propagates; its records are then lost, unless sent live (they stay in the
    worker's log)."""
    worker = _worker()
    address = str(worker.address) if worker is not None else "this process"
    send = _sender(worker, address, live) if live is not None and worker is not None else None
    with captured(level, send) as task:
        value = fn(*args)
    return value, task.carried(address)


def _sender(worker: Any, address: str, live: tuple[str, str]) -> Callable[[str, dict], None]:
    """:attr:`TaskLog.send` of a task on ``worker``: an event on the command's topic (:class:`LiveLogs`)."""
    topic, name = live

    def send(attempt: str, item: dict) -> None:  # from any thread: the worker hands it to its event loop
        worker.log_event(topic, {"task": name, "worker": address, "attempt": attempt, "record": item})

    return send


def _worker() -> Any:
    """The Dask worker running the calling task, or None (called directly, not on a worker)."""
    try:
        from distributed import get_worker

        return get_worker()
    except (ImportError, ValueError):
        return None


class LiveLogs:
    """The command's side of the live records (module docstring): subscribes its client to a topic of its own,
    logs each record that arrives, with the task's name and worker, and remembers which it logged, so that
    :func:`replay` leaves them out of the task's outcome. Close it (:meth:`close`) when the tasks are done.

    Parameters
    ----------
    client : the command's ``distributed.Client``
    """

    def __init__(self, client: Any):
        self.client = client
        self.topic = TOPIC_PREFIX + uuid.uuid4().hex
        self._logged: set[tuple[str, int]] = set()
        self._lock = threading.Lock()  # events arrive on the client's event loop thread, outcomes on the command's
        client.subscribe_topic(self.topic, self._arrived)

    def for_task(self, name: str) -> tuple[str, str]:
        """``live`` of :func:`run_logged` for the task called ``name``."""
        return self.topic, name

    def first(self, attempt: str, seq: int) -> bool:
        """Whether record ``seq`` of task attempt ``attempt`` is not logged yet (it is counted as logged now)."""
        with self._lock:
            if (attempt, seq) in self._logged:
                return False
            self._logged.add((attempt, seq))
            return True

    def _arrived(self, event: tuple[float, dict]) -> None:
        _, msg = event
        item = msg["record"]
        if self.first(msg["attempt"], item["seq"]):
            _log_item(item, f"[{msg['task']} on {msg['worker']}]")

    def close(self) -> None:
        self.client.unsubscribe_topic(self.topic)


def replay(carried: dict, task: str, live: LiveLogs | None = None) -> None:
    """Log the records a task carried back (:func:`run_logged`) in this process, each prefixed with the task's
    name and worker, with its own time, level, logger and process id; then a line counting those left out.

    Parameters
    ----------
    carried : the second item :func:`run_logged` returned
    task : the task's name ("press_0003")
    live : the :class:`LiveLogs` the task sent its records to: those it logged already are left out
    """
    where = f"[{task} on {carried['worker']}]"
    for item in carried["records"]:
        if live is None or live.first(carried["attempt"], item["seq"]):
            _log_item(item, where)
    if carried["more"]:
        level = logging.WARNING if carried["more_warnings"] else logging.INFO
        log.log(
            level,
            "%s %d more log record(s) (%d warning(s)) not carried back (the first %d were): the worker's own log "
            "may hold them",
            where,
            carried["more"],
            carried["more_warnings"],
            MAX_RECORDS,
        )


def _log_item(item: dict, where: str) -> None:
    """Log one record of a task (:func:`_as_dict`) through this process's handlers, prefixed with ``where``."""
    logger = logging.getLogger(item["logger"])
    if not logger.isEnabledFor(item["level"]):  # DEBUG lines of a worker whose command was -v: not ours
        return
    extra = {key: item[key] for key in EXTRA_KEYS if key in item}
    record = logger.makeRecord(
        item["logger"], item["level"], "(dask worker)", 0, f"{where} {item['message']}", None, None, extra=extra
    )
    record.created, record.msecs = item["time"], (item["time"] - int(item["time"])) * 1000
    record.process, record.threadName = item["process"], item["thread"]
    record.exc_text = item.get("exc")
    setattr(record, REPLAYED, True)
    logger.handle(record)


_formatter = logging.Formatter()


def _as_dict(record: logging.LogRecord) -> dict:
    """A record as plain types: its message formatted here (its arguments may not travel), a traceback as text."""
    item = {
        "level": record.levelno,
        "logger": record.name,
        "message": record.getMessage(),
        "time": record.created,
        "process": record.process,
        "thread": record.threadName,
    }
    if record.exc_info:
        item["exc"] = _formatter.formatException(record.exc_info)
    elif record.exc_text:
        item["exc"] = record.exc_text
    for key in EXTRA_KEYS:
        if hasattr(record, key):
            item[key] = getattr(record, key)
    return item
