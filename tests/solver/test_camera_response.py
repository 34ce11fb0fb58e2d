"""A camera that cannot turn its tone curve off, declared in meta.json (``sensor.camera_response: "srgb"``): the
loader undoes the IEC 61966-2-1 curve once, before the dark frame is subtracted, and the capture solves as its
linear twin; an unknown value is one line naming meta.json; an undeclared sRGB capture's warning names the flag.

Why: sRGB captures were named ("not linear in the light") but could not be used: the format had no tone-curve
field, and many UVC webcams cannot switch gamma off (s27 QA walk: 8-bit sRGB twin solved to 15.5 deg)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press, write_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.sensor_response import (
    CAMERA_RESPONSES,
    SensorResponse,
    srgb_to_linear,
    tone_curve_table,
)
from nlipscalib.solver import solve_press
from nlipscalib.solver.led_checks import linearity_notes

from . import synth


def _srgb(linear):
    """The sRGB transfer curve (IEC 61966-2-1), the encoding a webcam applies, of linear values in [0, 1]."""
    linear = np.clip(linear, 0, 1)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


OFFSET = 0.0007
"""The twin's dark offset above its black level, of full scale (s27-webcam2)."""


def _declare(folder, value):
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    meta["sensor"]["camera_response"] = value
    meta["format_version"] = 2
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    return folder


def test_the_inverse_srgb_curve_is_the_standards_and_keeps_black_and_white():
    # IEC 61966-2-1's break point, its mid grey and the ends
    assert srgb_to_linear(0.04045) == pytest.approx(0.04045 / 12.92)
    assert srgb_to_linear(0.5) == pytest.approx(0.214041, abs=1e-6)
    assert srgb_to_linear(0.0) == 0.0 and srgb_to_linear(1.0) == pytest.approx(1.0, abs=1e-15)
    x = np.linspace(0, 1, 1001)
    assert np.abs(srgb_to_linear(_srgb(x)) - x).max() < 1e-12
    assert srgb_to_linear(-0.01) == pytest.approx(-0.01 / 12.92)  # noise under black stays noise, not NaN

    assert tone_curve_table("linear", 256.0, 65520.0) is None
    table = tone_curve_table("srgb", 256.0, 65520.0)
    assert table.dtype == np.uint16 and table.shape == (65536,)
    assert table[256] == 256 and table[65520] == 65520 and table[65535] == 65535  # levels and clipped kept
    assert np.all(np.diff(table.astype(int)) >= 0)  # monotone: no value swaps order
    mid = 256 + (65520 - 256) // 2
    assert table[mid] == pytest.approx(256 + (65520 - 256) * 0.214041, abs=2)
    from nlipscalib.cli.capture import CAMERA_RESPONSES as CAPTURE_CHOICES  # named without numpy for --help

    assert CAMERA_RESPONSES == CAPTURE_CHOICES == ("linear", "srgb")


def test_a_declared_srgb_capture_loads_and_solves_as_its_linear_twin(tmp_path):
    """Both captures have a dark offset (the twin's: 0.07 % of full scale): the curve must be undone before the
    dark frame is subtracted, as the camera applied it to light plus offset."""
    from nlipscalib.core.imageio import read_png16, write_png16

    def with_dark(name, hook, dark):
        folder = synth.make_press(tmp_path / name, lin_hook=hook)
        write_png16(folder / "dark.png", synth.to_stored(np.full(read_png16(folder / "dark.png").shape, dark)))
        return folder

    linear = load_press(with_dark("linear", lambda lin: lin + OFFSET, OFFSET))
    encoded = with_dark("encoded", lambda lin: _srgb(lin + OFFSET), _srgb(OFFSET))
    undeclared = load_press(encoded)
    declared = load_press(_declare(encoded, "srgb"))
    assert declared.response.camera_response == "srgb" and undeclared.response.camera_response == "linear"

    # the curve undone at load, dark frame and every LED image: the linear twin's values to 16-bit rounding
    scale = synth.RESPONSE.white_level - synth.RESPONSE.black_level
    assert np.abs(declared.linear_led_images - linear.linear_led_images).max() < 3 / scale
    assert np.abs(undeclared.linear_led_images - linear.linear_led_images).max() > 0.1  # the encoded values
    assert np.abs(declared.dark.astype(int) - linear.dark).max() <= 1
    table = declared.response.tone_curve()
    assert np.array_equal(declared.tricolor, table[read_png16(encoded / "tricolor.png")])  # undone too
    from nlipscalib.learn.infer import load_tricolor  # nlips infer's own reading of a press folder: alike

    assert np.array_equal(load_tricolor(encoded)[0], declared.linear(declared.tricolor))

    # the linearity check: silent on the declared capture, names the flag on the undeclared one
    assert linearity_notes(declared, range(12)) == []
    said = linearity_notes(undeclared, range(12))
    assert len(said) == 1 and "--camera-response srgb" in said[0] and '"camera_response": "srgb"' in said[0]

    # solved: the declared capture's normals are the linear twin's
    n_lin, n_dec = solve_press(linear).normals, solve_press(declared).normals
    both = np.isfinite(n_lin).all(-1) & np.isfinite(n_dec).all(-1)
    angle = np.degrees(np.arccos(np.clip((n_lin[both] * n_dec[both]).sum(-1), -1, 1)))
    assert both.sum() > 1000 and np.median(angle) < 0.05, np.median(angle)


def test_an_unknown_camera_response_is_one_line_naming_meta_json(tmp_path, capsys):
    folder = _declare(synth.make_press(tmp_path / "p"), "gamma22")
    with pytest.raises(CaptureError, match=r"meta\.json: sensor\.camera_response must be one of 'linear', 'srgb'"):
        load_press(folder)
    assert main(["solve", str(folder), "--no-figures"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(folder / "meta.json") in err[0] and "'gamma22'" in err[0], err


def test_a_declared_curve_is_written_as_format_version_2_and_a_linear_capture_as_before(tmp_path):
    press = load_press(synth.make_press(tmp_path / "p"))
    args = (press.camera, press.leds)
    images = (press.dark, press.led_images, press.tricolor)
    for response, version in ((synth.RESPONSE, 1), (SensorResponse(camera_response="srgb"), 2)):
        folder = write_press(tmp_path / response.camera_response, *args, response, *images)
        meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
        assert meta["format_version"] == version
        # a linear capture's meta.json is what it was before the field (readers before it read it alike)
        assert ("camera_response" in meta["sensor"]) == (version == 2)
        assert load_press(folder).response == response


def test_linear_frames_declared_srgb_are_warned_about(tmp_path):
    """Undoing a curve the frames never had bends them the other way: the default twin's linear sphere1 declared
    sRGB solved to 20 deg without a word (slope 1.57 against the recorded LEDs, linear 0.75)."""
    folder = _declare(synth.make_press(tmp_path / "p"), "srgb")
    said = linearity_notes(load_press(folder), range(12))
    assert len(said) == 1 and "declares the camera's srgb tone curve" in said[0] and "linear already" in said[0]
    assert str(folder) in said[0]
