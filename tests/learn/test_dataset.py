"""The calibration dataset: what is sampled, with which labels, and how damage is reported."""

import json
import os
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press, load_reconstruction
from nlipscalib.core.errors import CaptureError
from nlipscalib.learn.dataset import SOURCE_NLIPS, SOURCE_REFERENCE, CalibrationDataset, SamplingConfig
from nlipscalib.learn.prefilter import Prefilter


def test_samples_pair_tricolor_pixels_with_reliable_nlips_normals(calib, twin_presses):
    s = calib.load("press_a")
    press = load_press(twin_presses / "press_a")
    rec = load_reconstruction(twin_presses / "press_a" / "nlips")
    u, v = s["pixel"][:, 0], s["pixel"][:, 1]
    # colours: the tri-colour image low-pass filtered over the gel, as the dataset's options say
    assert calib.smoothing_px == SamplingConfig().smoothing_px > 0
    assert calib.smoothing_colour == SamplingConfig().smoothing_colour > 0  # stopping at colour edges by default
    valid = np.isfinite(press.reference.depth)
    colours = Prefilter(valid, calib.smoothing_px, calib.smoothing_colour)(press.linear(press.tricolor))
    np.testing.assert_allclose(s["rgb"], colours[v, u], rtol=0, atol=1e-6)
    nl = s["source"] == SOURCE_NLIPS
    np.testing.assert_allclose(s["normal"][nl], rec.normals[v[nl], u[nl]], atol=1e-6)
    # labels only where NLiPs is reliable
    assert np.all(rec.reconstructed[v[nl], u[nl]]) and np.all(rec.confidence[v[nl], u[nl]] >= 0.5)
    assert np.all(rec.usable_leds[v[nl], u[nl]] >= 4)
    # the rest is labelled with the undeformed surface, never on the contact
    rest = s["source"] == SOURCE_REFERENCE
    assert not np.any(s["contact"][rest])
    np.testing.assert_allclose(s["normal"][rest], press.reference.normals[v[rest], u[rest]], atol=1e-6)
    # most of the true contact is sampled
    gt = press.ground_truth
    tilt = np.degrees(np.arccos(np.clip(np.sum(gt.normals * press.reference.normals, -1), -1, 1)))
    visible_dent = gt.contact & gt.valid & (tilt > 3)
    sampled = np.zeros_like(visible_dent)
    sampled[v[s["contact"]], u[s["contact"]]] = True
    assert (sampled & visible_dent).sum() >= 0.9 * visible_dent.sum()


def test_every_press_has_a_shard_and_the_index_counts_them(calib):
    assert sorted(calib.names) == sorted(f"press_{c}" for c in "abcdefg")
    arrays = calib.arrays(["press_a", "press_b"])
    assert set(np.unique(arrays["press"])) == {0, 1}
    assert len(arrays["rgb"]) == calib.entry("press_a")["samples"] + calib.entry("press_b")["samples"]
    assert calib.entry("press_b")["press"]["indenter"] == "cube"


def test_corrupt_dataset_is_named(calib, tmp_path):
    bad = tmp_path / "calib"
    shutil.copytree(calib.folder, bad)
    (bad / "samples" / "press_a.npz").write_bytes(b"not a zip")
    with pytest.raises(CaptureError, match="press_a.npz"):
        CalibrationDataset(bad).load("press_a")
    (bad / "index.json").write_text("{", encoding="utf-8")
    with pytest.raises(CaptureError, match="index.json"):
        CalibrationDataset(bad)


def test_cli_train_on_corrupt_dataset_fails_with_one_line(calib, tmp_path, capsys):
    bad = tmp_path / "calib"
    shutil.copytree(calib.folder, bad)
    index = json.loads((bad / "index.json").read_text(encoding="utf-8"))
    index["format_version"] = 99
    (bad / "index.json").write_text(json.dumps(index), encoding="utf-8")
    assert main(["train", str(bad), "--out", str(tmp_path / "m.pt")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "index.json" in err[0]


def test_cli_train_on_the_folder_of_presses_names_its_calibration_dataset(calib, tmp_path, capsys):
    """`nlips train PRESSES` (for PRESSES/calibration) said "not a calibration dataset (run `nlips calibrate`)"."""
    presses = tmp_path / "presses"
    shutil.copytree(calib.folder, presses / "calibration")
    assert main(["train", str(presses), "--out", str(tmp_path / "m.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"its calibration dataset is {presses / 'calibration'} (give that folder)" in err[0], err
    assert not (tmp_path / "m.pt").exists()


def test_cli_train_on_the_samples_folder_names_the_dataset_above_it(calib, tmp_path, capsys):
    """`nlips train DATASET/samples` said "DATASET/samples/index.json: missing; ... not a calibration dataset (run
    `nlips calibrate`)": the dataset was there, one folder up."""
    dataset = tmp_path / "calibration"
    shutil.copytree(calib.folder, dataset)
    assert main(["train", str(dataset / "samples"), "--out", str(tmp_path / "m.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips train: error: {dataset / 'samples'}: a folder inside a calibration dataset, not one; the dataset is "
        f"{dataset} (give that folder)"
    ], err
    assert not (tmp_path / "m.pt").exists()


def test_cli_train_on_the_index_file_names_it_a_file_and_the_dataset(calib, tmp_path, capsys):
    """`nlips train DATASET/index.json` (the file, typed for its folder) said "DATASET/index.json: a folder inside a
    calibration dataset": it is a file."""
    dataset = tmp_path / "calibration"
    shutil.copytree(calib.folder, dataset)
    assert main(["train", str(dataset / "index.json"), "--out", str(tmp_path / "m.pt")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips train: error: {dataset / 'index.json'}: a file inside a calibration dataset, not one; the dataset is "
        f"{dataset} (give that folder)"
    ], err
    assert not (tmp_path / "m.pt").exists()


def test_a_dataset_without_led_geometry_opens_with_a_warning(calib, tmp_path, caplog):
    """index.json written before 2026-12-03 lacks led_positions/led_directions: usable, said once, not silent."""
    import logging

    caplog.set_level(logging.WARNING)
    old = tmp_path / "calib"
    shutil.copytree(calib.folder, old)
    assert CalibrationDataset(old).sensor["led_positions"] and "LED geometry" not in caplog.text
    index = json.loads((old / "index.json").read_text(encoding="utf-8"))
    del index["sensor"]["led_positions"], index["sensor"]["led_directions"]
    (old / "index.json").write_text(json.dumps(index), encoding="utf-8")
    data = CalibrationDataset(old)
    assert data.names == calib.names
    assert f"{old / 'index.json'}: records no LED geometry" in caplog.text and "nlips calibrate" in caplog.text


def test_cli_calibrate_solves_samples_and_reports_coverage(twin_presses, tmp_path, capsys):
    root = tmp_path / "presses"
    shutil.copytree(twin_presses / "reference", root / "reference")
    for name in ("press_a", "press_b"):  # press_b unsolved: calibrate must solve it
        shutil.copytree(
            twin_presses / name, root / name, ignore=shutil.ignore_patterns("nlips") if name == "press_b" else None
        )
    assert main(["calibrate", str(root), "--no-progress"]) == 0
    assert (root / "press_b" / "nlips" / "result.npz").is_file()
    data = CalibrationDataset(root / "calibration")
    assert data.names == ["press_a", "press_b"]
    cov = json.loads((root / "calibration" / "coverage.json").read_text(encoding="utf-8"))
    assert 0 < cov["covered_fraction"] < 1
    assert cov["next_press"]["indenter"] in ("sphere", "cube")
    # the twin's reference records where its camera sits: the advice gives the press direction too
    assert 0 <= cov["next_press"]["polar_deg"] < 90 and 0 <= cov["next_press"]["azimuth_deg"] < 360
    assert "press direction polar" in cov["next_press"]["advice"]
    # a sphere and a cube tilt the gel by far less than 45 deg: the report asks for a press with steep relief
    assert 0 < cov["steep"]["taught_tilt_deg"] < 45 and cov["steep"]["untaught_from_deg"] <= 45
    assert (root / "calibration" / "coverage.png").stat().st_size > 1000
    printed = capsys.readouterr().err
    assert "press next" in printed and "steep relief" in printed and "press direction polar" in printed


def test_cli_calibrate_raw_colours_on_request_and_refuses_a_negative_sigma(twin_presses, tmp_path, capsys):
    root = tmp_path / "presses"
    for name in ("reference", "press_a"):
        shutil.copytree(twin_presses / name, root / name)
    assert main(["calibrate", str(root), "--smoothing", "-1", "--no-progress"]) != 0
    assert "--smoothing" in capsys.readouterr().err
    assert main(["calibrate", str(root), "--workers", "-2", "--no-progress"]) != 0
    assert "--workers" in capsys.readouterr().err
    assert main(["calibrate", str(root), "--smoothing", "0", "--no-progress"]) == 0
    data = CalibrationDataset(root / "calibration")
    s, press = data.load("press_a"), load_press(root / "press_a")
    assert data.smoothing_px == 0
    np.testing.assert_array_equal(s["rgb"], press.linear(press.tricolor)[s["pixel"][:, 1], s["pixel"][:, 0]])


@pytest.mark.parametrize(
    "field, value",
    [("min_confidence", 2.0), ("min_confidence", -0.1), ("min_leds", -1), ("rest_cells", 0)]
    + [("rest_per_cell", -1), ("seed", -1), ("smoothing_px", float("nan")), ("min_leds", 2.5)]
    + [("smoothing_colour", -0.1), ("smoothing_colour", 1.5)],
)
def test_sampling_config_refuses_out_of_range_fields(field, value):
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError, match=f"^{field} "):
        SamplingConfig(**{field: value})


@pytest.mark.parametrize(
    "option, value", [("--min-confidence", "2"), ("--min-leds", "99"), ("--min-leds", "-1"), ("--rest-per-cell", "-5")]
)
def test_cli_calibrate_refuses_sampling_options_that_leave_no_samples(twin_presses, tmp_path, capsys, option, value):
    root = tmp_path / "presses"
    shutil.copytree(twin_presses / "reference", root / "reference")
    shutil.copytree(twin_presses / "press_a", root / "press_a", ignore=shutil.ignore_patterns("nlips"))
    assert main(["calibrate", str(root), option, value, "--no-progress"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and f"error: {option} " in lines[0] and value in lines[0], err
    assert not (root / "press_a" / "nlips").exists() and not (root / "calibration").exists()  # before solving


def test_cli_calibrate_waits_for_a_press_another_run_holds_and_solves_it_when_that_run_fails(
    twin_presses, tmp_path, capsys
):
    """Two `nlips calibrate` runs at once: a press the other run holds is waited for, not reported unsolved."""
    import subprocess
    import sys
    from pathlib import Path

    root = tmp_path / "presses"
    shutil.copytree(twin_presses / "reference", root / "reference")
    shutil.copytree(twin_presses / "press_b", root / "press_b", ignore=shutil.ignore_patterns("nlips"))
    # another run claims press_b's result for 3 s, then ends without publishing one (it failed)
    holder = (
        "import sys, time\n"
        "from nlipscalib.core.claims import claim\n"
        "with claim(sys.argv[1]) as mine:\n"
        "    assert mine\n"
        "    print('held', flush=True)\n"
        "    time.sleep(3)\n"
    )
    repo = str(Path(__file__).resolve().parents[2])
    env = os.environ | {"PYTHONPATH": os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))}
    other = subprocess.Popen(
        [sys.executable, "-c", holder, str(root / "press_b" / "nlips")], stdout=subprocess.PIPE, text=True, env=env
    )
    try:
        assert other.stdout.readline().strip() == "held"
        assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
        assert other.poll() == 0  # calibrate waited for the other run to end first
    finally:
        other.kill()
        other.wait()
    assert (root / "press_b" / "nlips" / "result.npz").is_file()
    assert CalibrationDataset(root / "calibration").names == ["press_b"]
    assert "press not solved" not in capsys.readouterr().err


def test_cli_calibrate_with_another_reference_leaves_the_folders_own_out(twin_presses, tmp_path, capsys, caplog):
    """``nlips calibrate DS --reference OTHER`` solved DS/reference as if it were a press (and sampled it). Now it is
    left out with an info line when OTHER is of the same sensor, and the command refuses in one line, before any
    solving, when the two references are of different sensors."""
    import logging

    caplog.set_level(logging.INFO)
    root = tmp_path / "presses"
    shutil.copytree(twin_presses / "reference", root / "reference")
    shutil.copytree(twin_presses / "press_a", root / "press_a", ignore=shutil.ignore_patterns("nlips"))
    missing = tmp_path / "missing"  # a mistyped --reference: was one error per press, then "no press could be solved"
    assert main(["calibrate", str(root), "--reference", str(missing), "--no-progress"]) == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        f"nlips calibrate: error: {missing}: not a press folder (no such directory)"
    ]
    foreign = tmp_path / "foreign"  # the undeformed dome of another sensor: another focal length
    shutil.copytree(twin_presses / "reference", foreign)
    meta = json.loads((foreign / "meta.json").read_text(encoding="utf-8"))
    meta["camera"]["fx"] *= 1.1
    (foreign / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["calibrate", str(root), "--reference", str(foreign), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different sensors" in err[0] and "camera fx" in err[0], err
    assert str(root / "reference") in err[0] and str(foreign) in err[0]
    assert f"{foreign} has " in err[0] and "calibrated for" not in err[0]  # a capture, not a model: named
    assert not (root / "press_a" / "nlips").exists() and not (root / "calibration").exists()  # before solving

    alone = tmp_path / "alone"  # a folder without its own reference, given a foreign one: one line, not one per press
    shutil.copytree(root / "press_a", alone / "press_a")
    shutil.copytree(root / "press_a", alone / "press_b")
    assert main(["calibrate", str(alone), "--reference", str(foreign), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not a capture of the sensor of" in err[0] and "camera fx" in err[0], err
    assert f"{foreign} has " in err[0] and "calibrated for" not in err[0]
    assert not (alone / "press_a" / "nlips").exists()

    other = tmp_path / "other"  # the same sensor's undeformed dome, captured again
    shutil.copytree(twin_presses / "reference", other)
    assert main(["calibrate", str(root), "--reference", str(other), "--workers", "1", "--no-progress"]) == 0
    assert not (root / "reference" / "nlips").exists()  # not solved as a press
    data = CalibrationDataset(root / "calibration")
    assert data.names == ["press_a"]
    left_out = [r.getMessage() for r in caplog.records if "left out" in r.getMessage()]
    assert len(left_out) == 1 and str(root / "reference") in left_out[0] and str(other) in left_out[0]


def test_a_captured_press_records_no_indenter_kind(tmp_path):
    """A press without the twin's provenance was recorded as indenter "unknown", which the coverage report then
    named ("press next: an unknown"); null lets it call the operator's object "an object"."""
    from nlipscalib.core import load_press
    from nlipscalib.learn.dataset import press_description
    from tests.solver import synth

    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(32, 24)))
    assert press_description(press) == {"indenter": None, "polar_deg": None, "azimuth_deg": None, "depth_mm": None}


def test_cli_calibrate_killed_while_reporting_coverage_leaves_no_report_of_another_dataset(
    twin_presses, tmp_path, monkeypatch
):
    # coverage.json was written before coverage.png: a run killed between them (or while computing the coverage)
    # left the earlier dataset's report, or half of it, beside the new index.json
    from nlipscalib.report import learn as report_learn

    root = tmp_path / "presses"
    for name in ("reference", "press_a"):
        shutil.copytree(twin_presses / name, root / name)
    assert main(["calibrate", str(root), "--no-progress"]) == 0
    shutil.copytree(twin_presses / "press_b", root / "press_b")

    def killed(cov, path):
        raise KeyboardInterrupt

    monkeypatch.setattr(report_learn, "coverage_figure", killed)
    assert main(["calibrate", str(root), "--no-progress"]) == 130  # Ctrl-C's exit status
    assert CalibrationDataset(root / "calibration").names == ["press_a", "press_b"]
    assert not (root / "calibration" / "coverage.json").exists()
    assert not (root / "calibration" / "coverage.png").exists()


def test_presses_dimmer_than_the_undeformed_capture_keep_their_contact_samples(twin_presses, tmp_path, caplog):
    """A session whose presses are 10 % dimmer than its undeformed capture (LEDs aged, exposure changed between
    them): the change rule found what differs from the rest of a frame that differed everywhere, and the twin
    session of s28-together kept 3,904 of 36,724 contact samples, silently. The contact is now told apart against
    the undeformed frame scaled by the press's measured brightness, its colours sampled at the undeformed frame's
    (with them, a refresh by `nlips infer --reference` undid the fault: contact AAE 22.0 -> 4.7 deg), one warning."""
    import logging

    from nlipscalib.core.imageio import read_png16, write_png16
    from nlipscalib.learn.dataset import press_samples, reference_arrays

    ref = reference_arrays(load_press(twin_presses / "reference"))
    rec = load_reconstruction(twin_presses / "press_a" / "nlips")
    as_captured = press_samples(load_press(twin_presses / "press_a"), rec, ref, SamplingConfig())
    dimmed = tmp_path / "session" / "press_a"
    shutil.copytree(twin_presses / "press_a", dimmed)
    images = json.loads((dimmed / "meta.json").read_text(encoding="utf-8"))["images"]
    dark = read_png16(dimmed / images["dark"]).astype(float)
    lit = read_png16(dimmed / images["tricolor"]).astype(float) - dark
    write_png16(dimmed / images["tricolor"], np.clip(np.rint(dark + 0.9 * lit), 0, 65535).astype(np.uint16))
    with caplog.at_level(logging.INFO):
        samples = press_samples(load_press(dimmed), rec, ref, SamplingConfig())
    kept, before = int(samples["contact"].sum()), int(as_captured["contact"].sum())
    assert abs(kept - before) <= 0.05 * before, (kept, before)
    # the colours at the undeformed capture's brightness, as the model's reference frame (a refresh maps to it)
    brightness = np.median(samples["rgb"], axis=0) / np.median(as_captured["rgb"], axis=0)
    assert np.allclose(brightness, 1.0, atol=0.01), brightness
    said = [r for r in caplog.records if "tri-colour frame is red 0.90" in r.getMessage()]
    assert len(said) == 1 and said[0].levelno == logging.WARNING, said


def test_building_from_no_press_is_one_clear_error_and_writes_nothing(tmp_path):
    """`build_dataset(sorted(root.glob("press_*")), ...)` whose glob matched nothing wrote a dataset of no sample
    (index.json, sensor.npz), exit 0, which `train` then refused."""
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.learn.dataset import build_dataset
    from tests.solver import synth

    synth.make_press(tmp_path / "reference", "none", size=(64, 48))
    with pytest.raises(ConfigError, match="no press folders given"):
        build_dataset([], tmp_path / "reference", tmp_path / "calib", progress=False)
    assert not (tmp_path / "calib").exists()
