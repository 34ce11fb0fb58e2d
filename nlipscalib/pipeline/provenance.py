"""Provenance of a result: the settings and input identities (content hashes) that made it, and their key."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path
from typing import TYPE_CHECKING

from .. import __version__
from ..core.errors import CaptureError
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
    key = provenance_key(_keyed(described), inputs)
    return {"key": key, "software_version": __version__, "settings": described, "inputs": inputs}


def run_record(settings: SolveSettings) -> dict:
    """What ``settings`` make of any press, for runs sharing an output (pipeline.reuse._hold): the settings that
    decide a result, the reference capture's identity and the software version (as in a result's provenance,
    less the press), and ``key`` hashing them: two runs of one key make identical results."""
    inputs = {"reference": None if settings.reference is None else capture_identity(settings.reference)}
    keyed = _keyed(settings.describe())
    return {"key": provenance_key(keyed, inputs), "software_version": __version__, "settings": keyed, "inputs": inputs}


def _keyed(described: dict) -> dict:
    """The settings that decide a result: paths are left out (their content is an input or a setting's value)."""
    return {k: v for k, v in described.items() if k not in ("leds_file", "reference")}


@functools.lru_cache(maxsize=16)
def _capture_identity_cached(folder: str, stamp: tuple) -> str:
    from ..core.capture import META_FILE, read_meta

    meta = read_meta(folder)
    digest = hashlib.sha256((Path(folder) / META_FILE).read_bytes())
    images = meta["images"]
    for name in [images["dark"], images["tricolor"], *images["leds"], meta.get("reference")]:
        if not name:
            continue
        path = Path(folder) / name
        try:
            digest.update(name.encode() + b"\0" + path.read_bytes())
        except FileNotFoundError:
            raise CaptureError(f"{path}: listed in {META_FILE} but missing") from None
    return digest.hexdigest()


def capture_identity(folder: str | Path) -> str:
    """SHA-256 (hex) of a press folder's solver inputs: meta.json, images and reference.npz contents."""
    from ..core.capture import META_FILE

    meta = Path(folder) / META_FILE
    try:
        st = meta.stat()
    except FileNotFoundError:
        raise CaptureError(f"{meta}: missing; {folder} is not a complete press folder") from None
    # cached per process while meta.json is the same file (press folders are replaced whole, atomically)
    return _capture_identity_cached(str(Path(folder).resolve()), (st.st_ino, st.st_mtime_ns, st.st_size))
