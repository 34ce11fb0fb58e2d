"""The per-pixel model on cache-sized pixel chunks gives the numbers of the model on all pixels at once."""

import numpy as np
import pytest

from nlipscalib.solver import kernel

from . import synth


@pytest.fixture()
def level():
    """A model's inputs on 1,000 pixels of a dome seen by the default ring (lit, with some shadowed samples)."""
    rng = np.random.default_rng(5)
    n = 1000
    q = np.column_stack([rng.uniform(-0.8, 0.8, (n, 2)), np.ones(n)])
    A = rng.normal(0.0, 0.02, (n, 3))
    B = rng.normal(0.0, 0.02, (n, 3))
    C = np.column_stack([rng.normal(0.0, 1e-4, (n, 2)), np.full(n, 1e-3)])  # N = -C faces the camera
    leds = synth.ring_leds(jitter=1)
    pos = np.array([led.position for led in leds])
    dirs = np.array([led.direction for led in leds])
    mu = np.array([led.mu for led in leds])
    psi = np.array([led.intensity for led in leds])
    images = rng.uniform(0.0, 1.0, (len(leds), 3, n)).astype(np.float32)
    usable = (rng.uniform(size=images.shape) > 0.1).astype(np.float32)
    t = np.log(rng.uniform(12.0, 15.0, n))
    grad = rng.normal(0.0, 1e-3, (2, n))
    return (q, A, B, C, pos, dirs, mu, psi, images, usable), (t, *grad)


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_chunked_model_equals_the_model_on_all_pixels(monkeypatch, level, dtype):
    monkeypatch.setattr(kernel, "CHUNK_PIXELS", 96)  # 11 chunks, the last one partial
    args, (t, tu, tv) = level
    be = kernel.Backend("numpy", dtype)
    whole, chunked = kernel.Model(be, *args), kernel.ChunkedModel(be, *args)
    assert len(chunked.parts) == 11
    F, *dF = whole.shading(t, tu, tv, True)
    Fc, *dFc = chunked.shading(t, tu, tv, True)  # kept in chunks (kernel.Parts), cut alike by the next call
    assert isinstance(Fc, kernel.Parts) and len(Fc.arrays) == 11
    assert (F > 0).mean() > 0.5  # lit: the comparison is between numbers, not zeros
    for a, b in zip([F, *dF], [Fc, *dFc]):
        np.testing.assert_array_equal(a, chunked.whole(b))
    np.testing.assert_array_equal(whole.shading(t, tu, tv), chunked.whole(chunked.shading(t, tu, tv)))
    albedo = np.full((3, len(t)), 0.5, be.dtype)
    r = whole.residuals(F, albedo)
    rc = chunked.residuals(Fc, albedo)
    np.testing.assert_array_equal(r, chunked.whole(rc))
    np.testing.assert_array_equal(r, chunked.whole(chunked.residuals(F, albedo)))  # whole arrays in: the same
    w = whole.weights(r, 0.1, "cauchy")
    wc = chunked.weights(rc, 0.1, "cauchy")
    np.testing.assert_array_equal(w, chunked.whole(wc))
    np.testing.assert_array_equal(whole.albedo(F, w), chunked.whole(chunked.albedo(Fc, wc)))
    np.testing.assert_allclose(whole.data_energy(r, 0.1, "cauchy"), chunked.data_energy(rc, 0.1, "cauchy"), rtol=1e-12)
    np.testing.assert_array_equal(whole.gradient_curvature(dF, albedo, w), chunked.gradient_curvature(dFc, albedo, wc))
    for a, b in zip(
        whole.gauss_newton_blocks(F, dF, r, w, albedo), chunked.gauss_newton_blocks(Fc, dFc, rc, wc, albedo)
    ):
        np.testing.assert_array_equal(a, b)
    # the blocks with the weights made inside, per chunk: the blocks of the weights made first
    for a, b, c in zip(
        whole.gauss_newton_blocks(F, dF, r, w, albedo),
        whole.irls_blocks(F, dF, r, albedo, 0.1, "cauchy"),
        chunked.irls_blocks(Fc, dFc, rc, albedo, 0.1, "cauchy"),
    ):
        np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(a, c)
    for a, b in zip(whole.fit_sums(r, 0.1, "cauchy"), chunked.fit_sums(rc, 0.1, "cauchy")):
        np.testing.assert_array_equal(a, b)
    assert whole.whole(r) is r
    for step in (1, 7, 95, 96, 97, 1000, 10**6):  # the robust scale's subsample, read from the chunks: the same values
        np.testing.assert_array_equal(whole.every(r, step), chunked.every(rc, step))
        np.testing.assert_array_equal(whole.every(r, step), chunked.every(r, step))


def test_large_levels_run_chunked_whatever_the_core_count(monkeypatch, level):
    from nlipscalib.solver import threads

    args, _ = level
    be = kernel.Backend("numpy", "float32")
    monkeypatch.setattr(kernel, "PARALLEL_MIN_PIXELS", 500)
    monkeypatch.setattr(threads, "workers", lambda: 1)
    assert isinstance(kernel.make_model(be, *args), kernel.ChunkedModel)
    monkeypatch.setattr(kernel, "PARALLEL_MIN_PIXELS", 5000)
    assert isinstance(kernel.make_model(be, *args), kernel.Model)


def test_thread_pool_work_nested_in_a_pool_thread_runs_there(monkeypatch):
    from nlipscalib.solver import threads

    monkeypatch.setattr(threads, "workers", lambda: 2)
    out = threads.map_items(lambda i: sum(threads.map_items(lambda j: i * j, range(3))), range(4))
    assert out == [0, 3, 6, 9]


def test_masked_planes_are_the_masked_pixels_per_led_and_channel():
    from nlipscalib.solver.pyramid import masked_planes

    rng = np.random.default_rng(2)
    images = rng.random((4, 9, 11, 3)).astype(np.float32)
    mask = rng.random((9, 11)) > 0.4
    planes = masked_planes(images, mask, np.float32)
    assert planes.flags.c_contiguous and planes.shape == (4, 3, int(mask.sum()))
    np.testing.assert_array_equal(planes, np.moveaxis(images[:, mask], 2, 1))
    usable = masked_planes(images > 0.5, mask, np.float32)  # bool samples cast to the working dtype
    np.testing.assert_array_equal(usable, np.moveaxis(images[:, mask] > 0.5, 2, 1).astype(np.float32))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_cauchy_energy_is_log1p_to_a_few_units_in_the_last_place(dtype):
    """The Cauchy energy's log(1 + x) through the vectorised log: within 4 ulp of log1p, small x included."""
    from nlipscalib.solver import robust

    x = np.concatenate([[0.0], np.logspace(-12, 12, 2001), [np.inf]]).astype(dtype)
    exact = np.log1p(x.astype(np.float64))
    got = robust._log1p(x, np).astype(np.float64)
    finite = np.isfinite(exact)
    ulp = np.spacing(np.abs(exact[finite]).astype(dtype)).astype(np.float64)
    assert np.all(np.abs(got[finite] - exact[finite]) <= 4 * np.maximum(ulp, np.finfo(dtype).tiny))
    assert got[-1] == np.inf and got[0] == 0.0
    lam = 0.03
    r = np.linspace(-1, 1, 101).astype(dtype)
    expected = lam**2 * np.log1p(r * r / lam**2)
    np.testing.assert_allclose(robust.rho(r, lam, "cauchy"), expected, rtol=4 * np.finfo(dtype).eps)


@pytest.mark.parametrize("estimator", ["ls", "cauchy"])
def test_refit_in_one_pass_is_the_sequence_of_its_steps(monkeypatch, level, estimator):
    """Model.refit (and ChunkedModel's, in one pass over the chunks) gives the bits of its steps called one by one:
    weights at the start's residuals (none: the usable samples), albedo, residuals, energy."""
    monkeypatch.setattr(kernel, "CHUNK_PIXELS", 96)
    args, (t, tu, tv) = level
    be = kernel.Backend("numpy", "float32")
    whole, chunked = kernel.Model(be, *args), kernel.ChunkedModel(be, *args)
    F = whole.shading(t, tu, tv)
    start = np.full((3, len(t)), 0.5, be.dtype)
    for alb in (None, start):
        w = whole.usable if alb is None else whole.weights(whole.residuals(F, alb), 0.1, estimator)
        fit = whole.albedo(F, w)
        r = whole.residuals(F, fit)
        energy = whole.data_energy(r, 0.1, estimator)
        one = whole.refit(F, alb, 0.1, estimator, energy=True)
        np.testing.assert_array_equal(one[0], fit)
        np.testing.assert_array_equal(one[1], r)
        assert one[2] == energy
        assert whole.refit(F, alb, 0.1, estimator)[2] is None
        Fc = chunked.shading(t, tu, tv)
        rc = chunked.residuals(
            Fc,
            chunked.albedo(
                Fc, chunked.usable if alb is None else chunked.weights(chunked.residuals(Fc, alb), 0.1, estimator)
            ),
        )
        parts = chunked.refit(Fc, alb, 0.1, estimator, energy=True)
        np.testing.assert_array_equal(chunked.whole(parts[0]), fit)
        np.testing.assert_array_equal(chunked.whole(parts[1]), chunked.whole(rc))
        assert parts[2] == chunked.data_energy(rc, 0.1, estimator)


def test_shortcuts_give_the_general_paths_bits(level):
    """A model whose pixels are all lit and usable, and whose LEDs have mu = 1 and psi = 1, skips the masking and
    the products by 1s: on the same pixels, the model that takes the general path (with a pixel turned away from
    some LEDs, an excluded sample, mu and psi arrays that are 1 but not known to be) gives the same bits."""
    (q, A, B, C, pos, dirs, mu, psi, images, usable), (t, tu, tv) = level
    be = kernel.Backend("numpy", "float32")
    n = len(t)
    ones = np.ones_like(mu), np.ones_like(psi)
    every = np.ones_like(usable)
    with_dark = [np.concatenate([a, a[:1]]) for a in (q, A, B, C, t, tu, tv)]
    with_dark[5][-1] = 50.0  # steep: this pixel faces away from some LEDs
    images_g = np.concatenate([images, images[..., :1]], axis=-1)
    fast = kernel.Model(be, q, A, B, C, pos, dirs, *ones, images, every)
    usable_g = np.concatenate([every, every[..., :1]], -1)
    usable_g[0, 0, -1] = 0  # an excluded sample (on the extra pixel): the general path's usable products
    general = kernel.Model(be, *with_dark[:4], pos, dirs, *ones, images_g, usable_g)
    general.leds.mu_ones = general.psi_ones = False  # the general path: powers and products by the 1s
    assert fast.leds.mu_ones and fast.psi_ones and fast.all_usable and not general.all_usable
    F, *dF = fast.shading(t, tu, tv, True)
    Fg, *dFg = general.shading(*with_dark[4:], True)
    assert (F > 0).all() and (Fg[:, -1] == 0).any() and (Fg[:, -1] > 0).any()
    for a, b in zip([F, *dF], [Fg, *dFg]):
        np.testing.assert_array_equal(a, b[:, :n])
    albedo = np.full((3, n), 0.5, be.dtype)
    albedo_g = np.full((3, n + 1), 0.5, be.dtype)
    r, rg = fast.residuals(F, albedo), general.residuals(Fg, albedo_g)
    np.testing.assert_array_equal(r, rg[..., :n])
    np.testing.assert_array_equal(fast.weights(r, 0.1, "cauchy"), general.weights(rg, 0.1, "cauchy")[..., :n])
    for a, b in zip(fast.refit(F, albedo, 0.1, "cauchy")[:2], general.refit(Fg, albedo_g, 0.1, "cauchy")[:2]):
        np.testing.assert_array_equal(a, b[..., :n])
    blocks = fast.irls_blocks(F, dF, r, albedo, 0.1, "cauchy")
    for a, b in zip(blocks, general.irls_blocks(Fg, dFg, rg, albedo_g, 0.1, "cauchy")):
        np.testing.assert_array_equal(a, b[..., :n])
    for a, b in zip(fast.fit_sums(r, 0.1, "cauchy"), general.fit_sums(rg, 0.1, "cauchy")):
        np.testing.assert_array_equal(a, b[:n])
