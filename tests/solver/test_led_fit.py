import dataclasses

import numpy as np
import pytest
from scipy import ndimage
from scipy.optimize._numdiff import approx_derivative

from nlipscalib.core.leds import Led
from nlipscalib.solver.led_fit import _led, _LedProblem, disk_model, fit_leds, point_model


def _dome(count: int = 1500):
    """Points and normals of a spherical cap of radius 20 mm, 12-20 mm in front of the camera."""
    rng = np.random.default_rng(2)
    theta, phi = np.arccos(rng.uniform(0.75, 1.0, count)), rng.uniform(0, 2 * np.pi, count)
    normals = -np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)
    return np.array([0.0, 0.0, 32.0]) + 20.0 * normals, normals


TRUE = Led((8.0, -3.0, 4.0), (-0.35, 0.15, 1.0), 1.6, (1.3, 1.0, 0.7))


@pytest.mark.parametrize("model", [point_model, disk_model(1.8)], ids=["point", "disk"])
def test_the_fits_jacobian_is_its_residuals_finite_differences(model):
    """The Jacobian the fit hands scipy (the unknowns, the residual's scale and its used samples) against central
    differences of the fit's own residual, away from the start's values."""
    x, n = _dome()
    img = model(_params(TRUE), x, n)
    ok = np.ones_like(img, bool)
    ok[::7, 1] = False  # rows of some samples' channels left out: the Jacobian's rows must follow the residual's
    problem = _LedProblem.of(TRUE, img, ok, x, n, model)
    params = problem.p0 + np.array([0.1, -0.05, 0.2, 0.3, 0.05, -0.1, 0.4, -0.3, 0.2])
    analytic = problem.jacobian(params)
    numeric = approx_derivative(problem.residual, params, method="3-point")
    assert analytic.shape == numeric.shape == (problem.use.sum(), 9)
    for column in range(9):  # each against its own size (log K's are the images, the position's per mm)
        scale = np.abs(numeric[:, column]).max()
        np.testing.assert_allclose(analytic[:, column], numeric[:, column], atol=1e-6 * scale, rtol=0)


def test_a_disk_fit_from_an_offset_start_recovers_the_disk():
    x, n = _dome()
    model = disk_model(1.8)
    img = model(_params(TRUE), x, n)[None]
    start = Led((8.4, -2.7, 4.3), (-0.25, 0.1, 1.0), 1.2, (1.0, 1.0, 1.0))
    ((params, std, rms),) = fit_leds([start], x, n, img, np.ones_like(img, bool), "cauchy", model)
    fitted = _led(params)
    np.testing.assert_allclose(fitted.position, TRUE.position, atol=1e-6)
    np.testing.assert_allclose(fitted.direction, TRUE.direction, atol=1e-8)
    np.testing.assert_allclose([fitted.mu, *fitted.intensity], [TRUE.mu, *TRUE.intensity], rtol=1e-6)
    assert rms < 1e-9 * img.max() and np.all(np.isfinite(std))


def _params(led: Led) -> np.ndarray:
    d = np.asarray(led.direction)
    return np.array([*np.log(led.intensity), led.mu, np.arccos(d[2]), np.arctan2(d[1], d[0]), *led.position])


def test_an_led_without_a_usable_sample_is_held_at_its_start_and_left_out_of_the_summed_residual():
    """An LED whose image is left out whole (a stale frame in every capture, calibration_bands) has nothing to fit:
    it keeps its start's place, axis and mu, its brightness its start's share of the fitted LEDs' (here the others'
    true 2x), std and rms NaN; the summed squared residual the reflectance searches rank (calibration_term) leaves it
    out (its NaN made every reflectance tried NaN: the twin's stale LED 5 moved the profile's choice from 0.82 to 0.68
    and every other LED by 0.1 mm / 1.5 deg, s32-ledleft)."""
    from nlipscalib.solver.led_fit import summed_squares

    x, n = _dome()
    leds = [TRUE, Led((-8.0, 3.0, 4.0), (0.35, -0.15, 1.0), 1.4, (0.9, 1.1, 1.0)), Led((0.0, 8.0, 4.0), TRUE.direction)]
    bright = [dataclasses.replace(led, intensity=tuple(2 * np.asarray(led.intensity))) for led in leds]
    img = np.stack([point_model(_params(led), x, n) for led in bright])
    ok = np.ones_like(img, bool)
    ok[2] = False
    fitted = fit_leds(leds, x, n, img, ok, "linear")
    params, std, rms = fitted[2]
    np.testing.assert_allclose(params[3:], _params(leds[2])[3:])
    np.testing.assert_allclose(np.exp(params[:3]), 2 * np.asarray(leds[2].intensity), rtol=1e-6)
    assert np.isnan(std).all() and np.isnan(rms)
    assert all(np.isfinite(f[2]) for f in fitted[:2])
    assert summed_squares(fitted) == fitted[0][2] ** 2 + fitted[1][2] ** 2


def test_the_calibration_leaves_out_the_gels_outline_on_a_view_past_it_and_nothing_on_a_gel_filling_view(tmp_path):
    """The outline pixels of a wide view are covered by the gel only in part: their light is below the image model's
    (a whole pixel of surface), and the reflectance profile's plain squared residual, a tenth theirs, chose 1.06x the
    true reflectance and moved the LED disks 0.056 mm along the camera's axis (twin, s36-diskfit). Samples are taken
    from inside the outline only; a gel-filling view keeps every pixel of its stride (the frame's border is no
    outline), so its calibration is unchanged."""
    from nlipscalib.core import Camera, load_press
    from nlipscalib.solver.led_fit import capture_samples
    from nlipscalib.solver.outline import gel_outline

    from . import synth

    wide = Camera.from_fov(64, 48, 175.0, "fisheye", (0.05, -0.01, 0.0, 0.0))  # past the dome's base (78.7 deg)
    press = load_press(synth.make_press(tmp_path / "wide", "none", cam=wide))
    valid = np.isfinite(press.reference.depth)
    assert 0.3 < valid.mean() < 0.95, valid.mean()
    *_, sel = capture_samples(press, press, 12, 1)
    outline = valid & ~ndimage.binary_erosion(valid, np.ones((3, 3)), border_value=1)
    assert outline.sum() > 50 and not (sel & outline).any()
    np.testing.assert_array_equal(sel, valid & ~outline)
    np.testing.assert_array_equal(gel_outline(valid), outline)

    filling = load_press(synth.make_press(tmp_path / "filling", "none", size=(64, 48)))
    full = np.isfinite(filling.reference.depth)
    assert full.all()
    *_, sel = capture_samples(filling, filling, 12, 2)
    grid = np.zeros_like(full)
    grid[::2, ::2] = True
    np.testing.assert_array_equal(sel, grid)
