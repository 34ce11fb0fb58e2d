"""LED images that repeat the image before them (a camera whose frames lag the LED switch)."""

import numpy as np

from nlipscalib.core.repeated_frames import (
    DarkBand,
    dark_bands,
    dark_candidates,
    dark_lines,
    frame_checks,
    repeated_leds,
)
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


def test_a_band_of_dark_rows_is_found_with_its_rows_and_a_partial_dark_patch_is_not():
    """Samples' light over the modelled light (1 as modelled, 2 % noise) of 4 LEDs on a 120-row frame: LED 2's rows
    0-29 read while it was off (the dark frame's noise), LED 3's rows 60-79 (a global-reset exposure that missed
    it), LED 1's rows 0-59 dark over the left half only (a contact's flank turned away from it: not whole rows)."""
    rng = np.random.default_rng(1)
    rows = np.repeat(np.arange(120), 20)
    cols = np.tile(np.arange(20), 120)
    light = 1 + rng.normal(0, 0.02, (4, rows.size))
    light[2, rows < 30] = rng.normal(0, 0.002, (rows < 30).sum())
    light[3, (rows >= 60) & (rows < 80)] = 0.01
    light[1, (rows < 60) & (cols < 10)] = 0.0
    assert dark_bands(light, rows, 120) == [DarkBand(2, (0, 30), "top"), DarkBand(3, (60, 80), "middle")]
    light[0, rows >= 110] = 0.0  # 10 rows: two bands of five, fewer than DARK_BAND_ROWS
    assert [band.index for band in dark_bands(light, rows, 120)] == [2, 3]
    light[0, rows >= 100] = 0.0
    assert dark_bands(light, rows, 120)[0] == DarkBand(0, (100, 120), "bottom")


def test_rows_dark_in_every_led_image_are_found_by_the_images_alone():
    rng = np.random.default_rng(2)
    gel = np.ones((H, W), bool)
    images = _ring(rng)
    assert frame_checks(images, gel)[2] is None
    images[:, :15] = rng.normal(0, 1e-3, (L, 15, W, 3))  # a readout before any LED lit
    repeated, bands, dark = frame_checks(images, gel)
    assert dark == DarkBand(None, (0, 15), "top") and repeated == [] and bands == []


def test_a_band_of_dark_columns_is_found_as_columns_and_not_as_rows():
    """A camera turned 90 degrees reads the image's columns one after another: LED 1's columns 40-69 read while it
    was off are named as columns (middle); binned by rows the same samples hold no dark band."""
    rng = np.random.default_rng(3)
    rows = np.repeat(np.arange(120), 100)
    cols = np.tile(np.arange(100), 120)
    light = 1 + rng.normal(0, 0.02, (3, rows.size))
    light[1, (cols >= 40) & (cols < 70)] = 0.0
    assert dark_bands(light, cols, 100, "columns") == [DarkBand(1, (40, 70), "middle", "columns")]
    assert dark_bands(light, rows, 120) == []


def test_a_dark_band_of_a_few_rows_is_a_candidate_and_is_found_to_the_pixel_row():
    """Three rows (61-63) of LED 2 read while it was off: too short for the bands of five rows (their 90 % quantile
    stays lit), a candidate band there, and found to the row on samples dense along the rows; one dark row alone,
    or rows dark over half their width (a contact's flank), are not."""
    rng = np.random.default_rng(4)
    rows = np.repeat(np.arange(120), 20)
    light = 1 + rng.normal(0, 0.02, (3, rows.size))
    light[2, (rows >= 61) & (rows < 64)] = 0.0
    assert dark_bands(light, rows, 120) == []
    candidates = dark_candidates(light, rows, 120)
    assert candidates[0].size == 0 and candidates[1].size == 0 and set(candidates[2]) <= {12}
    dense_rows = np.repeat(np.arange(55, 70), 100)
    dense = 1 + rng.normal(0, 0.02, dense_rows.size)
    dense[(dense_rows >= 61) & (dense_rows < 64)] = 0.0
    assert dark_lines(dense, dense_rows, (0, 120), 2) == DarkBand(2, (61, 64), "middle")
    one = np.where((dense_rows >= 62) & (dense_rows < 64), 1 + rng.normal(0, 0.02, dense.size), dense)
    assert dark_lines(one, dense_rows, (0, 120), 2) is None
    half = 1 + rng.normal(0, 0.02, dense_rows.size)
    half[(dense_rows >= 61) & (dense_rows < 64) & (np.arange(dense.size) % 100 < 50)] = 0.0
    assert dark_lines(half, dense_rows, (0, 120), 2) is None
    assert dark_lines(dense, dense_rows, (61, 120), 2, "columns") == DarkBand(2, (61, 64), "left", "columns")


def test_a_few_rows_or_columns_dark_in_every_led_image_are_found_to_the_pixel():
    """Two rows (20-21) of every LED image read while no LED was lit: under the blocks' run of DARK_BAND_ROWS
    (15 pixels) nothing was found (s30-darkcols' leftover); now, as one LED's short band, to the row on the LEDs'
    summed light. Columns at the frame's right (beyond its last whole block) alike; one dark row alone, or rows
    dark over half the width (a contact's shadow from every LED), are not."""
    rng = np.random.default_rng(8)
    gel = np.ones((H, W), bool)
    images = _ring(rng)

    def darkened(*lines):
        dark = images.copy()
        dark[(slice(None), *lines)] = rng.normal(0, 1e-3, dark[(slice(None), *lines)].shape)
        return dark

    assert frame_checks(darkened(slice(20, 22)), gel)[2] == DarkBand(None, (20, 22), "middle")
    assert frame_checks(darkened(slice(0, 3)), gel)[2] == DarkBand(None, (0, 3), "top")
    assert frame_checks(darkened(slice(None), slice(45, 48)), gel)[2] == DarkBand(None, (45, 48), "right", "columns")
    assert frame_checks(darkened(slice(20, 21)), gel)[2] is None
    assert frame_checks(darkened(slice(20, 23), slice(0, 24)), gel)[2] is None


def test_columns_dark_in_every_led_image_are_found_by_the_images_alone():
    rng = np.random.default_rng(5)
    gel = np.ones((H, W), bool)
    images = _ring(rng)
    assert frame_checks(images, gel)[2] is None
    images[:, :, 30:] = rng.normal(0, 1e-3, (L, H, W - 30, 3))  # a camera turned 90 degrees, read before any LED lit
    assert frame_checks(images, gel)[2] == DarkBand(None, (30, 45), "right", "columns")  # to the 5-pixel block


def test_columns_read_before_the_switch_are_named_as_columns_though_some_rows_look_lagged_too():
    """60 % of the columns from the LED image before (a camera turned 90 degrees read across the switch), on a gel
    whose rows lie more to the left the higher they are (an ellipse at 45 degrees): its top rows then lie mostly in
    those columns and their medians look lagged too (the twin's sphere press with half its columns lagged was named
    "rows 0-334 (top)"). The check names the columns, whose every block is the previous light; a band of rows stays
    rows; fresh noise (5 %) in the lagged band changes neither."""
    rng = np.random.default_rng(6)
    h, w = 120, 160
    u, v = np.meshgrid(np.linspace(-1, 1, w), np.linspace(-1, 1, h))
    gel = ((u + v) / 1.4) ** 2 + ((u - v) / 0.7) ** 2 < 1
    angles = 2 * np.pi * np.arange(L) / L
    light = 0.3 * (1 + 0.4 * (np.cos(angles)[:, None, None] * u + np.sin(angles)[:, None, None] * v))
    images = light[..., None].repeat(3, axis=3) * (1 + rng.normal(0, 0.05, (L, h, w, 3)))
    assert frame_checks(images, gel)[:2] == ([], [])
    turned = images.copy()
    turned[3, :, :96] = light[2, :, :96, None] * (1 + rng.normal(0, 0.05, (h, 96, 3)))
    repeated, bands, _ = frame_checks(turned, gel)
    assert repeated == [] and [(b.index, b.axis, b.rows, b.where) for b in bands] == [(3, "columns", (30, 95), "left")]
    rows = images.copy()
    rows[3, :72] = light[2, :72, :, None] * (1 + rng.normal(0, 0.05, (72, w, 3)))
    assert [(b.index, b.axis, b.where) for b in frame_checks(rows, gel)[1]] == [(3, "rows", "top")]


def _ring_with_a_far_rim(rng, width):
    """(12, 60, width, 3) linear images of a 12-LED ring (30 deg apart) whose light, column by column, goes as
    ``1 + r cos(led angle - a)``: over most columns r = 0.5 with ``a`` turning by 90 deg across them (neighbouring LEDs
    up to 25 % apart), over the last twelfth r = 0.06 with ``a`` at LED 7 (index 6): a wide view's far base rim, where
    the LED across the dome lights least and the LEDs either side of it alike (LEDs 7 and 8 0.8 % apart, LEDs 7 and
    9 3 %); 0.2 % noise. The rim spans width / 60 lines of blocks: more, the finer the image."""
    h, count = 60, 12
    angles = 2 * np.pi * np.arange(count) / count
    x = np.arange(width)
    rim = x >= width - width // 12
    r = np.where(rim, 0.06, 0.5)
    a = np.where(rim, angles[6], 0.5 * np.pi * x / width)
    light = 0.3 * (1 + r * np.cos(angles[:, None] - a))  # (12, width)
    images = np.broadcast_to(light[:, None, :, None], (count, h, width, 3))
    return images * (1 + rng.normal(0, 0.002, (count, h, width, 3)))


def test_lines_the_ring_lights_alike_around_the_previous_led_are_no_lag_band_at_any_size():
    """s33-rimband: the next image alone (its contrast with the previous) let 3 or more such lines through once the
    rim spanned more lines of blocks: "led_08.png's columns 290-309 (right) show led_07.png's light" at 320x240."""
    rng = np.random.default_rng(4)
    for width in (240, 480, 960):  # the rim 4, 8 and 16 lines of blocks wide
        images = _ring_with_a_far_rim(rng, width)
        gel = np.ones(images.shape[1:3], bool)
        assert frame_checks(images, gel)[:2] == ([], []), width
        # LED 8's frame read across the switch, its right 3/8 (the rim and past it) still LED 7's light, other
        # noise: found from its first column, named by its columns at the right (the lines where no neighbour tells
        # the lights apart are not counted, so the band named can end before the frame's edge: the solve leaves it
        # out to the edge)
        band = 3 * width // 8
        lagged = images.copy()
        lagged[7][:, -band:] = images[6][:, -band:] * (1 + rng.normal(0, 0.002, (60, band, 3)))
        bands = frame_checks(lagged, gel)[1]
        assert [(found.index, found.axis, found.top) for found in bands] == [(7, "columns", False)], width
        assert bands[0].rows[0] == width - band
