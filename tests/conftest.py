"""Project-wide pytest settings: in CI the digital-twin tests must run, never skip quietly.

The solver's disk cache of sensor-level results (``nlipscalib.core.diskcache``) points at a folder of this
test session (subprocesses inherit it): tests never read or fill the user's own cache.

``--require-twin`` (or ``NLIPS_REQUIRE_TWIN=1``, which .ci/run sets) checks at start-up that Mitsuba
imports and renders with its LLVM backend, and turns every skip caused by a missing twin part
(Mitsuba, drjit, LLVM) into a failure, so a broken install cannot give a green suite.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import tempfile

import pytest

REQUIRE_TWIN_ENV = "NLIPS_REQUIRE_TWIN"
TWIN_PARTS = re.compile(r"mitsuba|drjit|llvm", re.IGNORECASE)
"""A skip whose reason mentions one of these was caused by a missing twin part."""


def pytest_addoption(parser):
    parser.addoption(
        "--require-twin",
        action="store_true",
        default=False,
        help=f"fail (not skip) when Mitsuba/LLVM cannot render; also set by {REQUIRE_TWIN_ENV}=1",
    )


def twin_required(config) -> bool:
    return bool(config.getoption("--require-twin")) or os.environ.get(REQUIRE_TWIN_ENV, "") not in ("", "0")


_CACHE_DIR: str | None = None


def pytest_configure(config):
    global _CACHE_DIR
    _CACHE_DIR = tempfile.mkdtemp(prefix="nlips-test-cache-")
    os.environ["NLIPS_CACHE_DIR"] = _CACHE_DIR


def pytest_unconfigure(config):
    import sys

    diskcache = sys.modules.get("nlipscalib.core.diskcache")
    if diskcache is not None:
        diskcache.wait()  # its background writes into the folder, before it goes
    if _CACHE_DIR is not None:
        shutil.rmtree(_CACHE_DIR, ignore_errors=True)


def pytest_sessionstart(session):
    if not twin_required(session.config):
        return
    problem = _twin_problem()
    if problem:
        pytest.exit(f"--require-twin: the digital twin cannot render here: {problem}", returncode=3)


def _twin_problem() -> str | None:
    try:
        import mitsuba  # noqa: F401
    except Exception as exc:  # ImportError, or a broken binary wheel
        return f"mitsuba does not import ({type(exc).__name__}: {exc})"
    from nlipscalib.sim.render.variant import llvm_usable

    if not llvm_usable():
        return "Mitsuba's LLVM backend cannot render (install libLLVM 16..19, see setup.sh)"
    return None


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    _fail_twin_skip(item.config, outcome.get_result())


@pytest.hookimpl(hookwrapper=True)
def pytest_make_collect_report(collector):
    outcome = yield
    _fail_twin_skip(collector.config, outcome.get_result())


def _fail_twin_skip(config, report) -> None:
    if not (report.skipped and twin_required(config)):
        return
    reason = report.longrepr[2] if isinstance(report.longrepr, tuple) else str(report.longrepr)
    if TWIN_PARTS.search(reason):
        report.outcome = "failed"
        report.longrepr = f"twin test skipped under --require-twin: {reason}"


class _Terminal(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def as_terminal(monkeypatch):
    """A function that, called in a test's body, replaces stderr with a text buffer that says it is a terminal and
    turns progress bars on; it returns the buffer (what a user at a terminal sees is in its ``getvalue()``). Called
    in the body, not done here: pytest's own capture puts its stderr back when the test's call begins. The progress
    switch is restored afterwards."""
    from nlipscalib import progress

    def start() -> io.StringIO:
        tty = _Terminal()
        monkeypatch.setattr("sys.stderr", tty)
        progress.configure(progress=True)
        return tty

    yield start
    progress.configure(progress=True)
