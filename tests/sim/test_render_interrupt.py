"""Ctrl-C or SIGTERM while Mitsuba renders: `nlips render` ends at once with its one line, not Mitsuba's coloured
warning before it."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.processes import ENDLESS_PATCH, as_from_a_terminal, endless_renders

pytest.importorskip("mitsuba")

ROOT = Path(__file__).resolve().parents[2]

CTRL_C_DURING_THE_RENDER = """
import os, signal, sys

signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
from nlipscalib.sim.render import plugins

make = plugins.make_integrator_class


def interrupting(mi, led):
    base = make(mi, led)

    class Interrupting(base):
        def sample(self, *args, **kwargs):  # runs while Mitsuba's own Ctrl-C handler is in place
            if not getattr(Interrupting, "pressed", False):
                Interrupting.pressed = True
                os.kill(os.getpid(), signal.SIGINT)
            return super().sample(*args, **kwargs)

    return Interrupting


plugins.make_integrator_class = interrupting
from nlipscalib.cli import main

sys.exit(main(sys.argv[1:]))
"""


def test_ctrl_c_during_a_mitsuba_render_is_our_one_line_alone(tmp_path):
    """Ctrl-C during `nlips render` printed Mitsuba's "\\x1b[31m... WARN [integrator_v.cpp:38] Received interrupt
    signal, winding down..\\x1b[0m" (on stdout, colour codes even into a file) with "nlips render: interrupted; ..."."""
    args = ["--no-progress", "render", "--width", "96", "--height", "72", "--spp", "1", "--out", str(tmp_path / "p")]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run(
        [sys.executable, "-c", CTRL_C_DURING_THE_RENDER, *args], capture_output=True, text=True, env=env, timeout=600
    )
    assert proc.returncode == 130, proc.stderr
    not_log = [line for line in proc.stderr.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    assert not_log == ["nlips render: interrupted; finished work is kept, run again to resume"], proc.stderr
    assert proc.stdout == ""  # where Mitsuba's log goes
    assert not (tmp_path / "p").exists()


def test_mitsuba_warnings_of_a_render_are_logged_once_each_without_its_interrupt_notice(caplog, capfd):
    """Mitsuba's warnings were held back while it rendered (the log level raised to errors, to hide the notice its
    Ctrl-C handler logs). Now each is logged as ours, once however many renders (presses) repeat it; the notice
    alone is dropped, and Mitsuba's log goes back to where it was after the render."""
    import logging
    import uuid

    from nlipscalib.sim.render import surface
    from nlipscalib.sim.render.variant import load_mitsuba

    mi, _ = load_mitsuba("scalar_rgb", 1)
    tag = uuid.uuid4().hex  # this test's messages: each is logged once per process
    with caplog.at_level(logging.WARNING, logger=surface.__name__):
        for _ in range(2):  # two presses' renders
            with surface._warnings_relayed(mi):
                mi.Log(mi.LogLevel.Warn, f"{tag} first\nits second line")
                mi.Log(mi.LogLevel.Warn, f"{tag} first\nits second line")
                mi.Log(mi.LogLevel.Warn, f"{surface.MITSUBA_INTERRUPT_NOTICE}.. {tag}")
                mi.Log(mi.LogLevel.Warn, f"{tag} second")
    logged = [r.getMessage() for r in caplog.records if tag in r.getMessage()]
    assert len(logged) == 2, logged
    assert logged[0].startswith("Mitsuba: ") and logged[0].endswith(f"{tag} first\nits second line")
    assert logged[1].endswith(f"{tag} second")
    assert capfd.readouterr().out == ""  # none on stdout, where Mitsuba logs
    mi.Log(mi.LogLevel.Warn, f"{tag} after the render")
    assert f"{tag} after the render" in capfd.readouterr().out


ENDLESS_RENDER = f"""
import signal

signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
{ENDLESS_PATCH}
from nlipscalib.cli import command

command()
"""
"""``nlips render`` (as the ``nlips`` command, which ends its own process) whose render's kernel never ends."""

HANG_GUARD_S = 120.0
"""Seconds after the signal before a test calls the command hung: a guard, not the claim. The renders never end
(:data:`~tests.processes.ENDLESS_PATCH`), so a command that ends at all was ended by the signal (~0.1 s here, on 2
busy cores); before, it waited for the render."""


def _signalled_while_rendering(proc: subprocess.Popen, traced, renders: int, send) -> tuple[str, str]:
    """Wait until ``renders`` endless renders of ``proc`` began (files in ``traced``) and ran a second, ``send()`` the
    signal; returns stdout and stderr once the process ended (fails if it still runs :data:`HANG_GUARD_S` later)."""
    deadline = time.monotonic() + 300
    while len(list(traced.iterdir())) < renders and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    began = len(list(traced.iterdir()))
    assert began == renders, proc.communicate()[1] if proc.poll() is not None else f"{began} of {renders} renders"
    time.sleep(1.0)
    assert proc.poll() is None
    send()
    try:
        return proc.communicate(timeout=HANG_GUARD_S)
    except subprocess.TimeoutExpired:
        pytest.fail(f"still running {HANG_GUARD_S:g} s after the signal: it waits for its endless render")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_during_a_long_render_ends_the_command_at_once(tmp_path, signum):
    """Ctrl-C or SIGTERM during a render (640x480, 16 spp, one bounce: tens of seconds) ended the command only when
    the render did: Python handles a signal in the main thread, which the native render call held. It now ends
    (the render here never does: its end is the signal's doing), with its one line, its status, and no press
    folder or temporary left."""
    traced = tmp_path / "traced"
    traced.mkdir()
    out = tmp_path / "p"
    args = ["--no-progress", "render", "--width", "16", "--height", "12", "--spp", "1", "--threads", "1"]
    temporaries = tmp_path / "tmp"  # the command's TMPDIR (Mitsuba's log while it renders)
    temporaries.mkdir()
    env = dict(os.environ, RENDER_TRACED=str(traced), TMPDIR=str(temporaries))
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    proc = as_from_a_terminal([sys.executable, "-c", ENDLESS_RENDER, *args, "--out", str(out)], env=env)
    try:
        # once the kernel compiled and runs: the main thread used to be inside it
        stdout, stderr = _signalled_while_rendering(proc, traced, 1, lambda: proc.send_signal(signum))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    how = "interrupted" if signum == signal.SIGINT else "terminated"
    assert proc.returncode == 128 + signum, stderr
    not_log = [line for line in stderr.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    assert not_log == [f"nlips render: {how}; finished work is kept, run again to resume"], stderr
    assert stdout == ""
    assert not out.exists()
    assert list(temporaries.iterdir()) == []  # SIGTERM left the log's folder in /tmp


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads the process table from /proc")
def test_ctrl_c_during_a_datasets_worker_renders_ends_the_run_at_once_and_a_rerun_resumes(tmp_path):
    """Ctrl-C from a terminal (SIGINT to the whole process group) of `nlips dataset --workers 2` while both render
    processes rendered: each died of it with a traceback or went on (its exit waited for the render it had left on
    a thread of its own), and the command waited for them: tens of seconds at 640x480, here forever. Now the render
    processes ignore Ctrl-C and the command ends them: its one line, exit 130 (the renders here never end: that the
    command and its render processes end at all is its doing), no claim, temporary or process left; the next run
    keeps the presses done and renders the interrupted ones."""
    from tests.cli.test_interrupt import _wait_until_gone
    from tests.specs import TINY_SPEC

    spec, out = tmp_path / "spec.toml", tmp_path / "out"
    spec.write_text(TINY_SPEC, encoding="utf-8")  # the reference and four presses
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    command = [sys.executable, "-m", "nlipscalib", "--no-progress", "dataset", str(spec), "--out", str(out)]
    done = subprocess.run([*command, "--limit", "1", "--workers", "1"], env=dict(os.environ, PYTHONPATH=path))
    assert done.returncode == 0  # the reference and press_0001 rendered

    env, traced = endless_renders(dict(os.environ, PYTHONPATH=path), tmp_path)
    proc = as_from_a_terminal([*command, "--workers", "2"], env=env, start_new_session=True)
    try:  # Ctrl-C once both kernels compiled and run
        stdout, stderr = _signalled_while_rendering(proc, traced, 2, lambda: os.killpg(proc.pid, signal.SIGINT))
        assert _wait_until_gone(proc.pid, 60) == []  # no render process left (60 s: a guard, gone at once)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 130, stderr
    not_log = [line for line in stderr.splitlines() if not line.startswith(("INFO ", "WARNING "))]
    assert not_log == ["nlips dataset: interrupted; finished work is kept, run again to resume"], stderr
    assert not [p.name for p in out.iterdir() if p.name.startswith((".claim-", ".tmp-"))]
    assert sorted(p.name for p in out.iterdir()) == ["dataset.json", "press_0001", "reference"]

    again = subprocess.run(command, env=dict(os.environ, PYTHONPATH=path), capture_output=True, text=True)
    assert again.returncode == 0, again.stderr
    counts = "3 presses rendered, 1 press and the undeformed reference already there, 0 failed"
    assert counts in again.stderr and again.stdout == f"{out}\n", again.stdout
