"""CI cannot go green without the twin: --require-twin turns twin skips into failures."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _pytest(folder: Path, *args: str, **env: str) -> subprocess.CompletedProcess:
    full_env = {k: v for k, v in os.environ.items() if k != "NLIPS_REQUIRE_TWIN"}  # CI sets it for us
    full_env.update(PYTHONPATH=str(ROOT), **env)
    cmd = [sys.executable, "-m", "pytest", "-p", "tests.conftest", "-q", "-p", "no:cacheprovider", *args, str(folder)]
    return subprocess.run(cmd, cwd=folder, env=full_env, capture_output=True, text=True, timeout=300)


def test_twin_skips_fail_only_when_required(tmp_path):
    (tmp_path / "test_twin_missing.py").write_text(
        "import pytest\npytest.importorskip('mitsuba_missing_for_this_test')\ndef test_a():\n    pass\n",
        encoding="utf-8",
    )
    (tmp_path / "test_other_skip.py").write_text(
        "import pytest\ndef test_b():\n    pytest.skip('no camera attached')\n", encoding="utf-8"
    )
    relaxed = _pytest(tmp_path)
    assert relaxed.returncode == 0 and "2 skipped" in relaxed.stdout
    strict = _pytest(tmp_path, "--require-twin", NLIPS_LLVM_OK="1")
    assert strict.returncode != 0 and "twin test skipped under --require-twin" in strict.stdout
    (tmp_path / "test_twin_missing.py").unlink()
    other = _pytest(tmp_path, NLIPS_REQUIRE_TWIN="1", NLIPS_LLVM_OK="1")
    assert other.returncode == 0 and "1 skipped" in other.stdout  # unrelated skips stay skips


def test_required_twin_that_cannot_render_stops_the_run(tmp_path):
    (tmp_path / "test_ok.py").write_text("def test_ok():\n    pass\n", encoding="utf-8")
    run = _pytest(tmp_path, NLIPS_REQUIRE_TWIN="1", NLIPS_LLVM_OK="0")  # as if LLVM were broken
    assert run.returncode != 0 and "cannot render" in run.stdout + run.stderr
