"""Interrupted, concurrent and damaged calibration datasets, checkpoints and model files (exact-data presses,
64x48, no rendering: a few seconds)."""

import dataclasses
import json
import logging
import shutil
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import claims as claims_module
from nlipscalib.core.atomic import TMP_PREFIX
from nlipscalib.core.claims import HOST, claim
from nlipscalib.core.errors import CaptureError
from nlipscalib.learn import dataset as dataset_module
from nlipscalib.learn.checkpoint import checkpoint_path
from nlipscalib.learn.dataset import CalibrationDataset, SamplingConfig, build_dataset
from nlipscalib.learn.model import load_model
from nlipscalib.learn.train import TrainConfig, train
from nlipscalib.pipeline import solve_folder
from nlipscalib.solver import SolverOptions
from tests.core.test_atomic import _dead_pid
from tests.core.test_reconstruction import _spoil_deflated_member
from tests.solver import synth

NAMES = ("a_sphere", "b_cube", "c_sphere_deep")
TINY = TrainConfig(hidden=(8,), dropout=0.0, max_epochs=2, patience=5)


@pytest.fixture(scope="module")
def solved(tmp_path_factory):
    """The undeformed dome and three exact-data presses, solved with NLiPs."""
    root = tmp_path_factory.mktemp("resume_presses")
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind, depth in zip(NAMES, ("sphere", "cube", "sphere"), (1.5, 1.5, 2.0)):
        synth.make_press(root / name, kind, depth=depth, size=(64, 48))
        solve_folder(root / name, options=SolverOptions(max_iters=6), figures=False, progress=False)
    return root


@pytest.fixture
def built(solved, tmp_path):
    out = tmp_path / "calib"
    build_dataset([solved / n for n in NAMES], solved / "reference", out, progress=False)
    return out


def _build(solved, out):
    return build_dataset([solved / n for n in NAMES], solved / "reference", out, progress=False)


def test_a_build_killed_before_its_index_resumes_from_the_shards(solved, built, monkeypatch):
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    (built / "index.json").unlink()  # index.json is written last: a build killed before it wrote none
    killed = built / "samples" / f"{TMP_PREFIX}b_cube.npz~{HOST}~{_dead_pid()}~x1y2"
    killed.write_bytes(b"half a shard")

    def never(*args):
        raise AssertionError("a finished shard was made again")

    monkeypatch.setattr(dataset_module, "press_samples", never)
    _build(solved, built)
    assert json.loads((built / "index.json").read_text(encoding="utf-8"))["presses"] == index["presses"]
    assert not killed.exists()
    assert len(CalibrationDataset(built).arrays()["rgb"]) == sum(e["samples"] for e in index["presses"])


def test_a_damaged_shard_is_made_again_and_named_when_read(solved, built, caplog):
    shard = built / "samples" / "b_cube.npz"
    whole = CalibrationDataset(built).load("b_cube")
    _spoil_deflated_member(shard, "rgb.npy")  # its zip directory is whole: only reading the array shows it
    # found reading the arrays' headers, before anything is inflated (a shard from elsewhere: docs/formats.md)
    with pytest.raises(CaptureError, match=r"b_cube\.npz: array 'rgb' is not readable \(compressed data damaged"):
        CalibrationDataset(built).load("b_cube")
    caplog.set_level(logging.WARNING)
    _build(solved, built)  # `nlips calibrate` again: it makes the shard again instead of failing on it
    assert "b_cube.npz" in caplog.text and "making it again" in caplog.text
    for key, value in CalibrationDataset(built).load("b_cube").items():
        np.testing.assert_array_equal(value, whole[key])


def test_a_build_waits_for_a_press_another_process_is_solving(solved, tmp_path, caplog, monkeypatch):
    """Two `nlips calibrate` runs split the solving; each build needs the presses the other one solved."""
    root = tmp_path / "presses"
    shutil.copytree(solved, root)
    finished = tmp_path / "finished"
    (root / "b_cube" / "nlips").rename(finished)
    holding = threading.Event()
    caplog.set_level(logging.INFO)

    def other_run():
        with claim(root / "b_cube" / "nlips"):  # a thread standing for the other run (claims are per process)
            holding.set()
            # until the build met the claim, not a fixed time: a build late on a loaded machine found it gone
            deadline = time.monotonic() + 60
            while "waiting for its result" not in caplog.text and time.monotonic() < deadline:
                time.sleep(0.01)
            finished.rename(root / "b_cube" / "nlips")

    monkeypatch.setattr(claims_module, "CLAIM_POLL_S", 0.05)
    thread = threading.Thread(target=other_run)
    thread.start()
    holding.wait()
    build_dataset([root / n for n in NAMES], root / "reference", tmp_path / "calib", progress=False)
    thread.join()
    assert "waiting for its result" in caplog.text
    assert CalibrationDataset(tmp_path / "calib").names == list(NAMES)


@pytest.mark.parametrize(
    "change, problem",
    [
        ({"presses": 3}, "'presses' must be a list"),
        ({"presses": [7]}, r"presses\[0\] must be a mapping"),
        ({"presses": [{"name": "../../etc/x", "samples": 1}]}, r"presses\[0\].name must be a press folder's name"),
        ({"presses": [{"name": "a_sphere"}]}, r"presses\[0\] \(a_sphere\): 'samples' must be a count"),
        ({"sensor": {}}, "'sensor' is not a sensor description .missing key 'camera'"),
        ({"sensor": {"camera": {"width": 64}}}, "'sensor' is not a sensor description .camera is missing keys"),
    ],
)
def test_a_hand_edited_index_is_one_line_naming_it(built, tmp_path, capsys, change, problem):
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    (built / "index.json").write_text(json.dumps(index | change), encoding="utf-8")
    with pytest.raises(CaptureError, match="index.json: " + problem):
        CalibrationDataset(built)
    assert main(["train", str(built), "--out", str(tmp_path / "m.pt"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "index.json" in err[0], err


def test_a_checkpoint_of_other_samples_is_not_resumed(built, tmp_path, caplog):
    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    first = train(data, TINY, out, val_names=["a_sphere"], progress=False)
    caplog.set_level(logging.INFO)
    again = train(data, TINY, out, val_names=["a_sphere"], progress=False)  # the same run: resumed, as it was
    assert "resuming after epoch 2" in caplog.text
    assert [h["seconds"] for h in again.history] == [h["seconds"] for h in first.history]
    for other in ({"val_names": ["b_cube"]}, {"val_names": ["a_sphere"], "exclude": ["c_sphere_deep"]}):
        caplog.clear()
        result = train(data, TINY, out, progress=False, **other)
        # resumed, it would train no epoch and report the old validation AAE as measured on these presses
        assert "made on other samples" in caplog.text
        assert [h["seconds"] for h in result.history] != [h["seconds"] for h in first.history]
        assert load_model(out).info["val_presses"] == other["val_names"]


@pytest.mark.parametrize("colour_input", ["ratio", "linear"])
def test_a_hand_edited_sampling_record_is_refused_in_one_line_not_reused(built, tmp_path, capsys, colour_input):
    """The model file carries the dataset's sampling record's smoothing_px (inference filters with it), which the
    samples' key does not hash: after a hand edit of index.json's ``sampling``, `nlips train` reused the model that
    carried the old one (training again would pair the old samples with the new record). Now one line naming the
    file and what differs; another --out trains with the record as it is. A model of colour ratios divides by the
    reference filtered with the record's smoothing, so its inputs' key follows the record: the edit went unnoticed
    and it trained again on the old samples over the new record's reference, finished or interrupted alike."""
    import hashlib

    import torch

    out = tmp_path / "m.pt"
    args = ["train", str(built), "--out", str(out), "--hidden", "8", "--epochs", "2", "--no-onnx", "--no-progress"]
    args += ["--colour-input", colour_input]
    assert main(args) == 0
    assert main(args) == 0 and "reused" in capsys.readouterr().err
    index = json.loads((built / "index.json").read_text(encoding="utf-8"))
    index["sampling"]["rest_cells"] += 1  # an option that decides only the samples, which are the same
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    assert main(args) == 0 and "reused" in capsys.readouterr().err
    was = index["sampling"]["smoothing_px"]
    index["sampling"]["smoothing_px"] = was + 1.0
    (built / "index.json").write_text(json.dumps(index), encoding="utf-8")
    before = out.read_bytes()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(built / "index.json") in err, err
    assert f"smoothing_px {was}, now {was + 1.0}" in err and "--out ANOTHER.pt" in err, err
    assert out.read_bytes() == before
    # killed before it finished (its progress file left, no model): refused alike
    published = checkpoint_path(out)
    ck = torch.load(published, weights_only=False)
    run = hashlib.sha1(f"{ck['key']}:{ck['data_key']}".encode()).hexdigest()[:12]  # progress_checkpoint_path's name
    published.rename(out.with_name(f"m.{run}.checkpoint.pt"))
    out.unlink()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"smoothing_px {was}, now {was + 1.0}" in err, err
    assert not out.exists()
    other = tmp_path / "other.pt"
    assert main([*args[:3], str(other), *args[4:]]) == 0
    assert load_model(other).smoothing_px == was + 1.0
    assert load_model(other).colour_input == colour_input


def test_a_model_another_training_made_is_replaced_with_a_warning_a_resumed_one_without(built, tmp_path, caplog):
    """`nlips train` again into the same --out with a tweak replaced the earlier (maybe better) model unnoticed."""
    import dataclasses

    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    train(data, TINY, out, val_names=["a_sphere"], progress=False)
    caplog.set_level(logging.INFO)
    caplog.clear()
    train(data, TINY, out, val_names=["a_sphere"], progress=False)  # the same run again: nothing is lost
    assert "resuming" in caplog.text and "a model is already there" not in caplog.text
    caplog.clear()
    train(data, dataclasses.replace(TINY, lr=1e-3), out, val_names=["a_sphere"], progress=False)
    warned = [r for r in caplog.records if r.levelno == logging.WARNING and "a model is already there" in r.message]
    assert len(warned) == 1 and str(out) in warned[0].message and "another --out" in warned[0].message
    checkpoint_path(out).unlink()  # a model whose checkpoint is gone (copied in, cleaned up) is not this run's
    caplog.clear()
    train(data, TINY, out, val_names=["a_sphere"], progress=False)
    assert "a model is already there" in caplog.text


def test_a_run_stopped_by_a_limit_continues_when_only_a_limit_changes_and_another_says_what_differs(
    built, tmp_path, caplog
):
    """Raising --epochs (or lifting --max-minutes, changing --patience) trained from scratch and replaced the model;
    these limits only decide where a run stops. Another option still starts afresh, and the log names it."""
    import dataclasses

    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    cfg = TrainConfig(hidden=(8,), dropout=0.0, max_epochs=2, patience=10, threads=1)
    first = train(data, cfg, out, val_names=["a_sphere"], progress=False)
    caplog.set_level(logging.INFO)
    longer = dataclasses.replace(cfg, max_epochs=4, patience=20, max_seconds=600.0)
    more = train(data, longer, out, val_names=["a_sphere"], progress=False)
    assert "resuming after epoch 2" in caplog.text and "a model is already there" not in caplog.text
    assert len(more.history) == 4 and more.history[:2] == first.history
    caplog.clear()
    shorter = train(data, dataclasses.replace(longer, max_epochs=3), out, val_names=["a_sphere"], progress=False)
    assert "trained 4 epochs, more than --epochs 3; training from scratch" in caplog.text and len(shorter.history) == 3
    caplog.clear()
    train(data, dataclasses.replace(longer, lr=1e-3), out, val_names=["a_sphere"], progress=False)
    assert "made with other training options (lr 0.002 -> 0.001); training from scratch" in caplog.text


def test_a_damaged_checkpoint_costs_only_its_progress(built, tmp_path, caplog):
    import torch

    from nlipscalib.learn.checkpoint import config_key

    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    train(data, TINY, out, progress=False)
    whole = checkpoint_path(out).read_bytes()
    caplog.set_level(logging.WARNING)
    hollow = tmp_path / "hollow.pt"
    torch.save({"key": config_key(TINY), "data_key": torch.load(checkpoint_path(out))["data_key"]}, hollow)
    for damage, why in (
        (whole[: len(whole) // 2], "truncated or damaged"),
        (b"\x00" * 300, "not a training checkpoint"),
        (b"", "empty"),
        (hollow.read_bytes(), "not resumable (it lacks 'history')"),  # right keys, no state: not a traceback either
    ):
        checkpoint_path(out).write_bytes(damage)
        caplog.clear()
        assert len(train(data, TINY, out, progress=False).history) == TINY.max_epochs
        assert "not resumable" in caplog.text and why in caplog.text and "training from scratch" in caplog.text


def test_killed_writes_beside_the_model_are_removed_by_the_next_training(built, tmp_path):
    out = tmp_path / "m.pt"
    dead = _dead_pid()
    leftovers = [tmp_path / f"{TMP_PREFIX}{name}~{HOST}~{dead}~k9" for name in ("m.pt", "m.checkpoint.pt")]
    live = tmp_path / f"{TMP_PREFIX}m.pt~{HOST}~1~k9"  # pid 1 lives: another training's write in progress
    for path in [*leftovers, live]:
        path.write_bytes(b"half")
    train(CalibrationDataset(built), TINY, out, progress=False)
    assert not any(p.exists() for p in leftovers) and live.exists()


def test_a_terminated_training_removes_its_staging_folder(tmp_path):
    """The SIGTERM handler removes this process's temporaries (core.atomic.remove_in_progress): the staging folder
    of a training's files is one of them (it used to stay until the next training into that place)."""
    from nlipscalib.core import atomic
    from nlipscalib.learn.publish import model_stage

    with model_stage(tmp_path / "m.pt") as stage:
        (stage / "m.pt").write_bytes(b"half a model")
        atomic.remove_in_progress()  # what the SIGTERM handler does before exiting
        assert not stage.exists()
    assert not list(tmp_path.iterdir())


def test_damaged_and_foreign_model_files_are_one_line(built, tmp_path, capsys):
    import torch

    out = tmp_path / "m.pt"
    train(CalibrationDataset(built), TINY, out, progress=False)
    whole = out.read_bytes()
    payload = torch.load(out, weights_only=True)
    cases = {
        "empty": (b"", "empty, not an NLiPsNet model file"),
        "garbage": (b"\x89PNG" + bytes(200), r"not an NLiPsNet model file \(not a torch.save archive\)"),
        "cut": (whole[:3000], "truncated or damaged, not usable as an NLiPsNet model file"),
    }
    for name, change, problem in (
        ("sensorless", {"sensor": {"camera": 5}}, "'sensor' is not a sensor description"),
        ("widthless", {"hidden": ["wide"]}, "'hidden' must list positive layer widths"),
        # widths the weights do not have: the net was built first (1.8 GB and 8 s for [20000, 20000]), then refused
        (
            "widened",
            {"hidden": [4096, 4096]},
            r"weights do not fit the architecture \('hidden' \[4096, 4096\] needs mlp.0.weight of shape \(4096, 5\)",
        ),
        ("noreference", {"reference": [1, 2]}, "'reference' must map names to arrays"),
        # a reference array missing or of another size: were a KeyError traceback, or a shape error not naming it
        (
            "novalid",
            {"reference": {k: v for k, v in payload["reference"].items() if k != "valid"}},
            "'reference' lacks the array 'valid'",
        ),
        (
            "shortdepth",
            {"reference": payload["reference"] | {"depth": payload["reference"]["depth"][:10]}},
            "'reference' array 'depth' is 10x64, the sensor's images need 48x64",
        ),
    ):
        torch.save(payload | change, tmp_path / "crafted.pt")
        cases[name] = ((tmp_path / "crafted.pt").read_bytes(), problem)
    for name, (data, problem) in cases.items():
        path = tmp_path / f"{name}.pt"
        path.write_bytes(data)
        with pytest.raises(CaptureError, match=f"{name}.pt: {problem}"):
            load_model(path)
        assert main(["infer", str(path), str(a_frame(tmp_path))]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"{name}.pt" in err[0], err


def a_frame(folder):
    """A folder with one blank tri-colour frame of the sensor's size: an input `nlips infer` has to infer, so the
    model is read (the inputs are checked before it)."""
    from nlipscalib.core.imageio import write_png16

    frames = folder / "frames"
    frames.mkdir(exist_ok=True)
    write_png16(frames / "f.png", np.zeros((48, 64, 3), np.uint16))
    return frames


EXPORT_WAITS = """
import pathlib, sys, time
from nlipscalib.learn import onnx_export
flags, export = pathlib.Path(sys.argv.pop(1)), onnx_export.export_onnx
def export_when_told(model, out, check=None):  # the model to export is loaded: hold on until the test says go
    (flags / "exporting").touch()
    while not (flags / "go").exists():
        time.sleep(0.02)
    return export(model, out, check=check)
onnx_export.export_onnx = export_when_told
from nlipscalib.cli import main
sys.exit(main(sys.argv[1:]))
"""
"""`nlips train` whose ONNX export waits for a file ``go`` in the folder given first (and says it waits)."""


def test_the_same_training_started_twice_waits_and_reuses_the_model_and_another_into_its_out_is_refused(
    built, tmp_path
):
    """Run A (8 wide) holds in its export. Two identical `nlips train` runs started at once both trained every epoch
    (nothing stopped the second) and the last to write won. Now B, the same command, waits for A, then reuses its
    model in one line, training and writing nothing; C, another training into A's --out, is refused at once in one
    line naming what differs (before: it ran start to end and A, finishing last, replaced its model)."""
    import os
    from pathlib import Path

    import torch

    from nlipscalib.learn.onnx_export import OnnxNet
    from tests.processes import until_each_waits_or_exits

    out = tmp_path / "models" / "m.pt"
    flags = tmp_path / "flags"
    flags.mkdir()
    args = ["train", str(built), "--out", str(out), "--epochs", "2", "--threads", "1", "--no-progress"]
    env = os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    run_a = subprocess.Popen(
        [sys.executable, "-c", EXPORT_WAITS, str(flags), *args, "--hidden", "8", "--dropout", "0"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    cli = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
    b_log = tmp_path / "b.log"
    run_b = None
    try:
        deadline = time.monotonic() + 120
        while not (flags / "exporting").exists():
            assert run_a.poll() is None, run_a.communicate()
            assert time.monotonic() < deadline
            time.sleep(0.05)
        line = _refused_in_one_line(cli, [*args, "--hidden", "4"], env)
        assert f"{out}: process {run_a.pid} on " in line and "is training another model into it" in line, line
        assert "hidden [8] (this run: [4])" in line and "another --out" in line, line
        with b_log.open("w") as log_file:
            run_b = subprocess.Popen(
                [sys.executable, "-c", cli, *args, "--hidden", "8", "--dropout", "0"],
                env=env,
                stdout=subprocess.PIPE,
                stderr=log_file,
                text=True,
            )
        until_each_waits_or_exits([run_b], [b_log], "is training the same model", timeout=120)
        assert run_b.poll() is None, b_log.read_text(encoding="utf-8")
        (flags / "go").touch()
        stdout, stderr = run_a.communicate(timeout=120)
        assert run_a.returncode == 0, stderr
        published = _model_files(out.parent)
        b_out = run_b.communicate(timeout=120)[0]
    finally:
        for proc in (run_a, run_b):
            if proc is not None:
                proc.kill()
                proc.wait()
    assert run_b.returncode == 0, b_log.read_text(encoding="utf-8")
    waited = [line for line in b_log.read_text(encoding="utf-8").splitlines() if "waiting for it" in line]
    assert len(waited) == 1 and f"process {run_a.pid} on" in waited[0], b_log.read_text(encoding="utf-8")
    assert b_out == f"{out}\n"  # stdout: the model's file alone; the reuse said on stderr
    assert f"{out}: reused, trained before with the same options on the same samples" in b_log.read_text(
        encoding="utf-8"
    )
    assert "resuming" not in b_log.read_text(encoding="utf-8")  # no epoch trained, nothing written again
    assert _model_files(out.parent) == published
    model = load_model(out)
    assert model.hidden == (8,)  # A's, whole: its .pt, .onnx and checkpoint
    OnnxNet(out.with_suffix(".onnx"), model)
    checkpoint = torch.load(checkpoint_path(out), weights_only=False)
    assert checkpoint["history"] == model.info["history"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["m.checkpoint.pt", "m.onnx", "m.pt", "m_curve.png"]
    assert stdout == f"{out}\n"  # the model's file alone; what it is on stderr
    assert f"{out}: best epoch" in stderr and f"{out.with_suffix('.onnx')}: onnxruntime vs PyTorch" in stderr


def _model_files(folder):
    """{name: modification time} of a training's files in ``folder`` (not the claims and stages of runs at work)."""
    return {p.name: p.stat().st_mtime_ns for p in folder.iterdir() if not p.name.startswith(".")}


def test_a_killed_trainings_hold_is_taken_over_and_its_progress_resumed(built, tmp_path, monkeypatch, capsys, caplog):
    """`nlips train` killed (-9) mid-run leaves its hold on the model path: the next run of the same training does not
    wait for it (its owner is gone), and continues from its checkpoint."""
    import json as json_module

    from nlipscalib.learn.checkpoint import training_run
    from nlipscalib.learn.publish import TRAIN_HOLD

    out = tmp_path / "m.pt"
    cfg = TrainConfig(hidden=(8,), dropout=0.0, max_epochs=4, patience=10, threads=1)
    data = CalibrationDataset(built)
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, cfg, out, progress=False))
    run = training_run(cfg, built, None, [])
    hold = tmp_path / f".claim-m.pt{TRAIN_HOLD}"
    hold.write_text(json_module.dumps({"host": HOST, "pid": _dead_pid(), "token": "k9", "note": run}), encoding="utf-8")
    caplog.set_level(logging.INFO)
    args = ["train", str(built), "--out", str(out), "--epochs", "4", "--patience", "10", "--hidden", "8"]
    assert main([*args, "--dropout", "0", "--threads", "1", "--no-progress", "--no-onnx"]) == 0
    assert "resuming after epoch 2" in caplog.text and "waiting" not in caplog.text
    assert len(load_model(out).info["history"]) == 4 and not hold.exists()
    capsys.readouterr()
    assert main([*args, "--dropout", "0", "--threads", "1", "--no-progress", "--no-onnx"]) == 0  # done: reused
    assert f"{out}: reused, trained before" in capsys.readouterr().err


@pytest.mark.parametrize("full_frame", [False, True])
def test_an_export_beside_the_model_is_never_of_the_model_a_training_replaced_meanwhile(
    built, tmp_path, monkeypatch, full_frame
):
    """`nlips export m.pt` read the model, a training published another m.pt (and its .onnx) meanwhile, then the export
    put the old model's .onnx beside the new .pt (inference refused it). The export now reads and writes while no
    training publishes into that place (their claim on the model path), so its .onnx is of the .pt beside it; the
    full-frame graph (`--full-frame`, m.frame.onnx, which `nlips infer --full-frame` runs) likewise (s40-companions:
    it was written without the claim)."""
    from nlipscalib.learn import model as model_module
    from nlipscalib.learn.onnx_export import OnnxNet
    from nlipscalib.learn.onnx_fullframe import check_full_frame
    from nlipscalib.learn.publish import model_files_held

    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    train(data, TINY, out, progress=False)
    other = tmp_path / "other" / "m.pt"
    train(data, TrainConfig(hidden=(4,), dropout=0.0, max_epochs=1, threads=1), other, progress=False)
    loaded, replaced, real_load = threading.Event(), threading.Event(), model_module.load_model

    def load_then_stall(*args, **kwargs):  # the model read: give a publish the moment to run (on the old code)
        model = real_load(*args, **kwargs)
        loaded.set()
        replaced.wait(timeout=3)
        return model

    monkeypatch.setattr(model_module, "load_model", load_then_stall)

    def publish_another():  # what publish_model does, under the same claim
        with model_files_held(out):
            held.set()
            loaded.wait(timeout=2)  # the export cannot read the model now: it waits for this claim
            out.with_suffix(".onnx").unlink(missing_ok=True)
            shutil.copy(other, out)
            replaced.set()

    held = threading.Event()
    publisher = threading.Thread(target=publish_another)
    publisher.start()
    held.wait(timeout=10)
    try:
        assert main(["export", str(out), *(["--full-frame"] if full_frame else [])]) == 0
    finally:
        publisher.join()
    assert load_model(out).hidden == (4,)
    # exported from the .pt beside it ("from another model" before)
    if full_frame:
        check_full_frame(out.with_suffix(".frame.onnx"), real_load(out))
    else:
        OnnxNet(out.with_suffix(".onnx"), real_load(out))


@pytest.mark.parametrize("torn", ["m.pt", "m.onnx"])
@pytest.mark.parametrize("length", [0, 300])
def test_a_finished_models_file_torn_after_it_was_published_is_made_again_not_reused(
    built, tmp_path, capsys, caplog, torn, length
):
    """A model or its export left empty or cut short after the run that published them had ended (a power cut
    before the disk had the files; a copy interrupted) beside a whole checkpoint: the next identical `nlips train`
    said "reused, trained before ...", exit 0, every time, and only `nlips infer` found the file damaged. Now it
    is named and made again from the checkpoint, without training an epoch again: the same weights as before."""
    from nlipscalib.learn.onnx_export import check_export

    out = tmp_path / "m.pt"
    args = ["train", str(built), "--out", str(out), "--epochs", "2", "--hidden", "8", "--threads", "1"]
    assert main([*args, "--no-progress"]) == 0
    weights = {k: v.clone() for k, v in load_model(out).net.state_dict().items()}
    with open(tmp_path / torn, "r+b") as f:
        f.truncate(length)
    capsys.readouterr()
    caplog.set_level(logging.INFO)
    assert main([*args, "--no-progress"]) == 0
    said = capsys.readouterr().err
    assert "reused" not in said and f"{tmp_path / torn}: " in caplog.text and "made again" in caplog.text
    assert "resuming after epoch 2" in caplog.text and "epoch 1 " not in said
    model = load_model(out)
    assert all(torch_equal(model.net.state_dict()[k], v) for k, v in weights.items())
    check_export(out.with_suffix(".onnx"), model)  # whole, and this model's
    capsys.readouterr()
    assert main([*args, "--no-progress"]) == 0 and f"{out}: reused" in capsys.readouterr().err  # now reused


def torch_equal(a, b) -> bool:
    import torch

    return bool(torch.equal(a, b))


def test_a_kept_re_run_decides_before_building_an_optimiser(built, tmp_path, monkeypatch):
    """A re-run that reuses its finished model built the net, AdamW and its scheduler first, and the optimiser's first
    construction imports torch._dynamo: ~1.5 s of a 2.7-4.4 s CPU re-run (s41-trainreuse). Now it reuses the model
    with the optimiser's constructor refusing; a run that trains still builds it (the patch bites)."""
    import torch

    cfg = TrainConfig(hidden=(8,), dropout=0.2, max_epochs=2, patience=5, threads=1)
    out = tmp_path / "m" / "net.pt"
    first = train(built, cfg, out, progress=False)
    before = out.read_bytes()

    def refused(self, *args, **kwargs):
        raise AssertionError("an optimiser was built")

    monkeypatch.setattr(torch.optim.Optimizer, "__init__", refused)
    again = train(built, cfg, out, progress=False, reuse=True)
    assert again.reused and again.history == first.history and out.read_bytes() == before
    with pytest.raises(AssertionError, match="an optimiser was built"):
        train(built, cfg, tmp_path / "other" / "net.pt", progress=False, reuse=True)


def test_a_training_without_onnx_removes_the_export_of_the_model_it_replaces(built, tmp_path, capsys):
    """`--no-onnx` into an --out that held another run's .pt and .onnx left that .onnx beside the new .pt."""
    out = tmp_path / "m.pt"
    args = ["train", str(built), "--out", str(out), "--epochs", "1", "--threads", "1", "--no-progress"]
    assert main([*args, "--hidden", "4"]) == 0 and out.with_suffix(".onnx").is_file()
    assert main([*args, "--hidden", "8", "--no-onnx"]) == 0
    assert load_model(out).hidden == (8,)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith("m")) == [
        "m.checkpoint.pt",
        "m.pt",
        "m_curve.png",
    ]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith((TMP_PREFIX, ".claim-"))]


def test_an_interrupted_training_resumed_makes_the_model_an_uninterrupted_one_makes(built, tmp_path, monkeypatch):
    """The batch order and the dropout masks of each epoch depend on the seed and the epoch alone: a resumed run
    used to reseed its batch order with seed + epochs done and kept no dropout state, so it trained another
    model (quick Q2: best epoch 21 vs 27)."""
    import torch

    cfg = TrainConfig(hidden=(8,), dropout=0.2, max_epochs=4, patience=10, threads=1)
    data = CalibrationDataset(built)
    whole = train(data, cfg, tmp_path / "whole" / "net.pt", progress=False)

    out = tmp_path / "resumed" / "net.pt"
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, cfg, out, progress=False))
    torch.manual_seed(12345)  # whatever the process drew in between
    resumed = train(data, cfg, out, progress=False)
    assert [h["val_aae_deg"] for h in resumed.history] == [h["val_aae_deg"] for h in whole.history]
    a, b = load_model(tmp_path / "whole" / "net.pt"), load_model(out)
    for (name, x), y in zip(a.net.state_dict().items(), b.net.state_dict().values()):
        assert torch.equal(x, y), name


def test_a_training_resumed_on_another_thread_count_says_so_and_records_each_epochs_count(
    built, tmp_path, monkeypatch, caplog
):
    """The thread count is left out of what a checkpoint must match (it only says how fast), but it sets the
    summation order: a run interrupted on 1 thread and resumed on 2 made a model slightly other than either count's
    uninterrupted one (up to 0.004 apart), said only "resuming after epoch 15", and its model file recorded
    threads 2 for all 40 epochs."""
    cfg = TrainConfig(hidden=(8,), dropout=0.2, max_epochs=4, patience=10, threads=1)
    data = CalibrationDataset(built)
    out = tmp_path / "net.pt"
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, cfg, out, progress=False))
    caplog.set_level(logging.INFO)
    resumed = train(data, dataclasses.replace(cfg, threads=2), out, progress=False)
    assert "resuming after epoch 2, trained on 1 thread(s) so far and on 2 from here" in caplog.text
    assert "--threads 1 carries on bit for bit" in caplog.text
    assert [h["threads"] for h in resumed.history] == [1, 1, 2, 2]
    assert [h["threads"] for h in load_model(out).info["history"]] == [1, 1, 2, 2]

    caplog.clear()
    again = tmp_path / "again.pt"
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, cfg, again, progress=False))
    train(data, cfg, again, progress=False)  # the same count: nothing to say
    assert "resuming after epoch 2\n" in caplog.text + "\n" and "thread(s) so far" not in caplog.text


def test_a_training_interrupted_while_another_run_trains_into_the_same_out_resumes_its_own_progress(
    built, tmp_path, monkeypatch, caplog
):
    """Every epoch's checkpoint was MODEL.checkpoint.pt, whichever run wrote it: a run with other options into the
    same --out overwrote an interrupted run's progress, which then trained from scratch. Now each run's progress is
    a checkpoint named by the run, and the published MODEL.checkpoint.pt is the last state of the run that ended."""
    import dataclasses

    import torch

    data, out = CalibrationDataset(built), tmp_path / "m.pt"
    cfg_a = TrainConfig(hidden=(8,), dropout=0.0, max_epochs=4, patience=10, threads=1)
    cfg_b = dataclasses.replace(cfg_a, hidden=(4,), max_epochs=2)
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, cfg_a, out, progress=False))
    progress = [p for p in tmp_path.iterdir() if p.name.endswith(".checkpoint.pt")]
    assert len(progress) == 1 and progress[0] != checkpoint_path(out)  # A's, named by its run
    b = train(data, cfg_b, out, progress=False)  # another run, start to end, into the same place
    assert torch.load(checkpoint_path(out), weights_only=False)["history"] == b.history
    caplog.set_level(logging.INFO)
    a = train(data, cfg_a, out, progress=False)
    assert f"{progress[0]}: resuming after epoch 2" in caplog.text
    assert f"{out}: a model is already there (not this training's" in caplog.text  # B's, replaced: said
    assert len(a.history) == 4 and load_model(out).hidden == (8,)
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.endswith(".checkpoint.pt")) == ["m.checkpoint.pt"]


def _interrupted_after_two_epochs(monkeypatch, run) -> None:
    """``run()`` (a training) with Ctrl-C arriving after its second epoch; the trainer is whole again afterwards."""
    from nlipscalib.learn import train as train_module

    real_epoch, calls = train_module._epoch, []

    def interrupted(*args):
        if len(calls) == 2:
            raise KeyboardInterrupt
        calls.append(1)
        return real_epoch(*args)

    with monkeypatch.context() as patch:
        patch.setattr(train_module, "_epoch", interrupted)
        with pytest.raises(KeyboardInterrupt):
            run()


def test_a_resumed_build_says_which_presses_samples_it_kept(solved, built, caplog):
    """`nlips calibrate` run again after a kill kept the finished shards without a word, where `nlips solve` and
    `nlips experiment` say what they reused."""
    (built / "index.json").unlink()  # killed before its index
    (built / "samples" / "b_cube.npz").unlink()  # ... and before b_cube's shard
    caplog.set_level(logging.INFO)
    _build(solved, built)
    assert "samples of 2 of 3 presses kept (made from the same results and options): a_sphere, c_sphere_deep" in (
        caplog.text
    )


# ---------------------------------------------------------------------- builds sharing a dataset folder
SAMPLES_WAIT = """
import pathlib, sys, time
from nlipscalib.learn import dataset
flags, gated, make = pathlib.Path(sys.argv.pop(1)), sys.argv.pop(1) == "gated", dataset.press_samples
def counted(press, *args):  # each press's samples made: a line in FLAGS/made; gated: held until FLAGS/go
    if gated:
        (flags / "sampling").touch()
        while not (flags / "go").exists():
            time.sleep(0.02)
    with open(flags / "made", "a") as f:
        f.write(press.folder.name + "\\n")
    return make(press, *args)
dataset.press_samples = counted
from nlipscalib.cli import main
sys.exit(main(sys.argv[1:]))
"""
"""`nlips calibrate` counting the presses whose samples it makes (FLAGS/made); ``gated``: each waits for FLAGS/go."""


@pytest.fixture(scope="module")
def cli_solved(tmp_path_factory):
    """The undeformed dome and three exact-data presses solved by `nlips calibrate` (its dataset removed), so that
    later runs reuse every result and only build samples."""
    root = tmp_path_factory.mktemp("cli_presses") / "presses"
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind in zip(NAMES, ("sphere", "cube", "sphere")):
        synth.make_press(root / name, kind, size=(64, 48))
    assert main(["calibrate", str(root), "--workers", "1", "--no-progress"]) == 0
    shutil.rmtree(root / "calibration")
    return root


def test_the_same_calibration_twice_makes_each_shard_once_and_one_of_other_samples_is_refused(cli_solved, tmp_path):
    """Run A holds in its first press's samples. Before, the sample build took no claim: B, the same command, made
    every press's samples a second time, and C, another --smoothing into the same --out, replaced shards under A's
    index.json. Now B makes the presses A is not at, waits for the one A is making (one line) and reuses it; C is
    refused at once in one line naming what differs, exit 2."""
    import os
    from pathlib import Path

    from tests.processes import until_each_waits_or_exits

    root = tmp_path / "presses"
    shutil.copytree(cli_solved, root)
    out, flags = root / "calibration", tmp_path / "flags"
    flags.mkdir()
    env = os.environ | {"PYTHONPATH": str(Path(__file__).resolve().parents[2])}
    args = ["calibrate", str(root), "--workers", "1", "--no-progress"]

    def start(gated: str, log_file) -> subprocess.Popen:
        code = [sys.executable, "-c", SAMPLES_WAIT, str(flags), gated, *args]
        return subprocess.Popen(code, env=env, stdout=subprocess.PIPE, stderr=log_file, text=True)

    a_log, b_log = tmp_path / "a.log", tmp_path / "b.log"
    run_a = run_b = None
    try:
        with a_log.open("w") as log_file:
            run_a = start("gated", log_file)
        deadline = time.monotonic() + 120
        while not (flags / "sampling").exists():
            assert run_a.poll() is None, a_log.read_text(encoding="utf-8")
            assert time.monotonic() < deadline
            time.sleep(0.05)
        cli = "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"
        line = _refused_in_one_line(cli, [*args, "--smoothing", "0"], env)
        assert f"{out}: process {run_a.pid} on " in line and "of other samples into it" in line, line
        assert "--smoothing 1.0 (this run: 0.0)" in line and "another --out" in line, line
        with b_log.open("w") as log_file:
            run_b = start("free", log_file)
        until_each_waits_or_exits([run_b], [b_log], "waiting for its shard", timeout=120)
        assert run_b.poll() is None, b_log.read_text(encoding="utf-8")
        (flags / "go").touch()
        assert run_a.wait(timeout=120) == 0, a_log.read_text(encoding="utf-8")
        assert run_b.wait(timeout=120) == 0, b_log.read_text(encoding="utf-8")
    finally:
        for proc in (run_a, run_b):
            if proc is not None:
                proc.kill()
                proc.wait()
    made = (flags / "made").read_text(encoding="utf-8").split()
    assert sorted(made) == sorted(NAMES), made  # each press's samples made once, by one run or the other
    waited = [
        line for line in b_log.read_text(encoding="utf-8").splitlines() if "being sampled by another process" in line
    ]
    assert len(waited) == 1 and f"{NAMES[0]}.npz" in waited[0], b_log.read_text(encoding="utf-8")
    data = CalibrationDataset(out)
    assert data.names == list(NAMES) and len(data.arrays()["rgb"]) == sum(e["samples"] for e in data.entries)
    assert not [p for p in out.rglob(".*") if p.name.startswith((".claim-", TMP_PREFIX))]


def test_a_killed_builds_claims_are_taken_over_and_its_finished_shards_reused(solved, built, monkeypatch, caplog):
    """`nlips calibrate` killed (-9) mid-build, of other samples: its hold on the folder and its claim on the shard
    it was making are a dead process's; the next build neither waits for them nor is refused by them."""
    from nlipscalib.learn.dataset import HOLD_NAME

    (built / "index.json").unlink()
    dead = {"host": HOST, "pid": _dead_pid(), "token": "k9"}
    hold = built / f".claim-{HOLD_NAME}~0123456789abcdef~k9"
    hold.write_text(
        json.dumps(dead | {"note": {"key": "0123456789abcdef", "options": {"smoothing_px": 0.0}}}), encoding="utf-8"
    )
    shard_claim = built / "samples" / ".claim-b_cube.npz"
    shard_claim.write_text(json.dumps(dead), encoding="utf-8")

    def never(*args):
        raise AssertionError("a finished shard was made again")

    monkeypatch.setattr(dataset_module, "press_samples", never)
    caplog.set_level(logging.INFO)
    _build(solved, built)
    assert "samples of 3 of 3 presses kept" in caplog.text and "waiting" not in caplog.text
    assert CalibrationDataset(built).names == list(NAMES)
    assert not hold.exists() and not shard_claim.exists()
    # each claim is called a claim: it was logged as "removed an interrupted write", a write that never was
    assert f"{hold}: removed the claim of a run that ended without releasing it (killed)" in caplog.text
    assert "interrupted write" not in caplog.text


def test_a_shard_another_build_replaced_is_never_mixed_in_and_is_made_again(solved, built, tmp_path, monkeypatch):
    """A build of other sampling options (--smoothing 0) into the folder, killed after one shard, left that shard
    beside the earlier build's index.json: the same sample count, other colours. Training read it as the index's, and
    the next build kept it (the index's record matched, and only the count was compared). Now a shard records what
    made it: reading it is refused, and the next build makes it again."""
    raw, presses = tmp_path / "raw", [solved / n for n in NAMES]
    build_dataset(presses, solved / "reference", raw, SamplingConfig(smoothing_px=0.0), progress=False)
    name = NAMES[-1]
    shutil.copy(raw / "samples" / f"{name}.npz", built / "samples" / f"{name}.npz")  # what the killed build left
    assert len(CalibrationDataset(raw).load(name)["rgb"]) == CalibrationDataset(built).entry(name)["samples"]
    with pytest.raises(CaptureError, match=rf"{name}\.npz: made from other results or sampling options"):
        CalibrationDataset(built).load(name)
    made, real = [], dataset_module.press_samples
    monkeypatch.setattr(dataset_module, "press_samples", lambda p, *a: made.append(p.folder.name) or real(p, *a))
    _build(solved, built)
    assert made == [name]
    CalibrationDataset(built).arrays()


def test_samples_are_made_again_against_another_undeformed_reference(solved, built, tmp_path, monkeypatch):
    """The reference frame decides which pixels are contact and the rest's labels, but a shard's stamp held only the
    result's size and time and the options: a build against another reference kept every shard."""
    other = tmp_path / "reference"
    synth.make_press(other, "none", size=(64, 48), lin_hook=lambda lin: lin * 1.02)  # another lamp current, say
    made, real = [], dataset_module.press_samples
    monkeypatch.setattr(dataset_module, "press_samples", lambda p, *a: made.append(p.folder.name) or real(p, *a))
    build_dataset([solved / n for n in NAMES], other, built, progress=False)
    assert made == list(NAMES)
    made.clear()
    build_dataset([solved / n for n in NAMES], other, built, progress=False)  # the same again: kept
    assert made == []


RULES_BEFORE_FRAME_GAIN = {"rule": 2}
"""learn.dataset.SAMPLE_RULES until 2026-12-06: what the shards made before contact_pixels scaled the reference frame
for a dimmed press were stamped with."""


def test_shards_stamped_before_the_dimmed_press_rule_are_made_again_on_resume(solved, tmp_path, monkeypatch):
    """s28-together changed which pixels of a press dimmer than its undeformed capture count as contact
    (learn.dataset.contact_pixels) without a new sampling version: a resumed `nlips calibrate` kept every shard the
    old rule had made (almost none of such a press's contact). Shards stamped with the older versions are made again;
    the next build keeps them."""
    out = tmp_path / "calib"
    monkeypatch.setattr(dataset_module, "SAMPLE_RULES", RULES_BEFORE_FRAME_GAIN)
    _build(solved, out)
    monkeypatch.undo()
    (out / "index.json").unlink()  # killed before its index: resumed from the shards' own entries
    made, real = [], dataset_module.press_samples
    monkeypatch.setattr(dataset_module, "press_samples", lambda p, *a: made.append(p.folder.name) or real(p, *a))
    _build(solved, out)
    assert made == list(NAMES)
    made.clear()
    _build(solved, out)
    assert made == []


RULES_BEFORE_GAIN_OUT = {"rule": 2, "frame_gain": 1}
"""learn.dataset.SAMPLE_RULES until 2026-12-08, before the change rule took a frame's per-colour gain out (rule 3)."""


def test_a_dataset_of_an_older_change_rule_is_made_again_with_one_line_naming_it(solved, tmp_path, monkeypatch, caplog):
    """`nlips calibrate` again on a dataset the change rule 2 sampled: every shard is made anew (their stamps hold
    the rules) and one INFO line says why, naming index.json and the versions; the next build keeps them, silently."""
    out = tmp_path / "calib"
    monkeypatch.setattr(dataset_module, "SAMPLE_RULES", RULES_BEFORE_GAIN_OUT)
    _build(solved, out)
    monkeypatch.undo()
    made, real = [], dataset_module.press_samples
    monkeypatch.setattr(dataset_module, "press_samples", lambda p, *a: made.append(p.folder.name) or real(p, *a))
    with caplog.at_level(logging.INFO, logger="nlipscalib"):
        _build(solved, out)
    said = [r for r in caplog.records if "sampling rules" in r.getMessage()]
    assert made == list(NAMES)
    assert [(r.levelno, r.getMessage()) for r in said] == [
        (
            logging.INFO,
            f"{out / 'index.json'}: made under other sampling rules (rule 2, now "
            f"{dataset_module.RULE_VERSION}): each press's samples are made again",
        )
    ]
    assert CalibrationDataset(out).older_sampling() is None
    made.clear()
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="nlipscalib"):
        _build(solved, out)
    assert made == [] and not [r for r in caplog.records if "sampling rules" in r.getMessage()]


def _refused_in_one_line(cli: str, args: list[str], env: dict) -> str:
    """Run ``python -c cli ARGS``, which must be refused: exit 2 and one line on stderr, returned."""
    run = subprocess.run([sys.executable, "-c", cli, *args], env=env, capture_output=True, text=True, timeout=120)
    assert run.returncode == 2, run.stderr
    (line,) = run.stderr.strip().splitlines()
    return line


def test_the_training_bar_names_its_labels(built, tmp_path, as_terminal):
    """q2 trains twice (NLiPs labels, then true normals) and showed two bars both called "training", which read as
    the training starting over; each bar now names what it learns."""
    tty = as_terminal()
    for labels in ("nlips", "true"):
        train(CalibrationDataset(built), dataclasses.replace(TINY, labels=labels), tmp_path / f"{labels}.pt")
    shown = tty.getvalue()
    assert "training on NLiPs labels: 100%" in shown and "training on true normals: 100%" in shown


def test_a_read_only_model_folder_is_named_by_the_model_path_not_its_training_hold(
    built, tmp_path, monkeypatch, capsys
):
    """`nlips train --out RO/x.pt` on read-only media said "RO/x.pt~train: Read-only file system": the name of the
    training's hold, which the user never gave."""
    import errno
    import os
    from pathlib import Path

    out = tmp_path / "ro" / "x.pt"
    real_write_bytes = Path.write_bytes

    def write_bytes(self, data):
        if self.parent == out.parent:  # the claim's first write: what a read-only mount refuses
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))
        return real_write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", write_bytes)
    assert main(["--no-progress", "train", str(built), "--out", str(out), "--hidden", "8"]) == 2
    err = capsys.readouterr().err
    assert err == f"nlips train: error: {out}: Read-only file system (choose a writable output folder)\n", err


def test_each_epoch_is_a_line_of_the_log_file(built, tmp_path):
    """A three-hour `nlips --log-file F train` left nothing in F between its start and its end: after a crash
    the lab could not tell how far it got. Each epoch is now a line there (on stderr only with -v:
    tests/test_progress.py)."""
    from nlipscalib import progress

    log = tmp_path / "train.log"
    try:
        progress.configure(progress=False, log_file=log)
        train(CalibrationDataset(built), TINY, tmp_path / "m.pt", val_names=["a_sphere"], progress=False)
    finally:
        progress.configure(progress=True)
    epochs = [line for line in log.read_text(encoding="utf-8").splitlines() if ": epoch " in line]
    assert [line.split(": epoch ")[1].split(":")[0] for line in epochs] == ["1 of at most 2", "2 of at most 2"]
    assert all("validation AAE" in line and "INFO nlipscalib.learn.train" in line for line in epochs), epochs


def test_a_folder_given_for_the_model_file_is_refused_before_training(tmp_path):
    """`train(dataset, cfg, "out/api")` with a folder trained every epoch, then failed naming its temporary file
    ("out/.tmp-api~host~pid~... -> out/api": Is a directory)."""
    import errno

    from nlipscalib.learn.train import train

    with pytest.raises(IsADirectoryError, match=r"a folder; give the path of the model file") as raised:
        train(tmp_path / "no dataset here", TINY, tmp_path, progress=False)  # refused before the dataset is read
    assert raised.value.errno == errno.EISDIR and raised.value.filename == str(tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_the_options_a_checkpoint_left_out_are_named_by_what_they_meant():
    """A linear model's checkpoint under the ratio default said "colour_input None -> 'ratio'", and a linear run
    over a ratio checkpoint "made with other training options ()": an option left out of the record (at the value
    records made before it existed meant) is named by that value, on either side."""
    from nlipscalib.learn.checkpoint import _options_changed, _trajectory_options

    linear, ratio = TrainConfig(colour_input="linear"), TrainConfig(colour_input="ratio")
    assert _options_changed(_trajectory_options(linear), ratio) == "colour_input 'linear' -> 'ratio'"
    assert _options_changed(_trajectory_options(ratio), linear) == "colour_input 'ratio' -> 'linear'"
    no_decay = dataclasses.replace(ratio, weight_decay=0.0)
    assert _options_changed(_trajectory_options(no_decay), ratio) == f"weight_decay 0.0 -> {ratio.weight_decay}"
    assert _options_changed(_trajectory_options(ratio), ratio) == ""
    # the reference's Gaussian (thirty-eighth session): a ratio checkpoint from before it meant 0 (the samples' filter)
    before = dataclasses.replace(ratio, reference_smoothing_px=0.0)
    assert _options_changed(_trajectory_options(before), ratio) == "reference_smoothing_px 0.0 -> 3.0"
