"""A level's operators: its difference operators, second-difference penalty and normal-matrix assembler (kept
for the next solve on the same mask, in the process or on disk, or made ahead on a thread), and the gradient and
unit normals of a log-depth through them, by pixel blocks on the thread pool."""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from . import geometry, reuse, threads
from .kernel import PARALLEL_MIN_PIXELS

if TYPE_CHECKING:  # in hints only
    import scipy.sparse as sp

OPERATOR_LEVELS = 8
"""Levels whose operators a process keeps (solver.reuse): a pyramid's four to six, and a spare. A 640x480 level's
take 160 MB (its pyramid's 210 MB); an auto ROI's a tenth of that."""


OPERATOR_PERSIST_PIXELS = 50_000
"""Levels of the sensor's whole gel (a solve whose mask is everywhere the prior is finite: every whole-frame
press of the sensor solves on those masks) with at least this many pixels keep their operators on disk for the
next process (:mod:`nlipscalib.core.diskcache`) and assemble their normal matrix with a fixed-pattern map
(:class:`nlipscalib.solver.geometry.NormalMatrix`): at 640x480 the finest level's operators and map take ~1.6 s
to build and ~0.15 s to read back, and its assemblies then take 0.04 s instead of 0.4 s; the 320x240 level's
0.01 s instead of 0.07 s. An ROI's masks (auto ROI: one per press) are built in the process as before: their
map would cost more than the few assemblies it saves, and they rarely recur."""


def level_operators(lv: dict) -> dict:
    """Difference operators and the normal-matrix assembler of a level (cached in ``lv``).

    They depend on the level's mask alone and cost 0.5-0.9 s at 640x480: kept for the next solve on the
    same mask (the outer interreflection loop's passes, the next press of a whole-frame dataset; a large
    level of the sensor's whole gel on disk too, see :data:`OPERATOR_PERSIST_PIXELS`)."""
    if "ops" not in lv:
        mk = lv["mask"]
        recurs = _persists(lv)
        ahead = lv.pop("ops_ahead", None)  # made on a thread of its own (:func:`operators_ahead`)
        lv["ops"] = reuse.reused(
            "operators",
            (reuse.digest(mk), recurs),
            ahead.result if ahead is not None else lambda: _make_operators(mk, fixed=recurs),
            most=OPERATOR_LEVELS,
            persist=recurs,
        )
    return lv["ops"]


def _persists(lv: dict) -> bool:
    """Whether a level's operators are kept on disk (:data:`OPERATOR_PERSIST_PIXELS`)."""
    return lv.get("recurs", False) and int(lv["mask"].sum()) >= OPERATOR_PERSIST_PIXELS


def operators_ahead(lv: dict, assembler: bool = False) -> None:
    """Start making level ``lv``'s operators on a thread of its own (:func:`level_operators` then waits for them),
    while the coarser levels are solved; nothing when they are kept (in this process or on disk) or when the
    solve has one core. ``assembler``: the level is iterated later (the outer loop's last pass, on the same mask):
    its normal-matrix assembler is made after them on the same thread (:class:`_Assembler`), else at its first
    assembly, if any.

    Why: an outer pass before the last solves a coarse level, then brings the finest one up
    (:func:`.coarse_to_fine._brought_up`), which needs the finest level's operators: 0.08-0.1 s of one core on the
    cube press's 336x332 auto ROI or its whole frame's 368x364 focus (0.025 s on the sphere's 210x218), built while the
    second core idled. SciPy's sparse kernels release the GIL, and the operators are the same bits on any
    thread."""
    if threads.workers() == 1 or "ops" in lv or _persists(lv):
        return
    mk = lv["mask"]
    if reuse.stored("operators", (reuse.digest(mk), False)):
        return
    pool = ThreadPoolExecutor(1, "nlips-operators")
    lv["ops_ahead"] = operators = pool.submit(_make_operators, mk)
    if assembler:  # after them, on the same thread: the level's bringing up waits for its difference operators alone
        pool.submit(lambda: operators.result()["normal"].make())
    pool.shutdown(wait=False)  # its tasks run on; its thread ends with them


class _Assembler:
    """A level's normal-matrix assembler by the grid's diagonals (:class:`nlipscalib.solver.geometry.NormalMatrix`,
    ``grid``), made once: by :meth:`make` (on the operators' thread, :func:`operators_ahead`) or at its first
    :meth:`assemble`; a level that is never iterated never makes it.

    Why: the stencil's build is ~45 ms of one core on the cube press's 111,552-pixel auto ROI (the products' 7.5 ms),
    repaid by its assemblies (7 ms instead of 29-31). Made with the difference operators, the levels only brought up
    paid it for nothing (a whole frame's dent focus, 60,500-133,952 pixels, at every focus pass) and, made in the same
    task, the cube press's first pass waited 40-480 ms at its bringing up for it: its many short NumPy calls each waited
    for the GIL while the coarse levels' Python ran on the main thread (benchmarks/RESULTS.md, s34-cubef32)."""

    def __init__(self, ops: dict, mk: np.ndarray):
        self._ops, self._mk = ops, mk
        self._made: geometry.NormalMatrix | None = None
        self._lock = threading.Lock()

    def make(self) -> geometry.NormalMatrix:
        """The assembler, made by the first caller (another waits for it)."""
        with self._lock:
            if self._made is None:
                self._made = _normal_matrix(self._ops, self._mk)
            return self._made

    def assemble(self, M: np.ndarray, weights: Sequence[float | np.ndarray] = ()) -> sp.csr_matrix:
        """:meth:`nlipscalib.solver.geometry.NormalMatrix.assemble` of the assembler (made here if not yet)."""
        return self.make().assemble(M, weights)


def _make_operators(mk: np.ndarray, fixed: bool = False) -> dict:
    """Difference operators of a level's mask and its normal-matrix assembler: by the grid's diagonals, made at its
    first use (:class:`_Assembler`), or by the fixed-pattern map (``fixed``, made here: a level kept on disk,
    :class:`nlipscalib.solver.geometry.NormalMatrix`)."""
    forward = geometry.difference_operators(mk)
    backward = geometry.difference_operators(mk, backward=True)
    Du, Dv, has_grad = geometry.gradient_operators(mk, forward, backward)
    (du_f, dv_f, _), (du_b, dv_b, _) = forward, backward
    # Second differences (forward minus backward; zero at edges): the checkerboard modes central
    # differences cannot see. A weak penalty on them couples the sub-lattices (and lets AMG work).
    second = [(du_f - du_b).tocsr(), (dv_f - dv_b).tocsr()]
    lap = (second[0].T @ second[0] + second[1].T @ second[1]).tocsr()
    # Central differences: one-sided ones put the normal half a pixel off the data and bias the
    # fit by about a degree on this lens.
    ops = {"Du": Du, "Dv": Dv, "has_grad": has_grad, "lap": lap, "second": second}
    ops["normal"] = _normal_matrix(ops, mk, fixed=True) if fixed else _Assembler(ops, mk)
    return ops


def _normal_matrix(ops: dict, mk: np.ndarray, fixed: bool = False) -> geometry.NormalMatrix:
    """The normal-matrix assembler of a level's difference operators ``ops`` on its mask ``mk``: by the grid's
    diagonals (the level's own mask), or by the fixed-pattern map (``fixed``)."""
    import scipy.sparse as sp

    eye = sp.identity(ops["Du"].shape[0], format="csr")
    return geometry.NormalMatrix((eye, ops["Du"], ops["Dv"]), ops["second"], fixed=fixed, grid=None if fixed else mk)


def log_depth_gradient(ops: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t_u, t_v), (N,) each, of a level's log-depth t (N,): its difference operators' products (``ops``:
    :func:`level_operators`), by row blocks on the pool on a large level (:class:`threads.RowBlocks`, the same bits)."""
    return threads.RowBlocks(ops["Du"]).dot(t), threads.RowBlocks(ops["Dv"]).dot(t)


def depth_normals(ops: dict, t: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals of a level's log-depth t (N,) (:func:`geometry.normals_from_gradient`, by pixel blocks)."""
    return unit_normals(*log_depth_gradient(ops, t), A, B, C)


def unit_normals(tu: np.ndarray, tv: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals of a level's log-depth gradient (tu, tv) (N,) each (:func:`geometry.normals_from_gradient`,
    by pixel blocks)."""
    return pixelwise(lambda p: geometry.normals_from_gradient(tu[p], tv[p], A[p], B[p], C[p]), len(tu))


PIXELWISE_PIXELS = 65_536
"""Pixels per task of a level's per-pixel work outside its model (:func:`pixelwise`): normals and their change
per iteration. Levels under :data:`nlipscalib.solver.kernel.PARALLEL_MIN_PIXELS` pixels run it in one piece."""


def pixelwise(fn: Callable[[slice], np.ndarray], n: int) -> np.ndarray:
    """``fn(slice(0, n))`` of a per-pixel ``fn`` (its result's first axis the pixels'), by pixel blocks on the thread
    pool on a large level: the same bits. On a 640x480 level an iteration's normals and their change from the last
    ones took ~15-20 ms of one core."""
    if n < PARALLEL_MIN_PIXELS:
        return fn(slice(0, n))
    return np.concatenate(threads.map_items(fn, threads.chunks(n, max(threads.workers(), -(-n // PIXELWISE_PIXELS)))))
