import numpy as np
import pytest

from nlipscalib.core.leds import Led, led_shading, tricolor_groups
from nlipscalib.errors import ConfigError


def test_shading_known_answer_directly_below_led():
    # LED 10 mm in front of a plane facing it, pointing straight at it: (n_s.d)^mu = 1, cos = 1
    led = Led(position=(0, 0, 0), direction=(0, 0, 1), mu=3.0, intensity=(2.0, 1.0, 0.5))
    s = led_shading(np.array([[0.0, 0, 10]]), np.array([[0.0, 0, -1]]), [led])
    np.testing.assert_allclose(s[0, 0], np.array([2.0, 1.0, 0.5]) / 100.0)


def test_shading_anisotropy_and_lambert_cosine():
    led = Led(position=(0, 0, 0), direction=(0, 0, 1), mu=2.0)
    x = np.array([[10.0, 0, 10]])  # 45 deg off the LED axis
    n = np.array([[0.0, 0, -1]])  # plane normal facing the LED side
    r2 = 200.0
    expected = np.cos(np.pi / 4) ** 2 * np.cos(np.pi / 4) / r2
    np.testing.assert_allclose(led_shading(x, n, [led])[0, 0, 0], expected, rtol=1e-12)


def test_shading_is_zero_in_attached_shadow():
    led = Led(position=(0, 0, 0))
    s = led_shading(np.array([[0.0, 0, 10]]), np.array([[0.0, 0, 1]]), [led])
    assert np.all(s == 0)


def test_tricolor_groups_nlipstac_and_general():
    g = tricolor_groups(12)
    assert list(g) == [0] * 4 + [1] * 4 + [2] * 4
    assert sorted(set(tricolor_groups(7))) == [0, 1, 2]
    with pytest.raises(ConfigError):
        tricolor_groups(2)


def test_led_validation():
    with pytest.raises(ConfigError, match="direction"):
        Led(position=(0, 0, 0), direction=(0, 0, 0))
    with pytest.raises(ConfigError, match="position"):
        Led(position=(0, 0))
    d = Led(position=(1, 2, 3), direction=(0, 0, 2)).to_dict()
    assert Led.from_dict(d).direction == (0.0, 0.0, 1.0)
