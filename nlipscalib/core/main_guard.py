"""A script's call that starts worker processes, checked to lie under its ``if __name__ == "__main__":`` guard."""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from types import FrameType

from .errors import ConfigError


def check_main_guarded(what: str, in_process: str = "workers=1") -> None:
    """ConfigError naming the script and line when ``what`` (e.g. "solve_presses(..., workers=2)") is run by a
    statement at a script's top level outside its ``if __name__ == "__main__":`` block; nothing in a notebook,
    ``python -c``, an imported module or the ``nlips`` command (no script of the caller's is ``__main__``).
    ``in_process``: the caller's arguments that run the work in this process, the message's other way out
    (a local Dask cluster's: ``scheduler=None``, not ``workers=1``).

    Why: the worker processes (forkserver or spawn) import the caller's script again, and so ran its call again,
    which failed in each of them with multiprocessing's "An attempt has been made to start a new process before the
    current process has finished its bootstrapping phase" traceback, and the call returned every press as "a solver
    process was killed (by a signal or for lack of memory)" (s36-apiwalk)."""
    main = sys.modules.get("__main__")
    path = getattr(main, "__file__", None)
    if main is None or not isinstance(path, str) or not path.endswith(".py"):
        return
    top = _script_frame(main.__dict__)
    if top is None:  # not called from the running script (a thread, an atexit function)
        return
    try:
        tree = ast.parse(Path(path).read_text(encoding="utf-8"))
    except (OSError, SyntaxError, ValueError):  # the script's file is gone or changed: no verdict
        return
    # any guard holding the line: also one inside a top-level block (a `with`, a `try`)
    if not any(_guards(node) and node.lineno <= top.f_lineno <= (node.end_lineno or 0) for node in ast.walk(tree)):
        raise ConfigError(
            f"{path}, line {top.f_lineno}: {what} at the script's top level: its worker processes import the script "
            'again and would run it too; call it under `if __name__ == "__main__":` '
            f"(or with {in_process})"
        )


def _script_frame(main_globals: dict) -> FrameType | None:
    """The frame running the script's top level (its module code), or None."""
    frame = sys._getframe(1)
    while frame is not None and not (frame.f_globals is main_globals and frame.f_code.co_name == "<module>"):
        frame = frame.f_back
    return frame


def _guards(node: ast.stmt) -> bool:
    """Whether ``node`` is ``if __name__ == "__main__":`` (either way round)."""
    if not isinstance(node, ast.If) or not isinstance(node.test, ast.Compare) or len(node.test.comparators) != 1:
        return False
    if not isinstance(node.test.ops[0], ast.Eq):
        return False
    sides = {_text(node.test.left), _text(node.test.comparators[0])}
    return sides == {"name:__name__", "str:__main__"}


def _text(node: ast.expr) -> str | None:
    if isinstance(node, ast.Name):
        return f"name:{node.id}"
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return f"str:{node.value}"
    return None
