"""What produced a report: software versions, git commit, machine (for the report's JSON)."""

from __future__ import annotations

import functools
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from .. import __version__

PACKAGES = ("numpy", "scipy", "pyamg", "mitsuba", "drjit", "torch", "dask", "distributed")


def checkout_root() -> Path | None:
    """The checkout the package was imported from, or None for an installed copy (or a checkout without git).

    An installed copy sits in site-packages; git asked there would name whatever repository holds the
    environment (a lab's own project with its .venv inside), not the version of nlipscalib that ran.
    """
    repo = Path(__file__).resolve().parents[2]
    return repo if (repo / ".git").exists() else None  # a file, not a folder, in a git worktree


def git_commit(repo: Path | None = None) -> str | None:
    """HEAD commit of the checkout the package was imported from (with "+dirty" for local changes); None when
    it was not imported from a git checkout."""
    repo = repo or checkout_root()
    if repo is None:
        return None
    try:
        head = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(
            ["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            timeout=10,
        )
        return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return None


@functools.cache
def made_by() -> dict:
    """The code that makes a task's result (recorded in it as ``made_by``): nlipscalib's version and git commit.
    Cached: once per process, not two git calls per task."""
    return {"nlipscalib": __version__, "git_commit": git_commit()}


def software() -> dict:
    versions = {}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {"nlipscalib": __version__, "git_commit": git_commit(), "python": platform.python_version()} | versions


def machine() -> dict:
    """Host, platform, CPU model, core count and load average (recorded with every report and benchmark)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="utf-8").splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    return {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_average": [round(x, 2) for x in load] if load else None,
    }
