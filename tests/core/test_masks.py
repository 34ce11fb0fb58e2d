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


@pytest.mark.parametrize("radius", [0, 1, 4])
def test_closing_is_scipy_ndimages_by_a_disc_with_nothing_beyond_the_image(mask, radius):
    import cv2

    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1)).astype(bool)
    padded = ndimage.binary_closing(np.pad(mask, radius), disc)  # scipy's own erodes the image's border in
    closed = masks.close(mask, radius)
    np.testing.assert_array_equal(closed, padded[radius : radius + mask.shape[0], radius : radius + mask.shape[1]])
    assert closed.dtype == bool and closed.shape == mask.shape and not (mask & ~closed).any()


def test_closing_fills_a_notch_narrower_than_its_disc_and_keeps_a_wider_one():
    square = np.zeros((40, 40), bool)
    square[5:35, 5:35] = True
    narrow, wide = square.copy(), square.copy()
    narrow[18:24, 5:15] = False  # 6 px wide, 10 deep, open to the outside: no hole
    wide[15:25, 5:15] = False  # 10 px wide: wider than the 9 px disc
    np.testing.assert_array_equal(masks.fill_holes(narrow), narrow)  # what hole filling leaves
    closed = masks.close(narrow, 4)
    assert closed[18:24, 6:15].all() and not closed[18:24, 5].any()  # but the mouth's column: the disc reaches it
    assert (closed & ~narrow).sum() == 6 * 9 and not (closed & ~square).any()
    closed = masks.close(wide, 4)
    assert not closed[15:25, 5:11].any() and not (closed & ~square).any()  # its inner corners rounded only


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
