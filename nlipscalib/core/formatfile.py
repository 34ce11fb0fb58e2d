"""Reading the workbench's files: the JSON header every format carries (``format``, ``format_version``),
checked once, and the .npz archives of arrays, with every problem one error naming the file."""

from __future__ import annotations

import contextlib
import json
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from .errors import CaptureError

if TYPE_CHECKING:  # named in hints only
    import numpy as np


def read_format_json(
    path: str | Path,
    name: str,
    version: int | tuple[int, ...],
    *,
    required: Iterable[str] = (),
    missing_hint: str = "",
    remake: str | Callable[[dict], str] = "",
) -> dict:
    """Read a JSON file of format ``name`` and version ``version`` (or one of several); every problem names the file.

    Parameters
    ----------
    path : the JSON file (meta.json, report.json, index.json ...)
    name, version : the expected ``format`` and ``format_version`` values (a tuple: the versions still read)
    required : top-level keys that must be present
    missing_hint : appended to the message when the file does not exist (what the user should run)
    remake : what makes the file anew with this nlipscalib (or a function of the file's content that says it),
        appended when its version is one this code does not read; a version above those read is also said to
        be a newer nlipscalib's

    Raises
    ------
    CaptureError -- missing, not JSON, another format or version, or a required key missing.
    """
    path = Path(path)
    hint = f"; {missing_hint}" if missing_hint else ""
    if path.parent.is_file():  # "FILE/index.json: missing" sent the user looking inside a file
        raise CaptureError(f"{path.parent}: a file, not a folder{hint}")
    if not path.parent.exists():
        raise CaptureError(f"{path.parent}: no such folder")
    if not path.is_file():
        raise CaptureError(f"{path}: missing{hint}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CaptureError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != name:
        raise CaptureError(f"{path}: 'format' must be {name!r}")
    versions = version if isinstance(version, tuple) else (version,)
    if data.get("format_version") not in versions:
        raise CaptureError(version_problem(path, data, versions, remake))
    for key in required:
        if key not in data:
            raise CaptureError(f"{path}: missing key '{key}'")
    return data


def version_problem(
    path: str | Path, data: dict, versions: tuple[int, ...], remake: str | Callable[[dict], str] = ""
) -> str:
    """The one line refusing a file whose ``format_version`` is not among ``versions``: the file, its version,
    those read, and what to do: upgrade nlipscalib for a newer file, ``remake`` (what makes it anew) for any."""
    found = data.get("format_version")
    names = [str(v) for v in versions]
    expected = " or ".join([", ".join(names[:-1]), names[-1]] if len(names) > 2 else names)  # "1, 2 or 3"
    line = f"{path}: format_version {found!r} is not supported (expected {expected})"
    advice = remake(data) if callable(remake) else remake
    if isinstance(found, int) and not isinstance(found, bool) and found > max(versions):
        newer = "written by a newer nlipscalib: upgrade nlipscalib to read it"
        return f"{line}; {newer}" + (f", or {advice}" if advice else "")
    return line + (f"; {advice}" if advice else "")


def read_arrays(
    path: str | Path,
    keys: Iterable[str] = (),
    unreadable: str = "damaged or truncated .npz",
    only: Iterable[str] | None = None,
) -> dict:
    """Every array of a .npz file (or those named in ``only``: :func:`nlipscalib.core.imageio.read_npz`), any
    damage one CaptureError.

    ``read_npz`` names a missing file, a truncated archive (no zip directory) and a bad CRC; a flipped
    byte inside a deflated array instead fails in zlib's decompressor (``zlib.error``, which is not an
    OSError), and a damaged array header in numpy's parser (struct or Unicode errors): those are named
    here alike, so a reading command prints one line, and a command that makes the file can make it again.

    Raises
    ------
    CaptureError -- missing, damaged or truncated, or lacking one of ``keys``.
    """
    from .imageio import read_npz

    with _damage_named(path, unreadable):
        return read_npz(path, keys, unreadable=unreadable, only=only)


def read_array_headers(
    path: str | Path, keys: Iterable[str] = (), unreadable: str = "damaged or truncated .npz"
) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """(shape, dtype) of every array of a .npz file, without inflating them (:func:`nlipscalib.core.imageio.
    npz_headers`); any damage one CaptureError, as :func:`read_arrays` names it."""
    from .imageio import npz_headers

    with _damage_named(path, unreadable):
        return npz_headers(path, keys, unreadable=unreadable)


@contextlib.contextmanager
def _damage_named(path: str | Path, unreadable: str) -> Iterator[None]:
    """The errors of a damaged archive that :func:`nlipscalib.core.imageio.read_npz` leaves unnamed, as one
    CaptureError naming ``path`` (:func:`read_arrays`)."""
    import struct
    import zlib

    try:
        yield
    except (zlib.error, struct.error, UnicodeDecodeError, NotImplementedError, OverflowError, MemoryError) as exc:
        what = "compressed data damaged" if isinstance(exc, zlib.error) else type(exc).__name__
        raise CaptureError(f"{path}: {unreadable} ({what}: {exc})") from None
