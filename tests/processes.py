"""Processes at controlled moments, for tests of interrupted and concurrent work (no timing guesses)."""

import signal
import subprocess
import sys
import time
from pathlib import Path


def as_from_a_terminal(argv: list[str], **kw) -> subprocess.Popen:
    """``argv`` started as a terminal's command is (Ctrl-C not ignored, whatever the test runner's own setting),
    stdout and stderr piped as text; ``kw`` to :class:`subprocess.Popen` (env, start_new_session, ...)."""
    return subprocess.Popen(
        argv,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
        **kw,
    )


def kill_when_it_says(code: str, *args: str, line: str) -> None:
    """Run ``python -c code *args``, wait until it prints ``line`` (the moment to kill it at), then SIGKILL it."""
    proc = subprocess.Popen([sys.executable, "-c", code, *args], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == line
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
    finally:
        proc.kill()
        proc.wait()


def until_each_waits_or_exits(procs: list, logs: list[Path], says: str, timeout: float) -> None:
    """Return once each process of ``procs`` has exited or written ``says`` into its log file (the same index of
    ``logs``): e.g. both runs of a race have met an item the test holds. Fails after ``timeout`` seconds."""
    deadline = time.time() + timeout
    while not all(p.poll() is not None or says in _text(log) for p, log in zip(procs, logs)):
        assert time.time() < deadline, f"no process said {says!r} nor exited within {timeout} s"
        time.sleep(0.1)


def _text(path: Path) -> str:
    return path.read_text() if path.exists() else ""
