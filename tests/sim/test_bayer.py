"""Known-answer tests of the twin's Bayer camera (sim.bayer): the mosaic, OpenCV's demosaicing, colour crosstalk,
and the scene's switch."""

import numpy as np
import pytest

from nlipscalib.core.errors import ConfigError
from nlipscalib.sim.bayer import (
    BAYER_PATTERNS,
    DEMOSAIC_METHODS,
    IDENTITY_CROSSTALK,
    TYPICAL_CROSSTALK,
    apply_crosstalk,
    bayer_camera,
    bayer_channels,
    mosaic,
)
from nlipscalib.sim.scene import SceneConfig

A = (1000, 20000, 41000)
B = (30000, 5000, 12000)
"""Two colours, 16-bit codes, each channel's step between them of another sign and size."""


def _field(shape: tuple[int, int], colour: tuple[int, int, int]) -> np.ndarray:
    return np.broadcast_to(np.asarray(colour, np.uint16), (*shape, 3)).copy()


def test_the_pattern_is_read_row_by_row_from_the_top_left_pixel():
    assert bayer_channels((2, 2), "RGGB").tolist() == [[0, 1], [1, 2]]
    assert bayer_channels((2, 2), "BGGR").tolist() == [[2, 1], [1, 0]]
    assert bayer_channels((2, 2), "GRBG").tolist() == [[1, 0], [2, 1]]
    assert bayer_channels((3, 5), "GBRG").tolist() == [[1, 2, 1, 2, 1], [0, 1, 0, 1, 0], [1, 2, 1, 2, 1]]


def test_the_mosaic_keeps_each_pixels_own_channel():
    images = np.arange(2 * 4 * 6 * 3, dtype=np.uint16).reshape(2, 4, 6, 3)
    raw = mosaic(images, "RGGB")
    assert raw.shape == (2, 4, 6) and raw.dtype == np.uint16
    assert raw[1, 0, 0] == images[1, 0, 0, 0] and raw[1, 0, 1] == images[1, 0, 1, 1]
    assert raw[1, 1, 0] == images[1, 1, 0, 1] and raw[1, 3, 5] == images[1, 3, 5, 2]


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
def test_a_flat_colour_field_survives_to_the_frames_edges(pattern, method):
    """Each pattern is given to OpenCV under its own name for it (an offset one would swap red and blue, or give
    green for both), and the interpolation of a constant is the constant, the frame's border rows included."""
    field = _field((10, 14), A)
    out = bayer_camera(np.stack([field, _field((10, 14), B)]), pattern, method)
    assert out.dtype == np.uint16
    assert np.array_equal(out[0], field)
    assert np.array_equal(out[1], _field((10, 14), B))


@pytest.mark.parametrize("method", DEMOSAIC_METHODS)
@pytest.mark.parametrize("pattern", BAYER_PATTERNS)
@pytest.mark.parametrize("vertical", [True, False])
def test_an_edge_shows_false_colour_on_its_two_neighbouring_lines_only_and_within_the_step(pattern, method, vertical):
    """A step from colour A to B at column (row) 8: every pixel two or more away from it keeps its colour; the two
    next to it mix the sides (the zipper, false colour) and stay within each channel's step, as an interpolation
    between the two sides; and they do show it (bounded, not absent)."""
    image = _field((16, 16), A)
    if vertical:
        image[:, 8:] = B
    else:
        image[8:] = B
    out = bayer_camera(image, pattern, method).astype(np.int64)
    error = np.abs(out - image)
    per_line = error.max(axis=(0, 2)) if vertical else error.max(axis=(1, 2))
    assert np.all(per_line[[k for k in range(16) if k not in (7, 8)]] == 0)
    assert per_line[7] + per_line[8] > 0
    low, high = np.minimum(A, B), np.maximum(A, B)
    assert np.all(out >= low) and np.all(out <= high)
    assert np.all(error <= high - low)


def test_bilinear_demosaicing_is_linear_in_the_light_and_edge_aware_nearly():
    """The tri-colour check's premise on a Bayer camera: the frame of several LEDs' light is the sum of each LED's
    frame. Bilinear demosaicing keeps it to rounding; the edge-aware one picks its direction from the light itself,
    so only nearly (measured here on two smooth random fields, under 1 % of the light)."""
    rng = np.random.default_rng(3)
    yy, xx = np.mgrid[0:24, 0:32] / 24.0
    a = (12000 * (1 + np.sin(3 * xx + rng.uniform(0, 6, 3)[:, None, None]))).transpose(1, 2, 0)
    b = (9000 * (1 + np.cos(4 * yy + 2 * xx + rng.uniform(0, 6, 3)[:, None, None]))).transpose(1, 2, 0)
    frames = np.rint(np.stack([a, b, a + b])).astype(np.uint16)
    for method, bound in (("bilinear", 2), ("edge_aware", 0.01 * 42000)):
        out = bayer_camera(frames, "RGGB", method).astype(np.int64)
        assert np.abs(out[2] - out[0] - out[1]).max() <= bound


def test_crosstalk_mixes_each_colours_light_into_the_other_channels():
    red = np.zeros((2, 3, 3), np.float32)
    red[..., 0] = 0.5
    assert np.allclose(apply_crosstalk(red, TYPICAL_CROSSTALK)[0, 0], 0.5 * np.asarray(TYPICAL_CROSSTALK)[:, 0])
    assert np.array_equal(apply_crosstalk(red, IDENTITY_CROSSTALK), red)
    with pytest.raises(ValueError, match="3x3"):
        apply_crosstalk(red, ((1.0, 0.0), (0.0, 1.0)))


def test_the_scene_records_the_bayer_camera_only_where_it_is_one():
    """Fields at their defaults are left out of the scene's mapping: every press rendered before they existed keeps
    its hash (not rendered again); a Bayer camera is recorded with its pattern and crosstalk."""
    plain = SceneConfig().to_dict()["camera_effects"]
    assert not {"bayer", "demosaic", "crosstalk"} & set(plain)
    webcam = SceneConfig().replace(camera_effects={"bayer": "RGGB", "crosstalk": TYPICAL_CROSSTALK})
    recorded = webcam.to_dict()["camera_effects"]
    assert recorded["bayer"] == "RGGB" and recorded["crosstalk"][1] == list(TYPICAL_CROSSTALK[1])
    assert "demosaic" not in recorded


@pytest.mark.parametrize(
    ("changes", "said"),
    [
        ({"bayer": "RGBG"}, "bayer"),
        ({"crosstalk": ((1.0, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.0))}, "own colour"),
        ({"crosstalk": ((1.0, -0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}, "crosstalk"),
    ],
)
def test_a_wrong_bayer_camera_is_refused_naming_the_field(changes, said):
    with pytest.raises(ConfigError, match=said):
        SceneConfig().replace(camera_effects=changes)


def test_the_twins_capture_of_a_flat_field_is_the_same_through_a_bayer_camera(monkeypatch):
    """sim.press.camera_capture with the noise off and a sharp lens: the dark frame, the LED images and the
    tri-colour frame of light that does not vary over the frame come back as without the mosaic; the LED images'
    noise-free light through the typical crosstalk is the crosstalk of the light."""
    from nlipscalib.sim import press

    scene = SceneConfig().replace(
        camera={"width": 16, "height": 12}, noise={"enabled": False}, camera_effects={"defocus_px": 0.0}
    )
    h, w = scene.camera_model().shape
    light = np.broadcast_to(np.linspace(0.001, 0.004, 12 * 3, dtype=np.float32).reshape(12, 1, 1, 3), (12, h, w, 3))
    monkeypatch.setattr(press, "scene_exposure", lambda scene, tricolor=False: 150.0)  # no render of the dome
    rgb = press.camera_capture(scene, light, seed=0)
    webcam = press.camera_capture(scene.replace(camera_effects={"bayer": "GRBG"}), light, seed=0)
    mixed = press.camera_capture(scene.replace(camera_effects={"crosstalk": TYPICAL_CROSSTALK}), light, seed=0)
    for plain, bayer in zip(rgb[:3], webcam[:3]):
        assert np.array_equal(plain, bayer)
    black = rgb[0].astype(np.float64)
    seen = (mixed[1] - black) / (rgb[1] - black)  # each channel's light over its own, per LED
    expected = (light[:, 0, 0] @ np.asarray(TYPICAL_CROSSTALK).T) / light[:, 0, 0]
    assert np.allclose(seen[:, 0, 0], expected, rtol=3e-3)  # rounding to 12-bit codes


def test_the_tricolour_check_measures_a_bayer_cameras_noise_so_a_clean_press_fits_and_an_exchange_is_named(tmp_path):
    """A Bayer camera's block means keep more noise than a three-colour camera's (each colour interpolated from a
    quarter or half of the pixels), and its demosaicing correlates neighbouring pixels: the noise measured between
    each block's own halves (until s43) was 0.4x the clean misfit, and a clean capture whose blocks keep 4 % was
    warned (3.1 % allowed). Measured between blocks 2 apart it is the clean misfit (within 15 %), the capture fits,
    and led_04 / led_05 exchanged under that noise is still named."""
    from nlipscalib.core import Press
    from nlipscalib.core.leds import tricolor_groups
    from nlipscalib.core.tricolor_check import (
        block_samples,
        captured_tricolor_note,
        channel_misfits,
        gel_samples,
        noise_misfits,
    )
    from tests.core.test_tricolor_check import _noisy_frames

    def webcam(order=range(12)):
        frames, camera, leds, response = _noisy_frames(np.random.default_rng(5), 0.12, order)
        return {name: bayer_camera(frame, "RGGB") for name, frame in frames.items()}, camera, leds, response

    frames, camera, leds, response = webcam()
    images = np.stack([frames[f"led_{i + 1:02d}"] for i in range(12)])
    press = Press(tmp_path, camera, tuple(leds), response, frames["dark"], images, frames["tricolor"], {})
    samples, groups = block_samples(press, gel_samples(None, camera.shape)), tricolor_groups(12)
    misfit = channel_misfits(samples.tricolor, samples.images, groups)
    assert np.max(misfit) > 0.035  # over the 3 % floor: the measured noise decides
    assert np.all(np.abs(noise_misfits(samples, groups) / misfit - 1) < 0.15)
    assert captured_tricolor_note(tmp_path / "clean", frames, camera, leds, response, None) is None
    line = captured_tricolor_note(tmp_path / "swapped", *webcam([0, 1, 2, 4, 3, *range(5, 12)]), None)
    assert line is not None and "with led_04.png (red group) and led_05.png (green) exchanged it fits" in line, line


def test_the_twin_exposes_for_the_light_the_channels_record_with_crosstalk():
    """A camera whose channels record half the light is exposed twice as long (auto exposure on its own frames); a
    crosstalk that brightens only some channels is exposed for the brightest; none leaves the exposure as it was."""
    from nlipscalib.sim.noise import auto_exposure

    y, x = np.mgrid[-3:3:20j, -3:3:20j]
    points = np.stack([x.ravel(), y.ravel(), np.full(x.size, 12.0)], axis=1)
    normals = np.tile([0.0, 0.0, -1.0], (x.size, 1))
    leds = SceneConfig().led_models()
    albedo = (0.8, 0.8, 0.8)
    for tricolor in (False, True):
        plain = auto_exposure(points, normals, leds, albedo, tricolor=tricolor)
        assert auto_exposure(points, normals, leds, albedo, tricolor=tricolor, crosstalk=IDENTITY_CROSSTALK) == (
            pytest.approx(plain, rel=1e-6)
        )
        half = 0.5 * np.eye(3)
        assert auto_exposure(points, normals, leds, albedo, tricolor=tricolor, crosstalk=half) == pytest.approx(
            2 * plain, rel=1e-5
        )
        assert auto_exposure(points, normals, leds, albedo, tricolor=tricolor, crosstalk=TYPICAL_CROSSTALK) < plain
