import numpy as np
import pytest

from nlipscalib.core import led_arrays
from nlipscalib.core.errors import ShapeError
from nlipscalib.solver import geometry
from nlipscalib.solver.kernel import Backend, Model

from . import synth


def test_difference_operators_exact_on_quadratics():
    mask = np.ones((7, 7), bool)
    mask[0, 0] = mask[3, 3] = False  # every edge pixel keeps two neighbours on one side
    v, u = np.mgrid[0:7, 0:7].astype(float)
    f = 0.3 * u**2 + 0.7 * u * v - 0.2 * v**2 + u
    du, dv, ok = geometry.gradient_operators(mask)
    assert ok.all()
    np.testing.assert_allclose(du @ f[mask], (0.6 * u + 0.7 * v + 1)[mask], atol=1e-12)
    np.testing.assert_allclose(dv @ f[mask], (0.7 * u - 0.4 * v)[mask], atol=1e-12)


def test_isolated_pixel_has_no_gradient():
    mask = np.zeros((5, 5), bool)
    mask[1:4, 1] = True
    mask[2, 3] = True
    _, _, ok = geometry.gradient_operators(mask)
    assert not ok.any()
    with pytest.raises(ShapeError):
        geometry.gradient_operators(np.ones((3, 3)))


def test_normals_of_true_depth_match_analytic_normals():
    cam = synth.camera()
    z, _, nrm, valid = synth.surface(cam, "sphere")
    q, qu, qv = geometry.ray_tables(cam)
    A, B, C = geometry.normal_basis(q[valid], qu[valid], qv[valid])
    du, dv, _ = geometry.gradient_operators(valid)
    t = np.log(z[valid])
    n = geometry.normals_from_gradient(du @ t, dv @ t, A, B, C)
    ang = np.degrees(np.arccos(np.clip(np.sum(n * nrm[valid], 1), -1, 1)))
    assert ang.mean() < 0.15
    assert np.all(np.sum(n * q[valid], 1) < 0)  # facing the camera


@pytest.mark.parametrize("every_pixel", [False, True])
def test_masked_basis_is_the_gathered_normal_basis_to_the_bit(every_pixel):
    cam = synth.camera(40, 30)
    _, _, _, valid = synth.surface(cam, "sphere")
    mask = np.ones_like(valid) if every_pixel else valid
    q, qu, qv = geometry.ray_tables(cam)
    got_q, got = geometry.masked_basis(q, qu, qv, mask)
    assert np.array_equal(got_q, q[mask])
    for g, want in zip(got, geometry.normal_basis(q[mask], qu[mask], qv[mask])):
        assert g.shape == want.shape and np.array_equal(g, want)


def test_kernel_matches_led_shading_and_its_derivatives():
    from nlipscalib.core import led_shading

    cam = synth.camera(32, 24)
    leds = synth.ring_leds(jitter=1)
    z, pts, _, valid = synth.surface(cam, "sphere")
    q, qu, qv = geometry.ray_tables(cam)
    A, B, C = geometry.normal_basis(q[valid], qu[valid], qv[valid])
    du, dv, _ = geometry.gradient_operators(valid)
    t = np.log(z[valid])
    tu, tv = du @ t, dv @ t
    L, N = len(leds), int(valid.sum())
    model = Model(
        Backend(), q[valid], A, B, C, *led_arrays(leds)[:3], np.ones((L, 3)), np.zeros((L, 3, N)), np.ones((L, 3, N))
    )
    F, dt, du_, dv_ = model.shading(t, tu, tv, derivatives=True)
    n = geometry.normals_from_gradient(tu, tv, A, B, C)
    ref = led_shading(np.exp(t)[:, None] * q[valid], n, [l.__class__(l.position, l.direction, l.mu) for l in leds])
    np.testing.assert_allclose(F, ref[..., 0], rtol=1e-10, atol=1e-14)
    h = 1e-6
    for d, args in (
        (dt, (t + h, tu, tv, t - h, tu, tv)),
        (du_, (t, tu + h, tv, t, tu - h, tv)),
        (dv_, (t, tu, tv + h, t, tu, tv - h)),
    ):
        num = (model.shading(*args[:3]) - model.shading(*args[3:])) / (2 * h)
        np.testing.assert_allclose(d, num, atol=1e-6 * np.abs(d).max())


def test_normal_matrix_assembly():
    import scipy.sparse as sp

    mask = np.ones((9, 11), bool)
    mask[3:5, 4:7] = False
    du, dv, _ = geometry.gradient_operators(mask)
    n = int(mask.sum())
    eye = sp.identity(n, format="csr")
    E = (du - dv).tocsr()
    rng = np.random.default_rng(0)
    M = rng.normal(size=(3, 3, n))
    M = M + M.transpose(1, 0, 2)
    ops = (eye, du, dv)
    ref = sum(ops[a].T @ sp.diags(M[a, b]) @ ops[b] for a in range(3) for b in range(3)) + 0.3 * (E.T @ E)
    H = geometry.NormalMatrix(ops, [E]).assemble(M, (0.3,))
    assert abs(H - ref).max() < 1e-12 and H.has_sorted_indices
    fixed = geometry.NormalMatrix(ops, [E], fixed=True)  # one sparse map of M instead of two products
    Hf = fixed.assemble(M, (0.3,))
    assert abs(Hf - ref).max() < 1e-12 and Hf.has_sorted_indices
    M[:, :, : n // 2] = 0.0  # unlit pixels: their zeros are left out as the products leave them out
    Hz, Hfz = geometry.NormalMatrix(ops, [E]).assemble(M, (0.3,)), fixed.assemble(M, (0.3,))
    assert abs(Hfz - Hz).max() < 1e-12 and Hfz.nnz == Hz.nnz


def test_the_fixed_pattern_adds_each_weighted_extra_after_the_blocks_to_the_bit():
    """The extras' weights are S's last columns (one product on both cores): each entry of H is its blocks' terms
    summed, then w_1 e_1 added, then w_2 e_2, the bits of adding each weighted extra's values at its positions after
    the blocks' product (the assembly before); weights not given count as 0."""
    import scipy.sparse as sp

    mask = np.ones((13, 17), bool)
    mask[4:7, 5:9] = False
    du, dv, _ = geometry.gradient_operators(mask)
    n = int(mask.sum())
    extras = [(du - dv).tocsr(), (du @ du + dv).tocsr()]
    rng = np.random.default_rng(4)
    M = rng.normal(size=(3, 3, n))
    M = M + M.transpose(1, 0, 2)
    fixed = geometry.NormalMatrix((sp.identity(n, format="csr"), du, dv), extras, fixed=True)
    blocks = fixed.assemble(M)  # weights not given: 0, the extras' entries left out as zeros
    zero = fixed.assemble(M, (0.0, 0.0))
    assert np.array_equal(zero.data, blocks.data) and np.array_equal(zero.indices, blocks.indices)
    weights = (0.37, 2.9e-3)
    H = fixed.assemble(M, weights)
    assert H.nnz > blocks.nnz
    pattern = fixed.fixed
    data = pattern.S[:, : 9 * n] @ M.ravel()  # the blocks' terms alone, on the whole pattern
    rows = np.repeat(np.arange(n), np.diff(pattern.indptr))
    slot = {(i, j): k for k, (i, j) in enumerate(zip(rows, pattern.indices))}
    for E, w in zip(extras, weights):
        EtE = (E.T @ E).tocoo()
        data[[slot[i, j] for i, j in zip(EtE.row, EtE.col)]] += w * EtE.data
    expected = sp.csr_matrix((data, pattern.indices, pattern.indptr), shape=H.shape)
    expected.eliminate_zeros()
    assert np.array_equal(H.data, expected.data) and np.array_equal(H.indices, expected.indices)
    ref = geometry.NormalMatrix((sp.identity(n, format="csr"), du, dv), extras).assemble(M, weights)
    assert abs(H - ref).max() < 1e-12


def test_variable_projection_blocks_match_reduced_jacobian():
    """M and b are J^T W J and J^T W r of the residual with the albedo refitted at every depth."""
    cam = synth.camera(12, 10)
    leds = synth.ring_leds(jitter=2)
    z, _, _, valid = synth.surface(cam, "sphere")
    q, qu, qv = geometry.ray_tables(cam)
    A, B, C = geometry.normal_basis(q[valid], qu[valid], qv[valid])
    du, dv, _ = geometry.gradient_operators(valid)
    pos, dirs, mu, psi = led_arrays(leds)
    L, N = len(leds), int(valid.sum())
    rng = np.random.default_rng(1)
    t_true = np.log(z[valid])
    w = rng.uniform(0.5, 1.0, (L, 3, N))
    model = Model(Backend(), q[valid], A, B, C, pos, dirs, mu, psi, np.zeros((L, 3, N)), np.ones((L, 3, N)))
    # Images of the model itself, depth perturbed: small residuals, where Kaufman's projected
    # Jacobian (which drops a term proportional to the residual) is the reduced problem's own.
    F_true = model.shading(t_true, du @ t_true, dv @ t_true)
    model.images = rng.uniform(0.5, 0.9, (1, 3, N)) * model.psi * F_true[:, None]
    t = t_true + 1e-3 * rng.normal(size=N)

    def reduced(tt):  # residuals with the albedo that minimises the w-weighted data term
        F = model.shading(tt, du @ tt, dv @ tt)
        return model.residuals(F, model.albedo(F, w))

    F, *dF = model.shading(t, du @ t, dv @ t, derivatives=True)
    alb = model.albedo(F, w)
    M, b = model.gauss_newton_blocks(F, dF, reduced(t), w, alb)
    # reduced Jacobian by finite differences along each pixel's own t (the block's (0, 0) entry
    # only couples a pixel with itself through the identity operator, so probe with du = dv = 0)
    h = 1e-6
    for p in (0, N // 2, N - 1):
        e = np.zeros(N)
        e[p] = h
        F_p = model.shading(t + e, du @ t, dv @ t)
        F_m = model.shading(t - e, du @ t, dv @ t)
        J = (model.residuals(F_p, model.albedo(F_p, w)) - model.residuals(F_m, model.albedo(F_m, w)))[:, :, p] / (2 * h)
        r = reduced(t)[:, :, p]
        np.testing.assert_allclose(M[0, 0, p], np.sum(w[:, :, p] * J * J), rtol=1e-3)
        np.testing.assert_allclose(b[0, p], np.sum(w[:, :, p] * J * r), rtol=1e-2)


def test_the_normal_basis_is_numpys_cross_products_to_the_bit():
    rng = np.random.default_rng(3)
    q, qu, qv = (rng.standard_normal((500, 3)) for _ in range(3))
    A, B, C = geometry.normal_basis(q, qu, qv)
    for got, (a, b) in zip((A, B, C), ((q, qv), (qu, q), (qu, qv))):
        np.testing.assert_array_equal(got, np.cross(a, b))


def test_the_grid_stencil_assembles_the_products_matrix_exactly_symmetric():
    """The assembly by the grid's diagonals (``grid=mask``) gives the products' H to rounding, on the same pattern
    (the products' zeros left out alike: unlit pixels), and exactly symmetric, on a mask with holes, a ragged edge
    and one-sided differences; an operator not on the mask's pixels is refused."""
    import scipy.sparse as sp

    from nlipscalib.solver.operators import _make_operators

    rng = np.random.default_rng(11)
    mask = np.ones((21, 26), bool)
    mask[6:9, 5:12] = False
    mask[0, :7] = mask[-1, 15:] = False
    mask[14, 3] = mask[2, 20] = False
    ops = _make_operators(mask)
    n = int(mask.sum())
    pieces = ((sp.identity(n, format="csr"), ops["Du"], ops["Dv"]), ops["second"])
    products = geometry.NormalMatrix(*pieces)
    grid = ops["normal"].make()  # a level's own operators: the grid stencil, made at its first use
    assert grid.stencil is not None and products.stencil is None
    M = rng.normal(size=(3, 3, n))
    M = np.einsum("abn,cbn->acn", M, M)
    weights = (rng.uniform(0.01, 1.0, n), rng.uniform(0.01, 1.0, n))
    for blocks in (M, np.where(np.arange(n) < n // 3, 0.0, M)):  # all lit; a third unlit
        ref, H = products.assemble(blocks, weights), grid.assemble(blocks, weights)
        np.testing.assert_array_equal(H.indptr, ref.indptr)
        np.testing.assert_array_equal(H.indices, ref.indices)
        np.testing.assert_allclose(H.data, ref.data, rtol=1e-12, atol=1e-12 * abs(ref.data).max())
        assert H.has_sorted_indices and (H != H.T).nnz == 0
    with pytest.raises(ShapeError, match="grid stencil"):
        geometry.NormalMatrix(*pieces, grid=np.ones((3, n), bool))
    for small in (np.zeros((4, 4), bool), np.eye(5, dtype=bool), np.pad(np.ones((1, 6), bool), 2)):  # none, lone, a row
        ops, m = _make_operators(small), int(small.sum())
        blocks = np.ones((3, 3, m)) + np.eye(3)[:, :, None]
        ref = geometry.NormalMatrix((sp.identity(m, format="csr"), ops["Du"], ops["Dv"]), ops["second"])
        H, expected = ops["normal"].assemble(blocks, (0.5, 0.5)), ref.assemble(blocks, (0.5, 0.5))
        assert H.shape == (m, m) and np.array_equal(H.indices, expected.indices)
        np.testing.assert_allclose(H.toarray(), expected.toarray(), rtol=1e-12, atol=1e-12)


def test_the_fixed_pattern_assembly_by_row_blocks_is_the_one_product(monkeypatch):
    """Each row block's task makes its part of H (S's product, the indices' copy, the check for zeros): the bits of
    S @ [M, w] in one product, on one thread or two, zeros left out alike; the arrays H's own."""
    import scipy.sparse as sp

    from nlipscalib.solver import threads

    mask = np.ones((30, 40), bool)
    mask[10:14, 12:20] = False
    du, dv, _ = geometry.gradient_operators(mask)
    n = int(mask.sum())
    extra = (du - dv).tocsr()
    rng = np.random.default_rng(9)
    M = rng.normal(size=(3, 3, n))
    M = M + M.transpose(1, 0, 2)
    fixed = geometry.NormalMatrix((sp.identity(n, format="csr"), du, dv), [extra], fixed=True)
    pattern = fixed.fixed
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    before = threads.workers()
    try:
        for blocks in (M, np.where(np.arange(n) < n // 3, 0.0, M)):  # all lit; a third unlit (zeros left out)
            data = pattern.S @ np.concatenate([blocks.ravel(), [0.3]])
            expected = sp.csr_matrix((data, pattern.indices.copy(), pattern.indptr.copy()), shape=(n, n))
            expected.eliminate_zeros()
            for count in (1, 2):
                threads.set_workers(count)
                assert len(threads.RowBlocks(pattern.S).blocks) == (2 if count == 2 else 0)
                H = fixed.assemble(blocks, (0.3,))
                for name in ("data", "indices", "indptr"):
                    np.testing.assert_array_equal(getattr(H, name), getattr(expected, name))
                assert not np.shares_memory(H.indices, pattern.indices)
                assert not np.shares_memory(H.indptr, pattern.indptr)
                assert H.has_sorted_indices
    finally:
        threads.set_workers(before)


@pytest.mark.parametrize("way", ["products", "fixed", "grid"])
def test_the_extras_weighted_per_row_are_their_weighted_grams(way, monkeypatch):
    """The edge-preserving smoothness weighs each second difference on its own: H = blocks + sum_j E_j^T diag(w_j)
    E_j with w_j one weight per row, alike in all three assemblies, on one thread or two (R's row blocks beside S's);
    a scalar weight is the array of it."""
    import scipy.sparse as sp

    from nlipscalib.solver import threads

    mask = np.ones((30, 40), bool)
    mask[10:14, 12:20] = False
    du, dv, _ = geometry.gradient_operators(mask)
    n = int(mask.sum())
    extras = [(du - dv).tocsr(), (du @ du + dv).tocsr()]
    rng = np.random.default_rng(5)
    M = rng.normal(size=(3, 3, n))
    M = M + M.transpose(1, 0, 2)
    ops = (sp.identity(n, format="csr"), du, dv)
    weights = (rng.uniform(0.01, 1.0, n), 0.3)
    blocks = sum(ops[a].T @ sp.diags(M[a, b]) @ ops[b] for a in range(3) for b in range(3))
    ref = blocks + extras[0].T @ sp.diags(weights[0]) @ extras[0] + 0.3 * (extras[1].T @ extras[1])
    matrix = geometry.NormalMatrix(ops, extras, fixed=way == "fixed", grid=mask if way == "grid" else None)
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            H = matrix.assemble(M, weights)
            assert abs(H - ref).max() < 1e-12 and H.has_sorted_indices
            scalar = matrix.assemble(M, (np.full(n, 0.3), np.full(n, 0.3)))
            assert abs(scalar - matrix.assemble(M, (0.3, 0.3))).max() < 1e-12
    finally:
        threads.set_workers(before)


def test_the_fixed_pattern_cuts_its_row_blocks_once_per_thread_count(monkeypatch):
    """S's (and R's) row blocks are cut at the first assembly and reused by the next ones of the same thread count
    (a 640x480 map's cut is ~16 MB of fresh memory per block), cut again for another count, and left out of the
    pickle the disk cache stores: every assembly the same bits as a fresh map's."""
    import pickle

    import scipy.sparse as sp

    from nlipscalib.solver import threads

    mask = np.ones((30, 40), bool)
    mask[10:14, 12:20] = False
    du, dv, _ = geometry.gradient_operators(mask)
    n = int(mask.sum())
    extras = [(du - dv).tocsr()]
    M = np.random.default_rng(3).normal(size=(3, 3, n))
    M = M + M.transpose(1, 0, 2)
    ops = (sp.identity(n, format="csr"), du, dv)
    weights = (np.linspace(0.1, 1.0, extras[0].shape[0]),)  # per row: R's blocks too
    monkeypatch.setattr(threads, "PRODUCT_MIN_ROWS", 1000)
    before = threads.workers()
    try:
        threads.set_workers(2)
        matrix = geometry.NormalMatrix(ops, extras, fixed=True)
        first = matrix.assemble(M, weights)
        cut = matrix.fixed._blocks
        assert len(cut[1]) == len(cut[2]) == 2  # S's and R's two row blocks
        again = matrix.assemble(M, weights)
        assert matrix.fixed._blocks is cut  # not cut again
        stored = pickle.loads(pickle.dumps(matrix))
        assert stored.fixed._blocks is None
        fresh = geometry.NormalMatrix(ops, extras, fixed=True).assemble(M, weights)
        for H in (again, stored.assemble(M, weights), matrix.assemble(M, (0.3,))):
            assert not np.shares_memory(H.data, first.data)
        for H in (again, stored.assemble(M, weights)):
            for name in ("data", "indices", "indptr"):
                np.testing.assert_array_equal(getattr(H, name), getattr(fresh, name))
        threads.set_workers(1)
        one = matrix.assemble(M, weights)
        assert matrix.fixed._blocks[0][0] == 1 and len(matrix.fixed._blocks[1]) == 1  # cut again: S whole
        np.testing.assert_array_equal(one.data, fresh.data)
    finally:
        threads.set_workers(before)
