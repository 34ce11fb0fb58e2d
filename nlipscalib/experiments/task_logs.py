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

How many: a task carries back its first :data:`MAX_RECORDS` records and sends its first :data:`MAX_LIVE_RECORDS`
live, so a task that fails or whose worker is killed shows that many of its lines; past them, it sends a count
every :data:`LEFT_OUT_EVERY` records, and the command says how many it left out (a killed attempt's: at least that
many). Why the bound: a task looping over a warning, or a ``-v`` run's debug lines, must not flood the scheduler
and the command's log.

The topic: the command's client's own id (``Client.id``), which the scheduler drops by itself
``distributed.scheduler.events-cleanup-delay`` (1 h by default) after that client leaves; events carry a random
``run`` of this command's, which the command matches. Why: a lab's long-lived shared scheduler kept a topic of
each run's own name, up to ``distributed.admin.low-level-log-length`` (1000) events, until it restarted; no
client API drops a topic (the scheduler's ``Broker.truncate`` is not public).
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
MAX_LIVE_RECORDS = 1000
"""Records a task sends live at most (the first ones, :class:`LiveLogs`): a failed or killed task's lines shown.
At least :data:`MAX_RECORDS` (a killed attempt's carried records are lost with it).
A tiny experiment's press task logs 3 at INFO; 14 us and ~300 bytes a record on the worker (s27-dasklive)."""
LEFT_OUT_EVERY = 100
"""Past :data:`MAX_LIVE_RECORDS`, a task sends the count of the records it left out at the first and every this
many (what the command says of a killed attempt's: "at least")."""
PACKAGE = "nlipscalib"
"""The logger whose records (its children's included) a task carries back; the libraries' stay on the worker."""
REPLAYED = "nlipscalib_task_log"
"""Attribute marking a record this module logged for a task (:func:`_log_item`, the counts of those left out):
never a task's own. Why: a worker
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
    sent: int = 0
    """Records sent live (:attr:`send`), the first ones."""
    left_out: int = 0
    """Records neither carried back nor sent live."""
    left_out_warnings: int = 0
    """Of ``left_out``, those of level WARNING or above."""
    send: Callable[[str, dict], None] | None = None
    """Sends an event to the command as it is made (:class:`LiveLogs`): a kept record (``{"record": ...}``), or
    the count of those left out (``{"left_out": n, "warnings": k}``); None: records travel with the outcome only."""
    attempt: str = dataclasses.field(default_factory=lambda: uuid.uuid4().hex)
    """This run of the task (Dask re-runs a dead worker's task): with a record's number, what tells the command
    that the outcome carries a record it already logged live."""

    def add(self, record: logging.LogRecord) -> None:
        if record.levelno < self.level:
            return
        seq = len(self.records) + self.more
        warning = record.levelno >= logging.WARNING
        item = _as_dict(record) if seq < max(MAX_RECORDS, self._live_bound()) else None
        if item is not None:
            item["seq"] = seq
        if seq < MAX_RECORDS:
            self.records.append(item)
        else:
            self.more += 1
            self.more_warnings += warning
        if seq < self._live_bound() and self._sent({"record": item}):
            self.sent += 1
        elif seq >= MAX_RECORDS:
            self.left_out += 1
            self.left_out_warnings += warning
            if self.left_out % LEFT_OUT_EVERY == 1 or LEFT_OUT_EVERY == 1:
                self.send_left_out()

    def _live_bound(self) -> int:
        return MAX_LIVE_RECORDS if self.send is not None else 0

    def _sent(self, event: dict) -> bool:
        if self.send is None:
            return False
        try:
            self.send(self.attempt, event)
        except Exception:  # a worker closing: a carried record still travels with the outcome
            return False
        return True

    def send_left_out(self, ended: bool = False) -> None:
        """Send the count of the records left out so far (``ended``: the task raised, no outcome will say it)."""
        if self.left_out:
            self._sent({"left_out": self.left_out, "warnings": self.left_out_warnings, "ended": ended})

    def carried(self, worker: str) -> dict:
        """What travels back with the outcome (plain types: any serializer takes it)."""
        return {
            "worker": worker,
            "attempt": self.attempt,
            "records": self.records,
            "more": self.more,
            "more_warnings": self.more_warnings,
            "left_out": self.left_out,
            "left_out_warnings": self.left_out_warnings,
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


def run_logged(
    fn: Callable[..., Any], level: int, *args: Any, live: tuple[str, str, str] | None = None
) -> tuple[Any, dict]:
    """``fn(*args)`` on a Dask worker, and the log records it emitted (:meth:`TaskLog.carried`), for
    :func:`replay`; with ``live`` (:meth:`LiveLogs.for_task`), each record is also sent to the command as it is
    made. An exception of ``fn`` propagates; its records are then lost, unless sent live (the first
    :data:`MAX_LIVE_RECORDS`, and the count of the rest; all stay in the worker's log)."""
    worker = _worker()
    address = str(worker.address) if worker is not None else "this process"
    send = _sender(worker, address, live) if live is not None and worker is not None else None
    with captured(level, send) as task:
        try:
            value = fn(*args)
        except BaseException:
            task.send_left_out(ended=True)
            raise
    return value, task.carried(address)


def _sender(worker: Any, address: str, live: tuple[str, str, str]) -> Callable[[str, dict], None]:
    """:attr:`TaskLog.send` of a task on ``worker``: an event on the command's topic (:class:`LiveLogs`)."""
    topic, run, name = live

    def send(attempt: str, event: dict) -> None:  # from any thread: the worker hands it to its event loop
        worker.log_event(topic, {"run": run, "task": name, "worker": address, "attempt": attempt, **event})

    return send


def _worker() -> Any:
    """The Dask worker running the calling task, or None (called directly, not on a worker)."""
    try:
        from distributed import get_worker

        return get_worker()
    except (ImportError, ValueError):
        return None


@dataclasses.dataclass
class _Attempt:
    """What the command knows of a task attempt's records left out (:class:`LiveLogs`)."""

    where: str
    """"[press_0003 on tcp://10.0.0.5:40123]"."""
    left_out: int = 0
    warnings: int = 0
    told: bool = False
    """Whether the final count was logged (the outcome or the task's end said it)."""


class LiveLogs:
    """The command's side of the live records (module docstring): subscribes its client to its own topic, logs
    each record of this command's tasks that arrives, with the task's name and worker, and remembers which it
    logged, so that :func:`replay` leaves them out of the task's outcome. Close it (:meth:`close`) when the tasks
    are done: it then counts the records left out by attempts that never brought an outcome (a killed worker's).
    One at a time per client (a client has one handler per topic).

    Parameters
    ----------
    client : the command's ``distributed.Client``
    """

    def __init__(self, client: Any):
        self.client = client
        self.topic = str(client.id)
        self.run = uuid.uuid4().hex
        self._logged: set[tuple[str, int]] = set()
        self._attempts: dict[str, _Attempt] = {}
        self._lock = threading.Lock()  # events arrive on the client's event loop thread, outcomes on the command's
        client.subscribe_topic(self.topic, self._arrived)

    def for_task(self, name: str) -> tuple[str, str, str]:
        """``live`` of :func:`run_logged` for the task called ``name``."""
        return self.topic, self.run, name

    def first(self, attempt: str, seq: int) -> bool:
        """Whether record ``seq`` of task attempt ``attempt`` is not logged yet (it is counted as logged now)."""
        with self._lock:
            if (attempt, seq) in self._logged:
                return False
            self._logged.add((attempt, seq))
            return True

    def _arrived(self, event: tuple[float, Any]) -> None:
        _, msg = event
        if not isinstance(msg, dict) or msg.get("run") != self.run:  # the scheduler's own events on the client's id
            return
        where = f"[{msg['task']} on {msg['worker']}]"
        if "record" in msg:
            if self.first(msg["attempt"], msg["record"]["seq"]):
                _log_item(msg["record"], where)
            return
        with self._lock:
            attempt = self._attempts.setdefault(msg["attempt"], _Attempt(where))
            first_count = attempt.left_out == 0
            attempt.left_out, attempt.warnings = msg["left_out"], msg["warnings"]
            ended, attempt.told = msg["ended"] and not attempt.told, attempt.told or msg["ended"]
        if ended:  # the task raised: no outcome will count them
            _log_left_out(where, attempt.left_out, attempt.warnings)
        elif first_count:
            log.info(
                "%s logs more than %d records: the rest are counted, not shown",
                where,
                MAX_LIVE_RECORDS,
                extra={REPLAYED: True},  # a worker in this process must not take it for its task's
            )

    def told(self, attempt: str) -> None:
        """The outcome of ``attempt`` counted its records left out (:func:`replay`)."""
        with self._lock:
            self._attempts.setdefault(attempt, _Attempt("")).told = True

    def close(self) -> None:
        self.client.unsubscribe_topic(self.topic)
        with self._lock:
            untold = [a for a in self._attempts.values() if not a.told]
        for attempt in untold:
            _log_left_out(attempt.where, attempt.left_out, attempt.warnings, without_outcome=True)


def replay(carried: dict, task: str, live: LiveLogs | None = None) -> None:
    """Log the records a task carried back (:func:`run_logged`) in this process, each prefixed with the task's
    name and worker, with its own time, level, logger and process id; then a line counting those left out
    (neither carried back nor, with ``live``, sent live).

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
    if live is not None:
        live.told(carried["attempt"])
    _log_left_out(where, carried["left_out"], carried["left_out_warnings"])


def _log_left_out(where: str, left_out: int, warnings: int, without_outcome: bool = False) -> None:
    """The line counting a task attempt's records the command did not log (none: no line)."""
    if not left_out:
        return
    log.log(
        logging.WARNING if warnings or without_outcome else logging.INFO,
        "%s %s%d more log record(s) (%d warning(s)) left out%s: the worker's own log may hold them",
        where,
        "at least " if without_outcome else "",
        left_out,
        warnings,
        " by an attempt that ended without an outcome (its worker died?)" if without_outcome else "",
        extra={REPLAYED: True},
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
