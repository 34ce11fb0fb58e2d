"""A press's PNG images decoded ahead of its loading, on a thread of their own.

Why: ``nlips solve PRESS`` spends its first ~0.2 s of CPU importing the solver (SciPy's sparse and linear
algebra modules), on the main thread, while the second core idles; the press's images are decoded only after
that, when the press is loaded (~0.14 s of CPU at 640x480 with 12 LEDs, on two threads, with the main thread
waiting for most of it). Decoding them beside the import takes that decoding off the command's serial path:
libpng and zlib release the GIL, so the decoding runs on the idle core.

The loading stays the one source of truth: :func:`.capture.load_press` reads and checks every file's bytes as
before, and takes an image decoded here only when the bytes decoded here are the bytes it read
(:func:`take`); anything else (a file replaced since, a read or decode that failed here, a file never
prefetched) is decoded there as before, and its problems reported there, naming the file.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .imageio import decode_png16


class _Item:
    """One file's prefetch: its bytes and image once ``done`` is set (either None when reading or decoding it
    failed, or it was skipped)."""

    __slots__ = ("data", "image", "done")

    def __init__(self):
        self.data: np.ndarray | None = None
        self.image: np.ndarray | None = None
        self.done = threading.Event()


_items: dict[str, _Item] = {}
_items_lock = threading.Lock()
_stop = threading.Event()


def _key(path: str | Path) -> str:
    return os.path.abspath(path)


def prefetch_images(paths: Sequence[str | Path]) -> threading.Thread:
    """Start reading and decoding the PNG files ``paths``, in order, on a daemon thread; returns the thread.

    Nothing is raised on the thread: a file that cannot be read or decoded is left to the loading, which reports
    it. The decoded images wait for :func:`take` (a press's load); until then they hold memory (~1.8 MB a
    640x480 image)."""
    items = [(_key(p), _Item()) for p in paths]
    with _items_lock:
        _stop.clear()
        _items.update(items)

    def run() -> None:
        for key, item in items:
            try:
                if not _stop.is_set():  # a loading began: it decodes what is left itself
                    item.data = np.fromfile(key, np.uint8)
                    item.image = decode_png16(item.data, key)
            except Exception:  # noqa: BLE001 -- the loading decodes the file again and reports its problem
                item.image = None
            finally:
                item.done.set()

    thread = threading.Thread(target=run, name="prefetch-images", daemon=True)
    thread.start()
    return thread


def stop() -> None:
    """Let the prefetching thread finish the image it is decoding and decode no more: a loading that begins
    decodes the rest on its own threads rather than wait for this one."""
    _stop.set()


def take(path: str | Path, data: np.ndarray) -> np.ndarray | None:
    """The image prefetched from ``path`` when its bytes were ``data`` ((n,) uint8, the bytes the loading read),
    else None; waits for an image being decoded. Each prefetched image is taken once (then forgotten)."""
    with _items_lock:
        item = _items.pop(_key(path), None)
    if item is None:
        return None
    item.done.wait()
    if item.image is None or item.data is None or not np.array_equal(item.data, data):
        return None
    return item.image
