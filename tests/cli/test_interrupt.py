"""Ctrl-C during a command: one line, exit 130, whatever exception the interrupted code turned it into."""

from __future__ import annotations

import os
import signal

import pytest

from nlipscalib import cli
from nlipscalib.cli import cache, main


@pytest.fixture
def default_sigint():
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # as a command-line process has it
    yield
    signal.signal(signal.SIGINT, previous)


def _interrupted_inside_a_native_library(args):
    try:
        os.kill(os.getpid(), signal.SIGINT)
        raise AssertionError("the interrupt did not arrive")
    except KeyboardInterrupt as exc:  # what drjit does with it: its own exception
        raise RuntimeError("drjit.custom(...): error while performing a custom differentiable operation") from exc


def test_ctrl_c_turned_into_another_exception_still_reads_as_an_interruption(monkeypatch, capsys, default_sigint):
    monkeypatch.setattr(cache, "run", _interrupted_inside_a_native_library)
    assert main(["cache"]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err and "drjit" not in err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # the handler is put back


def test_the_same_exception_without_ctrl_c_is_not_hidden(monkeypatch, default_sigint):
    def fails(args):
        raise RuntimeError("a real bug")

    monkeypatch.setattr(cache, "run", fails)
    with pytest.raises(RuntimeError, match="a real bug"):
        main(["cache"])
    assert not cli._INTERRUPTED


TERMINATED = "nlips solve: terminated; finished work is kept, run again to resume"


def test_sigterm_of_a_parallel_solve_is_one_line_without_leaked_semaphore_warnings(tmp_path):
    """`kill -TERM -PGID` of `nlips solve DATASET --workers 2`: the one line, exit 143, nothing after it.

    The worker pool's named semaphores used to outlive the process (os._exit skips multiprocessing's
    finalizers), and its resource tracker then printed "There appear to be N leaked semaphore objects".
    """
    import contextlib
    import subprocess
    import sys
    import time

    from tests.solver import synth

    for i in range(6):  # enough presses that the pool is still busy when the first result appears
        synth.make_press(tmp_path / f"p{i}", "sphere" if i % 2 else "cube", depth=1.0 + 0.1 * i, size=(64, 48))
    command = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    argv = [sys.executable, "-c", command, "--no-progress", "solve", str(tmp_path), "--workers", "2", "--no-figures"]
    proc = subprocess.Popen(argv, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 60
        while not list(tmp_path.glob("*/nlips/result.npz")) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        os.killpg(proc.pid, signal.SIGTERM)  # a scheduler's time limit: the whole process group
        _, err = proc.communicate(timeout=60)  # to EOF: the resource tracker's stderr too
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signal.SIGTERM, err
    not_log = [line for line in err.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    assert not_log == [TERMINATED], err
    assert not [p for p in tmp_path.rglob("*") if p.name.startswith((".claim-", ".tmp-"))]
