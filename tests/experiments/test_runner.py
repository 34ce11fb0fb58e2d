"""The local runner as a user meets it: Ctrl-C of ``nlips experiment --workers 2`` in a terminal."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.processes import as_from_a_terminal, kill_when_it_says

COMMAND = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
TINY = """
counts = [12]
[twin]
width = 40
height = 30
spp = 2
bounces = 0
[presses]
indenters = [{ kind = "sphere", size = 6.0 }]
polar_deg = [10.0, 20.0]
azimuth_deg = [30.0]
"""
"""One reference (run in the command's process) and two presses (the two worker processes)."""


def _nlips(*args: str, **kw) -> subprocess.Popen:
    argv = [sys.executable, "-c", COMMAND, "--no-progress", "experiment", *args]
    # as a shell with job control starts it: Ctrl-C not ignored, the command its own process group
    return as_from_a_terminal(argv, start_new_session=True, **kw)


def _not_log(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.strip() and not line.startswith(("INFO ", "WARNING "))]


def test_ctrl_c_with_worker_processes_is_one_line_and_a_rerun_resumes(tmp_path):
    """A terminal sends Ctrl-C to every process of the command. The worker processes used to die of it each
    with a multiprocessing traceback of their own (KeyboardInterrupt inside a render) after the parent's line."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    out = tmp_path / "out"
    args = ("ablation", "--config", str(config), "--workers", "2", "--out", str(out))
    tasks = out / "ablation-custom" / "tasks"
    proc, err = _interrupted_once_held(args, tasks, presses=1, timeout=120)  # a worker renders or solves a press
    assert proc.returncode == 130, err
    assert _not_log(err) == ["nlips experiment: interrupted; finished work is kept, run again to resume"], err
    left = [p for p in Path(out).rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
    assert not left, left

    again = _nlips(*args)
    stdout, err = again.communicate(timeout=300)
    assert again.returncode == 0, err
    assert stdout == f"{out / 'ablation-custom' / 'report'}\n", stdout  # the report's folder alone
    assert "3 tasks" in err and "0 failed" in err, err  # how the run went, on stderr
    assert len(list(tasks.glob("*.json"))) == 3


def _interrupted_once_held(args: tuple, tasks: Path, presses: int, timeout: float):
    """Run ``nlips ARGS``, Ctrl-C its process group once its workers hold ``presses`` presses' claims in ``tasks``;
    (process, stderr)."""
    proc = _nlips(*args)
    try:
        deadline = time.monotonic() + timeout
        while len(list(tasks.glob(".claim-sphere*"))) < presses and proc.poll() is None:
            assert time.monotonic() < deadline, f"no worker held {presses} press(es) within {timeout} s"
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before its workers took the presses"
        os.killpg(proc.pid, signal.SIGINT)
        _, err = proc.communicate(timeout=timeout)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    return proc, err


def test_ctrl_c_with_a_dask_local_cluster_leaves_no_claim(tmp_path):
    """Ctrl-C of `nlips experiment --scheduler local:2` while both workers held a press: closing the LocalCluster
    kills its busy workers (SIGKILL after Dask's grace, mid-render), and each left its task's claim behind until
    the next run. Now the command removes them on its way out; its workers no longer warn of the cancelled tasks."""
    pytest.importorskip("distributed")
    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    out = tmp_path / "out"
    tasks = out / "ablation-custom" / "tasks"
    args = ("ablation", "--config", str(config), "--scheduler", "local:2", "--out", str(out))
    proc, err = _interrupted_once_held(args, tasks, presses=2, timeout=180)  # both workers hold a press
    assert proc.returncode == 130, err
    # the one line: Ctrl-C no longer reaches a worker process (it could print a traceback of its own before it)
    assert _not_log(err) == ["nlips experiment: interrupted; finished work is kept, run again to resume"], err
    assert "ended with CancelledError" not in err, err  # Dask's workers' warnings, in a format of their own
    assert "Scheduler was unaware of this worker" not in err, err
    left = [p for p in Path(out).rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
    assert not left, left


HANG_GUARD_S = 60.0
"""Seconds after Ctrl-C before a test calls the command hung: a guard, not the claim (the run ends ~0.2 s after it,
~1.2 s under load, when its workers end on their SIGTERM or are killed
:data:`~nlipscalib.core.processes.LOCAL_WORKER_GRACE_S` after it)."""

TRACED_SIGTERM = """
import os

from nlipscalib.core import processes

_ends = processes._worker_terminated


def _traced(signum, frame):  # marks the process that got SIGTERM, then ends it as before (unless deaf)
    open(os.path.join(os.environ["SIGTERM_TRACED"], str(os.getpid())), "w").close()
    if not os.environ.get("SIGTERM_DEAF"):
        _ends(signum, frame)


processes._worker_terminated = _traced  # what worker_signals() installs
"""
"""Appended to the endless renders' ``sitecustomize``: each worker's SIGTERM handler marks its pid in
``$SIGTERM_TRACED``; with ``$SIGTERM_DEAF`` set it does nothing else, as when a worker's main thread does not get to
run it (seen under load: the worker then has to be killed)."""

PATIENT_NANNY = """
from distributed import nanny

_kill = nanny.WorkerProcess.kill


async def _patient(self, timeout=5, executor_wait=True, reason="workerprocess-kill"):
    return await _kill(self, timeout=3600, executor_wait=executor_wait, reason=reason)


def dask_setup(this_nanny):
    nanny.WorkerProcess.kill = _patient
"""
"""A Dask nanny preload (``distributed.nanny.preload``): closing a nanny asks its worker to close and kills it only an
hour later, not 0.8 x 5 s later. A busy worker then ends in time only by what the command itself does."""


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process table from /proc")
@pytest.mark.parametrize("deaf", [False, True], ids=["handler-runs", "handler-never-runs"])
def test_ctrl_c_with_a_dask_local_cluster_ends_its_busy_workers_at_once(tmp_path, deaf):
    """Ctrl-C of `nlips experiment --scheduler local:2` while a worker renders (here without end): closing the
    cluster asked the worker to close, which waited for its task until the nanny's grace ran out and it killed the
    worker (~4 s). Now the command ends its workers with SIGTERM first (each releases its claim): its one line,
    nothing left. A worker that does not answer its SIGTERM (under load one did not for seconds) is killed by the
    command soon after, its claim removed by the command.

    No clock: the render never ends and the nannies here wait an hour before they kill a worker
    (:data:`PATIENT_NANNY`), so a run that ends at all was ended by the command's SIGTERM (and, for a deaf worker, by
    its kill); the workers' handlers that run mark that they got it (:data:`TRACED_SIGTERM`)."""
    pytest.importorskip("distributed")
    pytest.importorskip("mitsuba")
    from tests.cli.test_interrupt import _wait_until_gone
    from tests.processes import endless_renders

    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    out = tmp_path / "out"
    env, traced = endless_renders(dict(os.environ), tmp_path)
    with (tmp_path / "endless" / "sitecustomize.py").open("a") as patch:
        patch.write(TRACED_SIGTERM)
    (tmp_path / "patient_nanny.py").write_text(PATIENT_NANNY, encoding="utf-8")
    sigtermed = tmp_path / "sigtermed"
    sigtermed.mkdir()
    env.update(
        SIGTERM_TRACED=str(sigtermed), DASK_DISTRIBUTED__NANNY__PRELOAD=repr([str(tmp_path / "patient_nanny.py")])
    )
    if deaf:
        env["SIGTERM_DEAF"] = "1"
    proc = _nlips("ablation", "--config", str(config), "--scheduler", "local:2", "--out", str(out), env=env)
    try:
        deadline = time.monotonic() + 300
        while not any(traced.iterdir()) and proc.poll() is None:  # a worker renders the reference
            assert time.monotonic() < deadline, "no render within 300 s"
            time.sleep(0.05)
        time.sleep(1.0)
        assert proc.poll() is None, proc.communicate()[1]
        os.killpg(proc.pid, signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=HANG_GUARD_S)
        except subprocess.TimeoutExpired:
            pytest.fail(f"still running {HANG_GUARD_S:g} s after Ctrl-C: its busy worker was left to its nanny")
        assert _wait_until_gone(proc.pid, HANG_GUARD_S) == []  # no worker left, none started anew
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, err
    # the command's SIGTERM reached its workers: the idle one's handler marks it. A busy worker's handler may not run
    # before the command kills it (in about a third of the runs on an idle 2-core machine too): that is the deaf
    # variant's path, so its mark is not required; its end within the guard, with its nanny waiting an hour, is
    assert list(sigtermed.iterdir()), "no worker of the cluster got the command's SIGTERM"
    assert _not_log(err) == ["nlips experiment: interrupted; finished work is kept, run again to resume"], err
    left = [p for p in Path(out).rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
    assert not left, left


def test_kill_unless_ended_kills_only_the_processes_that_outlive_their_sigterm():
    """The backstop of a local cluster's Ctrl-C: a process that ends on its SIGTERM is left to it; one that does
    not (its handler not run) is killed once the grace is over, not waited for (it would sleep for an hour)."""
    import threading

    from nlipscalib.core.processes import kill_unless_ended

    code = "import signal, sys, time; signal.signal(signal.SIGTERM, {}); print('ready', flush=True); time.sleep(3600)"
    deaf, obeys = (
        subprocess.Popen([sys.executable, "-c", code.format(handler)], stdout=subprocess.PIPE, text=True)
        for handler in ("signal.SIG_IGN", "signal.SIG_DFL")
    )
    try:
        for proc in (deaf, obeys):
            assert proc.stdout.readline().strip() == "ready"
            os.kill(proc.pid, signal.SIGTERM)
        start = time.monotonic()
        # on a thread, so that a call waiting for the deaf process's own end fails the test instead of hanging it
        call = threading.Thread(target=kill_unless_ended, args=([deaf.pid, obeys.pid], 2.0), daemon=True)
        call.start()
        call.join(HANG_GUARD_S)
        assert not call.is_alive(), f"still waiting {HANG_GUARD_S:g} s later for a process deaf to SIGTERM"
        assert time.monotonic() - start >= 2.0  # the grace given first (a lower bound: load only lengthens it)
        assert deaf.wait(timeout=HANG_GUARD_S) == -signal.SIGKILL
        assert obeys.wait(timeout=HANG_GUARD_S) == -signal.SIGTERM  # ended of its SIGTERM within the 2 s grace
    finally:
        for proc in (deaf, obeys):
            proc.kill()
            proc.wait()
            proc.stdout.close()


def test_kill_unless_ended_works_without_sigkill(monkeypatch):
    """Windows has no ``signal.SIGKILL``: the backstop raised AttributeError on the way out of a stopped
    ``nlips experiment`` instead of ending a worker that outlived its grace (s26-portable)."""
    from nlipscalib.core.processes import kill_unless_ended

    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(3600)"])
    try:
        with monkeypatch.context() as patch:  # Popen.kill below needs it back
            patch.delattr(signal, "SIGKILL")
            kill_unless_ended([sleeper.pid], 0.0)
        assert sleeper.wait(timeout=HANG_GUARD_S) == -signal.SIGTERM  # what ends a process there
    finally:
        sleeper.kill()
        sleeper.wait()


def _worker_signals_state() -> tuple[bool, bool]:
    """(Ctrl-C can reach this process, SIGTERM has a handler of its own): run in a Dask worker's main thread."""
    import signal

    blocked = signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])
    reachable = not blocked and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN
    return reachable, callable(signal.getsignal(signal.SIGTERM))


def test_a_local_clusters_workers_leave_ctrl_c_to_the_command_and_release_their_claims_on_sigterm():
    """A terminal's Ctrl-C reached `--scheduler local:2`'s worker processes too, which could die of it mid-task with
    a traceback of their own; and SIGTERM, which the terminated command sends its workers, killed them at once with
    their claims left. Now Ctrl-C is blocked from before they start, and SIGTERM releases a worker's claims first
    (pipeline.workers._worker_signals, as the local workers do)."""
    pytest.importorskip("distributed")
    from nlipscalib.experiments.runner import _backend

    backend = _backend("local:1", 1)
    with backend:
        states = backend.client.run(_worker_signals_state)
    assert list(states.values()) == [(False, True)], states


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process table from /proc")
@pytest.mark.parametrize("group", [True, False], ids=["kill-group", "kill-pid"])
def test_sigterm_with_a_dask_local_cluster_is_one_line_and_leaves_no_claim(tmp_path, group):
    """SIGTERM of `nlips experiment --scheduler local:2` while both workers held a press: the command terminated its
    worker processes, each died with its claim left for the next run, and the cluster's nannies started new ones,
    which failed with a traceback each once the command was gone. Now each worker releases its claim and the
    nannies start none: the one line, exit 143, nothing left."""
    pytest.importorskip("distributed")
    from tests.cli.test_interrupt import _wait_until_gone

    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    out = tmp_path / "out"
    tasks = out / "ablation-custom" / "tasks"
    proc = _nlips("ablation", "--config", str(config), "--scheduler", "local:2", "--out", str(out))
    try:
        deadline = time.monotonic() + 180
        while len(list(tasks.glob(".claim-sphere*"))) < 2 and proc.poll() is None:
            assert time.monotonic() < deadline, "no two workers held a press within 180 s"
            time.sleep(0.05)
        assert proc.poll() is None, "the run ended before its workers took the presses"
        (os.killpg if group else os.kill)(proc.pid, signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
        assert _wait_until_gone(proc.pid, 30) == []  # no worker left, none started anew
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, err
    # nothing after it: the resource tracker's "1 leaked semaphore objects" (4 lines) came in 2 runs in 4 under
    # load (tests/cli/test_interrupt.py, test_a_terminated_command_frees_its_semaphores_before_its_workers_end)
    assert _not_log(err) == ["nlips experiment: terminated; finished work is kept, run again to resume"], err
    assert "Restarting worker" not in err, err
    left = [p for p in Path(out).rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
    assert not left, left


def test_sigterm_without_a_dask_cluster_imports_no_dask():
    """SIGTERM of `nlips experiment --workers 2` (or of a run with a remote scheduler) imported dask.distributed in
    its handler, to mark a local cluster's nannies that it did not have: ~0.8 s idle, 2.5 s under load, before its
    worker processes were even signalled (`kill PID` took 2.8 s where Ctrl-C took 0.24 s)."""
    code = (
        "import sys; from nlipscalib.experiments import runner; runner.stop_restarting_workers(); "
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('distributed', 'dask')))"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"


def test_a_dask_local_cluster_run_prints_none_of_distributeds_info_lines(tmp_path):
    """`--scheduler local:2` printed ~40 INFO lines of distributed's own (its start and stop, "dashboard at:
    http://127.0.0.1:8787/status"); -v shows them."""
    pytest.importorskip("distributed")
    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    log_file = tmp_path / "log.txt"
    args = ("ablation", "--config", str(config), "--scheduler", "local:2", "--out", str(tmp_path / "out"))
    proc = _nlips(*args, "--log-file", str(log_file))
    stdout, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    assert "3 tasks (3 run now, 0 reused), 0 failed" in err and stdout.endswith("report\n")  # how it went: stderr
    assert not [line for line in err.splitlines() if line.startswith("INFO ")], err
    assert "dashboard" not in err and "8787" not in err, err
    # the presses' lines, logged in the workers, come back with their tasks (task_logs) into the --log-file
    solved = [line for line in log_file.read_text(encoding="utf-8").splitlines() if "pixels reconstructed" in line]
    assert len(solved) == 2 and all(" on tcp://127.0.0.1:" in line for line in solved), solved


def test_a_local_cluster_serves_no_dashboard_and_no_fixed_port_and_leaves_distributeds_log_levels():
    """dashboard_address=None keeps the dashboard off, but the scheduler still served its HTTP pages on 8787 (all
    runs at once on one port: "Port 8787 is already in use"); now on a free port of the loopback only."""
    import logging

    pytest.importorskip("distributed")
    from nlipscalib.experiments.runner import _backend

    before = logging.getLogger("distributed").level
    backend = _backend("local:1", 1)
    with backend:
        scheduler = backend.cluster.scheduler
        assert scheduler.http_server.address == "127.0.0.1" and scheduler.http_server.port != 8787
        assert logging.getLogger("distributed").level == logging.WARNING
    assert logging.getLogger("distributed").level == before


def test_a_second_run_says_it_reused_the_finished_tasks(tmp_path):
    """The command's line used to read "3 tasks, 0 failed" whether it ran them or found them done."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    args = ("ablation", "--config", str(config), "--out", str(tmp_path / "out"))
    first = _nlips(*args).communicate(timeout=300)[1]  # stderr: the run's line (stdout: the report's folder)
    assert "3 tasks (3 run now, 0 reused), 0 failed" in first
    second = _nlips(*args).communicate(timeout=300)[1]
    assert "3 tasks (0 run now, 3 reused), 0 failed" in second


ORPHAN = """
import sys, time
from nlipscalib.experiments.runner import _WorkerSlots
from nlipscalib.experiments.tasks import Task

slots = _WorkerSlots(1, sys.argv[1], 1, False)
proc, inbox = slots._start(0)
inbox.put(Task(kind="reference", id="ref-none", scene={}))  # fails at once: the worker is then idle in its loop
slots.results.get(timeout=120)
print(proc.pid, flush=True)
time.sleep(600)
"""


def test_a_worker_ends_when_the_command_that_started_it_is_killed(tmp_path):
    """`kill PID` of `nlips experiment --workers 2` (SIGTERM to the command alone: it exits at once) left its idle
    worker processes waiting for a next task forever.

    The command's stderr is piped and read to its end, when every process holding it has ended: the worker, and the
    resource tracker, which unlinks the 6 named semaphores of the two queues (SIGKILL left them) and warns "There
    appear to be 6 leaked semaphore objects". On pytest's own stderr that warning came out in a later test."""
    import psutil

    command = subprocess.Popen(
        [sys.executable, "-c", ORPHAN, str(tmp_path)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    worker = psutil.Process(int(command.stdout.readline()))
    try:
        command.kill()
        command.wait(timeout=10)
        worker.wait(timeout=20)  # psutil.TimeoutExpired while it still waits for a task
        _, err = command.communicate(timeout=60)  # subprocess.TimeoutExpired while a process of it holds stderr
        assert "Traceback" not in err, err
    finally:
        with contextlib.suppress(psutil.Error):
            worker.kill()
        command.stderr.close()  # what its processes still write goes nowhere, not into pytest's output


KILLED_AFTER_A_TASK = """
import sys, time
from nlipscalib.experiments import tasks
from nlipscalib.experiments.tasks import Task, execute

write = tasks.write_json


def written_then_killed(path, obj):  # the task's result is in place, its claim not yet released
    write(path, obj)
    print("written", flush=True)
    time.sleep(60)


tasks.write_json = written_then_killed
tasks._run_reference = lambda task, out, threads, keep: {}  # no render: the kill's moment is what matters
execute(Task(kind="reference", id="ref-none", scene={}), sys.argv[1])
"""


def test_a_task_kept_after_a_kill_loses_the_dead_runs_claim(tmp_path):
    """A laptop dying between a task's result and the release of its claim: the re-run reused the result
    (rightly) but left the dead run's ``tasks/.claim-ID.json`` there for good. Now the re-run removes it."""
    from nlipscalib.experiments.runner import run_tasks
    from nlipscalib.experiments.tasks import Task

    kill_when_it_says(KILLED_AFTER_A_TASK, str(tmp_path), line="written")
    tasks = tmp_path / "tasks"
    assert (tasks / ".claim-ref-none.json").exists()  # what the dead run left
    status = run_tasks([Task(kind="reference", id="ref-none", scene={})], tmp_path, progress=False)
    assert status.skipped == ["ref-none"] and not status.done  # reused, not run again
    assert not [p.name for p in tasks.iterdir() if p.name.startswith((".claim-", ".tmp-"))]


def test_the_task_bar_names_its_experiment(tmp_path, as_terminal):
    """`nlips experiment all` on a terminal drew one unnamed task bar per experiment, then each one's training
    bars: which experiment a bar counted showed only at its end. Each bar now says "NAME tasks"."""
    from nlipscalib.experiments.runner import run_tasks

    tty = as_terminal()
    run_tasks([], tmp_path, name="ablation")
    assert "ablation tasks: " in tty.getvalue(), tty.getvalue()


def test_a_local_worker_solves_on_its_share_of_the_cores(monkeypatch, tmp_path):
    """A local worker process rendered on its share of the cores (usable cores // workers) but solved on every
    usable core: 2 workers on 8 cores ran 16 solver threads. Its solver pool now takes the same share."""
    import queue

    from nlipscalib.experiments.runner import _worker_loop
    from nlipscalib.pipeline import workers
    from nlipscalib.solver import threads

    monkeypatch.setattr(workers, "_worker_signals", lambda: None)  # a worker's signal handlers: not in pytest
    monkeypatch.setattr(threads, "_workers", None)  # restored after the test, as the pool below
    monkeypatch.setattr(threads, "_pool", None)
    inbox, results = queue.Queue(), queue.Queue()
    inbox.put(None)  # no task: the loop sets itself up and returns
    _worker_loop(0, inbox, results, str(tmp_path), 3, False)
    assert threads.workers() == 3
    assert results.empty()


def test_a_local_dask_workers_solves_take_its_share_of_the_cores(monkeypatch):
    """--scheduler local:N: each worker process rendered on cores // N threads but solved on every core (N x cores
    solver threads on one machine); the task wrapper sets the solver's share. A remote worker (threads 0) keeps
    its own count."""
    import logging

    from nlipscalib.experiments import runner
    from nlipscalib.solver import threads as solver_threads

    ran = []
    monkeypatch.setattr(runner, "execute", lambda task, out, threads, keep: ran.append(threads) or "done")
    monkeypatch.setattr(solver_threads, "_workers", 5)
    monkeypatch.setattr(solver_threads, "_pool", None)
    assert runner._execute_on_dask_worker("task", "out", 0, False, logging.INFO)[0] == "done"
    assert solver_threads.workers() == 5  # remote: untouched
    assert runner._execute_on_dask_worker("task", "out", 3, False, logging.INFO)[0] == "done"
    assert solver_threads.workers() == 3 and ran == [0, 3]


def test_a_scheduler_gets_an_absolute_work_folder(tmp_path, monkeypatch, capsys):
    from nlipscalib.cli import main

    """A relative --out with --scheduler: the tasks ran in the remote workers' own working folder (/tmp/out-...)."""
    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    monkeypatch.chdir(tmp_path)
    base = ["experiment", "ablation", "--config", str(config), "--out", "rel", "--plan"]
    assert main([*base, "--scheduler", "local:1"]) == 0
    assert f"done in {tmp_path / 'rel' / 'ablation-custom'}" in capsys.readouterr().out
    assert main(base) == 0  # without a scheduler the folder is named as the user gave it
    assert f"done in {Path('rel') / 'ablation-custom'}" in capsys.readouterr().out


def test_a_stage_of_fewer_tasks_than_workers_shares_the_cores_among_the_tasks_it_runs(monkeypatch, tmp_path):
    """`nlips experiment q1 --workers 2` ran its one reference, then its one calibration, in the command's process
    on cores // 2 threads (q1's reference on 1 of 2 cores, 2 of 16 with --workers 8), the other cores idle; and a
    stage of 2 tasks under --workers 8 started 2 processes on cores // 8 threads each. The cores are now shared by
    the processes the stage runs: min(workers, tasks)."""
    from nlipscalib.experiments import runner
    from nlipscalib.experiments.tasks import Task

    monkeypatch.setattr(runner, "usable_cores", lambda: 16)
    ran, pools = [], []
    monkeypatch.setattr(runner, "execute", lambda task, out, threads, keep: ran.append((task.id, threads)) or "done")

    class Slots:
        def __init__(self, n, out, threads, keep):
            pools.append((n, threads))

        def run(self, tasks, status, bar):
            pass

    monkeypatch.setattr(runner, "_WorkerSlots", Slots)
    status, bar = runner.RunStatus(), runner._bar(3, 0, False, "")
    local = runner._backend(None, 8)._local
    local([Task(kind="reference", id="ref-0", scene={})], tmp_path, False, status, bar)
    assert ran == [("ref-0", 16)]  # in this process, on every core
    local([Task(kind="reference", id=f"ref-{i}", scene={"i": i}) for i in (1, 2)], tmp_path, False, status, bar)
    assert pools == [(2, 8)]  # two processes, half the cores each
    local([Task(kind="reference", id=f"ref-{i}", scene={"i": i}) for i in range(3, 13)], tmp_path, False, status, bar)
    assert pools[-1] == (8, 2)  # --workers 8 of them, as many as asked


def test_workers_with_a_scheduler_is_refused_not_dropped(tmp_path, capsys):
    """`--workers 4 --scheduler local:2` ran on the cluster's 2 workers and dropped --workers without a word."""
    from nlipscalib.cli import main

    config = tmp_path / "tiny.toml"
    config.write_text(TINY, encoding="utf-8")
    args = ["experiment", "ablation", "--config", str(config), "--out", str(tmp_path / "w"), "--plan"]
    assert main([*args, "--workers", "4", "--scheduler", "local:2"]) == 2
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert line == (
        "nlips experiment: error: --workers is not used with --scheduler local:2: the cluster's workers run the "
        "tasks (local:N starts N of them); drop --workers"
    )
    assert captured.out == "" and not (tmp_path / "w").exists()


def test_a_local_clusters_stage_of_one_task_renders_on_every_core(monkeypatch, tmp_path):
    """--scheduler local:N: every task had cores // N threads, a stage of one task (q1's reference) too."""
    distributed = pytest.importorskip("distributed")
    from nlipscalib.experiments import runner
    from nlipscalib.experiments.tasks import Task
    from nlipscalib.solver import threads as solver_threads

    ran = []
    monkeypatch.setattr(runner, "usable_cores", lambda: 8)
    monkeypatch.setattr(runner, "execute", lambda task, out, threads, keep: ran.append(threads) or "done")
    monkeypatch.setattr(solver_threads, "_workers", None)  # the worker (this process) sets its share: restored
    monkeypatch.setattr(solver_threads, "_pool", None)
    backend = runner._backend(None, 1)
    cluster = distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None)
    backend.client, backend.cluster_workers = distributed.Client(cluster), 4  # as local:4
    try:
        bar = runner._bar(3, 0, False, "")
        backend._dask([Task(kind="reference", id="ref-0", scene={})], tmp_path, False, runner.RunStatus(), bar)
        two = [Task(kind="reference", id=f"ref-{i}", scene={"i": i}) for i in (1, 2)]
        backend._dask(two, tmp_path, False, runner.RunStatus(), bar)
    finally:
        backend.client.close()
        cluster.close()
    assert ran == [8, 4, 4]
