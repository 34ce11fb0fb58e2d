"""NLiPsNet: accuracy against the lookup-table baseline on an unseen press, the model file, ONNX parity."""

import dataclasses
import json
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import CaptureError
from nlipscalib.learn.evaluate import net_predict, sample_scores
from nlipscalib.learn.lut import LookupTable
from nlipscalib.learn.model import PAPER_HIDDEN, load_model

from .conftest import HELD_OUT


def test_paper_architecture(trained):
    import torch

    model = load_model(trained)
    layers = list(model.net.mlp)
    linear = [m for m in layers if isinstance(m, torch.nn.Linear)]
    assert [m.out_features for m in linear] == [*PAPER_HIDDEN, 3]
    assert sum(isinstance(m, torch.nn.BatchNorm1d) for m in layers) == 3
    assert all(m.p == 0.2 for m in layers if isinstance(m, torch.nn.Dropout))
    out = model.net(torch.randn(10, 5) * 50)
    np.testing.assert_allclose(torch.linalg.vector_norm(out, dim=-1).detach().numpy(), 1, atol=1e-5)


def test_split_by_press_and_held_out_press_never_seen(trained):
    info = load_model(trained).info
    assert not set(info["train_presses"]) & set(info["val_presses"])
    assert HELD_OUT not in info["train_presses"] + info["val_presses"]


def test_net_beats_lookup_table_on_held_out_press(calib, trained):
    model = load_model(trained)
    train = calib.arrays(model.info["train_presses"])
    lut = LookupTable.fit(train["pixel"], train["rgb"], train["normal"], calib.filtered_reference())
    test = calib.load(HELD_OUT)
    net = sample_scores(net_predict(model, test["pixel"], test["rgb"]), test)
    table = sample_scores(lut.predict(test["pixel"], test["rgb"]), test)
    assert net["aae_vs_nlips_deg"] < table["aae_vs_nlips_deg"], (net, table)
    assert net["aae_vs_true_deg"] < table["aae_vs_true_deg"], (net, table)
    assert net["aae_vs_true_deg"] < 8.0, net


MODELS = ("trained", "trained_ratio")
"""The tests' models: the paper's (linear colour inputs) and the default's (colour ratios), both on every path."""


@pytest.mark.parametrize("trained_model", MODELS)
def test_onnx_matches_pytorch_within_a_tenth_of_a_degree(calib, trained_model, tmp_path, request):
    from nlipscalib.learn.model import model_inputs
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx, max_angle_deg

    model = load_model(request.getfixturevalue(trained_model))
    path = export_onnx(model, tmp_path / "net.onnx")
    s = calib.load(HELD_OUT)
    x = model_inputs(s["pixel"], s["rgb"])  # the export's inputs, every model's: a ratio model's graph divides them
    assert max_angle_deg(OnnxNet(path, model)(x), net_predict(model, s["pixel"], s["rgb"])) < 0.1


@pytest.mark.parametrize("trained_model", MODELS)
def test_int8_onnx_stays_close_to_the_float_network(calib, trained_model, tmp_path, monkeypatch, request):
    """Dynamic int8 quantisation (first and last layer float): a small, bounded angular cost. Its scratch folder in
    the system's temporary folder goes at the end, and a killed process's goes with the next (a TemporaryDirectory
    that a `kill -9` while it quantised left in /tmp for good)."""
    import os
    import tempfile

    from nlipscalib.core.atomic import TMP_PREFIX
    from nlipscalib.core.claims import HOST
    from nlipscalib.learn.model import model_inputs
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx
    from tests.core.test_atomic import _dead_pid

    system_tmp = tmp_path / "system_tmp"
    system_tmp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(system_tmp))
    killed = system_tmp / f"{TMP_PREFIX}nlips-onnx-int8~{HOST}~{_dead_pid()}~scratch-0123456789ab"
    killed.mkdir()
    model = load_model(request.getfixturevalue(trained_model))
    path = export_onnx(model, tmp_path / "net.onnx")
    s = calib.load(HELD_OUT)
    x = model_inputs(s["pixel"], s["rgb"])  # the export's inputs (a ratio model's graph divides them)
    int8, exact = OnnxNet(path, model, int8=True)(x), net_predict(model, s["pixel"], s["rgb"])
    angle = np.degrees(np.arccos(np.clip(np.sum(int8 * exact, -1), -1, 1)))
    assert angle.mean() < 0.5 and np.percentile(angle, 99) < 2.0, (angle.mean(), angle.max())
    assert OnnxNet(path, model).session.get_inputs()[0].name == "uvrgb"
    assert os.listdir(system_tmp) == []  # the killed one's and its own


def test_missing_and_corrupt_model_files_are_named(tmp_path, trained, capsys):
    from nlipscalib.core.imageio import write_png16

    with pytest.raises(CaptureError, match="missing"):
        load_model(tmp_path / "none.pt")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"garbage")
    with pytest.raises(CaptureError, match="bad.pt"):
        load_model(bad)
    truncated = tmp_path / "cut.pt"
    truncated.write_bytes(trained.read_bytes()[:1000])
    frames = tmp_path / "frames"  # an input to infer: the inputs are checked before the model is read
    frames.mkdir()
    write_png16(frames / "f.png", np.zeros((72, 96, 3), np.uint16))
    assert main(["infer", str(truncated), str(frames)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cut.pt" in err[0]


def test_a_training_checkpoint_given_as_the_model_names_the_model_file(tmp_path, trained, capsys):
    """MODEL.checkpoint.pt lies beside the model (the only .pt there while a training runs or after it stopped):
    given to `nlips infer` or `nlips export` it was "not an NLiPsNet model file (format must be
    'nlipscalib.nlipsnet')". Now the line says what it is and which file to give, or to finish the training."""
    import torch

    run = tmp_path / "net.0123456789ab.checkpoint.pt"  # a run's own checkpoint, its model not written yet
    torch.save({"key": "k", "history": []}, run)
    assert main(["export", str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{run}: a training checkpoint" in err[0], err
    assert f"run the same `nlips train` again to finish it, then give {tmp_path / 'net.pt'}" in err[0]
    shutil.copy(trained, tmp_path / "net.pt")
    published = tmp_path / "net.checkpoint.pt"
    shutil.copy(run, published)
    with pytest.raises(CaptureError, match=f"not the model file: give the model file {tmp_path / 'net.pt'}$"):
        load_model(published)
    load_model(tmp_path / "net.pt")  # the model itself still loads
    arrays = tmp_path / "sensor.npz"  # a calibration dataset's arrays: was "its entries inflate to ... bytes"
    np.savez_compressed(arrays, a=np.zeros(1000))
    with pytest.raises(CaptureError, match="sensor.npz: a NumPy archive .*, not the model file: give the .pt file"):
        load_model(arrays)


def test_model_refuses_a_capture_of_another_sensor(trained, twin_presses, tmp_path, capsys):
    other = tmp_path / "other_press"
    shutil.copytree(twin_presses / HELD_OUT, other)
    meta = json.loads((other / "meta.json").read_text(encoding="utf-8"))
    meta["camera"]["fx"] *= 1.1  # another lens
    (other / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["infer", str(trained), str(other)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other_press" in err[0] and "another sensor" in err[0] and "fx" in err[0]
    meta["camera"]["fx"] /= 1.1  # the same lens, but another dome's LED ring (1.5 mm further out)
    meta["leds"][0]["position"][0] += 1.5
    (other / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    assert main(["infer", str(trained), str(other)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "another sensor" in err[0] and "LED 1 is 1.50 mm" in err[0]


def test_wrong_image_size_is_refused(trained, tmp_path, capsys):
    from nlipscalib.core.imageio import write_png16

    frame = tmp_path / "small.png"
    write_png16(frame, np.zeros((30, 40, 3), np.uint16))
    assert main(["infer", str(trained), str(frame)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "small.png" in err[0] and "96x72" in err[0]


def test_training_resumes_from_its_checkpoint(calib, tmp_path):
    from nlipscalib.learn.train import TrainConfig, train

    cfg = TrainConfig(hidden=(8, 8), max_epochs=2, patience=5)
    first = train(calib, cfg, tmp_path / "m.pt", progress=False)
    assert (tmp_path / "m.checkpoint.pt").is_file()
    again = train(calib, cfg, tmp_path / "m.pt", progress=False)  # as after an interruption: nothing left to do
    assert [h["val_aae_deg"] for h in again.history] == [h["val_aae_deg"] for h in first.history]
    other_threads = dataclasses.replace(cfg, threads=2)  # how fast, not what: still resumed
    again = train(calib, other_threads, tmp_path / "m.pt", progress=False)
    assert [h["seconds"] for h in again.history] == [h["seconds"] for h in first.history]
    longer = TrainConfig(hidden=(8, 8), max_epochs=3, patience=5)  # other options: trained afresh
    assert len(train(calib, longer, tmp_path / "m.pt", progress=False).history) == 3


def test_cli_trains_a_small_variant_without_dropout(calib, tmp_path, capsys):
    import torch

    out = tmp_path / "small.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "16,16", "--dropout", "0", "--epochs", "2"]
    assert main([*args, "--exclude", HELD_OUT, "--no-progress"]) == 0
    model = load_model(out)
    assert model.hidden == (16, 16) and out.with_suffix(".onnx").is_file()
    assert not any(isinstance(m, torch.nn.Dropout) and m.p > 0 for m in model.net.mlp)
    capsys.readouterr()
    assert main(["train", str(calib.folder), "--out", str(tmp_path / "x.pt"), "--dropout", "1.5"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "dropout" in err[0]
    assert main(["train", str(calib.folder), "--out", str(tmp_path / "y.pt"), "--schedule", "step"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "schedule" in err[0] and not (tmp_path / "y.pt").exists()
    assert main(["train", str(calib.folder), "--out", str(tmp_path / "z.pt"), "--threads", "-1"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--threads" in err[0]


def test_cli_train_takes_press_lists_typed_with_spaces(calib, tmp_path, capsys):
    """`--val-presses "press_a, press_b"` was "validation presses [' press_b'] are not in the dataset". The summary
    says how many presses the net learnt from and which were kept out (it said neither: s41-userwalk)."""
    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--dropout", "0", "--epochs", "1"]
    capsys.readouterr()
    assert main([*args, "--val-presses", "press_a, press_b", "--exclude", f" {HELD_OUT} ,", "--no-onnx"]) == 0
    info = load_model(out).info
    assert info["val_presses"] == ["press_a", "press_b"] and info["excluded_presses"] == [HELD_OUT]
    trained = len(info["train_presses"])
    assert f"on press_a, press_b ({trained} presses trained on; kept out: {HELD_OUT}); " in capsys.readouterr().err


@pytest.mark.parametrize(
    ("val", "exclude", "said"),
    [
        ("press_a,nothere", None, "--val-presses nothere: not among its presses (press_a, "),
        ("press_a", "press_a", "press_a given to both --val-presses and --exclude: give each to one"),
        (None, None, "--val-presses holds all 6 presses left to train on (1 excluded): leave at least one"),
    ],
)
def test_validation_presses_that_cannot_be_used_are_one_line_naming_the_dataset_and_why(
    calib, tmp_path, capsys, val, exclude, said
):
    """`--val-presses P --exclude P` said "validation presses ['P'] are not in the dataset", though it is; every
    press held out for validation said "no training presses left ..." without naming the dataset or the option."""
    names = [n for n in calib.names if n != HELD_OUT]
    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--val-presses", val or ",".join(names)]
    assert main([*args, "--exclude", exclude or HELD_OUT, "--epochs", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(calib.folder / "index.json") in err[0] and said in err[0], err
    assert not out.exists()


def test_a_full_disk_as_the_checkpoint_is_rewritten_says_it_needs_room_for_a_second_copy(
    calib, tmp_path, capsys, monkeypatch
):
    """Each epoch's checkpoint replaces the last one atomically, so it needs room for two copies for a moment: with
    1.8 MB free a 1.6 MB checkpoint was written once and the second epoch's failed, "No space left on device", with
    1.6 MB seemingly free after the run. The line now says why."""
    import errno
    import os
    from pathlib import Path

    from nlipscalib.core import atomic

    real_write_bytes = atomic.write_bytes

    def full_for_a_second_copy(path, data):
        path = Path(path)
        if path.name.endswith(".checkpoint.pt") and path.exists():  # the first copy fitted, the second does not
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        return real_write_bytes(path, data)

    monkeypatch.setattr(atomic, "write_bytes", full_for_a_second_copy)
    out = tmp_path / "model" / "net.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--dropout", "0", "--epochs", "2"]
    assert main([*args, "--no-onnx", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    (checkpoint,) = out.parent.glob("net.*.checkpoint.pt")  # the first epoch's, kept whole
    assert len(err) == 1 and err[0].startswith(f"nlips train: error: {checkpoint}: No space left on device"), err
    assert "needs room for a second copy" in err[0] and "MB, while it replaces the first" in err[0], err


def test_a_full_disk_as_the_model_is_written_names_the_model_file_and_a_rerun_finishes(
    calib, tmp_path, capsys, monkeypatch, caplog
):
    """The model's files are assembled in a scratch folder beside it; a full disk there was reported as
    "OUT/net.pt/net.pt: No space left on device" (the folder named for net.pt, and the file inside it)."""
    import errno
    import os
    from pathlib import Path

    from nlipscalib.core import atomic

    real_write_bytes = atomic.write_bytes

    def full_for_the_model(path, data):
        path = Path(path)
        if path.name == "net.pt":  # fails as the real temporary file beside it would
            tmp = path.parent / (atomic.tmp_prefix(path.name) + "0123abcd")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))
        return real_write_bytes(path, data)

    monkeypatch.setattr(atomic, "write_bytes", full_for_the_model)
    out = tmp_path / "model" / "net.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--dropout", "0", "--epochs", "1"]
    assert main([*args, "--no-onnx", "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"nlips train: error: {out}: No space left on device (the disk is full: free space or choose another --out)"
    ]
    assert not out.exists() and not list(out.parent.glob(".tmp-*"))  # nothing a later run could take as the model
    monkeypatch.setattr(atomic, "write_bytes", real_write_bytes)
    with caplog.at_level("INFO"):
        assert main([*args, "--no-onnx", "--no-progress"]) == 0  # space freed: the run finishes from its checkpoint
    assert "resuming after epoch 1" in caplog.text and load_model(out).info["train_samples"] > 0


def test_plateau_schedule_lowers_the_rate_only_when_validation_stalls(calib, tmp_path, monkeypatch):
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.learn import train as train_module
    from nlipscalib.learn.train import TrainConfig, train

    scripted = iter([5.0, 4.0, 4.5, 4.2, 3.0, 3.5, 3.6])  # validation AAE per epoch: stalls at 3, 4, 6, 7
    monkeypatch.setattr(train_module, "_validate", lambda *args: (next(scripted), 0.0))
    cfg = TrainConfig(hidden=(8, 8), max_epochs=7, patience=10, lr_patience=1, lr_factor=0.5)
    history = train(calib, cfg, tmp_path / "m.pt", progress=False).history
    # lowered after two epochs in a row without a better AAE (epochs 3-4 and 6-7), not after one
    assert [h["lr"] / cfg.lr for h in history] == pytest.approx([1, 1, 1, 0.5, 0.5, 0.5, 0.25])
    with pytest.raises(ConfigError, match="schedule"):
        TrainConfig(schedule="step")


@pytest.mark.parametrize(
    "option, value",
    [
        ("--epochs", "0"),
        ("--epochs", "-3"),
        ("--batch-size", "0"),
        ("--lr", "-1"),
        ("--lr", "0"),
        ("--lr", "nan"),
        ("--max-minutes", "-1"),
        ("--patience", "-1"),
        ("--seed", "-1"),
        ("--hidden", "16,0"),
        ("--dropout", "-0.1"),
        ("--weight-decay", "-1"),
        ("--weight-decay", "nan"),
    ],
)
def test_cli_train_refuses_out_of_range_options_in_one_line_naming_them(calib, tmp_path, capsys, option, value):
    out = tmp_path / "m.pt"
    assert main(["train", str(calib.folder), "--out", str(out), option, value, "--no-progress"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and f"error: {option} " in lines[0], err
    assert value.replace(",", ", ") in lines[0]  # the value as given (--hidden: as parsed)
    assert not out.exists() and not list(tmp_path.iterdir())  # refused before training


def test_cli_train_into_a_folder_names_the_model_file_to_give(calib, tmp_path, capsys):
    """`nlips train DS --out models` (a folder that exists) said "the model file must end in .pt"."""
    models = tmp_path / "models"
    models.mkdir()
    assert main(["train", str(calib.folder), "--out", str(models), "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and f"--out {models}: a folder; give the model file to write in it (e.g. " in lines[0]
    assert not list(models.iterdir())


@pytest.mark.parametrize(
    "field, value",
    [("max_epochs", 0), ("batch_size", 0), ("lr", -1.0), ("lr", float("inf")), ("max_seconds", -60.0)]
    + [("patience", -1), ("threads", 0), ("seed", -1), ("max_epochs", 2.5), ("hidden", (16, 0))]
    + [("weight_decay", -0.1), ("weight_decay", float("nan")), ("weight_decay", 2.0), ("weight_decay", True)],
)
def test_train_config_refuses_out_of_range_fields(field, value):
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.learn.train import TrainConfig

    with pytest.raises(ConfigError, match=f"^{field} "):
        TrainConfig(**{field: value})


def test_weight_decay_is_on_by_default_shrinks_the_weights_and_is_left_out_of_the_keys_at_zero(calib, tmp_path):
    """TrainConfig.weight_decay (AdamW) by default: the same training without it ends with larger weights; at 0 the
    options a checkpoint and the experiments' model keys hold are those of the trainings before it (Adam)."""
    from nlipscalib.learn.checkpoint import jsonable_config
    from nlipscalib.learn.train import TrainConfig, train

    default = TrainConfig().weight_decay
    assert default > 0 and jsonable_config(TrainConfig())["weight_decay"] == default
    assert "weight_decay" not in jsonable_config(TrainConfig(weight_decay=0))

    def weights(decay: float) -> float:
        cfg = TrainConfig(hidden=(8, 8), dropout=0.0, max_epochs=3, batch_size=256, weight_decay=decay, lr=0.02)
        out = tmp_path / f"m{decay}.pt"
        train(calib, cfg, out, exclude=[HELD_OUT], progress=False)
        net = load_model(out).net
        return sum(float((m.weight.detach() ** 2).sum()) for m in net.mlp if hasattr(m, "in_features"))

    assert weights(1.0) < 0.8 * weights(0.0)


def test_default_weight_decay_is_the_one_tuned_with_the_colour_ratio_input():
    """0.5 by default: with the colour-ratio input it beat 0.2 on Q2 medium's unseen split at three training seeds
    (docs/experiments/RESULTS.md, s37-unseen2). The checkpoints' options (and so the experiments' model keys) hold it,
    so a net trained at the earlier default, 0.2, is never reused as one trained at this one."""
    from nlipscalib.learn.checkpoint import jsonable_config
    from nlipscalib.learn.train import DEFAULT_WEIGHT_DECAY, TrainConfig

    assert TrainConfig().weight_decay == DEFAULT_WEIGHT_DECAY == 0.5
    assert jsonable_config(TrainConfig())["weight_decay"] == 0.5
    assert jsonable_config(TrainConfig()) != jsonable_config(TrainConfig(weight_decay=0.2))


@pytest.mark.parametrize("scripted, best", [([5.0, 4.0, 3.0], 3), ([3.0, 4.0, 5.0], 1)])
def test_cli_train_numbers_epochs_from_one(calib, tmp_path, capsys, monkeypatch, scripted, best):
    from nlipscalib.learn import train as train_module
    from nlipscalib.report import learn as report_learn

    aae = iter(scripted)
    monkeypatch.setattr(train_module, "_validate", lambda *args: (next(aae), 1.0))
    figures = []
    save = report_learn._save
    monkeypatch.setattr(report_learn, "_save", lambda fig, path, **kw: figures.append(fig) or save(fig, path, **kw))
    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8,8", "--epochs", "3", "--patience", "5"]
    assert main([*args, "--no-onnx", "--no-progress"]) == 0
    printed, said = capsys.readouterr()
    assert printed == f"{out}\n"  # stdout: the model's file alone; how it trained on stderr
    printed = said
    assert f"best epoch {best} of 3," in printed and "stopped at the epoch limit (--epochs 3)" in printed
    # a net whose last epoch was its best is still learning: the line says more epochs may help, else not
    assert ("still improving at its last epoch: more --epochs may help" in printed) == (best == 3)
    assert printed.splitlines()[-1].startswith(f"next: nlips infer {out} ")  # what a new user does with the model
    curve = figures[0].axes[1]
    assert curve.get_title().startswith(f"best epoch {best}:")
    assert list(curve.lines[0].get_xdata()) == [1, 2, 3]
    assert list(curve.lines[-1].get_xdata()) == [best, best]  # the best-epoch marker
    info = load_model(out).info  # the stored numbers keep counting from 0 (docs/formats.md)
    assert info["best_epoch"] == best - 1 and [h["epoch"] for h in info["history"]] == [0, 1, 2]


def test_missing_onnx_file_names_the_ways_to_make_it(trained, twin_presses, tmp_path, capsys):
    import torch

    from nlipscalib.learn.onnx_export import export_onnx

    model = tmp_path / "net.pt"
    shutil.copy(trained, model)
    args = ["infer", str(model), str(twin_presses / HELD_OUT), "--backend", "onnx", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "net.onnx" in err[0] and "`nlips train`" in err[0]
    assert f"`nlips export {model}` writes it" in err[0]
    assert main(["export", str(model)]) == 0  # the way the message names works
    said = capsys.readouterr()  # stdout: the ONNX file alone; its check, on stderr
    assert said.out == f"{model.with_suffix('.onnx')}\n" and "max angular difference" in said.err
    assert main(args) == 0
    # stale (another model's export beside it, e.g. after retraining with --no-onnx): named, and export mends it
    other = tmp_path / "other.pt"
    payload = torch.load(trained, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    export_onnx(load_model(other), model.with_suffix(".onnx"))
    capsys.readouterr()
    assert main(args) == 0  # the kept result was made with the good export: kept, the model not even read
    capsys.readouterr()  # its closing lines (on stderr): not the refusal's
    fresh = [*args[:-1], str(tmp_path / "o2")]  # work to do: the stale export is found before it is used
    assert main(fresh) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exported from another model" in err[0] and f"`nlips export {model}`" in err[0]
    assert main(["export", str(model)]) == 0 and main(fresh) == 0
    # a copy elsewhere, checked alike; the wrong suffix and the ONNX file given as the model are one line each
    assert main(["export", str(model), "--out", str(tmp_path / "copy.onnx")]) == 0
    assert f"--onnx {tmp_path / 'copy.onnx'}` runs it" in capsys.readouterr().err
    for bad, problem in ((["--out", str(tmp_path / "x.pt")], "must end in .onnx"), ([], "the ONNX export")):
        target = str(model.with_suffix(".onnx")) if not bad else str(model)
        assert main(["export", target, *bad]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and problem in err[0], err


def test_a_model_with_nan_weights_is_refused_naming_the_file(tmp_path, trained):
    """NaN weights give NaN normals, which scored as a result hid the failure (AAE 0.04 deg, measured)."""
    import torch

    payload = torch.load(trained, weights_only=True)
    first = next(k for k, v in payload["state_dict"].items() if v.is_floating_point())
    payload["state_dict"][first][0] = float("nan")
    bad = tmp_path / "nan.pt"
    torch.save(payload, bad)
    with pytest.raises(CaptureError, match=f"nan.pt: weights '{first}' are not finite"):
        load_model(bad)


def test_an_export_that_fails_its_check_is_never_published(tmp_path, trained):
    """An interrupted `nlips export` left an ONNX file whose parity check never ran; `nlips infer` then used it."""
    from nlipscalib.learn.onnx_export import export_onnx

    out = tmp_path / "net.onnx"

    def interrupted(path):
        assert path != out and path.is_file()  # the written file, under its temporary name
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        export_onnx(load_model(trained), out, check=interrupted)
    assert not out.exists() and not list(tmp_path.iterdir())
    assert export_onnx(load_model(trained), out, check=lambda path: None) == out and out.is_file()


def test_a_failed_check_names_the_export_not_its_temporary(tmp_path, trained):
    from nlipscalib.learn.onnx_export import export_onnx

    out = tmp_path / "net.onnx"

    def differs(path):
        raise CaptureError(f"{path}: onnxruntime differs from PyTorch by 1.000 deg (limit 0.1)")

    with pytest.raises(CaptureError, match=f"^{out}: onnxruntime differs"):
        export_onnx(load_model(trained), out, check=differs)
    assert not out.exists()


def test_a_hostile_onnx_beside_a_received_model_stops_infer_in_one_line(trained, twin_presses, tmp_path, capsys):
    """A received model's .onnx pointing its weights at a file outside the model's folder: the default backend
    (auto) uses the .onnx beside the model, so `nlips infer` refuses it in one line, exit 2, no traceback, rather
    than fall back to PyTorch in silence (the lab would not learn what it was sent)."""
    onnx = pytest.importorskip("onnx")
    from nlipscalib.learn.onnx_export import export_onnx

    received = tmp_path / "received"
    received.mkdir()
    model = received / "net.pt"
    shutil.copy(trained, model)
    proto = onnx.load(str(export_onnx(load_model(model), received / "net.onnx")))
    weight = proto.graph.initializer[0]
    weight.ClearField("raw_data")
    weight.data_location = onnx.TensorProto.EXTERNAL
    entry = weight.external_data.add()
    entry.key, entry.value = "location", "../../etc/hostname"
    (received / "net.onnx").write_bytes(proto.SerializeToString())
    assert main(["infer", str(model), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"error: {received / 'net.onnx'}: its weight 'W0' refers to an external data file ('../../etc/" in err[0]
    assert err[0].endswith(f"`nlips export {model}` writes it again, or use --backend torch"), err
    assert not (tmp_path / "o").exists()
    assert main(["export", str(model)]) == 0  # the remedy named: the model's own export replaces it
    assert main(["infer", str(model), str(twin_presses / HELD_OUT), "--out", str(tmp_path / "o")]) == 0


def test_a_garbage_onnx_file_names_the_way_to_write_it_again(tmp_path):
    """`b.onnx: not a readable ONNX model (InvalidProtobuf)` gave no remedy; the missing-file line gave one."""
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import OnnxNet
    from tests.learn.test_onnx_digest import _save

    garbage = tmp_path / "net.onnx"
    garbage.write_bytes(np.random.default_rng(0).bytes(3000))
    model = load_model(_save(tmp_path / "net.pt"))  # the export is checked against its model before it is read
    with pytest.raises(CaptureError) as caught:
        OnnxNet(garbage, model)
    message = str(caught.value)
    assert message.startswith(f"{garbage}: not a readable ONNX model (")
    assert message.endswith(f"`nlips export {model.path}` writes it again, or use --backend torch"), message


def test_a_model_of_colour_ratios_divides_by_the_datasets_filtered_reference_and_records_it(calib, trained_ratio):
    """TrainConfig.colour_input "ratio": the network learns from each colour over the filtered reference's at its
    pixel; the model file records the option, and its scoring (net_predict) divides by the reference it carries."""
    import torch

    from nlipscalib.core.config import to_mapping
    from nlipscalib.learn.checkpoint import jsonable_config
    from nlipscalib.learn.model import model_inputs
    from nlipscalib.learn.train import TrainConfig

    # the ratio, the default since the thirty-seventh session, is written out (the keys and records of an explicit
    # "ratio" before it); linear, the earlier default, is left out (model keys and records as before the option)
    for written in (jsonable_config, to_mapping):
        assert written(TrainConfig())["colour_input"] == "ratio"
        assert written(TrainConfig()) == written(TrainConfig(colour_input="ratio"))
        assert "colour_input" not in written(TrainConfig(colour_input="linear"))
    from nlipscalib.learn.prefilter import Prefilter

    model = load_model(trained_ratio)
    assert model.colour_input == "ratio" and model.info["config"]["colour_input"] == "ratio"
    # the reference's own Gaussian (TrainConfig.reference_smoothing_px, 3 px by default), not the samples' prefilter
    assert model.reference_smoothing_px == model.info["config"]["reference_smoothing_px"] == 3.0
    valid = calib.reference()["valid"]
    ref = Prefilter(valid, 3.0, 0.0)(calib.reference()["tricolor"])
    np.testing.assert_array_equal(model.input_reference[valid], ref[valid])
    assert not np.array_equal(ref[valid], calib.filtered_reference()[valid])
    s = calib.arrays([HELD_OUT])
    ratio = s["rgb"] / ref[s["pixel"][:, 1], s["pixel"][:, 0]]
    # the colour normalisation was taken from the ratios (about 1), not from the linear colours
    offset = model.net.in_offset[2:].numpy()
    np.testing.assert_allclose(offset, 1.0, atol=0.05)
    assert np.all(np.abs(offset - s["rgb"].mean(0)) > 0.1)
    with torch.inference_mode():
        want = model.net(torch.from_numpy(np.concatenate([s["pixel"], ratio], 1).astype(np.float32))).numpy()
    np.testing.assert_allclose(net_predict(model, s["pixel"], s["rgb"]), want, atol=1e-6)
    np.testing.assert_allclose(model_inputs(s["pixel"], s["rgb"], model.input_reference)[:, 2:], ratio, rtol=1e-6)


def test_the_ratios_reference_smoothing_takes_the_references_noise_out_and_keeps_its_shading():
    """input_reference with ``reference_smoothing_px``: on a smooth shading field (a ramp and a gentle bump, as the
    undeformed dome's) with 1.4 % noise per pixel, as the twin's reference frame has, 3 px leaves about a third of the
    noise the samples' 1 px does (1 / (2 sqrt(pi) sigma) of it), and the field itself within 0.1 % of its value; 0 is
    the samples' prefilter bit for bit."""
    from nlipscalib.learn.model import input_reference
    from nlipscalib.learn.prefilter import Prefilter

    h, w = 120, 160
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    field = 0.5 + 0.2 * u / w + 0.1 * np.exp(-((u - 80) ** 2 + (v - 60) ** 2) / (2 * 40.0**2))
    clean = np.repeat(field[..., None], 3, -1)
    noisy = clean * (1 + 0.014 * np.random.default_rng(0).standard_normal(clean.shape))
    valid = np.ones((h, w), bool)
    reference = {"tricolor": noisy.astype(np.float32), "valid": valid}
    inner = (slice(15, -15), slice(15, -15))  # the Gaussian's normalisation at the frame's edge aside

    def error(a: np.ndarray) -> float:
        return float(np.std((a / clean - 1)[inner]))

    samples = input_reference(reference, 1.0, 0.08, "ratio")
    wide = input_reference(reference, 1.0, 0.08, "ratio", reference_smoothing_px=3.0)
    assert error(wide) < 0.4 * error(samples)
    assert 0.4 * 0.014 / (2 * np.sqrt(np.pi)) < error(samples)
    exact = input_reference({"tricolor": clean.astype(np.float32), "valid": valid}, 1.0, 0.0, "ratio", 3.0)
    np.testing.assert_allclose(exact[inner], clean[inner], rtol=1e-3)
    np.testing.assert_array_equal(samples, input_reference(reference, 1.0, 0.08, "ratio", reference_smoothing_px=0.0))
    np.testing.assert_array_equal(samples, Prefilter(valid, 1.0, 0.08)(reference["tricolor"]))
    assert input_reference(reference, 1.0, 0.08, "linear", 3.0) is None


def test_reference_smoothing_is_in_the_keys_of_ratio_nets_only_and_a_file_without_it_filters_as_the_samples(
    trained_ratio, calib, tmp_path
):
    """The model keys and checkpoints hold ``reference_smoothing_px`` (a net of another one is never reused as this
    one's); at 0, and for linear colours (no reference), it is left out, so those keys stay as they were. A model
    file without the field (every one before the option) divides by the reference filtered as the samples, and a
    file with a sigma no filter takes is refused naming the file."""
    import torch

    from nlipscalib.learn.checkpoint import jsonable_config
    from nlipscalib.learn.train import DEFAULT_REFERENCE_SMOOTHING_PX, TrainConfig

    assert TrainConfig().reference_smoothing_px == DEFAULT_REFERENCE_SMOOTHING_PX == 3.0
    assert jsonable_config(TrainConfig())["reference_smoothing_px"] == 3.0
    assert "reference_smoothing_px" not in jsonable_config(TrainConfig(reference_smoothing_px=0.0))
    assert "reference_smoothing_px" not in jsonable_config(TrainConfig(colour_input="linear"))
    for bad in (-1.0, float("nan"), 1000.0):
        with pytest.raises(Exception, match="reference_smoothing_px must be a sigma in"):
            TrainConfig(reference_smoothing_px=bad)
    payload = torch.load(trained_ratio, weights_only=True)
    assert payload["reference_smoothing_px"] == 3.0
    del payload["reference_smoothing_px"]
    old = tmp_path / "old.pt"
    torch.save(payload, old)
    valid = calib.reference()["valid"]
    np.testing.assert_array_equal(load_model(old).input_reference[valid], calib.filtered_reference()[valid])
    payload["reference_smoothing_px"] = -2.0
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(CaptureError, match=r"bad\.pt: 'reference_smoothing_px' must be a sigma in \[0, 50\] px"):
        load_model(tmp_path / "bad.pt")


def test_cli_train_reference_smoothing_is_checked_in_one_line_and_recorded(calib, tmp_path, capsys):
    out = tmp_path / "m.pt"
    args = ["--hidden", "8,8", "--epochs", "1", "--exclude", HELD_OUT, "--no-progress"]
    assert main(["train", str(calib.folder), "--out", str(out), "--reference-smoothing", "-1", *args]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "error: --reference-smoothing must be a sigma in [0, 50] px, got -1.0" in lines[0], lines
    assert not out.exists()
    assert main(["train", str(calib.folder), "--out", str(out), "--reference-smoothing", "2", *args]) == 0
    assert load_model(out).reference_smoothing_px == 2.0


def test_a_model_file_of_linear_colours_holds_no_colour_input_and_an_unknown_one_is_refused(trained, tmp_path):
    import torch

    payload = torch.load(trained, weights_only=True)
    assert "colour_input" not in payload  # files of linear colours are as before the option
    assert load_model(trained).input_reference is None
    payload["colour_input"] = "log"
    bad = tmp_path / "bad.pt"
    torch.save(payload, bad)
    with pytest.raises(CaptureError, match=r"bad\.pt: 'colour_input' must be one of linear, ratio, got 'log'"):
        load_model(bad)


def test_cli_train_colour_input_is_checked_in_one_line_and_recorded(calib, tmp_path, capsys):
    import torch

    out = tmp_path / "m.pt"
    assert main(["train", str(calib.folder), "--out", str(out), "--colour-input", "log", "--no-progress"]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "error: --colour-input must be one of linear, ratio, got 'log'" in lines[0], lines
    assert not out.exists()
    args = ["--hidden", "8,8", "--epochs", "1", "--exclude", HELD_OUT, "--no-progress"]
    assert main(["train", str(calib.folder), "--out", str(out), *args]) == 0
    assert load_model(out).colour_input == "ratio"  # the default since the thirty-seventh session
    assert out.with_suffix(".onnx").is_file()  # exported and checked against PyTorch on ratio inputs
    linear = tmp_path / "linear.pt"
    assert main(["train", str(calib.folder), "--out", str(linear), "--colour-input", "linear", *args]) == 0
    assert load_model(linear).colour_input == "linear" and "colour_input" not in torch.load(linear, weights_only=True)


def test_a_mistyped_colour_input_or_schedule_names_the_close_choice(tmp_path, capsys):
    """`nlips train --colour-input ration` listed the choices and left the user to spot the one meant, where a
    mistyped --labels or --backend named it (README: "a mistyped command, option or choice names the close match")."""
    from nlipscalib.core.errors import ConfigError
    from nlipscalib.learn.train import TrainConfig

    with pytest.raises(ConfigError, match=r"got 'ration' \(did you mean 'ratio'\?\)"):
        TrainConfig(colour_input="ration")
    with pytest.raises(ConfigError, match=r"got 'cosin' \(did you mean 'cosine'\?\)"):
        TrainConfig(schedule="cosin")
    assert main(["train", str(tmp_path), "--out", str(tmp_path / "m.pt"), "--colour-input", "linar"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("--colour-input must be one of linear, ratio, got 'linar' (did you mean 'linear'?)")
