"""LED images that repeat the image before them (a camera whose frames lag the LED switch)."""

import numpy as np

from nlipscalib.core.repeated_frames import repeated_leds
from nlipscalib.core.tolerances import REPEATED_FRAME_DIFFERENCE

H, W, L = 40, 48, 8


def _ring(rng):
    """(L, H, W, 3) linear images of L LEDs around the frame, each brighter towards its side, with 1 % noise."""
    u, v = np.meshgrid(np.linspace(-1, 1, W), np.linspace(-1, 1, H))
    angles = 2 * np.pi * np.arange(L) / L
    light = 0.3 * (1 + 0.4 * (np.cos(angles)[:, None, None] * u + np.sin(angles)[:, None, None] * v))
    return light[..., None].repeat(3, axis=3) * (1 + rng.normal(0, 0.01, (L, H, W, 3)))


def test_distinct_leds_repeat_nothing_and_a_lagged_frame_is_found():
    rng = np.random.default_rng(0)
    gel = np.ones((H, W), bool)
    images = _ring(rng)
    assert repeated_leds(images, gel) == []
    # the frame read for LED 6 was exposed under LED 5: the same light, other noise
    images[5] = images[4] * (1 + rng.normal(0, 0.01, (H, W, 3)))
    found = repeated_leds(images, gel)
    assert [index for index, _ in found] == [5] and found[0][1] < REPEATED_FRAME_DIFFERENCE


def test_a_dark_pair_gives_no_verdict():
    """Two black images (a dead LED after another) are the exposure check's to name, not repeats."""
    images = np.zeros((3, H, W, 3), np.float32)
    images[0] = 0.3
    assert repeated_leds(images, np.ones((H, W), bool)) == []
