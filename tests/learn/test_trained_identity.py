"""The identity of a model's data (s42-trainid): index.json records each sample file (its bytes and SHA-256) and the
capture each press's labels were solved from; a kept `nlips train` re-run decides from those records without
reading a sample, and still notices a sample file changed, replaced or cut since; the model file (format 2) records
the captures it learnt from, `nlips infer` compares each press it reads with them (report.json `trained_on`), and
`nlips eval` scores seen and unseen presses apart. Exact-data presses, 64x48, no rendering: seconds."""

import hashlib
import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import CaptureError
from nlipscalib.learn.checkpoint import checkpoint_path
from nlipscalib.learn.dataset import CalibrationDataset, build_dataset, write_shard
from nlipscalib.learn.train import TrainConfig, train
from nlipscalib.pipeline import capture_identity, solve_folder
from nlipscalib.solver import SolverOptions
from tests.solver import synth

torch = pytest.importorskip("torch")

PRESSES = {"a_sphere": ("sphere", 1.5), "b_cube": ("cube", 1.5), "c_sphere_deep": ("sphere", 2.0)}
HELD = "d_cube_deep"  # kept out of training and validation: the unseen press
VAL = "c_sphere_deep"
TINY = TrainConfig(hidden=(8,), dropout=0.0, max_epochs=2, patience=5)


def _make(folder, kind, depth):
    synth.make_press(folder, kind, depth=depth, size=(64, 48))
    solve_folder(folder, options=SolverOptions(max_iters=6), figures=False, progress=False)


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """The undeformed dome and four exact-data presses, solved with NLiPs through the pipeline (so each result
    records its capture's identity, as `nlips calibrate`'s do)."""
    root = tmp_path_factory.mktemp("identity_presses")
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, (kind, depth) in {**PRESSES, HELD: ("cube", 2.0)}.items():
        _make(root / name, kind, depth)
    return root


@pytest.fixture
def built(solved, tmp_path):
    out = tmp_path / "calib"
    build_dataset([solved / n for n in [*PRESSES, HELD]], solved / "reference", out, progress=False)
    return out


def _sha256(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_the_index_records_each_sample_file_and_the_capture_its_labels_were_solved_from(solved, built):
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    for entry in index["presses"]:
        shard = built / "samples" / f"{entry['name']}.npz"
        assert entry["shard"]["bytes"] == shard.stat().st_size and entry["shard"]["sha256"] == _sha256(shard)
        assert entry["capture_identity"] == capture_identity(solved / entry["name"])
    assert index["sensor_file"]["bytes"] == (built / "sensor.npz").stat().st_size
    assert index["sensor_file"]["sha256"] == _sha256(built / "sensor.npz")
    data = CalibrationDataset(built)
    key = data.samples_key(["a_sphere", "b_cube"], [VAL])
    assert len(key) == 16 and key == CalibrationDataset(built).samples_key(["a_sphere", "b_cube"], [VAL])
    others = [(["b_cube", "a_sphere"], [VAL]), (["a_sphere", "b_cube"], [HELD]), (["a_sphere"], ["b_cube", VAL])]
    assert key not in {data.samples_key(train, val) for train, val in others}
    assert data.samples_changed([*PRESSES, HELD]) is None
    del index["sensor_file"]  # a dataset built before 2026-12-07: no key, and its files cannot be checked
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    older = CalibrationDataset(built)
    assert older.samples_key(["a_sphere"], [VAL]) is None
    assert older.samples_changed(["a_sphere"]) == f"{built / 'sensor.npz'}: index.json records no digest of it"


def _refuse_reading(monkeypatch):
    def refused(self, name):
        raise AssertionError(f"{name}: samples read")

    monkeypatch.setattr(CalibrationDataset, "load", refused)


def test_a_kept_re_run_reads_no_sample_file_and_one_of_an_older_dataset_reads_them(built, tmp_path, monkeypatch):
    out = tmp_path / "m" / "net.pt"
    first = train(built, TINY, out, exclude=[HELD], progress=False)
    before = out.read_bytes()
    with monkeypatch.context() as patched:
        _refuse_reading(patched)
        again = train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)
        assert again.reused and again.history == first.history and out.read_bytes() == before
        assert (again.train_presses, again.val_presses) == (first.train_presses, first.val_presses)
        with pytest.raises(AssertionError, match="samples read"):  # other options: trained, so read
            train(built, TINY, out, exclude=[HELD, "b_cube"], progress=False, reuse=True)
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    for entry in index["presses"]:
        entry.pop("shard")  # as an nlipscalib before 2026-12-07 wrote it
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    again = train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)  # read, and recognised by its samples
    assert again.reused and out.read_bytes() == before
    with monkeypatch.context() as patched:
        _refuse_reading(patched)
        with pytest.raises(AssertionError, match="samples read"):
            train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)


def test_a_kept_cli_re_run_loads_the_model_once_and_reads_no_sample(built, tmp_path, monkeypatch, capsys):
    """It was loaded twice: once to check it and its MODEL.onnx whole, then again for its digest and record
    (~0.1 s of a 640x480 model)."""
    from nlipscalib.learn import model as model_module

    model = tmp_path / "net.pt"
    args = [
        "train",
        str(built),
        "--out",
        str(model),
        "--hidden",
        "8",
        "--dropout",
        "0",
        "--epochs",
        "2",
        "--no-progress",
    ]
    assert main(args) == 0
    loaded, load = [], model_module.load_model
    monkeypatch.setattr(model_module, "load_model", lambda path: loaded.append(Path(path)) or load(path))
    _refuse_reading(monkeypatch)
    capsys.readouterr()
    assert main(args) == 0
    assert ": reused, trained before" in capsys.readouterr().err
    assert loaded == [model]


@pytest.mark.parametrize("spoil", ["changed", "replaced", "cut"])
def test_a_sample_file_changed_replaced_or_cut_after_sampling_is_not_taken_for_the_one_trained_on(
    built, tmp_path, caplog, spoil
):
    """Each is told from the records (its size, or its SHA-256 when the size is the same), and the samples are
    then read as before: a changed one trains anew, a replaced or cut one is refused naming the file."""
    out = tmp_path / "m" / "net.pt"
    train(built, TINY, out, exclude=[HELD], progress=False)
    shard = built / "samples" / "a_sphere.npz"
    stat = shard.stat()
    if spoil == "changed":  # its samples rewritten with one colour changed, its entry carried and its time kept
        arrays = dict(np.load(shard))
        arrays["rgb"][0, 0] += 0.01
        write_shard(shard, arrays)
        os.utime(shard, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    elif spoil == "replaced":  # another press's samples copied over it (cp -p)
        shutil.copy2(built / "samples" / "b_cube.npz", shard)
    else:  # cut short
        with shard.open("r+b") as f:
            f.truncate(stat.st_size - 100)
    why = CalibrationDataset(built).samples_changed(["a_sphere"])
    assert why is not None and why.startswith(f"{shard}: ")
    assert ("bytes" in why) == (shard.stat().st_size != stat.st_size)  # the size first, then the content
    with caplog.at_level(logging.INFO, logger="nlipscalib.learn.train"):
        if spoil == "changed":
            again = train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)
            assert not again.reused  # other samples: trained on them
        else:
            with pytest.raises(CaptureError, match=f"^{shard}: "):
                train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)
    assert f"{why}; its samples are read to tell whether {out} was trained on them" in caplog.text


def test_a_training_on_a_file_unlike_its_record_records_no_key(built, tmp_path, monkeypatch):
    """A model trained on a sample file changed since the build keeps no key of the build's records: were the file put
    back, a re-run would otherwise take that model for one trained on it."""
    shard = built / "samples" / "a_sphere.npz"
    kept = shard.read_bytes()
    arrays = dict(np.load(shard))
    arrays["rgb"][:, 1] *= 1.05
    write_shard(shard, arrays)
    out = tmp_path / "m" / "net.pt"
    train(built, TINY, out, exclude=[HELD], progress=False)
    assert torch.load(checkpoint_path(out), weights_only=True)["samples_key"] is None
    shard.write_bytes(kept)
    again = train(built, TINY, out, exclude=[HELD], progress=False, reuse=True)
    assert not again.reused  # read: the samples it was trained on are not these


def test_the_model_records_the_captures_it_learnt_from_and_its_samples_key(solved, built, tmp_path):
    out = tmp_path / "net.pt"
    train(built, TINY, out, val_names=[VAL], exclude=[HELD], progress=False)
    payload = torch.load(out, weights_only=True)
    assert payload["format_version"] == 2
    data = CalibrationDataset(built)
    assert payload["info"]["captures"] == {name: capture_identity(solved / name) for name in PRESSES}
    key = data.samples_key(["a_sphere", "b_cube"], [VAL])
    assert payload["info"]["samples_key"] == key
    assert torch.load(checkpoint_path(out), weights_only=True)["samples_key"] == key


def _table(out: str) -> dict[str, list[str]]:
    return {line[:24].strip(): line[24:].split() for line in out.splitlines()[1:]}


def _scored_together(model, presses, out_folder, capsys) -> str:
    """`nlips infer MODEL PRESSES` then `nlips eval` of its results, from a model that cannot tell seen from unseen
    presses: the table as before (no data column, no seen/unseen rows). Returns eval's stderr."""
    argv = ["--no-progress", "infer", str(model), str(presses), "--out", str(out_folder), "--figures", "none"]
    assert main(argv) == 0
    capsys.readouterr()
    assert main(["eval", str(presses), "--result", str(out_folder)]) == 0
    out, err = capsys.readouterr()
    assert out.splitlines()[0].split()[:2] == ["press", "pixels"]  # the table as before
    assert set(_table(out)) == {*PRESSES, HELD, "mean", "pooled"}
    return err


def test_eval_scores_the_presses_a_model_learnt_from_and_the_others_apart(solved, built, tmp_path, capsys):
    """Trained on a_sphere and b_cube, validated on c_sphere_deep, d_cube_deep kept out: eval's table says which is
    which and gives the seen and unseen presses' figures apart; a press of a trained press's name in another folder,
    another capture, is unseen; the results of a model of format 1 (no captures) are scored together, said once."""
    presses = tmp_path / "presses"
    for name in [*PRESSES, HELD]:
        shutil.copytree(solved / name, presses / name)  # a copy is the same capture: seen
    _make(tmp_path / "elsewhere" / "a_sphere", "sphere", 1.2)  # the same name, another capture
    model = tmp_path / "net.pt"
    options = ["--hidden", "8", "--dropout", "0", "--epochs", "2", "--no-onnx", "--no-progress"]
    assert main(["train", str(built), "--out", str(model), "--val-presses", VAL, "--exclude", HELD, *options]) == 0
    inputs = [str(presses / name) for name in [*PRESSES, HELD]] + [str(tmp_path / "elsewhere" / "a_sphere")]
    assert main(["--no-progress", "infer", str(model), *inputs, "--figures", "none"]) == 0
    report = json.loads((presses / HELD / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["trained_on"] == "unseen"
    capsys.readouterr()

    assert main(["eval", str(presses), "--method", "nlipsnet"]) == 0
    out, err = capsys.readouterr()
    table = _table(out)
    assert out.splitlines()[0].split()[:3] == ["press", "data", "pixels"]
    assert {name: table[name][0] for name in [*PRESSES, HELD]} == {
        "a_sphere": "train",
        "b_cube": "train",
        VAL: "validation",
        HELD: "unseen",
    }
    seen_aae = float(table["pooled seen"][1])
    unseen_aae = float(table["pooled unseen"][1])
    assert int(table["pooled seen"][0]) == sum(int(table[n][1]) for n in PRESSES)
    assert float(table["mean unseen"][0]) == pytest.approx(float(table[HELD][2]), abs=1e-3)
    assert f"seen: 3 press(es), pooled AAE {seen_aae:.3f} deg" in err
    assert f"unseen: 1 press(es), pooled AAE {unseen_aae:.3f} deg" in err

    assert main(["eval", str(tmp_path / "elsewhere"), "--method", "nlipsnet"]) == 0
    out, err = capsys.readouterr()
    assert _table(out)["a_sphere"][0] == "unseen" and "seen: none; unseen: 1 press(es)" in err

    old = tmp_path / "old.pt"  # as `nlips train` wrote it before 2026-12-07
    payload = torch.load(model, weights_only=True)
    payload["format_version"] = 1
    for key in ("captures", "samples_key", "press_identities"):
        del payload["info"][key]
    torch.save(payload, old)
    err = _scored_together(old, presses, tmp_path / "old", capsys)
    assert err.count("seen and unseen presses not told apart") == 1


def test_a_lookup_table_records_the_captures_it_was_fitted_on_and_eval_scores_its_seen_and_unseen_presses_apart(
    solved, built, tmp_path, capsys
):
    """`nlips lut` fitted on a_sphere, b_cube and c_sphere_deep (d_cube_deep kept out): the table's file records their
    captures as a network's does, `nlips infer` writes `trained_on` into its results, and `nlips eval --method lut`
    gives the seen and unseen presses apart (a table has no validation presses: every seen press is "train"). A table
    fitted before it recorded captures: scored together, said once, naming `nlips lut`."""
    table = tmp_path / "lut.pt"
    assert main(["--no-progress", "lut", str(built), "--out", str(table), "--exclude", HELD]) == 0
    payload = torch.load(table, weights_only=True)
    assert payload["format_version"] == 1  # an added `info` key no reader of version 1 refuses: the version stays
    assert payload["info"]["captures"] == {name: capture_identity(solved / name) for name in PRESSES}
    presses = tmp_path / "presses"
    for name in [*PRESSES, HELD]:
        shutil.copytree(solved / name, presses / name)
    assert main(["--no-progress", "infer", str(table), str(presses), "--figures", "none"]) == 0
    capsys.readouterr()
    assert main(["eval", str(presses), "--method", "lut"]) == 0
    out, err = capsys.readouterr()
    table_rows = _table(out)
    assert out.splitlines()[0].split()[:3] == ["press", "data", "pixels"]
    assert {name: table_rows[name][0] for name in [*PRESSES, HELD]} == {
        **dict.fromkeys(PRESSES, "train"),
        HELD: "unseen",
    }
    assert int(table_rows["pooled seen"][0]) == sum(int(table_rows[n][1]) for n in PRESSES)
    assert int(table_rows["pooled unseen"][0]) == int(table_rows[HELD][1])
    assert "seen: 3 press(es), pooled AAE" in err and "unseen: 1 press(es), pooled AAE" in err

    old = tmp_path / "old.pt"  # as `nlips lut` wrote it before it recorded captures
    del payload["info"]["captures"], payload["info"]["press_identities"]
    torch.save(payload, old)
    err = _scored_together(old, presses, tmp_path / "old", capsys)
    assert err.count("seen and unseen presses not told apart") == 1 and "`nlips lut` and `nlips infer`" in err
