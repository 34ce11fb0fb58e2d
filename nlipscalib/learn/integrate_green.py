"""The inverse of a box's 5-point Laplacian (plus an anchor), which the rim box (:mod:`.integrate_rim`) is
built on: as a solve of the whole box (:func:`_box_solve`) and as the Green's function between pixels
(:func:`_box_green`), summed from the axes' modes.
"""

from __future__ import annotations

import numpy as np

from .integrate_box import _axis_eigenvalues, box_eigenvalues
from .integrate_regions import BOTH_SIDES, Edges


def _box_solve(f: np.ndarray, edges: Edges = (0, 0), anchor: float = 0.0) -> np.ndarray:
    """(m, n) float64: (L + anchor I)^-1 f, L the 5-point Laplacian of an (m, n) box
    (:func:`.integrate_box._axis_eigenvalues` per axis): fixed beyond both ends (DST-I), natural at both
    (:data:`.integrate_regions.BOTH_SIDES`: DCT-II; its zero eigenvalue needs the anchor where both axes are), or at the
    image border only (-1, +1: the DST-I of the array mirrored across it, as :func:`.integrate_box._solve_box`'s edge
    box)."""
    from scipy.fft import dct, dst, dstn, idct

    if edges == (0, 0):  # the plain rim box: one call per direction
        return dstn(dstn(f, type=1, norm="ortho") / (box_eigenvalues(*f.shape) + anchor), type=1, norm="ortho")
    shape = f.shape
    for axis, edge in enumerate(edges):
        if edge in (-1, 1):
            f = np.concatenate((np.flip(f, axis), f) if edge < 0 else (f, np.flip(f, axis)), axis)
    neumann = (edges[0] == BOTH_SIDES, edges[1] == BOTH_SIDES)
    lam = box_eigenvalues(*f.shape, neumann=neumann) + anchor
    for axis in (0, 1):
        f = dct(f, type=2, norm="ortho", axis=axis) if neumann[axis] else dst(f, type=1, norm="ortho", axis=axis)
    f = f / lam
    for axis in (0, 1):
        f = idct(f, type=2, norm="ortho", axis=axis) if neumann[axis] else dst(f, type=1, norm="ortho", axis=axis)
    return f[tuple(slice(-k, None) if edge == -1 else slice(0, k) for k, edge in zip(shape, edges))]


def _axis_modes(index: np.ndarray, n: int, edge: int = 0) -> np.ndarray:
    """(len(index), n) float64: the orthonormal eigenvectors of the 1-D Laplacian of
    :func:`.integrate_box._axis_eigenvalues` at the points ``index`` -- type-I sines (rows of
    ``scipy.fft.dst(eye(n), type=1, norm="ortho")``), type-II cosines (:data:`.integrate_regions.BOTH_SIDES`), or the
    doubled path's odd sines on the box's half of it (-1: its second half, +1: its first; sqrt(2) for the
    half's norm)."""
    i = np.asarray(index, float)
    if edge == BOTH_SIDES:
        scale = np.where(np.arange(n) == 0, np.sqrt(1.0 / n), np.sqrt(2.0 / n))
        return scale * np.cos(np.pi * np.outer(i + 0.5, np.arange(n)) / n)
    if edge:
        at = i + 1 + (n if edge < 0 else 0)  # 1-based place on the doubled path
        return 2 / np.sqrt(2 * n + 1) * np.sin(np.pi * np.outer(at, np.arange(1, 2 * n, 2)) / (2 * n + 1))
    return np.sqrt(2.0 / (n + 1)) * np.sin(np.pi * np.outer(i + 1, np.arange(1, n + 1)) / (n + 1))


def _green_cost(pr: np.ndarray, pc: np.ndarray, qr: np.ndarray, qc: np.ndarray, m: int, n: int) -> int:
    """Values :func:`_box_green` holds at once in its largest array, summing over the cheaper axis's modes."""
    return min(_green_rows_cost(pr, pc, qr, m, n), _green_rows_cost(pc, pr, qc, n, m))


def _box_green(
    pr: np.ndarray,
    pc: np.ndarray,
    qr: np.ndarray,
    qc: np.ndarray,
    m: int,
    n: int,
    edges: Edges = (0, 0),
    anchor: float = 0.0,
) -> np.ndarray:
    """(P, Q) float64: the (m, n) box's Green's function G(p, q), the inverse of its 5-point Laplacian plus
    ``anchor`` on the diagonal (:func:`_box_solve`; ``edges`` its natural sides), between interior pixels
    p = (pr, pc) and q = (qr, qc).

    G(p, q) = sum_k sum_l S_k(pr) S_k(qr) T_l(pc) T_l(qc) / (mu_k + nu_l + anchor), S and T the modes of the two
    axes (:func:`_axis_modes`). The inner sum, per row mode k, is a 1-D Green's function along the columns, needed
    only between the distinct columns of p and of q; the outer sum is then one matrix product per distinct column
    of p. The axes are swapped where that is cheaper (a rim along the rows, few distinct rows)."""
    if _green_rows_cost(pr, pc, qr, m, n) > _green_rows_cost(pc, pr, qc, n, m):
        return _box_green(pc, pr, qc, qr, n, m, (edges[1], edges[0]), anchor)
    columns_p, at_p = np.unique(pc, return_inverse=True)
    columns_q, at_q = np.unique(qc, return_inverse=True)
    eigenvalues = _axis_eigenvalues(m, edges[0])[:, None] + _axis_eigenvalues(n, edges[1])[None, :]
    inverse = 1.0 / (eigenvalues + anchor)  # (m, n)
    modes_p, modes_q = _axis_modes(columns_p, n, edges[1]), _axis_modes(columns_q, n, edges[1])
    along = np.matmul(modes_p[None] * inverse[:, None, :], modes_q.T)  # (m, distinct columns of p, of q)
    # (distinct columns of p, m, Q): contiguous per column of p, gathered by take (half the time of along[..., at_q])
    weighted = np.take(along.transpose(1, 0, 2), at_q, axis=2)
    weighted *= _axis_modes(qr, m, edges[0]).T
    green = np.empty((len(pr), len(qr)))
    order = np.argsort(at_p, kind="stable")
    starts = np.searchsorted(at_p[order], np.arange(len(columns_p) + 1))
    for a in range(len(columns_p)):
        rows = order[starts[a] : starts[a + 1]]
        green[rows] = _axis_modes(pr[rows], m, edges[0]) @ weighted[a]
    return green


def _green_rows_cost(pr: np.ndarray, pc: np.ndarray, qr: np.ndarray, m: int, n: int) -> int:
    """:func:`_green_cost` summing over the row modes: (m, distinct columns of p, n or Q) values."""
    return m * len(np.unique(pc)) * max(n, len(qr))
