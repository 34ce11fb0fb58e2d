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
from collections.abc import Callable, Collection
from pathlib import Path

from .atomic import write_json, write_new
from .errors import CaptureError
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


# ---------------------------------------------------------------------- the commands that read presses
EDITED_OPTION = "--allow-edited"
"""The option of ``nlips solve``, ``calibrate``, ``calibrate-leds``, ``train``, ``infer`` and ``eval`` that uses
presses whose files differ from their checksums.json (:func:`check_unchanged`): images a lab edited on purpose."""
CHANGED_SHOWN = 3
"""How many changed presses a refusal names (the rest are counted)."""


def changed_files(folder: str | Path, names: Collection[str] | None = None) -> dict[str, str]:
    """The files ``folder``'s checksums.json records that are whole at their ends (:func:`.file_checks.file_problem`)
    but of another size than recorded, each with its problem in a few words: another whole file copied over it (a
    user tidying up, a copy gone wrong), which the readers' own format checks pass. {} when none, or when the folder
    has no readable record (written before it existed: judged by the readers as before). ``names``: only those
    files (the ones a command reads: ``nlips infer`` a press's tri-colour and dark frames and reference, ``nlips
    eval`` its ground truth); None: every file recorded.

    A ``stat`` per recorded file and one small JSON read; a file's ends are read only where its size differs (a file
    missing, empty or cut short is left to the reader of the press, which names it as before)."""
    folder = Path(folder)
    changed = {}
    for name, entry in read_checksums(folder).items():
        if names is not None and name not in names:
            continue
        try:
            size = os.stat(folder / name).st_size
        except OSError:
            continue  # missing: the press's reader says so, naming it
        if size != entry["bytes"] and file_problem(folder / name) is None:
            changed[name] = f"changed since it was written ({size} bytes, {CHECKSUMS_FILE} records {entry['bytes']})"
    return changed


def check_unchanged(
    folders: list[str | Path], remedy: str | None = None, names: Callable[[Path], Collection[str]] | None = None
) -> None:
    """CaptureError (exit 2) in one line naming the first changed file (:func:`changed_files`) of ``folders`` (press
    folders, the reference among them), the count of other presses changed, and what to do: ``remedy`` or copy or
    capture the press again; :data:`EDITED_OPTION` to use it as it is. Nothing when every one is unchanged.
    ``names(folder)``: the files of each folder to compare (those the command reads); None: every file recorded.

    Why: a press with another whole image copied over one (another press's LED image, a tri-colour frame of another
    session) passed every reader's checks (a whole PNG of the camera's size): ``nlips solve`` solved it, ``nlips
    calibrate`` sampled it and ``nlips train`` learned from it without a word."""
    changed = {
        Path(f): problems for f in folders if (problems := changed_files(f, None if names is None else names(Path(f))))
    }
    if not changed:
        return
    (first, problems), *others = changed.items()
    name, problem = next(iter(problems.items()))
    more = [f" and {len(problems) - 1} more of its files"] if len(problems) > 1 else []
    if others:
        shown = ", ".join(str(f) for f, _ in others[:CHANGED_SHOWN])
        extra = f" and {len(others) - CHANGED_SHOWN} more" if len(others) > CHANGED_SHOWN else ""
        more.append(f"; {len(others)} other press{'es' if len(others) > 1 else ''} changed too ({shown}{extra})")
    remedy = remedy or "copy, capture or render the press again"
    raise CaptureError(
        f"{first / name}: {problem}{''.join(more)}: another file copied over it? {remedy}, or pass {EDITED_OPTION} "
        "to use the files as they are (edited on purpose)"
    )


# ---------------------------------------------------------------------- what a dataset records of its presses
def files_as_read(folder: str | Path, names: list[str]) -> dict[str, dict]:
    """What a reader of the press ``folder`` records of its files ``names`` as it reads them: {name: {"bytes": N}},
    with ``"crc32"`` where checksums.json records the file at that very size (its content as written; a file edited
    on purpose, :data:`EDITED_OPTION`, has none). A stat per file; no byte read but the record's.

    Why: a calibration dataset's samples are made from its presses' files as they were then; ``nlips train`` compares
    them with the presses' files now (:func:`changed_since`), so a dataset built before a press was captured or
    rendered again, or before a file was copied over, is told from one whose presses are as sampled."""
    folder = Path(folder)
    recorded = read_checksums(folder)
    files = {}
    for name in names:
        try:
            size = os.stat(folder / name).st_size
        except OSError:  # gone: the reader names it; nothing to record
            continue
        entry = {"bytes": size}
        if recorded.get(name, {}).get("bytes") == size:
            entry["crc32"] = recorded[name]["crc32"]
        files[name] = entry
    return files


def changed_since(folder: str | Path, files: dict) -> dict[str, str]:
    """The files of ``files`` (:func:`files_as_read`, as a reader recorded them) that differ in the press ``folder``
    now, each with its problem in a few words: gone, of another size, or recorded by the press's checksums.json with
    another CRC-32 (the press written anew at the same sizes). {} when each is as recorded, or ``files`` is not such
    a record. A stat per file and one small JSON read."""
    folder = Path(folder)
    if not isinstance(files, dict):
        return {}
    now = read_checksums(folder)
    problems = {}
    for name, was in files.items():
        if not isinstance(was, dict) or not isinstance(was.get("bytes"), int):
            continue
        try:
            size = os.stat(folder / name).st_size
        except OSError:
            problems[name] = "missing (there when it was sampled)"
            continue
        crc = now.get(name, {}).get("crc32") if now.get(name, {}).get("bytes") == size else None
        if size != was["bytes"]:
            problems[name] = f"changed since it was sampled ({size} bytes, {was['bytes']} then)"
        elif isinstance(was.get("crc32"), str) and crc is not None and crc != was["crc32"]:
            problems[name] = f"written anew since it was sampled (its {CHECKSUMS_FILE} records another CRC-32)"
    return problems


# ---------------------------------------------------------------------- a record for a folder written before it
RECORDED, HAD_ONE = "recorded", "had one"
""":func:`record_checksums`' outcomes besides a problem."""


def record_checksums(folder: str | Path) -> str:
    """Give the press ``folder`` its checksums.json when it has none, once its files are verified: each listed file
    whole at its ends and its format's own checksums sound (:func:`press_file_problems` with ``verify``), and the
    press loading as a solve loads it (its images PNGs of the camera's size: :func:`.capture.load_press`). Returns
    :data:`RECORDED`, :data:`HAD_ONE`, or why not in a few words ("led_02.png damaged inside (...)").

    Safe beside other processes: the record is published only where no file of its name exists
    (:func:`.atomic.write_new`: two runs at once record once; a press written anew meanwhile by ``nlips dataset``
    or ``capture`` keeps its own record), and only when no file changed while it was read (each file's inode, size
    and time the same before and after). CaptureError naming meta.json when it is unreadable."""
    from .press_meta import META_FILE, listed_files, read_meta

    folder = Path(folder)
    if (folder / CHECKSUMS_FILE).exists():
        return HAD_ONE if read_checksums(folder) else f"{CHECKSUMS_FILE} unreadable (delete it to record it anew)"
    names = listed_files(read_meta(folder))
    if problems := press_file_problems(folder, names, verify=True):
        return described_file_problems(problems)
    from .capture import load_press

    try:  # its images whole PNGs of the camera's size, its reference of the right shape: as a solve loads it
        load_press(folder, decode=False)
    except CaptureError as exc:
        return str(exc).removeprefix(f"{folder}{os.sep}").removeprefix(f"{folder}: ")
    before = _stamps(folder, [META_FILE, *names])
    files = {name: {"bytes": before[name][1], "crc32": file_crc32(folder / name)} for name in names}
    if _stamps(folder, [META_FILE, *names]) != before:
        return "its files changed while they were read (being written?): run again"
    record = {"format": CHECKSUMS_FORMAT, "format_version": CHECKSUMS_VERSION, "files": files}
    data = (json.dumps(record, indent=2) + "\n").encode()
    return RECORDED if write_new(folder / CHECKSUMS_FILE, data) else HAD_ONE


def _stamps(folder: Path, names: list[str]) -> dict[str, tuple[int, int, int] | None]:
    """(inode, size, mtime ns) of each of ``names`` in ``folder``; None for one that is gone."""
    stamps = {}
    for name in names:
        try:
            st = os.stat(folder / name)
            stamps[name] = (st.st_ino, st.st_size, st.st_mtime_ns)
        except OSError:
            stamps[name] = None
    return stamps
