"""Inexact Newton linear solves: preconditioned conjugate gradient (Jacobi, then pyamg AMG) and the forcing term."""

from __future__ import annotations

import contextlib
import threading
import weakref
from typing import TYPE_CHECKING

import numpy as np

from . import threads
from .options import SolverOptions

if TYPE_CHECKING:  # in hints; used, they are imported in the functions (solver/__init__.py says why)
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla


def forcing(g_norm: float, g_prev: float | None, eta_prev: float | None, opts: SolverOptions) -> float:
    """CG tolerance of an inexact Newton step (Eisenstat and Walker 1996, choice 2, safeguarded).

    eta = 0.9 (|g_k| / |g_k-1|)^2: solve the linear system only as accurately as the outer iteration
    is converging -- tighter is wasted work, since the Gauss-Newton model itself is approximate.
    """
    if g_prev is None or eta_prev is None:
        return opts.cg_rtol_max
    eta = 0.9 * (g_norm / max(g_prev, 1e-300)) ** 2
    if 0.9 * eta_prev**2 > 0.1:  # do not let the tolerance drop abruptly
        eta = max(eta, 0.9 * eta_prev**2)
    return float(min(opts.cg_rtol_max, max(opts.cg_rtol, eta)))


WARM_FIRST_RTOL = 1e-2
"""CG tolerance of the first Gauss-Newton step of a warm-started finest level (:func:`warm_first_step`), instead of the
forcing term's cap ``cg_rtol_max`` (0.1), solved with AMG from the start (no Jacobi attempt: Jacobi's CG stalls near
0.1 on these levels, benchmarks/RESULTS.md, s20-jac1).

Why: the forcing term starts loose because a first step is taken far from the solution, where the Gauss-Newton model
is itself poor. The outer loop's last pass starts its finest level from the coarser level's solution brought up,
close to its own: there a loose first step only takes the rough part of the Newton step and leaves the rest to a whole
later Gauss-Newton step (blocks, assembly, linear solve, line search). On the default twin's 640x480 auto ROIs the
last pass took 3 -> 2 steps on cube1 and sphere1, 5 -> 4 on coin1 (benchmarks/RESULTS.md, s30-lastpass). 0.03 left
cube1 at 3 steps."""


DRIFT_RATE = 0.85
"""A hierarchy whose CG residual fell by less than this per iteration (over 4 or more) has drifted from the matrix
(:meth:`Krylov._drifted`)."""

WARM_FIRST_MAX_ROWS = 200_000
"""Levels with at least this many rows (a whole 640x480 frame's finest, 307,200) keep the forcing term's first step
(:func:`warm_first_step`): there the tighter first step moved coin1's whole-frame contact AAE by +0.025 deg (4.710 ->
4.735; sphere1 -0.004, cube1 unchanged) and the relief presses' by a few hundredths before (s20-jac's ``tight1``), and
the whole frame meets its time goal without it (benchmarks/RESULTS.md, s30-lastpass)."""


def warm_first_step(rows: int, opts: SolverOptions) -> float | None:
    """The CG tolerance of a warm-started finest level's first Gauss-Newton step (:data:`WARM_FIRST_RTOL`, not below
    ``opts.cg_rtol``), solved by AMG alone; None where the level keeps the forcing term's (:data:`WARM_FIRST_MAX_ROWS`
    rows or more)."""
    if rows >= WARM_FIRST_MAX_ROWS:
        return None
    return max(WARM_FIRST_RTOL, opts.cg_rtol)


class Krylov:
    """Preconditioned conjugate gradient for the Gauss-Newton systems of one pyramid level.

    Jacobi-preconditioned CG is tried first, capped at ``opts.cg_jacobi_iters``: the first steps of a
    warm-started level are loose (inexact Newton) and converge in a few cheap iterations, where a
    smoothed-aggregation AMG hierarchy would cost more to build than the whole solve. Otherwise
    (or once a hierarchy exists) CG preconditioned by AMG V-cycles continues from that iterate. The
    matrix changes little between iterations (weights and shading drift), so the hierarchy is kept
    until its convergence factor per CG iteration degrades past :data:`DRIFT_RATE`. A hierarchy is fitted to a
    later matrix (:meth:`_VCycle.for_matrix`: its aggregates and transfers kept, its level matrices made again
    by Galerkin products, about a third of a set-up) in two cases: one made in the level's first solve (where
    Jacobi failed), at the second solve, because the first Gauss-Newton step moves the most; and one that drifted,
    at the next solve, once per set-up (made again if it drifts after that): what drifts is the level matrices'
    values, not the aggregates (coin1's whole frame: the fitted hierarchy took the last two steps in the same 4 and
    7 iterations as a set-up of its own; benchmarks/RESULTS.md, s40-relief).

    Jacobi is not tried where the level's last Jacobi solve predicts it would not reach the tolerance within
    its cap (:func:`jacobi_predicted`): on the warm-started 640x480 level of a whole frame's last outer pass,
    the second step's 30 Jacobi iterations (~0.15 s of CPU) left the residual where AMG alone takes it in the
    same 9 iterations from zero (benchmarks/RESULTS.md, s17-b). And a Jacobi solve that was tried is abandoned
    once its residual lies far above the prediction's (:func:`jacobi_give_up_rate`); AMG continues from its iterate.
    A level of :data:`JACOBI_ONCE_ROWS` rows or more (a whole frame's finest) tries Jacobi in its first solve only.
    A warm-started finest level's first solve (the outer loop's last pass) is tighter and by AMG alone
    (:func:`warm_first_step`).
    """

    def __init__(self, opts: SolverOptions):
        self.opts = opts
        self.amg: _VCycle | None = None
        """The level's AMG cycle, None until the first AMG-preconditioned solve or after a drift."""
        self._amg_matrix = None
        """A weak reference to the matrix :attr:`amg`'s level matrices were made for."""
        self._amg_solve = 0
        """The solve (1: the level's first) whose matrix :attr:`amg`'s level matrices were made for."""
        self.solves = 0
        self.setups = 0
        self.refreshes = 0
        """Hierarchies fitted to a later solve's matrix (:meth:`_VCycle.for_matrix`), set-ups not counted."""
        self._fit_next = False
        """The hierarchy drifted in the last solve: fitted to the next solve's matrix."""
        self._drift_fitted = False
        """The hierarchy was fitted after a drift since its set-up: made again if it drifts once more."""
        self.jacobi_rate: float | None = None
        """Residual reduction per iteration of this level's last Jacobi solve, bounded above (1: it failed)."""

    def solve(self, Hm: sp.csr_matrix, rhs: np.ndarray, rtol: float, jacobi: bool = True) -> tuple[np.ndarray, int]:
        """Approximate solution of Hm x = rhs to ``|r| <= rtol |rhs|``; returns x and CG iterations. ``jacobi``: False:
        AMG from the start (:func:`warm_first_step`)."""
        self.solves += 1
        x = None
        # the system's products on both cores; the same bits as Hm @ v (threads.RowBlocks)
        products = threads.RowBlocks(Hm)
        # Jacobi only for loose solves: below 1e-2 it needed more iterations than it is worth.
        cap = self.opts.cg_jacobi_iters
        jacobi_iters = 0
        predicted = jacobi_predicted(self.jacobi_rate, rtol)
        # a large level's Jacobi attempts after its first failed at their cap (JACOBI_ONCE_ROWS)
        once = Hm.shape[0] >= JACOBI_ONCE_ROWS and self.solves > 1
        if jacobi and self.amg is None and cap > 0 and rtol >= 1e-2 and predicted <= cap and not once:
            give_up = jacobi_give_up_rate(predicted, rtol)
            x, status, jacobi_iters = pcg(products, rhs, None, rtol, cap, _Jacobi(Hm), give_up)
            # converged: rtol^(1/iterations) bounds its rate from above (the residual reached rtol or less)
            self.jacobi_rate = rtol ** (1 / max(jacobi_iters, 1)) if status == 0 else 1.0
            if status == 0:
                return x, jacobi_iters
        if self.amg is None:
            self.amg = _amg_cycle(Hm)
            self.setups += 1
            self._amg_matrix, self._amg_solve = weakref.ref(Hm), self.solves
            self._drift_fitted = False
        elif (self._amg_solve == 1 or self._fit_next) and self._amg_matrix() is not Hm:
            # The first step's matrix is the furthest from the later ones (its step moves the depth, the weights
            # and the shading the most): on cube1's whole frame its hierarchy took steps 2 and 3 in 21 and 22 CG
            # iterations, fitted to step 2's matrix 11 and 14 (a set-up of its own at each step: 12 and 11), for
            # 0.08 s of CPU against a set-up's 0.2. A later step's hierarchy is a step closer: fitting it too saved
            # 0-3 iterations (sphere1, coin1, cube1's step 3), about what it costs (benchmarks/RESULTS.md, s20-amg).
            self.amg = self.amg.for_matrix(_single(Hm))
            self.refreshes += 1
            self._drift_fitted |= self._fit_next
            self._fit_next = False
            self._amg_matrix, self._amg_solve = weakref.ref(Hm), self.solves
        x, _, amg_iters = pcg(products, rhs, x, rtol, self.opts.cg_maxiter, self.amg)
        iters = max(amg_iters, 1)
        achieved = float(np.linalg.norm(rhs - products.dot(x))) / max(float(np.linalg.norm(rhs)), 1e-300)
        if iters >= 4 and min(max(achieved, 1e-16) ** (1 / iters), 1.0) > DRIFT_RATE:
            self._drifted()
        return x, jacobi_iters + amg_iters

    def _drifted(self) -> None:
        """The matrix drifted away from the one the hierarchy's level matrices were made for: fitted to the next
        solve's matrix, or made again there where it was fitted after a drift already."""
        if self._drift_fitted:
            self.amg = None
        else:
            self._fit_next = True


def pcg(
    system: threads.RowBlocks,
    b: np.ndarray,
    x0: np.ndarray | None,
    rtol: float,
    maxiter: int,
    preconditioner: _Jacobi | _VCycle,
    give_up_rate: float | None = None,
) -> tuple[np.ndarray, int, int]:
    """Preconditioned conjugate gradient for ``A x = b`` until ``|r| < rtol |b|``: SciPy's ``cg``, operation for
    operation (the same bits), with its vector work moved into the row-block tasks of the products.

    SciPy's loop runs its vector updates (``x += alpha p``, ``r -= alpha q``, the preconditioner's own elementwise
    work and conversions) on the calling thread, one pass over memory each, while the second core waits for the next
    product: on a 640x480 level ~3 ms of a ~17 ms iteration. Here each row block's share of them runs on the pool
    with that block's product (or in one extra hand-off per iteration: the updates of x and r with the
    preconditioner's first step); the dot products stay whole (their summation order is BLAS's).

    Parameters
    ----------
    system : :class:`threads.RowBlocks` of A -- (n, n) CSR, float64, symmetric positive definite.
    b : (n,) float64 -- the right-hand side.
    x0 : (n,) float64 or None (zero) -- the start, not written.
    rtol : relative residual to reach; maxiter : iterations at most.
    preconditioner : :class:`_Jacobi` or :class:`_VCycle` (its :meth:`_VCycle.begin` / :meth:`_VCycle.finish`).
    give_up_rate : stop (as failed) after iteration k where ``|r_k| > give_up_rate^k |b|``; None: never. The norm is
        the one the convergence test takes anyway: a solve that converges before it is met has the same bits.

    Returns
    -------
    x : (n,) float64; status : 0 converged, else the iterations made (``maxiter`` where not given up);
    iterations : completed iterations (SciPy's callbacks).
    """
    n = b.shape[0]
    bnrm2 = np.linalg.norm(b)
    atol = max(0.0, float(rtol) * float(bnrm2))
    if bnrm2 == 0:
        return b.copy(), 0, 0
    x = np.zeros(n) if x0 is None else np.array(x0, dtype=np.float64)
    blocks = system.blocks or [(slice(0, n), system.A)]
    r, q, scratch = np.empty(n), np.empty(n), np.empty(n)
    start = x.any()

    def first(part: tuple[slice, sp.csr_matrix]) -> None:
        rows, A = part
        if start:
            np.subtract(b[rows], A @ x, out=r[rows])
        else:
            r[rows] = b[rows]
        preconditioner.begin(r, rows)

    threads.map_items(first, blocks)
    p = rho_prev = alpha = None

    def product(part: tuple[slice, sp.csr_matrix]) -> None:
        rows, A = part
        q[rows] = A @ p

    def update(rows: slice) -> None:
        np.multiply(alpha, p[rows], out=scratch[rows])
        x[rows] += scratch[rows]
        np.multiply(alpha, q[rows], out=scratch[rows])
        r[rows] -= scratch[rows]
        preconditioner.begin(r, rows)

    for iteration in range(maxiter):
        residual = np.linalg.norm(r)
        if residual < atol:
            return x, 0, iteration
        if give_up_rate is not None and iteration > 0 and residual > give_up_rate**iteration * bnrm2:
            return x, iteration, iteration
        z = preconditioner.finish(r)
        rho_cur = np.dot(r, z)
        if iteration > 0:
            beta = rho_cur / rho_prev
            p *= beta
            p += z
        else:
            p = np.empty_like(r)
            p[:] = z
        threads.map_items(product, blocks)
        alpha = rho_cur / np.dot(p, q)
        threads.map_items(update, [rows for rows, _ in blocks])
        rho_prev = rho_cur
    return x, maxiter, maxiter


class _Jacobi:
    """The diagonal preconditioner of :func:`pcg`: ``z = r / diag(A)``, each row block's part made with the block's
    update of r."""

    def __init__(self, A: sp.csr_matrix):
        self.inv_diag = 1.0 / A.diagonal()
        self.z = np.empty(A.shape[0])

    def begin(self, r: np.ndarray, rows: slice) -> None:
        np.multiply(self.inv_diag[rows], r[rows], out=self.z[rows])

    def finish(self, r: np.ndarray) -> np.ndarray:
        return self.z


JACOBI_ONCE_ROWS = 200_000
"""Levels with at least this many rows try Jacobi in their first solve only (:meth:`Krylov.solve`): a whole 640x480
frame's finest level (307,200 rows, the only level of the outer loop's last pass). The auto ROI's levels (at most
111,552 rows on the twelve presses studied) are below it and keep their solves, bit for bit.

Why: after a first Jacobi solve at 0.1 in 15-22 iterations, its rate predicted the second step's tolerance
(0.05-0.08) within the cap of 30, and Jacobi then ran to the cap and failed on every such whole frame (coin1,
coin2, cone1, cube2, screw1, sphere2: 39-41 CG iterations, 30 of them Jacobi's, ~0.1-0.3 s of CPU a frame), stalling too
slowly for :func:`jacobi_give_up_rate` to abandon it. AMG from zero then took 10-12 iterations for the same step,
and the contact AAE moved by at most 0.001 deg (benchmarks/RESULTS.md, s22-jac1; s20-jac's rule on all levels of
>= 35,000 rows moved the demo's cube press's 73,980-row auto ROI by 0.03 deg and was reverted). Jacobi is not
dropped from the first solve: the 0.1 step AMG takes instead is a different step, which moved the relief presses'
AAE by up to 0.03 deg (s20-jac, s22-jac1) and saved no time even on cube1, whose first Jacobi solve fails at its cap
(the later steps took more AMG iterations from AMG's first step). A warm-started finest level's first solve is the
exception: to 0.01 by AMG it saves a whole Gauss-Newton step (:data:`WARM_FIRST_RTOL`)."""

JACOBI_PATIENCE = 10.0
"""How much slower than predicted a Jacobi solve may converge before it is abandoned (:func:`jacobi_give_up_rate`).

Why 10: over the 43 Jacobi solves with a prediction in 15 presses' solves (bench, extra and demo presses, auto ROI and
whole frame), every one that converged stayed within 5.7 times the predicted slowness at every iteration (the most:
cube1's whole-frame 160x120 level, 25 iterations predicted at 4.3), while the four that stalled for good (cube1,
cyl1, sphere2 auto ROIs: the residual back up to 0.66-0.99 after a few iterations; cone1's) passed 10 after 6-8
iterations (cone1 26) instead of running to the cap of 30 (benchmarks/RESULTS.md, s22-jac). The slow-but-converging
solves are thus untouched, the same bits."""


def jacobi_give_up_rate(predicted: float, rtol: float) -> float | None:
    """The per-iteration residual bound beyond which a Jacobi solve predicted at ``predicted`` iterations
    (:func:`jacobi_predicted`) to reach ``rtol`` is abandoned (:func:`pcg`'s ``give_up_rate``): the predicted rate
    ``rtol^(1/predicted)`` slowed by :data:`JACOBI_PATIENCE`, i.e. after k iterations the residual must have fallen by
    at least ``rtol^(k / (JACOBI_PATIENCE * predicted))``. None where there is no prediction (the level's first Jacobi
    solve): it runs to the cap."""
    if not 0.0 < predicted < float("inf"):
        return None
    return float(rtol ** (1.0 / (JACOBI_PATIENCE * predicted)))


def jacobi_predicted(rate: float | None, rtol: float) -> float:
    """Jacobi-preconditioned CG iterations to reduce the residual by ``rtol`` at a residual reduction of ``rate`` per
    iteration (the level's last Jacobi solve; None: none yet, 0 predicted; 1: it failed, infinitely many).

    A prediction from the last solve's average rate is optimistic: Jacobi's CG slows down as the smooth error is
    left (the 640x480 level's first step reached 0.1 in 23 iterations, 0.05 only in 56), so a solve predicted
    beyond the cap would not converge within it.
    """
    if rate is None:
        return 0.0
    if rate >= 1.0:
        return float("inf")
    return float(np.log(rtol) / np.log(max(rate, 1e-300)))


PRECONDITIONER_DTYPE = np.float32
"""Precision of the AMG hierarchy's matrices and its V-cycle (:func:`_amg_cycle`); CG itself (iterates,
residuals, the system's products) stays float64. A preconditioner need only approximate A^-1: single precision's
rounding (~6e-8 relative) lies far below what a cycle leaves (CG's residual falls ~0.7 per AMG-preconditioned
iteration on a 640x480 level) and below CG's tightest tolerance (``cg_rtol``, 1e-4). Each level's values take half
the bytes: on a whole frame's 640x480 level a cycle took ~26.5 ms instead of ~31 (its Gauss-Seidel sweeps then, two
thirds of it, gained only ~8 %, the products ~25 %; :class:`_L1Jacobi` has since replaced the large levels' sweeps),
every Gauss-Newton step of sphere1 and cube1 took the same CG iterations, and the contact AAE moved by under 1e-4 deg
(benchmarks/RESULTS.md, s18-h)."""


def _amg_cycle(Hm: sp.csr_matrix) -> _VCycle:
    """A smoothed-aggregation AMG V-cycle for ``Hm`` (:func:`_hierarchy`, :class:`_VCycle`), in
    :data:`PRECONDITIONER_DTYPE`."""
    return _VCycle(_hierarchy(_single(Hm)))


def _single(Hm: sp.csr_matrix) -> sp.csr_matrix:
    """``Hm.astype(PRECONDITIONER_DTYPE)`` (its own index arrays, the same bits), each row block's values and indices
    copied on the pool (the rows cut as :class:`threads.RowBlocks` cuts them): ~20 ms of one core on a 640x480
    level's 4 M entries, made at each AMG set-up and fit while the other core waited."""
    import scipy.sparse as sp

    Hm.sum_duplicates()  # as astype does first: a check of a canonical matrix
    if threads.workers() == 1 or Hm.shape[0] < threads.PRODUCT_MIN_ROWS:
        return Hm.astype(PRECONDITIONER_DTYPE)
    data, indices = np.empty(Hm.nnz, PRECONDITIONER_DTYPE), np.empty_like(Hm.indices)

    def copy(rows: slice) -> None:
        entries = slice(int(Hm.indptr[rows.start]), int(Hm.indptr[rows.stop]))
        data[entries] = Hm.data[entries]
        indices[entries] = Hm.indices[entries]

    threads.map_items(copy, threads.chunks(Hm.shape[0]))
    out = sp.csr_matrix(Hm.shape, dtype=PRECONDITIONER_DTYPE)
    out.data, out.indices, out.indptr = data, indices, Hm.indptr.copy()
    out.has_canonical_format = True
    return out


COARSE_SOLVER = "splu"
"""pyamg's solver of the hierarchy's coarsest level (at most ``max_coarse`` = 300 unknowns)."""


def import_amg_in_background() -> threading.Thread:
    """Start importing pyamg on a thread of its own and return the thread; :func:`_hierarchy`'s own import then
    finds the module imported, or waits for the thread (Python's import lock of the module).

    Why: pyamg's import (~25 ms, ~70 ms cold; its ``gallery`` imports ``scipy.io``) came at the first AMG set-up,
    inside a solve's pass, on the main thread while the other core waited; ``nlips solve`` starts it beside the
    press's loading instead. It also imports SciPy's sparse modules where the command has not (the solver's
    import does not: solver/__init__.py). An import that fails is not raised on the thread: the set-up's
    own import raises it. Not a daemon: the process's exit waits for a started import rather than stopping it half
    done."""

    from ..core.blas import LIBRARY_LOADS

    def run() -> None:
        # taken before any import lock (so the BLAS controller's walk, which takes it after its imports, waits
        # for this import or this import for it, never both for each other: core.blas.LIBRARY_LOADS)
        with LIBRARY_LOADS, contextlib.suppress(Exception):  # raised again by the set-up's own import, if needed
            import pyamg  # noqa: F401

    thread = threading.Thread(target=run, name="import-pyamg")
    thread.start()
    return thread


def _hierarchy(Hm: sp.csr_matrix) -> object:
    """pyamg's smoothed-aggregation hierarchy of ``Hm``, the same in every run and process.

    The Jacobi prolongation smoother is weighted row by row from Gershgorin bounds (pyamg's ``"local"``
    weighting) instead of by an estimate of the spectral radius of D^-1 A: that estimate (a few
    Arnoldi iterations) was about half of the set-up (0.6 s of 1.2-1.5 s on a 307,200-pixel level) and
    the hierarchies converge in the same CG iterations (twin 640x480 levels, benchmarks/RESULTS.md).
    It also drew its start vector from NumPy's global generator, which made two runs of one solve differ
    by ~2e-6 mm; nothing in this set-up is random.
    """
    import pyamg

    # improve_candidates=None: the constant near-null space is right for this operator, and
    # the smoothing of candidates cost a third of the setup for no gain in convergence.
    with _compiled_bsr_dedup():
        return pyamg.smoothed_aggregation_solver(
            Hm,
            symmetry="symmetric",
            max_coarse=300,
            coarse_solver=COARSE_SOLVER,
            improve_candidates=None,
            smooth=("jacobi", {"omega": 4.0 / 3.0, "weighting": "local"}),
        )


class _VCycle:
    """One V-cycle of a pyamg hierarchy from a zero start: the CG preconditioner.

    pyamg's own (``aspreconditioner``) runs its solver for one cycle, which also computes the residual norm
    before and after the cycle: two products with the finest matrix per application that nothing reads (the
    same cycle otherwise, operation for operation). And pyamg keeps its coarse levels, restrictions and
    prolongations as BSR matrices of 1x1 blocks, whose products and Gauss-Seidel sweeps run slower than the
    same matrices' CSR ones; they are converted once here. On the 307,200-pixel finest level of a 640x480
    whole frame one application took 30 ms instead of 44 ms (2 cores' machine), the CG iterations unchanged
    and the iterates equal to ~1e-13 (a CSR sweep divides by the diagonal where BSR multiplies by its
    inverse)."""

    def __init__(self, ml: object):
        self._set_levels(
            [level.A.tocsr() for level in ml.levels],
            [level.R.tocsr() for level in ml.levels[:-1]],
            [level.P.tocsr() for level in ml.levels[:-1]],
            ml.coarse_solver,
        )

    def _set_levels(self, A: list, R: list, P: list, coarse_solver: object) -> None:
        self.A, self.R, self.P, self.coarse_solver = A, R, P, coarse_solver
        # the large levels' products, their smoothers' included, by row blocks on both cores
        self.products = [tuple(threads.RowBlocks(m) for m in ops) for ops in zip(self.A, self.R, self.P)]
        self.smoothers = [_L1Jacobi.of(a, ops[0]) or _gauss_seidel for a, ops in zip(self.A[:-1], self.products)]
        self.fused = len(self.A) >= 2 and isinstance(self.smoothers[0], _L1Jacobi)
        """Whether :meth:`begin` and :meth:`finish` run the finest level in its products' row blocks (its smoother
        l1-Jacobi, a coarser level below it); else :meth:`finish` is :meth:`apply`."""
        if self.fused:  # their buffers: the finest level's iterate and residual, the result
            n, dtype = self.A[0].shape[0], self.A[0].dtype
            self._x, self._residual, self._z = np.empty(n, dtype), np.empty(n, dtype), np.empty(n)

    @property
    def levels(self) -> list[sp.csr_matrix]:
        """The level matrices, finest first."""
        return self.A

    def for_matrix(self, A: sp.csr_matrix) -> _VCycle:
        """The cycle of this hierarchy's aggregates for another matrix ``A`` (CSR, SPD, this one's shape and
        dtype): the same restrictions and prolongations, the coarse matrices their Galerkin products
        ``R A P`` (:func:`_galerkin`), the smoothers and the coarse solver's factors made from those.

        For the next Gauss-Newton step's matrix: weights and shading drift, the aggregates (the strength of
        connections, the grid) hardly do. On a 640x480 level this costs about a third of a set-up (cube1 0.08 s
        of CPU against 0.2 s) for the CG iterations of a set-up of its own (benchmarks/RESULTS.md). Symmetric
        positive definite as any Galerkin hierarchy of an SPD matrix; the products by rows, the same bits on
        any number of threads."""
        levels = [A]
        for R, P in zip(self.R, self.P):
            levels.append(_galerkin(R, levels[-1], P))
        cycle = object.__new__(_VCycle)
        cycle._set_levels(levels, self.R, self.P, _coarse_solver())
        return cycle

    def operator(self) -> spla.LinearOperator:
        """The cycle as a SciPy operator (for SciPy's and pyamg's Krylov solvers; :func:`pcg` calls :meth:`finish`)."""
        import scipy.sparse.linalg as spla  # here, not at the module's import: `nlips solve` never calls this

        return spla.LinearOperator(self.A[0].shape, matvec=self.apply, dtype=np.float64)

    def apply(self, b: np.ndarray) -> np.ndarray:
        """(n,) float64 -- the cycle's approximation of A^-1 b for (n,) ``b``, computed in the hierarchy's precision
        (``b`` rounded to it, the result widened back)."""
        b = np.ravel(b).astype(self.A[0].dtype, copy=False)
        if len(self.A) == 1:
            x = self.coarse_solver(self.A[0], b)
        else:
            x = np.zeros_like(b)
            self._cycle(0, x, b)
        return np.asarray(x, dtype=np.float64)

    def begin(self, r: np.ndarray, rows: slice) -> None:
        """:func:`pcg`'s first part of the cycle for (n,) float64 ``r``, on its rows ``rows`` (a row block's task):
        the finest level's pre-smoothing sweep from zero, ``x = omega D^-1 r`` in the hierarchy's precision."""
        if self.fused:
            np.multiply(r[rows], self.smoothers[0].scale[rows], out=self._x[rows], dtype=self.A[0].dtype)

    def finish(self, r: np.ndarray) -> np.ndarray:
        """(n,) float64 -- :meth:`apply` of ``r`` (the same bits) once :meth:`begin` has run on all of its rows: the
        finest level's residual, its post-smoothing and the result's widening in the row blocks of its products. The
        array is this cycle's own, overwritten by the next call."""
        if not self.fused:
            return self.apply(r)
        x, residual, z = self._x, self._residual, self._z
        (A0, R0, P0), smoother, dtype = self.products[0], self.smoothers[0], self.A[0].dtype
        blocks = A0.blocks or [(slice(0, len(x)), self.A[0])]
        p_blocks = P0.blocks or [(slice(0, len(x)), self.P[0])]

        def residual_rows(part: tuple[slice, sp.csr_matrix]) -> None:
            rows, A = part
            np.subtract(r[rows], A @ x, out=residual[rows], dtype=dtype)

        threads.map_items(residual_rows, blocks)
        coarse_b = R0.dot(residual)
        coarse_x = np.zeros_like(coarse_b)
        if len(self.A) == 2:
            coarse_x[:] = self.coarse_solver(self.A[-1], coarse_b)
        else:
            self._cycle(1, coarse_x, coarse_b)

        def correct(part: tuple[slice, sp.csr_matrix]) -> None:
            rows, P = part
            x[rows] += P @ coarse_x

        threads.map_items(correct, p_blocks)

        def post_smooth(part: tuple[slice, sp.csr_matrix]) -> None:
            rows, A = part
            sweep = np.subtract(r[rows], A @ x, dtype=dtype)
            sweep *= smoother.scale[rows]
            sweep += x[rows]
            z[rows] = sweep

        threads.map_items(post_smooth, blocks)
        return z

    def _cycle(self, k: int, x: np.ndarray, b: np.ndarray) -> None:
        """Improve ``x`` (in place) toward the solution of level k's system with right-hand side ``b``."""
        A, smoother, (A_k, R_k, P_k) = self.A[k], self.smoothers[k], self.products[k]
        smoother(A, x, b)
        coarse_b = R_k.dot(b - A_k.dot(x))
        coarse_x = np.zeros_like(coarse_b)
        if k == len(self.A) - 2:
            coarse_x[:] = self.coarse_solver(self.A[-1], coarse_b)
        else:
            self._cycle(k + 1, coarse_x, coarse_b)
        x += P_k.dot(coarse_x)
        smoother(A, x, b)


def _galerkin(R: sp.csr_matrix, A: sp.csr_matrix, P: sp.csr_matrix) -> sp.csr_matrix:
    """``R @ A @ P`` (CSR), computed as ``R @ (A @ P)`` with both products by row blocks on the pool's threads
    (SciPy's sparse kernels release the GIL): each row of a product depends on that row of its left factor
    alone, so the bits are those of one thread."""
    return _by_rows(R, _by_rows(A, P))


def _by_rows(L: sp.csr_matrix, M: sp.csr_matrix) -> sp.csr_matrix:
    """``L @ M`` (CSR) by the row blocks of :class:`threads.RowBlocks` (none where there is one thread or ``L`` is
    small: one product) on the pool, stacked by hand: SciPy's ``vstack`` checks and copies took longer than the
    second thread saved."""
    import scipy.sparse as sp

    blocks = threads.RowBlocks(L).blocks
    if not blocks:
        return (L @ M).tocsr()
    parts = threads.map_items(lambda block: (block[1] @ M).tocsr(), blocks)
    indptr = [parts[0].indptr]
    for part in parts[1:]:
        indptr.append(part.indptr[1:] + indptr[-1][-1])
    out = sp.csr_matrix((L.shape[0], M.shape[1]), dtype=parts[0].dtype)
    out.data = np.concatenate([part.data for part in parts])
    out.indices = np.concatenate([part.indices for part in parts])
    out.indptr = np.concatenate(indptr)
    return out


def _gauss_seidel(A: sp.csr_matrix, x: np.ndarray, b: np.ndarray) -> None:
    """One symmetric Gauss-Seidel sweep on ``x`` (in place) for ``A x = b``: the smaller levels' smoother, pyamg's
    default for a smoothed-aggregation hierarchy (its ``block_gauss_seidel`` of 1x1 blocks is this)."""
    from pyamg.relaxation.relaxation import gauss_seidel

    gauss_seidel(A, x, b, iterations=1, sweep="symmetric")


def _coarse_solver() -> object:
    """The hierarchy's coarsest-level solver (a sparse LU, factored at its first call), as :func:`_hierarchy`'s."""
    import pyamg

    return pyamg.coarse_grid_solver(COARSE_SOLVER)


SMOOTHER_MIN_ROWS = 50_000
"""Levels with at least this many rows smooth by l1-Jacobi (:class:`_L1Jacobi`), the smaller ones by pyamg's own
symmetric Gauss-Seidel (one sweep before and after): on a 640x480 level (307,200 rows) Gauss-Seidel's two symmetric
sweeps were two thirds of a cycle's 26 ms; the next level's (20,483 rows) take ~2.5 ms, and l1-Jacobi there cost
more CG iterations than it saved (benchmarks/RESULTS.md, s18-k)."""
SMOOTHER_OMEGA = 1.8
"""Damping of :class:`_L1Jacobi`. Its scaled matrix's eigenvalues lie in (0, 1] (Gershgorin), so any weight below 2
converges and keeps the cycle positive definite; the 640x480 levels' largest is ~0.95, at which 1.8 leaves the
highest-frequency error a factor 0.71 per sweep and took fewer CG iterations than 1.6 or 1.3 (s18-k)."""


class _L1Jacobi:
    """One damped l1-Jacobi sweep, ``x += omega D^-1 (b - A x)`` with ``D_ii = sum_j |a_ij|``: a large level's smoother.

    A product with ``A`` (by row blocks, on both cores: :class:`threads.RowBlocks`) and elementwise work, instead of
    Gauss-Seidel's row-by-row sweep, which waits on the rows before it (latency, not bandwidth) and so gained ~8 %
    from single precision where the products gained ~25 %. The l1 row sums bound the spectrum of ``D^-1 A`` by 1
    without an eigenvalue estimate (a set-up cost, and pyamg's is random). The same symmetric operator before and
    after the coarse correction: CG's preconditioner stays symmetric positive definite. A weaker smoother than a
    symmetric Gauss-Seidel sweep: the 640x480 levels took ~1.3-1.5x the CG iterations at ~40 % of the cycle's CPU
    (benchmarks/RESULTS.md, s18-k). Elementwise and by rows: the same bits on any number of threads.

    Parameters
    ----------
    A : (n, n) scipy.sparse CSR matrix, float32 or float64 -- the level's matrix, symmetric positive definite.
    product : :class:`threads.RowBlocks` of ``A`` -- the cycle's own, shared.
    """

    def __init__(self, A: sp.csr_matrix, product: threads.RowBlocks):
        self.product = product
        # every row holds its positive diagonal (A is SPD): reduceat sums each row, none empty
        # each row block's sums on the pool (the same segments, the same bits): ~18 ms of one core at 640x480
        parts = product.blocks or [(slice(0, A.shape[0]), A)]
        row_sums = np.concatenate(
            threads.map_items(
                lambda part: np.add.reduceat(np.abs(part[1].data, dtype=np.float64), part[1].indptr[:-1]), parts
            )
        )
        self.scale = (SMOOTHER_OMEGA / row_sums).astype(A.dtype)
        """(n,) A's dtype -- omega / D_ii."""

    @classmethod
    def of(cls, A: sp.csr_matrix, product: threads.RowBlocks) -> _L1Jacobi | None:
        """The smoother of level matrix ``A`` (CSR, ``product`` its RowBlocks), or None where symmetric Gauss-Seidel
        (:func:`_gauss_seidel`) serves: a level under :data:`SMOOTHER_MIN_ROWS` rows."""
        return cls(A, product) if A.shape[0] >= SMOOTHER_MIN_ROWS else None

    def __call__(self, A: sp.csr_matrix, x: np.ndarray, b: np.ndarray) -> None:
        """One sweep on ``x`` (n,) of ``A``'s dtype, in place, for the system ``A x = b`` (pyamg's smoother's
        signature; ``A`` is the level's matrix this smoother was made for). From a zero ``x`` (the pre-smoother)
        the residual is ``b`` itself: the product is skipped, the bits the same."""
        r = b - self.product.dot(x) if x.any() else b.copy()
        r *= self.scale
        x += r


_dedup_lock = threading.Lock()
_dedup_users = [0, None]  # [set-ups inside the block now, SciPy's own method while they are]


@contextlib.contextmanager
def _compiled_bsr_dedup():
    """Within the block, SciPy's BSR ``sum_duplicates`` first sorts (compiled) and returns when no
    duplicate is left, before its pure-Python loop over block rows.

    Why: the "local" weighting takes ``abs`` of each coarse level's Galerkin product (BSR, 1x1 blocks),
    and SciPy deduplicates a BSR matrix in a Python loop over its rows even when, as here, its entries
    are only unsorted, never duplicated: 0.56 s of a 0.99 s set-up on a 307,200-pixel level under cProfile,
    which inflates Python loops; 0.1-0.2 s of wall time of a whole-frame solve (benchmarks/RESULTS.md). The
    result is the same matrix; the loop still runs if a duplicate exists. Set-ups in several threads share
    one installation (counted under a lock): SciPy's method is back once the last one leaves.
    """
    import scipy.sparse as sp

    cls = next(c for c in type(sp.bsr_array((1, 1))).__mro__ if "sum_duplicates" in vars(c))
    with _dedup_lock:
        if _dedup_users[0] == 0:
            original = cls.sum_duplicates
            _dedup_users[1] = original

            def sum_duplicates(self: sp.bsr_array | sp.bsr_matrix):  # installed as the BSR classes' method
                if not self.has_canonical_format:
                    self.sort_indices()
                    if not _has_duplicates(self.indptr, self.indices):
                        self.has_canonical_format = True
                        return
                original(self)

            cls.sum_duplicates = sum_duplicates
        _dedup_users[0] += 1
    try:
        yield
    finally:
        with _dedup_lock:
            _dedup_users[0] -= 1
            if _dedup_users[0] == 0:
                cls.sum_duplicates = _dedup_users[1]


def _has_duplicates(indptr: np.ndarray, indices: np.ndarray) -> bool:
    """Whether a compressed matrix with sorted indices repeats a column within a row."""
    same = indices[1:] == indices[:-1]
    if not same.any():
        return False
    row_start = np.zeros(len(indices), bool)
    row_start[indptr[1:-1][indptr[1:-1] < len(indices)]] = True
    return bool((same & ~row_start[1:]).any())
