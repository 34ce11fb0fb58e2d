"""The package boundaries of the README: core/ imports nothing of the package above it; solver/ never imports
sim/ or device/; learn/ never imports solver/; device/ never imports sim/ (lazy imports count too)."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "nlipscalib"

# package -> the top-level parts of nlipscalib it must not import
FORBIDDEN = {"solver": {"sim", "device"}, "learn": {"solver"}, "device": {"sim"}}


def imported_modules(path: Path) -> list[tuple[int, str]]:
    """Every ``nlipscalib...`` module (or module.name) that ``path`` imports, with its line, relative ones resolved."""
    here = ["nlipscalib", *path.relative_to(PACKAGE).parent.parts]
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.ImportFrom):
            base = here[: len(here) - node.level + 1] if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            found += [(node.lineno, f"{module}.{alias.name}") for alias in node.names]
        elif isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
    return [(line, name) for line, name in found if name.split(".")[0] == "nlipscalib"]


def test_core_imports_nothing_outside_core_but_the_version():
    wrong = [
        f"{path.relative_to(PACKAGE)}:{line}: {name}"
        for path in sorted((PACKAGE / "core").rglob("*.py"))
        for line, name in imported_modules(path)
        if not name.startswith("nlipscalib.core.") and name != "nlipscalib.__version__"
    ]
    assert not wrong, wrong


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_packages_import_only_what_the_layout_allows(package):
    wrong = [
        f"{path.relative_to(PACKAGE)}:{line}: {name}"
        for path in sorted((PACKAGE / package).rglob("*.py"))
        for line, name in imported_modules(path)
        if name.split(".")[1] in FORBIDDEN[package]
    ]
    assert not wrong, wrong
