import numpy as np
import pytest

import nlipscalib.core.leds_jacobian as jacobian_module
from nlipscalib.core.leds import Led, disk_shading, led_falloff
from nlipscalib.core.leds_jacobian import falloff_gradient


def _scene(count: int = 400):
    """Points on a bumpy dome-like patch 12-28 mm in front of an LED ring, some behind the LED or facing away."""
    rng = np.random.default_rng(7)
    points = rng.normal(size=(count, 3)) * [7.0, 7.0, 1.5] + [0.0, 0.0, 20.0]
    normals = rng.normal(size=(count, 3)) * 0.5 + [0.0, 0.0, -1.0]
    return points, normals / np.linalg.norm(normals, axis=1, keepdims=True)


def _falloff(points, normals, mu, axis, position, radius):
    led = Led(tuple(position), tuple(axis), max(mu, 0.0))
    return disk_shading(points, normals, (led,), radius)[0, :, 0] if radius else led_falloff(points, normals, (led,))[0]


@pytest.mark.parametrize("radius", [0.0, 1.8])
@pytest.mark.parametrize("mu", [0.0, 1.0, 2.3])
def test_the_falloffs_derivatives_are_its_finite_differences(radius, mu):
    """Known answer: central differences of the model itself (point and disk, whose quadrature points turn with
    its axis), at a position and axis off every symmetry; mu = 0 from above (the model clips mu at 0)."""
    points, normals = _scene()
    axis = np.array([0.25, -0.35, 1.0]) / np.linalg.norm([0.25, -0.35, 1.0])
    position = np.array([6.0, -4.0, 3.0])
    value, gradient = falloff_gradient(points, normals, Led(tuple(position), tuple(axis), mu), radius)
    np.testing.assert_allclose(value, _falloff(points, normals, mu, axis, position, radius), rtol=1e-12)
    assert np.count_nonzero(value) > len(value) // 2 and np.count_nonzero(value == 0) > 0  # lit and unlit points
    h, still = 1e-6, np.zeros(3)

    def central(step_mu=0.0, step_axis=still, step_position=still):
        up = _falloff(points, normals, mu + step_mu, axis + step_axis, position + step_position, radius)
        down = _falloff(points, normals, mu - step_mu, axis - step_axis, position - step_position, radius)
        return (up - down) / 2

    # the axis only along its turns (the model normalises no axis: Led does, on construction)
    across = np.cross(axis, [1.0, 0.0, 0.0])
    across /= np.linalg.norm(across)
    checks = [(gradient[:, 4 + k], central(step_position=h * np.eye(3)[k]) / h) for k in range(3)]
    checks += [(gradient[:, 1:4] @ t, central(step_axis=h * t) / h) for t in (across, np.cross(axis, across))]
    if mu > 0:
        checks.append((gradient[:, 0], central(step_mu=h) / h))
    else:  # forward difference: the derivative from above
        up = _falloff(points, normals, h, axis, position, radius)
        checks.append((gradient[:, 0], (up - value) / h))
    for analytic, numeric in checks:
        scale = np.max(np.abs(numeric))
        assert scale > 0 or (mu == 0 and radius == 0)  # an isotropic point's light does not turn with its axis
        np.testing.assert_allclose(analytic, numeric, atol=2e-6 * scale, rtol=0)


def test_the_gradient_in_blocks_equals_each_point_alone(monkeypatch):
    points, normals = _scene(37)
    led = Led((6.0, -4.0, 3.0), (0.2, -0.3, 1.0), 1.4)
    whole = falloff_gradient(points, normals, led, 1.8)
    monkeypatch.setattr(jacobian_module, "GRADIENT_BLOCK", 7 * 5)  # 5 points a block: eight blocks, one partial
    blocked = falloff_gradient(points, normals, led, 1.8)
    np.testing.assert_allclose(blocked[0], whole[0], rtol=1e-14)
    np.testing.assert_allclose(blocked[1], whole[1], rtol=1e-12, atol=1e-14 * np.abs(whole[1]).max())
