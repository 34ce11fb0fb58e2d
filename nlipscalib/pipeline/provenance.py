"""Provenance of a result: the settings and input identities (content hashes) that made it, and their key."""

from __future__ import annotations

import contextlib
import functools
import hashlib
import os
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from .. import __version__
from ..core import diskcache
from ..core.code_version import code_fingerprint
from ..core.errors import CaptureError
from ..core.libraries import SOLVE_LIBRARIES, library_versions
from ..core.reconstruction import provenance_key

if TYPE_CHECKING:
    from .settings import SolveSettings


def make_provenance(folder: Path, settings: SolveSettings) -> dict:
    """What makes the reconstruction of ``folder`` with ``settings``: settings, input identities, and their key.

    Input identities are content hashes (SHA-256) of the capture files the solver reads (meta.json,
    the images, reference.npz), so a moved or copied press keeps its identity and a re-captured one
    does not.
    """
    inputs = {
        "press": capture_identity(folder),
        "reference": None if settings.reference is None else capture_identity(settings.reference),
    }
    described = settings.describe()
    libraries = library_versions(SOLVE_LIBRARIES)
    key = provenance_key(_keyed(described), inputs, libraries)
    return {
        "key": key,
        "software_version": __version__,
        "code": code_fingerprint(),
        "libraries": libraries,
        "settings": described,
        "inputs": inputs,
    }


def run_record(settings: SolveSettings) -> dict:
    """What ``settings`` make of any press, for runs sharing an output (pipeline.reuse._hold): the settings that
    decide a result, the reference capture's identity and the software version (as in a result's provenance,
    less the press), the code's fingerprint, the libraries' versions, and ``key`` hashing them: two runs of one key
    make identical results."""
    inputs = {"reference": None if settings.reference is None else capture_identity(settings.reference)}
    keyed = _keyed(settings.describe())
    libraries = library_versions(SOLVE_LIBRARIES)
    key = provenance_key(keyed, inputs, libraries)
    return {
        "key": key,
        "software_version": __version__,
        "code": code_fingerprint(),
        "libraries": libraries,
        "settings": keyed,
        "inputs": inputs,
    }


def _keyed(described: dict) -> dict:
    """The settings that decide a result: paths are left out (their content is an input or a setting's value)."""
    return {k: v for k, v in described.items() if k not in ("leds_file", "reference")}


def capture_identity(folder: str | Path) -> str:
    """SHA-256 (hex) of a press folder's solver inputs: meta.json, images and reference.npz contents.

    Cached per process while every file it reads keeps its stamp (:func:`~nlipscalib.core.stored_images.file_stamp`):
    a long-lived process (a notebook, ``nlips calibrate``) notices a file replaced in place, and a warm call
    costs a stat per file (~60 us at 12 LEDs), not the hashing of every image (tens of ms).
    """
    from ..core.press_meta import META_FILE
    from ..core.stored_images import file_stamp

    meta = Path(folder) / META_FILE
    try:
        meta_stamp = file_stamp(str(meta))
    except FileNotFoundError:
        raise CaptureError(f"{meta}: missing; {folder} is not a complete press folder") from None
    where = str(Path(folder).resolve())
    names = _identity_files(where, meta_stamp)
    stamps = []
    for name in names:  # os.path, not pathlib: half the cost of each stat, most of a warm call
        path = os.path.join(where, name)
        try:
            stamps.append(file_stamp(path))
        except FileNotFoundError:  # named as the folder was given (the resolved path is only the cache's key)
            raise CaptureError(f"{Path(folder) / name}: listed in {META_FILE} but missing") from None
    # one hashing at a time: a call made while identity_in_background hashes these files waits for that result
    # (then cached) rather than reading and hashing them a second time
    with _hashing:
        return _capture_identity_cached(where, names, (meta_stamp, *stamps))


_hashing = threading.Lock()


def identity_in_background(*folders: str | Path | None) -> None:
    """Start :func:`capture_identity` of ``folders`` (None: skipped) on a daemon thread, for a call to come.

    Why: reading the files and SHA-256 release the GIL, so the hashing (~0.03 s of a 640x480 press with 12 LEDs)
    runs on the second core while ``nlips solve`` imports the solver (GIL-bound, ~0.2 s), not after it. A folder
    that is not a press (a dataset, a typo) fails here silently: the call that needs its identity reports it. The
    disk cache's key salt is made here too (:func:`nlipscalib.core.diskcache.salt_ahead`), after the identities."""

    def hash_all() -> None:
        code_fingerprint()  # the reuse key's too, read and hashed here rather than on the main thread
        library_versions(SOLVE_LIBRARIES)  # and the libraries' versions (metadata files read, cached)
        for folder in folders:
            if folder is not None:
                with contextlib.suppress(Exception):  # said, with its context, by the call that needs the identity
                    capture_identity(folder)
        with contextlib.suppress(Exception):  # the disk cache's key salt, for the load's first entry (not an error)
            diskcache.salt_ahead()

    threading.Thread(target=hash_all, name="capture-identity", daemon=True).start()


@functools.lru_cache(maxsize=16)
def _identity_files(folder: str, meta_stamp: tuple) -> tuple[str, ...]:
    """The files of ``folder`` whose contents the identity hashes after meta.json's, in order (read from
    meta.json, checked: its errors name it), per meta.json's stamp."""
    from ..core.press_meta import read_meta

    meta = read_meta(folder)
    images = meta["images"]
    return tuple(name for name in [images["dark"], images["tricolor"], *images["leds"], meta.get("reference")] if name)


@functools.lru_cache(maxsize=16)
def _capture_identity_cached(folder: str, names: tuple[str, ...], stamps: tuple) -> str:
    """The identity of ``folder`` hashing meta.json and ``names``, per the files' ``stamps`` (the cache key)."""
    from ..core.press_meta import META_FILE

    digest = hashlib.sha256((Path(folder) / META_FILE).read_bytes())
    for name in names:
        path = Path(folder) / name
        try:
            digest.update(name.encode() + b"\0" + path.read_bytes())
        except FileNotFoundError:  # removed since its stat
            raise CaptureError(f"{path}: listed in {META_FILE} but missing") from None
    return digest.hexdigest()
