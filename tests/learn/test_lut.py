"""The GelSight-style lookup table (learn.lut): its fit on a known colour -> normal mapping, its model file, and the
user's path `nlips lut` -> `nlips infer` -> `nlips eval`, as NLiPsNet's."""

import json
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.metrics import aae
from nlipscalib.learn.lut import LookupTable

H, W = 24, 32


def _known_mapping(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(pixel, rgb, normal, reference): normals within 40 deg of the camera's axis (toward it) and colours that are
    the reference's plus an invertible linear function of the normal, which depends on the region (the left half
    of the image sees it mirrored in x)."""
    rng = np.random.default_rng(seed)
    tilt, azimuth = np.radians(40) * np.sqrt(rng.random(n)), 2 * np.pi * rng.random(n)
    normal = np.stack([np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), -np.cos(tilt)], -1)
    pixel = np.stack([rng.integers(0, W, n), rng.integers(0, H, n)], -1)
    reference = np.full((H, W, 3), 0.3, np.float32)
    mix = np.array([[0.4, 0.1, 0.0], [-0.1, 0.4, 0.1], [0.0, 0.0, -0.5]])
    flip = np.where(pixel[:, :1] < W // 2, -1.0, 1.0)
    rgb = 0.3 + (normal * np.concatenate([flip, np.ones((n, 2))], 1)) @ mix.T
    return pixel, rgb, normal, reference


def test_a_table_fitted_on_a_known_colour_to_normal_mapping_predicts_it():
    pixel, rgb, normal, reference = _known_mapping(200_000, seed=1)
    table = LookupTable.fit(pixel, rgb, normal, reference, cells=2, bins=32)
    test_pixel, test_rgb, test_normal, _ = _known_mapping(20_000, seed=2)
    predicted = table.predict(test_pixel, test_rgb)
    np.testing.assert_allclose(np.linalg.norm(predicted, axis=-1), 1, atol=1e-9)
    assert aae(predicted, test_normal) < 1.5  # a bin's width: ~1 deg; the mapping's spread over 40 deg
    pooled = LookupTable.fit(pixel, rgb, normal, reference, cells=1, bins=32)  # one region: the mirror defeats it
    assert aae(pooled.predict(test_pixel, test_rgb), test_normal) > 5 * aae(predicted, test_normal)


def test_a_tables_file_entry_gives_back_the_same_table():
    pixel, rgb, normal, reference = _known_mapping(20_000, seed=3)
    table = LookupTable.fit(pixel, rgb, normal, reference, cells=4, bins=8)
    entry = table.arrays()
    assert entry["keys"].dtype == np.int16 and entry["lo"].dtype == np.float64 and -1 in entry["region"]
    again = LookupTable.from_arrays(entry, reference, "t.pt")
    test_pixel, test_rgb, _, _ = _known_mapping(5_000, seed=4)
    np.testing.assert_allclose(again.predict(test_pixel, test_rgb), table.predict(test_pixel, test_rgb), atol=1e-6)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda e: e.update(bins=1), "'bins' must be an integer in [2, 256]"),
        (lambda e: e.update(cells=True), "'cells' must be an integer"),
        (lambda e: e["keys"].__setitem__((0, 0), 8), "'keys' must be bin indices in [0, 8)"),
        (lambda e: e.update(region=e["region"][e["region"] != -1][:1].repeat(len(e["region"]))), "with -1 (pooled)"),
        (lambda e: e["normals"].__setitem__((0, 0), np.nan), "'normals' must be finite unit vectors"),
        (lambda e: e.update(hi=e["lo"]), "hi above lo"),
        (lambda e: e.update(normals=e["normals"][1:]), "disagree in shape"),
    ],
)
def test_a_damaged_or_edited_table_entry_is_one_error_naming_the_file(change, message):
    pixel, rgb, normal, reference = _known_mapping(5_000, seed=5)
    entry = LookupTable.fit(pixel, rgb, normal, reference, cells=2, bins=8).arrays()
    change(entry)
    with pytest.raises(CaptureError, match="^t.pt: ") as err:
        LookupTable.from_arrays(entry, reference, "t.pt")
    assert message in str(err.value)


# ---------------------------------------------------------------------- the model file and the commands
@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A calibration dataset of the exact-data sensor (64x48, three presses solved with NLiPs, no rendering) and the
    lookup table `nlips lut` fits on it."""
    from nlipscalib.pipeline import solve_folder
    from nlipscalib.solver import SolverOptions
    from tests.learn.test_resume import NAMES
    from tests.solver import synth

    root = tmp_path_factory.mktemp("lut")
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind in zip(NAMES, ("sphere", "cube", "sphere")):
        synth.make_press(root / name, kind, size=(64, 48))
        solve_folder(root / name, options=SolverOptions(max_iters=6), figures=False, progress=False)
    from nlipscalib.learn.dataset import build_dataset

    build_dataset([root / n for n in NAMES], root / "reference", root / "calib", progress=False)
    assert main(["--no-progress", "lut", str(root / "calib"), "--out", str(root / "lut.pt")]) == 0
    return root / "lut.pt", root


def test_nlips_lut_writes_a_model_file_that_predicts_as_its_fit_and_is_the_experiments_baseline(tiny, capsys):
    from nlipscalib.learn.dataset import CalibrationDataset
    from nlipscalib.learn.lut import fit_lookup_table
    from nlipscalib.learn.model import TABLE_FORMAT, load_model, model_method

    table_file, root = tiny
    model = load_model(table_file)
    assert model.method == "lut" and model.net is None and model_method(table_file) == "lut"
    data = CalibrationDataset(root / "calib")
    assert model.sensor == data.sensor and model.info["train_presses"] == data.names
    assert model.info["labels"] == "nlips" and model.info["contact_samples"] > 0
    s = data.arrays()
    fitted = fit_lookup_table(data, data.names)  # the experiments' call
    # what the experiments fitted before the command existed: LookupTable.fit on every sample, NLiPs labels
    before = LookupTable.fit(s["pixel"], s["rgb"], s["normal"], data.filtered_reference())
    np.testing.assert_array_equal(fitted.predict(s["pixel"], s["rgb"]), before.predict(s["pixel"], s["rgb"]))
    np.testing.assert_allclose(
        model.table.predict(s["pixel"], s["rgb"]), before.predict(s["pixel"], s["rgb"]), atol=1e-6
    )
    # the same fit again writes the same bytes: `nlips infer` keeps the results it made with the table
    again = table_file.with_name("again.pt")
    assert main(["--no-progress", "lut", str(root / "calib"), "--out", str(again)]) == 0
    assert again.read_bytes() == table_file.read_bytes()
    assert capsys.readouterr().out == f"{again}\n"
    import torch

    assert torch.load(table_file, weights_only=True)["format"] == TABLE_FORMAT


def test_nlips_infer_and_eval_run_the_table_on_presses_and_frames_as_on_nlipsnet(tiny, tmp_path, capsys):
    from nlipscalib.core import load_press, load_reconstruction
    from nlipscalib.core.metrics import evaluate
    from tests.learn.test_resume import NAMES

    table_file, root = tiny
    presses = tmp_path / "presses"
    for name in ("reference", *NAMES):
        shutil.copytree(root / name, presses / name)
    assert main(["--no-progress", "infer", str(table_file), str(presses), "--ply"]) == 0
    out, said = capsys.readouterr()
    assert out.split() == [str(presses / n / "lut") for n in NAMES]  # beside PRESS/nlipsnet, not in it
    assert "lookup table 16 levels, 8x8 regions" in said and "frames/s" in said
    press = load_press(presses / NAMES[0])
    rec = load_reconstruction(presses / NAMES[0] / "lut", press.camera.shape)
    assert rec.report["method"] == "lut" and rec.report["table"] == {"bins": 16, "cells": 8}
    assert rec.report["backend"] == "lut" and "hidden" not in rec.report
    assert evaluate(rec, press.ground_truth)["contact"]["aae_deg"] < 6.0
    assert (presses / NAMES[0] / "lut" / "points.ply").is_file()
    assert main(["--no-progress", "eval", str(presses), "--method", "lut", "--region", "contact"]) == 0
    table = capsys.readouterr().out
    assert all(name in table for name in NAMES) and "pooled" in table
    # again: every result kept, said without loading the table
    assert main(["--no-progress", "infer", str(table_file), str(presses), "--ply"]) == 0
    assert "kept: 3 result folder(s) as they were" in capsys.readouterr().err
    # a tri-colour frame of a press, as a camera gives it
    frames = tmp_path / "frames"
    frames.mkdir()
    shutil.copy(root / NAMES[1] / "tricolor.png", frames / "f1.png")
    assert main(["--no-progress", "infer", str(table_file), str(frames), "--out", str(tmp_path / "fr")]) == 0
    assert json.loads((tmp_path / "fr" / "f1" / "report.json").read_text(encoding="utf-8"))["method"] == "lut"
    assert main(["--no-progress", "eval", str(presses / NAMES[1]), "--result", str(tmp_path / "fr" / "f1")]) == 0


def _one_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_missing_damaged_or_edited_table_file_is_one_line(tiny, tmp_path, capsys):
    import torch

    table_file, root = tiny
    press = root / "a_sphere"
    assert main(["infer", str(tmp_path / "none.pt"), str(press), "--out", str(tmp_path / "o")]) == 2
    assert _one_line(capsys) == f"nlips infer: error: {tmp_path / 'none.pt'}: model file is missing"
    cut = tmp_path / "cut.pt"
    for length in (-200, 1000):  # the archive's directory lost, and the file cut inside its first entry
        cut.write_bytes(table_file.read_bytes()[:length])
        assert main(["infer", str(cut), str(press), "--out", str(tmp_path / "o")]) == 2
        # named as what it was meant to be (it was "... not usable as an NLiPsNet model file"), told from its first
        # entry as model_method tells a whole one
        assert _one_line(capsys) == (
            f"nlips infer: error: {cut}: truncated or damaged, not usable as a lookup table's file from `nlips lut` "
            "(the archive's directory is missing)"
        )
    payload = torch.load(table_file, weights_only=True)
    payload["table"]["keys"][0, 0] = 99
    edited = tmp_path / "edited.pt"
    torch.save(payload, edited)
    assert main(["infer", str(edited), str(press), "--out", str(tmp_path / "o")]) == 2
    assert (
        _one_line(capsys)
        == f"nlips infer: error: {edited}: 'keys' must be bin indices in [0, 16) (and the table not empty)"
    )
    payload = torch.load(table_file, weights_only=True)
    payload["format_version"] = 7
    newer = tmp_path / "newer.pt"
    torch.save(payload, newer)
    assert main(["infer", str(newer), str(press), "--out", str(tmp_path / "o")]) == 2
    assert "upgrade nlipscalib" in _one_line(capsys)
    assert not (tmp_path / "o").exists()


def test_a_press_of_another_sensor_and_a_network_runtime_are_refused_for_a_table(tiny, tmp_path, capsys):
    table_file, root = tiny
    other = tmp_path / "other_ring"
    shutil.copytree(root / "a_sphere", other, ignore=shutil.ignore_patterns("nlips*"))
    meta = json.loads((other / "meta.json").read_text(encoding="utf-8"))
    for led in meta["leds"]:
        led["position"][2] += 1.5  # a ring 1.5 mm higher: another sensor
    (other / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["--no-progress", "infer", str(table_file), str(other), "--out", str(tmp_path / "o")]) == 2
    assert "another sensor" in _one_line(capsys)
    press = root / "a_sphere"
    assert main(["infer", str(table_file), str(press), "--out", str(tmp_path / "o"), "--backend", "onnx"]) == 2
    assert "a lookup table (`nlips lut`)" in _one_line(capsys)
    assert main(["infer", str(table_file), str(press), "--out", str(tmp_path / "o"), "--full-frame"]) == 2
    assert "a lookup table runs on the CPU" in _one_line(capsys)
    assert main(["export", str(table_file)]) == 2
    assert "a lookup table (`nlips lut`), not a network: nothing to export" in _one_line(capsys)
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--bins", "1"], "--bins must be an integer in [2, 256], got 1"),
        (["--cells", "0"], "--cells must be an integer in [1, 64], got 0"),
        (["--exclude", "nope"], "excluded presses ['nope'] are not in the dataset"),
        (["--labels", "true", "--exclude", "a_sphere,b_cube,c_sphere_deep"], "no press with ground truth"),
    ],
)
def test_nlips_lut_refuses_bad_options_in_one_line(tiny, tmp_path, capsys, args, message):
    _, root = tiny
    out = tmp_path / "t.pt"
    assert main(["lut", str(root / "calib"), "--out", str(out), *args]) == 2
    assert message in _one_line(capsys)
    assert not out.exists()


def test_nlips_lut_of_no_dataset_or_to_no_pt_file_is_one_line(tiny, tmp_path, capsys):
    _, root = tiny
    assert main(["lut", str(tmp_path / "nothing"), "--out", str(tmp_path / "t.pt")]) == 2
    assert _one_line(capsys).startswith(f"nlips lut: error: {tmp_path / 'nothing'}")
    assert main(["lut", str(root / "calib"), "--out", str(tmp_path / "t.npz")]) == 2
    assert "must end in .pt" in _one_line(capsys)


def test_a_tables_file_is_told_from_a_networks_without_unpickling_it(tmp_path):
    """`nlips infer` decides where the results go (PRESS/lut or PRESS/nlipsnet) before the model loads."""
    import torch

    from nlipscalib.learn.model import MODEL_FORMAT, TABLE_FORMAT, model_method

    for fmt, method in ((TABLE_FORMAT, "lut"), (MODEL_FORMAT, "nlipsnet")):
        torch.save({"format": fmt, "format_version": 1, "info": {"dataset": TABLE_FORMAT}}, tmp_path / "m.pt")
        assert model_method(tmp_path / "m.pt") == method
    torch.save({"info": {"format": TABLE_FORMAT}, "format": MODEL_FORMAT}, tmp_path / "m.pt")  # not the first key
    assert model_method(tmp_path / "m.pt") == "nlipsnet"
    for fmt, method in ((TABLE_FORMAT, "lut"), (MODEL_FORMAT, "nlipsnet")):  # cut short: told from the first entry
        torch.save({"format": fmt, "format_version": 1, "weights": torch.zeros(4000)}, tmp_path / "m.pt")
        (tmp_path / "cut.pt").write_bytes((tmp_path / "m.pt").read_bytes()[:-5000])
        assert model_method(tmp_path / "cut.pt") == method
    (tmp_path / "junk.pt").write_bytes(b"PK\x03\x04 not a zip")
    assert model_method(tmp_path / "junk.pt") == model_method(tmp_path / "none.pt") == "nlipsnet"  # its load says why


def test_the_kept_answers_are_the_searched_ones(monkeypatch):
    """predict looks each bin's answer up in one array made once; the k-d tree search it replaced (kept for tables of
    more than DENSE_ANSWERS bins) gives the same normals, regions without samples taking the pooled table's."""
    from nlipscalib.learn import lut

    pixel, rgb, normal, reference = _known_mapping(30_000, seed=6)
    keep = pixel[:, 0] >= 8  # the left quarter's regions get no sample: the pooled table answers there
    table = LookupTable.fit(pixel[keep], rgb[keep], normal[keep], reference, cells=4, bins=12)
    test_pixel, test_rgb, _, _ = _known_mapping(5_000, seed=7)
    kept = table.predict(test_pixel, test_rgb)
    assert table._answers is not None
    monkeypatch.setattr(lut, "DENSE_ANSWERS", 0)
    np.testing.assert_array_equal(table.predict(test_pixel, test_rgb), kept)


def test_the_bin_step_is_the_median_angle_between_neighbouring_filled_bins():
    """Known answer: region 0's bins (0,0,0), (1,0,0), (2,0,0), (0,1,0) tilted 0, 2, 6, 10 deg: neighbours 2, 4 and
    10 deg apart, median 4. Not neighbours (each would move the median to 7): (3,1,0), diagonal to (2,0,0); region 0's
    last red level (7,0,0) and region 1's first, next to it in the flat index; the pooled table's two bins."""
    keys = [[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0], [3, 1, 0], [7, 0, 0], [0, 0, 0], [0, 0, 0], [1, 0, 0]]
    tilt = np.radians([0, 2, 6, 10, 30, 50, 0, 0, 60])
    arrays = {
        "bins": 8,
        "cells": 2,
        "lo": np.zeros(3),
        "hi": np.ones(3),
        "region": np.array([0, 0, 0, 0, 0, 0, 1, -1, -1], np.int32),
        "keys": np.array(keys, np.int16),
        "normals": np.stack([np.sin(tilt), np.zeros_like(tilt), -np.cos(tilt)], -1).astype(np.float32),
    }
    reference = np.zeros((H, W, 3), np.float32)
    assert LookupTable.from_arrays(arrays, reference).bin_step_deg == pytest.approx(4.0, abs=1e-4)
    arrays["keys"][1], arrays["keys"][3] = [4, 4, 4], [6, 6, 6]  # no two bins of one region side by side
    assert np.isnan(LookupTable.from_arrays(arrays, reference).bin_step_deg)


def test_a_tables_stream_and_live_name_the_table_not_nlipsnet(tiny, tmp_path, capsys):
    """A table's stream wrote `"hidden": []` in stream.json and its stage line a "network" stage; `nlips live --model
    TABLE` and the help texts spoke of NLiPsNet alone (s38-lutcli)."""
    from tests.learn.test_resume import NAMES

    table_file, root = tiny
    frames = tmp_path / "frames"
    frames.mkdir()
    for i, name in enumerate(NAMES):
        shutil.copy(root / name / "tricolor.png", frames / f"f_{i:04d}.png")
    out = tmp_path / "stream"
    assert main(["--no-progress", "infer", str(table_file), str(frames / "f_%04d.png"), "--out", str(out)]) == 0
    said = capsys.readouterr().err
    assert "lookup table 16 levels, 8x8 regions (lut), mean per frame: " in said and "table lookup " in said
    assert "network" not in said and "NLiPsNet" not in said, said
    report = json.loads((out / "stream.json").read_text(encoding="utf-8"))
    assert report["method"] == "lut" and report["table"] == {"bins": 16, "cells": 8} and "hidden" not in report
    assert report["model"] == str(table_file.resolve()) and report["backend"] == "lut" and report["frames"] == 3
    assert "network" in report["median_stage_s"]  # the stage's key, as a network's, for readers of both

    assert main(["--no-progress", "live", "--model", str(table_file), "--camera", str(frames), "--no-window"]) == 0
    said = capsys.readouterr().err
    assert "3 frames in" in said and "NLiPsNet" not in said and "network" not in said, said
    for command in ("live", "infer"):
        with pytest.raises(SystemExit):
            main([command, "--help"])
        assert "lookup table" in capsys.readouterr().out
