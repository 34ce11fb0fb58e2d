"""docs/faults.md: every test its last column names exists, so a row cannot point at a renamed or imagined test."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FAULTS = ROOT / "docs" / "faults.md"


def _references() -> list[tuple[str, str, str | None]]:
    """(row text, test file, test name or None) for every test a table row's last column names.

    A cell names tests as `tests/dir/test_x.py::test_y`, `test_x.py::test_y` (a file found under tests/) or
    `::test_z` (another test of the file named before it in the same cell), or a whole file."""
    refs = []
    for line in FAULTS.read_text(encoding="utf-8").splitlines():
        if not line.startswith("|") or line.startswith("|---"):
            continue
        cell = line.rstrip().rstrip("|").rsplit("|", 1)[-1]
        current = None
        for ref in re.findall(r"`([^`]+)`", cell):
            file, _, name = ref.partition("::")
            if file:
                if not file.endswith(".py"):
                    continue
                current = file
            if current is not None:
                refs.append((line, current, name or None))
    return refs


def _test_file(name: str) -> Path | None:
    if "/" in name:
        path = ROOT / name
        return path if path.is_file() else None
    found = sorted((ROOT / "tests").rglob(name))
    return found[0] if len(found) == 1 else None


def test_every_test_the_faults_table_names_exists():
    refs = _references()
    assert len(refs) > 40  # the parser reads the tables (a format change would otherwise pass silently)
    missing = []
    for row, file, name in refs:
        path = _test_file(file)
        if path is None or (
            name is not None and not re.search(rf"^def {re.escape(name)}\(", path.read_text(encoding="utf-8"), re.M)
        ):
            missing.append(f"{file}::{name}  (row: {row[:60]}...)")
    assert missing == []


OTHER_TOOLS_OPTIONS = {
    "--require-twin": "pytest (tests/conftest.py)",
    "--force": "setup.sh",
    "--sdist": "python -m build",
    "--defaults": "benchmarks/bench_effects.py",
    "--now": "systemctl",
    "--gres": "SLURM",
    "--nthreads": "dask worker",
    "--cpus": "docker run",
}
"""Options the docs name that belong to other tools than ``nlips`` (each with its tool)."""


def test_every_option_the_docs_name_is_one_nlips_takes():
    """faults.md named `nlips capture --white-level`, an option no command has (the single-LED drive is
    ``SessionConfig.white_level``, Python only): a user copying it gets "unrecognized arguments"."""
    import argparse

    from nlipscalib.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    known = {o for p in [parser, *commands.values()] for a in p._actions for o in a.option_strings}
    # not the RESULTS.md logs: they record variants tried and not merged, with the options they had
    pages = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if p.name != "RESULTS.md")]
    named = {
        option: page.relative_to(ROOT)
        for page in pages
        for option in re.findall(r"(?<![\w/.-])(--[a-z][a-z0-9-]*)", page.read_text(encoding="utf-8"))
    }
    assert len(named) > 100  # the pages were read
    assert {o: str(p) for o, p in named.items() if o not in known and o not in OTHER_TOOLS_OPTIONS} == {}
    assert set(OTHER_TOOLS_OPTIONS) <= set(named) - known  # none listed here in vain (or taken by nlips since)


NAMED_ONLY_IN_HELP: set[str] = set()
"""Options that only their command's ``--help`` describes (none of README.md or docs/ names them): empty since
s28-docs2 documented the last 14 (``train --lr``, ``leds --dwell``, ...); an option added since must be named in the
pages (or added here, knowingly)."""


def test_every_option_nlips_takes_is_named_in_the_pages_or_listed_as_help_only():
    """s28 added --allow-sensor-misfit, --keep-led-order, --camera-response and infer's --reference: the README named
    none of them (docs/ did). The reverse of the test above: a new flag the pages do not name fails here."""
    import argparse

    from nlipscalib.cli import build_parser

    pages = [ROOT / "README.md", *sorted(p for p in (ROOT / "docs").rglob("*.md") if p.name != "RESULTS.md")]
    text = "\n".join(page.read_text(encoding="utf-8") for page in pages)
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices
    unnamed = {
        f"{name} {option}"
        for name, command in commands.items()
        for action in command._actions
        # -v/--verbose, --help, --log-file ...: every command's, named once in the README
        if not any(o in ("-v", "-h") for o in action.option_strings)
        for option in action.option_strings
        if option.startswith("--") and not re.search(rf"(?<![\w/.-]){re.escape(option)}(?![\w-])", text)
    }
    assert len(commands) > 15  # the parser was read
    assert sorted(unnamed - NAMED_ONLY_IN_HELP) == []
    assert sorted(NAMED_ONLY_IN_HELP - unnamed) == []  # named since: take it off the list
