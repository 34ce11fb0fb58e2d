"""``indirect.scaled_into``: the outer loop's light on a box, scaled per pixel and zero off the receivers."""

import numpy as np

from nlipscalib.solver import radiosity
from nlipscalib.solver.indirect import scaled_into


def _inputs(rng: np.random.Generator):
    patches = rng.random((3, 4, 5, 3)).astype(np.float32)  # 3 LEDs, 4x5 patches of 4 px
    per_led = radiosity.Upsampled(patches, (16, 20), 4)
    part = (slice(2, 14), slice(3, 18))
    scale = rng.random((12, 15, 3)).astype(np.float32)
    return per_led, part, scale


def test_scaled_into_is_the_scaled_light_zero_where_dark():
    per_led, part, scale = _inputs(np.random.default_rng(0))
    dark = np.zeros((12, 15), bool)
    dark[4:7, 2:9] = True
    out = np.full((3, 12, 15, 3), np.nan, np.float32)
    scaled_into(out, per_led, part, scale, dark)
    expected = scale * np.asarray(per_led)[:, part[0], part[1]]
    expected[:, dark] = 0.0
    np.testing.assert_array_equal(out, expected)


def test_scaled_into_without_dark_pixels_writes_every_pixel():
    # no pixel to zero (an auto ROI's box on the gel): the product alone, every element written
    per_led, part, scale = _inputs(np.random.default_rng(1))
    out = np.full((3, 12, 15, 3), np.nan, np.float32)
    scaled_into(out, per_led, part, scale, np.zeros((12, 15), bool))
    np.testing.assert_array_equal(out, scale * np.asarray(per_led)[:, part[0], part[1]])
