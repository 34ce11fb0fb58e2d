"""A press's images decoded at their first read: the loaders a :class:`~nlipscalib.core.capture.Press` field may be
given (:class:`Loader`, :class:`FileLoader`, :class:`StoredImages`) and the field that loads them
(:class:`LoadedOnRead`), the decoding of a capture's PNGs on a thread pool, together or in the background
(:func:`decode_together`, :func:`decode_in_background`), and the stamp that tells a file changed
(:func:`file_stamp`)."""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .camera import Camera
from .cpus import usable_cores
from .errors import CaptureError
from .imageio import capture_shape_problem, decode_png16, read_png_bytes
from .prefetch import stop as stop_prefetching
from .prefetch import take as take_prefetched
from .press_meta import META_FILE, existing_file
from .sensor_response import undo_tone_curve


class Loader:
    """A value of a :class:`.capture.Press` field given before it is loaded: ``load()`` makes it at the first read of
    the field (:class:`LoadedOnRead`), and any error it raises (a CaptureError naming the file) comes out there."""

    def __init__(self, load: Callable[[], object]):
        self._load = load

    def load(self) -> object:
        return self._load()


class FileLoader(Loader):
    """A :class:`Loader` of one file of the capture, which must still be the file that was there when the press
    was loaded: a press is what its folder held then, and a file replaced since (the folder rendered or captured
    again) would mix two presses in one object. Such a read is refused, naming the file."""

    def __init__(self, path: Path, load: Callable[[], object]):
        super().__init__(load)
        self.path = path
        self.stamp = _stamp_or_none(path)

    def load(self) -> object:
        if _stamp_or_none(self.path) != self.stamp:
            raise CaptureError(f"{self.path}: changed since the press was loaded; load the press again")
        return self._load()


def _stamp_or_none(path: Path) -> tuple[int, ...] | None:
    try:
        return file_stamp(path)
    except OSError:  # missing: the loader names it at the read, as it would have at the load
        return None


def file_stamp(path: str | os.PathLike) -> tuple[int, ...]:
    """What tells that a file's content may have changed without reading it, for caches of what a process read
    from a capture: device and inode (replaced by a rename), size, and modification and change times in ns
    (written in place; the change time too, as a copy that keeps the old modification time still sets it).
    FileNotFoundError when there is none. A stat: microseconds (os.stat of a str: half pathlib's cost)."""
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


class StoredImages(Loader):
    """Stored images of a capture read from their PNG files now, decoded at the first read.

    The files' bytes are read once and kept until decoded, so the decoded images and :attr:`digest` always
    name the same content, whatever happens to the files later.
    """

    def __init__(
        self,
        paths: Sequence[Path],
        data: Sequence[np.ndarray],
        camera: Camera,
        stacked: bool,
        named: bool = True,
        tone_curve: np.ndarray | None = None,
    ):
        self._paths, self._data, self._camera, self._stacked = list(paths), list(data), camera, stacked
        self._tone_curve = tone_curve
        """(65536,) uint16 table undoing the camera's tone curve after decoding (``SensorResponse.tone_curve``), or
        None (a linear camera)."""
        self._images, self._lock = None, threading.Lock()
        self.digest = _bytes_digest(self._data) if named else None
        """Digest of the files' raw bytes, in order; None when not ``named`` (images decoded at once: ~25 ms
        of hashing at 640x480 that nothing reads)."""

    def load(self) -> np.ndarray:
        return decode_together(self)[0]

    def __getstate__(self) -> dict:  # a Press sent to another process (a worker): the lock is this process's
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _lock=threading.Lock())


def _bytes_digest(data: Sequence[np.ndarray]) -> str:
    h = hashlib.blake2b(digest_size=16)
    for d in data:  # lengths too: the same bytes cut between two files otherwise would not differ
        h.update(len(d).to_bytes(8, "little"))
        h.update(memoryview(d))
    return f"png:{h.hexdigest()}"


def decode_together(*sources: StoredImages) -> list[np.ndarray]:
    """The images of ``sources``, each (H, W, 3) or stacked (N, H, W, 3) uint16, decoded on one thread pool
    (libpng and zlib release the GIL) once for all reads of them; a problem names its file (:func:`load_image`'s
    errors)."""
    for src in sources:  # in order, always: two threads reading two fields at once wait for each other
        src._lock.acquire()
    try:
        todo = [src for src in sources if src._images is None]
        # each image decoded straight into its place in the result: no per-image copies, no np.stack
        images = [np.empty((len(src._paths),) + src._camera.shape + (3,), np.uint16) for src in todo]
        jobs = [
            (_decode_image, p, d, src._camera, out[i], src._tone_curve)
            for src, out in zip(todo, images)
            for i, (p, d) in enumerate(zip(src._paths, src._data))
        ]
        if jobs:
            stop_prefetching()  # what the prefetch has not begun is decoded here, on two threads
            in_threads(jobs)
        for src, out in zip(todo, images):  # only now: a failed decode leaves the source undecoded
            src._images = out if src._stacked else out[0]
            src._data = []  # the bytes are no longer needed
        return [src._images for src in sources]
    finally:
        for src in sources:
            src._lock.release()


def decode_in_background(*sources: StoredImages) -> threading.Thread:
    """Start :func:`decode_together` of ``sources`` on a thread of its own and return it; the first read of them
    waits for it (the sources' locks), or decodes them itself when it comes before the thread took them.

    Why: cv2's PNG decoding releases the GIL, so the decoding runs on the second core while the caller goes on
    (``nlips solve`` reads and checks reference.npz meanwhile; the decoding is ~0.14 s on two threads at 640x480
    with 12 LEDs).

    A problem is not raised on the thread: a failed decode leaves its source undecoded, and the first read decodes
    it again and raises the error there, naming the file (:func:`load_image`'s errors)."""

    def decode() -> None:
        with contextlib.suppress(Exception):  # raised again, at the first read, to whoever reads the images
            decode_together(*sources)

    thread = threading.Thread(target=decode, name="decode-capture", daemon=True)
    thread.start()
    return thread


class LoadedOnRead:
    """A field of a frozen dataclass (:class:`.capture.Press`, :class:`.surface_files.GroundTruth`) that takes its
    value or a :class:`Loader` of it: the value is loaded at the first read and kept. Why: a solve reads neither
    the ground truth nor, but for its check against the LED images (:mod:`.tricolor_check`, a few samples), the
    tri-colour image, and a solve that reuses the undeformed capture's results never
    reads its images (decoding them is most of a warm process's loading); an error map reads 3 of the ground
    truth's 5 arrays."""

    def __init__(self, default: object = dataclasses.MISSING):
        self.default = default

    def __set_name__(self, owner: type, name: str):
        self.name = name

    def __get__(self, obj: object, owner: type | None = None) -> object:
        if obj is None:  # the dataclass asks for the field's default
            if self.default is dataclasses.MISSING:
                raise AttributeError(self.name)
            return self.default
        value = obj.__dict__[self.name]
        if isinstance(value, Loader):
            value = value.load()
            obj.__dict__[self.name] = value  # the Loader stays in the source: what the value was read from
        return value

    def __set__(self, obj: object, value: object) -> None:  # __init__ only: the frozen Press refuses others
        obj.__dict__[self.name] = value
        obj.__dict__[f"{self.name}_source"] = value if isinstance(value, Loader) else None


def load_image(folder: Path, name: str, camera: Camera, tone_curve: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint16 of the image ``name`` that meta.json lists in ``folder``, read, decoded and checked
    against the camera (:func:`_decode_image`), the camera's ``tone_curve`` undone (:class:`StoredImages`);
    CaptureError naming the file."""
    path = existing_file(folder, name)
    return _decode_image(path, read_png_bytes(path), camera, tone_curve=tone_curve)


def _decode_image(
    path: Path, data: np.ndarray, camera: Camera, out: np.ndarray | None = None, tone_curve: np.ndarray | None = None
) -> np.ndarray:
    """(H, W, 3) uint16 of a capture's PNG read from ``path`` (``data``: its bytes), checked against the camera;
    written into ``out`` ((H, W, 3) uint16) when given; the camera's ``tone_curve`` undone (:class:`StoredImages`:
    once, as each image is decoded, on the decoding's threads). An image decoded ahead from these same bytes
    (:mod:`.prefetch`) is taken rather than decoded again."""
    img = take_prefetched(path, data)
    if img is None:
        img = decode_png16(data, path, out=out)
    elif out is not None and out.shape == img.shape:
        out[...] = img
        img = out
    if problem := capture_shape_problem(img.shape, camera.shape, META_FILE):
        raise CaptureError(f"{path}: {problem}")
    return undo_tone_curve(img, tone_curve)


def in_threads(jobs: list[tuple]) -> list:
    """Run (func, *args) jobs on a thread pool: PNG and zlib coding release the GIL, so this scales."""
    with ThreadPoolExecutor(max_workers=min(len(jobs), usable_cores()) or 1) as pool:
        return list(pool.map(lambda job: job[0](*job[1:]), jobs))
