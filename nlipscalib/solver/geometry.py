"""Geometry of a distorted camera for log-depth unknowns: ray tables, difference operators, normals.

With the exact unit ray omega of a pixel and q = omega / omega_z = (a, b, 1), a surface point is
x = z q. With log-depth t = log z, dx/du = z (t_u q + q_u), so the unnormalised normal

    N = -[(t_u q + q_u) x (t_v q + q_v)] = -[t_u (q x q_v) + t_v (q_u x q) + q_u x q_v]

is linear in the gradient of t (the minus sign makes it face the camera: N . x < 0). No pinhole
approximation is made: q, q_u, q_v come from the lens model's own per-pixel rays.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera, pixel_derivatives
from ..core.errors import ShapeError
from . import threads

if TYPE_CHECKING:  # in hints; used, it is imported in the function (solver/__init__.py says why)
    import scipy.sparse as sp


def ray_tables(camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-pixel q = omega / omega_z and its derivatives along u and v.

    Returns
    -------
    q, q_u, q_v : (H, W, 3) float64, camera frame; q has unit z, the derivatives are per pixel.
    """
    omega = camera.rays
    q = omega / omega[..., 2:3]
    q_u, q_v = pixel_derivatives(q)  # of the exact ray table: one unprojection only
    return q, q_u, q_v


def normal_basis(q: np.ndarray, q_u: np.ndarray, q_v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A, B, C with the camera-facing unnormalised normal N = -(t_u A + t_v B + C).

    Parameters
    ----------
    q, q_u, q_v : (..., 3) float64, from :func:`ray_tables`

    Returns
    -------
    A, B, C : (..., 3) float64
    """
    return _cross(q, q_v), _cross(q_u, q), _cross(q_u, q_v)


def masked_basis(
    q: np.ndarray, q_u: np.ndarray, q_v: np.ndarray, mask: np.ndarray
) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``q[mask]`` and :func:`normal_basis` of the tables on ``mask``'s pixels, the same bits.

    Why not the gathers and then :func:`normal_basis`: the tables' components are gathered as contiguous planes
    (flat indices; none where every pixel is kept) and the cross products written into their outputs' columns, so
    no gathered (N, 3) copy is read back by strided component views: 18 against 27 ms of one core at 336 x 332
    (benchmarks/RESULTS.md, s21-cpu).

    Parameters
    ----------
    q, q_u, q_v : (H, W, 3) float64, from :func:`ray_tables`
    mask : (H, W) bool

    Returns
    -------
    q : (N, 3) float64; A, B, C : (N, 3) float64 each -- N the mask's pixels, in row-major order.
    """
    index = None if mask.all() else np.flatnonzero(mask)

    def planes(table: np.ndarray) -> list[np.ndarray]:
        flat = table.reshape(-1, 3)
        return [flat[:, c] if index is None else flat[index, c] for c in range(3)]

    q_p, qu_p, qv_p = planes(q), planes(q_u), planes(q_v)
    basis = tuple(np.empty((len(q_p[0]), 3)) for _ in range(3))
    for (a, b), out in zip(((q_p, qv_p), (qu_p, q_p), (qu_p, qv_p)), basis):
        _cross_into(a, b, out)
    flat_q = q.reshape(-1, 3)
    return (flat_q if index is None else flat_q[index]), basis  # q is the caller's fresh table: a view will do


def _cross_into(a: Sequence[np.ndarray], b: Sequence[np.ndarray], out: np.ndarray) -> None:
    """``out[:] = np.cross(a, b)`` of vectors given as three (N,) component planes each, the same bits as
    :func:`_cross`; out (N, 3)."""
    a0, a1, a2 = a
    b0, b1, b2 = b
    np.subtract(a1 * b2, a2 * b1, out=out[:, 0])
    np.subtract(a2 * b0, a0 * b2, out=out[:, 1])
    np.subtract(a0 * b1, a1 * b0, out=out[:, 2])


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.cross(a, b)`` of (..., 3) arrays, the same bits (its products and differences, in its order), 5x
    faster on a 640x480 level's 307,200 pixels (4 against 25 ms: np.cross moves axes and writes strided)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def difference_operators(mask: np.ndarray, backward: bool = False) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray]:
    """Sparse one-sided first differences of a field defined on the pixels of ``mask``.

    Forward differences t[p+1] - t[p] (or backward t[p] - t[p-1] with ``backward=True``). Where the
    preferred neighbour is missing (mask edge) the second-order one-sided difference from the other
    side, (3 t[p] - 4 t[p-1] + t[p-2]) / 2, is used, or the first-order one if only one neighbour
    exists. One-sided differences couple every pixel to its neighbours (central ones would split the
    grid into four decoupled sub-lattices and leave checkerboard modes free); the solver uses both
    orientations so that their half-pixel biases cancel.

    Parameters
    ----------
    mask : (H, W) bool -- the unknowns, numbered in row-major order of ``mask``.
    backward : bool -- prefer the previous pixel instead of the next one.

    Returns
    -------
    Du, Dv : (N, N) scipy.sparse.csr_matrix, float64 -- d/du (columns) and d/dv (rows), per pixel.
    has_gradient : (N,) bool -- False where a pixel has no neighbour in u or in v (isolated).
    """
    import scipy.sparse as sp

    mask = np.asarray(mask)
    if mask.ndim != 2 or mask.dtype != bool:
        raise ShapeError(f"mask must be a 2-D bool array, got {mask.shape} {mask.dtype}")
    n = int(mask.sum())
    index = np.full(mask.shape, -1, dtype=np.int64)
    index[mask] = np.arange(n)
    padded = np.pad(index, 2, constant_values=-1)
    rr, cc = np.nonzero(mask)
    me = index[rr, cc]
    ops, ok = [], np.ones(n, dtype=bool)
    for axis in (1, 0):
        step = np.array([0, 1]) if axis == 1 else np.array([1, 0])
        s = -1 if backward else 1  # preferred direction

        def nb(k: int, s: int = s, step: np.ndarray = step) -> np.ndarray:
            return padded[rr + 2 + k * s * step[0], cc + 2 + k * s * step[1]]

        p1, m1, m2 = nb(1), nb(-1), nb(-2)
        rows, cols, vals = [], [], []
        pref = p1 >= 0
        second = ~pref & (m1 >= 0) & (m2 >= 0)
        first = ~pref & (m1 >= 0) & (m2 < 0)
        # preferred one-sided: s * (t[p + s] - t[p])
        for sel, terms in (
            (pref, ((me, -s), (p1, s))),
            (second, ((me, 1.5 * s), (m1, -2.0 * s), (m2, 0.5 * s))),
            (first, ((me, s), (m1, -s))),
        ):
            for col, val in terms:
                rows.append(me[sel])
                cols.append(col[sel])
                vals.append(np.full(int(sel.sum()), val, dtype=np.float64))
        ops.append(sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)))
        ok &= pref | second | first
    return ops[0], ops[1], ok


def gradient_operators(
    mask: np.ndarray,
    forward: tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray] | None = None,
    backward: tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray] | None = None,
) -> tuple[sp.csr_matrix, sp.csr_matrix, np.ndarray]:
    """Central differences (t[p+1] - t[p-1]) / 2 inside the mask, second-order one-sided at its edges.

    The mean of the forward- and backward-preferring operators of :func:`difference_operators`.

    Parameters
    ----------
    mask : (H, W) bool
    forward, backward : :func:`difference_operators` of ``mask`` (forward and backward), when the caller has
        them (None: computed here).

    Returns
    -------
    Du, Dv : (N, N) scipy.sparse.csr_matrix, float64, per pixel
    has_gradient : (N,) bool
    """
    import scipy.sparse as sp

    du_f, dv_f, ok = difference_operators(mask) if forward is None else forward
    du_b, dv_b, _ = difference_operators(mask, backward=True) if backward is None else backward
    out = []
    for axis, f, b in ((1, du_f, du_b), (0, dv_f, dv_b)):
        nxt = np.zeros_like(mask)
        prv = np.zeros_like(mask)
        if axis == 1:
            nxt[:, :-1], prv[:, 1:] = mask[:, 1:], mask[:, :-1]
        else:
            nxt[:-1], prv[1:] = mask[1:], mask[:-1]
        both = (nxt & prv)[mask].astype(np.float64)
        # rows with both neighbours: central; at an edge, the operator that fell back to the
        # second-order one-sided difference (forward-preferring at the far edge, and vice versa)
        wf = both / 2 + (~nxt[mask]).astype(np.float64)
        wb = both / 2 + (nxt[mask] & ~prv[mask]).astype(np.float64)
        out.append((sp.diags(wf) @ f + sp.diags(wb) @ b).tocsr())
    return out[0], out[1], ok


def normals_from_gradient(t_u: np.ndarray, t_v: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Unit normals facing the camera from the log-depth gradient.

    Parameters
    ----------
    t_u, t_v : (N,) float -- d(log z)/du, d(log z)/dv, per pixel
    A, B, C : (N, 3) float -- from :func:`normal_basis`

    Returns
    -------
    normals : (N, 3) float64, unit, camera frame
    """
    nvec = -(t_u[:, None] * A + t_v[:, None] * B + C)
    return nvec / np.linalg.norm(nvec, axis=1, keepdims=True)


class NormalMatrix:
    """Assembles H = sum_ab P_a^T diag(M_ab) P_b + sum_j E_j^T diag(w_j) E_j for per-pixel symmetric blocks M and
    each extra's weight w_j: a scalar, or one per row of E_j (the edge-preserving smoothness's IRLS weights).

    Two ways, the same matrix (to rounding):

    - **products** (default): H = G^T (K G) with G = [P_0; ...; E_0; ...] stacked once per level and K
      block-diagonal per pixel, whose CSR structure is fixed: two sparse products, no sums of sparse matrices
      (each of which costs as much as a product at this size).
    - **fixed pattern** (``fixed=True``): H's sparsity pattern is fixed, and its values are linear in M, so
      ``H.data = S m + sum_j w_j e_j`` with one sparse map S, built once. An assembly is then one sparse
      matrix-vector product: 0.04 s instead of 0.38-0.49 s at 307,200 pixels, for a build of 1.1-1.5 s. That
      pays where the level recurs: the large levels of the sensor's whole gel, whose operators are kept on disk
      for every later press of the sensor (:data:`nlipscalib.solver.operators.OPERATOR_PERSIST_PIXELS`).
    - **grid stencil** (``grid=mask``): the operators are stencils on the pixel grid of ``mask`` (each row a pixel,
      each entry a neighbour at a small offset), so every term of H lies on one of a few diagonals of the grid, and
      an assembly is a few dozen whole-grid products and shifted sums (:class:`_GridStencil`): 7 ms instead of
      29-31 ms on the cube press's 336x332 auto ROI (111,552 pixels), for a build of ~45 ms against the products'
      ~7.5, made at a level's first assembly or ahead on its operators' thread
      (:class:`nlipscalib.solver.operators._Assembler`). Exactly symmetric; the products' values to rounding
      (benchmarks/RESULTS.md, s34-cubef32).

    Parameters
    ----------
    ops : k sparse (N, N) operators P_a coupled by the blocks (here identity, D_u, D_v).
    extras : sparse (M_j, N) operators E_j weighted by scalars (here the second differences).
    fixed : build the fixed-pattern map (see above).
    grid : (H, W) bool or None -- the mask whose pixels, in row-major order, are the operators' rows and columns
        (every operator, extras too, then (N, N)): assemble by the grid's diagonals (see above). Not with ``fixed``.
    """

    def __init__(
        self,
        ops: Sequence[sp.spmatrix],
        extras: Sequence[sp.spmatrix] = (),
        fixed: bool = False,
        grid: np.ndarray | None = None,
    ):
        import scipy.sparse as sp

        n = ops[0].shape[1]
        self.n, self.k = n, len(ops)
        self.sizes = [E.shape[0] for E in extras]
        self.fixed = None
        self.stencil = None
        if fixed:
            self.fixed = _FixedPattern(ops, extras)
            return
        if grid is not None:
            self.stencil = _GridStencil(grid, ops, extras)
            return
        self.G = sp.vstack(list(ops) + list(extras)).tocsr()
        self.GT = self.G.T.tocsr()
        k = self.k
        # K's rows: k*n block rows with k entries each (pixel i couples to itself in every operator),
        # then one diagonal entry per row of each extra operator.
        block_cols = (np.arange(k)[None, None, :] * n + np.arange(n)[None, :, None]).repeat(k, axis=0).ravel()
        m_extra = sum(self.sizes)
        self._indices = np.concatenate([block_cols, k * n + np.arange(m_extra)]).astype(np.int32)
        self._indptr = np.concatenate([np.arange(0, k * k * n, k), k * k * n + np.arange(m_extra + 1)])
        self._indptr = self._indptr.astype(np.int32)
        self._shape = (k * n + m_extra, k * n + m_extra)

    def assemble(self, M: np.ndarray, weights: Sequence[float | np.ndarray] = ()) -> sp.csr_matrix:
        """H (N, N) CSR, float64, sorted indices, for blocks M (k, k, N) (symmetric in its first two axes)
        and the extras' weights (each a scalar or an (M_j,) array, one per row of E_j)."""
        import scipy.sparse as sp

        if self.fixed is not None:
            return self.fixed.assemble(M, weights)
        if self.stencil is not None:
            return self.stencil.assemble(M, weights)
        parts = [np.ascontiguousarray(M.transpose(0, 2, 1)).ravel()]  # K[a*n + i, b*n + i] = M[a, b, i]
        parts += [np.broadcast_to(np.asarray(w, np.float64), (m,)) for m, w in zip(self.sizes, weights)]
        K = sp.csr_matrix((np.concatenate(parts), self._indices, self._indptr), shape=self._shape)
        H = (self.GT @ (K @ self.G)).tocsr()
        H.sort_indices()
        return H


class _FixedPattern:
    """The fixed-pattern assembly of :class:`NormalMatrix`: H's pattern (the union of every term's) and the map S
    from the blocks M (k, k, N), raveled, and the extras' weights to H.data: each extra's E_j^T E_j is one more
    column of S (:func:`_with_extras`)."""

    def __init__(self, ops: Sequence[sp.spmatrix], extras: Sequence[sp.spmatrix]) -> None:
        import scipy.sparse as sp

        ops = [sp.csr_matrix(P) for P in ops]
        extras = [sp.csr_matrix(E) for E in extras]
        n, k = ops[0].shape[1], len(ops)
        self.shape = (n, n)
        pattern = _union_pattern(ops, extras)
        self.indices, self.indptr = pattern.indices, pattern.indptr
        where = sp.csr_matrix((np.arange(1, pattern.nnz + 1, dtype=np.float64), pattern.indices, pattern.indptr))
        padded = [_padded_rows(P) for P in ops]
        rows, cols, coef, counts = [], [], [], []
        for a in range(k):
            for b in range(k):
                (ca, va), (cb, vb) = padded[a], padded[b]
                ok = (ca[:, :, None] >= 0) & (cb[:, None, :] >= 0)  # (N, wa, wb): pixel i's pairs of entries
                rows.append(np.broadcast_to(ca[:, :, None], ok.shape)[ok])
                cols.append(np.broadcast_to(cb[:, None, :], ok.shape)[ok])
                coef.append((va[:, :, None] * vb[:, None, :])[ok])
                counts.append(ok.reshape(n, -1).sum(axis=1))
        # M.ravel()[(a * k + b) * n + i] = M[a, b, i]: the loop made S's columns in that order, each contiguous
        indptr = np.concatenate([[0], np.cumsum(np.concatenate(counts))])
        position = _positions(where, np.concatenate(rows), np.concatenate(cols))
        S = sp.csc_matrix((np.concatenate(coef), position, indptr), shape=(pattern.nnz, k * k * n)).tocsr()
        self.S = _with_extras(S, [(_positions(where, EtE.row, EtE.col), EtE.data) for EtE in _gram(extras)])
        self.n_extras = len(extras)
        self.sizes = [E.shape[0] for E in extras]
        self.R = sp.hstack([_row_gram_map(where, E) for E in extras], format="csr") if extras else None
        """The map from weights per row of the extras, concatenated, to H.data: used only where a weight is an
        array (the edge-preserving smoothness), so that scalar weights keep S's bits."""
        self._blocks: tuple | None = None
        """S's and R's row blocks (:meth:`_row_blocks`) with the thread count and row threshold they were cut for."""

    def __getstate__(self) -> dict:
        # the row blocks are views of S and R, cut for this process's threads: not stored (the disk cache)
        return {**self.__dict__, "_blocks": None}

    def _row_blocks(self, per_row: bool) -> tuple[list, list]:
        """S's row blocks (:class:`threads.RowBlocks`, or S whole) and, ``per_row``, R's in the same rows (else
        None per block), cut once per thread count, not at every assembly.

        Why: S has a row per entry of H (~4 M at 640x480), and cutting a block makes an empty CSR matrix of its
        rows (a zeroed row pointer) and the block's own row pointer: ~16 MB of fresh memory per block, on the main
        thread while the other core waited, twice per assembly with R (benchmarks/RESULTS.md, s42-speed). The
        blocks are views of S's and R's arrays, which nothing writes: the same products, the same bits."""
        key = (threads.workers(), threads.PRODUCT_MIN_ROWS)
        # read and replaced whole, never read back: two threads assembling at once at worst cut the blocks twice
        cut = getattr(self, "_blocks", None)  # (a map stored before it had them: none)
        if cut is None or cut[0] != key:
            cut = (key, threads.RowBlocks(self.S).blocks or [(slice(0, self.S.shape[0]), self.S)], None)
        if per_row and cut[2] is None:  # R's: cut at the first assembly with weights per row
            cut = (*cut[:2], threads.RowBlocks(self.R).blocks or [(slice(0, self.R.shape[0]), self.R)])
        self._blocks = cut
        return cut[1], cut[2] if per_row else [None] * len(cut[1])

    def assemble(self, M: np.ndarray, weights: Sequence[float | np.ndarray] = ()) -> sp.csr_matrix:
        # the extras' weights after the blocks (absent ones 0: not added); by row blocks on both cores, the same bits
        # as S @ x (threads.RowBlocks). Weights per row (any weight an array): S's extra columns get 0 and R's
        # product adds them all.
        import scipy.sparse as sp

        weights = list(weights[: self.n_extras])
        per_row = any(np.ndim(w) for w in weights)
        extra = np.zeros(self.n_extras)
        row_weights = None
        if per_row:
            weights += [0.0] * (self.n_extras - len(weights))
            row_weights = np.concatenate(
                [np.broadcast_to(np.asarray(w, np.float64), (m,)) for m, w in zip(self.sizes, weights)]
            )
        else:
            extra[: len(weights)] = weights
        blocks = np.ascontiguousarray(M, np.float64).reshape(-1)
        # Each row block's task makes its part of H: S's product (the bits of S @ x, threads.RowBlocks), the copy of
        # its column indices and the check for zeros; x (the blocks, then the weights) is copied by halves first.
        # On the main thread, x's concatenation, the 16 MB index copy and the check took ~10-15 ms of a 640x480
        # assembly while the other core waited.
        x = np.empty(blocks.size + self.n_extras)
        x[blocks.size :] = extra
        threads.map_items(lambda part: x.__setitem__(part, blocks[part]), threads.chunks(blocks.size))
        data, indices = np.empty(self.S.shape[0]), np.empty_like(self.indices)

        def rows(part: tuple[tuple[slice, sp.csr_matrix], tuple[slice, sp.csr_matrix] | None]) -> bool:
            (entries, S), by_row = part
            data[entries] = S @ x
            if by_row is not None:
                data[entries] += by_row[1] @ row_weights
            indices[entries] = self.indices[entries]
            return bool(data[entries].all())

        blocks, by_rows = self._row_blocks(per_row)  # R's rows in the same blocks as S's (the same row count)
        nonzero = threads.map_items(rows, list(zip(blocks, by_rows)))
        H = sp.csr_matrix(self.shape, dtype=np.float64)
        H.data, H.indices, H.indptr = data, indices, self.indptr.copy()
        H.has_sorted_indices = True
        if not all(nonzero):
            H.eliminate_zeros()  # as the products leave them out: the same pattern for AMG's set-up
        return H


STENCIL_DENSE_SHARE = 0.25
"""An operator's entries at one grid offset are held as a whole grid (:class:`_GridStencil`'s products over the grid)
where more than this share of the pixels have one, else as a list (the one-sided differences along the mask's edges,
the second differences' far ends): their few terms are added at their positions."""


class _GridStencil:
    """The grid-stencil assembly of :class:`NormalMatrix` (``grid=mask``).

    Each operator is split by the grid offset of its entries (row pixel p, column pixel p + o): a coefficient per
    pixel for each offset o. The blocks' term P_a^T diag(M_ab) P_b then puts M_ab[p] c_a,o1[p] c_b,o2[p] at (p + o1,
    p + o2), i.e. on H's diagonal d = o2 - o1 at row p + o1: H's upper diagonals (d >= 0) are sums of whole-grid
    products shifted by o1, held on a grid padded by twice the operators' reach so that no shift leaves it, and
    its lower ones their mirror (exactly symmetric). H's pattern (where a term lands) and where each of its entries
    lies among the diagonals are found once, at the build.

    Parameters
    ----------
    mask : (H, W) bool -- the operators' pixels, in row-major order.
    ops, extras : as :class:`NormalMatrix`'s; every one (N, N), N the mask's pixels.
    """

    def __init__(self, mask: np.ndarray, ops: Sequence[sp.spmatrix], extras: Sequence[sp.spmatrix]) -> None:
        import scipy.sparse as sp

        mats = [sp.csr_matrix(P) for P in (*ops, *extras)]
        ys, xs = (a.astype(np.int64) for a in np.nonzero(mask))
        n = len(ys)
        if any(P.shape != (n, n) for P in mats):
            raise ShapeError(f"a grid stencil needs (N, N) operators on the mask's {n} pixels")
        entries = []  # per operator: each entry's row pixel and its grid step (dy, dx) to the column's pixel
        for P in mats:
            rows = np.repeat(np.arange(n), np.diff(P.indptr))
            entries.append((rows, ys[P.indices] - ys[rows], xs[P.indices] - xs[rows]))
        reach = max([int(max(np.abs(dy).max(initial=0), np.abs(dx).max(initial=0))) for _, dy, dx in entries] + [0])
        pad = 2 * reach  # a term's row is p + o1, its column p + o2: within twice the reach of p
        width = mask.shape[1] + 2 * pad
        self.L = (mask.shape[0] + 2 * pad) * width
        self.margin = pad * (width + 1)
        self.n, self.pos = n, (ys + pad) * width + xs + pad
        self.shape = (n, n)
        offsets = [self._offsets(P, e, reach, width) for P, e in zip(mats, entries)]
        k = len(ops)
        self.pairs = [(a, b) for a in range(k) for b in range(a, k)] + [(k + j, k + j) for j in range(len(extras))]
        self.diags = sorted(
            {abs(o2 - o1) for a, b in self.pairs for o1, *_ in offsets[a] for o2, *_ in offsets[b] if a < b or o2 >= o1}
        )
        """H's upper diagonals, as flat grid offsets (0 first)."""
        touched = self._plan(offsets)
        self._pattern(touched)

    def _offsets(self, P: sp.csr_matrix, entries: tuple, reach: int, width: int) -> list[tuple]:
        """(flat grid offset, its coefficients on the grid, the grid positions of its entries where they are few,
        else None) of each offset of ``P``'s entries."""
        rows, dy, dx = entries
        side = 2 * reach + 1
        code = (dy + reach) * side + dx + reach
        counts = np.bincount(code, minlength=side * side)
        at = self.pos[rows]
        out = []
        for c in np.flatnonzero(counts):
            sel = np.flatnonzero(code == c)
            coef = np.zeros(self.L)
            coef[at[sel]] = P.data[sel]
            few = at[sel] if counts[c] <= STENCIL_DENSE_SHARE * self.n else None
            out.append(((c // side - reach) * width + c % side - reach, coef, few))
        return out

    def _plan(self, offsets: list[list[tuple]]) -> np.ndarray:
        """Each pair's terms: whole-grid ones in :attr:`dense` ((pair, o1's coefficients, [(o2's coefficients,
        shift, diagonal)])), the few in :attr:`few_target` / :attr:`few_weight` / :attr:`few_coef`; returns the
        (diagonals, L) bool grid of the upper diagonals' positions some term reaches."""
        L, lo = self.L, self.margin
        index = {d: j for j, d in enumerate(self.diags)}
        touched = np.zeros((len(self.diags), L), bool)
        self.dense: list[tuple] = []
        target, weight, coef = [], [], []
        for q, (a, b) in enumerate(self.pairs):
            for o1, c1, few1 in offsets[a]:
                inner = []
                for o2, c2, few2 in offsets[b]:
                    if a == b and o2 < o1:  # its mirror: the same term (o1, o2) below the diagonal
                        continue
                    twice = 2.0 if a != b and o1 == o2 else 1.0  # (a, b) and (b, a) on the diagonal alike
                    shift, j = min(o1, o2), index[abs(o2 - o1)]
                    if few1 is None and few2 is None:
                        inner.append((c2 * twice if twice != 1.0 else c2, shift, j))
                        touched[j, lo + shift : L - lo + shift] |= (c1[lo : L - lo] != 0) & (c2[lo : L - lo] != 0)
                        continue
                    at = few1 if few2 is None or (few1 is not None and len(few1) <= len(few2)) else few2
                    value = twice * c1[at] * c2[at]
                    at, value = at[value != 0], value[value != 0]
                    target.append(j * L + at + shift)
                    weight.append(q * L + at)
                    coef.append(value)
                    touched[j, at + shift] = True
                if inner:
                    self.dense.append((q, c1, inner))
        self.few_target = np.concatenate(target) if target else np.zeros(0, np.int64)
        self.few_weight = np.concatenate(weight) if weight else np.zeros(0, np.int64)
        self.few_coef = np.concatenate(coef) if coef else np.zeros(0)
        return touched

    def _pattern(self, touched: np.ndarray) -> None:
        """H's CSR pattern (sorted: the grid is row-major) and each entry's position among the upper diagonals
        (:attr:`gather`): entry (p, p + d) is there where a term reached its upper position, row p for d >= 0,
        row p + d for d < 0. Each diagonal's positions are read off the grid by a slice, then at the pixels by one
        take: no (N, diagonals) index arrays (a 640x480 level's would be ~80 MB each)."""
        L, lo = self.L, self.margin
        index = {d: j for j, d in enumerate(self.diags)}
        full = np.array(sorted({*self.diags, *(-d for d in self.diags)}), np.int64)
        upper = np.array([index[abs(d)] * L + min(d, 0) for d in full], np.int64)
        span = L - 2 * lo
        shifted = np.empty((len(full), span), bool)
        for s, d in enumerate(full):
            j = index[abs(d)]
            shifted[s] = touched[j, lo + min(d, 0) : lo + min(d, 0) + span]
        valid = np.ascontiguousarray(shifted.take(self.pos - lo, axis=1).T)  # (N, diagonals)
        pixel, slot = np.divmod(np.flatnonzero(valid), len(full))  # each entry's row and diagonal, in CSR order
        rows = self.pos[pixel]  # its row's pixel on the grid
        self.gather = rows + upper[slot]
        column = np.full(L, -1, np.int32)
        column[self.pos] = np.arange(self.n, dtype=np.int32)
        self.indices = column[rows + full[slot]]
        self.indptr = np.concatenate([[0], np.cumsum(np.count_nonzero(valid, axis=1))]).astype(np.int32)

    def assemble(self, M: np.ndarray, weights: Sequence[float | np.ndarray] = ()) -> sp.csr_matrix:
        """H (N, N) CSR, float64, sorted indices, for blocks M (k, k, N) and the extras' weights (each a scalar or
        one per pixel; not given: 0)."""
        import scipy.sparse as sp

        L = self.L
        k = M.shape[0]
        given = [M[a, b] for a in range(k) for b in range(a, k)] + list(weights)
        given += [0.0] * (len(self.pairs) - len(given))
        grid = np.zeros((len(self.pairs), L))
        for q, w in enumerate(given):
            grid[q, self.pos] = w
        upper = np.zeros((len(self.diags), L))
        product, term = np.empty(L), np.empty(L)
        for q, c1, inner in self.dense:
            np.multiply(grid[q], c1, out=product)
            for c2, shift, j in inner:
                np.multiply(product, c2, out=term)
                if shift >= 0:  # the term at pixel p belongs to row p + shift
                    upper[j, shift:] += term[: L - shift]
                else:
                    upper[j, :shift] += term[-shift:]
        if len(self.few_target):
            np.add.at(upper.reshape(-1), self.few_target, grid.reshape(-1)[self.few_weight] * self.few_coef)
        H = sp.csr_matrix(self.shape, dtype=np.float64)
        H.data, H.indices, H.indptr = upper.reshape(-1)[self.gather], self.indices.copy(), self.indptr.copy()
        H.has_sorted_indices = True
        if not H.data.all():
            H.eliminate_zeros()  # as the products leave them out: the same pattern for AMG's set-up
        return H


def _gram(extras: Sequence[sp.csr_matrix]) -> list[sp.coo_matrix]:
    """E_j^T E_j of each extra operator, COO."""
    return [(E.T @ E).tocoo() for E in extras]


def _row_gram_map(where: sp.csr_matrix, E: sp.csr_matrix) -> sp.csr_matrix:
    """(pattern nnz, M) CSR map from weights w (M,), one per row of E (M, N), to the data of E^T diag(w) E on the
    pattern (``where``: 1 + the index into the pattern's data of each entry): row j's pairs of entries (a, b) add
    w_j E_ja E_jb at (a, b)."""
    import scipy.sparse as sp

    cols, vals = _padded_rows(sp.csr_matrix(E))
    ok = (cols[:, :, None] >= 0) & (cols[:, None, :] >= 0)  # (M, w, w): row j's pairs of entries
    rows_h = np.broadcast_to(cols[:, :, None], ok.shape)[ok]
    cols_h = np.broadcast_to(cols[:, None, :], ok.shape)[ok]
    coef = (vals[:, :, None] * vals[:, None, :])[ok]
    indptr = np.concatenate([[0], np.cumsum(ok.reshape(len(cols), -1).sum(axis=1))])
    position = _positions(where, rows_h, cols_h)
    return sp.csc_matrix((coef, position, indptr), shape=(where.nnz, E.shape[0])).tocsr()


def _with_extras(S: sp.csr_matrix, extras: Sequence[tuple[np.ndarray, np.ndarray]]) -> sp.csr_matrix:
    """S with one column per extra, ``(positions, values)`` (unique positions into the pattern's data): the extra's
    values at its positions' rows, after each row's entries of S.

    Why: ``S @ [m, w_1, ...]`` then sums each row's blocks' terms, then adds w_1 v_1, then w_2 v_2, in that order, as
    the assembly's former ``data[position] += w_j * values`` after ``S @ m`` did, so H has the same bits; but as one
    product by row blocks on both cores, where those two scatters (1.5 M entries each at 640x480) took ~60 ms of one
    core per assembly (benchmarks/RESULTS.md, s19-b)."""
    import scipy.sparse as sp

    rows = S.shape[0]
    cols = [
        sp.csr_matrix((values, (positions, np.zeros(len(positions), np.int32))), shape=(rows, 1))
        for positions, values in extras
    ]
    out = sp.hstack([S, *cols], format="csr")
    return out


def _union_pattern(ops: Sequence[sp.spmatrix], extras: Sequence[sp.spmatrix]) -> sp.csr_matrix:
    """The sparsity pattern of sum_ab P_a^T P_b + sum_j E_j^T E_j (absolute values: nothing cancels), sorted."""
    absolute = [abs(P) for P in ops]
    total = sum(absolute)
    pattern = total.T @ total
    for E in extras:
        pattern = pattern + abs(E).T @ abs(E)
    pattern = pattern.tocsr()
    pattern.sort_indices()
    return pattern


def _padded_rows(P: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """(columns, values) of each row of P as (N, w) arrays, w its most entries per row; column -1 pads."""
    counts = np.diff(P.indptr)
    w = int(counts.max()) if counts.size else 0
    cols = np.full((P.shape[0], w), -1, np.int32)
    vals = np.zeros((P.shape[0], w))
    rows = np.repeat(np.arange(P.shape[0]), counts)
    slot = np.arange(P.nnz) - np.repeat(P.indptr[:-1], counts)
    cols[rows, slot], vals[rows, slot] = P.indices, P.data
    return cols, vals


def _positions(where: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Index into the pattern's data of the entries (rows, cols): ``where`` holds 1 + that index."""
    found = np.asarray(where[rows, cols]).ravel()
    return (found - 1).astype(np.int32)
