"""Exceptions shared by every part of the workbench.

All are ``ValueError`` subclasses so that callers who only know numpy-style errors still catch them;
the CLI turns them into one readable line instead of a traceback.
"""

from __future__ import annotations

import numbers
import os
import reprlib
from collections.abc import Mapping
from types import ModuleType


class NlipsError(ValueError):
    """Base class of every error the workbench raises on purpose."""


class ConfigError(NlipsError):
    """A scene, press or dataset spec is wrong (the message names the file and the key)."""


class CaptureError(NlipsError):
    """A press folder is missing something or holds inconsistent data (the message names the file)."""


class NoContactError(CaptureError):
    """``--roi auto`` found no contact: the press's images match the undeformed dome within noise. A folder solve
    notes the press and goes on (not a failure); ``nlips solve PRESS`` refuses it in one line."""


class DeviceError(NlipsError):
    """The LED controller or camera failed: port missing, no permission, no answer, wrong firmware, reset."""


class ShapeError(NlipsError):
    """An argument given to a public function has the wrong shape, dtype or kind (:func:`check_kind`)."""


class MissingDependencyError(ImportError):
    """An optional heavy dependency (mitsuba, OpenCV, onnxruntime, pyserial, torch) is not installed."""


def require(module: str, extra: str, purpose: str) -> ModuleType:
    """Import an optional module or fail with a message saying how to install it.

    Parameters
    ----------
    module : str
        Importable module name, e.g. ``"cv2"``.
    extra : str
        pip requirement that provides it, e.g. ``"opencv-python-headless"``.
    purpose : str
        What needs it, shown to the user.
    """
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise MissingDependencyError(
            f"{purpose} needs the optional package '{module}'. Install it with: pip install {extra}"
        ) from exc


PATH = (str, os.PathLike)
"""What a path argument may be (``str`` or ``pathlib.Path``), for :func:`check_kind`."""
NUMBER = numbers.Real
"""What a number argument may be (int, float, NumPy's scalars; a bool never), for :func:`check_kind`."""


def check_paths(
    values: object, name: str, what: str, kinds: type | tuple[type, ...] = PATH, each: str = "a path (str or Path)"
) -> list:
    """``values`` as a list, ShapeError naming ``name`` unless it is an iterable (a list, a tuple, a generator) of
    ``kinds`` (default paths, str or Path; ``each`` says what one must be): one path alone, whose characters would be
    taken for paths, is refused with ``what`` and how to give one (``[path]``).

    A dict is refused too (its keys would be taken).

    Why: ``solve_presses("out/press")`` went through the string's characters as press folders; ``solve_presses(3)``
    and ``build_dataset([3], ...)`` failed with Python's "'int' object is not iterable" or "expected str, bytes or
    os.PathLike object" from inside (s37 capcheck)."""
    if isinstance(values, PATH) and str in _as_tuple(kinds):
        raise ShapeError(f"{name} must be {what}, got one path {os.fspath(values)!r}: give [{os.fspath(values)!r}]")
    try:
        if isinstance(values, (str, bytes, Mapping)):  # its characters, or a dict's keys: not what was meant
            raise TypeError
        listed = list(values)
    except TypeError:
        raise ShapeError(f"{name} must be {what}, got {type(values).__name__} {reprlib.repr(values)}") from None
    for i, value in enumerate(listed):
        check_kind(value, kinds, f"{name}[{i}]", each)
    return listed


def check_kind(value: object, kinds: type | tuple[type, ...], name: str, what: str) -> None:
    """ShapeError "``name`` must be ``what``, got ..." unless ``value`` is one of ``kinds`` (``bool`` is never taken
    for a number).

    Why: the public functions of docs/api.md given another kind of argument (``load_press(3)``,
    ``save_reconstruction("x", folder)``, ``save_leds(path, [1, 2])``) failed with Python's own TypeError or
    AttributeError from deep inside them; an isinstance test at entry costs well under a microsecond
    (s36-apileft)."""
    if isinstance(value, kinds) and not (isinstance(value, bool) and bool not in _as_tuple(kinds)):
        return
    raise ShapeError(f"{name} must be {what}, got {type(value).__name__} {reprlib.repr(value)}")


def _as_tuple(kinds: type | tuple[type, ...]) -> tuple[type, ...]:
    return kinds if isinstance(kinds, tuple) else (kinds,)


def check_flag(value: object, name: str, none: bool = False) -> None:
    """ShapeError "``name`` must be True or False, got ..." unless ``value`` is a bool (NumPy's too; None with
    ``none``).

    Why: a flag given as a string (``solve_press(press, check_sensor="no")``, ``solve_folder(press, overwrite="no")``)
    is truthy and did the opposite of what it said, without a word (s38-apikinds)."""
    numpy_bool = type(value).__module__ == "numpy" and type(value).__name__ in ("bool", "bool_")
    if isinstance(value, bool) or numpy_bool or (none and value is None):
        return
    raise ShapeError(
        f"{name} must be True or False{' or None' if none else ''}, got {type(value).__name__} {reprlib.repr(value)}"
    )


def check_whole(value: object, name: str, minimum: int = 0) -> int:
    """``value`` unless it is not a whole number (an int or NumPy's, never a bool nor a float such as 2.0: a
    ShapeError) or is below ``minimum`` (a ConfigError); both name ``name``.

    Why: counts given as 2.0, "2" or -1 (``run_experiment(..., workers="2")``, ``solve_press(..., max_outer=-1)``)
    failed in Python's comparison of str and int deep inside, or ran with a meaningless count (s38-apikinds)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ShapeError(
            f"{name} must be a whole number >= {minimum}, got {type(value).__name__} {reprlib.repr(value)}"
        )
    if value < minimum:
        raise ConfigError(f"{name} must be a whole number >= {minimum}, got {value}")
    return int(value)
