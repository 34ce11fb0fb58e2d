"""Sensor-level results of a solve, kept for the next press of the same sensor in this process.

A calibration solves some 50 presses of one sensor in a few long-lived worker processes (``nlips
calibrate``, ``nlips solve DATASET``, the experiments). Part of every solve depends on the sensor alone,
not on the press: the direct shading of the undeformed surface, that surface as radiosity patches, the
dome beyond the view, and the interreflection fit on the capture of the undeformed dome. At 640x480 that
is about 1-1.5 s of each press's solve. The sparse difference operators of a pyramid level depend
on its mask alone (0.5-0.9 s at 640x480), and every pass of the outer interreflection loop and every whole-frame
press of a dataset solves on the same masks. Those results are memoised here, keyed by what they are computed
from (camera, LEDs, a digest of the undeformed surface's arrays or of a mask, or the identity of a loaded
reference capture), a few per kind, so a changed input is never served a stale result; and by the BLAS thread
setting they were computed under (:func:`nlipscalib.core.blas.blas_setting`): a matrix product's last bits
depend on it, and a sweep that runs its tasks under one BLAS thread for reproducible numbers must not
be served a result an earlier call computed under two. Stored arrays are made read-only: a caller that
would modify one fails loudly instead of corrupting the next press's solve.

Results that depend on the sensor alone are also kept on disk for the next process
(``persist=True``; :mod:`nlipscalib.core.diskcache`, written in the background): their keys must name their
inputs by content, never by the identity of an object in this process, and neither they nor the objects
holding their arrays may be changed once returned (their arrays are made read-only).

A result that later computations mostly use as part of their own keys (the undeformed surface's direct
shading: 88 MB at 640x480) is handed out :func:`deferred`: named by its key, its values loaded or computed only
when a consumer misses its own cache and needs them (:func:`values`).
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import TypeVar

import numpy as np

from ..core import diskcache

T = TypeVar("T")

PER_KIND = 2
"""Results kept per kind (one sensor, and a second one for runs that alternate)."""

_store: dict[str, OrderedDict] = {}


digest = diskcache.digest
"""Content digest of arrays (:func:`nlipscalib.core.diskcache.digest`): the keys of both tiers name arrays alike."""


def reused(
    kind: str,
    key: Hashable,
    compute: Callable[[], T],
    keep: object | None = None,
    most: int = PER_KIND,
    persist: bool = False,
) -> T:
    """``compute()``, or the result stored under ``(kind, key)`` by an earlier call.

    ``keep``: an object the key identifies by ``id`` (a loaded capture): it is stored with the result,
    which is served only while ``keep`` is that same object (an ``id`` can be reused after it is freed).
    ``most``: results of this kind kept (the least recently used go first).
    ``persist``: also look for the result on disk, and store it there for later processes
    (:mod:`nlipscalib.core.diskcache`); ``key`` must then name the inputs by content and ``keep`` be None.
    """
    shelf = _store.setdefault(kind, OrderedDict())
    key = _with_setting(key)
    hit = shelf.get(key)
    if hit is not None and hit[0] is keep:
        shelf.move_to_end(key)
        return hit[1]
    value = _from_disk(kind, key, compute) if persist and keep is None else compute()
    freeze(value)
    shelf[key] = (keep, value)
    while len(shelf) > most:
        shelf.popitem(last=False)
    return value


def stored(kind: str, key: Hashable) -> bool:
    """Whether :func:`reused` would serve ``(kind, key)`` from this process's store (a result without ``keep``):
    a caller that would compute it ahead of time, on another thread, need not."""
    hit = _store.get(kind, {}).get(_with_setting(key))
    return hit is not None and hit[0] is None


def _with_setting(key: Hashable) -> tuple:
    """``key`` with the BLAS thread setting it is computed under: the full key of a stored result."""
    from ..core.blas import blas_setting

    return key, blas_setting()


class Deferred:
    """A result of :func:`reused` named by its (kind, key) before its values are needed (:func:`deferred`).

    ``origin``: the (kind, full key) :func:`reused` stores the values under, the BLAS setting of when the
    object was made included (its consumers run in the same solve, under that setting).
    """

    def __init__(self, kind: str, key: Hashable, compute: Callable[[], object], persist: bool):
        self.origin = (kind, _with_setting(key))
        self._key, self._compute, self._persist = key, compute, persist

    def values(self) -> object:
        """The result: from this process's store, from disk, or computed (as :func:`reused` would)."""
        kind = self.origin[0]
        return reused(kind, self._key, self._compute, persist=self._persist)


def deferred(kind: str, key: Hashable, compute: Callable[[], object], persist: bool = False) -> Deferred:
    """:func:`reused`'s result of ``(kind, key)`` as a :class:`Deferred`: nothing is loaded or computed
    until a consumer asks for :func:`values`. For a large result that its consumers mostly name in their
    own keys (:func:`origin`) and only need when they miss their own caches."""
    return Deferred(kind, key, compute, persist)


def values(value: object) -> object:
    """``value``'s values: a :class:`Deferred` loaded or computed, anything else as it is."""
    return value.values() if isinstance(value, Deferred) else value


def origin(value: object) -> tuple[str, Hashable] | None:
    """(kind, key) under which :func:`reused` returned this very object (or a :class:`Deferred` names), or
    None: a later computation from it can name its input by that key instead of hashing it again."""
    if isinstance(value, Deferred):
        return value.origin
    for kind, shelf in _store.items():
        for key, (_, stored) in shelf.items():
            if stored is value:
                return kind, key
    return None


def _from_disk(kind: str, key: Hashable, compute: Callable[[], T]) -> T:
    """The result on disk, else ``compute()`` written there (nothing on disk when the tier is off)."""
    path = diskcache.entry(kind, key)
    if path is None:
        return compute()
    try:
        return diskcache.load(path)
    except KeyError:
        pass
    value = compute()
    freeze(value)  # before the background write references its arrays' memory
    # written on a thread of its own while the solve goes on: a cold 640x480 command's ~250 MB cost it 1-2 s of
    # wall on the main thread, nearly all of it fresh page-cache pages (benchmarks/RESULTS.md, s17-f)
    diskcache.store_later(path, value)
    return value


def clear() -> None:
    """Forget every stored result (tests; a process that moves to another sensor needs no call)."""
    _store.clear()


def freeze(*values: object) -> None:
    """Make the arrays in ``values`` (arrays, and dicts, tuples and lists of them) read-only."""
    for value in values:
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
        elif isinstance(value, dict):
            freeze(*value.values())
        elif isinstance(value, (tuple, list)):
            freeze(*value)
