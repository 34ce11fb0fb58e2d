"""The README's and docs/' module paths name modules (and their functions) that exist.

Modules move (``solver/blas.py`` became ``core/blas.py``, session 25) and the prose that names them does not
follow by itself: a reader sent to ``nlipscalib.solver.blas`` finds nothing. benchmarks/RESULTS.md and
docs/experiments/RESULTS.md are records of their day and are not checked.
"""

from __future__ import annotations

import ast
import dataclasses
import functools
import re
from pathlib import Path

import pytest

from nlipscalib.solver.options import SolverOptions

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "nlipscalib"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "docs" / "experiments" / "README.md"]
SUBPACKAGES = "core|sim|solver|learn|device|pipeline|report|experiments|cli"
SLASHED = re.compile(rf"(?<![\w./-])(?:nlipscalib/)?(?:{SUBPACKAGES})/[\w/]*\w(?:\.[a-z]+)?")
"""``core/claims.py``, ``sim/render/surface``, ``nlipscalib/core/tolerances.py``."""
DOTTED = re.compile(rf"(?<![\w./\"])(?:nlipscalib\.)?(?:{SUBPACKAGES})(?:\.\w+)+")
"""``nlipscalib.core.cpus.usable_cores``, ``core.metrics.evaluate``; not a quoted format name ("nlipscalib.press")."""
FILE_SUFFIXES = {"py", "md", "json", "toml", "yaml", "png", "npz", "txt"}
SOLVER_KEYS = {f.name for f in dataclasses.fields(SolverOptions)}


@functools.cache
def top_level_names(module: Path) -> frozenset[str]:
    """Names a module defines or imports at its top level (what ``module.name`` can reach)."""
    names = set()
    for node in ast.parse(module.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(node.name)
        elif isinstance(node, ast.Assign | ast.AnnAssign):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        elif isinstance(node, ast.Import | ast.ImportFrom):
            names |= {(alias.asname or alias.name).split(".")[0] for alias in node.names}
    return frozenset(names)


def dotted_problem(reference: str) -> str | None:
    """Why ``reference`` (a dotted path) names nothing, or None: packages and modules must exist, and the name
    after a module must be one it defines (further attributes are not followed)."""
    parts = reference.removeprefix("nlipscalib.").split(".")
    if parts[-1] in FILE_SUFFIXES:  # a file name such as report.json
        return None
    if reference.startswith("solver.") and parts[1] in SOLVER_KEYS:  # a --config key ([solver] table)
        return None
    folder = PACKAGE
    for i, part in enumerate(parts):
        if (folder / part).is_dir():
            folder = folder / part
        elif (folder / f"{part}.py").is_file():
            rest = parts[i + 1 :]
            if rest and rest[0] not in top_level_names(folder / f"{part}.py"):
                return f"{folder.relative_to(ROOT)}/{part}.py defines no {rest[0]}"
            return None
        elif part in top_level_names(folder / "__init__.py"):
            return None
        else:
            return f"no module {folder.relative_to(ROOT)}/{part}"
    return None


def references(page: Path) -> list[str]:
    text = page.read_text(encoding="utf-8")
    return SLASHED.findall(text) + [m.rstrip(".") for m in DOTTED.findall(text)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_module_path_a_page_names_exists(page):
    problems = []
    for reference in references(page):
        if "/" in reference:
            path = PACKAGE / reference.removeprefix("nlipscalib/")
            if not (path.exists() or path.with_suffix(".py").exists()):
                problems.append(f"{reference}: no such file or folder")
        elif why := dotted_problem(reference):
            problems.append(f"{reference}: {why}")
    assert not problems, f"{page.name}: " + "; ".join(problems)


def test_the_check_finds_a_moved_module_and_a_missing_function():
    assert dotted_problem("nlipscalib.solver.blas") == "no module nlipscalib/solver/blas"
    assert dotted_problem("core.cpus.no_such_function") == "nlipscalib/core/cpus.py defines no no_such_function"
    assert dotted_problem("nlipscalib.core.blas") is None
    assert dotted_problem("core.load_press") is None  # exported by core/__init__.py
    assert references(ROOT / "README.md"), "the README names modules: the patterns must find them"


LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)\s]*)?\)")
"""A Markdown link's relative target: ``[docs/api.md](docs/api.md)``, ``[the API](../api.md#solve)``."""


def relative_links(text: str) -> list[str]:
    return [target for target in LINK.findall(text) if not re.match(r"[a-z][a-z0-9+.-]*:", target)]


def test_every_relative_link_of_the_pages_and_the_notebook_reaches_a_file():
    """README and docs/ pages (not the RESULTS.md records) and the quickstart notebook's text cells link files by
    relative paths, which break silently when a page or the notebook moves (docs/examples/ is one level down)."""
    import json

    sources = {p: p.read_text(encoding="utf-8") for p in [ROOT / "README.md", *(ROOT / "docs").rglob("*.md")]}
    sources = {p: text for p, text in sources.items() if p.name != "RESULTS.md"}
    for notebook in (ROOT / "docs").rglob("*.ipynb"):
        cells = json.loads(notebook.read_text(encoding="utf-8"))["cells"]
        sources[notebook] = "\n".join("".join(c["source"]) for c in cells if c["cell_type"] == "markdown")
    links = [(page, target) for page, text in sources.items() for target in relative_links(text)]
    assert len(links) > 40  # the pattern reads the pages' links
    assert [f"{p.relative_to(ROOT)}: {t}" for p, t in links if not (p.parent / t).exists()] == []
    assert relative_links("[a](../api.md#solve) [b](https://x.org/y.md) [c](#top)") == ["../api.md"]
