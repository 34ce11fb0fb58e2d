"""A disk tier for sensor-level results: the next *process* working on the same sensor loads them.

A lab solves its presses one command at a time (``nlips solve press_0001``, then ``press_0002``, ...) or in
worker processes. Part of every solve depends on the sensor alone (the undeformed surface's direct shading,
that surface as radiosity patches, the difference operators of a whole frame's pyramid levels): about 1-1.5 s
of a 640x480 command, recomputed by every process. :mod:`nlipscalib.solver.reuse` keeps those results within
a process; this module keeps them on disk between processes.

- **Where:** ``$NLIPS_CACHE_DIR``; else ``$XDG_CACHE_HOME/nlipscalib``; else ``~/.cache/nlipscalib``.
  ``NLIPS_CACHE_DIR=off`` turns the tier off (results are then computed in every process, as before).
- **Keys:** a digest of the result's kind, its key (camera, LEDs, digests of the arrays it is computed from,
  the BLAS setting), and a digest of the package's own source, NumPy's and SciPy's versions: a changed
  formula or library never serves an old result.
- **Entries:** ``<dir>/<kind>/<digest>.pkl``, pickled (protocol 5), written atomically (temporary file, then
  rename: :func:`nlipscalib.core.atomic.write_bytes`), so processes sharing the folder never read a partial
  entry; two writing the same key write the same result and the last rename wins. Pickles stream to the file:
  no in-memory copy of a 100 MB result. An entry that cannot be
  read (truncated, another Python) is treated as missing, recomputed and replaced; one that reads but holds
  no result of this package (another program's pickle under that name) is removed with a warning and
  recomputed: each entry carries :data:`TAG`.
- **Size:** at most ``$NLIPS_CACHE_MB`` (default :data:`DEFAULT_MB`) megabytes; after a write the least
  recently used entries (reads touch them) are removed.
- **Trust:** entries are pickles, loaded only from the user's own cache folder (as joblib's ``Memory`` does);
  do not point ``NLIPS_CACHE_DIR`` at a folder others can write to.

Why not ``joblib.Memory``: it keys by function and arguments and would hash the 640x480 arrays again that
:mod:`~nlipscalib.solver.reuse` has already digested, and importing it costs ~60 ms of every command whose
budget is about a second; the project's atomic writes give the rest.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import logging
import os
import pickle
import sys
from pathlib import Path

import numpy as np

from . import atomic

log = logging.getLogger(__name__)

ENV_DIR = "NLIPS_CACHE_DIR"
"""Environment variable naming the cache folder (``off`` or empty: no disk tier)."""
ENV_MB = "NLIPS_CACHE_MB"
"""Environment variable: the most megabytes the cache folder may hold."""
DEFAULT_MB = 2048
"""Default size bound, MB: a 640x480 sensor's entries take about 300 MB."""
SUFFIX = ".pkl"
TAG = "nlipscalib.diskcache.entry/1"
"""First item of every stored (TAG, value) pair: an entry without it was not written by :func:`store`."""

_salt: str | None = None
_warned: set[str] = set()
"""Warnings given once per process (a bad setting is read before every entry)."""


def _warn_once(message: str, *args) -> None:
    text = message % args
    if text not in _warned:
        _warned.add(text)
        log.warning(text)


def folder() -> Path | None:
    """The cache folder, or None when the disk tier is off (a file in its place turns it off, said once)."""
    root = configured_folder()
    return None if root is None else _usable(root)


def configured_folder() -> Path | None:
    """The cache folder the environment names, whatever is there (a file, nothing yet); None when it is off."""
    env = os.environ.get(ENV_DIR)
    if env is not None:
        env = env.strip()
        return None if env.lower() in ("", "off", "0", "none") else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME", "").strip()
    if not base:
        try:
            base = Path.home() / ".cache"
        except RuntimeError:  # no home folder (a bare service account): no disk tier
            return None
    return Path(base) / "nlipscalib"


def _usable(root: Path) -> Path | None:
    """``root``, or None (the tier off, said once) when a file is in its place: every entry would fail to
    be written or read, and the user would wonder why every command recomputes."""
    if root.exists() and not root.is_dir():
        _warn_once("cache folder %s is a file, not a folder: the disk cache is off (set %s)", root, ENV_DIR)
        return None
    return root


def limit_bytes() -> int:
    """The size bound from ``$NLIPS_CACHE_MB`` (default :data:`DEFAULT_MB`), bytes."""
    import math

    text = os.environ.get(ENV_MB, "").strip()
    try:
        mb = float(text) if text else DEFAULT_MB
    except ValueError:
        mb = math.nan
    if not (math.isfinite(mb) and mb >= 0):  # a negative or infinite bound is no size
        _warn_once("%s=%r is not a number of megabytes >= 0; the cache keeps at most %d MB", ENV_MB, text, DEFAULT_MB)
        mb = DEFAULT_MB
    return int(mb * 2**20)


def digest(*arrays: np.ndarray) -> str:
    """Content digest of arrays (shape, dtype and bytes): a 640x480 surface in a few milliseconds."""
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(repr((a.shape, a.dtype.str)).encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def stable_key(obj: object) -> str:
    """A text that names ``obj`` the same way in every process: tuples, lists, dicts and dataclasses field
    by field, arrays by content digest, everything else by ``repr`` (numbers, strings, None)."""
    if isinstance(obj, np.ndarray):
        return f"array:{digest(obj)}"
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        fields = ",".join(f"{f.name}={stable_key(getattr(obj, f.name))}" for f in dataclasses.fields(obj))
        return f"{type(obj).__qualname__}({fields})"
    if isinstance(obj, (tuple, list)):
        return "(" + ",".join(stable_key(v) for v in obj) + ")"
    if isinstance(obj, dict):
        return "{" + ",".join(f"{stable_key(k)}:{stable_key(v)}" for k, v in sorted(obj.items(), key=repr)) + "}"
    if isinstance(obj, np.generic):
        return repr(obj.item())
    return repr(obj)


def entry(kind: str, key: object) -> Path | None:
    """The file that holds (or would hold) the result of ``kind`` under ``key``; None when the tier is off."""
    root = folder()
    if root is None:
        return None
    h = hashlib.blake2b(digest_size=20)
    h.update(_source_salt().encode())
    h.update(kind.encode())
    h.update(stable_key(key).encode())
    return root / kind.replace(" ", "_") / (h.hexdigest() + SUFFIX)


def load(path: Path) -> object:
    """The result stored at ``path``; raises KeyError when there is none or it cannot be read."""
    try:
        with open(path, "rb") as f:
            stored = pickle.load(f)
    except FileNotFoundError:
        raise KeyError(str(path)) from None
    except Exception as exc:  # a truncated or foreign entry is a miss, not an error: it is recomputed
        log.debug("cache entry %s unreadable (%s); recomputing", path, exc)
        raise KeyError(str(path)) from None
    if not (isinstance(stored, tuple) and len(stored) == 2 and stored[0] == TAG):
        # readable, but not written by store(): served, it failed deep inside the solver (AttributeError)
        log.warning("cache entry %s holds no result of this program: removed, recomputing", path)
        with contextlib.suppress(OSError):
            path.unlink()
        raise KeyError(str(path))
    with contextlib.suppress(OSError):
        os.utime(path)  # recently used: the size bound removes the oldest first
    return stored[1]


def store(path: Path, value: object) -> None:
    """Write ``value`` to ``path`` atomically, then keep the folder within its size bound. A failed write
    (read-only or full disk, a value that cannot be pickled) only costs the next process the computation:
    it is logged, not raised."""
    try:
        atomic.write_with(path, lambda f: pickle.dump((TAG, value), f, protocol=5))
        trim(path.parent.parent, limit_bytes())
    except OSError as exc:  # a folder that cannot be written (read-only, /proc, full): every command recomputes
        _warn_once(
            "the disk cache in %s cannot be written (%s): sensor-level results are computed again by every "
            "command (set %s to a writable folder, or to off)",
            path.parent.parent,
            exc.strerror or exc,
            ENV_DIR,
        )
    except (pickle.PicklingError, TypeError, AttributeError) as exc:
        log.debug("could not write cache entry %s: %s", path, exc)


def trim(root: Path, limit: int) -> int:
    """Remove the least recently used entries under ``root`` until they hold at most ``limit`` bytes;
    returns the bytes left. Entries another process removes meanwhile are skipped; temporary files of
    writers that died are removed (:func:`nlipscalib.core.atomic.clean_interrupted`: never a live one's)."""
    for kind in root.iterdir():
        if kind.is_dir():
            atomic.clean_interrupted(kind)
    files = []
    for p in root.glob(f"*/*{SUFFIX}"):
        with contextlib.suppress(OSError):
            st = p.stat()
            files.append((st.st_mtime, st.st_size, p))
    total = sum(size for _, size, _ in files)
    for _, size, p in sorted(files, key=lambda f: f[0]):
        if total <= limit:
            break
        with contextlib.suppress(OSError):
            p.unlink()
            total -= size
    return total


def clear(root: Path | None = None) -> int:
    """Remove every entry (and leftover temporary file) of the cache folder; returns the bytes freed."""
    root = folder() if root is None else root
    freed = 0
    if root is None or not root.is_dir():
        return 0
    for p in root.glob("*/*"):
        if p.is_file() and (p.suffix == SUFFIX or p.name.startswith(atomic.TMP_PREFIX)):
            with contextlib.suppress(OSError):
                size = p.stat().st_size
                p.unlink()
                freed += size
    return freed


def usage(root: Path | None = None) -> tuple[int, int]:
    """(entries, bytes) in the cache folder."""
    root = folder() if root is None else root
    if root is None or not root.is_dir():
        return 0, 0
    sizes = [size for p in root.glob(f"*/*{SUFFIX}") if (size := _size(p)) is not None]
    return len(sizes), sum(sizes)


def _size(path: Path) -> int | None:
    """Bytes of an entry, or None when another process removed it since it was listed."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return None


def _source_salt() -> str:
    """Digest of the package's Python source and the versions of the libraries whose objects are stored:
    any edit of a formula, or another NumPy/SciPy, makes every earlier entry a miss (computed once)."""
    global _salt
    if _salt is None:
        import scipy

        h = hashlib.blake2b(digest_size=16)
        h.update(f"{sys.version_info[:2]} numpy {np.__version__} scipy {scipy.__version__}".encode())
        package = Path(__file__).resolve().parent.parent
        for path in sorted(package.rglob("*.py")):
            h.update(str(path.relative_to(package)).encode())
            h.update(path.read_bytes())
        _salt = h.hexdigest()
    return _salt
