"""Warnings said once per command, not once per press: a fault of the whole session (a wiring error that swapped
two LED images, LEDs aged since the undeformed capture) shows in every press of a batch, and the batch's presses may
be solved in several worker processes (``--workers``), each of which would otherwise say it once.

The parent of a worker pool makes a folder (:func:`shared_between_processes`) and hands its path to each worker
(:func:`share`); the first process to create a key's file there says the warning, the others log it at INFO.
Without a shared folder the keys are kept in this process only.

How long a key counts as said: one :func:`scope` (each ``nlips`` command; each call of
:func:`nlipscalib.pipeline.solve_presses` or :func:`nlipscalib.learn.dataset.build_dataset`; a scope opened inside
another joins it). Outside any scope (a script's bare ``solve_press`` or ``solve_folder`` calls) a key is said once
per process. Why: a notebook that solved a session's folder twice, or another session's folder of the same path,
heard its swapped or aged LEDs only the first time."""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator
from pathlib import Path

_SAID: set[str] = set()
"""Digests of the keys already said by this process (or, after a pool, by its workers)."""
_IN_SCOPE = False
"""Whether a :func:`scope` is open (``_SAID`` is then its own set, the process-wide one put aside until it ends)."""
_SHARED: Path | None = None
"""The folder shared with the other processes of this command (None: keys kept in this process only)."""


def _digest(key: str) -> str:
    """A file name for ``key`` (a key names folders: any characters, any length)."""
    return hashlib.sha256(key.encode("utf-8")).hexdigest()[:32]


def first_time(key: str) -> bool:
    """True the first time this command asks for ``key`` (in this process, or in any process sharing its folder).

    Why a file per key: ``os.open`` with ``O_EXCL`` is atomic between processes, needs no lock or manager process,
    and the pool's parent removes the folder at the end."""
    digest = _digest(key)
    if digest in _SAID:
        return False
    _SAID.add(digest)
    if _SHARED is None:
        return True
    try:
        os.close(os.open(_SHARED / digest, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
    except FileExistsError:
        return False
    except OSError:  # the folder is gone or unwritable: saying a warning twice beats not saying it
        return True
    return True


@contextlib.contextmanager
def scope() -> Iterator[None]:
    """Each key said once within the block (a command, one API call over a folder of presses), said again in a
    later block; inside an open scope, part of it (``nlips calibrate``'s solves and dataset build: one command).

    The keys said outside any scope (process-wide) are neither seen inside nor added to by it."""
    global _SAID, _IN_SCOPE
    if _IN_SCOPE:
        yield
        return
    before = _SAID
    _SAID, _IN_SCOPE = set(), True
    try:
        yield
    finally:
        _SAID, _IN_SCOPE = before, False


def share(folder: str | None) -> None:
    """In a worker process: say each key once together with the other processes of ``folder`` (None: alone)."""
    global _SHARED
    _SHARED = None if folder is None else Path(folder)


@contextlib.contextmanager
def shared_between_processes() -> Iterator[str]:
    """A folder (its path, for the workers' :func:`share`) in which this process and its workers say each key once;
    what the workers said counts as said by this process afterwards. Removed at the end."""
    from .atomic import system_scratch_dir

    global _SHARED
    before = _SHARED
    # not a TemporaryDirectory: a killed command's (kill -9) is removed by the next command's
    with system_scratch_dir("nlips-said") as scratch:
        folder = str(scratch)
        for digest in _SAID:  # said here already (an earlier batch of this command): not again in a worker
            Path(folder, digest).touch()
        _SHARED = Path(folder)
        try:
            yield folder
        finally:
            _SHARED = before
            _SAID.update(p.name for p in Path(folder).iterdir())
