"""The package constants outside core/tolerances.py that the README and docs/ name exist, a number quoted beside
one is its value, and every docs section that a message or a page points to ("docs/formats.md, Cameras") is a
heading of that page.

tests/test_docs_tolerances.py checks `tolerances.NAME`; the same drift happens to other modules' constants
(`learn.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS` (20,000), `progress.BAR_LOCK_WAIT_S` (1 s)) and to the sections that
warnings send a user to (s27-docs2). Read from the source with ``ast``: nothing is imported.
"""

from __future__ import annotations

import ast
import functools
import math
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "nlipscalib"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "docs" / "experiments" / "README.md"]
NAMED = re.compile(r"`((?:[a-z_]+\.)+)([A-Z][A-Z0-9_]*)`")
"""`learn.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS`, `progress.BAR_LOCK_WAIT_S`: a module path (from the package, or the
tail of one: `press.CACHE_SIZE`), then the constant."""
QUOTED = re.compile(
    r"`((?:[a-z_]+\.)+)([A-Z][A-Z0-9_]*)`[,:]?\s+\(?(\d{1,3}(?:,\d{3})+|\d+(?:\.\d+)?(?:e-?\d+)?)\s*(%)?"
)
"""A constant with a number right after it: "`learn.model.BATCHNORM_EPS`, 1e-5", "`X` (20,000)", "`X` (1 s"."""
SECTION = re.compile(r"docs/([\w/]+\.md),?\s+(?:\"([^\"]+)\"|([A-Z][\w'-]*)(?=[);]))")
"""A pointer to a page's section: 'docs/formats.md, "Files from others"', "(docs/formats.md, Cameras)"."""


def _pages() -> dict[str, str]:
    return {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in PAGES}


@functools.cache
def _modules(dotted: str) -> tuple[Path, ...]:
    """The package's source file of module path ``dotted`` ("learn.integrate"), else those whose path ends with it
    ("press": sim/press.py and solver/press.py); empty when none does."""
    parts = dotted.split(".")
    exact = [PACKAGE.joinpath(*parts).with_suffix(".py"), PACKAGE.joinpath(*parts, "__init__.py")]
    if found := [p for p in exact if p.is_file()]:
        return tuple(found[:1])
    tails = PACKAGE.rglob(f"{parts[-1]}.py")
    return tuple(
        sorted(p for p in tails if p.relative_to(PACKAGE).with_suffix("").parts[-len(parts) :] == tuple(parts))
    )


def _lookup(dotted: str, name: str) -> tuple[bool, object]:
    """Whether one of :func:`_modules` defines ``name``, and its literal value (None where not a literal)."""
    for path in _modules(dotted):
        if name in (constants := _constants(path)):
            return True, constants[name]
    return False, None


@functools.cache
def _constants(path: Path) -> dict[str, object]:
    """Module-level UPPER_CASE names of ``path`` and their literal values (None where not a literal)."""
    found: dict[str, object] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        targets = (
            node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        )
        for target in targets:
            if isinstance(target, ast.Name) and target.id.isupper() and node.value is not None:
                try:
                    found[target.id] = ast.literal_eval(node.value)
                except ValueError:
                    found[target.id] = None
    return found


def unknown_constants(text: str) -> list[str]:
    """The `module.NAME` of ``text`` that name no module of the package or no constant of it."""
    missing = []
    for dotted, name in NAMED.findall(text):
        if not _lookup(dotted.rstrip("."), name)[0]:
            missing.append(f"{dotted}{name}" + ("" if _modules(dotted.rstrip(".")) else " (no such module)"))
    return missing


def misquoted_values(text: str) -> list[str]:
    """Where ``text`` gives a constant's value beside its name and the value is another."""
    wrong = []
    for dotted, name, number, percent in QUOTED.findall(text):
        value = _lookup(dotted.rstrip("."), name)[1]
        if isinstance(value, bool) or not isinstance(value, int | float):
            continue
        quoted = float(number.replace(",", "")) / (100 if percent else 1)
        if not math.isclose(quoted, value, rel_tol=1e-9):
            wrong.append(f"{dotted}{name}: quoted {number}{percent}, is {value:g}")
    return wrong


def _source_strings() -> dict[str, str]:
    """Every string of the package's source (messages, docstrings), per file: implicitly concatenated parts are
    one constant (f-strings: their constant parts joined), whitespace runs one space."""
    found = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        texts = []
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                texts.append(node.value)
            elif isinstance(node, ast.JoinedStr):
                texts.append("{}".join(p.value for p in node.values if isinstance(p, ast.Constant)))
        found[str(path.relative_to(ROOT))] = " ".join(" ".join(t.split()) for t in texts)
    return found


@functools.cache
def _headings(page: str) -> tuple[str, ...]:
    path = ROOT / "docs" / page
    if not path.is_file():
        return ()
    lines = path.read_text(encoding="utf-8").splitlines()
    return tuple(line.lstrip("#").strip().replace("`", "") for line in lines if line.startswith("#"))


def dangling_sections(text: str) -> list[str]:
    """The 'docs/PAGE.md, "Section"' pointers of ``text`` whose page has no heading starting with that section."""
    missing = []
    for page, quoted, bare in SECTION.findall(" ".join(text.split())):
        section = quoted or bare
        if not any(heading.startswith(section) for heading in _headings(page)):
            missing.append(f'docs/{page}, "{section}"')
    return missing


def test_every_constant_a_page_names_exists():
    pages = _pages()
    assert sum(len(NAMED.findall(t)) for t in pages.values()) > 10  # the pattern finds the pages' names
    assert [f"{page}: {m}" for page, text in pages.items() for m in unknown_constants(text)] == []


def test_a_value_a_page_quotes_beside_a_constant_is_its_value():
    pages = _pages()
    assert sum(len(QUOTED.findall(t)) for t in pages.values()) >= 3
    assert [f"{page}: {w}" for page, text in pages.items() for w in misquoted_values(text)] == []


def test_every_docs_section_a_message_or_page_points_to_is_a_heading():
    sources, pages = _source_strings(), _pages()
    assert sum(len(SECTION.findall(t)) for t in sources.values()) >= 10  # the messages' pointers are found
    assert 'docs/formats.md, "Cameras"' in sources["nlipscalib/core/sensor_response.py"]  # the camera messages' guide
    found = [f"{where}: {m}" for where, text in {**sources, **pages}.items() for m in dangling_sections(text)]
    assert found == []


def test_the_checks_find_a_renamed_constant_a_stale_value_and_a_renamed_section():
    assert unknown_constants("`learn.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS`, `press.CACHE_SIZE`") == []
    assert unknown_constants("`learn.integrate.SPARSE_MIN_UNKNOWNS`") == ["learn.integrate.SPARSE_MIN_UNKNOWNS"]
    assert unknown_constants("`lern.integrate.X`") == ["lern.integrate.X (no such module)"]
    assert misquoted_values("`learn.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS` (20,000) changed pixels") == []
    assert misquoted_values("`learn.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS` (10,000) changed pixels")
    assert misquoted_values("`progress.BAR_LOCK_WAIT_S` (2 s: a draw") == ["progress.BAR_LOCK_WAIT_S: quoted 2, is 1"]
    assert dangling_sections("gamma off (docs/formats.md, Cameras); the solve") == []
    assert dangling_sections('(docs/formats.md, "Files from others")') == []
    assert dangling_sections("(docs/formats.md, Webcams); the solve") == ['docs/formats.md, "Webcams"']
    assert dangling_sections('docs/protocol.md, "Line speed"') == ['docs/protocol.md, "Line speed"']
