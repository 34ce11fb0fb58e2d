"""learn.resolution: `nlips infer` warns where a frame's contact is too small or steep for NLiPsNet's normals, against
the solve's rule and against what the calibration presses covered (recorded in the model file at training)."""

import logging

import numpy as np
import pytest

from nlipscalib.core import load_press, masks, tolerances
from nlipscalib.learn.resolution import (
    INFO_KEY,
    RIM_PX,
    judge_steepness,
    measure_contact,
    press_contact,
    recorded_steepness,
    steepness_warning,
)

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
    # beyond the network's own figure alone: steeper calibration presses would not lift it, so they are not advised
    assert why.endswith("; capture at a higher resolution or press with a larger indenter"), why
    assert "calibrate with presses" not in why


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
    assert why.endswith("or calibrate with presses as small and steep"), why  # what lifts this limit


def test_a_tables_normals_are_held_to_its_own_lower_figure():
    """A lookup table's normals stop at its bins' steepest, so a steep contact reads flatter on them: its results are
    held to ``TABLE_CHANGED_TILT_PER_PX`` (0.3 deg/px), a network's to ``CHANGED_TILT_PER_PX`` (0.4; s40-steep)."""
    from nlipscalib.learn.resolution import NETWORK_WORDS, ModelWords

    dent = _dent(24, 14)  # less the rim ~40 px across, 14 deg: 0.35 deg/px, between the two
    table = ModelWords("a lookup table's normals resolve", "its normals there are smoothed", table=True)
    assert (table.limit_per_px, NETWORK_WORDS.limit_per_px) == (0.3, 0.4)
    assert steepness_warning(*dent, "f", None) is None
    assert "beyond the ~0.3 deg/px a lookup table's normals resolve;" in steepness_warning(*dent, "f", None, table)
    assert steepness_warning(*_dent(24, 11), "f", None, table) is None  # 0.27 deg/px: within the table's figure


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


def _samples(changed: np.ndarray, normals: np.ndarray, reference: np.ndarray, labelled: np.ndarray) -> dict:
    """A shard of every pixel, its contact samples those of ``changed`` that are ``labelled`` (as the dataset keeps
    only the contact's reliable NLiPs labels)."""
    v, u = np.nonzero(~changed | labelled)
    return {
        "pixel": np.stack([u, v], 1).astype(np.int16),
        "contact": changed[v, u],
        "normal": normals[v, u],
        "true_normal": reference[v, u],
    }


def test_a_press_with_unreliable_labels_in_its_contact_is_recorded_as_its_frame_is_judged():
    """Known answer: a disc 40 px across tilted 10 deg, every 5th pixel of every 5th row without a label (a coin's
    steep walls the solve could not label). The press is recorded at the figure its frame is judged by: the disc less
    the 4 px rim, 10 deg. Before (s39-steepwarn) the rim was taken off every unlabelled pixel too: the contact fell
    apart into specks, a figure of a few pixels' patch, or none."""
    changed, normals, reference = _dent(20, 10)
    labelled = np.ones(SHAPE, bool)
    labelled[::5, ::5] = False
    core = masks.erode(changed, RIM_PX)
    diameter = 2 * np.sqrt(core.sum() / np.pi)  # 2 sqrt(area / pi) of the disc of radius 16: ~32 px
    assert diameter == pytest.approx(32, abs=1)
    recorded = press_contact(_samples(changed, normals, reference, labelled), reference)
    judged = measure_contact(changed, normals, reference)
    assert judged == pytest.approx((diameter, 10), abs=1e-3)
    # within 1 %: an unlabelled pixel on the disc's edge is a notch, not a hole (32.45 against 32.57 px)
    assert recorded == pytest.approx((diameter, 10), rel=0.01)
    per_px = recorded[1] / recorded[0]  # 0.31 deg/px, within the rule's 0.4
    assert judge_steepness(changed, normals, reference, per_px) is None  # a press of the calibration: no warning
    steeper = _dent(20, 10 * tolerances.UNCALIBRATED_STEEPNESS_FACTOR * 1.1)  # 10 % beyond the margin: warned
    assert f"the {per_px:.2f} deg/px of the steepest calibration press" in judge_steepness(*steeper, per_px).limits


def _cap(radius_px: float, sphere_px: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(changed, normals, reference normals): a disc of ``radius_px`` pressed by a sphere of ``sphere_px``, its
    normals tilting arcsin(r / ``sphere_px``) away from its middle: steepest at its edge."""
    v, u = np.mgrid[: SHAPE[0], : SHAPE[1]]
    changed = (u - 32) ** 2 + (v - 32) ** 2 <= radius_px**2
    reference = np.broadcast_to(UP, SHAPE + (3,)).astype(np.float32)
    tilt = np.arcsin(np.clip(np.hypot(u - 32, v - 32) / sphere_px, 0, 1))
    turn = np.arctan2(v - 32, u - 32)
    normals = reference.copy()
    cap = np.stack([np.sin(tilt) * np.cos(turn), np.sin(tilt) * np.sin(turn), -np.cos(tilt)], -1)
    normals[changed] = cap[changed]
    return changed, normals, reference


def test_unreliable_labels_notching_a_contacts_edge_leave_its_recorded_figure_as_its_frames():
    """Known answer: a spherical dent 40 px across (its normals 30 deg at its edge), a notch of unlabelled pixels 6 px
    wide and 10 deep cut into its edge (a steep wall the solve could not label, open to the outside: no hole). Its
    recorded figure is its frame's within 0.5 %: the notch is closed before the 4 px rim is taken off. Before
    (s40-steep) the rim ate round the notch: 30.4 px against 32.6, 0.681 deg/px against 0.636 (+7 %)."""
    changed, normals, reference = _cap(20, 40)
    labelled = np.ones(SHAPE, bool)
    labelled[29:35, 12:22] = False  # the disc's left edge is column 12
    assert not (masks.fill_holes(changed & labelled) & ~labelled).any()  # a notch, not a hole
    judged = measure_contact(changed, normals, reference)
    assert judged[0] == pytest.approx(2 * np.sqrt(masks.erode(changed, RIM_PX).sum() / np.pi))
    recorded = press_contact(_samples(changed, normals, reference, labelled), reference)
    assert recorded == pytest.approx(judged, rel=0.005)
    assert recorded[1] / recorded[0] == pytest.approx(judged[1] / judged[0], rel=0.005)


def test_a_contact_is_measured_on_its_pixels_with_its_holes_spanned():
    """A ring's middle is no part of its contact (unchanged, or unlabelled): it counts toward the diameter, not the
    tilt. Known answer: a disc 48 px across whose middle 10 px radius is flat, its ring tilted 20 deg."""
    changed, normals, reference = _dent(24, 20)
    v, u = np.mgrid[: SHAPE[0], : SHAPE[1]]
    middle = (u - 32) ** 2 + (v - 32) ** 2 <= 10**2
    ring = changed & ~middle
    normals[middle] = reference[middle]  # the flat middle the change rule left out: its tilt would be 0
    diameter, tilt = measure_contact(ring, normals, reference)
    assert diameter == pytest.approx(2 * np.sqrt(masks.erode(changed, RIM_PX).sum() / np.pi))
    assert tilt == pytest.approx(20, abs=1e-3)


def test_training_records_the_calibration_contacts(trained):
    from nlipscalib.learn.model import load_model

    from .conftest import HELD_OUT, PRESSES

    contacts = load_model(trained).info[INFO_KEY]
    assert set(contacts["presses"]) == set(PRESSES) - {HELD_OUT}
    per_px = [t / d for d, t in contacts["presses"].values()]
    assert contacts["max_tilt_per_px"] == pytest.approx(max(per_px)) and 0 < max(per_px) < 1
    assert contacts["min_diameter_px"] == min(d for d, _ in contacts["presses"].values()) > 5


def test_no_calibration_press_is_judged_steeper_than_the_calibration(trained, twin_presses):
    """Every press the fixture's net was calibrated on, through the net as `nlips infer` judges it: within the
    margin of its own recorded figure, so never warned against the calibration (a helper saw a Q2 press warned so:
    it was not one of that model's presses, benchmarks/RESULTS.md s39-steepwarn); the same frame with its normals'
    tilt tripled is warned."""
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model

    predictor = Predictor(trained, depth=False)
    contacts = load_model(trained).info[INFO_KEY]
    steepest = recorded_steepness(load_model(trained).info)
    ref = predictor.ref_normals
    frames = {}
    for name, (diameter, tilt) in contacts["presses"].items():
        frames[name] = frame = predictor.predict_stored(load_press(twin_presses / name).tricolor)
        judged_d, judged_tilt = measure_contact(frame.changed, frame.normals, ref)
        assert judged_tilt / judged_d <= tolerances.UNCALIBRATED_STEEPNESS_FACTOR * tilt / diameter, name
        judged = judge_steepness(frame.changed, frame.normals, ref, steepest)
        assert judged is None or not any("calibration press" in limit for limit in judged.limits), name
    # the steepest press's normals each turned three times as far from the undeformed one, about the same axis
    name = max(contacts["presses"], key=lambda n: contacts["presses"][n][1] / contacts["presses"][n][0])
    frame = frames[name]
    cosine = np.clip(np.sum(frame.normals * ref, -1, keepdims=True), -1.0, 1.0)
    angle, away = np.arccos(cosine), frame.normals - cosine * ref
    norm = np.linalg.norm(away, axis=-1, keepdims=True)
    away = np.divide(away, norm, out=np.zeros_like(away), where=norm > 1e-9)
    steeper = (np.cos(3 * angle) * ref + np.sin(3 * angle) * away).astype(np.float32)
    judged = judge_steepness(frame.changed, steeper, ref, steepest)
    assert judged is not None and f"the {steepest:.2f} deg/px of the steepest calibration press" in judged.limits


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
    monkeypatch.setattr(tolerances, "TABLE_CHANGED_TILT_PER_PX", 0.05)  # below the table's own contact: the rule speaks
    with caplog.at_level(logging.WARNING):
        assert main(["--no-progress", "infer", str(table), str(press), "--out", str(tmp_path / "a")]) == 0
    (line,) = [r.getMessage() for r in caplog.records if "contact about" in r.getMessage()]
    step = load_model(table).table.bin_step_deg
    assert 0 < step < 90
    assert "beyond the ~0.05 deg/px a lookup table's normals resolve" in line, line
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
    assert "deg/px a lookup table's normals resolve;" in why and "NLiPsNet" not in why
