"""Every text file the package reads or writes names its encoding (UTF-8), so a lab on Windows, whose default is the
ANSI code page (cp1252), reads what Linux wrote: ``°``, ``µm``, a press named in another script (s26-portable).

ruff's PLW1514 (unspecified-encoding, preview only in ruff 0.17) sees ``Path(...).read_text()`` but not a path held
in a variable, which is most of ours; this walks the calls itself."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CHECKED = ("nlipscalib", "benchmarks", "tools", "tests")


def _text_mode(call: ast.Call) -> bool:
    """Whether an ``open(...)`` call opens in text mode (no mode given, or one without ``b``)."""
    mode = call.args[1] if len(call.args) > 1 else next((k.value for k in call.keywords if k.arg == "mode"), None)
    if mode is None:
        return True
    return not (isinstance(mode, ast.Constant) and isinstance(mode.value, str) and "b" in mode.value)


def unnamed_encodings(path: Path) -> list[int]:
    """Lines of ``path`` with ``open(...)`` in text mode, ``X.read_text()`` or ``X.write_text(text)`` that name no
    encoding (a ``**kwargs`` counts as naming one)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if not isinstance(node, ast.Call) or any(k.arg in ("encoding", None) for k in node.keywords):
            continue
        func = node.func
        if isinstance(func, ast.Name) and func.id == "open":
            unnamed = bool(node.args) and _text_mode(node)
        elif isinstance(func, ast.Attribute) and func.attr == "read_text":
            unnamed = not node.args
        elif isinstance(func, ast.Attribute) and func.attr == "write_text":
            unnamed = len(node.args) == 1  # Path.write_text(text); core.atomic.write_text(path, text) is UTF-8
        else:
            unnamed = False
        if unnamed:
            found.append(node.lineno)
    return found


def test_every_text_read_and_write_names_its_encoding():
    files = [p for folder in CHECKED for p in sorted((ROOT / folder).rglob("*.py"))]
    assert len(files) > 100  # the walk found the code
    missing = [f"{p.relative_to(ROOT)}:{line}" for p in files for line in unnamed_encodings(p)]
    assert not missing, "no encoding='utf-8' at " + ", ".join(missing)


def test_the_check_finds_a_text_write_without_its_encoding(tmp_path):
    code = tmp_path / "example.py"
    code.write_text(
        "from pathlib import Path\n"
        "p = Path('a.txt')\n"
        "p.write_text('deg')\n"
        "open(p, 'w')\n"
        "open(p, 'rb')\n"
        "p.read_text(encoding='utf-8')\n",
        encoding="utf-8",
    )
    assert unnamed_encodings(code) == [3, 4]
