"""What LED calibration (``nlips calibrate-leds``) tells the user: a coating reflectance it did not use, a
reflectance it could not profile, and a fit too poor to trust (``solver.calibration_quality.fit_quality``).

CI-sized renders of the default twin's undeformed dome (160x120, the sensor's noise on, as ``nlips render
--undeformed`` makes them), calibrated at stride 4 (a second each): direct light only, one bounce at 16 spp
(good), one bounce at 2 spp (the denoised bounce light's Monte Carlo blotches: poor LEDs).
"""

import json
import logging
import re

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.ledfile import read_led_file  # noqa: E402
from nlipscalib.core.tolerances import FIT_NOISE_RATIO  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import calibrate_leds  # noqa: E402

STRIDE = 4


@pytest.fixture(scope="module")
def captures(tmp_path_factory):
    root = tmp_path_factory.mktemp("calibration_quality")

    def undeformed(name, bounces, spp):
        scene = load_scene().replace(render={"bounces": bounces, "spp": spp}, camera={"width": 160, "height": 120})
        return render_press(scene, None, root / name, seed=21)

    return {"direct": undeformed("direct", 0, 4), "good": undeformed("good", 1, 16), "noisy": undeformed("noisy", 1, 2)}


def worst_led(cal, true):
    """(deg, mm): the calibrated point LEDs' worst axis and position error (the twin's 3.6 mm disk LEDs: the
    best points sit ~0.23 mm behind the disks' centres by design)."""
    ang = max(np.degrees(np.arccos(min(1.0, np.dot(a.direction, t.direction)))) for a, t in zip(cal.leds, true))
    return ang, max(np.linalg.norm(np.subtract(a.position, t.position)) for a, t in zip(cal.leds, true))


def test_a_reflectance_the_calibration_cannot_use_is_reported(captures, caplog):
    flat = load_press(captures["direct"])
    plain = calibrate_leds(flat, stride=STRIDE)
    assert not plain.warnings and plain.quality["reliable"]
    with caplog.at_level(logging.WARNING, logger="nlipscalib"):
        given = calibrate_leds(flat, stride=STRIDE, coating_reflectance=0.8)
    # the capture shows no interreflection: the value scales nothing, and the user is told so, once
    (note,) = given.warnings
    assert note.startswith("coating reflectance 0.8 (--coating-reflectance) not used: no capture shows interreflection")
    assert "--interreflection on forces" in note
    assert [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING] == [note]
    assert given.leds == plain.leds  # what the warning says: fitted as direct light
    # the term switched off by request: the same, without the hint to force it
    (note,) = calibrate_leds(flat, stride=STRIDE, interreflection="off", coating_reflectance=(0.8, 0.8, 0.7)).warnings
    assert "[0.8, 0.8, 0.7] (--coating-reflectance) not used: the interreflection term is off (requested)" in note
    assert "forces" not in note
    # forced on, the given reflectance is honoured
    forced = calibrate_leds(flat, stride=STRIDE, interreflection="on", coating_reflectance=0.8)
    assert not any("not used" in w for w in forced.warnings)
    assert "reflectance set to [0.8, 0.8, 0.8]" in forced.interreflection[0]["reason"]
    # LED disks without a known reflectance (the default from a design that declares its LEDs' size): nothing to
    # profile without interreflection, which is no fault of the capture: an INFO line, not a warning
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nlipscalib"):
        disks = calibrate_leds(flat, stride=STRIDE, led_radius=1.8)
    assert disks.reflectance_profile is None and len(disks.emitters) == len(flat.leds) and not disks.warnings
    said = [r.getMessage() for r in caplog.records if r.levelno == logging.INFO]
    assert any(m.startswith("LED disks fitted to the images as direct light") for m in said), said


def test_calibrate_leds_command_warns_about_an_unused_reflectance(captures, tmp_path, caplog, capsys):
    out = tmp_path / "leds.json"
    argv = ["--no-progress", "calibrate-leds", str(captures["direct"]), "--out", str(out), "--stride", str(STRIDE)]
    with caplog.at_level(logging.WARNING, logger="nlipscalib"):
        assert main([*argv, "--coating-reflectance", "0.8"]) == 0
    (note,) = json.loads(out.read_text(encoding="utf-8"))["warnings"]
    assert "not used" in note and note in caplog.text
    printed = capsys.readouterr().err
    assert "1 warning(s) above, also in the file" in printed
    # the summary's albedo is legible (it printed Python's full float reprs, 103.04731814227624)
    written = next(line for line in printed.splitlines() if line.startswith("written "))
    assert re.search(r"albedo \d+(\.\d+)?, \d+(\.\d+)?, \d+(\.\d+)?\)", written), written
    assert not re.search(r"\.\d{7}", written), written


def test_a_good_capture_calibrates_without_a_quality_warning(captures):
    flat = load_press(captures["good"])
    cal = calibrate_leds(flat, stride=STRIDE)
    q = cal.quality
    assert q["reliable"] and q["median_ratio"] <= FIT_NOISE_RATIO and not cal.warnings, q
    assert len(q["ratio"]) == len(q["noise"]) == len(q["residual"]) == len(flat.leds)
    ang, pos = worst_led(cal, flat.leds)
    assert ang <= 2.5 and pos <= 0.5, (ang, pos)


def test_a_noisy_capture_is_reported_unreliable(captures, tmp_path, caplog, capsys):
    """A one-bounce render at 2 spp: the LEDs come out poor (worst 2-3 deg, 0.8-1.4 mm on four seed/stride
    pairs), with a Jacobian std of ~0.2 deg that hides it; the residual against the image noise shows it."""
    out = tmp_path / "leds.json"
    argv = ["--no-progress", "calibrate-leds", str(captures["noisy"]), "--out", str(out), "--stride", str(STRIDE)]
    with caplog.at_level(logging.WARNING, logger="nlipscalib"):
        assert main(argv) == 0
    data = json.loads(out.read_text(encoding="utf-8"))
    assert not data["quality"]["reliable"] and data["quality"]["median_ratio"] > FIT_NOISE_RATIO
    (note,) = data["warnings"]
    assert note.startswith("LED calibration unreliable") and "more samples per pixel" in note
    assert note in caplog.text
    assert "UNRELIABLE" in capsys.readouterr().err
    # the warning is right: these LEDs are poor. The file holds the LEDs the warning is about: the command ran
    # calibrate_leds(flat, stride=STRIDE) with every other setting at its default (loss, interreflection, bounces,
    # no disks, no reflectance), and JSON keeps every float's bits, so fitting again here would give the same LEDs
    flat = load_press(captures["noisy"])
    ang, pos = worst_led(read_led_file(out), flat.leds)
    assert ang > 2.0 or pos > 0.5, (ang, pos)


def test_calibrate_leds_refuses_a_pressed_capture_and_fits_around_its_contact_when_allowed(captures, tmp_path, capsys):
    """A fresh-eyes trial: a press's folder given as the undeformed reference was calibrated and called reliable
    without a word, and every later solve with those LEDs would be off. The command refuses it (the undeformed
    captures of this module's other tests, bounce-free and one-bounce, pass the same check); ``--allow-contact``
    fits without the contact's pixels and says so."""
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig

    scene = load_scene().replace(camera={"width": 160, "height": 120})
    coin = PressConfig(IndenterConfig(kind="coin", size=6.0), polar_deg=15, azimuth_deg=0, depth=1.0)
    pressed = render_press(scene, coin, tmp_path / "pressed", seed=21)
    out = tmp_path / "leds.json"
    argv = ["--no-progress", "calibrate-leds", str(pressed), "--out", str(out), "--stride", str(STRIDE)]
    assert main(argv) == 2  # the twin's meta.json names the press: refused before the fit
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"nlips calibrate-leds: error: {pressed}: a press of the twin (a coin of 6 mm"), line
    meta_file = pressed / "meta.json"  # a real sensor's capture records no press: the fit's contact check tells
    meta = json.loads(meta_file.read_text(encoding="utf-8"))
    del meta["provenance"]["press"]
    meta_file.write_text(json.dumps(meta), encoding="utf-8")
    assert main(argv) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"nlips calibrate-leds: error: {pressed}: not a capture of the undeformed dome: "), line
    assert "--allow-contact" in line and not out.exists()
    assert main([*argv, "--allow-contact"]) == 0
    data = json.loads(out.read_text(encoding="utf-8"))
    (count,) = data["contact_pixels"]
    assert count > 0 and any("left out of the LED fit" in w for w in data["warnings"]), data["warnings"]
    assert data["quality"]["reliable"], data["quality"]
    # the undeformed captures: accepted, nothing left out
    for name in ("direct", "good"):
        assert calibrate_leds(load_press(captures[name]), stride=STRIDE).contact_pixels == ()


def test_a_weakly_interreflecting_dome_gets_the_term_when_light_alone_leaves_more_than_noise(tmp_path):
    # the oblate dome interreflects less (share ~0.09 with the starting LEDs, below the calibration's 0.1): the
    # share decision leaves the term off, the direct-only fit does not explain the images, the term does
    scene = load_scene("oblate").replace(render={"bounces": 1, "spp": 16}, camera={"width": 160, "height": 120})
    capture = load_press(render_press(scene, None, tmp_path / "oblate", seed=21))
    cal = calibrate_leds(capture, stride=STRIDE)
    (model,) = cal.interreflection
    assert model["enabled"] and "direct-only fit did not explain the images" in model["reason"]
    assert cal.quality["reliable"] and not cal.warnings
    ang, _ = worst_led(cal, capture.leds)
    off = calibrate_leds(capture, stride=STRIDE, interreflection="off")
    assert not off.quality["reliable"] and ang < worst_led(off, capture.leds)[0] / 2
