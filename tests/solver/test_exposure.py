"""Black or saturated captures: the solver and the LED calibration say why they cannot use one, and how much of a
capture they left out as saturated (the audit's real_black, real_sat and real_over sessions)."""

import dataclasses
import json
import logging

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.tolerances import SATURATED_SHARE_WARN
from nlipscalib.solver import calibrate_leds, solve_press
from nlipscalib.solver.exposure import dark_frame_fault, saturated_share
from nlipscalib.solver.indirect import fit_indirect

from . import synth
from .twin_helpers import recorded_anew

SIZE = (64, 48)


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    """Undeformed captures at 64x48: exposed as usual, black (no light above the dark frame), saturated (every
    sample at the white level), over-exposed (a third of the gel's samples clipped)."""
    root = tmp_path_factory.mktemp("exposure")
    hooks = {
        "good": None,
        "black": lambda lin: lin * 0.0,
        "saturated": lambda lin: lin + 10.0,
        "over": lambda lin: lin * 2.5,
    }
    return {name: synth.make_press(root / name, "none", size=SIZE, lin_hook=hook) for name, hook in hooks.items()}


def test_no_usable_pixel_says_the_led_images_are_black_or_saturated(captures, tmp_path, capsys):
    """It said "no usable pixel to fit the interreflection term on", and nothing of why."""
    black, sat = load_press(captures["black"]), load_press(captures["saturated"])
    with pytest.raises(CaptureError, match=r"led_01\.png \.\. led_12\.png\) are black \(no light above the dark"):
        fit_indirect(black)
    with pytest.raises(CaptureError, match=r"100 % of the gel's samples in its LED images .* are saturated") as err:
        fit_indirect(sat)
    assert str(captures["saturated"]) in str(err.value) and "--exposure-ms" in str(err.value)
    # the commands, with the interreflection term and without (calibrate-leds then stopped on a numpy traceback)
    for folder, why in ((captures["black"], "are black"), (captures["saturated"], "are saturated")):
        for cmd in (["calibrate-leds", str(folder), "--out", str(tmp_path / "l.json")], ["solve", str(folder)]):
            for mode in ("auto", "off"):
                assert main([*cmd, "--interreflection", mode]) == 2
                err = capsys.readouterr().err.strip().splitlines()
                assert len(err) == 1 and str(folder) in err[0] and why in err[0], (mode, err)


def test_solve_and_calibrate_leds_report_a_large_saturated_share(captures, tmp_path, caplog):
    """The solver counted the saturated samples it left out (`saturated_samples`) and no user ever saw it."""
    over, good = load_press(captures["over"]), load_press(captures["good"])
    share = saturated_share(over)
    assert 0.1 < share < 0.9 and saturated_share(good) == 0.0
    caplog.set_level(logging.WARNING)
    result = solve_press(over, interreflection="off", dent_interreflection=False)
    assert result.report["saturated_share"] == pytest.approx(share, abs=1e-4)
    (note,) = result.report["warnings"]
    assert f"{100 * share:.0f} % of the gel's samples" in note and "left out of the solve" in note
    assert str(captures["over"]) in note and note in caplog.text
    quiet = solve_press(good, interreflection="off", dent_interreflection=False)
    assert quiet.report["saturated_share"] == 0.0 and "warnings" not in quiet.report

    cal = calibrate_leds(over, interreflection="off")
    assert cal.saturated_share == (round(share, 4),)
    assert "left out of the LED fit" in cal.warnings[0]  # first: the likely cause of an unreliable fit
    assert main(["calibrate-leds", str(captures["over"]), "--out", str(tmp_path / "l.json")]) == 0
    written = json.loads((tmp_path / "l.json").read_text(encoding="utf-8"))
    assert written["saturated_share"] == [round(share, 4)] and "saturated" in written["warnings"][0]
    assert SATURATED_SHARE_WARN == 0.05
    assert not [w for w in calibrate_leds(good, interreflection="off").warnings if "saturated" in w]


def test_a_share_below_the_threshold_is_recorded_without_a_warning(captures):
    """A few clipped samples (specular glints) are normal: recorded, not warned about."""
    press = load_press(captures["good"])
    images = press.led_images.copy()
    gel = np.isfinite(press.reference.depth)
    rows, cols = np.nonzero(gel)
    images[0, rows[:20], cols[:20]] = press.response.white_level  # 20 of the gel's pixels in one LED image
    clipped = dataclasses.replace(press, led_images=images)
    share = saturated_share(clipped)
    assert 0 < share < SATURATED_SHARE_WARN
    result = solve_press(clipped, interreflection="off", dent_interreflection=False)
    assert result.report["saturated_share"] == pytest.approx(share, abs=1e-4) and "warnings" not in result.report


def test_the_saturated_share_and_what_is_left_to_fit_count_every_clipped_sample(captures):
    """Both compare an image with the white level only when its brightest value reaches it (a glint made every
    solve ~35 ms slower, the full comparison ran on every calibration): the same share and verdict as counting
    every sample of the gel, with the dark frame's clipped samples counted once per LED image."""
    from nlipscalib.core.tolerances import LIT_LEVEL
    from nlipscalib.solver.exposure import nothing_to_fit
    from nlipscalib.solver.image_stats import led_levels

    press = load_press(captures["good"])
    white, gel = press.response.white_level, np.isfinite(press.reference.depth)
    rng = np.random.default_rng(3)
    for case in range(8):
        images, dark = press.led_images.copy(), press.dark.copy()
        images[case % 3][rng.random(gel.shape) < 0.2] = white  # one image with a clipped patch
        if case % 2:
            dark[rng.random(dark.shape) < 0.3] = white
        if case >= 6:  # every lit sample clipped somewhere: nothing to fit
            images[:] = white
        clipped = dataclasses.replace(press, led_images=images, dark=dark)
        sat = (images >= white) | (dark >= white)[None]
        assert saturated_share(clipped) == np.count_nonzero(sat[:, gel]) / sat[:, gel].size
        live = led_levels(clipped.linear(images), gel) >= LIT_LEVEL
        usable = bool((~sat[live][:, gel]).any())
        assert (nothing_to_fit(clipped) == "") == usable, case


def test_a_noisy_black_capture_is_refused_before_the_led_fit(tmp_path):
    """The exposure check runs on every calibration, not only once the fit fails: a black capture's sensor noise
    (1.5 DN at 12 bits, below the lit level) does not fail the fit that says why, it ran off instead."""
    rng = np.random.default_rng(0)
    folder = synth.make_press(
        tmp_path / "noisy", "none", size=SIZE, lin_hook=lambda lin: rng.normal(0, 3.7e-4, lin.shape)
    )
    with pytest.raises(CaptureError, match=r"no usable pixel to calibrate the LEDs on: its LED images .* are black"):
        calibrate_leds(load_press(folder), interreflection="off")


def test_a_dark_frame_that_holds_light_is_refused_and_one_below_the_black_level_warned(tmp_path, capsys):
    """An LED image saved as the dark frame was solved on to "no pixel could be reconstructed (... dead LEDs [1])";
    a dark frame below meta.json's black level (zeros, black level 1024) moved the twin's cube press from 0.42 to
    0.72 deg without a word. Now: "not a dark frame", exit 2; and a warning naming the dark frame, in report.json."""
    from nlipscalib.core.imageio import read_png16, write_png16

    lit = synth.make_press(tmp_path / "lit", "sphere")
    write_png16(lit / "dark.png", read_png16(lit / "led_01.png"))
    recorded_anew(lit)  # saved so by its capture: recorded as such (a copy over it later is refused before this)
    assert main(["solve", str(lit), "--roi", "auto", "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "dark.png: not a dark frame" in err and "Traceback" not in err

    low = synth.make_press(tmp_path / "low", "sphere")
    meta = json.loads((low / "meta.json").read_text(encoding="utf-8"))
    meta["sensor"]["black_level"] = 1024.0  # the stored dark frame holds 256
    (low / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    result = solve_press(load_press(low), roi="auto")
    said = [n for n in result.report.get("warnings", []) if "dark.png" in n]
    assert len(said) == 1 and "below the black level 1024" in said[0]
    assert dark_frame_fault(load_press(synth.make_press(tmp_path / "clean", "sphere"))) is None


def test_calibrate_leds_refuses_a_dead_led_and_a_lit_dark_frame_in_one_line_each(tmp_path):
    """The LED fit of a dead LED diverged ("led.intensity must be 3 finite numbers, got (inf, inf, inf)" behind
    numpy's "Mean of empty slice"); an LED image saved as the dark frame ran past 200 s on the twin's reference."""
    from nlipscalib.core.imageio import read_png16, write_png16

    def kill(lin):
        lin = lin.copy()
        lin[4] = 0.0
        return lin

    dead = synth.make_press(tmp_path / "dead", "none", lin_hook=kill)
    with pytest.raises(CaptureError, match=r"LED 5 \(led_05.png\): image dark .*dead LED"):
        calibrate_leds(load_press(dead))
    lit = synth.make_press(tmp_path / "lit", "none")
    write_png16(lit / "dark.png", read_png16(lit / "led_02.png"))
    with pytest.raises(CaptureError, match="dark.png: not a dark frame"):
        calibrate_leds(load_press(lit))


def _srgb(linear):
    """The sRGB transfer curve (IEC 61966-2-1) of linear values in [0, 1]."""
    linear = np.clip(linear, 0, 1)
    return np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)


def test_a_gamma_encoded_dark_frame_above_the_black_level_is_put_down_to_the_tone_curve(tmp_path, capsys):
    """An 8-bit sRGB webcam captured with ``--black-level 0`` was refused as "not a dark frame ... (an LED lit, or
    room light?)" with every LED off (s27 QA walk): the curve is steepest at black (12.92 times), so the sensor's
    0.07 % dark offset came out at 2 of 255 steps. With LED images that are not linear either, the refusal now
    names the tone curve and the fix; with linear ones the same dark frame is still light (an LED, a room)."""
    from nlipscalib.core.imageio import read_png16, write_png16

    offset = 0.0007  # the twin's dark offset above its black level, of full scale

    def with_dark(name, hook):
        folder = synth.make_press(tmp_path / name, "none", lin_hook=hook)
        dark = synth.to_stored(np.full(read_png16(folder / "dark.png").shape, _srgb(offset)))
        write_png16(folder / "dark.png", dark)
        recorded_anew(folder)  # captured so
        return folder

    encoded = with_dark("srgb", lambda lin: _srgb(lin + offset))
    assert main(["solve", str(encoded), "--no-figures"]) == 2
    err = capsys.readouterr().err
    assert "dark.png: its median on the gel" in err and "above the black level" in err and "Traceback" not in err
    assert "not linear in the light" in err and "gamma-encoded (sRGB)" in err and "LED lit" not in err
    with pytest.raises(CaptureError, match=r"dark.png: .*gamma-encoded \(sRGB\) frames\? A tone curve"):
        calibrate_leds(load_press(encoded))

    linear = with_dark("linear", lambda lin: lin + _srgb(offset))
    message, refused = dark_frame_fault(load_press(linear))
    assert refused and "not a dark frame" in message and "(an LED lit, or room light?)" in message
    assert "tone curve" not in message and "not linear" not in message


def test_an_even_dark_frame_above_the_black_level_names_the_cameras_black_level(tmp_path, capsys):
    """A camera with a pedestal, captured at the default ``--black-level 0``, was refused press by press with "not a
    dark frame ... (an LED lit, or room light?); capture it with every LED off", which the lab had done (s36 device
    walk). An even offset now names the black level to declare; an LED image as the dark frame keeps the old line."""
    from nlipscalib.core.imageio import read_png16, write_png16

    folder = synth.make_press(tmp_path / "pedestal", "sphere")
    for image in folder.glob("*.png"):  # a pedestal of 2048 on every value, meta.json's black level left at 256
        write_png16(image, read_png16(image) + np.uint16(2048))
    recorded_anew(folder)
    message, refused = dark_frame_fault(load_press(folder))
    bits, dn = synth.RESPONSE.bit_depth, 256 + 2048
    assert refused and "black level 256" in message and "even across the gel" in message, message
    assert f"`nlips capture --black-level {dn:.4g}`, in the camera's {bits}-bit values)" in message, message
    assert main(["solve", str(folder), "--no-figures"]) == 2
    assert "--black-level" in capsys.readouterr().err

    lit = synth.make_press(tmp_path / "lit", "sphere")
    write_png16(lit / "dark.png", read_png16(lit / "led_01.png"))
    recorded_anew(lit)
    message, refused = dark_frame_fault(load_press(lit))
    assert refused and "(an LED lit, or room light?); capture it with every LED off" in message
    assert "--black-level" not in message


def test_the_black_level_named_for_a_press_declaring_a_tone_curve_is_the_cameras_own_value(tmp_path):
    """A press declaring the camera's sRGB curve (meta.json sensor.camera_response) is loaded with the curve undone,
    and its even dark frame was told `--black-level` in those linear values: 2.047 of 255 where the camera gave 22
    and `nlips capture` of the same frames said 22 (s37). The value named is the camera's own, as `nlips capture
    --black-level` takes it."""
    import re

    from nlipscalib.core.imageio import read_png16, write_png16

    folder = synth.make_press(tmp_path / "srgb", "sphere")
    black, white = synth.RESPONSE.black_level, synth.RESPONSE.white_level
    pedestal = 8000  # added by the camera after its curve: 1.4 % of full scale in the light
    for path in folder.glob("*.png"):
        light = np.clip((read_png16(path).astype(float) - black) / (white - black), 0, 1)
        encoded = np.clip(np.rint(black + pedestal + _srgb(light) * (white - black)), 0, white)
        write_png16(path, encoded.astype(np.uint16))
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    meta["sensor"]["camera_response"] = "srgb"
    (folder / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    recorded_anew(folder)
    press = load_press(folder)
    message, refused = dark_frame_fault(press)
    encoded = float(np.median(read_png16(folder / "dark.png")[np.isfinite(press.reference.depth)]))
    said = float(re.search(r"`nlips capture --black-level ([0-9.]+)`", message).group(1))
    assert refused and abs(said - encoded) <= 2, message
    assert "in the camera's 16-bit values as it encodes them, its srgb curve not undone" in message
