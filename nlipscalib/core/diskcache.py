"""A disk tier for sensor-level results: the next *process* working on the same sensor loads them.

A lab solves its presses one command at a time (``nlips solve press_0001``, then ``press_0002``, ...) or in
worker processes. Part of every solve depends on the sensor alone (the undeformed surface's direct shading,
that surface as radiosity patches, the difference operators of a whole frame's pyramid levels): about 1-1.5 s
of a 640x480 command, recomputed by every process. :mod:`nlipscalib.solver.reuse` keeps those results within
a process; this module keeps them on disk between processes.

- **Where:** ``$NLIPS_CACHE_DIR``; else ``$XDG_CACHE_HOME/nlipscalib``; else ``~/.cache/nlipscalib``.
  ``NLIPS_CACHE_DIR=off`` turns the tier off (results are then computed in every process, as before).
- **Keys:** a digest of the result's kind, its key (camera, LEDs, digests of the arrays it is computed from,
  the BLAS setting), and a digest of the package's own source and of the versions of the libraries that shape
  a solve (NumPy, SciPy, pyamg, OpenCV: :data:`~nlipscalib.core.libraries.SOLVE_LIBRARIES`): a changed formula or
  library never serves an old result.
- **Entries:** ``<dir>/<kind>/<digest>.pkl``: :data:`MAGIC`, a table of sizes, the pickle (protocol 5) of
  (:data:`TAG`, value) with its arrays' bytes out of band, then those bytes as they are in memory, each from an
  offset that is a multiple of :data:`ALIGN` (:func:`_serialised`). Read, the file is mapped and the arrays
  view the mapping (:func:`load`): no copy of them is made. Written atomically (temporary file, then rename:
  :func:`nlipscalib.core.atomic.write_with`), so processes sharing the folder never read a partial entry; two
  writing the same key write the same result and the last rename wins. An entry that cannot be read (truncated,
  another Python) is treated as missing, recomputed and replaced; one that reads but holds no result of this
  package (another program's file under that name) is removed with a warning and recomputed.
- **Writes in the background** (:func:`store_later`, what :mod:`nlipscalib.solver.reuse` uses): the entry's
  structure is pickled by the caller (milliseconds: the arrays are only referenced; a kept result is never
  changed once made, :mod:`nlipscalib.solver.reuse`), its bytes written by a thread of their own while the
  solve goes on. Writing a 640x480 sensor's entries cost a cold command's main thread 1.5-2 s, nearly all of it the
  kernel giving the file's page cache fresh pages on the 2-core VM this project runs on
  (benchmarks/RESULTS.md, s17-f). The thread is not a daemon: the interpreter's exit, and
  :func:`nlipscalib.cli._exit`'s ``threading._shutdown``, wait for it; a signal that ends the process at once
  (:func:`nlipscalib.cli._end_at_once`) removes its temporary file (:func:`nlipscalib.core.atomic.remove_in_progress`),
  so a write cut short never leaves an entry. :func:`load` of an entry this process is still writing waits for it.
- **Size:** at most ``$NLIPS_CACHE_MB`` (default :data:`DEFAULT_MB`) megabytes; after a write the least
  recently used entries (reads touch them) are removed. An entry above :data:`ENTRY_MAX_SHARE` of that bound is
  not written at all (said at DEBUG): it would evict most of the others, a sensor's own included, each run.
- **Trust:** entries are pickles, loaded only from the user's own cache folder (as joblib's ``Memory`` does);
  do not point ``NLIPS_CACHE_DIR`` at a folder others can write to.

Why not ``joblib.Memory``: it keys by function and arguments and would hash the 640x480 arrays again that
:mod:`~nlipscalib.solver.reuse` has already digested, and importing it costs ~60 ms of every command whose
budget is about a second; the project's atomic writes give the rest.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import hashlib
import logging
import mmap
import os
import pickle
import struct
import sys
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import BinaryIO

import numpy as np

from . import atomic

log = logging.getLogger(__name__)

ENV_DIR = "NLIPS_CACHE_DIR"
"""Environment variable naming the cache folder (``off`` or empty: no disk tier)."""
ENV_MB = "NLIPS_CACHE_MB"
"""Environment variable: the most megabytes the cache folder may hold."""
DEFAULT_MB = 2048
"""Default size bound, MB: a 640x480 sensor's entries take about 250 MB (sphere1: 251 MB)."""
ENTRY_MAX_SHARE = 0.5
"""An entry whose file would take more than this share of the size bound (:func:`limit_bytes`) is not written: it
is recomputed by every process instead. Why: written, it evicted most of the cache, and a sensor whose entries
together exceed the bound evicted its own in turn, each run writing again what the last one removed (the 1280x960
whole frame's difference operators are one 857 MB entry, its other entries ~310 MB: under ``NLIPS_CACHE_MB=1000``
writing the operators evicted the oldest of those, which the next run wrote again). At the default bound every
entry of a 640x480 sensor (the largest 214 MB) and of a 1280x960 one is written, as before: loaded, those operators
take a 1280x960 whole-frame solve to 14.3-14.8 s against 19.9-23.4 s building them (benchmarks/RESULTS.md,
s24-mem), so they are worth their room where there is room."""
SUFFIX = ".pkl"
TAG = "nlipscalib.diskcache.entry/3"
"""First item of every stored (TAG, value) pair: an entry without it was not written by :func:`store`."""
MAGIC = b"nlipscalib.diskcache/3\n"
"""First bytes of every entry file (:func:`_serialised`): a file without them is another program's."""
_SIZES = struct.Struct("<QQ")
"""(bytes of the pickle, number of out-of-band buffers) after :data:`MAGIC`; then each buffer's bytes as ``<Q``."""
ALIGN = 64
"""Every out-of-band buffer starts at a multiple of this many bytes from the file's start (zeros pad the gaps): the
arrays viewing a mapped entry are aligned as NumPy and SciPy's kernels want them (a page-aligned mapping, a
cache line apart), never copied for it."""

_salt: str | None = None
_salt_lock = threading.Lock()
"""Held while the salt is computed: a thread that asks meanwhile waits for it (:func:`salt_ahead`'s thread) rather
than read the package's source a second time."""
_pending: dict[Path, threading.Thread] = {}
"""Entries this process is writing in the background (:func:`store_later`), by path."""
_pending_lock = threading.Lock()
_one_writer = threading.Lock()
"""Held by a background write: one entry's pages at a time, not all of them competing with the solve at once."""
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
    """The result stored at ``path``; raises KeyError when there is none or it cannot be read. An entry this
    process is writing in the background (:func:`store_later`) is waited for.

    The file is mapped (copy on write: an array changed in place changes this process's page, never the file) and
    the result's arrays view the mapping. Why not read it into memory: a whole 640x480 frame's entries are ~300 MB,
    and read they were as many fresh pages to fault in and a copy from the page cache; mapped, the pages are the
    page cache's own, faulted in 64 KiB at a time (benchmarks/RESULTS.md, s18-d). An entry is replaced by renaming
    a new file over it (:mod:`nlipscalib.core.atomic`), never written in place, so a mapping always sees whole,
    unchanging bytes."""
    wait(path)
    try:
        with open(path, "rb") as f:
            ours = f.read(len(MAGIC)) == MAGIC
            stored = _read_entry(f) if ours else None
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


def _read_entry(f: BinaryIO) -> object:
    """The (TAG, value) of an entry file ``f``, read past :data:`MAGIC`: the file is mapped and each out-of-band
    buffer is a view of the mapping, which the value's arrays then view (no copy). ValueError when the file is
    short or long (truncated, or not written by :func:`_serialised`)."""
    head = f.read(_SIZES.size)
    if len(head) != _SIZES.size:
        raise ValueError("truncated")
    size, count = _SIZES.unpack(head)
    table = f.read(8 * count)
    if len(table) != 8 * count:
        raise ValueError("truncated")
    pickled = f.read(size)
    if len(pickled) != size:
        raise ValueError("truncated")
    lengths = struct.unpack(f"<{count}Q", table)
    starts = _buffer_starts(f.tell(), lengths)
    end = starts[-1] + lengths[-1] if count else f.tell()
    if os.fstat(f.fileno()).st_size != end:
        raise ValueError("truncated or too long")
    buffers = []
    if count:
        whole = memoryview(mmap.mmap(f.fileno(), end, access=mmap.ACCESS_COPY))
        buffers = [whole[a : a + n] for a, n in zip(starts, lengths)]
    return pickle.loads(pickled, buffers=buffers)


def _buffer_starts(offset: int, lengths: Sequence[int]) -> list[int]:
    """File offsets of the out-of-band buffers of ``lengths`` bytes that follow the pickle, which ends at
    ``offset``: each at the next multiple of :data:`ALIGN`."""
    starts = []
    for n in lengths:
        offset = -(-offset // ALIGN) * ALIGN
        starts.append(offset)
        offset += n
    return starts


def _serialised(value: object) -> list:
    """The pieces of ``value``'s entry file, in order: :data:`MAGIC` and the sizes, the pickle of (TAG, value)
    with its contiguous arrays out of band (protocol 5), then those arrays' bytes as views of their memory (no
    copy), each after the zeros that start it at a multiple of :data:`ALIGN`. Pickling errors (a value that cannot
    be pickled) are raised here, in the caller's thread."""
    buffers: list[pickle.PickleBuffer] = []
    pickled = pickle.dumps((TAG, value), protocol=5, buffer_callback=buffers.append)
    raw = [b.raw() for b in buffers]
    lengths = [r.nbytes for r in raw]
    head = MAGIC + _SIZES.pack(len(pickled), len(raw)) + struct.pack(f"<{len(raw)}Q", *lengths)
    parts, offset = [head, pickled], len(head) + len(pickled)
    for r, start in zip(raw, _buffer_starts(offset, lengths)):
        parts += [bytes(start - offset), r]
        offset = start + r.nbytes
    return parts


def store(path: Path, value: object) -> None:
    """Write ``value`` to ``path`` atomically, then keep the folder within its size bound. A failed write
    (read-only or full disk, a value that cannot be pickled) only costs the next process the computation:
    it is logged, not raised."""
    parts = _pieces_or_none(path, value)
    if parts is not None and _fits(path, parts):
        _write(path, parts)


def _pieces_or_none(path: Path, value: object) -> list | None:
    """:func:`_serialised` of ``value``, or None (logged) when it cannot be pickled: a cache entry is never needed."""
    try:
        return _serialised(value)
    except (pickle.PicklingError, TypeError, AttributeError) as exc:
        log.debug("could not write cache entry %s: %s", path, exc)
        return None


def _fits(path: Path, parts: list) -> bool:
    """Whether an entry of ``parts`` (:func:`_serialised`) is at most :data:`ENTRY_MAX_SHARE` of the size bound;
    one that is not is said at DEBUG (it is recomputed by the next process: no fault)."""
    size = sum(memoryview(p).nbytes for p in parts)
    limit = limit_bytes()
    if size <= ENTRY_MAX_SHARE * limit:
        return True
    log.debug(
        "cache entry %s not written: %.0f MB, more than %.0f %% of the cache's %.0f MB (%s)",
        path,
        size / 2**20,
        100 * ENTRY_MAX_SHARE,
        limit / 2**20,
        ENV_MB,
    )
    return False


def store_later(path: Path, value: object) -> None:
    """:func:`store` on a thread of its own: ``value`` is pickled now (its arrays only referenced: neither they
    nor the objects holding them may change afterwards), its bytes written while the caller goes on. The
    process's exit waits for the write (a non-daemon thread); :func:`wait` waits for it sooner."""
    parts = _pieces_or_none(path, value)
    if parts is None or not _fits(path, parts):
        return

    def write() -> None:
        try:
            with _one_writer:
                _write(path, parts)
        finally:
            with _pending_lock:
                if _pending.get(path) is threading.current_thread():
                    del _pending[path]

    thread = threading.Thread(target=write, name=f"nlips cache write {path.parent.name}")
    with _pending_lock:
        earlier = _pending.get(path)
        _pending[path] = thread
    if earlier is not None:  # the same key written twice (its result evicted, then computed again): in order
        earlier.join()
    thread.start()


def wait(path: Path | None = None) -> None:
    """Wait for this process's background writes (:func:`store_later`) of ``path``, or of every entry (None)."""
    with _pending_lock:
        threads = list(_pending.values()) if path is None else [_pending.get(path)]
    for thread in threads:
        if thread is not None and thread is not threading.current_thread():
            thread.join()


def _write(path: Path, parts: list) -> None:
    """Write an entry's ``parts`` (:func:`_serialised`) to ``path`` atomically, then trim the folder; a failed
    write is logged once, not raised."""

    def write_parts(f: BinaryIO) -> None:
        for part in parts:
            f.write(part)

    try:
        atomic.write_with(path, write_parts)
        trim(path.parent.parent, limit_bytes())
    except OSError as exc:  # a folder that cannot be written (read-only, /proc, full): every command recomputes
        if exc.errno == errno.ENOSPC:  # entries that fit were written: only those that do not are recomputed
            _warn_once(
                "the disk cache in %s is on a full disk (%s): sensor-level results that do not fit are computed "
                "again by every command (free space, lower %s, or set %s to another folder, or to off)",
                path.parent.parent,
                exc.strerror or exc,
                ENV_MB,
                ENV_DIR,
            )
            return
        _warn_once(
            "the disk cache in %s cannot be written (%s): sensor-level results are computed again by every "
            "command (set %s to a writable folder, or to off)",
            path.parent.parent,
            exc.strerror or exc,
            ENV_DIR,
        )


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
    wait()
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
    """(entries, bytes) in the cache folder (this process's background writes finished first)."""
    wait()
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
    """Digest of the package's Python source and the versions of the libraries that compute or store the entries:
    any edit of a formula, or another NumPy, SciPy, pyamg or OpenCV (the smoothed shading is OpenCV's blur), makes
    every earlier entry a miss (computed once; thread-safe)."""
    global _salt
    with _salt_lock:
        if _salt is None:
            from .code_version import python_sources, source_digest
            from .libraries import SOLVE_LIBRARIES, library_versions

            h = hashlib.blake2b(digest_size=16)
            h.update(f"{sys.version_info[:2]} {sorted(library_versions(SOLVE_LIBRARIES).items())}".encode())
            h.update(source_digest(python_sources()).encode())  # the whole package: any formula's edit misses
            _salt = h.hexdigest()
        return _salt


def salt_ahead() -> None:
    """Compute the entries' salt (:func:`_source_salt`) now, when the tier is on: for a thread that runs beside the
    command's imports (:func:`nlipscalib.pipeline.provenance.identity_in_background`).

    Why: the first entry a solve looks up (the press's reference.npz, :mod:`nlipscalib.core.surface_files`) made it
    on the main thread, reading and hashing every source file of the package (35-80 ms at load 10 on the 2-core VM)
    just after the imports, while the second core had nothing to do (benchmarks/RESULTS.md, s31-cube)."""
    if folder() is not None:
        _source_salt()
