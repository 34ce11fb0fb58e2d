"""The sparse path (:mod:`.integrate`'s docstring): least squares on the changed pixels only, any shape, by
SuperLU, or from :data:`SPARSE_AMG_MIN_UNKNOWNS` pixels up by AMG-preconditioned CG (its hierarchies kept
per region shape).
"""

from __future__ import annotations

import collections
import threading
from typing import TYPE_CHECKING

import numpy as np

from .integrate_geometry import RayGeometry, _gradient64
from .integrate_regions import _grown_bounds

if TYPE_CHECKING:  # scipy.sparse is imported where it is used: named for the type checker only
    from scipy.sparse import csr_matrix as sparse_matrix

ANCHOR_WEIGHT = 1e-4
"""Weak pull toward the reference log-range, on the unknown regions that touch no known pixel only (their
Poisson equation fixes the shape but not the level). Never on a region with a known neighbour: a fixed
weight there is a real bias, against the Laplacian's smallest eigenvalue ~2 (pi / L)^2 of a region L pixels
across; at 1e-4 on every pixel, contacts 50-150 px across at 640x480 came out 4-14 % too shallow."""


def _solve_sparse(
    normals: np.ndarray,
    unknown: np.ndarray,
    on_gel: np.ndarray,
    geo: RayGeometry,
    crop: tuple[slice, slice] | None = None,
) -> np.ndarray:
    """Log-range of the changed pixels ((n,) in ``unknown`` order): least squares on them only (any shape),
    SuperLU on the normal equations (AMG-preconditioned CG from :data:`SPARSE_AMG_MIN_UNKNOWNS` pixels up).

    Built on ``crop`` (default: the changed pixels' bounds grown by one pixel, where every pair of pixels that
    touches one lies), not the whole image: the same equations in the same order, and a group of noise specks
    at a 1280x960 frame's border (:func:`.integrate_regions._regions`) costs what its size says. Solves the changed
    pixels in ``crop`` (in their order there); none of their neighbours may be changed pixels outside it.
    """
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    crop = _grown_bounds(unknown) if crop is None else crop
    unknown, on_gel = unknown[crop], on_gel[crop]
    known_lr = geo.log_range[crop]
    normals64 = np.asarray(normals[crop], np.float64)
    p = _gradient64(normals64, geo.rays[crop], geo.d_u[crop])
    q = _gradient64(normals64, geo.rays[crop], geo.d_v[crop])
    index = np.full(unknown.size, -1, np.int64)
    index[np.flatnonzero(unknown)] = np.arange(int(unknown.sum()))
    rows, cols, vals, rhs = _equations(unknown, on_gel, index, known_lr, p, q)
    n = int(unknown.sum())
    A = coo_matrix((vals, (rows, cols)), shape=(len(rhs), n)).tocsr()
    anchor = ANCHOR_WEIGHT * _unbounded(unknown, on_gel)[unknown]
    normal_matrix = (A.T @ A + diags(anchor)).tocsr()
    b = A.T @ rhs + anchor * known_lr[unknown]
    if n >= SPARSE_AMG_MIN_UNKNOWNS:
        solution = _solve_amg(normal_matrix, b, known_lr[unknown], (unknown, on_gel))
        if solution is not None:
            return solution
    return splu(normal_matrix.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(b)


SPARSE_AMG_MIN_UNKNOWNS = 20_000
"""Fewest changed pixels of a sparse-path region that :func:`_solve_sparse` solves by AMG-preconditioned CG
(:func:`_solve_amg`) rather than SuperLU. The crossover, SuperLU vs AMG CPU ms (median of 3 cold solves,
s27-amgpath, 2-core Xeon at load 4-8): compact regions (a flat-pad gel disc) 5,013 px 12 vs 14, 15,361 px 55 vs
37, 31,397 px 177 vs 69; thin crosses of bands over the default dome (little SuperLU fill) 13,296 px 19 vs 32,
22,000 px 41 vs 49, 32,700 px 71 vs 74, 48,375 px 127 vs 103. SuperLU's cost grows as its fill (n^1.5 on a
compact region), AMG's as n."""


AMG_HIERARCHY_CACHE_SIZE = 2
"""Most AMG hierarchies kept, one per region shape (its changed and gel pixels: the normal matrix depends on them
alone, not on the normals). A stream repeats them (a frame whose lighting drifted flags the same whole gel; a
contact held still keeps its mask): the set-up, a third to a half of a cold solve, is then skipped. Each holds
its levels' matrices: 57 MiB for the flat pad's whole gel at 640x480, 15 MiB for the default dome's cross."""


_amg_cache: collections.OrderedDict[bytes, object] = collections.OrderedDict()


_amg_cache_lock = threading.Lock()


def _solve_amg(
    normal_matrix: sparse_matrix, b: np.ndarray, guess: np.ndarray, shape_masks: tuple[np.ndarray, np.ndarray]
) -> np.ndarray | None:
    """(n,) float64 solution of the sparse path's normal equations by conjugate gradients preconditioned with a
    classical (Ruge-Stuben) AMG V-cycle (pyamg), from ``guess`` (the reference log-range), to the relative residual
    :data:`~nlipscalib.core.tolerances.INTEGRATION_AMG_RTOL`; None where CG did not reach it (SuperLU then).

    Why Ruge-Stuben, not smoothed aggregation: on this 5-point M-matrix it took 6-9 CG steps to SA's 7-16 and half
    SA's CPU time at the same depth error (s27-amgpath). The hierarchy depends on ``shape_masks`` (the crop's changed
    and gel pixels) alone, and is kept per shape (:data:`AMG_HIERARCHY_CACHE_SIZE`).
    """
    import hashlib

    import pyamg

    from ..core.blas import blas_threads
    from ..core.tolerances import INTEGRATION_AMG_RTOL

    unknown, on_gel = shape_masks
    digest = hashlib.blake2b(repr(unknown.shape).encode(), digest_size=16)
    for mask in shape_masks:
        digest.update(np.packbits(mask).tobytes())
    key = digest.digest()
    with _amg_cache_lock:
        hierarchy = _amg_cache.get(key)
        if hierarchy is not None:
            _amg_cache.move_to_end(key)
    # one BLAS thread: CG's norms and dot products of ~1e5 values took 16 ms each, not 0.03, with a second
    # thread waiting on a shared machine (load 5, s27-amgpath)
    with blas_threads(1):
        if hierarchy is None:
            hierarchy = pyamg.ruge_stuben_solver(normal_matrix.tocsr())
            with _amg_cache_lock:
                _amg_cache[key] = hierarchy
                while len(_amg_cache) > AMG_HIERARCHY_CACHE_SIZE:
                    _amg_cache.popitem(last=False)
        x, info = hierarchy.solve(b, x0=guess.copy(), tol=INTEGRATION_AMG_RTOL, accel="cg", return_info=True)
    return x if info == 0 else None


def _unbounded(unknown: np.ndarray, on_gel: np.ndarray) -> np.ndarray:
    """(H, W) bool -- the unknown pixels whose 4-connected region has no known on-gel neighbour (nothing
    fixes its level: e.g. a region that covers the whole gel)."""
    from scipy import ndimage

    labels, count = ndimage.label(unknown)
    touching = ndimage.binary_dilation(on_gel & ~unknown) & unknown
    bounded = np.zeros(count + 1, bool)
    bounded[np.unique(labels[touching])] = True
    return unknown & ~bounded[labels]


def _equations(
    unknown: np.ndarray, on_gel: np.ndarray, index: np.ndarray, known_lr: np.ndarray, p: np.ndarray, q: np.ndarray
):
    """Rows of the least-squares system x_j - x_i = (g_i + g_j) / 2 over neighbour pairs touching an unknown."""
    rows, cols, vals, rhs = [], [], [], []
    n_eq = 0
    flat_lr = known_lr.ravel()
    for axis, grad in ((1, p), (0, q)):
        a = (slice(None), slice(None, -1)) if axis == 1 else (slice(None, -1), slice(None))
        b = (slice(None), slice(1, None)) if axis == 1 else (slice(1, None), slice(None))
        lin = np.arange(unknown.size).reshape(unknown.shape)
        ia, ib = lin[a].ravel(), lin[b].ravel()
        use = (on_gel[a] & on_gel[b] & (unknown[a] | unknown[b])).ravel()
        ia, ib = ia[use], ib[use]
        g = 0.5 * (grad.ravel()[ia] + grad.ravel()[ib])
        ua, ub = index[ia], index[ib]
        eq = n_eq + np.arange(len(ia))
        # x_b - x_a = g ; a known endpoint moves to the right-hand side
        r = g.copy()
        r += np.where(ua < 0, flat_lr[ia], 0.0)
        r -= np.where(ub < 0, flat_lr[ib], 0.0)
        for sign, u_idx in ((-1.0, ua), (1.0, ub)):
            m = u_idx >= 0
            rows.append(eq[m])
            cols.append(u_idx[m])
            vals.append(np.full(int(m.sum()), sign))
        rhs.append(r)
        n_eq += len(ia)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), np.concatenate(rhs)
