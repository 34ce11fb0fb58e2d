"""NLiPsNet files of a format version this code does not read (built here, as docs/formats.md describes them):
one line naming the file, its version, the version read and what remakes it."""

from __future__ import annotations

import json
import logging

import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.learn.dataset import FORMAT_NAME, CalibrationDataset
from nlipscalib.learn.model import MODEL_FORMAT, load_model


def test_a_model_file_of_a_newer_version_says_upgrade_or_train_again(tmp_path):
    torch = pytest.importorskip("torch")
    path = tmp_path / "model.pt"
    torch.save({"format": MODEL_FORMAT, "format_version": 2}, path)
    with pytest.raises(CaptureError) as refused:
        load_model(path)
    assert str(refused.value) == (
        f"{path}: format_version 2 is not supported (expected 1); written by a newer nlipscalib: upgrade nlipscalib "
        "to read it, or train it again (`nlips train`) on its calibration dataset"
    )


@pytest.mark.parametrize(
    "made_by, advice",
    [
        (None, "run `nlips calibrate` on its presses again"),
        ("nlips experiment", "run the experiment again on its work folder"),
    ],
)
def test_a_calibration_index_of_another_version_names_what_remakes_it(tmp_path, made_by, advice):
    folder = tmp_path / "calibration"
    folder.mkdir()
    index = {"format": FORMAT_NAME, "format_version": 0, "sensor": {}, "presses": []}
    (folder / "index.json").write_text(json.dumps(index | ({"made_by": made_by} if made_by else {})), encoding="utf-8")
    with pytest.raises(CaptureError, match=rf"index\.json: format_version 0 is not supported \(expected 1\); {advice}"):
        CalibrationDataset(folder)


def test_training_on_a_dataset_without_led_geometry_warns_once_naming_the_dataset(calib, tmp_path, caplog):
    # index.json of before 2026-12-03: its sensor record without led_positions / led_directions. The model read
    # back for its export repeated the warning, naming its temporary file (.tmp-m.pt~HOST~PID~.../m.pt).
    import shutil

    from nlipscalib.cli import main

    old = tmp_path / "calibration"
    shutil.copytree(calib.folder, old)
    index = json.loads((old / "index.json").read_text(encoding="utf-8"))
    for key in ("led_positions", "led_directions"):
        index["sensor"].pop(key)
    (old / "index.json").write_text(json.dumps(index), encoding="utf-8")
    out = tmp_path / "m.pt"
    args = ["train", str(old), "--out", str(out), "--hidden", "8", "--dropout", "0", "--epochs", "1", "--no-progress"]
    with caplog.at_level(logging.WARNING):
        assert main(args) == 0
    warned = [r.getMessage() for r in caplog.records if "records no LED geometry" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(str(old / "index.json")), warned
    assert out.with_suffix(".onnx").is_file()
