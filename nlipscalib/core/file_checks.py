"""Whether a finished file is whole, judged from a few bytes at its ends: for the decisions that reuse a file
written earlier (a press's images and arrays, a result's figures, an error map) rather than make it again.

Why: writes are atomic (a temporary, then a rename: core.atomic) but not synced, so after a power cut soon after
a command published its files a file renamed into place can come back empty or cut short (fsync of each file was
measured and dropped: 2-5 % of a solve, benchmarks/RESULTS.md s30-killwalk). A reuse decision that only saw the
file there kept it, and the command reading it failed later. Each format here ends with a fixed record that a file
cut short loses: a PNG its IEND chunk, a zip archive (.npz) its end-of-central-directory record. Reading those
bytes (and the signature at the start: a power cut may also leave a file's first block zeros) costs one open and
two short reads, not the file: ~10-20 us a file (benchmarks/RESULTS.md, s30-torn). Damage inside a file of whole
length (a bad disk block) is not seen here: the readers check that as they decode.
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
from pathlib import Path
from typing import BinaryIO

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
"""The 8 bytes every PNG file starts with."""
PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""The 12 bytes every PNG file ends with: its IEND chunk (length 0, type, CRC), the last chunk of the format."""
ZIP_SIGNATURE = b"PK"
"""The start of every zip archive (.npz): a local file header ``PK\\x03\\x04``, or an empty archive's end record."""
ZIP_END = b"PK\x05\x06"
"""The signature of a zip archive's end-of-central-directory record (its last 22 bytes when it has no comment)."""
ZIP_END_SIZE = 22
"""Bytes of the end-of-central-directory record without a comment (NumPy's .npz never has one)."""
JSON_MOST_BYTES = 1 << 20
"""A .json file up to this size is parsed in full to judge it (a press's meta.json, a report: kilobytes); a larger
one only for being empty."""

MISSING, EMPTY = "missing", "empty"
""":func:`file_problem`'s words for a file that is not there (or not a regular file) and for one of 0 bytes."""


def file_problem(path: str | Path) -> str | None:
    """Why the finished file at ``path`` cannot be reused as it is, in a few words ("missing", "empty", "cut short
    (no PNG end chunk)"), or None when it looks whole.

    A .png must start with the PNG signature and end with its IEND chunk; an .npz (a zip archive) start with
    ``PK`` and end with its end-of-central-directory record; a .json (up to :data:`JSON_MOST_BYTES`) parse; any
    other file be there and not empty. Only the bytes at the ends are read (a JSON file whole).

    Parameters
    ----------
    path : the file
    """
    path = Path(path)
    try:
        st = path.stat()  # before opening: a folder or a pipe of that name is no file (and a pipe would block)
        if not stat.S_ISREG(st.st_mode):
            return MISSING
        if st.st_size == 0:
            return EMPTY
        suffix = path.suffix.lower()
        if suffix not in (".png", ".npz", ".json"):
            return None
        with open(path, "rb") as f:
            if suffix == ".png":
                return _png_problem(f, st.st_size)
            if suffix == ".npz":
                return _zip_problem(f, st.st_size, path)
            return _json_problem(f.read()) if st.st_size <= JSON_MOST_BYTES else None
    except FileNotFoundError:
        return MISSING
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"


def unusable_files(folder: str | Path, names: list[str]) -> list[str]:
    """The names in ``names`` whose file in ``folder`` is missing, empty or cut short (:func:`file_problem`)."""
    folder = Path(folder)
    return [name for name in names if file_problem(folder / name) is not None]


def described_problems(folder: str | Path, names: list[str], most: int = 3) -> str:
    """``names`` (:func:`unusable_files` of ``folder``) in words: "led_02.png missing, led_05.png cut short (no PNG
    end chunk) and 2 more"."""
    said = [f"{name} {file_problem(Path(folder) / name) or 'whole now'}" for name in names[:most]]
    return ", ".join(said) + (f" and {len(names) - most} more" if len(names) > most else "")


def _png_problem(f: BinaryIO, size: int) -> str | None:
    if f.read(len(PNG_SIGNATURE)) != PNG_SIGNATURE:
        return "damaged (no PNG signature at its start)"
    if size < len(PNG_SIGNATURE) + len(PNG_END):
        return "cut short (no PNG end chunk)"
    f.seek(-len(PNG_END), os.SEEK_END)
    return None if f.read() == PNG_END else "cut short (no PNG end chunk)"


def _zip_problem(f: BinaryIO, size: int, path: Path) -> str | None:
    if f.read(len(ZIP_SIGNATURE)) != ZIP_SIGNATURE:
        return "damaged (no zip signature at its start)"
    if size >= ZIP_END_SIZE:
        f.seek(-ZIP_END_SIZE, os.SEEK_END)
        end = f.read()
        if end.startswith(ZIP_END) and end[-2:] == b"\0\0":  # the record, with no comment after it
            return None
    # an archive with a comment (not NumPy's): the standard library looks for its record in the last 64 KiB
    return None if zipfile.is_zipfile(path) else "cut short (no zip end record)"


def _json_problem(data: bytes) -> str | None:
    try:
        json.loads(data)
    except ValueError:  # JSONDecodeError, UnicodeDecodeError
        return "cut short or damaged (not valid JSON)"
    return None
