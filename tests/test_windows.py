"""Windows' behaviour, taken away or imitated on Linux: a file held open by another program, log lines of several
processes in one file, Ctrl-Break, the 260-character path limit (README "Platforms")."""

from __future__ import annotations

import errno
import os
import sys

import pytest

from nlipscalib.cli import describe_os_error
from nlipscalib.core import atomic


def _held_open_until(monkeypatch, held: list[str], refusals: int) -> list[float]:
    """``os.replace``/``os.rename`` refused as Windows refuses them while another program holds the target open,
    (or a file in a folder being moved), ``refusals`` times; returns the list the waits between tries go to."""
    real_replace, real_rename, waits = os.replace, os.rename, []

    def refused(real):
        def call(source, target, *args, **kwargs):
            if {os.fspath(source), os.fspath(target)} & set(held) and len(waits) < refusals:
                raise PermissionError(errno.EACCES, "Access is denied", os.fspath(source), None, os.fspath(target))
            return real(source, target, *args, **kwargs)

        return call

    monkeypatch.setattr(sys, "platform", "win32")
    monkeypatch.setattr(os, "replace", refused(real_replace))
    monkeypatch.setattr(os, "rename", refused(real_rename))
    monkeypatch.setattr(atomic.time, "sleep", waits.append)
    return waits


def test_a_file_held_open_for_a_moment_on_windows_is_replaced_after_a_wait(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    target.write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(target)], refusals=2)  # an antivirus scan
    atomic.write_text(target, "new")
    assert target.read_text(encoding="utf-8") == "new"
    assert waits == list(atomic.HELD_OPEN_WAITS_S[:2])
    assert [p.name for p in tmp_path.iterdir()] == ["result.csv"]


def test_a_file_held_open_on_windows_fails_after_about_a_second_naming_it(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    target.write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(target)], refusals=100)  # Excel
    with pytest.raises(PermissionError) as info:
        atomic.write_text(target, "new")
    assert 0.5 <= sum(waits) <= 1.5
    assert describe_os_error(info.value) == f"{target}: {atomic.HELD_OPEN}"
    assert target.read_text(encoding="utf-8") == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["result.csv"]


def test_a_folder_with_a_file_held_open_on_windows_is_swapped_after_a_wait(tmp_path, monkeypatch):
    report = tmp_path / "report"
    report.mkdir()
    (report / "results.json").write_text("old", encoding="utf-8")
    waits = _held_open_until(monkeypatch, [str(report)], refusals=1)  # a viewer closing its figure
    with atomic.whole_dir(report, "results.json") as tmp:
        (tmp / "results.json").write_text("new", encoding="utf-8")
    assert (report / "results.json").read_text(encoding="utf-8") == "new"
    assert waits == [atomic.HELD_OPEN_WAITS_S[0]]


def test_a_permission_error_on_linux_is_raised_at_once(tmp_path, monkeypatch):
    target = tmp_path / "result.csv"
    waits = _held_open_until(monkeypatch, [str(target)], refusals=100)
    monkeypatch.setattr(sys, "platform", "linux")
    with pytest.raises(PermissionError) as info:
        atomic.write_text(target, "new")
    assert waits == [] and info.value.errno == errno.EACCES


def _appends_as_windows_does(monkeypatch, path) -> None:
    """``os.write`` to the log ``path`` as Windows' C runtime emulates ``O_APPEND``: find the end, then write there,
    two steps another process's write can come between."""
    import time

    real_write = os.write

    def write(fd: int, data: bytes) -> int:
        if not os.path.samestat(os.fstat(fd), os.stat(path)):
            return real_write(fd, data)
        end = os.fstat(fd).st_size
        time.sleep(0.001)  # another process runs meanwhile
        with open(path, "r+b") as f:
            f.seek(end)
            return f.write(data)

    monkeypatch.setattr(os, "write", write)


@pytest.mark.parametrize("locked", [True, False])
def test_log_lines_of_several_processes_stay_whole_where_appends_interleave(tmp_path, monkeypatch, locked):
    import logging
    import threading

    from nlipscalib import progress

    log = tmp_path / "nlips.log"
    log.touch()
    monkeypatch.setattr(progress, "APPENDS_INTERLEAVE", locked)
    handlers = [progress.AppendFileHandler(log) for _ in range(4)]  # one per process, each its own lock
    _appends_as_windows_does(monkeypatch, log)

    together = threading.Barrier(4)

    def log_lines(n: int) -> None:
        together.wait()
        for i in range(25):
            handlers[n].handle(logging.makeLogRecord({"msg": f"process {n} line {i:02d} " + "x" * 60}))

    threads = [threading.Thread(target=log_lines, args=(n,)) for n in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for handler in handlers:
        handler.close()
    lines = log.read_text(encoding="utf-8").splitlines()
    whole = sorted(f"process {n} line {i:02d} " + "x" * 60 for n in range(4) for i in range(25))
    if locked:
        assert sorted(lines) == whole
    else:  # the imitation does what it says: without the lock lines are lost
        assert sorted(lines) != whole


WINDOWS_SIGNALS = """
import signal, sys, time
# Windows' signal module: no SIGHUP, SIGKILL, SIGALRM, SIGUSR1, pthread_sigmask; handlers only for these seven
# (ValueError for any other); SIGBREAK (Ctrl-Break) stood in for by SIGUSR2, which the test sends
signal.SIGBREAK = signal.SIGUSR2
WINDOWS = {signal.SIGABRT, signal.SIGFPE, signal.SIGILL, signal.SIGINT, signal.SIGSEGV, signal.SIGTERM, signal.SIGBREAK}
for name in ("SIGHUP", "SIGKILL", "SIGALRM", "SIGUSR1", "SIGQUIT", "pthread_sigmask", "pthread_kill"):
    delattr(signal, name)
real_signal = signal.signal

def windows_signal(signum, handler):
    if signum not in WINDOWS:
        raise ValueError("invalid signal value")
    return real_signal(signum, handler)

signal.signal = windows_signal
from nlipscalib.cli import cache, command

def run(args):
    print("working", flush=True)
    time.sleep(30)

cache.run = run
sys.exit(command())
"""


def test_ctrl_break_on_windows_ends_a_command_as_ctrl_c_does():
    """Ctrl-Break's default on Windows ends the process at once: no "interrupted" line, temporaries and claims
    left, LEDs on. The command takes it for Ctrl-C; its handlers install with Windows' signal module."""
    import signal
    import subprocess
    from pathlib import Path

    env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1]))
    proc = subprocess.Popen(
        [sys.executable, "-c", WINDOWS_SIGNALS, "cache"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    try:
        assert proc.stdout.readline() == "working\n", proc.stderr.read()
        proc.send_signal(signal.SIGUSR2)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1].startswith("nlips cache: interrupted"), err


def test_a_worker_on_windows_leaves_ctrl_break_to_its_command(monkeypatch):
    import signal

    from nlipscalib.core.processes import _worker_terminated, worker_signals

    monkeypatch.setattr(signal, "SIGBREAK", signal.SIGUSR2, raising=False)
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM, signal.SIGUSR2)}
    try:
        worker_signals()
        assert signal.getsignal(signal.SIGBREAK) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN
        assert signal.getsignal(signal.SIGTERM) is _worker_terminated
    finally:
        for signum, handler in saved.items():
            signal.signal(signum, handler)


def test_a_worker_on_windows_whose_command_is_gone_runs_its_sigterm_handler(monkeypatch):
    """``os.kill`` of itself on Windows is TerminateProcess: the handler that releases a worker's claims never ran."""
    import signal

    from nlipscalib.core import processes

    handled, killed = [], []
    monkeypatch.setattr(sys, "platform", "win32")
    monkeypatch.setattr(signal, "getsignal", lambda signum: lambda *args: handled.append(signum))
    monkeypatch.setattr(os, "kill", lambda pid, signum: killed.append(signum))
    processes._terminate_self()  # what end_with_parent's watch does once the command is gone
    assert handled == [signal.SIGTERM]


def _windows_without_long_paths(monkeypatch, enabled: bool = False) -> None:
    from nlipscalib.core import long_paths

    monkeypatch.setattr(long_paths, "WINDOWS", True)
    monkeypatch.setattr(long_paths, "long_paths_enabled", lambda: enabled)  # the registry is not read in tests
    monkeypatch.setattr(long_paths, "_warned", set())


def test_an_output_folder_too_long_for_windows_is_warned_about_once_before_the_work(monkeypatch, caplog):
    from nlipscalib.core.long_paths import DEEPEST_BELOW_OUT, MAX_PATH, warn_if_too_long

    _windows_without_long_paths(monkeypatch)
    room = MAX_PATH - 1 - DEEPEST_BELOW_OUT["experiment"]
    fits, too_long = "/" + "a" * (room - 1), "/" + "a" * room  # nothing is made: any path will do
    assert not warn_if_too_long(fits, "experiment")
    assert warn_if_too_long(too_long, "experiment")
    assert not warn_if_too_long(too_long, "experiment")  # once
    [line] = [r.getMessage() for r in caplog.records if r.name == "nlipscalib.core.long_paths"]
    assert line.startswith(f"{too_long}: paths up to {MAX_PATH} characters") and f"at most {room} characters" in line


def test_no_warning_with_long_paths_on_or_off_windows(tmp_path, monkeypatch):
    from nlipscalib.core import long_paths
    from nlipscalib.core.long_paths import warn_if_too_long

    deep = tmp_path / ("a" * 200)
    _windows_without_long_paths(monkeypatch, enabled=True)
    assert not warn_if_too_long(deep, "dataset")
    _windows_without_long_paths(monkeypatch)
    monkeypatch.setattr(long_paths, "WINDOWS", False)
    assert not warn_if_too_long(deep, "dataset")


def test_nlips_experiment_warns_of_a_long_out_on_windows(tmp_path, monkeypatch, caplog):
    from nlipscalib.cli import main

    _windows_without_long_paths(monkeypatch)
    out = tmp_path / ("o" * 150)
    assert main(["experiment", "q1", "--out", str(out), "--plan"]) == 0
    [line] = [r.getMessage() for r in caplog.records if r.name == "nlipscalib.core.long_paths"]
    assert line.startswith(f"{out}: paths up to")
