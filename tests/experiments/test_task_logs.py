"""A Dask task's log records travel back with its outcome and are logged in the command, once, with the task's
name and worker (experiments/task_logs.py): a remote scheduler's workers' warnings never reached the user."""

from __future__ import annotations

import logging
import os
import signal
import threading
import time
import uuid

import pytest

from nlipscalib.experiments import task_logs
from nlipscalib.solver import threads as solver_threads

distributed = pytest.importorskip("distributed")

DARK = "LED 7: image dark (mean 3.1 of 255)"
_both_running = threading.Barrier(2, timeout=60)
"""Lets two tasks of one in-process worker log only once both run (their records would mix if any did)."""


def _warn_dark() -> str:
    logging.getLogger("nlipscalib.sim.render").warning(DARK)
    logging.getLogger("nlipscalib.solver").debug("below the command's level: not carried")
    return "done"


def _log_from_own_threads(name: str) -> list[str]:
    """A task logging in its thread, in the solver's pool (a copy of its context) and in a thread it starts
    without its context, while another task does the same on the same worker."""
    log = logging.getLogger("nlipscalib.solver")
    _both_running.wait()
    log.warning("%s: in its thread", name)
    solver_threads.map_items(lambda part: log.warning("%s: pool part %d", name, part), range(4))
    plain = threading.Thread(target=log.warning, args=("%s: a plain thread", name))
    plain.start()
    plain.join()
    _both_running.wait()  # neither has ended before the other's plain thread logged
    return [thread.name for thread in threading.enumerate()]


SEEN_WAIT_S = 60.0
"""How long a task waits for the test to see its line in this process's log (a loaded machine's worker is slow)."""


def _warn_until_seen(seen: str, message: str) -> bool:
    """Log ``message`` and wait until the test has seen it in the command's log (``seen``: a Dask Event's name):
    True when it did while the task still ran."""
    logging.getLogger("nlipscalib.sim.render").warning(message)
    return distributed.Event(seen).wait(SEEN_WAIT_S)


KILLED_LINES = task_logs.MAX_RECORDS + 50
"""Lines the killed attempt logs: more than a task carries back (those past the 100th were lost, s27-dasklive)."""


def _killed_mid_task(seen: str, first_attempt: str) -> str:
    """The first attempt logs :data:`KILLED_LINES` lines and, once the test saw the last (or the wait is over),
    dies as the kernel's OOM killer ends a process: SIGKILL, no clean-up. Dask runs the task again on the
    restarted worker."""
    log = logging.getLogger("nlipscalib.sim.render")
    if not os.path.exists(first_attempt):
        open(first_attempt, "w", encoding="utf-8").close()
        for part in range(KILLED_LINES):
            log.warning("LED 3: rendering part %d", part)
        distributed.Event(seen).wait(SEEN_WAIT_S)
        os.kill(os.getpid(), signal.SIGKILL)
    log.warning("the second attempt")
    return "done"


def _wait_for_line(caplog: pytest.LogCaptureFixture, text: str) -> bool:
    deadline = time.monotonic() + SEEN_WAIT_S
    while time.monotonic() < deadline:
        if any(text in r.getMessage() for r in list(caplog.records)):
            return True
        time.sleep(0.05)
    return False


def _lines_with(caplog: pytest.LogCaptureFixture, text: str) -> list[str]:
    return [r.getMessage() for r in caplog.records if text in r.getMessage()]


def _messages(carried: dict) -> list[str]:
    return [item["message"] for item in carried["records"]]


def test_a_task_warning_reaches_the_command_once_with_the_task_and_worker(caplog, capfd):
    """A worker process of the command's local cluster (as ``--scheduler local:1``): the warning comes once, from
    the command's logging, with the worker's time and process id; the worker's stderr (the terminal) shows none."""
    from nlipscalib.experiments.runner import _backend

    caplog.set_level(logging.INFO)
    backend = _backend("local:1", 1)
    with backend:
        outcome, carried = backend.client.submit(task_logs.run_logged, _warn_dark, logging.INFO).result()
        task_logs.replay(carried, "press_0003")
    assert outcome == "done"
    dark = [r for r in caplog.records if DARK in r.getMessage()]
    assert len(dark) == 1, [r.getMessage() for r in caplog.records]
    (record,) = dark
    assert record.getMessage() == f"[press_0003 on {carried['worker']}] {DARK}"
    assert carried["worker"].startswith("tcp://")
    assert record.levelno == logging.WARNING and record.name == "nlipscalib.sim.render"
    assert record.process != os.getpid()  # the worker's, as the --log-file line shows it
    assert not [r for r in caplog.records if "not carried" in r.getMessage()]  # DEBUG: below the level asked
    assert DARK not in capfd.readouterr().err  # no last-resort print on the worker's stderr


def test_two_tasks_on_one_worker_at_once_keep_their_own_records_the_solver_pools_included():
    """Two tasks on two threads of one worker, logging at the same time: each carries back its own records, those
    its solver pool threads logged included; a thread started without the task's context belongs to neither
    (module docstring), but to the only task when it runs alone."""
    before = solver_threads.workers()
    solver_threads.set_workers(2)
    try:
        with (
            distributed.LocalCluster(
                n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None
            ) as cluster,
            distributed.Client(cluster) as client,
        ):
            futures = [client.submit(task_logs.run_logged, _log_from_own_threads, logging.INFO, n) for n in "ab"]
            results = client.gather(futures)
            alone = client.submit(task_logs.run_logged, _log_from_own_threads, logging.INFO, "c", pure=False)
            # the other party of its barrier's two waits, not a task
            helper = threading.Thread(target=lambda: [_both_running.wait() for _ in range(2)])
            helper.start()
            _, lone = alone.result()
            helper.join()
    finally:
        solver_threads.set_workers(before)
    for name, (thread_names, carried) in zip("ab", results):
        assert any(t.startswith("nlips-pool") for t in thread_names)  # the parts ran on the solver's pool
        assert sorted(_messages(carried)) == sorted(
            [f"{name}: in its thread"] + [f"{name}: pool part {p}" for p in range(4)]
        )
    assert "c: a plain thread" in _messages(lone)


def test_a_task_carries_the_first_records_and_counts_the_rest(caplog):
    caplog.set_level(logging.INFO)
    level = logging.getLogger("nlipscalib").level
    log = logging.getLogger("nlipscalib.sim.render")
    _, carried = task_logs.run_logged(lambda: [log.warning("LED %d dark", i) for i in range(130)], logging.INFO)
    assert _messages(carried) == [f"LED {i} dark" for i in range(task_logs.MAX_RECORDS)]
    assert carried["more"] == carried["more_warnings"] == 130 - task_logs.MAX_RECORDS
    task_logs.replay(carried, "press_0001")
    lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("[press_0001 on this process]")]
    assert len(lines) == task_logs.MAX_RECORDS + 1
    assert "30 more log record(s) (30 warning(s)) left out" in lines[-1]
    assert logging.getLogger("nlipscalib").level == level  # lowered for the task only


def test_the_runner_logs_a_dask_tasks_warning_before_its_outcome(tmp_path, monkeypatch, caplog):
    """The runner's path: ``_execute_on_dask_worker`` carries the records, ``_dask`` logs them, prefixed with the
    task's id, before the task's own outcome line (one Dask worker thread in this process, for the stand-in)."""
    from nlipscalib.experiments import runner
    from nlipscalib.experiments import tasks as tasks_mod
    from nlipscalib.experiments.tasks import Task

    def reference(task, out, threads, keep):
        logging.getLogger("nlipscalib.sim.render").warning(DARK)
        raise ValueError("a broken scene")

    monkeypatch.setattr(tasks_mod, "_run_reference", reference)
    caplog.set_level(logging.INFO)
    backend = runner._backend(None, 1)
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
    backend.client, backend.cluster_workers = distributed.Client(cluster), 1
    status, solver_workers = runner.RunStatus(), solver_threads.workers()
    try:
        task = Task(kind="reference", id="ref-0", scene={})
        backend._dask([task], tmp_path, False, status, runner._bar(1, 0, False, ""))
    finally:
        backend.client.close()
        cluster.close()
        solver_threads.set_workers(solver_workers)  # the worker, this process, set its share
    lines = [r.getMessage() for r in caplog.records]
    replayed = [i for i, line in enumerate(lines) if line.startswith("[ref-0 on ") and line.endswith(DARK)]
    failed = [i for i, line in enumerate(lines) if line.startswith("ref-0: failed: ValueError: a broken scene")]
    assert len(replayed) == 1 and len(failed) == 1 and replayed[0] < failed[0], lines


def test_a_tasks_warning_reaches_the_command_while_it_runs_and_once(caplog):
    """A worker process's warning is in the command's log before its task ends (the task waits for the test to
    see it), and the task's outcome, which carries it too, does not log it again."""
    from nlipscalib.experiments.runner import _backend

    caplog.set_level(logging.INFO)
    seen = f"seen-{uuid.uuid4().hex}"
    backend = _backend("local:1", 1)
    with backend:
        client = backend.client
        live = task_logs.LiveLogs(client)
        future = client.submit(
            task_logs.run_logged, _warn_until_seen, logging.INFO, seen, DARK, live=live.for_task("press_0003")
        )
        arrived = _wait_for_line(caplog, DARK)
        distributed.Event(seen, client=client).set()
        while_running, carried = future.result()
        task_logs.replay(carried, "press_0003", live)
        live.close()
    assert arrived and while_running
    assert _lines_with(caplog, DARK) == [f"[press_0003 on {carried['worker']}] {DARK}"]
    assert _messages(carried) == [DARK]  # carried too: a worker that cannot send them live still brings them


def test_a_killed_workers_last_lines_are_in_the_commands_log(caplog, tmp_path):
    """The worker dies (SIGKILL) mid-task: the lines it logged before, past the 100 a task carries back
    included, are in the command's log, once each; the task's second attempt, on the restarted worker, logs its
    own line once (live and carried back)."""
    from nlipscalib.experiments.runner import _backend

    caplog.set_level(logging.INFO)
    seen = f"seen-{uuid.uuid4().hex}"
    backend = _backend("local:1", 1)
    with backend:
        client = backend.client
        live = task_logs.LiveLogs(client)
        future = client.submit(
            task_logs.run_logged,
            _killed_mid_task,
            logging.INFO,
            seen,
            str(tmp_path / "first-attempt"),
            live=live.for_task("press_0004"),
            pure=False,
        )
        arrived = _wait_for_line(caplog, f"LED 3: rendering part {KILLED_LINES - 1}")
        distributed.Event(seen, client=client).set()
        outcome, carried = future.result()
        task_logs.replay(carried, "press_0004", live)
        live.close()
    assert arrived and outcome == "done"
    killed = _lines_with(caplog, "LED 3: rendering")
    assert [line.split("] ", 1)[1] for line in killed] == [f"LED 3: rendering part {p}" for p in range(KILLED_LINES)]
    assert all(line.startswith("[press_0004 on tcp://") for line in killed)
    assert not _lines_with(caplog, "left out")  # none was: the bound of the lines sent live is far
    assert _lines_with(caplog, "the second attempt") == [f"[press_0004 on {carried['worker']}] the second attempt"]
    assert _messages(carried) == ["the second attempt"]  # the killed attempt's line came live only


def _many_then_raise(lines: int) -> None:
    log = logging.getLogger("nlipscalib.sim.render")
    for i in range(lines):
        log.warning("LED %d dark", i)
    raise RuntimeError("out of memory")


def test_a_failed_task_shows_its_lines_up_to_the_live_bound_and_counts_the_rest(caplog, monkeypatch):
    """A task that raises brings no outcome: its lines come live only, past the 100 it would carry back, up to
    :data:`task_logs.MAX_LIVE_RECORDS`; then one line counts the rest (a worker in this process, for the bounds)."""
    monkeypatch.setattr(task_logs, "MAX_LIVE_RECORDS", 120)
    monkeypatch.setattr(task_logs, "LEFT_OUT_EVERY", 10)
    caplog.set_level(logging.INFO)
    with (
        distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as c,
        distributed.Client(c) as client,
    ):
        live = task_logs.LiveLogs(client)
        future = client.submit(
            task_logs.run_logged, _many_then_raise, logging.INFO, 150, live=live.for_task("press_0005")
        )
        with pytest.raises(RuntimeError, match="out of memory"):
            future.result()
        counted = _wait_for_line(caplog, "left out")
        live.close()
    assert counted
    shown = [line for line in _lines_with(caplog, "[press_0005 on ") if " dark" in line]
    assert [line.split("] ", 1)[1] for line in shown] == [f"LED {i} dark" for i in range(120)]
    (left_out,) = _lines_with(caplog, "left out")
    assert "] 30 more log record(s) (30 warning(s)) left out: " in left_out
    assert len(_lines_with(caplog, "more than 120 records")) == 1  # said once, as the first was left out


class _StandInClient:
    """What :class:`task_logs.LiveLogs` asks of a Dask client, for an attempt that never brings an outcome."""

    id = "Client-stand-in"

    def subscribe_topic(self, topic, handler):
        self.handler = handler

    def unsubscribe_topic(self, topic):
        self.handler = None


def test_an_attempt_without_an_outcome_past_the_live_bound_is_said_to_have_left_lines_out(caplog, monkeypatch):
    """A killed attempt's records past the live bound: the command's close says at least how many (the count
    the attempt last sent), as a warning; an attempt whose outcome came says nothing more at close."""
    monkeypatch.setattr(task_logs, "MAX_RECORDS", 3)
    monkeypatch.setattr(task_logs, "MAX_LIVE_RECORDS", 5)
    monkeypatch.setattr(task_logs, "LEFT_OUT_EVERY", 10)
    caplog.set_level(logging.INFO)
    client = _StandInClient()
    live = task_logs.LiveLogs(client)
    topic, run, name = live.for_task("press_0006")

    def send(attempt, event):
        client.handler((time.time(), {"run": run, "task": name, "worker": "tcp://w:1", "attempt": attempt, **event}))

    client.handler((time.time(), {"action": "add-client", "client": client.id}))  # the scheduler's own: ignored
    log = logging.getLogger("nlipscalib.sim.render")
    with task_logs.captured(logging.INFO, send):  # the killed attempt: 27 lines, no outcome
        for i in range(27):
            log.warning("LED %d dark", i)
    with task_logs.captured(logging.INFO, send) as done:  # the next attempt, whose outcome comes
        for i in range(4):
            log.info("part %d", i)
    task_logs.replay(done.carried("tcp://w:2"), name, live)
    live.close()
    lines = _lines_with(caplog, "[press_0006 on tcp://w:")
    assert len([line for line in lines if " dark" in line]) == 5
    assert len([line for line in lines if "] part " in line]) == 4  # each once: live and carried back
    (at_close,) = [r for r in caplog.records if "without an outcome" in r.getMessage()]
    assert at_close.levelno == logging.WARNING
    assert "[press_0006 on tcp://w:1] at least 21 more log record(s) (21 warning(s)) left out" in at_close.getMessage()
    assert len(_lines_with(caplog, "left out")) == 1


def test_a_shared_scheduler_drops_a_finished_runs_task_lines(monkeypatch):
    """Two runs (two clients, as two ``nlips experiment --scheduler tcp://...``) on one long-lived scheduler: once
    each has left, the scheduler holds none of their tasks' records (after ``events-cleanup-delay``, an hour by
    default; here 0.2 s). A run's own topic kept up to 1000 events until the scheduler restarted."""
    import dask

    def holding_records(client) -> dict:
        return {
            topic: len(events)
            for topic, events in client.get_events().items()
            if any(isinstance(msg, dict) and "record" in msg for _, msg in events)
        }

    with (
        dask.config.set({"distributed.scheduler.events-cleanup-delay": "200ms"}),
        distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as c,
    ):
        held_while_running = []
        for run in range(2):
            with distributed.Client(c) as client:
                live = task_logs.LiveLogs(client)
                future = client.submit(task_logs.run_logged, _warn_dark, logging.INFO, live=live.for_task(f"r{run}"))
                _, carried = future.result()
                task_logs.replay(carried, f"r{run}", live)
                held_while_running.append(sum(holding_records(client).values()))
                live.close()
        with distributed.Client(c) as observer:
            deadline = time.monotonic() + SEEN_WAIT_S
            while holding_records(observer) and time.monotonic() < deadline:
                time.sleep(0.1)
            left = holding_records(observer)
    assert held_while_running[0] >= 1  # the record did go through the scheduler
    assert left == {}
