"""The lag-band check's cost and the LED pairs it is blind to (s36-lagcost): its LED model kept per design in a
process, each line's median tested by counts to the bit, and the consecutive LEDs a lag between which it cannot see
named once.

The designs: nlipstac's dome and camera at 160x120 (the undeformed surface computed analytically, no render), its
12 LEDs on the 9 mm ring either evenly (the shipped ring) or in six pairs ``apart`` mm apart (s35-exchange's copy)."""

import dataclasses
import logging
import math

import numpy as np
import pytest

from nlipscalib.core import repeated_frames as rf
from nlipscalib.core import said_once
from nlipscalib.core.dome import reference_surface
from nlipscalib.core.lag_blind import lag_blind_pairs, say_lag_blind
from nlipscalib.core.sensor import shipped_design
from nlipscalib.core.tolerances import LAG_BLIND_SHARE


def _design(apart: float | None):
    """nlipstac at 160x120; ``apart`` mm: its LEDs in six pairs that far apart along the ring (None: as shipped)."""
    design = shipped_design("nlipstac")
    design = dataclasses.replace(design, camera=dataclasses.replace(design.camera, width=160, height=120))
    if apart is not None:
        angles = [math.pi * g / 3 + (k - 0.5) * apart / 9.0 for g in range(6) for k in range(2)]
        tilt = math.radians(20.0)
        places = tuple((9.0 * math.cos(a), 9.0 * math.sin(a), 0.0) for a in angles)
        axes = tuple((-math.sin(tilt) * math.cos(a), -math.sin(tilt) * math.sin(a), math.cos(tilt)) for a in angles)
        design = dataclasses.replace(design, leds=dataclasses.replace(design.leds, positions=places, directions=axes))
    return design


def _model(apart: float | None) -> tuple[rf.ModelLight, np.ndarray]:
    """A fresh ModelLight of :func:`_design` (its own arrays: what a second capture of the design loads) and the gel."""
    design = _design(apart)
    reference = reference_surface(design)
    model = rf.model_light(reference.depth, reference.normals, design.camera_model(), design.led_models())
    return model, np.isfinite(reference.depth)


def _images(model: rf.ModelLight, gel: np.ndarray, rng) -> np.ndarray:
    """(L, H, W, 3) linear LED images of the model's light (albedo 0.5 over the median LED's, 0.5 % noise)."""
    rows, cols = np.nonzero(gel)
    light = model.each(rows, cols)
    images = np.zeros((len(light), *gel.shape, 3))
    images[:, rows, cols] = (0.3 * light / np.median(light))[..., None]
    return images * (1 + rng.normal(0, 0.005, images.shape))


@pytest.mark.parametrize("seed", range(6))
def test_each_lines_median_against_a_threshold_is_told_by_counts_as_the_sorted_median_tells_it(seed):
    """Random lines with ties at the threshold, even and odd counts, half the values under it, and NaN: the counts'
    verdict equals the sorted median's, either way round, on every line."""
    rng = np.random.default_rng(seed)
    shape = (60, 17)
    ties = rng.choice([0.005, 0.01, 0.015, 0.02, 0.025, 0.04], size=shape)
    values = np.where(rng.random(shape) < 0.5, ties, rng.uniform(0, 0.04, shape))
    values[rng.random(shape) < 0.02] = np.nan
    lit = rng.random(values.shape) < 0.8
    lit[:, :2] = True
    lines = rf.Lines(lit, np.count_nonzero(lit, axis=1))
    counted = rng.random(60) < 0.9
    medians = rf._row_medians(values[counted], lit[counted])
    for threshold in (0.01, 0.02):
        at_least = rf.median_at_least(values, lines, counted, threshold)
        under = rf.median_at_least(values, lines, counted, threshold, below=True)
        assert np.array_equal(at_least, medians >= threshold)
        assert np.array_equal(under, medians < threshold)
    # a line of an even count with half its values under the threshold: the median decides (both ways)
    tie = np.array([[0.01, 0.03, 0.005, 0.04], [0.01, 0.02, 0.005, 0.03]])
    both = rf.Lines(np.ones(tie.shape, bool), np.full(2, 4))
    assert rf.median_at_least(tie, both, np.ones(2, bool), 0.02).tolist() == [True, False]


def test_the_model_is_computed_once_per_design_and_anew_for_another(monkeypatch):
    """Two captures of one design (each its own arrays, as a press and its undeformed capture load them) share
    the LED model's blocks; a design with its LEDs elsewhere gets its own, and both checks say the same as with
    a fresh computation."""
    rng = np.random.default_rng(0)
    first, gel = _model(0.8)
    images = _images(first, gel, rng)
    images[2, :45] = images[1, :45]  # LED 3's frame read across its switch: its top rows hold LED 2's light
    ring, ring_gel = _model(None)
    ring_images = _images(ring, ring_gel, rng)
    rf._MODEL_BLOCKS.clear()
    calls = []
    each = rf.ModelLight.each
    monkeypatch.setattr(rf.ModelLight, "each", lambda self, r, c: calls.append(len(r)) or each(self, r, c))
    found = rf.frame_checks(images, gel, first)
    assert [(band.index, band.axis, band.top) for band in found[1]] == [(2, "rows", True)]
    again, _ = _model(0.8)
    assert rf.frame_checks(images, gel, again) == found and len(calls) == 1
    rf.frame_checks(ring_images, ring_gel, ring)
    assert len(calls) == 2
    rf._MODEL_BLOCKS.clear()
    assert rf.frame_checks(images, gel, again) == found and len(calls) == 3


def test_leds_in_close_pairs_are_named_as_pairs_a_lag_between_which_goes_unseen_and_the_ring_is_not():
    """LEDs 0.5 mm apart: every pair named (LED 1 to 2, 3 to 4, ...), a band over half the lines or more unseen;
    1.2 mm apart the blind share is under the half of 0.5 mm's; the shipped ring: none."""
    rf._MODEL_BLOCKS.clear()
    close = lag_blind_pairs(*_model(0.5))
    assert [pair.leds for pair in close] == [(k, k + 1) for k in range(0, 12, 2)]
    assert all(pair.unseen >= 0.5 and pair.apart == pytest.approx(0.5, abs=0.01) for pair in close)
    wider = lag_blind_pairs(*_model(1.2))
    assert all(pair.unseen < min(p.unseen for p in close) / 2 for pair in wider)
    assert lag_blind_pairs(*_model(None)) == []
    assert lag_blind_pairs(lambda rows, cols: np.ones(len(rows)), np.ones((120, 160), bool)) == []


def test_the_blind_pairs_are_said_once_per_command_naming_the_leds(caplog):
    model, gel = _model(0.5)
    with said_once.scope(), caplog.at_level(logging.INFO, logger="nlipscalib.core.lag_blind"):
        assert say_lag_blind("P1", model, gel) and say_lag_blind("P2", _model(0.5)[0], gel)
        assert say_lag_blind("R", *_model(None)) == []
    said = [record.getMessage() for record in caplog.records]
    assert len(said) == 1 and said[0].startswith("P1: the lag-band check cannot see a frame read out across the")
    assert "LEDs 1 to 2 (0.5 mm apart: a band over up to" in said[0] and "11 to 12 (0.5 mm, " in said[0]
    assert "--flush 1 or more" in said[0]
    assert LAG_BLIND_SHARE <= min(pair.unseen for pair in lag_blind_pairs(model, gel))
