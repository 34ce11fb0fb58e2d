"""A press folder's record of its files as written: ``checksums.json``, each listed file's size and CRC-32, written
with the folder (before meta.json, inside its atomic write) and compared when a finished press is reused.

Why: a rerun of ``nlips dataset`` kept a finished press whose image had changed since it was written while staying
whole at its ends (core.file_checks reads only those): a bad disk block or copy inside a file, or another press's
image copied over it. The press was "already there", and the damage met late, in a solve or in training (the
readers' own checks), or never (a whole image from another press). The size is compared on every rerun: the
``stat`` the end check makes anyway, one small JSON read a press. The CRC-32 reads every byte, so only when asked
(``nlips dataset --verify``): ~25 ms a 640x480 press with the files in the page cache, the disk's read rate when
not (benchmarks/RESULTS.md, s33-datacheck). A folder without the record (written before it existed, or copied
without it) is judged as before: by its files' ends, and with ``verify`` by the formats' own checksums
(:func:`.file_checks.damage_inside`).

Why CRC-32 (zlib's): it finds any accidental change (all bursts up to 32 bits, others but for 1 in 2**32), and is
the fastest hash in the standard library here, 1.6 GB/s against 0.8 for SHA-1 and 0.34 for BLAKE2b (same bench).
It is not meant to resist a forger: nothing here is.
"""

from __future__ import annotations

import json
import os
import zlib
from pathlib import Path

from .atomic import write_json
from .file_checks import damage_inside, file_problem

CHECKSUMS_FILE = "checksums.json"
"""The record's name in a press folder (docs/formats.md, "Capture format")."""
CHECKSUMS_FORMAT = "nlipscalib.checksums"
CHECKSUMS_VERSION = 1
READ_CHUNK = 1 << 20
"""Bytes read at a time for a file's CRC-32 (a 640x480 ground truth is ~8 MB: not held whole)."""


def file_crc32(path: str | Path) -> str:
    """CRC-32 (zlib's) of the file at ``path``, as 8 lower-case hex digits."""
    crc = 0
    with open(path, "rb") as f:
        while chunk := f.read(READ_CHUNK):
            crc = zlib.crc32(chunk, crc)
    return f"{crc:08x}"


def write_checksums(folder: str | Path, names: list[str]) -> Path:
    """Write ``folder``'s checksums.json recording each of ``names`` (files in ``folder``) as it is now: its size in
    bytes and CRC-32. Called on a folder being written (core.atomic.atomic_dir), before its meta.json."""
    folder = Path(folder)
    files = {name: {"bytes": os.stat(folder / name).st_size, "crc32": file_crc32(folder / name)} for name in names}
    record = {"format": CHECKSUMS_FORMAT, "format_version": CHECKSUMS_VERSION, "files": files}
    return write_json(folder / CHECKSUMS_FILE, record)


def read_checksums(folder: str | Path) -> dict[str, dict]:
    """``folder``'s recorded files, {name: {"bytes": int, "crc32": str}}; {} when it has no readable record (none
    written: an older nlipscalib, a copy without it; or the record itself damaged): its files are then judged
    without it. Entries of another shape are left out."""
    try:
        record = json.loads((Path(folder) / CHECKSUMS_FILE).read_bytes())
        if record.get("format") != CHECKSUMS_FORMAT or record.get("format_version") != CHECKSUMS_VERSION:
            return {}
        files = record["files"]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}
    if not isinstance(files, dict):
        return {}
    return {
        name: entry
        for name, entry in files.items()
        if isinstance(entry, dict) and isinstance(entry.get("bytes"), int) and isinstance(entry.get("crc32"), str)
    }


def press_file_problems(folder: str | Path, names: list[str], verify: bool = False) -> dict[str, str]:
    """Why each of ``names`` (files in press folder ``folder``) cannot be reused, in a few words, for those that
    cannot: missing, empty or cut short (:func:`.file_checks.file_problem`), or of another size than checksums.json
    records; with ``verify`` also of another CRC-32 than recorded, or (a file the record does not list) damaged
    inside by its format's own checksums. {} when every one looks whole. In the order of ``names``.

    Parameters
    ----------
    folder : the press folder
    names : the files its meta.json lists (core.press_meta.listed_files)
    verify : read every byte of each file (its CRC-32); else only its ends and its size
    """
    folder = Path(folder)
    recorded = read_checksums(folder)
    problems = {}
    for name in names:
        path = folder / name
        problem = file_problem(path)
        if problem is None and name in recorded:
            problem = _recorded_problem(path, recorded[name], verify)
        elif problem is None and verify:
            problem = damage_inside(path)
        if problem is not None:
            problems[name] = problem
    return problems


def described_file_problems(problems: dict[str, str], most: int = 3) -> str:
    """``problems`` (:func:`press_file_problems`) in words: "led_02.png missing, led_05.png cut short (no PNG end
    chunk) and 2 more"."""
    said = [f"{name} {problem}" for name, problem in list(problems.items())[:most]]
    return ", ".join(said) + (f" and {len(problems) - most} more" if len(problems) > most else "")


def _recorded_problem(path: Path, entry: dict, verify: bool) -> str | None:
    """How the file at ``path`` differs from its record ``entry`` (size, then with ``verify`` CRC-32), or None."""
    try:
        size = path.stat().st_size
        if size != entry["bytes"]:
            return f"changed since it was written ({size} bytes, {CHECKSUMS_FILE} records {entry['bytes']})"
        if verify and file_crc32(path) != entry["crc32"].lower():
            return f"changed since it was written (its CRC-32 is not the one {CHECKSUMS_FILE} records)"
    except OSError as exc:
        return f"unreadable ({exc.strerror or exc})"
    return None
