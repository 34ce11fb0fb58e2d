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
    torch.save({"format": MODEL_FORMAT, "format_version": 3}, path)  # 2 since 2026-12-07 (s42-trainid): read
    with pytest.raises(CaptureError) as refused:
        load_model(path)
    assert str(refused.value) == (
        f"{path}: format_version 3 is not supported (expected 1 or 2); written by a newer nlipscalib: upgrade "
        "nlipscalib to read it, or train it again (`nlips train`) on its calibration dataset"
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


@pytest.mark.parametrize(
    "rules, said",
    [
        (None, "records no sampling rules: made by an nlipscalib before 2026-12-06: its samples may differ"),
        ({"rule": 3, "frame_gain": 0}, "made under other sampling rules (frame_gain 0, now 1): its samples may differ"),
        ({"rule": 2, "frame_gain": 1}, "made under other sampling rules (rule 2, now 3): its samples may differ"),
    ],
)
def test_training_on_a_dataset_of_older_sampling_rules_warns_naming_the_dataset(calib, tmp_path, caplog, rules, said):
    """`nlips train` on a dataset an older nlipscalib made read its samples without a word, while `nlips calibrate`
    makes such shards again (a press dimmer than the reference kept almost none of its contact samples before
    learn.dataset.FRAME_GAIN_RULE). A dataset of this version's rules says nothing."""
    import shutil

    from nlipscalib.cli import main
    from nlipscalib.learn.dataset import SAMPLE_RULES

    assert calib.sample_rules == SAMPLE_RULES and calib.older_sampling() is None
    old = tmp_path / "calibration"
    shutil.copytree(calib.folder, old)
    index = json.loads((old / "index.json").read_text(encoding="utf-8"))
    index.pop("sample_rules")
    (old / "index.json").write_text(json.dumps(index | ({"sample_rules": rules} if rules else {})), encoding="utf-8")
    args = ["train", str(old), "--out", str(tmp_path / "m.pt"), "--hidden", "8", "--epochs", "1", "--no-onnx"]
    with caplog.at_level(logging.WARNING):
        assert main([*args, "--no-progress"]) == 0
    warned = [r.getMessage() for r in caplog.records if "sampling rules" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{old / 'index.json'}: {said}"), warned
    assert warned[0].endswith("run `nlips calibrate` on its presses again to make them with this version")


def test_a_model_an_older_nlipscalib_trained_is_reused_with_a_warning_of_what_it_lacks(calib, tmp_path, caplog):
    """`nlips train` after an upgrade reuses a model of the same options and samples whatever code trained it; one
    trained before 2026-12-06 records no calibrated contacts (`nlips infer` cannot judge a contact against the
    steepest calibration press) and was reused without a word. Reused now with a warning; this version's, without."""
    torch = pytest.importorskip("torch")
    from nlipscalib.cli import main
    from nlipscalib.learn.resolution import INFO_KEY

    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--epochs", "1", "--no-onnx"]
    assert main([*args, "--no-progress"]) == 0
    with caplog.at_level(logging.WARNING):
        assert main([*args, "--no-progress"]) == 0  # reused: this version's model, nothing to say
    assert not [r for r in caplog.records if "records no calibrated contacts" in r.getMessage()]
    payload = torch.load(out, weights_only=True)
    del payload["info"][INFO_KEY]
    torch.save(payload, out)  # as a training of before 2026-12-06 wrote it
    with caplog.at_level(logging.WARNING):
        assert main([*args, "--no-progress"]) == 0
    warned = [r.getMessage() for r in caplog.records if "records no calibrated contacts" in r.getMessage()]
    assert len(warned) == 1 and warned[0].startswith(f"{out}: trained by an nlipscalib before 2026-12-06"), warned


@pytest.mark.parametrize("recorded", ["0" * 32, None])  # other training code; none recorded (before 2026-12-06)
def test_a_model_other_training_code_made_is_trained_again_not_reused(calib, tmp_path, caplog, capsys, recorded):
    """`nlips train` reused a finished model of the same options and samples whatever code trained it (a changed
    loss or initialisation went unseen after an upgrade), warning only of a missing ``info.contacts``. Now its
    checkpoint records the training code's fingerprint, and a model of another is trained again, as `nlips solve`
    solves a result of other code again; the run after that reuses it."""
    torch = pytest.importorskip("torch")
    from nlipscalib.cli import main
    from nlipscalib.learn.checkpoint import checkpoint_path, training_code

    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--epochs", "1", "--no-onnx"]
    assert main([*args, "--no-progress"]) == 0
    ck = torch.load(checkpoint_path(out), weights_only=True)
    assert ck["code"] == training_code()
    if recorded is None:
        del ck["code"]
    else:
        ck["code"] = recorded
    torch.save(ck, checkpoint_path(out))
    capsys.readouterr()
    with caplog.at_level(logging.INFO):
        assert main([*args, "--no-progress"]) == 0
    said = capsys.readouterr().err
    warned = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and str(out) in r.getMessage()]
    assert len(warned) == 1 and "trained again" in warned[0], warned
    assert ("other nlipscalib training code" if recorded else "recorded no fingerprint") in warned[0]
    assert "reused" not in said and "training from scratch" in caplog.text  # not resumed from that checkpoint
    assert torch.load(checkpoint_path(out), weights_only=True)["code"] == training_code()
    assert main([*args, "--no-progress"]) == 0 and "reused" in capsys.readouterr().err  # now this code's
