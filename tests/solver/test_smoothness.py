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


def test_about_a_prior_the_penalty_is_the_deformations():
    """With ``about`` (the level's prior log-depth) the term is the one of t - about: the prior itself costs
    nothing and pulls nowhere, whatever its curvature, for the squared and the edge-preserving penalty alike."""
    ops, n = _ops()
    rng = np.random.default_rng(5)
    curved = 0.02 * (np.arange(n) % 18) ** 2 / 18  # a log-depth curved along u, as a dome's near its base
    t = curved + rng.normal(scale=0.01, size=n)
    for scale in (None, 0.05):
        plain, about = Smoothness(ops, 0.7, scale), Smoothness(ops, 0.7, scale, about=curved)
        assert plain.energy(curved) > 0 and about.energy(curved) == 0.0
        assert not np.any(about.gradient_and_weights(curved)[0])
        assert about.energy(t) == pytest.approx(plain.energy(t - curved), rel=1e-12)
        g_about, w_about = about.gradient_and_weights(t)
        g_plain, w_plain = plain.gradient_and_weights(t - curved)
        np.testing.assert_allclose(g_about, g_plain, rtol=1e-12, atol=1e-15)
        for wa, wp in zip(w_about, w_plain):
            np.testing.assert_allclose(wa, wp)


WIDE_BASE_MM = 8.0
"""The camera's distance below the dome's base in :func:`_wide_dome`: its 130 deg view sees the dome down to it."""


def _wide_dome(centre_shift_mm: float, radius: float):
    """A 64x48 camera 8 mm below the base of a 12 mm hemisphere (inner surface), seen down to its base (black
    corners), 12 default-scene LEDs in the base plane; exact images of a dome shifted ``centre_shift_mm`` along x and
    of ``radius``, against the design's (centred, 12 mm) depth as the prior. (images, camera, LEDs, prior depth,
    true normals)."""
    import math

    from nlipscalib.core import Camera, Led, led_shading

    cam = Camera.from_fov(64, 48, 130.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    omega = cam.rays
    centre = np.array([0.0, 0.0, WIDE_BASE_MM])

    def dome(c: np.ndarray, r: float) -> tuple[np.ndarray, np.ndarray]:
        b = omega @ c
        pts = (b + np.sqrt(b**2 - (c @ c - r**2)))[..., None] * omega  # the far root: the inner surface
        return pts, (c - pts) / r

    design, _ = dome(centre, 12.0)
    pts, normals = dome(centre + [centre_shift_mm, 0.0, 0.0], radius)
    tilt = math.radians(20.0)
    leds = []
    for k in range(12):
        a = 2 * math.pi * k / 12
        direction = (-math.sin(tilt) * math.cos(a), -math.sin(tilt) * math.sin(a), math.cos(tilt))
        leds.append(Led((9 * math.cos(a), 9 * math.sin(a), WIDE_BASE_MM), direction, 1.0, (1.0, 1.0, 1.0)))
    valid = design[..., 2] > WIDE_BASE_MM
    images = led_shading(pts, normals, leds) * 0.8
    images *= 0.7 / np.percentile(images[:, valid], 99.5)
    return images, cam, leds, np.where(valid, design[..., 2], np.nan), normals


def test_a_view_down_to_the_domes_base_solves_its_edge_from_exact_data():
    """Known answer (issue 6): exact images of a dome 0.5 mm off and 0.2 mm larger than the design, seen down to its
    base, solved whole frame against the design's depth. The smoothness of log-depth itself pulled the dome's own
    curvature straight where the light near the base is weak: 7.4 / 3.2 deg mean normal error within 1 / 1-2 px of
    the gel's edge (0.07 deg inside); of the deformation from the prior: 0.22 / 0.07 deg (0.03 inside; the prior's own
    normals are 1.9 deg off there)."""
    from scipy import ndimage

    from nlipscalib.core.metrics import angle_deg
    from nlipscalib.solver import SolverOptions, solve

    images, cam, leds, prior, truth = _wide_dome(0.5, 12.2)
    valid = np.isfinite(prior)
    assert 0.6 < valid.mean() < 0.85  # black corners
    edge = valid & (ndimage.distance_transform_edt(valid) <= 2)

    def edge_error(options: SolverOptions) -> float:
        normals = solve(images, cam, leds, prior_depth=prior, options=options).normals
        return float(angle_deg(normals[edge], truth[edge]).mean())

    prior_normals_off = 1.5  # deg: what the prior alone would give there (1.9)
    assert edge_error(SolverOptions()) < 0.5  # 0.14: "auto" on a view past the gel
    assert edge_error(SolverOptions(smooth_deformation="off")) > 2 * prior_normals_off  # 5.3: the cause


def test_a_gel_filling_view_or_no_prior_surface_keeps_the_smoothness_of_log_depth():
    """The "auto" smoothness takes the deformation only where the camera sees past the gel: a gel-filling view (a
    32x24 crop of the wide camera's middle: all gel) keeps the bits of "off"; so does a solve without a prior depth
    (the nominal distance is a guess, not a surface), even "on"."""
    import dataclasses

    from nlipscalib.solver import SolverOptions, solve

    images, cam, leds, prior, _ = _wide_dome(0.5, 12.2)
    crop = (slice(12, 36), slice(16, 48))
    middle = dataclasses.replace(cam, width=32, height=24, cx=cam.cx - 16, cy=cam.cy - 12)
    filled = prior[crop]
    assert np.isfinite(filled).all()

    def solved(mode: str, prior_depth: np.ndarray | None, mask: np.ndarray | None = None):
        options = SolverOptions(max_iters=3, smooth_deformation=mode)
        return solve(images[:, crop[0], crop[1]], middle, leds, prior_depth=prior_depth, mask=mask, options=options)

    auto, off, on = (solved(mode, filled) for mode in ("auto", "off", "on"))
    np.testing.assert_array_equal(auto.depth, off.depth)
    assert not np.array_equal(on.depth, off.depth)  # "on" is a change
    every = np.ones(filled.shape, bool)
    np.testing.assert_array_equal(solved("on", None, every).depth, solved("off", None, every).depth)


def test_an_unknown_smooth_deformation_is_refused_in_one_line():
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.solver import SolverOptions

    with pytest.raises(ConfigError, match=r"smooth_deformation: must be one of \['auto', 'on', 'off'\], got 'yes'"):
        SolverOptions(smooth_deformation="yes")
