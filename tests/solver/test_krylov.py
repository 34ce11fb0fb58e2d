"""The AMG set-up's BSR deduplication shortcut: same matrices, SciPy's method restored afterwards."""

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from nlipscalib.solver import krylov


def _unsorted_bsr(duplicate: bool):
    # rows 0 and 2 hold their columns out of order; with ``duplicate`` row 1 holds column 0 twice
    indptr = np.array([0, 2, 4, 6])
    indices = np.array([2, 0, 0, 0 if duplicate else 1, 2, 1])
    data = np.arange(1.0, 7.0).reshape(-1, 1, 1)
    return sp.bsr_array((data, indices, indptr), shape=(3, 3))


def test_dedup_shortcut_keeps_the_matrix_and_restores_scipy():
    original = type(_unsorted_bsr(False)).sum_duplicates
    for duplicate in (False, True):
        expected = _unsorted_bsr(duplicate).toarray()
        with krylov._compiled_bsr_dedup():
            m = _unsorted_bsr(duplicate)
            m.sum_duplicates()
            assert m.has_canonical_format
            np.testing.assert_array_equal(m.toarray(), expected)
            assert len(m.indices) == (5 if duplicate else 6)
        assert abs(m).toarray().sum() == np.abs(expected).sum()
    assert type(_unsorted_bsr(False)).sum_duplicates is original


def test_has_duplicates_only_within_a_row():
    # the last column of row 0 equals the first of row 1: not a duplicate
    assert not krylov._has_duplicates(np.array([0, 2, 4]), np.array([0, 3, 3, 5]))
    assert krylov._has_duplicates(np.array([0, 2, 4]), np.array([0, 3, 5, 5]))
    assert not krylov._has_duplicates(np.array([0, 0, 1, 1]), np.array([2]))  # empty rows


def test_dedup_shortcut_nested_or_overlapping_restores_scipy_once_the_last_leaves():
    original = type(_unsorted_bsr(False)).sum_duplicates
    outer = krylov._compiled_bsr_dedup()
    inner = krylov._compiled_bsr_dedup()
    outer.__enter__()
    installed = type(_unsorted_bsr(False)).sum_duplicates
    inner.__enter__()  # a second set-up (another thread) shares the installation
    assert type(_unsorted_bsr(False)).sum_duplicates is installed is not original
    outer.__exit__(None, None, None)  # the first leaves before the second: still installed
    assert type(_unsorted_bsr(False)).sum_duplicates is installed
    inner.__exit__(None, None, None)
    assert type(_unsorted_bsr(False)).sum_duplicates is original


def _laplacian(side: int) -> sp.csr_matrix:
    """A 2-D five-point Laplacian plus a small diagonal: SPD, several AMG levels at side >= 40."""
    d = sp.diags([-np.ones(side - 1), 2 * np.ones(side), -np.ones(side - 1)], [-1, 0, 1])
    eye = sp.identity(side)
    return (sp.kron(d, eye) + sp.kron(eye, d) + 1e-3 * sp.identity(side * side)).tocsr()


def test_the_v_cycle_is_pyamgs_one_cycle_preconditioner():
    """The preconditioner skips pyamg's residual norms and runs on CSR copies of the levels: the same cycle."""
    rng = np.random.default_rng(0)
    for side in (60, 10):  # several levels; one level (below max_coarse: the coarse solver alone)
        A = _laplacian(side)
        ml = krylov._hierarchy(A)
        b = rng.standard_normal(A.shape[0])
        expected = ml.aspreconditioner(cycle="V") @ b
        cycle = krylov._VCycle(ml)
        assert (len(ml.levels) > 2) == (side == 60)
        assert all(m.format == "csr" for m in cycle.A + cycle.R + cycle.P)
        np.testing.assert_allclose(cycle.apply(b), expected, rtol=1e-10, atol=1e-12 * np.abs(expected).max())


def test_cg_with_the_v_cycle_converges_as_with_pyamgs():
    A = _laplacian(60)
    b = np.random.default_rng(1).standard_normal(A.shape[0])
    ml = krylov._hierarchy(A)
    counts = []
    for M in (ml.aspreconditioner(cycle="V"), krylov._VCycle(ml).operator()):
        iterates = []
        x, status = spla.cg(A, b, rtol=1e-8, M=M, callback=iterates.append)
        assert status == 0 and np.linalg.norm(A @ x - b) <= 1e-8 * np.linalg.norm(b)
        counts.append(len(iterates))
    assert counts[0] == counts[1]


def test_the_preconditioner_cycles_in_single_precision_for_a_double_precision_cg(monkeypatch):
    """The hierarchy and its V-cycle in float32 (half the bytes of each level's values), taking and returning
    float64: within float32's rounding of the float64 cycle, and CG (float64) reaches the same tolerance in the
    same iterations as with that cycle, on a system of known answer; the same bits on one thread or two."""
    from nlipscalib.solver import threads
    from nlipscalib.solver.options import SolverOptions

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)  # the finest level smooths by l1-Jacobi, as at 640x480
    A = _laplacian(60)
    x_true = np.random.default_rng(6).standard_normal(A.shape[0])
    b = A @ x_true
    cycles = []

    class Recorded(krylov._VCycle):  # the cycles the solver makes
        def __init__(self, ml: object):
            super().__init__(ml)
            cycles.append(self)

    monkeypatch.setattr(krylov, "_VCycle", Recorded)
    M = krylov._amg_cycle(A).operator()
    cycle = cycles[-1]
    assert len(cycle.levels) > 2 and cycle.smoothers[0] is not None
    assert all(m.dtype == np.float32 for m in cycle.A + cycle.R + cycle.P)
    assert M.dtype == np.float64 and M.matvec(b).dtype == np.float64
    double = krylov._VCycle(krylov._hierarchy(A))
    expected = double.apply(b)
    np.testing.assert_allclose(M.matvec(b), expected, rtol=0, atol=1e-5 * np.abs(expected).max())
    before = threads.workers()
    results = []
    for count in (1, 2):
        threads.set_workers(count)
        try:
            results.append(krylov._amg_cycle(A).operator().matvec(b))
        finally:
            threads.set_workers(before)
    np.testing.assert_array_equal(results[0], results[1])

    counts = []
    for precond in (M, double.operator()):
        iterates = []
        x, status = spla.cg(A, b, rtol=1e-8, M=precond, callback=iterates.append)
        assert status == 0 and np.linalg.norm(A @ x - b) <= 1e-8 * np.linalg.norm(b)
        counts.append(len(iterates))
    assert abs(counts[0] - counts[1]) <= 1
    # the solver's own path: AMG at its tightest tolerance (no Jacobi), the answer to that tolerance
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=0))
    x, iters = pcg.solve(A, b, SolverOptions().cg_rtol)
    assert pcg.setups == 1 and cycles[-1].A[0].dtype == np.float32 and iters <= counts[1]
    assert np.linalg.norm(A @ x - b) <= SolverOptions().cg_rtol * np.linalg.norm(b)
    assert np.linalg.norm(x - x_true) <= 1e-3 * np.linalg.norm(x_true)


def test_row_block_products_are_the_products(monkeypatch):
    """Products by row blocks on two threads: the same bits as the matrix's own, blocks or not."""
    from nlipscalib.solver import threads

    A = sp.random(3000, 2500, density=0.004, format="csr", random_state=np.random.default_rng(2))
    x = np.random.default_rng(3).standard_normal(2500)
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    before = threads.workers()
    for count, blocks in ((2, 2), (1, 0)):
        threads.set_workers(count)
        try:
            products = threads.RowBlocks(A)
            assert len(products.blocks) == blocks
            np.testing.assert_array_equal(products.dot(x), A @ x)
        finally:
            threads.set_workers(before)


def test_row_blocks_view_the_matrix_without_copying_it(monkeypatch):
    """Every block's values and column indices are views of the matrix's own (SciPy's format check copied a
    block viewing less than half of them: 92 MB per assembly of a whole 640x480 frame's normal matrix)."""
    from nlipscalib.solver import threads

    A = sp.random(3000, 2500, density=0.004, format="csr", random_state=np.random.default_rng(2))
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    before = threads.workers()
    threads.set_workers(3)  # three blocks: each views a third of A's entries
    try:
        products = threads.RowBlocks(A)
    finally:
        threads.set_workers(before)
    assert len(products.blocks) == 3
    for rows, block in products.blocks:
        assert np.shares_memory(block.data, A.data) and np.shares_memory(block.indices, A.indices)
        np.testing.assert_array_equal(block.toarray(), A[rows].toarray())


def test_large_levels_smooth_by_one_l1_jacobi_sweep_on_any_threads(monkeypatch):
    """A large level's smoother: x + omega (b - A x) / sum_j |a_ij|, from a zero x omega b / sum_j |a_ij|; on one
    or two threads (the product by row blocks) the same bits."""
    from nlipscalib.solver import threads

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    A = _laplacian(40)  # 1600 rows: row sums |a_ij| 8.001 inside, less on the border
    rng = np.random.default_rng(4)
    b, x0 = rng.standard_normal(1600), rng.standard_normal(1600)
    dense = A.toarray()
    l1 = np.abs(dense).sum(axis=1)
    omega = krylov.SMOOTHER_OMEGA
    results, before = [], threads.workers()
    for count in (1, 2):
        threads.set_workers(count)
        try:
            smoother = krylov._VCycle(krylov._hierarchy(A)).smoothers[0]
            assert isinstance(smoother, krylov._L1Jacobi)
            assert len(smoother.product.blocks) == (2 if count == 2 else 0)
            x, zero = x0.copy(), np.zeros(1600)
            smoother(A, x, b)
            smoother(A, zero, b)
            results.append((x, zero))
        finally:
            threads.set_workers(before)
    np.testing.assert_allclose(results[0][0], x0 + omega * (b - dense @ x0) / l1, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(results[0][1], omega * b / l1, rtol=1e-15, atol=0)
    for one, two in zip(*results):
        np.testing.assert_array_equal(one, two)


def test_large_level_smoother_only_from_its_row_count(monkeypatch):
    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    cycle = krylov._VCycle(krylov._hierarchy(_laplacian(40)))  # 1600 rows, the next level under 1000
    assert isinstance(cycle.smoothers[0], krylov._L1Jacobi)
    assert all(s is krylov._gauss_seidel for s in cycle.smoothers[1:])  # pyamg's symmetric Gauss-Seidel there


def test_the_cycle_with_l1_jacobi_is_symmetric_positive_definite(monkeypatch):
    """CG needs a symmetric positive definite preconditioner: the cycle's matrix (its columns, float64 hierarchy)
    is symmetric to rounding and its eigenvalues positive, with the l1-Jacobi weight up to just below 2."""
    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    A = _laplacian(34)  # 1156 rows, two levels or more
    for omega in (krylov.SMOOTHER_OMEGA, 1.99):
        monkeypatch.setattr(krylov, "SMOOTHER_OMEGA", omega)
        cycle = krylov._VCycle(krylov._hierarchy(A))
        assert len(cycle.levels) >= 2 and isinstance(cycle.smoothers[0], krylov._L1Jacobi)
        M = np.column_stack([cycle.apply(e) for e in np.eye(A.shape[0])])
        np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-12 * np.abs(M).max())
        assert np.linalg.eigvalsh((M + M.T) / 2).min() > 0


def test_cg_with_l1_jacobi_smoothing_converges_on_a_known_answer(monkeypatch):
    """The large levels' l1-Jacobi sweep is weaker than pyamg's symmetric Gauss-Seidel sweep: CG reaches 1e-8 on a
    known answer within twice the iterations of pyamg's own cycle (13 against 7 here; ~1.3-1.5x on 640x480 levels,
    where the cycle costs ~40 % of the CPU)."""
    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    A = _laplacian(80)
    x_true = np.random.default_rng(5).standard_normal(A.shape[0])
    b = A @ x_true
    ml = krylov._hierarchy(A)
    cycle = krylov._VCycle(ml)
    assert isinstance(cycle.smoothers[0], krylov._L1Jacobi)
    counts = []
    for M in (ml.aspreconditioner(cycle="V"), cycle.operator()):
        iterates = []
        x, status = spla.cg(A, b, rtol=1e-8, M=M, callback=iterates.append)
        assert status == 0 and np.linalg.norm(A @ x - b) <= 1e-8 * np.linalg.norm(b)
        assert np.linalg.norm(x - x_true) <= 1e-5 * np.linalg.norm(x_true)
        counts.append(len(iterates))
    assert counts[0] < counts[1] <= 2 * counts[0]


def _scaled_poisson(n: int) -> sp.csr_matrix:
    """A 2-D Poisson matrix on an n x n grid, slightly shifted and diagonally scaled: Jacobi-preconditioned CG
    reaches 0.1 within its cap and slows down past it, as on a whole frame's warm-started level."""
    lap1 = sp.diags([-1.0, 2.0, -1.0], [-1, 0, 1], shape=(n, n))
    eye = sp.identity(n)
    scale = sp.diags(np.linspace(1.0, 3.0, n * n))
    return (scale @ (sp.kron(lap1, eye) + sp.kron(eye, lap1) + 1e-3 * sp.identity(n * n)) @ scale).tocsr()


def test_jacobi_prediction_from_the_last_rate():
    assert krylov.jacobi_predicted(None, 0.01) == 0.0  # no Jacobi solve yet: try it
    assert krylov.jacobi_predicted(1.0, 0.05) == np.inf  # it failed: never again on this level
    # the 640x480 level's first step: 0.1 in 23 iterations; its second step's 0.038 then lies beyond 30
    assert 30 < krylov.jacobi_predicted(0.1 ** (1 / 23), 0.038) < 34


def test_jacobi_not_tried_where_its_last_rate_predicts_failure():
    """A tighter solve that Jacobi's last rate puts beyond its cap goes to AMG at once: no capped Jacobi
    iterations spent first (they were 30 of the step's 39 on a whole frame's last pass)."""
    from nlipscalib.solver.options import SolverOptions

    H = _scaled_poisson(40)
    rhs = np.random.default_rng(0).standard_normal(H.shape[0])
    opts = SolverOptions()
    pcg = krylov.Krylov(opts)
    _, first = pcg.solve(H, rhs, 0.1)
    assert first < opts.cg_jacobi_iters and pcg.setups == 0  # Jacobi converged
    assert krylov.jacobi_predicted(pcg.jacobi_rate, 0.02) > opts.cg_jacobi_iters
    x, second = pcg.solve(H, rhs, 0.02)
    assert pcg.setups == 1 and second < 10  # AMG alone (30 Jacobi iterations and AMG's before)
    assert np.linalg.norm(rhs - H @ x) <= 0.02 * np.linalg.norm(rhs)


def test_a_failed_jacobi_solve_is_not_tried_again():
    from nlipscalib.solver.options import SolverOptions

    H = _scaled_poisson(40)
    rhs = np.random.default_rng(1).standard_normal(H.shape[0])
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=3))
    _, first = pcg.solve(H, rhs, 0.1)
    assert first > 3 and pcg.jacobi_rate == 1.0  # capped, then AMG
    pcg.amg = None  # as after a drift: the hierarchy is rebuilt, Jacobi is not tried
    _, second = pcg.solve(H, rhs, 0.1)
    assert second < 3 and pcg.setups == 2


def test_jacobi_give_up_bound_from_the_prediction():
    assert krylov.jacobi_give_up_rate(0.0, 0.05) is None  # the level's first Jacobi solve: to the cap
    assert krylov.jacobi_give_up_rate(np.inf, 0.05) is None
    rate = krylov.jacobi_give_up_rate(6.47, 0.0241)  # cube1's auto ROI, last pass, step 2 (predicted 6.47)
    assert rate == 0.0241 ** (1 / (krylov.JACOBI_PATIENCE * 6.47))
    assert rate**6 < 0.9  # its residual was 0.99 after 6 iterations: abandoned there, not at 30
    # cube1's whole-frame 160x120 level: predicted 4.25 for 0.0383, converged at 25 (residual 0.039 at 24)
    assert krylov.jacobi_give_up_rate(4.25, 0.0383) ** 24 > 0.039


def test_pcg_gives_up_only_past_the_bound():
    """A bound the residual never crosses leaves the solve's bits alone; one it crosses stops the solve there, as
    a cap of that many iterations would, reported as not converged."""
    A = _scaled_poisson(30)
    b = np.random.default_rng(2).standard_normal(A.shape[0])
    system = krylov.threads.RowBlocks(A)
    x, status, iters = krylov.pcg(system, b, None, 1e-3, 500, krylov._Jacobi(A))
    assert status == 0 and iters > 20
    loose = krylov.pcg(system, b, None, 1e-3, 500, krylov._Jacobi(A), give_up_rate=0.9999)
    assert loose[1:] == (0, iters)
    np.testing.assert_array_equal(loose[0], x)
    stopped, status, made = krylov.pcg(system, b, None, 1e-3, 500, krylov._Jacobi(A), give_up_rate=0.7)
    assert 0 < made < iters and status == made
    assert np.linalg.norm(b - A @ stopped) > 0.7**made * np.linalg.norm(b)
    capped = krylov.pcg(system, b, None, 1e-3, made, krylov._Jacobi(A))
    np.testing.assert_array_equal(stopped, capped[0])


def test_a_stalling_jacobi_solve_is_abandoned_for_amg(monkeypatch):
    """A level whose first Jacobi solve was fast predicts a second one of a few iterations; where that one stalls
    (here: a much harder matrix) it stops long before the cap and AMG continues from its iterate, to the tolerance."""
    from nlipscalib.solver.options import SolverOptions

    easy = (sp.identity(1600) + 0.05 * _scaled_poisson(40)).tocsr()
    hard = _scaled_poisson(40)
    rhs = np.random.default_rng(3).standard_normal(1600)
    made = []
    pcg = krylov.pcg
    monkeypatch.setattr(krylov, "pcg", lambda *args, **kw: (out := pcg(*args, **kw), made.append((args[5], out[2])))[0])
    opts = SolverOptions()
    solver = krylov.Krylov(opts)
    _, first = solver.solve(easy, rhs, 0.1)
    assert solver.setups == 0 and first <= 4  # Jacobi converged fast: the next solve is predicted short
    assert krylov.jacobi_predicted(solver.jacobi_rate, 0.05) < 6
    made.clear()
    x, second = solver.solve(hard, rhs, 0.05)
    jacobi = [k for pre, k in made if isinstance(pre, krylov._Jacobi)]
    assert len(jacobi) == 1 and 0 < jacobi[0] < opts.cg_jacobi_iters  # abandoned before the cap
    assert solver.setups == 1 and solver.jacobi_rate == 1.0
    assert np.linalg.norm(rhs - hard @ x) <= 0.05 * np.linalg.norm(rhs)


def test_a_large_level_tries_jacobi_in_its_first_solve_only(monkeypatch):
    """On a level of JACOBI_ONCE_ROWS rows or more a second solve that Jacobi's first rate predicts within the cap goes
    to AMG at once (on a whole frame it ran to the cap and failed); a smaller level tries Jacobi again."""
    from nlipscalib.solver.options import SolverOptions

    easy = (sp.identity(1600) + 0.05 * _scaled_poisson(40)).tocsr()
    rhs = np.random.default_rng(4).standard_normal(1600)
    made = []
    pcg = krylov.pcg
    monkeypatch.setattr(krylov, "pcg", lambda *args, **kw: (pcg(*args, **kw), made.append(args[5]))[0])
    tried = {}
    for once_rows in (1601, 1600):  # the level below the bound, then at it
        monkeypatch.setattr(krylov, "JACOBI_ONCE_ROWS", once_rows)
        solver = krylov.Krylov(SolverOptions())
        solver.solve(easy, rhs, 0.1)
        assert solver.setups == 0 and krylov.jacobi_predicted(solver.jacobi_rate, 0.05) < 10
        made.clear()
        x, _ = solver.solve(easy, rhs, 0.05)
        tried[once_rows] = [type(pre) for pre in made]
        assert np.linalg.norm(rhs - easy @ x) <= 0.05 * np.linalg.norm(rhs)
    assert tried[1601] == [krylov._Jacobi]  # converged again by Jacobi, no set-up
    assert tried[1600] == [krylov._VCycle]  # AMG alone


def _weighted_laplacian(n: int, seed: int) -> sp.csr_matrix:
    """A 2-D Laplacian on an n x n grid whose edges are weighted by a random positive field (as one Gauss-Newton
    step's robust weights), plus a small shift: SPD; two seeds, two steps' matrices of one pattern."""
    w = np.exp(np.random.default_rng(seed).standard_normal((n, n)))
    diff = sp.diags([-1.0, 1.0], [0, 1], shape=(n - 1, n))
    eye = sp.identity(n)
    dx, dy = sp.kron(eye, diff), sp.kron(diff, eye)
    wx, wy = sp.diags((w[:, :-1] + w[:, 1:]).ravel() / 2), sp.diags((w[:-1] + w[1:]).ravel() / 2)
    return (dx.T @ wx @ dx + dy.T @ wy @ dy + 1e-3 * sp.identity(n * n)).tocsr()


def test_a_hierarchy_for_another_matrix_is_its_galerkin_hierarchy(monkeypatch):
    """``for_matrix``: the same transfers, the coarse matrices R A P of the new matrix (to rounding: pyamg multiplies
    in another order), its own l1-Jacobi scaling, a coarse solver of its coarsest matrix; a symmetric positive
    definite cycle; the same bits on one thread or two (the Galerkin products by row blocks)."""
    from nlipscalib.solver import threads

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    A1, A2 = _weighted_laplacian(50, 0), _weighted_laplacian(50, 1)  # 2500 rows, three levels
    first = krylov._VCycle(krylov._hierarchy(A1))
    assert len(first.A) >= 3
    again = first.for_matrix(A1)
    for mine, pyamgs in zip(again.A, first.A):
        np.testing.assert_allclose(mine.toarray(), pyamgs.toarray(), rtol=0, atol=1e-12 * abs(pyamgs).max())
    b = np.random.default_rng(7).standard_normal(A1.shape[0])
    np.testing.assert_allclose(again.apply(b), first.apply(b), rtol=0, atol=1e-10 * np.abs(first.apply(b)).max())

    results, before = [], threads.workers()
    for count in (1, 2):
        threads.set_workers(count)
        try:
            cycle = first.for_matrix(A2)
            results.append([m.toarray() for m in cycle.A] + [cycle.apply(b)])
        finally:
            threads.set_workers(before)
    for one, two in zip(*results):
        np.testing.assert_array_equal(one, two)
    assert cycle.R is first.R and cycle.P is first.P and cycle.A[0] is A2
    coarse = A2.toarray()
    for k, (R, P) in enumerate(zip(first.R, first.P)):
        coarse = R.toarray() @ coarse @ P.toarray()
        np.testing.assert_allclose(cycle.A[k + 1].toarray(), coarse, rtol=0, atol=1e-12 * np.abs(coarse).max())
    row_sums = np.abs(A2.toarray()).sum(axis=1)
    np.testing.assert_allclose(cycle.smoothers[0].scale, krylov.SMOOTHER_OMEGA / row_sums, rtol=1e-14)
    # the cycle's matrix (its columns) on a smaller pair: symmetric to rounding, positive definite
    small = krylov._VCycle(krylov._hierarchy(_weighted_laplacian(34, 0))).for_matrix(_weighted_laplacian(34, 1))
    M = np.column_stack([small.apply(e) for e in np.eye(small.A[0].shape[0])])
    np.testing.assert_allclose(M, M.T, rtol=0, atol=1e-12 * np.abs(M).max())
    assert len(small.A) >= 2 and np.linalg.eigvalsh((M + M.T) / 2).min() > 0


def test_a_first_solves_hierarchy_is_fitted_to_the_second_solves_matrix(monkeypatch):
    """The level's second Gauss-Newton matrix (other weights, one pattern): the hierarchy made in the first solve has
    its level matrices made again from it, not a set-up, and CG converges within two iterations of a hierarchy of its
    own, where the first matrix's levels took ten times as many. Later matrices keep the hierarchy as it is."""
    from nlipscalib.solver.options import SolverOptions

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    A1, A2 = _weighted_laplacian(60, 0), _weighted_laplacian(60, 1)
    A3 = (A2 + 1e-2 * sp.identity(A2.shape[0])).tocsr()  # a step later: closer
    x_true = np.random.default_rng(8).standard_normal(A2.shape[0])
    b = A2 @ x_true
    rtol = 1e-8
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=0))
    pcg.solve(A1, A1 @ x_true, rtol)
    first = pcg.amg
    x, iters = pcg.solve(A2, b, rtol)
    assert (pcg.setups, pcg.refreshes) == (1, 1) and pcg.amg is not first and pcg.amg.R is first.R
    assert np.linalg.norm(A2 @ x - b) <= rtol * np.linalg.norm(b)
    assert np.linalg.norm(x - x_true) <= 1e-5 * np.linalg.norm(x_true)

    def iterations(M: spla.LinearOperator) -> int:
        iterates = []
        _, status = spla.cg(A2, b, rtol=rtol, M=M, callback=iterates.append, maxiter=1000)
        assert status == 0
        return len(iterates)

    own = iterations(krylov._amg_cycle(A2).operator())
    stale = iterations(first.operator())
    assert iters <= own + 2 and stale > 10 * iters
    second = pcg.amg
    x, _ = pcg.solve(A3, A3 @ x_true, rtol)  # the third matrix: the hierarchy kept as it is
    assert pcg.amg is second and (pcg.setups, pcg.refreshes, pcg.solves) == (1, 1, 3)
    assert np.linalg.norm(A3 @ x - A3 @ x_true) <= rtol * np.linalg.norm(A3 @ x_true)


def test_a_drifted_hierarchy_is_fitted_to_the_next_matrix_once_then_made_again(monkeypatch):
    """A hierarchy that drifted (its CG residual falling by less than DRIFT_RATE per iteration) has its level matrices
    made again from the next solve's matrix, its aggregates kept, not a set-up; one that drifts again after such a
    fit is set up anew at the next solve. Every solve reaches its tolerance."""
    from nlipscalib.solver.options import SolverOptions

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    monkeypatch.setattr(krylov, "DRIFT_RATE", 0.0)  # every AMG solve of 4 iterations or more counts as drifted
    matrices = [_weighted_laplacian(40, seed) for seed in range(6)]
    x_true = np.random.default_rng(3).standard_normal(matrices[0].shape[0])
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=0))
    counts, kept = [], []
    for A in matrices:
        b = A @ x_true
        x, iters = pcg.solve(A, b, 1e-8)
        assert iters >= 4 and np.linalg.norm(A @ x - b) <= 1e-8 * np.linalg.norm(b)
        counts.append((pcg.setups, pcg.refreshes))
        kept.append(pcg.amg is not None)
    # set up, drifted: fitted at the next solve, drifted again: set up anew at the next, ... (the third solve's
    # hierarchy is fitted at the fourth although it was not made in the level's first solve)
    assert counts == [(1, 0), (1, 1), (2, 1), (2, 2), (3, 2), (3, 3)]
    assert kept == [True, False, True, False, True, False]


def test_a_hierarchy_that_keeps_converging_is_not_fitted_after_the_second_solve():
    """Without a drift (the default DRIFT_RATE, matrices a step apart), the hierarchy is fitted once (to the second
    solve's matrix) and then kept as it is."""
    from nlipscalib.solver.options import SolverOptions

    A = _weighted_laplacian(40, 0)
    steps = [A, (A + 1e-2 * sp.identity(A.shape[0])).tocsr(), (A + 2e-2 * sp.identity(A.shape[0])).tocsr()]
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=0))
    for M in steps:
        pcg.solve(M, np.ones(M.shape[0]), 1e-6)
    assert (pcg.setups, pcg.refreshes) == (1, 1)


def test_a_first_solves_hierarchy_is_not_fitted_to_its_own_matrix_again():
    from nlipscalib.solver.options import SolverOptions

    A = _weighted_laplacian(30, 0)
    b = np.ones(A.shape[0])
    pcg = krylov.Krylov(SolverOptions(cg_jacobi_iters=0))
    pcg.solve(A, b, 1e-6)
    first = pcg.amg
    pcg.solve(A, b, 1e-8)
    assert pcg.amg is first and (pcg.setups, pcg.refreshes) == (1, 0)


def test_the_background_import_of_pyamg_imports_it_and_keeps_a_failure_off_its_thread(monkeypatch):
    """``nlips solve`` imports pyamg beside the press's loading: the thread leaves the module imported; an import
    that fails raises nothing on the thread (no traceback printed there), the set-up's own import raises it."""
    import sys
    import threading

    import pytest

    thread = krylov.import_amg_in_background()
    thread.join()
    assert "pyamg" in sys.modules and not thread.daemon
    failures = []
    monkeypatch.setattr(threading, "excepthook", failures.append)
    monkeypatch.setitem(sys.modules, "pyamg", None)  # import pyamg now raises ImportError
    krylov.import_amg_in_background().join()
    assert failures == []
    with pytest.raises(ImportError):
        krylov._hierarchy(sp.identity(4, format="csr"))


def test_importing_the_solver_imports_no_scipy():
    """``import nlipscalib.solver`` leaves SciPy to the functions that use it (a reused result's ``nlips solve``
    never waits for its import); pyamg's background import brings what a solve needs."""
    import subprocess
    import sys
    from pathlib import Path

    code = (
        "import sys, nlipscalib.solver\n"
        "assert not [m for m in sys.modules if m.split('.')[0] in ('scipy', 'pyamg')], 'scipy imported'\n"
        "from nlipscalib.solver import krylov\n"
        "krylov.import_amg_in_background().join()\n"
        "assert {'scipy.sparse', 'scipy.sparse.linalg', 'pyamg'} <= set(sys.modules), 'not imported'\n"
    )
    root = Path(krylov.__file__).parents[2]  # the checkout under test: `python -c` imports from its directory
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root)
    assert done.returncode == 0, done.stderr


def _scipy_cg(A: sp.csr_matrix, b: np.ndarray, x0, rtol: float, maxiter: int, M: spla.LinearOperator):
    """SciPy's cg as Krylov ran it before :func:`krylov.pcg`: (x, status, iterations)."""
    count = []
    x, status = spla.cg(A, b, x0=x0, rtol=rtol, maxiter=maxiter, M=M, callback=count.append)
    return x, status, len(count)


def test_pcg_is_scipys_cg_bit_for_bit_on_one_or_two_threads(monkeypatch):
    """:func:`krylov.pcg` moves SciPy's vector updates and the cycle's finest-level work into the products' row
    blocks: the same iterates to the last bit as SciPy's ``cg`` with the cycle's (or Jacobi's) operator, converged
    or stopped at its cap, from zero or from a start, on one thread or two (row blocks of 1000 rows here)."""
    from nlipscalib.solver import threads

    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    A = _weighted_laplacian(60, 3)  # 3600 rows: an l1-Jacobi finest level and coarser ones
    rng = np.random.default_rng(6)
    b, x0 = rng.standard_normal(3600), rng.standard_normal(3600)
    inv_diag = 1.0 / A.diagonal()
    jacobi = spla.LinearOperator(A.shape, matvec=lambda v: inv_diag * v.ravel(), dtype=np.float64)
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            cycle = krylov._amg_cycle(A)
            assert cycle.fused and len(cycle.levels) >= 3
            assert len(threads.RowBlocks(A).blocks) == (2 if count == 2 else 0)
            for start in (None, x0):
                for rtol, cap in ((1e-6, 200), (1e-12, 5)):  # converged; stopped at the cap
                    ours = krylov.pcg(threads.RowBlocks(A), b, start, rtol, cap, cycle)
                    theirs = _scipy_cg(A, b, start, rtol, cap, cycle.operator())
                    assert ours[1:] == theirs[1:] and (ours[1] == 0) == (rtol == 1e-6)
                    np.testing.assert_array_equal(ours[0], theirs[0])
                    ours = krylov.pcg(threads.RowBlocks(A), b, start, rtol, cap, krylov._Jacobi(A))
                    theirs = _scipy_cg(A, b, start, rtol, cap, jacobi)
                    assert ours[1:] == theirs[1:]
                    np.testing.assert_array_equal(ours[0], theirs[0])
            assert np.linalg.norm(b - A @ krylov.pcg(threads.RowBlocks(A), b, None, 1e-6, 200, cycle)[0]) <= (
                1e-6 * np.linalg.norm(b)
            )
    finally:
        threads.set_workers(before)


def test_the_fused_cycle_is_the_cycle(monkeypatch):
    """:meth:`_VCycle.finish` after :meth:`_VCycle.begin` on every row block is :meth:`_VCycle.apply`, bit for bit,
    in the hierarchy's single precision; a cycle whose finest level smooths by Gauss-Seidel or that has one level is
    not fused, and its ``finish`` is ``apply``."""
    monkeypatch.setattr(krylov, "SMOOTHER_MIN_ROWS", 1000)
    rng = np.random.default_rng(7)
    for side, fused in ((60, True), (30, False), (10, False)):  # 3600 rows l1-Jacobi; 900 Gauss-Seidel; one level
        cycle = krylov._amg_cycle(_weighted_laplacian(side, 4))
        assert cycle.fused == fused and cycle.levels[0].dtype == np.float32
        for _ in range(2):  # its buffers used again
            r = rng.standard_normal(side * side)
            for rows in (slice(0, 1000), slice(1000, None)):
                cycle.begin(r, rows)
            z = cycle.finish(r).copy()
            assert z.dtype == np.float64
            np.testing.assert_array_equal(z, cycle.apply(r))


def test_the_single_precision_copy_is_astypes_on_one_or_two_threads(monkeypatch):
    """``_single``: the float32 copy AMG is set up from and fitted to, by row blocks on the pool: astype's values,
    indices and row pointers, in arrays of its own."""
    from nlipscalib.solver import threads

    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    A = _weighted_laplacian(50, 8)
    A.data *= np.pi  # values float32 rounds
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            single, expected = krylov._single(A), A.astype(np.float32)
            assert single.dtype == np.float32 and single.has_sorted_indices
            for name in ("data", "indices", "indptr"):
                np.testing.assert_array_equal(getattr(single, name), getattr(expected, name))
                assert not np.shares_memory(getattr(single, name), getattr(A, name))
    finally:
        threads.set_workers(before)


def test_the_amg_set_up_draws_nothing_from_numpys_global_generator():
    """pyamg estimates a smoother's spectral radius from a random start vector of NumPy's global generator; the
    hierarchy weights its smoother from Gershgorin bounds instead, so it draws nothing: no caller needs to seed
    the generator for the same bits, and a notebook's generator is left as it was."""
    import pyamg

    from nlipscalib.solver import krylov

    matrix = pyamg.gallery.poisson((60, 60), format="csr")
    np.random.seed(7)
    untouched = np.random.random()  # the generator's next value had nothing drawn from it
    np.random.seed(7)
    first = krylov._hierarchy(matrix)
    assert np.random.random() == untouched
    second = krylov._hierarchy(matrix)
    assert len(first.levels) == len(second.levels) > 1
    for a, b in zip(first.levels, second.levels):
        assert (a.A != b.A).nnz == 0
