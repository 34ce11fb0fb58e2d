"""``nlips calibrate-camera-response`` end to end on the emulated sensor, whose camera encodes with a curve the
tools are not told (gamma 2.2, an S-shaped vendor curve): the measured curve recovers it, a capture declaring it
loads as a linear camera's, and a bracket that cannot give a curve is one line.

Why: many webcams have neither a gamma-off switch nor the exact sRGB curve; their captures solved wrong."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.response_curve import read_response_file
from nlipscalib.core.tolerances import RESPONSE_ADDITIVITY_ERROR, RESPONSE_CURVE_ERROR
from nlipscalib.device.response_fit import fit_response
from nlipscalib.emulator import EMULATED_TONE_CURVES

SIZE = ["--width", "64", "--height", "48", "--spp", "1"]
LIT_CODES = slice(10, 251)
"""Codes the recovered curve is held to: the darkest few are read noise around black in every bracket."""


def _true_curve(name: str) -> np.ndarray:
    """The light each 8-bit code of the emulated curve ``name`` stands for (its inverse, numerically)."""
    grid = np.linspace(0, 1, 400001, dtype=np.float32)
    encoded = EMULATED_TONE_CURVES[name](grid).astype(np.float64)
    return np.interp(np.arange(256) / 255, encoded, grid.astype(np.float64))


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """Response files of the emulated camera with gamma 2.2 and with the S-shaped vendor curve."""
    folder = tmp_path_factory.mktemp("response")
    out = {}
    for curve in ("gamma2.2", "s-curve"):
        path = folder / f"{curve}.json"
        args = ["calibrate-camera-response", "--emulate", "nlipstac", "--emulate-tone-curve", curve, *SIZE]
        assert main([*args, "--out", str(path)]) == 0
        out[curve] = path
    return out


@pytest.mark.parametrize("curve", ["gamma2.2", "s-curve"])
def test_the_measured_curve_recovers_the_cameras(measured, curve):
    response = read_response_file(measured[curve])
    error = np.abs(np.asarray(response.curve) - _true_curve(curve))[LIT_CODES]
    assert error.max() < RESPONSE_CURVE_ERROR, error.max()
    # against the other emulated curve it is far off: the check can fail (sRGB is within 1 % of gamma 2.2)
    other = _true_curve("s-curve" if curve == "gamma2.2" else "gamma2.2")
    assert np.abs(np.asarray(response.curve) - other)[LIT_CODES].max() > 2 * RESPONSE_CURVE_ERROR
    prov = response.provenance
    assert prov["exposures_ms"][0] == 0.5 and len(prov["exposures_ms"]) == 15 and prov["fit_residual"] < 0.01
    assert prov["monotonic"]["max_dip"] < 0.005 and "Robertson" in prov["method"]
    # one curve for the three channels (they agree within the fit's error): written as before, version 1
    assert (
        prov["per_channel"] is False and json.loads(measured[curve].read_text(encoding="utf-8"))["format_version"] == 1
    )
    assert prov["exposure_ratio_error"] < 0.01 and prov["dark_median_code"] == 0
    # the emulated board's LEDs lit apart and together add with the curve as fitted (0.3-0.4 %): not raised
    assert prov["additivity"]["pairs"] == [[1, 2], [1, 7], [2, 7]] and prov["additivity"]["power"] == 1.0
    assert prov["additivity"]["error"] < RESPONSE_ADDITIVITY_ERROR / 2
    assert measured[curve].with_suffix(".png").stat().st_size > 10_000  # the figure


def test_a_camera_whose_channels_differ_keeps_a_curve_per_channel_and_captures_linear(tmp_path, capsys):
    """The emulated webcam of gamma 2.0 / 2.2 / 2.4 in R / G / B: each channel's curve is kept (response file
    version 2) and undone on its channel (meta.json format_version 3): the capture's LED images agree with a linear
    camera's in every channel. The channels' mean, kept before (s30), is far off red and blue."""
    from nlipscalib.emulator import RGB_GAMMAS

    path = tmp_path / "rgb.json"
    args = ["calibrate-camera-response", "--emulate", "nlipstac", "--emulate-tone-curve", "rgb-gammas", *SIZE]
    assert main([*args, "--out", str(path)]) == 0
    said = capsys.readouterr()  # stdout: the response file alone; the fit, on stderr
    assert said.out == f"{path}\n" and "a curve per channel kept" in said.err
    response = read_response_file(path)
    assert response.provenance["per_channel"] is True and "a curve per channel" in response.provenance["method"]
    assert json.loads(path.read_text(encoding="utf-8"))["format_version"] == 2
    curves = np.asarray(response.curve)
    codes = np.arange(256) / 255
    for c, gamma in enumerate(RGB_GAMMAS):
        assert np.abs(curves[c] - codes**gamma)[LIT_CODES].max() < RESPONSE_CURVE_ERROR
        assert np.abs(curves.mean(axis=0) - codes**gamma)[LIT_CODES].max() > (2 * RESPONSE_CURVE_ERROR if c != 1 else 0)
    base = ["capture", "--emulate", "nlipstac", *SIZE, "--presses", "1", "--yes", "--out"]
    assert main([*base, str(tmp_path / "linear")]) == 0
    declared = ["--emulate-tone-curve", "rgb-gammas", "--camera-response", str(path)]
    assert main([*base, str(tmp_path / "declared"), *declared]) == 0
    meta = json.loads((tmp_path / "declared" / "press_0001" / "meta.json").read_text(encoding="utf-8"))
    assert meta["format_version"] == 3 and meta["sensor"]["camera_response"] == response.name
    linear = _led_images(tmp_path / "linear")
    diff = _led_images(tmp_path / "declared") - linear
    for c in range(3):
        lit = linear[..., c] > 0.02
        assert np.median(np.abs(diff[..., c][lit])) < 0.004 and abs(np.mean(diff[..., c][lit])) < 0.004, c


def _led_images(folder):
    return np.asarray(load_press(folder / "press_0001").linear_led_images)


def test_a_capture_declaring_the_measured_curve_is_linear_as_a_linear_cameras(measured, tmp_path, capsys):
    """The same scene, seed and noise through a linear camera and through gamma 2.2: declared, their LED images
    agree within the noise (the capture's own median noise is ~0.005 of full scale at this size); undeclared,
    they are far apart."""
    base = ["capture", "--emulate", "nlipstac", *SIZE, "--presses", "1", "--yes", "--out"]
    assert main([*base, str(tmp_path / "linear")]) == 0
    gamma = ["--emulate-tone-curve", "gamma2.2"]
    assert main([*base, str(tmp_path / "declared"), *gamma, "--camera-response", str(measured["gamma2.2"])]) == 0
    assert main([*base, str(tmp_path / "undeclared"), *gamma]) == 0
    capsys.readouterr()
    meta = json.loads((tmp_path / "declared" / "press_0001" / "meta.json").read_text(encoding="utf-8"))
    assert meta["sensor"]["camera_response"] == read_response_file(measured["gamma2.2"]).name
    linear = _led_images(tmp_path / "linear")
    lit = linear > 0.02
    declared = _led_images(tmp_path / "declared") - linear
    undeclared = _led_images(tmp_path / "undeclared") - linear
    assert np.median(np.abs(declared[lit])) < 0.004 and abs(np.mean(declared[lit])) < 0.004
    assert np.median(np.abs(undeclared[lit])) > 0.1


@pytest.mark.parametrize(
    "exposures, problem",
    [
        ("1,2,4", "at least 5 different exposures"),
        ("200,300,400,500,600", "are well exposed (0 black, 5 saturated)"),
        ("0.01,0.02,0.03,0.04,0.05", "are well exposed (5 black, 0 saturated)"),
        ("4,5,6,7,8,9", "a curve needs codes from 48 or below"),
    ],
)
def test_a_bracket_that_cannot_give_a_curve_is_one_line(tmp_path, capsys, exposures, problem):
    out = tmp_path / "r.json"
    args = ["calibrate-camera-response", "--emulate", "nlipstac", *SIZE, "--exposures-ms", exposures]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--emulate nlipstac" in err[0] and problem in err[0], err
    assert not out.exists()


def test_a_bracket_whose_light_changed_is_refused_as_not_brightening(measured):
    """Frames of a bracket swapped (the exposure did not follow, the light changed): a longer exposure's frame is
    darker, refused before the fit (whose curve fell; s30-bracket's check names the frames)."""
    codes = np.arange(256, dtype=np.float64)
    light = np.linspace(0.05, 0.4, 64 * 48).reshape(48, 64, 1) * np.ones(3)
    exposures = [0.5 * 2 ** (k / 2) for k in range(15)]
    frames = [
        np.clip(np.rint(255 * np.minimum(light * t / 8, 1) ** (1 / 2.2)), 0, 255).astype(np.uint8) for t in exposures
    ]
    fit = fit_response(frames, exposures, "test bracket")
    assert np.abs(fit.curve - (codes / 255) ** 2.2)[LIT_CODES].max() < RESPONSE_CURVE_ERROR
    frames[6], frames[8] = frames[8], frames[6]
    with pytest.raises(CaptureError, match=r"^test bracket: the bracket's frame at 5\.65\d* ms is darker than at 4 ms"):
        fit_response(frames, exposures, "test bracket")


def test_a_damaged_response_file_given_to_capture_is_one_line_naming_it(measured, tmp_path, capsys):
    doc = json.loads(measured["gamma2.2"].read_text(encoding="utf-8"))
    doc["response_curve"] = doc["response_curve"][:100]
    damaged = tmp_path / "damaged.json"
    damaged.write_text(json.dumps(doc), encoding="utf-8")
    base = ["capture", "--emulate", "nlipstac", *SIZE, "--presses", "1", "--yes", "--out", str(tmp_path / "s")]
    for path, problem in ((damaged, "must have 256 or 65536 entries"), (tmp_path / "none.json", "missing")):
        assert main([*base, "--camera-response", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(path) in err[0] and problem in err[0], err
    assert not (tmp_path / "s").exists()


def test_a_device_capture_records_the_measured_curve_and_refuses_another_black_level(measured, tmp_path, capsys):
    """The curve spans the black level it was measured from to white: a capture at another --black-level is one
    line; at the same, meta.json records the curve's name, its values and how it was measured."""
    import cv2

    from nlipscalib.core import Camera
    from nlipscalib.device.virtual_board import VirtualBoard

    camera = Camera.from_fov(64, 48, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))
    (tmp_path / "camera.json").write_text(json.dumps({"camera": camera.to_dict()}), encoding="utf-8")
    frames = tmp_path / "frames"
    frames.mkdir()
    response = read_response_file(measured["gamma2.2"])
    black = response.provenance["black_level_dn"]  # the emulated camera's, 64 DN of 12 bits
    for k in range(2 * 15):  # as tests/device/test_capture_cli.py: a reference and a press of 12 LEDs
        value = round(black) if k % 15 == 1 else 100 + (k % 15) * (k % 15 != 14)  # the dark frame at the black level
        cv2.imwrite(str(frames / f"{k:03d}.png"), np.full((48, 64, 3), value, np.uint8))
    board = VirtualBoard(12)
    args = ["capture", "--port", board.url, "--camera", str(frames), "--design", "nlipstac", "--yes", "--presses"]
    args += ["1", "--camera-calibration", str(tmp_path / "camera.json"), "--out", str(tmp_path / "s")]
    args += ["--camera-response", str(measured["gamma2.2"])]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"black level at {black:g} DN, --black-level is 0" in err[0], err
    assert main([*args, "--black-level", f"{black:g}"]) == 0, capsys.readouterr().err
    meta = json.loads((tmp_path / "s" / "press_0001" / "meta.json").read_text(encoding="utf-8"))
    assert meta["sensor"]["camera_response"] == response.name
    assert meta["sensor"]["response_curve"] == list(response.curve)
    assert meta["provenance"]["camera_response"]["fit_residual"] == response.provenance["fit_residual"]
    board.close()


def test_a_camera_that_is_no_live_one_is_refused_before_a_bracket(tmp_path, capsys):
    """The exposure of recorded frames cannot be stepped: one line naming --camera, exit 2, the LEDs left off."""
    import cv2

    from nlipscalib.device.virtual_board import VirtualBoard

    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "000.png"), np.full((48, 64, 3), 100, np.uint8))
    board = VirtualBoard(12)
    out = tmp_path / "r.json"
    argv = ["calibrate-camera-response", "--port", board.url, "--camera", str(frames), "--out", str(out)]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"--camera {frames}: a live camera is needed" in err[0], err
    assert err[0].endswith("taken at several exposures with the camera's own tool: --bracket FOLDER, without --port")
    assert not board.latched.any() and not out.exists()
    board.close()


def test_the_emulated_tone_curves_are_the_commands_choices():
    from nlipscalib.cli.camera_response import TONE_CURVE_CHOICES

    assert tuple(EMULATED_TONE_CURVES) == TONE_CURVE_CHOICES


def _emulated_camera(monkeypatch, power: float = 1.0, droop: float = 1.0) -> None:
    """The emulated camera made to take ``0.5 (t / 0.5) ** power`` ms when asked ``t`` and to see LEDs lit together
    at ``droop`` times their drive (:func:`tests.device.fakes.skewed_emulated_camera`)."""
    from nlipscalib import emulator
    from tests.device.fakes import skewed_emulated_camera

    monkeypatch.setattr(emulator, "EmulatedCamera", skewed_emulated_camera(power, droop))


def test_leds_dimmed_two_percent_together_are_refused_not_taken_for_a_power(monkeypatch, tmp_path, capsys):
    """LEDs lit together at 0.98 of their light apart: the curve as fitted misses by 1.7-2.2 %, and the power that
    fits best (1.03) left the pair's two mixes 0.39-0.59 % apart over 50 noise seeds and five curves, under the 0.6 %
    allowed then: the curve was raised by it, ~1 % off, without a word. Clean cameras whose times are a power of the
    asked ones leave them 0.23 % apart at most (200 runs): the 0.3 % now allowed refuses the sagging pair
    (benchmarks/RESULTS.md, s32-devleft)."""
    _emulated_camera(monkeypatch, droop=0.98)
    out = tmp_path / "r.json"
    args = ["calibrate-camera-response", "--emulate", "nlipstac", "--emulate-tone-curve", "gamma2.2", *SIZE]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--emulate nlipstac: with the fitted curve undone, LEDs" in err[0], err
    assert "lit together give 0.98" in err[0] and "the LEDs dim each other when lit together" in err[0]
    assert not out.exists()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_times_a_power_of_the_asked_ones_are_pinned_not_refused_over_noise_seeds(monkeypatch, tmp_path, seed):
    """The false alarm the tighter gap could raise: the emulated camera whose times are ``t ** 0.95`` is pinned
    (its two mixes 0.02-0.23 % apart once raised), its curve back within the fit's error, on any noise seed."""
    _emulated_camera(monkeypatch, power=0.95)
    out = tmp_path / "r.json"
    args = ["calibrate-camera-response", "--emulate", "nlipstac", "--emulate-tone-curve", "gamma2.2", *SIZE]
    assert main([*args, "--seed", str(seed), "--out", str(out)]) == 0
    response = read_response_file(out)
    assert abs(response.provenance["additivity"]["power"] - 0.95) < 0.01
    assert np.abs(np.asarray(response.curve) - _true_curve("gamma2.2"))[LIT_CODES].max() < RESPONSE_CURVE_ERROR
