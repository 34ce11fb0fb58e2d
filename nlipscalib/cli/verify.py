"""``nlips verify FOLDER...``: read every byte of each press folder's files and compare them with its checksums.json;
``--record`` gives a press written before the record existed (2026-12-06) one, once its files are verified."""

from __future__ import annotations

import argparse
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "verify",
        help="check press folders byte by byte against their checksums.json (--record: give older folders one)",
        description="Read every file of each press folder at or below FOLDER (a press, a dataset, a capture session "
        "with its reference/) and compare it with the size and CRC-32 its checksums.json recorded when it was written; "
        "a press without one (written before 2026-12-06) is checked by its formats' own checksums (each PNG chunk's "
        "CRC, each .npz member inflated). Each damaged press is named with its file, exit 1. With --record, a whole "
        "press without checksums.json gets one (its images also loaded as a solve loads them), so that `nlips solve`, "
        "`calibrate` and `train` notice a file copied over one later, as they do for presses written since. Safe "
        "beside other runs: a record is written only where none exists, and not when a file changes while read.",
    )
    p.add_argument("folders", nargs="+", metavar="FOLDER", help="press folders, or folders of presses")
    p.add_argument(
        "--record",
        action="store_true",
        help="write checksums.json into each whole press that has none (the press folder must be writable)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.errors import CaptureError
    from ..core.press_folders import find_presses, no_presses_error
    from ..progress import say, track

    presses: list[Path] = []
    for folder in args.folders:
        found = find_presses(folder)
        if not found:
            raise no_presses_error(folder)
        presses += [p for p in found if p not in presses]
    damaged: dict[Path, str] = {}
    counts = {"recorded": 0, "unrecorded": 0}
    for folder in track(presses, enabled=not args.no_progress, desc="verifying", unit="press"):
        try:
            problem = _verified(folder, args.record, counts)
        except CaptureError as exc:  # meta.json unreadable: named by the error itself
            problem = str(exc).removeprefix(f"{folder}{os.sep}").removeprefix(f"{folder}: ")
        if problem:
            damaged[folder] = problem
            log.error("%s: %s", folder, problem)
    whole = len(presses) - len(damaged)
    line = f"{len(presses)} press folder{'s' if len(presses) != 1 else ''} verified: {whole} whole"
    line += f", {len(damaged)} damaged ({', '.join(str(f) for f in damaged)})" if damaged else ""
    if counts["recorded"]:
        line += f"; checksums.json recorded in {counts['recorded']}"
    if counts["unrecorded"]:
        line += (
            f"; {counts['unrecorded']} without checksums.json (written before 2026-12-06: checked by their formats' "
            "own checksums only): --record gives them one"
        )
    say(line, warning=bool(damaged))
    return 1 if damaged else 0


def _verified(folder: Path, record: bool, counts: dict[str, int]) -> str:
    """Why the press ``folder`` is damaged, in a few words ("led_02.png changed since it was written (...)"), or "";
    with ``record``, its checksums.json written when it has none and is whole (``counts`` counts what was done)."""
    from ..core.press_checksums import (
        HAD_ONE,
        RECORDED,
        described_file_problems,
        press_file_problems,
        read_checksums,
        record_checksums,
    )
    from ..core.press_meta import listed_files, read_meta

    has_record = bool(read_checksums(folder))
    if record and not has_record:
        outcome = record_checksums(folder)
        if outcome == RECORDED:
            counts["recorded"] += 1
            return ""
        if outcome != HAD_ONE:
            return outcome
    try:
        names = listed_files(read_meta(folder))
    except (KeyError, TypeError):
        return "meta.json lists no images (malformed 'images')"
    problems = press_file_problems(folder, names, verify=True)
    if not problems and not has_record and not read_checksums(folder):
        counts["unrecorded"] += 1
    return described_file_problems(problems)
