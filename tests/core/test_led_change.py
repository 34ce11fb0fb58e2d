"""Two LED calibrations of one sensor compared (core.led_change, `nlips calibrate-leds --previous`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.led_change import (
    check_previous_sensor,
    compare_calibrations,
    led_brightness_ratios,
    light_level,
    overall_brightness_ratio,
)
from nlipscalib.core.ledfile import LedFile, read_led_file, save_leds
from nlipscalib.core.sensor_record import describe_sensor
from tests.solver import synth


def _scaled(leds, gains):
    """``leds`` with each LED's Psi times its gain (all channels)."""
    return tuple(
        dataclasses.replace(led, intensity=tuple(g * np.asarray(led.intensity))) for led, g in zip(leds, gains)
    )


def _file(leds, not_fitted=(), level=None):
    return LedFile(tuple(leds), describe_sensor(synth.camera(), leds), tuple(not_fitted), light_level=level)


def _level(gain=1.0, exposure_ms=10.0):
    """A light level of 12 LEDs (:func:`light_level`'s record), each LED's ``gain`` times a fixed one."""
    base = np.linspace(0.2, 0.4, 36).reshape(12, 3)
    return {"gel_median": (base * np.reshape(gain, (-1, 1))).tolist(), "exposure_ms": exposure_ms, "gain": 1.0}


def test_brightness_ratios_are_relative_to_the_median_led_whatever_the_gauge():
    """A group dimmed to 0.9 reads 0.9 and the others 1, though the gauge (mean Psi = 1) rescales every LED."""
    leds = synth.ring_leds(jitter=3)
    gains = np.where(np.arange(12) < 4, 0.9, 1.0)
    aged = _scaled(leds, gains / gains.mean())  # as a new calibration's gauge has it
    assert np.allclose(led_brightness_ratios(leds, aged), gains)


def test_an_aged_group_is_one_change_and_an_led_on_its_own_another():
    leds = synth.ring_leds(jitter=3)
    gains = np.ones(12)
    gains[4:8] = 0.9  # the green group
    gains[10] = 1.12  # LED 11 alone
    compared = compare_calibrations(_file(leds), "old.json", _scaled(leds, gains))
    group, single = compared["changes"]
    assert group.startswith("LEDs 5-8 (the green tri-colour group) give 0.90 times") and "old.json" in group
    assert single.startswith("LED 11 gives 1.12 times"), single
    assert compared["brightness"][4] == pytest.approx(0.9)


def test_an_led_within_its_aged_group_is_not_named_again_nor_an_unchanged_sensor():
    leds = synth.ring_leds(jitter=3)
    assert compare_calibrations(_file(leds), "old.json", leds)["changes"] == []
    gains = np.where(np.arange(12) < 4, 0.9, 1.0)
    gains[0] = 0.88  # within the LED tolerance of its group's 0.9
    (only,) = compare_calibrations(_file(leds), "old.json", _scaled(leds, gains))["changes"]
    assert only.startswith("LEDs 1-4")


def test_a_moved_or_turned_led_is_named_and_a_not_fitted_one_is_not_compared():
    leds = list(synth.ring_leds(jitter=3))
    moved = list(leds)
    moved[2] = dataclasses.replace(leds[2], position=tuple(np.add(leds[2].position, (0.8, 0.0, 0.0))))
    moved[6] = dataclasses.replace(leds[6], intensity=(0.5, 0.5, 0.5))  # held at its start: not a change
    compared = compare_calibrations(_file(leds), "old.json", moved, not_fitted=(6,))
    (line,) = compared["changes"]
    assert line.startswith("LED 3 sits 0.80 mm"), line
    assert np.isnan(compared["brightness"][6]) and np.isnan(compared["moved_mm"][6])


def test_a_previous_file_of_another_sensor_or_of_none_is_refused():
    leds = synth.ring_leds()
    ours = describe_sensor(synth.camera(), leds)
    check_previous_sensor(_file(leds), "old.json", ours, "ref")  # the same sensor: accepted
    other = LedFile(leds, describe_sensor(synth.camera(48, 36), leds))
    with pytest.raises(CaptureError, match=r"^--previous old.json: calibrated on another sensor than ref \(image"):
        check_previous_sensor(other, "old.json", ours, "ref")
    with pytest.raises(CaptureError, match="records no sensor"):
        check_previous_sensor(LedFile(leds, None), "old.json", ours, "ref")


def test_light_level_is_the_gels_median_above_the_dark_frame_and_scales_with_the_leds(tmp_path):
    """Every LED image 0.9 times as bright (aged alike, or a shorter exposure) reads 0.9, though the calibrations'
    gauge (mean Psi = 1) gives both the same Psi."""
    first = load_press(synth.make_press(tmp_path / "a", kind="none"))
    dimmed = load_press(synth.make_press(tmp_path / "b", kind="none", lin_hook=lambda lin: 0.9 * lin))
    level, dim = light_level([first]), light_level([dimmed])
    gel = np.isfinite(first.reference.depth)
    assert np.allclose(level["gel_median"][2], np.median(first.linear_led_images[2][gel], axis=0))
    assert level["exposure_ms"] == first.response.exposure_ms and level["gain"] == first.response.gain
    assert overall_brightness_ratio(level, dim) == pytest.approx(0.9, abs=1e-3)
    assert overall_brightness_ratio(level, light_level([first, dimmed])) == pytest.approx(0.95, abs=1e-3)
    swapped = light_level([first], order=[1, 0] + list(range(2, 12)))  # LEDs 1 and 2 fitted to each other's image
    assert swapped["gel_median"][0] == level["gel_median"][1] and swapped["gel_median"][2] == level["gel_median"][2]


def test_all_leds_dimmed_alike_are_one_change_the_shares_cannot_see():
    leds = synth.ring_leds(jitter=3)
    compared = compare_calibrations(_file(leds, level=_level()), "old.json", leds, level=_level(0.9))
    (line,) = compared["changes"]
    assert line.startswith("all LEDs together give 0.90 times the light they gave in old.json"), line
    assert "every LED aged alike" in line
    assert compared["overall_brightness"] == pytest.approx(0.9)
    assert compare_calibrations(_file(leds, level=_level()), "old.json", leds, level=_level(1.02))["changes"] == []
    # one group aged alone: the group's share, not all LEDs (the sum of the 12 went to 0.967)
    group = np.where(np.arange(12) < 4, 0.9, 1.0)
    compared = compare_calibrations(_file(leds, level=_level()), "old.json", _scaled(leds, group), level=_level(group))
    (line,) = compared["changes"]
    assert line.startswith("LEDs 1-4") and compared["overall_brightness"] == pytest.approx(1.0)
    # the camera's exposure halved: named as the cause; an older file without a level: not compared
    (line,) = compare_calibrations(_file(leds, level=_level()), "o", leds, level=_level(0.5, 5.0))["changes"]
    assert "exposure or gain changed (10 ms at gain 1, now 5 ms at gain 1)" in line, line
    unknown = compare_calibrations(_file(leds), "old.json", leds, level=_level(0.5))
    assert unknown["changes"] == [] and unknown["overall_brightness"] is None


def test_the_overall_level_leaves_out_the_leds_not_fitted_and_sorts_first():
    leds = synth.ring_leds(jitter=3)
    gains = np.full(12, 0.9)
    gains[3] = 0.0  # a stale frame here: not fitted, not counted
    compared = compare_calibrations(_file(leds, level=_level()), "old.json", leds, (3,), _level(gains))
    assert compared["overall_brightness"] == pytest.approx(0.9)
    moved = list(leds)
    moved[0] = dataclasses.replace(leds[0], position=tuple(np.add(leds[0].position, (0.8, 0.0, 0.0))))
    first, led1 = compare_calibrations(_file(leds, level=_level()), "old.json", moved, level=_level(0.9))["changes"]
    assert first.startswith("all LEDs together") and led1.startswith("LED 1 sits")


def test_an_led_file_keeps_its_light_level_and_a_malformed_one_is_refused(tmp_path):
    leds = synth.ring_leds()
    path = save_leds(tmp_path / "leds.json", leds, {"light_level": _level()})
    assert read_led_file(path).light_level == _level()
    assert read_led_file(save_leds(tmp_path / "old.json", leds)).light_level is None
    bad = save_leds(tmp_path / "bad.json", leds, {"light_level": _level() | {"gel_median": [[1.0, 2.0, 3.0]]}})
    with pytest.raises(CaptureError, match=r"bad.json: not a valid LED file \('light_level.gel_median' must hold 12"):
        read_led_file(bad)


def test_two_leds_in_each_others_place_are_one_exchange_and_a_moved_led_stays_moved():
    """led_01.png and led_02.png captured in each other's place calibrate LED 1 at LED 2's place and back: it was
    said as two LEDs "loosened, bent or replaced" 4.6 mm off. Now one line names the exchange; an LED that moved
    on its own (LED 7 by 2 mm) is still said as moved."""
    leds = synth.ring_leds(jitter=3)
    new = list(leds)
    new[0], new[1] = leds[1], leds[0]
    new[6] = dataclasses.replace(leds[6], position=tuple(np.add(leds[6].position, (2.0, 0.0, 0.0))))
    exchange, moved = compare_calibrations(_file(leds), "old.json", tuple(new))["changes"]
    assert exchange.startswith("LEDs 1 and 2 each sit where the other did in old.json"), exchange
    assert "captured in each other's place" in exchange
    assert moved.startswith("LED 7 sits 2.00 mm"), moved


def test_what_only_one_file_holds_is_said_as_not_compared_and_disks_in_both_are_compared_as_disks():
    """An OLD file written before light_level (s32-ledaged's r8.json, which holds disks): the command said "no LED
    changed beyond the tolerances" with every LED's common light never judged, and compared the point LEDs though
    both files held the disks. Now the disks' places are compared where both hold them (an LED disk moved 0.8 mm while
    its point stayed: named), and what only one file holds is one item each of ``not_compared``."""
    leds = synth.ring_leds(jitter=3)
    disks = tuple(dataclasses.replace(led, position=tuple(np.add(led.position, (0.0, 0.0, 0.23)))) for led in leds)
    moved = list(disks)
    moved[5] = dataclasses.replace(disks[5], position=tuple(np.add(disks[5].position, (0.8, 0.0, 0.0))))
    old = LedFile(tuple(leds), describe_sensor(synth.camera(), leds), emitters=disks, emitter_radius=1.8)
    both = compare_calibrations(old, "old.json", leds, level=_level(), emitters=tuple(moved))
    assert both["places"] == "disks" and both["moved_mm"][5] == pytest.approx(0.8)
    assert both["not_compared"] == [
        "all LEDs' light together (old.json records no light_level: written before 2026-12-06)"
    ]
    assert [line[:23] for line in both["changes"]] == ["LED 6 sits 0.80 mm and "]
    points = compare_calibrations(old, "old.json", leds, level=_level())  # this calibration fitted no disks
    assert points["places"] == "points" and points["changes"] == []
    assert points["not_compared"][1] == "the LED disks (only old.json holds them: the places compared as point LEDs)"
    full = _file(leds, level=_level())
    assert compare_calibrations(full, "old.json", leds, level=_level())["not_compared"] == []
