"""A pressed frame given as the sensor's undeformed frame now (``nlips infer --reference``), told from an aged one.

The refresh carried the dent into every later frame without a word (on the 160x120 twin a coin pressed in the
reference tripled the contact error of other presses, s34-inferref); a colour-balance check could not tell a press
from a dimmed LED. Now the change rule and the colour rule must both find one patch (learn.reference_press).
"""

import logging
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.capture import load_press
from nlipscalib.core.imageio import read_png16, write_png16
from nlipscalib.core.leds import tricolor_colors
from nlipscalib.core.press_meta import read_meta
from nlipscalib.core.tolerances import REFERENCE_PRESS_SHARE
from nlipscalib.learn.change import changed_pixels
from nlipscalib.learn.infer import load_tricolor
from nlipscalib.learn.reference_press import colour_patch, press_in_frame
from nlipscalib.sim.press import render_press

from .conftest import HELD_OUT, small_twin


@pytest.fixture(scope="module")
def other_seed(twin_presses, tmp_path_factory):
    """The undeformed dome rendered again with another seed (other noise and samples): a clean frame of the
    calibration's sensor that is not the calibration's frame."""
    folder = tmp_path_factory.mktemp("reference_press") / "reference_s2"
    render_press(small_twin(), None, folder, seed=2)
    return folder


def _frames(twin_presses):
    calibration = load_tricolor(twin_presses / "reference")[0]
    valid = np.isfinite(load_press(twin_presses / "reference").reference.depth)
    return calibration, valid


def _one_led_dimmed(folder, led, gain):
    """The linear tri-colour frame of ``folder`` with LED ``led``'s light times ``gain`` (its own image, scaled onto
    its colour group's share of the tri-colour frame by least squares): one LED aged, the others not."""
    press = load_press(folder)
    frame = load_tricolor(folder)[0].astype(np.float64)
    lit = press.linear(press.led_images).astype(np.float64)  # (L, H, W[, 3])
    colour = int(np.argmax(tricolor_colors(len(press.leds))[led]))
    group = [i for i, c in enumerate(tricolor_colors(len(press.leds))) if c[colour] > 0]
    single = lambda i: lit[i][..., colour] if lit.ndim == 4 else lit[i]  # noqa: E731
    total = sum(single(i) for i in group)
    scale = float((frame[..., colour] * total).sum() / (total * total).sum())
    frame[..., colour] -= (1 - gain) * scale * single(led)
    return frame.astype(np.float32)


def test_a_press_is_found_where_it_is(twin_presses):
    calibration, valid = _frames(twin_presses)
    found = press_in_frame(calibration, load_tricolor(twin_presses / HELD_OUT)[0], valid)
    assert found is not None and found.share >= REFERENCE_PRESS_SHARE
    contact = np.load(twin_presses / HELD_OUT / "gt.npz")["contact"]
    x, y, w, h = found.box
    rows, cols = np.nonzero(contact)
    assert x <= np.median(cols) < x + w and y <= np.median(rows) < y + h
    assert (found.mask & contact).sum() > 0.5 * contact.sum()


def test_clean_and_aged_undeformed_frames_show_no_press(twin_presses, other_seed):
    """Another seed, each colour group dimmed, all darker, one LED at 95 % and 80 %, and noise: none is a press."""
    calibration, valid = _frames(twin_presses)
    frame = load_tricolor(other_seed)[0]
    rng = np.random.default_rng(0)
    noisy = frame + rng.normal(0, 0.02 * np.median(frame[valid]), frame.shape).astype(np.float32)
    aged = [frame, frame * np.float32([0.8, 1, 1]), frame * np.float32([1, 0.95, 0.97]), frame * np.float32(0.8)]
    aged += [_one_led_dimmed(other_seed, led, gain) for led in (0, 4, 8) for gain in (0.95, 0.8)]
    for i, candidate in enumerate([*aged, noisy]):
        assert press_in_frame(calibration, candidate, valid) is None, i


def test_one_led_at_half_its_light_is_no_press_with_the_models_leds(trained, twin_presses, other_seed):
    """A smooth field alone left a patch by an LED at half its light (LED 2: 2.9 % of the gel, LED 8: 2.0 %); the
    LEDs' shares of their colour on the undeformed dome, from the model file, explain it. Presses are still found."""
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.reference_press import LedShares

    calibration, valid = _frames(twin_presses)
    model = load_model(trained)
    leds = LedShares.of_model(model.sensor, model.reference)
    assert leds is not None and len(leds.leds) == 12
    frame = load_tricolor(other_seed)[0]
    for led in (1, 7):
        aged = _one_led_dimmed(other_seed, led, 0.5)
        assert press_in_frame(calibration, aged, valid) is not None  # what the LEDs' shares are for
        assert press_in_frame(calibration, aged, valid, leds) is None, led
    assert press_in_frame(calibration, frame, valid, leds) is None
    for name in ("press_a", HELD_OUT):
        assert press_in_frame(calibration, load_tricolor(twin_presses / name)[0], valid, leds) is not None


def test_a_press_on_a_sensor_whose_red_dimmed_is_still_found(twin_presses):
    """The change rule alone, against the whole gel 20 % less red, found no patch (the press hid in the drift)."""
    calibration, valid = _frames(twin_presses)
    press = load_tricolor(twin_presses / HELD_OUT)[0] * np.float32([0.8, 1, 1])
    assert press_in_frame(calibration, press, valid) is not None


def test_a_scuffed_coating_is_no_press(twin_presses, other_seed):
    """A patch 25 % darker in all three colours (a scuff): the change rule finds it, but its colour did not move."""
    calibration, valid = _frames(twin_presses)
    frame = load_tricolor(other_seed)[0]
    rows, cols = np.mgrid[0 : valid.shape[0], 0 : valid.shape[1]]
    cy, cx = (int(np.median(a[valid])) for a in (rows, cols))
    scuff = 1 - 0.25 * np.exp(-((cols - cx) ** 2 + (rows - cy) ** 2) / (2 * 6.0**2))
    scuffed = frame * scuff[..., None].astype(np.float32)
    assert changed_pixels(scuffed, calibration, valid).sum() > REFERENCE_PRESS_SHARE * valid.sum()
    inside = scuff < 0.95
    assert (colour_patch(calibration, scuffed, valid) & inside).sum() < REFERENCE_PRESS_SHARE * valid.sum()
    assert press_in_frame(calibration, scuffed, valid) is None


def _pressed_copy(twin_presses, out):
    """A copy of a press folder recorded as if it were an undeformed capture (what a user may hand over)."""
    shutil.copytree(twin_presses / "press_a", out)
    return out


def test_infer_refuses_a_pressed_reference_in_one_line_and_takes_it_when_forced(
    trained, twin_presses, tmp_path, capsys, caplog
):
    press, reference = twin_presses / HELD_OUT, _pressed_copy(twin_presses, tmp_path / "ref")
    args = ["infer", str(trained), str(press), "--out", str(tmp_path / "out"), "--figures", "none"]
    assert main([*args, "--reference", str(reference)]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith(f"nlips infer: error: --reference {reference}: shows a press ("), err
    assert "--force-reference" in err[0] and not (tmp_path / "out").exists()
    # a 16-bit tri-colour PNG of it, as captured, alike
    png = tmp_path / "pressed.png"
    write_png16(png, read_png16(reference / read_meta(reference)["images"]["tricolor"]))
    assert main([*args, "--reference", str(png)]) == 2
    assert f"--reference {png}: shows a press" in capsys.readouterr().err
    caplog.set_level(logging.WARNING)
    assert main([*args, "--reference", str(reference), "--force-reference"]) == 0
    assert f"--reference {reference}: shows a press" in caplog.text and "used anyway (--force-reference)" in caplog.text
    assert (tmp_path / "out" / HELD_OUT / "nlipsnet" / "result.npz").is_file()


def test_infer_takes_a_clean_reference_of_another_seed_without_a_word(
    trained, twin_presses, other_seed, tmp_path, caplog
):
    caplog.set_level(logging.WARNING)
    args = ["infer", str(trained), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o"), "--figures", "none"]
    assert main([*args, "--reference", str(other_seed)]) == 0
    assert "shows a press" not in caplog.text


def test_force_reference_without_a_reference_is_refused(trained, twin_presses, capsys):
    assert main(["infer", str(trained), str(twin_presses / HELD_OUT), "--force-reference"]) == 2
    err = capsys.readouterr().err
    assert "--force-reference is for --reference FRAME" in err
