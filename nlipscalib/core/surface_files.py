"""A press folder's per-pixel surface arrays: the ground truth of a synthetic press (gt.npz, :class:`GroundTruth`)
and the undeformed surface (reference.npz, :class:`Reference`), read and checked against the format's promise (the
reference once per process while its file is the same, its arrays kept on disk under their bytes' digest)."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
from pathlib import Path

import numpy as np

from .camera import Camera
from .errors import CaptureError
from .formatfile import read_arrays
from .imageio import save_npz
from .leds import Led, Leds
from .press_meta import existing_file
from .stored_images import FileLoader, Loader, file_stamp
from .surface_checks import surface_problem

GT_KEYS = {"depth": 2, "points": 3, "normals": 3, "valid": 2, "contact": 2}
"""Ground-truth arrays and their number of dimensions; all (H, W[, 3]) in the camera frame."""


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Per-pixel truth of a synthetic press, camera frame, millimetres."""

    depth: np.ndarray
    """(H, W) float32, mm -- z coordinate of the surface point; NaN where the ray misses the gel."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, pointing toward the camera (shading normals)."""
    valid: np.ndarray
    """(H, W) bool -- the pixel sees the gel surface."""
    contact: np.ndarray
    """(H, W) bool -- the gel under this pixel is displaced by the press."""

    def save(self, path: Path) -> None:
        save_npz(path, {k: getattr(self, k) for k in GT_KEYS})

    @classmethod
    def load(cls, path: Path, shape: tuple[int, int]) -> GroundTruth:
        arrays = _load_npz(path, GT_KEYS)
        for key, ndim in GT_KEYS.items():
            a = arrays[key]
            want = shape + ((3,) if ndim == 3 else ())
            if a.shape != want:
                raise CaptureError(f"{path}: ground truth '{key}' has shape {a.shape}, expected {want}")
        return cls(**{k: arrays[k] for k in GT_KEYS})


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
        arrays = _load_npz_kept(path, {"depth": 2, "normals": 3})
        if arrays["depth"].shape != shape or arrays["normals"].shape != shape + (3,):
            raise CaptureError(f"{path}: reference arrays do not match the camera size {shape}")
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


def read_reference(folder: Path, meta: dict, camera: Camera, leds: Leds) -> Reference | None:
    """The capture's reference.npz, checked against the format's promise; None when it has none."""
    if not meta.get("reference"):
        return None
    path = existing_file(folder, meta["reference"])
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
    arrays = read_arrays(path, keys, unreadable="not a readable .npz file")
    for k in keys:
        if arrays[k].dtype.kind not in "biuf":  # strings, objects: else numpy's "ufunc 'isfinite' not supported"
            raise CaptureError(f"{path}: array '{k}' holds {arrays[k].dtype} values, expected numbers")
        if arrays[k].dtype.kind == "f" and k != "depth" and k != "points" and not np.all(np.isfinite(arrays[k])):
            # normals are finite everywhere by convention (zero where invalid); depth/points use NaN
            raise CaptureError(f"{path}: array '{k}' contains NaN or infinity")
    return arrays
