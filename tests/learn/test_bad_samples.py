"""Calibration datasets and model files holding values no capture gives (NaN, strings, pixels outside the image,
a bad sampling record): one error naming the file and the array or key, never a traceback or a silent model
(exact-data presses, 64x48, no rendering: a few seconds)."""

import json

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import CaptureError, ConfigError
from nlipscalib.learn.dataset import CalibrationDataset, SamplingConfig
from nlipscalib.learn.model import load_model
from nlipscalib.learn.train import train
from tests.learn.test_resume import NAMES, TINY, a_frame, built, solved  # noqa: F401 (fixtures)


def _edit_npz(path, change) -> None:
    with np.load(path) as d:
        arrays = dict(d)
    change(arrays)
    np.savez(path, **arrays)


def _one_line(capsys, *needles) -> None:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in err, err
    for needle in needles:
        assert needle in lines[0], lines[0]


def _set(key, index, value):
    return lambda a: a[key].__setitem__(index, value)


@pytest.mark.parametrize(
    "change,problem",
    [
        (_set("rgb", slice(0, 10), np.nan), "array 'rgb' has NaN or infinite values in 10 of"),
        (_set("rgb", slice(0, 3), np.inf), "array 'rgb' has NaN or infinite values in 3 of"),
        (_set("normal", slice(0, 4), np.nan), "array 'normal' has NaN or infinite values in 4 of"),
        (_set("pixel", slice(0, 5), 30000), "array 'pixel' has 5 samples outside the sensor's 64x48 image"),
        (_set("pixel", slice(0, 1), -1), "array 'pixel' has 1 samples outside the sensor's 64x48 image"),
        (lambda a: a.__setitem__("rgb", a["rgb"].astype("U4")), "array 'rgb' holds <U4 values, expected floating"),
    ],
)
def test_a_shard_with_values_no_capture_gives_is_named(built, tmp_path, capsys, change, problem):  # noqa: F811
    """NaN or infinite colours stopped `nlips train` with a TypeError after its epochs (no best state); NaN
    normals, pixels outside the image and colours stored as strings were trained on without a word."""
    shard = built / "samples" / f"{NAMES[1]}.npz"
    _edit_npz(shard, change)
    with pytest.raises(CaptureError, match=f"{NAMES[1]}.npz: {problem}"):
        CalibrationDataset(built).load(NAMES[1])
    assert main(["train", str(built), "--out", str(tmp_path / "m.pt"), "--no-onnx", "--no-progress"]) == 2
    _one_line(capsys, str(shard), problem)
    assert not list(tmp_path.glob("m*"))  # no model, no checkpoint left


@pytest.mark.parametrize(
    "sampling,problem",
    [
        ("x", "'sampling' must be a mapping of sampling options, got 'x'"),
        ({"smoothing_px": -3}, "'sampling.smoothing_px' must be a sigma in [0, 50] px, got -3"),
        ({"smoothing_px": 1e9}, "'sampling.smoothing_px' must be a sigma in [0, 50] px, got 1000000000.0"),
        ({"smoothing_px": "wide"}, "'sampling.smoothing_px' must be a sigma in [0, 50] px, got 'wide'"),
        ({"smoothing_colour": -1}, "'sampling.smoothing_colour' must be a colour sigma in [0, 1], got -1"),
        ({"smoothing_colour": "edge"}, "'sampling.smoothing_colour' must be a colour sigma in [0, 1], got 'edge'"),
    ],
)
def test_a_bad_sampling_record_is_named_when_the_dataset_opens(built, sampling, problem):  # noqa: F811
    """``"sampling": "x"`` was an AttributeError in `nlips train`; a negative sigma was trained with and only
    refused by `nlips infer` ("prefilter sigma must be ..."), naming neither the model nor the key."""
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    index["sampling"] = sampling
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    with pytest.raises(CaptureError) as caught:
        CalibrationDataset(built)
    assert str(caught.value) == f"{built / 'index.json'}: {problem}"


@pytest.mark.parametrize("pixels", [slice(None), (slice(5, 8), slice(10, 20))])
def test_nan_in_the_reference_frame_is_refused_before_training(built, tmp_path, capsys, pixels):  # noqa: F811
    """A NaN tri-colour reference in sensor.npz went into the model file: inference then found no pixel that
    differs from it and returned the undeformed dome, exit 0."""
    _edit_npz(built / "sensor.npz", _set("tricolor", pixels, np.nan))
    with pytest.raises(CaptureError, match=r"sensor.npz: reference array 'tricolor' is NaN or infinite at \d+ pixels"):
        CalibrationDataset(built).reference()
    assert main(["train", str(built), "--out", str(tmp_path / "m.pt"), "--no-onnx", "--no-progress"]) == 2
    _one_line(capsys, "sensor.npz: reference array 'tricolor' is NaN")


def test_too_few_presses_to_train_names_the_dataset(built, tmp_path, capsys):  # noqa: F811
    """``"presses": []`` said "training needs at least 2 presses (one to validate on), got 0", naming no file."""
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    index["presses"] = []
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    assert main(["train", str(built), "--out", str(tmp_path / "m.pt"), "--no-onnx", "--no-progress"]) == 2
    _one_line(capsys, f"{built / 'index.json'}: training needs at least 2 presses", "0 of the 0 it lists")


def test_a_dataset_without_contact_samples_is_refused_naming_it(built, tmp_path, capsys):  # noqa: F811
    """A session of black or over-exposed presses gave "3 presses, 4189 samples (0 contact)"; `nlips train` then
    wrote a model of the undeformed dome and printed "validation AAE 98.51 deg (contact nan deg)", exit 0."""
    for name in NAMES:
        _edit_npz(built / "samples" / f"{name}.npz", lambda a: a["contact"].fill(False))
    assert main(["train", str(built), "--out", str(tmp_path / "m.pt"), "--no-onnx", "--no-progress"]) == 2
    _one_line(capsys, f"{built}: no contact samples: none of the", "of its 3 presses differ from the reference frame")
    assert not list(tmp_path.glob("m*"))  # no model, no checkpoint left


def test_validation_presses_without_contact_say_so_never_nan_deg(built, tmp_path, capsys):  # noqa: F811
    """The summary printed "(contact nan deg)" when the validation presses held no contact sample."""
    _edit_npz(built / "samples" / f"{NAMES[0]}.npz", lambda a: a["contact"].fill(False))
    cmd = ["train", str(built), "--out", str(tmp_path / "m.pt"), "--val-presses", NAMES[0], "--hidden", "8"]
    assert main(cmd + ["--dropout", "0", "--epochs", "2", "--no-onnx", "--no-progress"]) == 0
    out = capsys.readouterr().err
    assert f"(no contact samples) on {NAMES[0]} (" in out and "nan" not in out.lower(), out


def test_a_model_with_a_nan_reference_or_a_bad_sigma_is_named(built, tmp_path, capsys):  # noqa: F811
    import torch

    out = tmp_path / "m.pt"
    train(CalibrationDataset(built), TINY, out, progress=False)
    payload = torch.load(out, weights_only=True)
    nan_reference = payload["reference"] | {"tricolor": payload["reference"]["tricolor"] * float("nan")}
    for name, change, problem in (
        ("nanref", {"reference": nan_reference}, "reference array 'tricolor' is NaN or infinite at 3072 pixels"),
        ("negative", {"smoothing_px": -3.0}, "'smoothing_px' must be a sigma in [0, 50] px, got -3.0"),
        ("nan", {"smoothing_px": float("nan")}, "'smoothing_px' must be a sigma in [0, 50] px, got nan"),
        ("colour", {"smoothing_colour": 5.0}, "'smoothing_colour' must be a colour sigma in [0, 1], got 5.0"),
    ):
        path = tmp_path / f"{name}.pt"
        torch.save(payload | change, path)
        with pytest.raises(CaptureError) as caught:
            load_model(path)
        assert str(caught.value) == f"{path}: {problem}"
        assert main(["infer", str(path), str(a_frame(tmp_path))]) == 2
        _one_line(capsys, f"{path}: {problem}")


@pytest.mark.parametrize("value", ["1e9", "51", "-3", "nan"])
def test_calibrate_refuses_a_smoothing_sigma_out_of_range(tmp_path, capsys, value):
    """``--smoothing 1e9`` reached OpenCV ("Can't parse 'ksize'") after every press was solved."""
    assert main(["--no-progress", "calibrate", str(tmp_path), "--smoothing", value]) == 2
    _one_line(capsys, "--smoothing must be")
    with pytest.raises(ConfigError, match=r"smoothing_px must be a sigma in \[0, 50\] px"):
        SamplingConfig(smoothing_px=float(value))


@pytest.mark.parametrize("value", ["-1", "2", "nan"])
def test_calibrate_refuses_a_colour_sigma_out_of_range(tmp_path, capsys, value):
    assert main(["--no-progress", "calibrate", str(tmp_path), "--smoothing-colour", value]) == 2
    _one_line(capsys, "--smoothing-colour must be a colour sigma in [0, 1]")
