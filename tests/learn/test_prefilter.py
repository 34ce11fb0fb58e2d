"""The tri-colour prefilter: normalised over the gel, windows identical to the full frame, noise cut."""

import numpy as np
import pytest

from nlipscalib.core.errors import ShapeError
from nlipscalib.learn.prefilter import Prefilter, kernel_radius


def _disc(h=60, w=80):
    rows, cols = np.mgrid[0:h, 0:w]
    return (rows - h / 2) ** 2 + (cols - w / 2) ** 2 < (0.45 * h) ** 2


def test_a_constant_gel_stays_constant_up_to_its_edge_whatever_lies_outside():
    valid = _disc()
    image = np.full(valid.shape + (3,), 0.4, np.float32)
    image[~valid] = np.nan  # off the gel: nothing, not even NaN, leaks in
    out = Prefilter(valid, 1.5)(image)
    np.testing.assert_allclose(out[valid], 0.4, rtol=1e-5)


@pytest.mark.parametrize(
    "rows, cols",
    [
        (slice(0, 60), slice(0, 80)),
        (slice(20, 31), slice(30, 47)),
        (slice(0, 5), slice(70, 80)),
        (slice(57, 60), slice(0, 3)),
    ],
)
def test_a_window_equals_the_same_pixels_of_the_whole_filtered_frame(rows, cols):
    valid = _disc()
    image = np.random.default_rng(0).random(valid.shape + (3,)).astype(np.float32)
    pre = Prefilter(valid, 1.0)
    np.testing.assert_allclose(pre(image, rows, cols), pre(image)[rows, cols], rtol=0, atol=1e-6)


def test_white_noise_shrinks_as_the_gaussian_weights_say():
    sigma = 1.0
    valid = np.ones((200, 200), bool)
    noise = np.random.default_rng(1).normal(0, 1, (200, 200, 3)).astype(np.float32)
    out = Prefilter(valid, sigma)(noise)[10:-10, 10:-10]
    expected = 1 / (2 * np.sqrt(np.pi) * sigma)  # root sum of squared weights of a 2D Gaussian
    assert abs(out.std() / expected - 1) < 0.08


def test_sigma_zero_passes_frames_unchanged_and_bad_sigmas_are_refused():
    valid = _disc()
    image = np.random.default_rng(2).random(valid.shape + (3,)).astype(np.float32)
    np.testing.assert_array_equal(Prefilter(valid, 0.0)(image), image)
    assert kernel_radius(0.0) == 0 and kernel_radius(1.0) == 3
    for bad in (-1.0, float("nan")):
        with pytest.raises(ShapeError, match="sigma"):
            Prefilter(valid, bad)
    with pytest.raises(ShapeError, match="does not match"):
        Prefilter(valid, 1.0)(image[:10])
