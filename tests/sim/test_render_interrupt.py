"""Ctrl-C while Mitsuba renders: `nlips render` says its one line, not Mitsuba's coloured warning before it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

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
