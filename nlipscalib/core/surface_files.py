"""A press folder's per-pixel surface arrays: the ground truth of a synthetic press (gt.npz, :class:`GroundTruth`)
and the undeformed surface (reference.npz, :class:`Reference`), read and checked against the format's promise (the
reference once per process while its file is the same, its arrays kept on disk under their bytes' digest)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import threading
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import CaptureError
from .formatfile import read_array_headers, read_arrays
from .imageio import save_npz
from .leds import Led, Leds
from .press_meta import existing_file
from .stored_images import FileLoader, LoadedOnRead, Loader, file_stamp
from .surface_checks import surface_problem

GT_KEYS = {"depth": 2, "points": 3, "normals": 3, "valid": 2, "contact": 2}
"""Ground-truth arrays and their number of dimensions; all (H, W[, 3]) in the camera frame."""
NPZ_UNREADABLE = "not a readable .npz file"
"""How a surface file's messages word an archive numpy cannot read."""


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Per-pixel truth of a synthetic press, camera frame, millimetres.

    Made from its arrays, or read from a gt.npz by :meth:`load`: each array is then inflated and checked at its
    first read, naming the file and the array when it is damaged. Why: its readers need some of them (an error map
    the normals, the valid and the contact masks; a score no points), and inflating all five of a 640x480 file took
    ~60 ms of CPU, more than ``nlips infer``'s inference."""

    depth: np.ndarray = LoadedOnRead()
    """(H, W) float32, mm -- z coordinate of the surface point; NaN where the ray misses the gel."""
    points: np.ndarray = LoadedOnRead()
    """(H, W, 3) float32, mm, camera frame."""
    normals: np.ndarray = LoadedOnRead()
    """(H, W, 3) float32, unit, camera frame, pointing toward the camera (shading normals)."""
    valid: np.ndarray = LoadedOnRead()
    """(H, W) bool -- the pixel sees the gel surface."""
    contact: np.ndarray = LoadedOnRead()
    """(H, W) bool -- the gel under this pixel is displaced by the press."""

    def save(self, path: Path) -> None:
        save_npz(path, {k: getattr(self, k) for k in GT_KEYS})

    @classmethod
    def load(cls, path: Path, shape: tuple[int, int]) -> GroundTruth:
        """The ground truth in ``path`` for a camera of ``shape`` (H, W): the archive and its arrays' shapes and
        types are checked now (their headers: nothing is inflated), each array's values at its first read
        (:func:`_read_checked`, from the same file: one replaced since is refused)."""
        headers = read_array_headers(path, GT_KEYS, unreadable=NPZ_UNREADABLE)
        for key, ndim in GT_KEYS.items():
            found, dtype = headers[key]
            want = shape + ((3,) if ndim == 3 else ())
            _check_type(path, key, dtype)
            if found != want:
                raise CaptureError(f"{path}: ground truth '{key}' has shape {found}, expected {want}")
        return cls(**{k: FileLoader(path, functools.partial(_read_checked, path, k)) for k in GT_KEYS})


def _read_checked(path: Path, key: str) -> np.ndarray:
    """The array ``key`` of the .npz at ``path``, inflated alone and checked (:func:`_check_values`); a damaged one
    is one CaptureError naming the file and the array."""
    array = read_arrays(path, (key,), unreadable=f"array '{key}' is not readable", only=(key,))[key]
    _check_type(path, key, array.dtype)
    _check_values(path, key, array)
    return array


@dataclasses.dataclass(frozen=True)
class Reference:
    """The undeformed sensor surface as seen by the camera (from the design or a calibration)."""

    depth: np.ndarray
    """(H, W) float32, mm -- z of the undeformed gel surface; NaN where the ray misses the gel."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, toward the camera."""

    def save(self, path: Path) -> None:
        save_npz(path, {"depth": self.depth, "normals": self.normals})

    @classmethod
    def load(cls, path: Path, shape: tuple[int, int]) -> Reference:
        """The reference in ``path`` for a camera of ``shape`` (H, W). Its arrays' shapes and types are checked from
        their headers before anything is inflated, and only ``depth`` and ``normals`` are inflated.

        Why: a reference.npz comes with every press folder, from elsewhere too; a tiny archive may declare an array
        of gigabytes (zeros deflate ~1000:1), or carry one beside the two: a 5 MB file with a 1 GiB extra member
        took a solve from 0.6 to 1.2 GB of memory before it was read whole (docs/formats.md, "Files from others")."""
        keys = {"depth": 2, "normals": 3}
        headers = read_array_headers(path, keys, unreadable=NPZ_UNREADABLE)
        for key in keys:
            _check_type(path, key, headers[key][1])
        if headers["depth"][0] != shape or headers["normals"][0] != shape + (3,):
            raise CaptureError(f"{path}: reference arrays do not match the camera size {shape}")
        arrays = _load_npz_kept(path, keys)
        return cls(depth=arrays["depth"], normals=arrays["normals"])


def ground_truth_loader(folder: Path, meta: dict, camera: Camera, leds: Leds) -> Loader:
    """The press's ground truth, loaded at its first read (:func:`_ground_truth`)."""
    load = functools.partial(_ground_truth, folder, meta, camera, leds)
    name = meta.get("ground_truth")
    return FileLoader(folder / name, load) if name and isinstance(name, str) else Loader(load)


def _ground_truth(folder: Path, meta: dict, camera: Camera, leds: Leds) -> GroundTruth | None:
    """The capture's gt.npz, checked against the format's promise; None when it has none."""
    if not meta.get("ground_truth"):
        return None
    path = existing_file(folder, meta["ground_truth"])
    gt = GroundTruth.load(path, camera.shape)
    _check_surface(path, surface_problem(gt.depth, gt.normals, gt.valid.astype(bool), camera, leds))
    return gt


_reading_reference = threading.Lock()
"""Held while a reference.npz is read and checked: a load that asks for the one a thread is reading ahead
(:func:`nlipscalib.core.capture.prefetch_press`) waits for it, then finds it kept, rather than read it again."""


def read_reference(folder: Path, meta: dict, camera: Camera, leds: Leds) -> Reference | None:
    """The capture's reference.npz, checked against the format's promise; None when it has none."""
    if not meta.get("reference"):
        return None
    path = existing_file(folder, meta["reference"])
    with _reading_reference:
        return _checked_reference(path, file_stamp(path), camera, tuple(leds))


@functools.lru_cache(maxsize=4)
def _checked_reference(path: Path, stamp: tuple, camera: Camera, leds: tuple[Led, ...]) -> Reference:
    """The reference.npz at ``path``, checked, its arrays read-only: loaded once per process while the file is the same
    file, size and times (``stamp``, :func:`file_stamp`). Why: a solve with a reference reads each capture's file twice
    (the settings check's :func:`.capture.read_optics`, then :func:`.capture.load_press`), ~35 ms each at 640x480."""
    ref = Reference.load(path, camera.shape)
    _check_surface(path, surface_problem(ref.depth, ref.normals, np.isfinite(ref.depth), camera, leds))
    for array in (ref.depth, ref.normals):  # shared by every Press loaded from the file
        array.setflags(write=False)
    return ref


def _check_surface(path: Path, problem: str | None) -> None:
    """CaptureError naming the file when ``problem`` (:func:`nlipscalib.core.surface_checks.surface_problem` of
    its depth and normals) says what is wrong with the surface it holds; nothing when ``problem`` is None."""
    if problem:
        raise CaptureError(f"{path}: {problem}")


def _load_npz_kept(path: Path, keys: dict) -> dict:
    """:func:`_load_npz`, its arrays kept in the disk tier (:mod:`nlipscalib.core.diskcache`) under a digest of the
    file's bytes: the next process reading the same bytes maps them instead of inflating them.

    Why: a sensor's presses carry the same reference.npz (the undeformed surface, the same bytes in every press
    folder), and inflating its 4.3 MB took ~27 ms of one core at the start of every ``nlips solve`` (~0.16 s of the
    main thread under load, beside the press's PNG decoding on the other core); reading and hashing the file
    takes ~5 ms. The same arrays: those :func:`_load_npz` read and checked, stored as they are."""
    from . import diskcache

    entry = None
    with contextlib.suppress(OSError):  # missing or unreadable: _load_npz names the file and the problem
        content = hashlib.blake2b(path.read_bytes(), digest_size=16).hexdigest()
        entry = diskcache.entry("npz arrays", (content, sorted(keys.items())))
    if entry is not None:
        with contextlib.suppress(KeyError):  # not kept yet, or unreadable: read again and kept
            return diskcache.load(entry)
    arrays = _load_npz(path, keys)
    if entry is not None:
        diskcache.store_later(entry, arrays)
    return arrays


def _load_npz(path: Path, keys: dict) -> dict:
    """Every array of the .npz at ``path``, read now and checked (:func:`_check_type`, :func:`_check_values`)."""
    arrays = read_arrays(path, keys, unreadable=NPZ_UNREADABLE, only=keys)
    for k in keys:
        _check_type(path, k, arrays[k].dtype)
        _check_values(path, k, arrays[k])
    return arrays


def _check_type(path: Path, key: str, dtype: np.dtype) -> None:
    """CaptureError naming the file unless the array ``key`` holds numbers."""
    if dtype.kind not in "biuf":  # strings, objects: else numpy's "ufunc 'isfinite' not supported"
        raise CaptureError(f"{path}: array '{key}' holds {dtype} values, expected numbers")


def _check_values(path: Path, key: str, array: np.ndarray) -> None:
    """CaptureError naming the file when the array ``key`` holds NaN or infinity where the format allows none."""
    if array.dtype.kind == "f" and key != "depth" and key != "points" and not np.all(np.isfinite(array)):
        # normals are finite everywhere by convention (zero where invalid); depth/points use NaN
        raise CaptureError(f"{path}: array '{key}' contains NaN or infinity")
