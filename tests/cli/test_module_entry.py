"""``python -m nlipscalib`` and ``python -m nlipscalib.cli`` run the ``nlips`` command (a Python whose venv
scripts are not on PATH, e.g. a notebook's or a scheduler's)."""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("module", ["nlipscalib", "nlipscalib.cli"])
def test_python_dash_m_runs_the_nlips_command(module, tmp_path):
    ok = subprocess.run([sys.executable, "-m", module, "solve", "--help"], capture_output=True, text=True, cwd=ROOT)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: nlips solve"), ok.stderr
    bad = subprocess.run(
        [sys.executable, "-m", module, "solve", str(tmp_path / "missing")], capture_output=True, text=True, cwd=ROOT
    )
    assert bad.returncode != 0 and "Traceback" not in bad.stderr
    assert "missing" in bad.stderr


def test_the_command_ends_once_its_work_is_done_with_the_solvers_thread_pool_idle(tmp_path):
    """The solver's threads are a concurrent.futures pool kept for the process: ``command()`` ends the process
    itself (cli._exit), and joining those idle threads without telling them to end waited forever."""
    from tests.solver import synth

    press = synth.make_press(tmp_path / "p", "sphere", size=(48, 36))
    run = subprocess.run(
        [sys.executable, "-m", "nlipscalib", "--no-progress", "solve", str(press), "--no-figures"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr
    assert (press / "nlips" / "result.npz").exists()
