"""LED images that do not show their LEDs (a wiring error, a weak LED) are warned about, naming the images."""

import dataclasses
import logging
import shutil

import numpy as np
import pytest

from nlipscalib.core import load_press, tolerances
from nlipscalib.core.repeated_frames import LaggedBand
from nlipscalib.solver import SolverOptions, solve_press
from nlipscalib.solver.led_checks import (
    _samples,
    agreed_gains,
    detected_order,
    exposure_ratio,
    led_check,
    led_check_measured,
    led_gains,
    led_mismatch_notes,
    linearity_notes,
    response_slope,
)

from . import synth


def _press(tmp_path, name, hook=None):
    return load_press(synth.make_press(tmp_path / name, "sphere", lin_hook=hook))


def test_two_swapped_led_images_are_named_as_swapped_in_the_log_and_the_report(tmp_path, caplog):
    """Two LED images in each other's place (a wiring error) were solved without a word about it (the twin's cube
    press: contact AAE 6.1 deg, depth 6.7 mm off, only "the solve drifted"); the solve now names both images (kept in
    the captured order here: the order they show is the next test's)."""

    def swap(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    press = _press(tmp_path, "swapped", swap)
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, options=SolverOptions(max_iters=2), reorder_leds=False)
    said = [note for note in result.report.get("warnings", []) if "look swapped" in note]
    assert len(said) == 1 and "LED 3 (led_03.png)" in said[0] and "LED 6 (led_06.png)" in said[0]
    assert said[0] in caplog.text


def test_swapped_led_images_are_solved_in_the_order_they_show_unless_kept_as_captured(tmp_path, caplog):
    """The twin's cube press with LED images 3 and 7 swapped was solved as captured after its warning: contact AAE
    6.1 deg, a result the tool knew was wrong. The image labelled 3 was lit by LED 6 here: the solve now uses it
    as LED 6's (the physics), says so, and records the order; ``reorder_leds=False`` keeps the captured order."""

    def swap(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    options = SolverOptions(max_iters=2)
    clean = solve_press(_press(tmp_path, "clean"), options=options)
    press = _press(tmp_path, "swapped", swap)
    with caplog.at_level(logging.WARNING):
        fixed = solve_press(press, options=options)
    order = [0, 1, 5, 3, 4, 2, 6, 7, 8, 9, 10, 11]
    assert fixed.report["led_order"] == order and fixed.report["leds_reordered"] is True
    said = [note for note in fixed.report["warnings"] if "out of order" in note]
    assert (
        len(said) == 1 and "led_06.png (image 6 of images.leds) as LED 3" in said[0] and "--keep-led-order" in said[0]
    )
    assert said[0] in caplog.text and not any("look swapped" in note for note in fixed.report["warnings"])
    gel = clean.reconstructed & fixed.reconstructed
    assert np.abs(fixed.depth[gel] - clean.depth[gel]).max() < 1e-6
    kept = solve_press(press, options=options, reorder_leds=False)
    assert kept.report["led_order"] == list(range(12)) and kept.report["leds_reordered"] is False
    assert any("look swapped" in note for note in kept.report["warnings"])
    assert np.abs(kept.depth[gel] - clean.depth[gel]).max() > 0.1


def _exchanged(first: int, second: int):
    """A hook exchanging two LED images (0-based) of a synthetic press, as files renamed by hand."""

    def exchange(lin):
        lin = lin.copy()
        lin[[first, second]] = lin[[second, first]]
        return lin

    return exchange


def test_neighbouring_led_images_exchanged_are_refused_naming_them_unless_kept_as_captured(tmp_path, caplog):
    """led_03.png and led_04.png exchanged (a capture script's off-by-one, files renamed by hand): neighbours light
    the dome alike, above the 0.5 of the misplaced images' check, and the press was solved without a word (the
    twin's sphere: its auto box widened to the whole gel, 1.09 deg there against the clean press's 0.80). Now one
    line names both files and what to do, as ``nlips calibrate-leds`` refuses them; ``reorder_leds=False``
    (``--keep-led-order``) solves them as captured with that line as a warning and records them."""
    from nlipscalib.core.errors import CaptureError

    options = SolverOptions(max_iters=2)
    press = _press(tmp_path, "exchanged", _exchanged(2, 3))
    with pytest.raises(CaptureError) as refused:
        solve_press(press, options=options)
    line = str(refused.value)
    assert line.startswith(f"{press.folder}: led_03.png and led_04.png look exchanged (") and "\n" not in line
    assert "led_03.png 0." in line and "with LED 4's" in line and "not solved" in line and "--keep-led-order" in line
    with caplog.at_level(logging.WARNING):
        kept = solve_press(press, options=options, reorder_leds=False)
    assert kept.report["leds_exchanged"] == [[2, 3]]
    (said,) = [note for note in kept.report["warnings"] if "look exchanged" in note]
    assert said.endswith("solved as captured (--keep-led-order; report.json leds_exchanged)") and said in caplog.text
    cycle = _press(tmp_path, "cycle", lambda lin: lin[[0, 1, 3, 4, 2, *range(5, 12)]])  # 3 shows 4, 4 5, 5 3
    with pytest.raises(CaptureError, match=r"led_03.png, led_04.png and led_05.png \(a cycle\) look exchanged"):
        solve_press(cycle, options=options)  # led_05.png two LEDs off: misplaced, but no clean order to solve in
    clean = solve_press(_press(tmp_path, "clean"), options=options)
    assert "leds_exchanged" not in clean.report
    assert not any("exchanged" in note for note in clean.report.get("warnings", []))


def test_an_led_file_holding_neighbouring_leds_exchanged_is_named_as_the_likelier_culprit(tmp_path):
    """An LED file calibrated on images captured in each other's place and kept so (``calibrate-leds
    --keep-led-order``) holds LED 3 at LED 4's design place and back; a clean press solved with it was refused
    as "led_03.png and led_04.png look exchanged ... (right only when the LED model misplaces those LEDs ...)",
    blaming the press and naming no file. Now the line names the file (``leds_name``) as the likelier exchanged,
    the press's images showing its design's order; an exchanged press with a clean file is still the press's."""
    from nlipscalib.core.errors import CaptureError

    options = SolverOptions(max_iters=2)
    clean = _press(tmp_path, "clean")
    swapped = list(clean.leds)
    swapped[2], swapped[3] = swapped[3], swapped[2]
    with pytest.raises(CaptureError) as refused:
        solve_press(clean, options=options, leds=swapped, leds_name="cal/leds.json")
    line = str(refused.value)
    assert line.startswith(f"{clean.folder}: led_03.png and led_04.png look exchanged (") and "\n" not in line
    assert "against the LEDs of cal/leds.json, which holds them at each other's places" in line
    assert "cal/leds.json is the likelier exchanged" in line and "calibrate the LEDs again" in line
    assert "captured in each other's place (the LED wiring" not in line
    press = _press(tmp_path, "exchanged", _exchanged(2, 3))
    with pytest.raises(CaptureError) as theirs:
        solve_press(press, options=options, leds=list(press.leds), leds_name="cal/leds.json")
    assert "cal/leds.json" not in str(theirs.value) and "(the LED wiring" in str(theirs.value)


def test_an_undeformed_capture_with_neighbouring_images_exchanged_is_refused_naming_it(tmp_path):
    """The press's own images in order, the undeformed capture it is solved with (``--reference``) holding
    led_03.png and led_04.png exchanged: the press's light was compared with the wrong LEDs' there (the twin's
    sphere: only "--roi auto left out 10227 misfitting pixels along the gel's edge"). The images alone tell (one LED's
    images correlate far better than two neighbours'); the press fits its LED model, so the line names the undeformed
    capture as the likelier exchanged. The same exchange in both: the press's own check names it first."""
    from nlipscalib.core.errors import CaptureError

    def flat(name, hook=None):
        return load_press(synth.make_press(tmp_path / name, "none", lin_hook=hook))

    options = SolverOptions(max_iters=2)
    press, exchanged = _press(tmp_path, "press"), flat("ref_exchanged", _exchanged(2, 3))
    with pytest.raises(CaptureError) as refused:
        solve_press(press, indirect=exchanged, options=options)
    line = str(refused.value)
    assert line.startswith(f"{press.folder}: led_03.png and led_04.png hold the light {exchanged.folder}'s led_04.png")
    assert f"{exchanged.folder}'s are the likelier exchanged" in line and "--keep-led-order" in line
    kept = solve_press(press, indirect=exchanged, options=options, reorder_leds=False)
    assert kept.report["leds_exchanged"] == [[2, 3]]
    both = _press(tmp_path, "both", _exchanged(2, 3))
    with pytest.raises(CaptureError, match="led_03.png and led_04.png look exchanged"):
        solve_press(both, indirect=exchanged, options=options)
    assert "leds_exchanged" not in solve_press(press, indirect=flat("ref"), options=options).report


def test_the_undeformed_capture_given_with_the_same_swap_is_reordered_alike(tmp_path):
    """A session's undeformed capture (``--reference``, a folder's ``reference/``) shows its presses' wiring error:
    reordering the press and not it would compare LED 6's light with LED 3's model of the undeformed dome."""

    def swap(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    def flat(name, hook=None):
        return load_press(synth.make_press(tmp_path / name, "none", lin_hook=hook))

    options = SolverOptions(max_iters=2)
    clean = solve_press(_press(tmp_path, "clean"), indirect=flat("ref"), options=options)
    fixed = solve_press(_press(tmp_path, "swapped", swap), indirect=flat("ref_swapped", swap), options=options)
    gel = clean.reconstructed & fixed.reconstructed
    assert fixed.report["leds_reordered"] and np.abs(fixed.depth[gel] - clean.depth[gel]).max() < 1e-6


def test_a_sessions_wiring_error_is_warned_about_once_and_recorded_in_every_report(tmp_path, caplog):
    """A wiring error is the session's: ``nlips calibrate`` of 50 presses would say it 50 times. The first press of a
    folder out of an order warns; the next ones say it at INFO, each report keeping the line."""

    def swap(lin):
        lin = lin.copy()
        lin[[2, 5]] = lin[[5, 2]]
        return lin

    presses = [_press(tmp_path / "session", name, swap) for name in ("p1", "p2")]
    with caplog.at_level(logging.INFO):
        results = [solve_press(p, options=SolverOptions(max_iters=1)) for p in presses]
    warned = [r for r in caplog.records if "out of order" in r.getMessage() and r.levelno == logging.WARNING]
    assert len(warned) == 1 and "said once" in warned[0].getMessage()
    assert all(any("out of order" in w for w in r.report["warnings"]) for r in results)


def test_only_a_clean_pair_or_cycle_of_misplaced_images_gives_an_order():
    """A wrong order is corrected only when it is plain: each misplaced image shows an LED whose own image is
    misplaced too, no LED twice, each well (``REORDER_CORRELATION``)."""
    assert detected_order({1: (3, 0.98), 3: (1, 0.97)}, 5) == [0, 3, 2, 1, 4]
    assert detected_order({0: (1, 0.98), 1: (2, 0.98), 2: (0, 0.98)}, 4) == [2, 0, 1, 3]
    assert detected_order({1: (3, 0.98)}, 5) is None  # LED 4's own image fits it: not a swap
    assert detected_order({1: (3, 0.98), 2: (3, 0.98), 3: (1, 0.98)}, 5) is None  # LED 4 shown twice
    assert detected_order({1: (3, 0.98), 3: (1, 0.7)}, 5) is None  # a poor match: only warned about
    assert detected_order({}, 5) is None


def test_a_weak_led_is_named_with_its_share_of_the_modelled_light(tmp_path):
    def weaken(lin):
        lin = lin.copy()
        lin[4] *= 0.3
        return lin

    notes = led_mismatch_notes(_press(tmp_path, "weak", weaken), synth.ring_leds(), range(12))
    assert len(notes) == 1 and "LED 5 (led_05.png) gives 0.3" in notes[0] and "weak LED?" in notes[0]


def test_a_press_whose_images_match_their_leds_gets_no_led_warning(tmp_path):
    press = _press(tmp_path, "clean")
    assert led_mismatch_notes(press, press.leds, range(len(press.leds))) == []
    result = solve_press(press, roi="auto", options=SolverOptions(max_iters=2))
    assert not any("LED" in note for note in result.report.get("warnings", []))


def test_a_weak_led_is_left_out_of_the_solve_and_the_auto_roi_finds_the_contact(tmp_path, caplog):
    """A 30 % LED 7 in the twin's cube press ended on "--roi auto found no contact" after its warning (its misfit
    everywhere raised the contact finder's floor), and solved on the whole gel with it to 0.64 deg (0.42 clean). It
    is now left out, as a dead LED is: the auto ROI boxes the dent, and the report numbers the capture's LEDs."""

    def weaken(lin):
        lin = lin.copy()
        lin[6] *= 0.3
        return lin

    press = _press(tmp_path, "weak", weaken)
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, roi="auto", options=SolverOptions(max_iters=2))
    rep = result.report
    assert rep["leds_left_out"] == [6] and 6 not in rep["leds_used"] and len(rep["leds_used"]) == 11
    said = [note for note in rep["warnings"] if "LED 7 (led_07.png)" in note]
    assert len(said) == 1 and "left out of the solve" in said[0] and "nlips calibrate-leds" in said[0]
    assert said[0] in caplog.text
    contact = press.ground_truth.contact
    assert result.reconstructed[contact].all()  # the box holds the whole dent


def test_an_led_image_that_repeats_the_one_before_is_named_and_left_out(tmp_path, caplog):
    """A webcam whose frames lag the LED switch: LED 5's image is LED 4's light. Solved silently before (the
    one-bounce twin at 320x240, 8-bit: contact AAE 0.62 deg instead of 0.47 on the sphere press); now named, with
    the fix, and left out of the solve (0.47 deg)."""

    def lag(lin):
        lin = lin.copy()
        lin[4] = lin[3]
        return lin

    press = _press(tmp_path, "lagged", lag)
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, options=SolverOptions(max_iters=2))
    rep = result.report
    said = [note for note in rep["warnings"] if "repeats" in note]
    assert len(said) == 1 and "led_05.png repeats led_04.png" in said[0] and "--flush" in said[0]
    assert rep["leds_left_out"] == [4] and 4 not in rep["leds_used"]
    assert said[0] in caplog.text
    assert said[0].endswith("; left out of the solve (they hold the light of the LED before them)")


def test_repeated_led_images_too_many_to_leave_out_are_said_to_be_used(tmp_path):
    """Every LED image after the first repeats it (a camera handing out one frame throughout): leaving 11 of 12 LEDs
    out would leave too few to solve, so they are used, and the warning says so (it said "left out of the solve"
    whatever the solve did, s27-docs2)."""
    press = _press(tmp_path, "stuck", lambda lin: lin[[0] * len(lin)])
    notes, left_out, _, _ = led_check(press, press.leds, range(len(press.leds)))
    said = [note for note in notes if "repeats" in note]
    assert left_out == [] and len(said) == 1
    assert "led_12.png repeats led_11.png" in said[0] and "; used (too few LEDs to leave them out)" in said[0]


def test_gamma_encoded_led_images_are_called_not_linear(tmp_path, caplog):
    """An 8-bit webcam's sRGB output, read as linear: a contact AAE of 15-17 deg on the one-bounce twin with no
    warning (s27 QA walk). The images grow as the LED model's light to the power ~0.45: named, with the fix, by the
    solve once its indirect term is fitted (in its log and report), also when it is given other LEDs (a calibration
    that absorbed the curve): the verdict is the recorded LEDs'."""
    encoded = _press(tmp_path, "srgb", lambda lin: np.clip(lin, 0, None) ** (1 / 2.2) * 0.5)
    said = linearity_notes(encoded, range(12))
    # 0.56 here: with no interreflection to find, the fitted indirect term takes up a little of the curve
    assert len(said) == 1 and "power 0.5" in said[0] and "gamma" in said[0]
    moved = tuple(dataclasses.replace(led, position=tuple(1.3 * np.asarray(led.position))) for led in encoded.leds)
    with caplog.at_level(logging.WARNING):
        result = solve_press(encoded, leds=moved, options=SolverOptions(max_iters=2), check_sensor=False)
    in_report = [note for note in result.report["warnings"] if "not linear in the light" in note]
    assert len(in_report) == 1 and "power 0.5" in in_report[0] and in_report[0] in caplog.text
    assert response_slope(*_samples(encoded, encoded.leds, list(range(12)))) < 0.5
    linear = _press(tmp_path, "linear")
    assert response_slope(*_samples(linear, linear.leds, list(range(12)))) > 0.9
    assert linearity_notes(linear, range(12)) == []


def test_led_images_exposed_unlike_the_undeformed_captures_are_warned_about(tmp_path, caplog):
    """Auto exposure and white balance left on: each LED image scaled by its own factor (the 8-bit twin with +-15 %
    and +-8 %: "--roi auto found no contact ... the LED model does not fit this sensor", and nothing about the
    camera). Against the undeformed capture each LED's brightness ratio shows it; taken alike, no warning."""
    gains = np.array([1.0, 1.12, 0.9, 1.0, 0.95, 1.08, 1.0, 0.87, 1.0, 1.1, 1.0, 0.93])

    def auto_exposure(lin):
        return lin * gains[:, None, None, None]

    reference = load_press(synth.make_press(tmp_path / "reference", "none"))
    drifted = _press(tmp_path, "drifted", auto_exposure)
    with caplog.at_level(logging.WARNING):
        result = solve_press(drifted, indirect=reference, options=SolverOptions(max_iters=2))
    said = [note for note in result.report["warnings"] if "auto exposure" in note]
    assert len(said) == 1 and "0.87-1.12 times as bright" in said[0] and said[0] in caplog.text
    steady = solve_press(_press(tmp_path, "steady"), indirect=reference, options=SolverOptions(max_iters=2))
    assert not any("auto exposure" in note for note in steady.report.get("warnings", []))


def test_a_linear_capture_of_an_interreflecting_design_is_not_called_gamma_encoded(tmp_path, caplog):
    """The capsule's own interreflection: every linear capsule capture, undeformed or pressed, was warned about as
    gamma-encoded (slope 0.28-0.34 against the direct light alone: its direct share, s28-capsule). Against the LED
    model with its fitted indirect term it is 1.0, and the solve says nothing; its sRGB encoding (about 0.49) is
    still named."""
    pytest.importorskip("mitsuba")
    from nlipscalib.core.imageio import read_png16, write_png16
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    from .test_camera_response import _srgb

    scene = load_scene("capsule").replace(render={"bounces": 1, "spp": 8}, camera={"width": 160, "height": 120})
    folder = render_press(scene, None, tmp_path / "linear", seed=5)
    linear = load_press(folder)
    every = list(range(len(linear.leds)))
    assert response_slope(*_samples(linear, linear.leds, every)) < 0.4  # the direct light alone: the false alarm
    assert linearity_notes(linear, every) == []
    with caplog.at_level(logging.WARNING):
        result = solve_press(linear, options=SolverOptions(max_iters=2))
    assert not [note for note in result.report.get("warnings", []) if "not linear" in note]
    assert "not linear" not in caplog.text

    encoded = shutil.copytree(folder, tmp_path / "srgb")  # the camera's curve on every frame, levels kept
    black, white = linear.response.black_level, linear.response.white_level
    for path in encoded.glob("*.png"):
        fraction = (read_png16(path).astype(float) - black) / (white - black)
        write_png16(path, np.rint(black + _srgb(fraction) * (white - black)).astype(np.uint16))
    said = linearity_notes(load_press(encoded), every)
    assert len(said) == 1 and "power 0.4" in said[0] and "gamma-encoded (sRGB)" in said[0]


def test_one_led_group_dimmer_is_named_as_possibly_aged_and_left_out_of_the_global_gain(tmp_path):
    """A group of LEDs aged on its own (the red third 10 % dimmer) is no global gain: the per-LED warning says it,
    now naming aged LEDs beside auto exposure, and the solve's gain stays 1."""
    from nlipscalib.solver.led_checks import exposure_drift_note, exposure_ratio, reference_gain

    reference = load_press(synth.make_press(tmp_path / "reference", "none"))
    red_aged = _press(tmp_path, "red", lambda lin: lin * np.repeat([0.9, 1.0, 1.0], 4)[:, None, None, None])
    ratio = exposure_ratio(red_aged, reference)
    assert np.allclose(reference_gain(ratio), 1.0, atol=0.005)
    note = exposure_drift_note(red_aged, reference, ratio)
    assert note is not None and "auto exposure" in note and "LEDs aged" in note


def _rows_from(source_of, rows, axis="rows"):
    """A lin_hook: each LED image k in ``source_of`` takes its first ``rows`` rows (``axis`` "columns": columns)
    from image ``source_of[k]`` as captured (an int), or from the dark frame (None): a rolling shutter read out
    across the LED switch."""

    def hook(lin):
        captured, lin = lin, lin.copy()
        lines = (slice(None), slice(rows)) if axis == "columns" else (slice(rows),)
        for k, source in source_of.items():
            lin[(k, *lines)] = 0.0 if source is None else captured[(source, *lines)]
        return lin

    return hook


def test_an_led_image_read_out_across_the_switch_is_named_with_its_rows_and_only_those_rows_left_out(tmp_path, caplog):
    """A rolling shutter that read LED 5's frame while the LEDs switched: its top half is LED 4's light. Called a
    whole repeat before (or, a quarter, not seen at all; the twin's cube press with three quarters lagged: contact
    AAE 0.500 deg, 0.446 clean); then the rows, the cause and the fix were named and the LED left out whole (0.458);
    now only its rows, DARK_BAND_MARGIN more and to the frame's edge are left out, for LED 5 alone, as a dark band's
    (s31-darkall): the solve's usable LEDs there one fewer than the clean solve's, the same below. Its gain against
    the undeformed capture is measured off the band (with the band, 0.98 on the twin's sphere: rescaled by it)."""
    options = SolverOptions(max_iters=2)
    reference = load_press(synth.make_press(tmp_path / "undeformed", "none"))
    clean = solve_press(_press(tmp_path, "clean"), indirect=reference, options=options)
    press = _press(tmp_path, "rolling", _rows_from({4: 3}, 36))
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, indirect=reference, options=options)
    rep = result.report
    said = [note for note in rep["warnings"] if "read the frame out" in note]
    assert len(said) == 1 and "led_05.png's rows 0-34 (top)" in said[0] and "led_04.png's light" in said[0]
    assert "rolling shutter" in said[0] and "--flush" in said[0] and said[0] in caplog.text
    assert "left out of the solve for that LED only" in said[0] and "the rest of its image used" in said[0]
    assert not any("repeats" in note or "are dark" in note for note in rep["warnings"])
    assert "leds_left_out" not in rep and 4 in rep["leds_used"] and rep["led_gains"] is None
    assert rep["lagged_bands_left_out"] == [{"led": 4, "rows": [0, 35], "margin": tolerances.DARK_BAND_MARGIN}]
    fewer = clean.usable_leds.astype(int) - result.usable_leds
    edge = 35 + tolerances.DARK_BAND_MARGIN
    inside = result.mask & clean.mask
    assert (fewer[:edge][inside[:edge]] == 1).all() and (fewer[edge:][inside[edge:]] == 0).all()

    # a band of two thirds of the rows at other light than the LED's (here half of it) sets the median of its
    # ratio to the undeformed capture; measured off the band, the LED's own light
    def halved(lin):
        lin = lin.copy()
        lin[4, :48] *= 0.5
        return lin

    other = _press(tmp_path, "other_light", halved)
    assert np.allclose(exposure_ratio(other, reference)[4], 0.5, atol=0.01)
    assert np.allclose(exposure_ratio(other, reference, [LaggedBand(4, (0, 45), True)])[4], 1.0, atol=0.005)


def test_an_led_image_read_out_across_the_switch_by_a_camera_turned_90_degrees_is_named_with_its_columns(
    tmp_path, caplog
):
    """A camera mounted turned 90 degrees reads the columns one after another: LED 5's left columns from LED 4's
    light were solved as its own, said nowhere (the check looked at rows only; dark columns were named since
    s30-darkcols). Now the columns, the cause and the fix are named and only those columns left out for the LED, as
    for rows; solved against the undeformed capture, its gain is measured off them (with them, 0.97: the solve
    rescaled the rest of its image by it)."""
    press = _press(tmp_path, "rolling_turned", _rows_from({4: 3}, 56, "columns"))
    reference = load_press(synth.make_press(tmp_path / "undeformed", "none"))
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, indirect=reference, options=SolverOptions(max_iters=2))
    rep = result.report
    said = [note for note in rep["warnings"] if "read the frame out" in note]
    assert len(said) == 1 and "led_05.png's columns 0-54 (left) show led_04.png's light" in said[0], said
    assert "turned 90 degrees" in said[0] and "--flush" in said[0] and "for that LED only" in said[0]
    assert not any("repeats" in note or "are dark" in note for note in rep["warnings"])
    assert "leds_left_out" not in rep and said[0] in caplog.text and rep["led_gains"] is None
    assert rep["lagged_bands_left_out"] == [{"led": 4, "columns": [0, 55], "margin": tolerances.DARK_BAND_MARGIN}]


def test_dark_top_rows_of_an_led_image_are_named_and_only_those_rows_left_out_for_that_led(tmp_path, caplog):
    """LED 9's top 20 rows read while it was off (the dark frame's level): solved without a word about it, or with a
    wrong cause (the twin's presses, LED 5's top 20-60 rows: "misfitting pixels along the gel's edge ... vignetting";
    its top 200 rows: refused as another sensor's images; s29-darkrows); the rows, the cause and the fix are named.
    Then s29 left the LED out whole; now only its rows 0-19 and DARK_BAND_MARGIN more are left out, for LED 9 alone:
    the solve's usable LEDs there are one fewer than in the clean press's solve, and the same below. Not taken for a
    readout across the switch, for a repeat or for a weak LED."""
    options = SolverOptions(max_iters=2)
    clean = solve_press(_press(tmp_path, "clean"), options=options)
    press = _press(tmp_path, "rolling_dark", _rows_from({8: None}, 20))
    with caplog.at_level(logging.WARNING):
        result = solve_press(press, options=options)
    rep = result.report
    said = [note for note in rep["warnings"] if "are dark" in note]
    assert len(said) == 1 and "led_09.png's rows 0-19 (top) are dark" in said[0], said
    assert "--flush" in said[0] and "left out of the solve for that LED only" in said[0] and said[0] in caplog.text
    assert "leds_left_out" not in rep and 8 in rep["leds_used"]
    assert rep["dark_bands_left_out"] == [{"led": 8, "rows": [0, 20], "margin": tolerances.DARK_BAND_MARGIN}]
    fewer = clean.usable_leds.astype(int) - result.usable_leds
    edge = 20 + tolerances.DARK_BAND_MARGIN
    inside = result.mask & clean.mask
    assert (fewer[:edge][inside[:edge]] == 1).all() and (fewer[edge:][inside[edge:]] == 0).all()
    assert not any("read the frame out" in note or "repeats" in note or "weak" in note for note in rep["warnings"])


def test_an_exchange_of_an_image_with_a_dark_band_is_told_off_its_band(tmp_path, monkeypatch):
    """An LED image with a dark band got no exchange verdict against the LED model (its light is off the model in the
    band), so led_03.png and led_04.png exchanged, led_03.png's top 20 rows dark, were solved without a word where no
    --reference was given. Now its correlations are measured outside the band and the exchange refused as without
    one; the band in a clean image names none; where too little of the image lies outside its band the dark-band
    warning says that no exchange could be told there."""
    from nlipscalib.core.errors import CaptureError

    def exchanged_and_dark(lin):
        return _rows_from({2: None}, 20)(_exchanged(2, 3)(lin))

    press = _press(tmp_path, "exchanged_dark", exchanged_and_dark)
    found = led_check_measured(press, press.leds, range(12))
    assert [band.index for band in found.bands] == [2] and [e.leds for e in found.exchanged] == [(2, 3)]
    with pytest.raises(CaptureError) as refused:
        solve_press(press, options=SolverOptions(max_iters=2))
    line = str(refused.value)
    assert line.startswith(f"{press.folder}: led_03.png and led_04.png look exchanged (") and "\n" not in line
    assert "with LED 4's (outside its dark band)" in line and "--keep-led-order" in line
    dark_only = _press(tmp_path, "dark", _rows_from({2: None}, 20))
    found = led_check_measured(dark_only, dark_only.leds, range(12))
    assert [band.index for band in found.bands] == [2] and found.exchanged == []
    assert not any("too little" in note or "exchanged" in note for note in found.notes)
    monkeypatch.setattr(tolerances, "EXCHANGE_OFF_BAND_SHARE", 0.9)  # more than the band leaves
    found = led_check_measured(press, press.leds, range(12))
    assert found.exchanged == []
    (said,) = [note for note in found.notes if "are dark" in note]
    assert said.endswith(
        "; too little of led_03.png lies outside its band to tell an exchange with a neighbour's image there (solving "
        "with --reference, the undeformed dome's capture, tells it)"
    ), said


def test_dark_rows_of_the_undeformed_capture_are_named_and_left_out_for_that_led_there_and_in_the_press(tmp_path):
    """The undeformed capture a press is solved against (``indirect``, ``--reference``) with LED 9's top 20 rows read
    while it was off: nothing was said (the twin's sphere press against such a capture, LED 5's top 60 rows: contact
    AAE 0.622 deg, clean 0.509, "misfitting pixels along the gel's edge ... vignetting"); now the capture's rows are
    named with the fix, and left out for LED 9 in both captures (0.509): the solve's usable LEDs there one fewer."""
    options = SolverOptions(max_iters=2)
    press = _press(tmp_path, "pressed")
    clean = solve_press(press, indirect=load_press(synth.make_press(tmp_path / "undeformed", "none")), options=options)
    dark = load_press(synth.make_press(tmp_path / "undeformed_dark", "none", lin_hook=_rows_from({8: None}, 20)))
    result = solve_press(press, indirect=dark, options=options)
    rep = result.report
    said = [note for note in rep["warnings"] if "in the undeformed capture the press is solved against" in note]
    assert len(said) == 1 and said[0].startswith(f"{dark.folder}: led_09.png's rows 0-19 (top) are dark"), said
    assert rep["undeformed_dark_bands_left_out"] == [{"led": 8, "rows": [0, 20], "margin": tolerances.DARK_BAND_MARGIN}]
    assert "dark_bands_left_out" not in rep and "undeformed_dark_bands_left_out" not in clean.report
    fewer = clean.usable_leds.astype(int) - result.usable_leds
    edge = 20 + tolerances.DARK_BAND_MARGIN
    inside = result.mask & clean.mask
    assert (fewer[:edge][inside[:edge]] == 1).all() and (fewer[edge:][inside[edge:]] == 0).all()
    # its interreflection fit, kept under the capture's content, is not the unmasked capture's
    from nlipscalib.core.capture import with_unusable_samples
    from nlipscalib.solver.light_and_contact import capture_key

    masked = with_unusable_samples(dark, np.zeros((12, *dark.camera.shape), bool))
    assert capture_key(masked) != capture_key(dark)


def test_lagged_rows_of_the_undeformed_capture_are_named_and_left_out_for_that_led_there_and_in_the_press(tmp_path):
    """The undeformed capture a press is solved against with LED 9's top 20 rows read before the LEDs switched (LED
    8's light): its lagged bands were not looked for (its dark ones were, s30-darkcols), so the press was compared
    with LED 8's light there and LED 9's gain measured with it. Now named with the fix, once, and left out for LED 9
    in both captures (to the frame's edge, as a lagged band of the press), its gain measured off them."""
    options = SolverOptions(max_iters=2)
    press = _press(tmp_path, "pressed")
    clean = solve_press(press, indirect=load_press(synth.make_press(tmp_path / "undeformed", "none")), options=options)
    lagged = load_press(synth.make_press(tmp_path / "undeformed_lagged", "none", lin_hook=_rows_from({8: 7}, 20)))
    result = solve_press(press, indirect=lagged, options=options)
    rep = result.report
    said = [note for note in rep["warnings"] if "in the undeformed capture the press is solved against" in note]
    assert len(said) == 1 and said[0].startswith(f"{lagged.folder}: led_09.png's rows 0-19 (top) show led_08.png's")
    assert "to the frame's edge" in said[0] and "--flush" in said[0], said
    assert rep["undeformed_lagged_bands_left_out"] == [
        {"led": 8, "rows": [0, 20], "margin": tolerances.DARK_BAND_MARGIN}
    ]
    assert "undeformed_dark_bands_left_out" not in rep and "lagged_bands_left_out" not in rep
    assert rep["led_gains"] is None  # LED 9 measured off its band: as bright as the press's
    fewer = clean.usable_leds.astype(int) - result.usable_leds
    edge = 20 + tolerances.DARK_BAND_MARGIN
    inside = result.mask & clean.mask
    assert (fewer[:edge][inside[:edge]] == 1).all() and (fewer[edge:][inside[edge:]] == 0).all()


def test_a_repeated_image_in_the_undeformed_capture_is_named_once_and_its_led_left_out_of_the_solve(tmp_path):
    """The undeformed capture a press is solved against with LED 9's whole image LED 8's (a dropped frame): its
    lagged and dark bands were looked for, not whole repeated images (s31-darkleft), so the press's LED 9 was
    compared with LED 8's light, its gain measured with it, and the interreflection fitted on it. Now named once with
    the fix and LED 9 left out of the solve, as a repeated press image is."""
    options = SolverOptions(max_iters=2)
    press = _press(tmp_path, "pressed")
    repeated = load_press(synth.make_press(tmp_path / "undeformed_repeated", "none", lin_hook=_rows_from({8: 7}, 72)))
    result = solve_press(press, indirect=repeated, options=options)
    rep = result.report
    said = [note for note in rep["warnings"] if "in the undeformed capture the press is solved against" in note]
    assert len(said) == 1 and said[0].startswith(f"{repeated.folder}: led_09.png repeats led_08.png"), said
    assert "--flush" in said[0] and "that LED is left out of the solve" in said[0], said
    assert rep["leds_left_out"] == [8] and rep["undeformed_repeated_left_out"] == [8], rep.get("leds_left_out")
    assert rep["led_gains"] is None  # LED 9's ratio (LED 8's light) not measured as a gain
    assert result.usable_leds.max() == len(press.leds) - 1  # no pixel solved with LED 9
    assert "undeformed_lagged_bands_left_out" not in rep and "undeformed_dark_bands_left_out" not in rep


def test_dark_columns_and_a_few_dark_rows_of_an_led_image_are_named(tmp_path):
    """A camera mounted turned 90 degrees: its rolling shutter reads the columns, and LED 9's first 20 columns were
    read while it was off; a short glitch darkened LED 4's rows 30-32 (under the 15 rows of the bands). Neither was
    named before (s29-darkrows: rows of 15 or more only); now both are, with their columns and rows."""

    def hook(lin):
        lin = lin.copy()
        lin[8, :, :20] = 0.0
        lin[3, 30:33] = 0.0
        return lin

    press = _press(tmp_path, "dark_columns", hook)
    notes, _, _, _ = led_check(press, press.leds, range(len(press.leds)))
    said = [note for note in notes if "are each dark" in note]
    assert len(said) == 1, notes
    assert "led_04.png's rows 30-32 (middle)" in said[0] and "led_09.png's columns 0-19 (left)" in said[0], said


def test_the_check_of_too_few_live_leds_says_nothing_in_the_shape_of_every_answer(tmp_path):
    """With fewer than 3 live LEDs nothing is judged: empty notes, nothing left out, no dark bands (the solve
    unpacks the six answers whichever path gave them)."""
    press = _press(tmp_path, "few")
    assert led_check_measured(press, press.leds, [0, 1]) == ([], [], [], None, None, [], [])


def test_rows_dark_in_every_led_image_are_warned_about_and_no_led_is_left_out(tmp_path):
    press = _press(tmp_path, "all_dark", _rows_from(dict.fromkeys(range(12)), 15))
    notes, left_out, _, _ = led_check(press, press.leds, range(len(press.leds)))
    said = [note for note in notes if "are dark" in note]
    assert len(said) == 1 and "rows 0-14 (top) of every LED image are dark" in said[0], said
    assert "no LED can be left out" in said[0] and left_out == []


def test_a_few_rows_dark_in_every_led_image_are_warned_about_to_the_row(tmp_path):
    """Rows 30-32 of every LED image read while no LED was lit: under the blocks' run of 15 rows nothing was said
    (one LED's short band was named since s30-darkcols, every LED's not); now to the row, by the images alone, and
    not as each LED's dark rows."""

    def hook(lin):
        lin = lin.copy()
        lin[:, 30:33] = 0.0
        return lin

    press = _press(tmp_path, "all_dark_short", hook)
    notes, left_out, _, _ = led_check(press, press.leds, range(len(press.leds)))
    said = [note for note in notes if "are dark" in note]
    assert len(said) == 1 and "rows 30-32 (middle) of every LED image are dark" in said[0], said
    assert "no LED can be left out" in said[0] and left_out == []


def test_a_clean_press_and_a_deep_press_filling_the_frame_have_no_dark_rows(tmp_path):
    """A contact's flank turned away from an LED is dark in that LED's image where the undeformed dome's model
    lights it, but in part of a row, not whole rows: a deep dent (3 mm) with the frame cropped on it is not named."""
    centre = synth.dent_centre() + np.array([0.0, 4.0, 0.0])  # the dent at the frame's top edge
    for name, kind, cam in (
        ("clean", "sphere", None),
        ("edge", "sphere", synth.crop_camera((480, 360), (96, 72), centre)),
        ("filled", "cube", synth.crop_camera((480, 360), (96, 72), synth.dent_centre())),
    ):
        press = load_press(synth.make_press(tmp_path / name, kind, depth=3.0 if cam else 1.5, cam=cam))
        assert press.ground_truth.contact.any(axis=1).mean() > (0.2 if cam is None else 0.7)
        notes, left_out, _, _ = led_check(press, press.leds, range(len(press.leds)))
        assert not any("are dark" in note for note in notes) and left_out == [], (name, notes)


def test_every_led_image_read_out_across_its_switch_is_named_as_a_systematic_timing_error(tmp_path):
    """Every LED frame's top third read out before its LED switched (LED 1's: the dark frame's): neighbouring
    images then share no rows' light, so only the LED model tells; the rows are named, for every image. A camera
    turned 90 degrees reads the columns so: its left columns were not looked at (rows only, before s31-darkall);
    now they are named as columns, and the rows are not."""
    shifted = {k: (k - 1 if k else None) for k in range(12)}
    for axis, lines, where in (("rows", 24, "(top)"), ("columns", 32, "(left)")):
        press = _press(tmp_path, f"rolling_all_{axis}", _rows_from(shifted, lines, axis))
        notes, _, _, _ = led_check(press, press.leds, range(len(press.leds)))
        said = [note for note in notes if "of the LED images show the light of the LED captured before each" in note]
        assert len(said) == 1 and f": {axis} 0-" in said[0] and where in said[0], (axis, notes)
        assert "every frame alike" in said[0] and "--flush" in said[0]
        assert ("turned 90 degrees" in said[0]) == (axis == "columns")


def test_leds_aged_on_their_own_are_measured_per_led_and_named_in_the_drift_note(tmp_path):
    """Per-LED gains against the undeformed capture (``led_gains``): None for a press taken as the capture was
    (within ``LED_GAIN_CORRECTION``: as captured, solved as before); the red group's 0.9 when it aged on its own, the
    others 1; an LED whose image shows another LED's light kept at 1; the drift note names the rescaled LEDs."""
    from nlipscalib.solver.led_checks import exposure_drift_note, exposure_ratio, led_gains

    reference = load_press(synth.make_press(tmp_path / "reference", "none"))
    steady = _press(tmp_path, "steady")
    assert led_gains(exposure_ratio(steady, reference)) is None
    red_aged = _press(tmp_path, "red", lambda lin: lin * np.repeat([0.9, 1.0, 1.0], 4)[:, None, None, None])
    ratio = exposure_ratio(red_aged, reference)
    gains = led_gains(ratio)
    assert gains is not None and np.allclose(gains, np.repeat([0.9, 1.0, 1.0], 4)[:, None], atol=0.01), gains
    assert np.array_equal(led_gains(ratio, misplaced=[0])[0], [1.0, 1.0, 1.0])
    note = exposure_drift_note(red_aged, reference, ratio, gains)
    assert "LED 4 (led_04.png) 0.90" in note and "LED 5" not in note and "report.json led_gains" in note
    assert "LED 1" not in exposure_drift_note(red_aged, reference, ratio).split("most changed")[1]


# The twin's design LEDs against its sphere press (benchmarks/RESULTS.md, s28-noref: model_relative_gains), as
# captured and with its red group 5 % dimmer: the LED model's own error puts LEDs 1 and 7 3 % low on every press.
AS_CAPTURED = [0.972, 0.994, 1.007, 1.015, 1.009, 0.990, 0.966, 0.989, 1.004, 1.012, 1.010, 0.996]
RED_5_PERCENT = [0.936, 0.952, 0.968, 0.976, 1.020, 1.001, 0.975, 0.999, 1.014, 1.021, 1.023, 1.011]


def test_without_a_reference_the_model_error_is_no_ageing_but_a_dimmer_group_is_judged_as_one():
    """Against the LED model alone an LED's gain carries the model's error (0.966-1.022 as captured): rescaling
    every LED by it made the solve worse, rescaling LEDs beyond 5 % one by one caught a 5 % dimmer red group's LED 1
    alone (1.60 deg instead of 0.50). As captured nothing is off; the 5 % group is one gain on its four LEDs; one
    LED 15 % dimmer is caught on its own."""
    from nlipscalib.core.leds import tricolor_groups
    from nlipscalib.solver.led_checks import model_led_gains

    groups = tricolor_groups(12)
    assert model_led_gains(np.array(AS_CAPTURED), groups) is None
    gains = model_led_gains(np.array(RED_5_PERCENT), groups)
    assert gains is not None and np.allclose(gains[:4], gains[0]) and 0.95 < gains[0] < 0.97
    assert np.array_equal(gains[4:], np.ones(8))
    one = np.array(AS_CAPTURED) * np.where(np.arange(12) == 4, 0.85, 1.0)
    gains = model_led_gains(one, groups)
    assert gains is not None and np.flatnonzero(gains != 1).tolist() == [4] and 0.84 < gains[4] < 0.88


def test_without_a_reference_an_led_group_aged_on_its_own_is_named_and_rescaled(tmp_path, caplog):
    """Without ``--reference`` the red group 10 % dimmer was solved without a word (the twin's sphere press 4.8 deg,
    cube 5.5 deg: only LEDs below 0.6 of the model were named). The solve now names the LEDs, the remedy, rescales
    their images (report.json led_gains) and lands near the clean solve, warned once for a session's presses; a clean
    press gets neither."""
    options = SolverOptions(max_iters=4)
    clean = solve_press(_press(tmp_path, "clean"), options=options)
    assert clean.report["led_gains"] is None
    assert not any("LED model expects" in note for note in clean.report.get("warnings", []))
    dimmer = np.repeat([0.9, 1.0, 1.0], 4)[:, None, None, None]
    red_aged = _press(tmp_path, "red", lambda lin: lin * dimmer)
    with caplog.at_level(logging.WARNING):
        result = solve_press(red_aged, options=options)
    said = [note for note in result.report.get("warnings", []) if "LED model expects" in note]
    assert len(said) == 1 and said[0] in caplog.text
    assert "LED 1 (led_01.png) 0.90" in said[0] and "LED 4 (led_04.png) 0.90" in said[0] and "LED 5" not in said[0]
    assert "--reference" in said[0] and "nlips calibrate-leds" in said[0]
    gains = np.array(result.report["led_gains"])
    assert np.allclose(gains[:4], 0.9, atol=0.01) and np.array_equal(gains[4:], np.ones((8, 3)))
    contact = red_aged.ground_truth.contact
    off = np.abs(result.depth - clean.depth)[contact & result.reconstructed & clean.reconstructed]
    assert np.median(off) < 0.01, np.median(off)
    caplog.clear()  # the sensor's fault: a session's next press keeps it in its report, said at INFO
    with caplog.at_level(logging.INFO):
        again = solve_press(_press(tmp_path, "red2", lambda lin: lin * dimmer), options=options)
    assert any("LED model expects" in note for note in again.report["warnings"])
    said = [r.levelno for r in caplog.records if "LED model expects" in r.getMessage()]
    assert said == [logging.INFO], said


def test_without_a_reference_the_led_ageing_check_reuses_the_weak_led_checks_samples(tmp_path, monkeypatch):
    """The no-reference ageing check (model_gain_check) sampled the gel and shaded it with every live LED a second
    time, after the weak-LED check (led_check) had done the same. A solve now samples them once; the gains it passes
    on are the ones measured afresh, bit for bit, and another set of LEDs is measured anew."""
    from nlipscalib.solver import led_checks
    from nlipscalib.solver.led_checks import led_check_measured, model_gain_check

    dimmer = np.repeat([0.9, 1.0, 1.0], 4)[:, None, None, None]
    press = _press(tmp_path, "red", lambda lin: lin * dimmer)
    every = list(range(12))
    measured = led_check_measured(press, press.leds, every)[4]
    assert measured is not None and measured.live == tuple(every)
    fresh = model_gain_check(press, press.leds, every)
    shared = model_gain_check(press, press.leds, every, measured)
    assert fresh[0] == shared[0] and np.array_equal(fresh[1], shared[1])
    assert fresh[1] is not None and np.allclose(fresh[1][:4], 0.9, atol=0.01)
    fewer = every[1:]
    assert np.array_equal(
        model_gain_check(press, press.leds, fewer, measured)[1], model_gain_check(press, press.leds, fewer)[1]
    )

    direct, real = [], led_checks._sampled
    monkeypatch.setattr(
        led_checks,
        "_sampled",
        lambda p, leds, live, indirect=None: direct.append(indirect is None) or real(p, leds, live, indirect),
    )
    result = solve_press(press, options=SolverOptions(max_iters=1))
    assert result.report["led_gains"] is not None
    assert sum(direct) == 1, direct  # the direct shading's samples: once (the linearity check adds its own)


def test_relative_gains_stay_finite_when_the_judged_leds_light_none_of_the_model_lit_samples():
    """The ring's LEDs 80 deg off their design (test_calibrate's far-from-design case): the dark-band check took 8 of
    12 LED images as banded, and 2 of the 4 left lit none of the samples, so their median gain 0 scaled every LED's to
    inf / NaN (a RuntimeWarning in CI). The lit LEDs set the scale then."""
    from nlipscalib.solver.led_checks import _relative_gains

    image = np.ones((4, 10, 3))
    image[:2] = 0.0  # LEDs 1 and 2: no light where the model has it
    model = np.ones((4, 10, 3))
    with np.errstate(divide="raise", invalid="raise"):
        relative = _relative_gains(image, model, judged=[0, 1, 2])
    np.testing.assert_array_equal(relative, [0.0, 0.0, 1.0, 1.0])
    with np.errstate(divide="raise", invalid="raise"):
        np.testing.assert_array_equal(_relative_gains(np.zeros((3, 5, 3)), np.ones((3, 5, 3))), [0.0, 0.0, 0.0])
    np.testing.assert_allclose(_relative_gains(image * 2, model, judged=[2, 3]), [0.0, 0.0, 1.0, 1.0])


def test_a_slope_asked_to_fit_a_power_law_is_not_told_from_images_that_follow_none():
    """``nlips capture``'s reference check asks the power law to fit (tolerances.RESPONSE_POWER_LAW_FIT): flat test
    frames of another scene gave slope 0.06 and were named a tone curve where the black level was the fault (s37).
    A gamma-encoded image fits (its slope told); one unrelated to the model does not (None); without ``min_fit``,
    as the solve asks, both slopes are told as before."""
    rng = np.random.default_rng(0)
    model = rng.uniform(0.05, 0.8, (12, 500, 1)).repeat(3, axis=2)  # grey: the channels averaged alike
    encoded = model ** (1 / 2.2)
    unrelated = rng.uniform(0.05, 0.8, (12, 500, 3))
    fit = tolerances.RESPONSE_POWER_LAW_FIT
    assert response_slope(encoded, model, min_fit=fit) == pytest.approx(1 / 2.2, abs=1e-6)
    assert response_slope(unrelated, model, min_fit=fit) is None
    assert abs(response_slope(unrelated, model)) < 0.2


def test_a_contact_over_most_of_the_gel_is_no_led_gain_when_the_solve_box_holds_it(tmp_path):
    """``exposure_ratio`` measures on the gel outside the solve's box: a contact whose shading changes one LED's
    image over most of the gel (here LED 1 at 0.9 inside a box of 60 % of the frame, as the twin's flat pad pressed
    by a 5 mm cube moved LEDs 1 and 12 by 2-3 %) is no gain outside it, so the solve rescales no image; over the whole
    gel the median took the contact's 0.9 for LED 1's gain (benchmarks/RESULTS.md, s41-flatcube)."""
    reference = load_press(synth.make_press(tmp_path / "reference", "none"))
    H, W = reference.camera.shape
    box = (0, 0, int(W * 0.6), H)  # (x0, y0, w, h)

    def shaded(lin):
        lin = lin.copy()
        lin[0, :, : box[2]] *= 0.9
        return lin

    press = _press(tmp_path, "wide", shaded)
    outside = np.ones((H, W), bool)
    outside[:, : box[2]] = False
    assert np.allclose(exposure_ratio(press, reference)[0], 0.9, atol=0.01)  # the contact's, over the whole gel
    ratio = exposure_ratio(press, reference, outside=outside)
    assert np.allclose(ratio, 1.0, atol=0.005), ratio
    rep = solve_press(press, indirect=reference, roi=box).report
    assert rep["led_gains"] is None
    assert solve_press(press, indirect=reference, roi=(0, 0, W, H)).report["led_gains"] is not None  # no outside


def test_a_contact_over_most_of_the_gel_is_no_led_gain_with_the_auto_roi(tmp_path):
    """``--roi auto`` finds its box on the images as they are before the per-LED gains are measured, which are then
    taken outside it as with an explicit box: LED 1's image shaded to 0.9 over the right 62 % of the frame, around the
    dent (a change over most of the gel, as the twin's flat pad pressed by a 5 mm cube moved 7 of 12 LEDs' whole-gel
    medians by 1-3 %), is no gain outside the box, so no image is rescaled. Before, the whole gel's median took it for
    LED 1's gain and the solve rescaled its image (benchmarks/RESULTS.md, s41-autogain)."""
    reference = load_press(synth.make_press(tmp_path / "reference", "none"))

    def shaded(lin):
        lin = lin.copy()
        lin[0, :, 36:] *= 0.9
        return lin

    press = _press(tmp_path, "wide", shaded)
    assert led_gains(exposure_ratio(press, reference)) is not None  # the whole gel's median: a gain
    rep = solve_press(press, indirect=reference, roi="auto", options=SolverOptions(max_iters=2)).report
    x0, y0, w, h = rep["roi"]
    assert w * h > 0.5 * press.camera.shape[0] * press.camera.shape[1]  # the box holds most of the gel
    assert rep["led_gains"] is None


def test_only_leds_both_measures_find_astray_the_same_way_are_rescaled():
    """Known answer of ``agreed_gains``: LED 1 strays on both (0.98, 0.985): rescaled by the outside's 0.985; LED 2 only
    outside the box (0.985), LED 3 only on the whole gel (1.02), LED 4 both ways but apart (0.98 against 1.02), one
    channel of LED 5 on both (0.97, 0.98): its whole LED by the outside's. The others as captured (1)."""
    whole = np.ones((6, 3))
    away = np.ones((6, 3))
    whole[0], away[0] = 0.98, 0.985
    whole[1], away[1] = 0.995, 0.985
    whole[2], away[2] = 1.02, 1.005
    whole[3], away[3] = 0.98, 1.02
    whole[4, 2], away[4] = 0.97, [0.999, 1.0, 0.98]
    gains = agreed_gains(whole, away)
    expected = np.ones((6, 3))
    expected[0], expected[4] = 0.985, [0.999, 1.0, 0.98]
    assert np.array_equal(gains, expected)
    assert agreed_gains(whole[1:4], away[1:4]) is None  # none stray on both the same way
    assert agreed_gains(whole, None) is None  # no gain outside the box
