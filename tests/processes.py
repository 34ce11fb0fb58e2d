"""Processes at controlled moments, for tests of interrupted and concurrent work (no timing guesses)."""

import os
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
    return path.read_text(encoding="utf-8") if path.exists() else ""


ENDLESS_PATCH = """
import os

import drjit as dr

from nlipscalib.sim.render import plugins

make = plugins.make_integrator_class


def endless(mi, led):
    class Endless(make(mi, led)):
        def sample(self, *args, **kwargs):  # traced once, into a kernel that never ends
            total, valid, aovs = super().sample(*args, **kwargs)
            width = dr.width(total[0])
            # x <- x^2 / 2 + 1/4 while x > 0: from 1/4 it stays in [1/4, 1 - 1/sqrt(2)], so the loop never ends,
            # which no compiler can tell (it would have to bound a float recurrence)
            def step(x):
                return (dr.fma(x * 0.5, x, 0.25),)

            x = dr.while_loop((dr.full(mi.Float, 0.25, width),), lambda x: x > 0, step)[0]
            open(os.path.join(os.environ["RENDER_TRACED"], str(os.getpid())), "w").close()
            return total + dr.select(x < 0, 1.0, 0.0), valid, aovs

    return Endless


plugins.make_integrator_class = endless
"""
"""Every render of the process endless: only a signal ends it, so a test of the signal's path needs no clock; each
process that traced one marks it by a file (its pid) in the folder ``$RENDER_TRACED``."""


def endless_renders(env: dict[str, str], folder: Path) -> tuple[dict[str, str], Path]:
    """``env`` for a command whose every Mitsuba render, in each of its processes, is endless (:data:`ENDLESS_PATCH`
    as a ``sitecustomize`` module in ``folder``, first on PYTHONPATH); and the folder where each process that traced
    a render marks it (a file named by its pid)."""
    patch, traced = folder / "endless", folder / "traced"
    patch.mkdir()
    traced.mkdir()
    (patch / "sitecustomize.py").write_text(
        ENDLESS_PATCH, encoding="utf-8"
    )  # imported by every Python process the command starts
    path = os.pathsep.join([str(patch), env.get("PYTHONPATH", "")])
    return dict(env, PYTHONPATH=path, RENDER_TRACED=str(traced)), traced


def claim_mark_and_wait(folder: Path) -> None:
    """A worker's task that never ends: claims ``folder/held`` (``folder/.claim-held``), marks that it runs by a file
    named by its pid in ``folder``, then sleeps; picklable by name, for pools whose workers a test watches."""
    from nlipscalib.core.claims import claim

    with claim(folder / "held"):
        (folder / str(os.getpid())).write_text("", encoding="utf-8")
        while True:
            time.sleep(60)


def wait_until(predicate, timeout: float = 2.0):
    """``predicate()``'s first true value, polled until ``timeout`` s passed (then its last, false, value): another
    thread or process acts when it is scheduled, which on a loaded machine is not within any fixed sleep."""
    deadline = time.monotonic() + timeout
    while not (value := predicate()):
        if time.monotonic() > deadline:
            return value
        time.sleep(0.01)
    return value


def sleepy_status(folder, marks) -> str:
    """A stand-in for a press's solve in a pool (pickled by name): ``marks/started/NAME`` made; ``press_0`` then
    waits (at most 10 s) until ``press_1`` has started on the other worker, so that one is running whatever the
    machine's load (a worker process can take longer to start than a quick press), the others sleep 1 s; then
    ``marks/NAME`` made and "solved"."""
    name, started = Path(folder).name, Path(marks) / "started"
    started.mkdir(exist_ok=True)
    (started / name).touch()
    if name == "press_0":
        deadline = time.monotonic() + 10.0
        while not (started / "press_1").exists() and time.monotonic() < deadline:
            time.sleep(0.01)
    else:
        time.sleep(1.0)
    (Path(marks) / name).touch()
    return "solved"


def threads_status(folder) -> str:
    """A stand-in for a press's solve in a pool (pickled by name): the worker's solver and OpenCV thread counts."""
    import cv2

    from nlipscalib.solver import threads

    return f"solver {threads.workers()} opencv {cv2.getNumThreads()}"


def terminate_once_started(argv: list[str], started: Path, env: dict[str, str], wait: float) -> tuple[int, str, str]:
    """Run ``argv``, send it SIGTERM once it has made the file ``started`` (its frames began: the moment to stop
    it at), and return (exit code, stdout, stderr); it is SIGKILLed if it outlives the test. ``wait`` bounds both
    the start and the end, seconds."""
    import contextlib

    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + wait
        while not started.exists() and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=wait)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, signal.SIGKILL)
    return proc.returncode, out, err
