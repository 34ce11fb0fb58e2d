"""Digests of the package's own Python source: what tells two versions of its code apart when its version number
does not (``__version__`` is the same in every commit between releases).

Used by the reuse of results (:func:`code_fingerprint`, in :func:`nlipscalib.core.reconstruction.provenance_key`)
and by the disk cache's keys (:func:`python_sources`, in :mod:`nlipscalib.core.diskcache`). Read through
:mod:`importlib.resources`, so an installed wheel (site-packages) is fingerprinted as a checkout is; no git needed.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.resources
import threading
from collections.abc import Iterator
from importlib.resources.abc import Traversable

PACKAGE = __name__.split(".")[0]
"""The package whose source is digested (``nlipscalib``)."""
RESULT_CODE = ("core", "solver", "pipeline", "learn")
"""Subpackages whose source decides a result's numbers: formats and shared models (core), NLiPs (solver), the
solve pipeline (pipeline), NLiPsNet's inference (learn). The command line (cli), the twin (sim), the device,
experiments and figures only choose settings (recorded in the key themselves) or make inputs (identified by
content): a change there keeps results reusable."""
TRAIN_CODE = ("core", "learn")
"""Subpackages whose source decides a trained NLiPsNet's weights: the samples' formats and shared models (core) and
NLiPsNet's network, training loop and checkpoints (learn). A finished model whose checkpoint records another digest
(or none: trained before 2026-12-06) is trained again, not reused (:func:`nlipscalib.learn.checkpoint.
training_code`), as a result of other solver code is solved again."""
RENDER_CODE = ("core", "sim")
"""Subpackages whose source decides a rendered press's images: the twin (sim) and the formats and shared models it
writes with (core). The solver is not among them: a rendered press (an experiment's reference, an ``nlips dataset``
press) is kept when only the solver changed, as re-rendering costs seconds to minutes a press."""


def python_sources(
    package: Traversable | None = None, subpackages: tuple[str, ...] | None = None
) -> list[tuple[str, bytes]]:
    """(path relative to the package, with "/", file bytes) of every ``.py`` file below ``package`` (default this
    package, as installed), in ``subpackages`` only when given (None: all, the top-level modules too), sorted by path
    parts: the order :func:`code_fingerprint` and the disk cache hash them in. Compiled ``__pycache__`` files are left
    out: a source tree digests alike compiled or not. Only the files asked for are read."""
    root = importlib.resources.files(PACKAGE) if package is None else package
    if subpackages is None:
        found = _walk(root, ())
    else:
        found = (item for name in subpackages if (sub := root / name).is_dir() for item in _walk(sub, (name,)))
    return sorted(found, key=lambda item: item[0].split("/"))


def _walk(folder: Traversable, parts: tuple[str, ...]) -> Iterator[tuple[str, bytes]]:
    for entry in folder.iterdir():
        if entry.is_dir():
            if entry.name != "__pycache__":
                yield from _walk(entry, (*parts, entry.name))
        elif entry.name.endswith(".py"):
            yield "/".join((*parts, entry.name)), entry.read_bytes()


def source_digest(sources: list[tuple[str, bytes]]) -> str:
    """BLAKE2b-128 (hex) of ``sources`` (:func:`python_sources`), each path then its bytes: a file edited, added,
    removed or renamed changes it."""
    h = hashlib.blake2b(digest_size=16)
    for name, data in sources:
        h.update(name.encode())
        h.update(data)
    return h.hexdigest()


_computing = threading.Lock()


def code_fingerprint() -> str:
    """Digest of the source of :data:`RESULT_CODE` in the package as installed (32 hex), computed once per process.

    Why: results are reused when their key matches (``nlips solve``, ``nlips infer``), and the version number is
    "0.1.0" in every commit, so a user who upgraded was served a result of the old code silently. Costs one read
    of ~1 MB of source, a few ms, on first use (benchmarks/RESULTS.md, s26-leftovers); thread-safe, so a
    background thread may compute it ahead (:func:`nlipscalib.pipeline.identity_in_background`)."""
    with _computing:
        return _fingerprint()


@functools.cache
def _fingerprint() -> str:
    return source_digest(python_sources(subpackages=RESULT_CODE))


def subpackages_fingerprint(subpackages: tuple[str, ...]) -> str:
    """Digest (32 hex) of the source of ``subpackages`` (names below the package, e.g. :data:`RENDER_CODE`) as
    installed, computed once per process and tuple: what an experiment's task result (and a rendered press)
    records of the code that made it, so that a change of that code, and of no other, makes it anew.

    The same digest as :func:`code_fingerprint` for ``RESULT_CODE`` (one file order, one hash)."""
    with _computing:
        return _subpackages_fingerprint(tuple(subpackages))


@functools.cache
def _subpackages_fingerprint(subpackages: tuple[str, ...]) -> str:
    return source_digest(python_sources(subpackages=subpackages))
