"""The tri-colour prefilter: normalised over the gel, windows identical to the full frame, noise cut."""

import numpy as np
import pytest

from nlipscalib.core.errors import ShapeError
from nlipscalib.learn.prefilter import Prefilter, kernel_radius
from tests.learn.test_resume import NAMES, TINY, solved  # noqa: F401 (fixture)


def _disc(h=60, w=80):
    rows, cols = np.mgrid[0:h, 0:w]
    return (rows - h / 2) ** 2 + (cols - w / 2) ** 2 < (0.45 * h) ** 2


def test_a_constant_gel_stays_constant_up_to_its_edge_whatever_lies_outside():
    valid = _disc()
    image = np.full(valid.shape + (3,), 0.4, np.float32)
    image[~valid] = np.nan  # off the gel: nothing, not even NaN, leaks in
    out = Prefilter(valid, 1.5)(image)
    np.testing.assert_allclose(out[valid], 0.4, rtol=1e-5)


WINDOWS = [
    (slice(0, 60), slice(0, 80)),
    (slice(20, 31), slice(30, 47)),
    (slice(0, 5), slice(70, 80)),
    (slice(57, 60), slice(0, 3)),
]
"""Windows of the 60x80 test frame: the whole, inside, and touching its edges and corners."""


@pytest.mark.parametrize("rows, cols", WINDOWS)
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


def _wall(h=60, w=80, step=0.3, noise=0.006, seed=3):
    """A gel (disc) of two flat colours either side of a vertical wall at column w // 2, with sensor-like noise."""
    valid = _disc(h, w)
    image = np.full((h, w, 3), 0.5, np.float32)
    image[:, w // 2 :] += step  # the wall: a steep facet's colour differs by far more than the noise
    image += np.random.default_rng(seed).normal(0, noise, image.shape).astype(np.float32)
    return valid, image


def test_the_colour_sigma_keeps_a_walls_colour_out_of_the_flat_gel_beside_it():
    valid, image = _wall()
    beside = (slice(20, 40), slice(38, 40))  # the two columns next to the wall, on its dim side
    gauss = Prefilter(valid, 1.0)(image)[beside]
    edge = Prefilter(valid, 1.0, 0.08)(image)[beside]
    # the Gaussian mixes the bright side in (the pixel next to it gets ~1/4 of the step), the bilateral does not
    assert np.mean(gauss - 0.5) > 0.02
    assert abs(np.mean(edge - 0.5)) < 0.003
    # and on flat gel it still averages the noise: nearly the Gaussian's cut (1 / (2 sqrt(pi)) of the noise)
    flat = valid.copy()
    flat[:, 30:] = False  # the dim side, away from the wall
    assert np.std(Prefilter(valid, 1.0, 0.08)(image)[flat]) < 1.25 * np.std(Prefilter(valid, 1.0)(image)[flat])
    assert np.std(Prefilter(valid, 1.0, 0.08)(image)[flat]) < 0.5 * np.std(image[flat])


def test_the_colour_sigma_leaves_the_gels_outside_out():
    valid = _disc()
    image = np.full(valid.shape + (3,), 0.4, np.float32)
    image[~valid] = np.nan
    np.testing.assert_allclose(Prefilter(valid, 1.5, 0.08)(image)[valid], 0.4, rtol=1e-5)


@pytest.mark.parametrize("rows, cols", WINDOWS)
def test_with_a_colour_sigma_a_window_equals_the_whole_frame_bit_for_bit(rows, cols):
    # OpenCV's float bilateral filter is given a window of another value range than the frame's: its weights must
    # not depend on it (inference filters the changed pixels' window, the dataset the whole frame)
    valid, image = _wall(noise=0.05)
    image[25:35, 10:20] = 0.9  # a window of narrow range beside a frame of wide range
    pre = Prefilter(valid, 1.0, 0.08)
    np.testing.assert_array_equal(pre(image, rows, cols), pre(image)[rows, cols])
    np.testing.assert_array_equal(pre(image, slice(26, 34), slice(12, 18)), pre(image)[26:34, 12:18])


def test_colour_sigma_zero_is_the_gaussian_bit_for_bit_and_bad_colour_sigmas_are_refused():
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.learn.prefilter import check_colour_sigma

    valid, image = _wall()
    np.testing.assert_array_equal(Prefilter(valid, 1.0, 0.0)(image), Prefilter(valid, 1.0)(image))
    for bad in (-0.1, float("nan"), 2.0):
        with pytest.raises(ShapeError, match="colour sigma"):
            Prefilter(valid, 1.0, bad)
        with pytest.raises(ConfigError, match="^smoothing_colour must"):
            check_colour_sigma(bad, "smoothing_colour")


def test_a_colour_sigma_goes_from_the_sampling_options_to_the_samples_the_model_and_inference(solved, tmp_path):  # noqa: F811
    import json

    import torch

    from nlipscalib.core import load_press
    from nlipscalib.learn.dataset import CalibrationDataset, SamplingConfig, build_dataset
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.train import train

    folders = [solved / n for n in NAMES]
    gaussian = SamplingConfig(smoothing_colour=0.0)
    plain = build_dataset(folders, solved / "reference", tmp_path / "plain", gaussian, progress=False)
    edge = build_dataset(folders, solved / "reference", tmp_path / "edge", progress=False)  # the default, 0.08
    # without it the record is as before the option (the keys of older datasets and experiment tasks stay theirs);
    # the default is written out, so it never shares a key with the records made while the default was 0
    assert "smoothing_colour" not in json.loads((plain / "index.json").read_text(encoding="utf-8"))["sampling"]
    assert json.loads((edge / "index.json").read_text(encoding="utf-8"))["sampling"]["smoothing_colour"] == 0.08
    data = CalibrationDataset(edge)
    assert data.smoothing_colour == 0.08 and CalibrationDataset(plain).smoothing_colour == 0.0
    s, press = data.load(NAMES[1]), load_press(solved / NAMES[1])
    valid = data.reference()["valid"]
    colours = Prefilter(valid, data.smoothing_px, 0.08)(press.linear(press.tricolor))
    np.testing.assert_array_equal(s["rgb"], colours[s["pixel"][:, 1], s["pixel"][:, 0]])
    assert not np.array_equal(s["rgb"], CalibrationDataset(plain).load(NAMES[1])["rgb"])
    # the model carries it, inference filters with it, on the CPU path and on the whole-frame device path alike
    model = tmp_path / "m.pt"
    train(data, TINY, model, progress=False)
    assert load_model(model).smoothing_colour == 0.08
    predictor = Predictor(model, depth=False)
    assert predictor.prefilter.colour_sigma == 0.08
    frame = press.linear(press.tricolor)
    cpu = predictor.predict(frame)
    whole = Predictor(model, depth=False, full_frame=True).predict(frame)
    assert cpu.changed.sum() > 20
    np.testing.assert_allclose(whole.normals[cpu.changed], cpu.normals[cpu.changed], atol=1e-4)
    plain_model = tmp_path / "p.pt"
    train(CalibrationDataset(plain), TINY, plain_model, progress=False)
    assert "smoothing_colour" not in torch.load(plain_model, weights_only=True)  # files as before
