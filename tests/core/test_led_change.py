"""Two LED calibrations of one sensor compared (core.led_change, `nlips calibrate-leds --previous`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.core.led_change import check_previous_sensor, compare_calibrations, led_brightness_ratios
from nlipscalib.core.ledfile import LedFile
from nlipscalib.core.sensor_record import describe_sensor
from tests.solver import synth


def _scaled(leds, gains):
    """``leds`` with each LED's Psi times its gain (all channels)."""
    return tuple(
        dataclasses.replace(led, intensity=tuple(g * np.asarray(led.intensity))) for led, g in zip(leds, gains)
    )


def _file(leds, not_fitted=()):
    return LedFile(tuple(leds), describe_sensor(synth.camera(), leds), tuple(not_fitted))


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
