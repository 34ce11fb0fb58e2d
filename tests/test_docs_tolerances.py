"""The tolerances the README and docs/ name exist, and a number they quote for one is its value now.

Thresholds move (``NO_CONTACT_PEAK`` went 8 -> 6 -> 8 in two sessions) and the prose that quotes them does not follow
by itself: a page quoting the refusal "a contact's above 6" after the code says 8, or "`tolerances.X` 0.75 px" after X
changed, sends a reader to the wrong threshold. benchmarks/RESULTS.md and docs/experiments/RESULTS.md are records of
their day and are not checked.
"""

from __future__ import annotations

import ast
import functools
import math
import re
from pathlib import Path

from nlipscalib.core import tolerances

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "nlipscalib"
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "docs" / "experiments" / "README.md"]
NAMED = re.compile(r"`(?:core\.)?tolerances\.([A-Z][A-Z0-9_]*)(\*?)`")
"""`tolerances.CAMERA_SHIFT_PX`, `core.tolerances.SATURATED_SHARE_WARN`, `tolerances.MAX_LED_*` (a prefix)."""
QUOTED = re.compile(
    r"`(?:(?:core\.)?tolerances\.)?([A-Z][A-Z0-9_]+)`[,:]?\s+\(?(\d+(?:\.\d+)?(?:e-?\d+)?)(?:\s+x\s+(\d+))?\s*(%)?"
)
"""A constant's name with its value right after it: "`tolerances.CAMERA_SHIFT_PX` 0.75 px", "`X`, 0.5 %",
"`tolerances.MAX_IMAGE_PIXELS`: 4096 x 4096", "`OTHER_CAPTURE_DEPTH_MM` (0.3 mm"."""
NUMBER = r"\s*(-?\d+(?:\.\d+)?(?:e-?\d+)?)"


def _pages() -> dict[str, str]:
    return {str(p.relative_to(ROOT)): p.read_text(encoding="utf-8") for p in PAGES}


def _constants() -> dict[str, float]:
    return {k: v for k, v in vars(tolerances).items() if k.isupper() and isinstance(v, int | float)}


def misquoted_values(text: str) -> list[str]:
    """Where ``text`` gives a tolerance's value beside its name and the value is another."""
    constants, wrong = _constants(), []
    for name, value, times, percent in QUOTED.findall(text):
        if name not in constants:
            continue
        quoted = float(value) * (int(times) if times else 1) / (100 if percent else 1)
        if not math.isclose(quoted, constants[name], rel_tol=1e-9):
            wrong.append(f"{name}: quoted {value}{' x ' + times if times else ''}{percent}, is {constants[name]:g}")
    return wrong


@functools.cache
def message_templates() -> tuple[tuple[str, str, str, str], ...]:
    """(where, text before, value, text after) for every f-string of the package that formats a tolerance
    (``f"a contact's above {tolerances.NO_CONTACT_PEAK:g}, and ..."``): the value as the message writes it, between
    the words around it (the last three before, the first two after)."""
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, ast.JoinedStr):
                continue
            parts = node.values
            for i, part in enumerate(parts):
                if not (isinstance(part, ast.FormattedValue) and "tolerances." in ast.unparse(part.value)):
                    continue
                try:  # tolerances.X or arithmetic on it; a call of another helper is left out
                    value = eval(ast.unparse(part.value), {"tolerances": tolerances})  # noqa: S307 - the package's own source
                except NameError:
                    continue
                spec = "".join(c.value for c in part.format_spec.values) if part.format_spec else ""
                before = parts[i - 1].value if i and isinstance(parts[i - 1], ast.Constant) else ""
                after = parts[i + 1].value if i + 1 < len(parts) and isinstance(parts[i + 1], ast.Constant) else ""
                before, after = " ".join(before.split()[-3:]), " ".join(after.split()[:2])
                if len(before) >= 8 and (after or i + 1 == len(parts)):  # at the message's end: no words after
                    where = f"{path.relative_to(ROOT)}:{node.lineno}"
                    found.append((where, before, format(value, spec), after))
    return tuple(found)


def _words(text: str) -> str:
    """A regex of ``text`` whose spaces match any run of whitespace (a page wraps its lines)."""
    return r"\s+".join(re.escape(word) for word in text.split())


def quoted_messages(text: str) -> list[tuple[str, str, str]]:
    """(where, value the code writes, value quoted) for each place ``text`` quotes a message's words around a
    tolerance with a number between them."""
    quotes = []
    for where, before, value, after in message_templates():
        pattern = _words(before) + NUMBER + (r"\s*" + _words(after) if after else r"(?![\d.])")
        quotes += [(f"'{before} {quoted} {after}' ({where})", value, quoted) for quoted in re.findall(pattern, text)]
    return quotes


def misquoted_messages(text: str) -> list[str]:
    """Where ``text`` quotes a message's words around a tolerance with another number between them."""
    return [
        f"{quote}: the message says {value}"
        for quote, value, quoted in quoted_messages(text)
        if not math.isclose(float(quoted), float(value), rel_tol=1e-9)
    ]


def test_every_tolerance_a_page_names_exists():
    names = set(_constants()) | {k for k in vars(tolerances) if k.isupper()}
    missing = [
        f"{page}: tolerances.{name}{star}"
        for page, text in _pages().items()
        for name, star in NAMED.findall(text)
        if not (any(n.startswith(name) for n in names) if star else name in names)
    ]
    assert not missing


def test_a_value_a_page_quotes_beside_a_tolerance_is_its_value():
    pages = _pages()
    assert sum(len(QUOTED.findall(t)) for t in pages.values()) > 4  # the pattern finds the pages' quotes
    assert [f"{page}: {w}" for page, text in pages.items() for w in misquoted_values(text)] == []


def test_a_message_a_page_quotes_gives_the_tolerance_the_code_formats_into_it():
    pages = _pages()
    assert any(before.endswith("contact's above") for _, before, _, _ in message_templates())
    assert len(quoted_messages(pages["docs/faults.md"])) >= 2  # the no-contact refusal's peak and patch at least
    assert [f"{page}: {w}" for page, text in pages.items() for w in misquoted_messages(text)] == []


def test_the_checks_find_a_stale_threshold():
    """The no-contact refusal quoted with NO_CONTACT_PEAK's old 6, a stale quoted value, a constant renamed."""
    peak = f"{tolerances.NO_CONTACT_PEAK:g}"
    assert misquoted_messages(f"misfit is 4.7 times its floor, a contact's above {peak}, and no patch") == []
    assert misquoted_messages("misfit is 4.7 times its floor, a contact's\n  above 6, and no patch")
    assert misquoted_values("(`tolerances.CAMERA_SHIFT_PX` 0.5 px)") == []
    assert misquoted_values("(`tolerances.CAMERA_SHIFT_PX` 0.75 px)")
    assert misquoted_values("`tolerances.DARK_FRAME_OFFSET`, 0.5 % of full scale") == []
    assert misquoted_values("`tolerances.MAX_IMAGE_PIXELS`: 4096 x 4096") == []
    assert misquoted_values("`tolerances.MAX_IMAGE_PIXELS`: 4096 x 2048")
    assert NAMED.findall("`tolerances.NO_SUCH_THING`") == [("NO_SUCH_THING", "")]
