import numpy as np
import pytest
import scipy.sparse as sp

from nlipscalib.solver import geometry
from nlipscalib.solver.operators import _make_operators
from nlipscalib.solver.smoothness import Smoothness, cauchy_weights, edge_scale


def _ops():
    mask = np.ones((14, 18), bool)
    mask[5:8, 6:10] = False
    return _make_operators(mask), int(mask.sum())


@pytest.mark.parametrize("scale", [None, 0.05])
def test_the_gradient_is_half_the_energys_and_the_weights_its_gauss_newton_curvature(scale):
    """The solver's convention (its data blocks are halved): gradient_and_weights gives half the energy's gradient,
    and gamma * sum E_j^T diag(w_j) E_j is the energy's halved Gauss-Newton matrix (exact for the squared penalty)."""
    ops, n = _ops()
    rng = np.random.default_rng(3)
    t = rng.normal(scale=0.05, size=n)
    term = Smoothness(ops, 0.7, scale)
    g, w = term.gradient_and_weights(t)
    h = 1e-6
    for i in rng.choice(n, 12, replace=False):
        e = np.zeros(n)
        e[i] = h
        numeric = (term.energy(t + e) - term.energy(t - e)) / (2 * h)
        assert abs(2 * g[i] - numeric) < 1e-6 * max(1.0, abs(numeric))
    H = sum(E.T @ sp.diags(np.broadcast_to(wj, (E.shape[0],))) @ E for E, wj in zip(ops["second"], w))
    if scale is None:  # the squared penalty: the Laplacian's, as before
        np.testing.assert_allclose(H.toarray(), 0.7 * ops["lap"].toarray(), atol=1e-12)
        assert term.energy(t) == pytest.approx(0.7 * float(t @ (ops["lap"] @ t)))
    else:  # the IRLS weights: 1 / (1 + (s / scale)^2) of each second difference
        s_u = ops["second"][0] @ t
        np.testing.assert_allclose(w[0], 0.7 / (1 + (s_u / scale) ** 2))
        assert np.all(w[0] <= 0.7) and H.diagonal().min() > 0


def test_the_edge_preserving_penalty_is_the_square_below_its_scale_and_bends_above():
    """Second differences well under the scale (noise, a smooth indenter) cost what the squared penalty did; a step
    (a relief's wall) costs far less and has a small weight, so the smoothness no longer pulls it flat."""
    ops, n = _ops()
    scale = 0.01
    small = np.linspace(0, 1e-3, n)
    squared, edge = Smoothness(ops, 1.0, None), Smoothness(ops, 1.0, scale)
    assert edge.energy(small) == pytest.approx(squared.energy(small), rel=0.01)
    step = np.where(np.arange(n) % 18 < 9, 0.0, 0.1)
    assert edge.energy(step) < 0.1 * squared.energy(step)
    assert cauchy_weights(np.array([0.0, 0.001, 0.1]), scale).tolist() == pytest.approx([1.0, 1 / 1.01, 1 / 101])


def test_the_edge_scale_is_the_slope_change_times_the_pixels_angle():
    """|C| / |A| is a pixel's angular size (1 / f for a pinhole at its centre): the scale is smoothness_edge times
    that; 0 turns the edge-preserving penalty off."""
    f = 400.0
    q = np.array([[0.0, 0.0, 1.0]])
    qu, qv = np.array([[1 / f, 0.0, 0.0]]), np.array([[0.0, 1 / f, 0.0]])
    A, _, C = geometry.normal_basis(q, qu, qv)
    assert edge_scale(A, C, 0.15) == pytest.approx(0.15 / f)
    assert edge_scale(A, C, 0.0) is None


@pytest.mark.parametrize("value", [-0.1, float("nan")])
def test_a_negative_or_missing_edge_scale_is_refused_in_one_line(value):
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.solver import SolverOptions

    with pytest.raises(ConfigError, match="smoothness_edge"):
        SolverOptions(smoothness_edge=value)
