import numpy as np
import pytest

from nlipscalib.core import led_arrays
from nlipscalib.errors import ShapeError
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
    model = Model(Backend(), q[valid], A, B, C, *led_arrays(leds)[:3], np.ones((L, 3)), np.zeros((L, 3, N)),
                  np.ones((L, 3, N)))
    F, dt, du_, dv_ = model.shading(t, tu, tv, derivatives=True)
    n = geometry.normals_from_gradient(tu, tv, A, B, C)
    ref = led_shading(np.exp(t)[:, None] * q[valid], n, [l.__class__(l.position, l.direction, l.mu) for l in leds])
    np.testing.assert_allclose(F, ref[..., 0], rtol=1e-10, atol=1e-14)
    h = 1e-6
    for d, args in ((dt, (t + h, tu, tv, t - h, tu, tv)), (du_, (t, tu + h, tv, t, tu - h, tv)),
                    (dv_, (t, tu, tv + h, t, tu, tv - h))):
        num = (model.shading(*args[:3]) - model.shading(*args[3:])) / (2 * h)
        np.testing.assert_allclose(d, num, atol=1e-6 * np.abs(d).max())
