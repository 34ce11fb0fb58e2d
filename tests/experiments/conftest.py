"""Fixtures shared by the experiment tests: one quick Q1 run per test session (about 30 s)."""

from __future__ import annotations

from pathlib import Path

import pytest

from nlipscalib.cli import main

BASELINE = Path(__file__).resolve().parents[2] / "nlipscalib" / "experiments" / "baselines" / "q1_quick.json"


@pytest.fixture(scope="session")
def q1(tmp_path_factory):
    """(work folder OUT, the command's argv, its exit code) of ``nlips experiment q1`` at the quick size, checked
    against the stored baseline; the report is OUT/q1-quick/report. Tests may re-run it (resume, other solver
    options): the report stays one of a complete quick Q1 run."""
    out = tmp_path_factory.mktemp("q1")
    argv = ["experiment", "q1", "--out", str(out), "--keep-presses", "--check", str(BASELINE)]
    return out, argv, main(argv)
