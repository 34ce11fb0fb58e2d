"""learn.resolution: `nlips infer` warns where a frame's contact is too small or steep for NLiPsNet's normals, against
the solve's rule and against what the calibration presses covered (recorded in the model file at training)."""

import logging

import numpy as np
import pytest

from nlipscalib.core import load_press, masks, tolerances
from nlipscalib.learn.resolution import INFO_KEY, RIM_PX, press_contact, recorded_steepness, steepness_warning

SHAPE = (64, 64)
UP = np.array([0.0, 0.0, -1.0])


def _dent(radius_px: float, tilt_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(changed, normals, reference normals): a disc of ``radius_px`` whose normals tilt by ``tilt_deg``."""
    v, u = np.mgrid[: SHAPE[0], : SHAPE[1]]
    changed = (u - 32) ** 2 + (v - 32) ** 2 <= radius_px**2
    reference = np.broadcast_to(UP, SHAPE + (3,)).astype(np.float32)
    t = np.radians(tilt_deg)
    normals = reference.copy()
    normals[changed] = [np.sin(t), 0.0, -np.cos(t)]
    return changed, normals, reference


def test_a_small_steep_contact_is_warned_about_naming_the_frame():
    changed, normals, reference = _dent(9, 30)  # less the change rule's 4 px rim: ~10 px across, 30 deg: 3 deg/px
    why = steepness_warning(changed, normals, reference, "frames/f7.png", None)
    assert why is not None and why.startswith("frames/f7.png: contact about 10 px across")
    assert "deg/px NLiPsNet resolves" in why and "calibration press" not in why


def test_a_large_gentle_contact_is_not_warned_about():
    changed, normals, reference = _dent(24, 10)  # less the rim ~40 px across, 10 deg: 0.25 deg/px
    assert steepness_warning(changed, normals, reference, "f", None) is None
    assert steepness_warning(*_dent(24, 20), "f", None) is not None  # 0.5 deg/px: beyond the rule
    assert steepness_warning(changed, normals, reference, "f", calibrated_per_px=0.25) is None
    assert steepness_warning(*_dent(5, 40), "f", None) is None  # a speck (5 px less the rim) is no contact


def test_steeper_than_the_calibration_is_warned_about_below_the_solves_rule():
    changed, normals, reference = _dent(24, 10)  # 0.25 deg/px: resolved, but 2.5 times the steepest press taught
    why = steepness_warning(changed, normals, reference, "press9", calibrated_per_px=0.1)
    assert why is not None and "the 0.10 deg/px of the steepest calibration press" in why
    assert "NLiPsNet resolves" not in why


@pytest.mark.parametrize("info", [{}, {INFO_KEY: None}, {INFO_KEY: {"max_tilt_per_px": "x"}}, {INFO_KEY: []}, None])
def test_model_files_without_a_usable_record_are_not_checked_against_the_calibration(info):
    assert recorded_steepness(info) is None
    assert recorded_steepness({INFO_KEY: {"max_tilt_per_px": 0.3}}) == 0.3


def test_a_press_contact_is_measured_from_its_shards_contact_samples():
    changed, normals, reference = _dent(12, 20)
    v, u = np.nonzero(np.ones(SHAPE, bool))
    samples = {
        "pixel": np.stack([u, v], 1).astype(np.int16),
        "contact": changed[v, u],
        "normal": normals[v, u],
        "true_normal": reference[v, u],
    }
    diameter, tilt = press_contact(samples, reference)
    core = masks.erode(changed, RIM_PX)
    assert diameter == pytest.approx(2 * np.sqrt(core.sum() / np.pi)) and tilt == pytest.approx(20, abs=1e-3)
    assert press_contact(samples, reference, labels="true")[1] == pytest.approx(0, abs=1e-3)


def test_training_records_the_calibration_contacts(trained):
    from nlipscalib.learn.model import load_model

    from .conftest import HELD_OUT, PRESSES

    contacts = load_model(trained).info[INFO_KEY]
    assert set(contacts["presses"]) == set(PRESSES) - {HELD_OUT}
    per_px = [t / d for d, t in contacts["presses"].values()]
    assert contacts["max_tilt_per_px"] == pytest.approx(max(per_px)) and 0 < max(per_px) < 1
    assert contacts["min_diameter_px"] == min(d for d, _ in contacts["presses"].values()) > 5


def test_infer_warns_on_a_press_beyond_the_rule_or_the_calibration_and_not_within(
    trained, twin_presses, tmp_path, caplog, monkeypatch
):
    """The tests' 96x72 twin is itself near the limit: its held-out 6 mm sphere measures ~0.55 deg/px (a 1.5 mm
    sphere's at 640x480); the rule and the calibration are moved around it to see each one speak and keep quiet."""
    from nlipscalib.cli import main

    from .conftest import HELD_OUT

    press = twin_presses / HELD_OUT

    def said(out: str) -> list[str]:
        caplog.clear()
        with caplog.at_level(logging.WARNING):
            assert main(["--no-progress", "infer", str(trained), str(press), "--out", str(tmp_path / out)]) == 0
        return [r.getMessage() for r in caplog.records if "contact about" in r.getMessage()]

    beyond_rule = said("a")
    assert len(beyond_rule) == 1 and beyond_rule[0].startswith(f"{press}: contact about")
    assert "NLiPsNet resolves" in beyond_rule[0] and "calibration press" not in beyond_rule[0]
    monkeypatch.setattr(tolerances, "CHANGED_TILT_PER_PX", 5.0)  # as if at a resolution that resolves it
    assert said("b") == []
    monkeypatch.setattr(tolerances, "UNCALIBRATED_STEEPNESS_FACTOR", 0.01)  # as if calibrated on far gentler presses
    beyond_calibration = said("c")
    assert len(beyond_calibration) == 1 and "calibration press" in beyond_calibration[0]


def test_a_stream_says_it_once_and_counts_it(trained, twin_presses, caplog, monkeypatch):
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.watch import MismatchWatch

    from .conftest import HELD_OUT

    predictor = Predictor(trained, depth=False)
    stored = load_press(twin_presses / HELD_OUT).tricolor
    watch = MismatchWatch(predictor, "camera 0")
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for _ in range(3):
            watch(stored)
        watch.report()
    lines = [r.getMessage() for r in caplog.records]
    assert lines[0].startswith("camera 0 frame 0: contact about"), lines
    assert "repeated 2 more times" in lines[1] and lines[-1].startswith("3 of 3 frames had a contact too small")


def test_the_whole_frame_path_warns_as_the_changed_pixel_path(trained, twin_presses, caplog):
    """``--full-frame`` (the network on every gel pixel; torch on the CPU here) was never checked: every gel pixel
    counted as changed. Its change rule's pixels (``Frame.contact``) are measured as the changed-pixel path's: the
    same warning on the held-out press (the same contact within a pixel and a degree), none on the undeformed
    reference, and a stream counts it."""
    import re

    pytest.importorskip("torch")
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.resolution import frame_warning
    from nlipscalib.learn.watch import MismatchWatch

    from .conftest import HELD_OUT

    changed_only, whole = Predictor(trained, depth=False), Predictor(trained, depth=False, full_frame=True)
    stored = load_press(twin_presses / HELD_OUT).tricolor
    part, full = changed_only.predict_stored(stored), whole.predict_stored(stored)
    assert np.array_equal(full.changed, whole.valid) and full.contact is not None  # every gel pixel the network's
    assert (part.changed ^ full.contact).sum() <= 0.02 * part.changed.sum()
    said = [frame_warning(p, f, "f") for p, f in ((changed_only, part), (whole, full))]
    assert all(said), said
    numbers = [[float(x) for x in re.findall(r"about (\S+) px .*~(\S+) deg \((\S+) deg/px", s)[0]] for s in said]
    assert abs(numbers[0][0] - numbers[1][0]) <= 1 and abs(numbers[0][1] - numbers[1][1]) <= 1, numbers
    reference = load_press(twin_presses / "reference").tricolor
    assert frame_warning(whole, whole.predict_stored(reference), "r") is None

    watch = MismatchWatch(whole, "camera 0")
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        for _ in range(2):
            watch(stored)
        watch.report()
    assert caplog.records[-1].getMessage().startswith("2 of 2 frames had a contact too small")


@pytest.fixture(scope="module")
def table(calib, tmp_path_factory):
    """`nlips lut` on the twin's calibration, HELD_OUT left out (as the trained net's)."""
    from nlipscalib.cli import main

    from .conftest import HELD_OUT

    out = tmp_path_factory.mktemp("resolution_lut") / "lut.pt"
    assert main(["--no-progress", "lut", str(calib.folder), "--out", str(out), "--exclude", HELD_OUT]) == 0
    return out


def test_a_tables_results_are_warned_about_in_its_own_words(table, twin_presses, tmp_path, caplog, monkeypatch):
    """The warning named NLiPsNet for a lookup table's results (s38-lutcli): the limit is said without it, and the
    table by what its bins resolve (its neighbouring bins' step, its levels), by `nlips infer` and by a stream."""
    import re

    from nlipscalib.cli import main
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.watch import MismatchWatch

    from .conftest import HELD_OUT

    press = twin_presses / HELD_OUT
    monkeypatch.setattr(tolerances, "CHANGED_TILT_PER_PX", 0.05)  # below the table's own contact: the rule speaks
    with caplog.at_level(logging.WARNING):
        assert main(["--no-progress", "infer", str(table), str(press), "--out", str(tmp_path / "a")]) == 0
    (line,) = [r.getMessage() for r in caplog.records if "contact about" in r.getMessage()]
    step = load_model(table).table.bin_step_deg
    assert 0 < step < 90
    assert "beyond the ~0.05 deg/px the calibration's smoothed colours resolve" in line, line
    assert (
        f"; the lookup table resolves what its bins resolve (its neighbouring bins' normals ~{step:.1f} deg apart, "
        "16 levels per colour channel), and its normals there are smoothed (expect several degrees" in line
    ), line
    assert "NLiPsNet" not in line and re.match(rf"{re.escape(str(press))}: contact about \d+ px", line)

    caplog.clear()
    watch = MismatchWatch(Predictor(table, backend="auto", depth=False), "camera 0")
    with caplog.at_level(logging.WARNING, logger="nlipscalib.learn.watch"):
        watch(load_press(press).tricolor)
    first = caplog.records[0].getMessage()
    assert first.startswith("camera 0 frame 0: contact about") and "what its bins resolve" in first, first
    assert "NLiPsNet" not in first


def test_a_network_and_a_table_without_neighbouring_bins_are_named_so():
    """What names which: a network (or a caller naming none) NLiPsNet; a table whose filled bins are never
    neighbours has no step to say, only its levels."""
    from types import SimpleNamespace

    from nlipscalib.learn.lut import LookupTable
    from nlipscalib.learn.resolution import NETWORK_WORDS, model_words

    assert model_words(SimpleNamespace(table=None)) == NETWORK_WORDS
    changed, normals, reference = _dent(9, 30)
    assert "NLiPsNet's normals there are smoothed" in steepness_warning(changed, normals, reference, "f", None)
    keys = np.array([[0, 0, 0], [2, 2, 2], [0, 0, 0]], np.int16)  # two regions' lone bins and the pooled one
    arrays = {
        "bins": 4,
        "cells": 2,
        "lo": np.zeros(3),
        "hi": np.ones(3),
        "region": np.array([0, 0, -1], np.int32),
        "keys": keys,
        "normals": np.array([[0, 0, -1.0]] * 3, np.float32),
    }
    lone = LookupTable.from_arrays(arrays, np.zeros((8, 8, 3), np.float32))
    words = model_words(SimpleNamespace(table=lone))
    assert "(its 4 levels per colour channel)" in words.normals and "deg apart" not in words.normals
    why = steepness_warning(changed, normals, reference, "f", None, words)
    assert "deg/px the calibration's smoothed colours resolve;" in why and "NLiPsNet" not in why
