"""The rim box (:mod:`.integrate`'s docstring): a box holding off-gel pixels, its gel pixels solved by the
capacitance-matrix method (Buzbee, Dorr, George & Golub 1971), where it applies and with which anchor.
Its right-hand side, capacitance and solve are shared with the torch path.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from .integrate_box import _where, box_rhs
from .integrate_geometry import Array, RayGeometry
from .integrate_green import _box_green, _box_solve, _green_cost
from .integrate_regions import BOTH_SIDES, Box, Edges, _faster, _interior
from .integrate_sparse import ANCHOR_WEIGHT

MAX_RIM_GREEN_VALUES = 1 << 22
"""Most values of the box's Green's function that one rim box may sum (:func:`.integrate_green._box_green`: the modes of
one axis times the rim's points and columns; 32 MiB of float64 each of its two largest arrays). A region beyond it (a
rim box thousands of rim pixels long, such as the flat pad's whole gel) keeps the sparse path."""


def _interior_mask(on_gel: np.ndarray, edges: Edges = (0, 0)) -> np.ndarray:
    """(h, w) bool: a rim box's solved pixels -- the gel pixels of its interior (all but the ring, which its sides
    at the image border, ``edges``, lack)."""
    solved = np.zeros_like(on_gel)
    interior = tuple(_interior(edge) for edge in edges)
    solved[interior] = on_gel[interior]
    return solved


def _rim_box_applies(unknown: np.ndarray, on_gel: np.ndarray, crop: Box, edges: Edges = (0, 0)) -> bool:
    """Whether the region group in ``crop`` is solved as a rim box (:func:`_rim_box_anchor`)."""
    return _rim_box_anchor(unknown, on_gel, crop, edges) is not None


def _rim_box_anchor(unknown: np.ndarray, on_gel: np.ndarray, crop: Box, edges: Edges = (0, 0)) -> float | None:
    """The anchor weight of the rim box of the region group in ``crop`` (its bounds grown by the ring,
    :func:`.integrate_regions._regions`; ``edges`` its sides at the image border,
    :func:`.integrate_regions._crop_edges`), or None where the sparse path must solve it.

    It applies where its ring (the sides off the image border) holds no changed pixel, its rim is small enough
    (:data:`MAX_RIM_GREEN_VALUES`), and either every connected part of the interior's gel touches a gel pixel of
    the ring (which fixes its level: anchor 0), or none does and every one of its pixels is a changed pixel (the
    sparse path then anchors every unknown, the same equation: :data:`.integrate_sparse.ANCHOR_WEIGHT`; e.g. a frame
    changed on the whole gel). A mix, or an unchanged pixel in a box without a fixed pixel, keeps the sparse path:
    anchoring pixels that the sparse path holds at the reference would be another equation."""
    from scipy import ndimage

    changed, gel = unknown[crop], on_gel[crop]
    interior = tuple(_interior(edge) for edge in edges)
    if min(gel[interior].shape) < 1:
        return None
    solved = _interior_mask(gel, edges)
    if (changed & ~solved).any():  # a changed pixel on the ring
        return None
    labels, count = ndimage.label(solved)
    held = ndimage.binary_dilation(gel & ~solved) & solved  # solved pixels next to a gel pixel of the ring
    touching = len(np.unique(labels[held]))
    if touching == count:
        anchor = 0.0
    elif touching == 0 and not (solved & ~changed).any():
        anchor = ANCHOR_WEIGHT
    else:
        return None
    rim = _rim_rows(_beyond_border(gel, edges, True))[1]
    cost = _green_cost(*np.nonzero(rim), *np.nonzero(rim), *rim.shape)
    return anchor if cost <= MAX_RIM_GREEN_VALUES else None


def _faster_rim_box(
    unknown: np.ndarray,
    on_gel: np.ndarray,
    crop: Box,
    others: Sequence[Box],
    edges: Edges = (0, 0),
    anchor: float = 0.0,
) -> Box:
    """A rim box (``edges`` its sides at the image border) grown to FFT-friendly sides
    (:func:`.integrate_regions._faster`) within the image, clear of the boxes solved apart (``others``), where it still
    applies with the same ``anchor`` (:func:`_rim_box_anchor`); else ``crop``. Its sine solves are most of its time: the
    ridge across the flat pad's box, 148 x 536 inside its ring, has the prime factors 149 and 179 in its transform
    lengths."""
    rect = (crop[0].start, crop[0].stop, crop[1].start, crop[1].stop)
    bounds = [(b[0].start, b[0].stop, b[1].start, b[1].stop) for b in others]
    grown = _faster(rect, np.ones_like(on_gel), bounds, edges)
    return grown if grown != crop and _rim_box_anchor(unknown, on_gel, grown, edges) == anchor else crop


def _beyond_border(a: np.ndarray, edges: Edges, value: object) -> np.ndarray:
    """``a`` ((h, w, ...) over a box) with one line of ``value`` joined beyond each of its sides at the image
    border (``edges``), in the place of the ring those sides lack."""
    pad = [(int(edge in (-1, BOTH_SIDES)), int(edge in (1, BOTH_SIDES))) for edge in edges]
    return np.pad(a, pad + [(0, 0)] * (a.ndim - 2), constant_values=value)


def _rim_rows(on_gel: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Off-gel neighbours of a rim box's interior pixels, per side (up, down, left, right: (m, n) bool each), and
    the rim: (m, n) bool, the interior's gel pixels with at least one off-gel neighbour."""
    off = ~on_gel
    sides = [off[:-2, 1:-1], off[2:, 1:-1], off[1:-1, :-2], off[1:-1, 2:]]
    return sides, on_gel[1:-1, 1:-1] & (sides[0] | sides[1] | sides[2] | sides[3])


def _solve_rim_box(
    normals: np.ndarray, geo: RayGeometry, on_gel: np.ndarray, box: Box, edges: Edges = (0, 0), anchor: float = 0.0
) -> np.ndarray:
    """(h, w) float64 log-range over a rim box (:mod:`.integrate`'s docstring): its interior's gel pixels solved, the
    rest the reference (NaN off the gel); the sparse path's equation with those pixels unknown, up to rounding.

    The box's Laplacian L (DST-I; on ``edges`` sides at the image border a natural side,
    :func:`.integrate_green._box_solve`), plus ``anchor`` on its diagonal, becomes the rim box's matrix M = L + U V^T:
    the rows of the rim pixels (U: their unit columns) lose their off-gel neighbours (V^T: minus their count on the
    diagonal, plus one at each off-gel interior neighbour, whose own rows stay L's: M is block triangular, its gel block
    the sparse path's). Woodbury: M x = f is x = L^-1 (f - U s) with the capacitance system (I + V^T L^-1 U) s = V^T
    L^-1 f, L^-1's entries at the rim and its neighbours from :func:`.integrate_green._box_green`
    (:func:`rim_box_capacitance`; :func:`rim_box_rhs` and :func:`rim_box_solve` are shared with the torch path).
    """
    from scipy.linalg import lu_factor, lu_solve

    from ..core.blas import blas_threads

    gel = on_gel[box]
    x = np.where(gel, geo.log_range[box], 0.0)
    # beyond a side at the image border, a line with no pixel pair (off the gel for box_rhs) and nothing known
    arrays = [_beyond_border(a, edges, 0.0) for a in (normals[box], geo.rays[box], geo.d_u[box], geo.d_v[box], x)]
    f = rim_box_rhs(*arrays, _beyond_border(gel, edges, False))
    solved = _interior_mask(gel, edges)[tuple(_interior(edge) for edge in edges)]
    f[solved] += anchor * arrays[-1][1:-1, 1:-1][solved]
    rim, points, v_t, capacitance = rim_box_capacitance(gel, edges, anchor)
    with blas_threads(1):  # a small dense factorisation: a second BLAS thread only waits on a shared machine
        factor = lu_factor(capacitance) if len(rim) else None
    y = rim_box_solve(f, lambda rhs: _box_solve(rhs, edges, anchor), rim, points, v_t, lambda b: lu_solve(factor, b))
    out = np.where(gel, geo.log_range[box], np.nan)
    out[tuple(_interior(edge) for edge in edges)][solved] = y[solved]
    return out


def rim_box_rhs(normals: Array, rays: Array, d_u: Array, d_v: Array, x: Array, gel: Array) -> Array:
    """Right-hand side of a rim box's solve (:func:`_solve_rim_box`); numpy or torch (shared with
    :mod:`.integrate_torch`).

    Parameters
    ----------
    normals, rays, d_u, d_v : (h, w, 3) over the box (the normals unit, toward the camera, where ``gel``)
    x : (h, w) -- the reference log-range over the box, 0 off the gel
    gel : (h, w) bool -- the box's gel pixels

    Returns
    -------
    (h - 2, w - 2): :func:`.integrate_box.box_rhs` with no pair across the gel's outline, 0 in an off-gel pixel's row
    (L's own, decoupled from the gel's)
    """
    facing = _where(gel[..., None], normals, -rays)  # any finite normal off the gel: no pair uses it
    f = box_rhs(facing, rays, d_u, d_v, x, gel)
    return _where(gel[1:-1, 1:-1], f, 0 * f)


def rim_box_capacitance(
    gel: np.ndarray, edges: Edges = (0, 0), anchor: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The low-rank change of a rim box's Laplacian (:func:`_solve_rim_box`), from its gel pixels alone.

    Parameters
    ----------
    gel : (h, w) bool -- the box's gel pixels
    edges : its sides at the image border (no rim there: the box's Laplacian has that side,
        :func:`.integrate_green._box_solve`)
    anchor : added to the Laplacian's diagonal (:func:`_rim_box_anchor`)

    Returns
    -------
    rim : (r,) int64 -- flat indices (in the (h - 2, w - 2) interior) of the rim pixels
    points : (P,) int64 -- flat interior indices where V^T has entries (the rim and its off-gel neighbours)
    v_t : (r, P) float64 -- V^T on ``points``
    capacitance : (r, r) float64 -- I + V^T L^-1 U
    """
    from ..core.blas import blas_threads

    sides, rim_mask = _rim_rows(_beyond_border(gel, edges, True))  # the image border is no rim: L has it
    m, n = rim_mask.shape
    rim = np.flatnonzero(rim_mask)
    rr, rc = np.divmod(rim, n)
    # V^T's entries: (rim row, interior pixel, value); the rim pixel itself, then its off-gel neighbours
    rows, pixels, values = [np.arange(len(rim))], [rim], [-sum(side.ravel()[rim] for side in sides).astype(float)]
    for (dr, dc), side in zip(((-1, 0), (1, 0), (0, -1), (0, 1)), sides):
        nr, nc = rr + dr, rc + dc
        inside = side.ravel()[rim] & (nr >= 0) & (nr < m) & (nc >= 0) & (nc < n)
        rows.append(np.flatnonzero(inside))
        pixels.append(nr[inside] * n + nc[inside])
        values.append(np.ones(int(inside.sum())))
    points, column = np.unique(np.concatenate(pixels), return_inverse=True)
    v_t = np.zeros((len(rim), len(points)))
    np.add.at(v_t, (np.concatenate(rows), column), np.concatenate(values))
    if not len(rim):
        return rim, points, v_t, np.eye(0)
    with blas_threads(1):  # small dense products: a second BLAS thread only waits on a shared machine
        green = _box_green(*np.divmod(points, n), rr, rc, m, n, edges, anchor)
        capacitance = np.eye(len(rim)) + v_t @ green
    return rim, points, v_t, capacitance


def rim_box_solve(
    f: Array,
    solve: Callable[[Array], Array],
    rim: Array,
    points: Array,
    v_t: Array,
    solve_capacitance: Callable[[Array], Array],
) -> Array:
    """(m, n) solution of a rim box's equation M y = f (:func:`_solve_rim_box`) by two box solves and one
    capacitance solve; numpy or torch.

    Parameters
    ----------
    f : (m, n) -- :func:`rim_box_rhs` (changed in place)
    solve : the box's solve, L^-1 of an (m, n) array (:func:`.integrate_green._box_solve`, or the torch path's)
    rim, points, v_t : of :func:`rim_box_capacitance` (as arrays of ``f``'s kind)
    solve_capacitance : s with (I + V^T L^-1 U) s = b, of a (r,) b
    """
    y = solve(f)
    if len(rim):
        s = solve_capacitance(v_t @ y.reshape(-1)[points])
        f.reshape(-1)[rim] -= s  # a view of f: contiguous (box_rhs's arithmetic made it)
        y = solve(f)
    return y
