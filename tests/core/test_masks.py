"""core.masks (OpenCV) gives scipy.ndimage's binary erosion, dilation, hole filling and 4-connected components."""

import numpy as np
import pytest
from scipy import ndimage

from nlipscalib.core import masks


@pytest.fixture
def mask():
    rng = np.random.default_rng(4)
    m = ndimage.uniform_filter(rng.uniform(size=(61, 83)), 5) > 0.52  # blobs, some touching the border
    m[0, :10] = True
    return m


@pytest.mark.parametrize("iterations", [1, 2, 4])
def test_erosion_and_dilation_match_scipy_ndimage(mask, iterations):
    np.testing.assert_array_equal(masks.erode(mask, iterations), ndimage.binary_erosion(mask, iterations=iterations))
    np.testing.assert_array_equal(masks.dilate(mask, iterations), ndimage.binary_dilation(mask, iterations=iterations))
    assert masks.erode(mask).dtype == bool and masks.erode(mask).shape == mask.shape


def test_dilation_by_the_square_matches_scipy_ndimage_with_its_structure(mask):
    square = ndimage.binary_dilation(mask, np.ones((3, 3), bool))
    np.testing.assert_array_equal(masks.dilate(mask, 1, structure=masks.SQUARE), square)
    assert (square & ~masks.dilate(mask)).any()  # the diagonals the cross leaves out


def test_components_match_scipy_ndimage_labels(mask):
    labels, sizes = masks.components(mask)
    ref, count = ndimage.label(mask)
    assert len(sizes) == count > 3
    assert sorted(sizes) == sorted(ndimage.sum(mask, ref, np.arange(1, count + 1)).astype(int))
    # the same partition: each of our components is exactly one of scipy's
    for k in range(1, count + 1):
        assert len(np.unique(ref[labels == k])) == 1
    assert ((labels > 0) == mask).all()
    empty_labels, empty_sizes = masks.components(np.zeros((4, 5), bool))
    assert len(empty_sizes) == 0 and not empty_labels.any()


def test_holes_are_filled_as_scipy_ndimage_fills_them(mask):
    holed = ~mask  # the blobs' complement: holes where blobs lie inside, none where they touch the border
    filled = masks.fill_holes(holed)
    np.testing.assert_array_equal(filled, ndimage.binary_fill_holes(holed))
    assert (filled & ~holed).any() and filled.dtype == bool
    ring = np.zeros((9, 9), bool)
    ring[2:7, 2:7], ring[4, 4] = True, False
    assert masks.fill_holes(ring)[4, 4] and not masks.fill_holes(ring)[0, 0]
    open_ring = ring.copy()
    open_ring[4, 2:5] = False  # a channel of off pixels to the outside: no hole
    np.testing.assert_array_equal(masks.fill_holes(open_ring), open_ring)


def test_sample_grid_is_the_coarsest_regular_grid_with_enough_pixels():
    from nlipscalib.core.masks import sample_grid

    mask = np.ones((480, 640), bool)
    grid = sample_grid(mask, 20_000)  # every 4th row and column: 19,200, too few; every 4th row, 2nd column
    assert grid.sum() == 38_400 and grid[::4, ::2].all() and not grid[1::4].any() and not grid[:, 1::2].any()
    assert sample_grid(mask, 19_000).sum() == 19_200
    small = np.zeros((72, 96), bool)
    small[10:60, 20:80] = True
    assert np.array_equal(sample_grid(small, 20_000), small)  # fewer than asked: all of it
    assert not (sample_grid(small, 500) & ~small).any()  # never outside the mask
