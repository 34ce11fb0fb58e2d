"""The coarse-to-fine image pyramid of a solve (cv2.resize INTER_AREA, Camera.scaled)."""

from __future__ import annotations

from collections.abc import Container
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera
from ..core.errors import ShapeError
from . import geometry, reuse, threads
from .options import SolverOptions

if TYPE_CHECKING:
    import numpy.typing as npt


def resize(a: np.ndarray, shape: tuple[int, int], linear: bool = False) -> np.ndarray:
    import cv2

    interp = cv2.INTER_LINEAR if linear else cv2.INTER_AREA
    a = np.ascontiguousarray(a, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] > 4:  # OpenCV handles up to 512 channels, but keep it simple
        return np.stack([resize(a[..., k], shape, linear) for k in range(a.shape[2])], axis=-1)
    return cv2.resize(a, (shape[1], shape[0]), interpolation=interp).astype(np.float64)


def checked_prior_weights(weights: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    if weights is None:
        return np.ones(shape)
    weights = np.asarray(weights, dtype=np.float64)
    if weights.shape != shape or not np.all(np.isfinite(weights)) or weights.min() < 0:
        raise ShapeError(f"prior_weights must be a finite, non-negative {shape} array, got {weights.shape}")
    return weights


def masked_planes(stack: np.ndarray, mask: np.ndarray, dtype: npt.DTypeLike) -> np.ndarray:
    """(L, 3, N) contiguous ``dtype`` -- the mask's pixels of (L, H, W, 3) ``stack``, one plane per LED and
    channel. Gathered plane by plane (the strided channel indexed at the mask's pixels): a third of the time
    of indexing the stack and moving its channel axis (0.05 against 0.18 s for 12 LEDs at 640x480); one LED's
    planes per task on the thread pool (NumPy's indexing releases the GIL)."""
    index = np.flatnonzero(mask)
    out = np.empty((stack.shape[0], stack.shape[-1], len(index)), dtype)

    def planes(i: int) -> None:
        flat = stack[i].reshape(-1, stack.shape[-1])
        for c in range(flat.shape[1]):
            out[i, c] = flat[index, c]  # a cast too where dtype differs (the bool usable samples)

    threads.map_items(planes, range(stack.shape[0]))
    return out


GEOMETRY_LEVELS = 8
"""Levels whose rays and normal basis a process keeps (as :data:`nlipscalib.solver.operators.OPERATOR_LEVELS` keeps
their operators): a pyramid's four to six, and a spare."""


def level_geometry(
    camera: Camera, mask: np.ndarray, persist: bool = False
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """A level's rays q and normal basis (A, B, C) on its mask's pixels (:mod:`nlipscalib.solver.geometry`),
    kept for the next solve on the same camera and mask (solver.reuse; read-only): the outer interreflection loop's
    passes and a dataset's whole-frame presses solve on the same levels, and at 640x480 they cost ~0.2 s.

    ``persist``: also keep them on disk for the next process (a level of the sensor's whole gel, which every
    whole-frame press solves on): a 640x480 pyramid's levels take 0.08 s of CPU to compute and 0.004 s to read back
    (39 MB; benchmarks/RESULTS.md, s17-k). An ROI's levels (one per press) are computed in the process.

    Returns
    -------
    q : (N, 3) float64; A, B, C : (N, 3) float64 each -- N the mask's pixels, in row-major order.
    """

    def make():
        q, qu, qv = geometry.ray_tables(camera)
        return geometry.masked_basis(q, qu, qv, mask)

    return reuse.reused("level geometry", (camera, reuse.digest(mask)), make, most=GEOMETRY_LEVELS, persist=persist)


def build_pyramid(
    cam: Camera,
    data: np.ndarray,
    use: np.ndarray,
    mask: np.ndarray,
    t0: np.ndarray,
    w0: np.ndarray,
    opts: SolverOptions,
    skip: Container[int] = (),
    scale: float = 1.0,
    whole_gel: bool = False,
    bare: Container[int] = (),
) -> list[dict]:
    """Levels from coarse to fine; each: camera, images (L, 3, N), usable, mask, t0, zeta, rays.

    ``data``: (L, H, W, 3) float; the levels hold ``data / scale`` (``scale``: a scalar of ``data``'s dtype).
    ``skip``: levels not built, counted from the finest (0); they still count in ``opts.pyramid_levels``.
    ``whole_gel``: ``mask`` is the sensor's whole gel, so the levels' rays are kept on disk (:func:`level_geometry`).
    ``bare``: levels built without images and usable samples, counted from the finest: levels brought up from a
    coarser one, not solved (an outer pass's finest: 88 MB gathered at 640x480 with 12 LEDs); a level that ends up
    the only one is given them all the same."""
    n_levels = opts.pyramid_levels
    if n_levels == 0:
        n_levels = 1
        while min(cam.shape) / 2**n_levels >= 2 * opts.min_level_size:
            n_levels += 1
    built = [k for k in range(n_levels) if k not in skip]
    # the coarser levels are resized from the whole divided images; the finest level's planes are divided once
    # gathered (the same bits: one division per value), so a warm-started pass (the finest level alone) makes
    # no divided copy of the images (44 MB, 0.03 s at 640x480)
    divided = data / scale if any(k > 0 for k in built) else None
    levels = []
    for k in built:
        c = cam if k == 0 else cam.scaled(0.5**k)
        if k == 0:
            d, u, mk, tk, wk = data, use, mask, t0, w0
        else:
            d = np.stack([resize(img, c.shape) for img in divided]).astype(data.dtype, copy=False)
            u = np.stack([resize(x.astype(np.float32), c.shape) for x in use]) > 0.999
            mk = resize(mask.astype(np.float32), c.shape) > 0.999
            with np.errstate(divide="ignore"):  # log(0) off the mask, replaced just below
                tk = np.log(
                    resize(np.where(mask, np.exp(t0), 0.0), c.shape)
                    / np.maximum(resize(mask.astype(np.float32), c.shape), 1e-9)
                )
            tk = np.where(mk, tk, 0.0)
            wk = resize(w0.astype(np.float32), c.shape)
        if mk.sum() < 16:
            break
        q, (A, B, C) = level_geometry(c, mk, persist=whole_gel)
        level = {
            "camera": c,
            "mask": mk,
            "t0": tk,
            "zeta": opts.prior_weight * wk[mk].astype(np.float64),  # (N,) per-pixel prior weight
            "q": q,
            "ABC": (A, B, C),
        }
        if k not in bare:
            level.update(_samples(d, u, mk, scale if k == 0 else None))
        levels.append(level)
    if len(levels) == 1 and "images" not in levels[0]:  # nothing coarser to bring it up from: it is solved
        levels[0].update(_samples(data, use, mask, scale))
    return levels[::-1]


def _samples(images: np.ndarray, usable: np.ndarray, mask: np.ndarray, scale: float | None) -> dict:
    """A level's images and usable samples on its mask, (L, 3, N) contiguous each (the model's pixel chunks are
    then views, not copies), the images divided by ``scale`` (None: already divided)."""
    planes = masked_planes(images, mask, images.dtype)
    if scale is not None:
        planes /= scale
    return {"images": planes, "usable": masked_planes(usable, mask, images.dtype)}
