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
