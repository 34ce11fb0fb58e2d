"""Whether a finished file is whole, judged from a few bytes at its ends: for the decisions that reuse a file
written earlier (a press's images and arrays, a result's figures, an error map) rather than make it again.

Why: writes are atomic (a temporary, then a rename: core.atomic) but not synced, so after a power cut soon after
a command published its files a file renamed into place can come back empty or cut short (fsync of each file was
measured and dropped: 2-5 % of a solve, benchmarks/RESULTS.md s30-killwalk). A reuse decision that only saw the
file there kept it, and the command reading it failed later. Each format here ends with a fixed record that a file
cut short loses: a PNG its IEND chunk, a zip archive (.npz) its end-of-central-directory record. Reading those
bytes (and the signature at the start: a power cut may also leave a file's first block zeros) costs one open and
two short reads, not the file: ~10-20 us a file (benchmarks/RESULTS.md, s30-torn). Damage inside a file of whole
length (a bad disk block, a bad copy) is not seen from its ends: the readers check that as they decode, and
:func:`damage_inside` reads the whole file for it, for a command that would otherwise meet it late (``nlips calibrate``
checks each press's tri-colour image and ground truth before solving: the build that reads them comes after every
solve).
"""

from __future__ import annotations

import json
import os
import stat
import zipfile
import zlib
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


def damage_inside(path: str | Path, members: tuple[str, ...] | None = None) -> str | None:
    """Why the file at ``path``, whole at its ends, holds damage inside, from all of its bytes and the format's own
    checksums, in a few words ("damaged inside (chunk IDAT at byte 81931 fails its CRC-32 check)"); None when each
    checksum agrees (or the file is neither .png nor .npz).

    A PNG: each chunk's CRC-32 (:func:`png_checksum_problem`, ~1 ms for a 640x480 16-bit image, a few % of its
    decoding); an .npz: each member's CRC-32, inflated as a reader would (``members``: only those, e.g.
    ``("normals.npy",)``; the others are not read). The file's ends are :func:`file_problem`'s to judge.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".png":
            return png_checksum_problem(path.read_bytes())
        if suffix == ".npz":
            return _zip_members_problem(path, members)
    except FileNotFoundError:
        return MISSING
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return None


def png_checksum_problem(data: bytes | memoryview) -> str | None:
    """The first chunk of a PNG's bytes whose CRC-32 disagrees with its type and data, in words, or that runs past
    the file's end; None when every chunk agrees (the signature and the end chunk are :func:`file_problem`'s).

    Why here and not left to libpng: OpenCV's libpng meets the damage mid-decode and prints its own line on stderr
    ("libpng error: IDAT: CRC error", or "bad adaptive filter value" when the inflated rows go wrong before the
    chunk's check), and the reader's error could only say "not a readable PNG image"."""
    view = memoryview(data)
    pos, size = len(PNG_SIGNATURE), len(view)
    while pos + 12 <= size:  # length (4), type (4), data, CRC (4)
        length = int.from_bytes(view[pos : pos + 4], "big")
        end = pos + 8 + length
        kind = bytes(view[pos + 4 : pos + 8]).decode("latin-1")
        if end + 4 > size:
            return f"damaged inside (chunk {_chunk_name(kind)} at byte {pos} runs past the end of the file)"
        if zlib.crc32(view[pos + 4 : end]) != int.from_bytes(view[end : end + 4], "big"):
            return f"damaged inside (chunk {_chunk_name(kind)} at byte {pos} fails its CRC-32 check)"
        pos = end + 4
    return None


def _chunk_name(kind: str) -> str:
    """A PNG chunk's 4-letter type as printed: letters kept, any other byte (damage) as an escape."""
    return kind if kind.isalpha() and kind.isascii() else ascii(kind)


def _zip_members_problem(path: Path, members: tuple[str, ...] | None) -> str | None:
    """The first member of the zip archive at ``path`` (of ``members``, when given) whose bytes do not inflate or
    disagree with their CRC-32, in words; None when each agrees. zipfile compares the CRC once a member is read
    to its end; zlib fails first on a damaged deflate stream."""
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                if members is not None and info.filename not in members:
                    continue
                try:
                    with archive.open(info) as f:
                        while f.read(1 << 20):
                            pass
                except (zipfile.BadZipFile, zlib.error, EOFError) as exc:
                    return f"damaged inside (member {info.filename}: {exc})"
    except (zipfile.BadZipFile, EOFError, ValueError) as exc:
        return f"damaged (not a readable zip archive: {exc})"
    return None


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
