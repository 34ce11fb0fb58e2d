"""`nlips train` over a model that had exports beside it (MODEL.onnx and the full-frame graph MODEL.frame.onnx, `nlips
export MODEL --full-frame`): each made again for the new model and published with it, or removed in the same publish
with one line naming it and the command that writes it (exact-data presses, 64x48: seconds)."""

import logging

import pytest

from nlipscalib.cli import main
from nlipscalib.core.atomic import TMP_PREFIX
from nlipscalib.learn.model import load_model
from tests.learn.test_resume import built, solved  # noqa: F401 (fixtures)

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

TRAIN = ["--epochs", "1", "--threads", "1", "--no-progress"]


def _trained_with_both_exports(built, out, capsys):  # noqa: F811 (the fixture's name)
    """A model of one run with its per-pixel export and its full-frame graph beside it."""
    assert main(["train", str(built), "--out", str(out), "--hidden", "4", *TRAIN]) == 0
    assert main(["export", str(out), "--full-frame"]) == 0
    assert out.with_suffix(".onnx").is_file() and out.with_suffix(".frame.onnx").is_file()
    capsys.readouterr()
    return load_model(out).digest


def _left(folder):
    return [p.name for p in folder.iterdir() if p.name.startswith((TMP_PREFIX, ".claim-"))]


def test_a_retrained_model_gets_both_exports_made_again_and_auto_runs_them(built, tmp_path, capsys, caplog):  # noqa: F811
    """Retrained (other options): MODEL.onnx and MODEL.frame.onnx are the new model's (their checks pass), said, and
    `--backend auto` takes them without a warning; before, the full-frame graph of the old model stayed beside the
    new one and `nlips infer --full-frame` stopped on it."""
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.onnx_export import check_export
    from nlipscalib.learn.onnx_fullframe import check_full_frame

    out = tmp_path / "m.pt"
    old = _trained_with_both_exports(built, out, capsys)
    assert main(["train", str(built), "--out", str(out), "--hidden", "8", *TRAIN]) == 0
    err = capsys.readouterr().err
    model = load_model(out)
    assert model.hidden == (8,) and model.digest != old
    check_export(out.with_suffix(".onnx"), model)  # whole, and this model's
    check_full_frame(out.with_suffix(".frame.onnx"), model)
    assert f"{out.with_suffix('.frame.onnx')}: made again for the new model" in err
    assert "max angular difference" in err and "removed" not in err
    assert not _left(tmp_path)
    caplog.set_level(logging.WARNING)
    for full_frame in (False, True):
        assert Predictor(out, backend="auto", full_frame=full_frame, depth=False).backend == "onnx"
    assert "exported from another model" not in caplog.text


def test_a_retrain_without_onnx_removes_both_exports_and_says_how_to_make_them(built, tmp_path, capsys, caplog):  # noqa: F811
    """`--no-onnx`: neither export is made, so both of the replaced model are removed with the model's publish, one
    warning each naming the file and the command that writes the new model's."""
    out = tmp_path / "m.pt"
    _trained_with_both_exports(built, out, capsys)
    caplog.set_level(logging.WARNING)
    assert main(["train", str(built), "--out", str(out), "--hidden", "8", "--no-onnx", *TRAIN]) == 0
    assert not out.with_suffix(".onnx").exists() and not out.with_suffix(".frame.onnx").exists()
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    for name, command in (("m.onnx", f"`nlips export {out}`"), ("m.frame.onnx", f"`nlips export {out} --full-frame`")):
        said = [line for line in lines if line.startswith(f"{tmp_path / name}: ")]
        assert len(said) == 1, lines
        assert "removed (not made again: --no-onnx)" in said[0] and command in said[0], said
    assert not _left(tmp_path)


def test_a_full_frame_graph_that_cannot_be_made_again_is_removed_and_said(built, tmp_path, capsys, caplog, monkeypatch):  # noqa: F811
    """The new model's full-frame graph failing its check (or refused: a bilateral disc too wide to unroll): the model
    and its per-pixel export are published, the old graph removed in the same publish, one warning naming the reason
    and the command; exit 0 (the training and MODEL.onnx are whole)."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.learn import onnx_fullframe
    from nlipscalib.learn.onnx_export import check_export

    out = tmp_path / "m.pt"
    _trained_with_both_exports(built, out, capsys)

    def failing(model, path, check=True):
        raise CaptureError(f"{path}: onnxruntime's normal map differs from PyTorch's full-frame path by 0.2 deg")

    monkeypatch.setattr(onnx_fullframe, "export_full_frame", failing)
    caplog.set_level(logging.WARNING)
    assert main(["train", str(built), "--out", str(out), "--hidden", "8", *TRAIN]) == 0
    check_export(out.with_suffix(".onnx"), load_model(out))
    assert not out.with_suffix(".frame.onnx").exists()
    lines = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    said = [line for line in lines if line.startswith(f"{out.with_suffix('.frame.onnx')}: the full-frame")]
    assert len(said) == 1, lines
    assert "differs from PyTorch's full-frame path by 0.2 deg" in said[0] and TMP_PREFIX not in said[0], said
    assert f"`nlips export {out} --full-frame` writes the new model's" in said[0]
    assert not _left(tmp_path)


def test_auto_skips_a_per_pixel_export_of_another_model_and_a_kept_rerun_never_loads_the_model(
    trained, twin_presses, tmp_path, capsys, caplog, monkeypatch
):
    """MODEL.onnx of another model beside the .pt (left from before a retrain, a model copied over): auto runs PyTorch
    with one warning naming the file and `nlips export MODEL`, exit 0, the result recording torch; the same run again
    keeps that result, found without loading the model (the export's digest is read from its metadata); --backend
    onnx, asked by name, is refused in one line."""
    import json
    import shutil

    import torch

    from nlipscalib.learn import infer as infer_module
    from nlipscalib.learn.onnx_export import export_onnx
    from tests.learn.conftest import HELD_OUT

    model = tmp_path / "net.pt"
    shutil.copy(trained, model)
    other = tmp_path / "other.pt"
    payload = torch.load(trained, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    export_onnx(load_model(other), model.with_suffix(".onnx"))
    press, out = str(twin_presses / HELD_OUT), tmp_path / "o"
    caplog.set_level(logging.WARNING)
    assert main(["infer", str(model), press, "--out", str(out)]) == 0
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    said = [line for line in lines if "net.onnx" in line]
    assert len(said) == 1, lines
    assert said[0].startswith(f"{model.with_suffix('.onnx')}: exported from another model than {model}"), said
    assert "skipped, PyTorch runs the network" in said[0] and f"`nlips export {model}` writes it again" in said[0]
    report = json.loads((out / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["backend"] == "torch"

    def not_loaded(*args, **kwargs):
        raise AssertionError("the model was loaded for a re-run whose result is kept")

    monkeypatch.setattr(infer_module, "load_model", not_loaded)
    capsys.readouterr()
    assert main(["infer", str(model), press, "--out", str(out)]) == 0
    assert "1 kept" in capsys.readouterr().err
    monkeypatch.undo()
    assert main(["infer", str(model), press, "--backend", "onnx", "--out", str(tmp_path / "onnx")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exported from another model" in err[0] and f"`nlips export {model}`" in err[0], err


def _of_another_model(out, tmp_path, full_frame):
    """Write beside the model ``out`` the export (``full_frame``: the full-frame graph) of another model of its
    sensor, its weights 1 % larger: what an nlipscalib before the fortieth session left beside a model it trained
    again, unchecked (as a file of another model would be); returns its path."""
    import torch

    from nlipscalib.learn.onnx_export import export_onnx
    from nlipscalib.learn.onnx_fullframe import export_full_frame

    other = tmp_path / "other" / out.name
    other.parent.mkdir(exist_ok=True)
    payload = torch.load(out, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    if full_frame:
        return export_full_frame(load_model(other), out.with_suffix(".frame.onnx"), check=False)[0]
    return export_onnx(load_model(other), out.with_suffix(".onnx"))


def _warnings(caplog):
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def test_a_reused_training_makes_a_stale_full_frame_graph_again_and_leaves_a_current_one(
    built,  # noqa: F811 (the fixture)
    tmp_path,
    capsys,
    caplog,
):
    """The same `nlips train` again reuses the model (nothing published); MODEL.frame.onnx beside it of another model
    (left by an nlipscalib whose retrain did not make it again) is made again for it, said with its check, so auto
    runs it without a warning; run once more, the current graph is left as it is (not rewritten, nothing said)."""
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.onnx_fullframe import check_full_frame

    out = tmp_path / "m.pt"
    _trained_with_both_exports(built, out, capsys)
    frame = _of_another_model(out, tmp_path, full_frame=True)
    caplog.set_level(logging.WARNING)
    assert Predictor(out, backend="auto", full_frame=True, depth=False).backend == "torch"  # skipped, said
    assert "exported from another model" in caplog.text
    caplog.clear()
    args = ["train", str(built), "--out", str(out), "--hidden", "4", *TRAIN]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"{out}: reused" in err, err
    stale = f"exported from another model than {out} (left from before it was trained again?)"
    assert f"{frame}: made again ({stale}): onnxruntime's normal map vs PyTorch's full-frame path" in err, err
    check_full_frame(frame, load_model(out))
    assert not _warnings(caplog) and not _left(tmp_path)
    assert Predictor(out, backend="auto", full_frame=True, depth=False).backend == "onnx"
    assert "exported from another model" not in caplog.text
    written = frame.stat().st_mtime_ns, out.with_suffix(".onnx").stat().st_mtime_ns
    assert main(args) == 0
    err = capsys.readouterr().err
    assert f"{out}: reused" in err and "made again" not in err and not _warnings(caplog), err
    assert (frame.stat().st_mtime_ns, out.with_suffix(".onnx").stat().st_mtime_ns) == written


def test_a_reused_training_with_no_onnx_removes_stale_exports_and_keeps_current_ones(
    built,  # noqa: F811 (the fixture)
    tmp_path,
    capsys,
    caplog,
):
    """`--no-onnx` on a reused model: its own exports are kept; exports of another model beside it (MODEL.onnx is not
    checked whole then) are removed, one warning each naming the file, why and the command that writes the model's,
    as a training that replaces a model says it."""
    out = tmp_path / "m.pt"
    _trained_with_both_exports(built, out, capsys)
    args = ["train", str(built), "--out", str(out), "--hidden", "4", "--no-onnx", *TRAIN]
    caplog.set_level(logging.WARNING)
    assert main(args) == 0
    assert f"{out}: reused" in capsys.readouterr().err and not _warnings(caplog)
    assert out.with_suffix(".onnx").is_file() and out.with_suffix(".frame.onnx").is_file()
    for full_frame in (False, True):
        _of_another_model(out, tmp_path, full_frame)
    assert main(args) == 0
    assert f"{out}: reused" in capsys.readouterr().err
    assert not out.with_suffix(".onnx").exists() and not out.with_suffix(".frame.onnx").exists()
    lines = _warnings(caplog)
    for name, what, command in (
        ("m.onnx", "ONNX export", f"`nlips export {out}`"),
        ("m.frame.onnx", "full-frame ONNX graph", f"`nlips export {out} --full-frame`"),
    ):
        said = [line for line in lines if line.startswith(f"{tmp_path / name}: ")]
        assert len(said) == 1, lines
        assert said[0] == (
            f"{tmp_path / name}: the {what} beside the reused model, exported from another model than {out} (left from "
            f"before it was trained again?), removed (not made again: --no-onnx); {command} writes the model's"
        ), said
    assert not _left(tmp_path)


def test_a_reused_models_cut_short_full_frame_graph_that_cannot_be_made_again_is_removed_and_said(
    built,  # noqa: F811 (the fixture)
    tmp_path,
    capsys,
    caplog,
    monkeypatch,
):
    """A MODEL.frame.onnx cut short (its metadata, written last, lost: it records no digest) beside a reused model is
    made again; when that fails it is removed, one warning naming why it was stale, the failure and the command;
    the run still exits 0 (the model and MODEL.onnx are whole)."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.learn import onnx_fullframe
    from nlipscalib.learn.onnx_export import check_export

    out = tmp_path / "m.pt"
    _trained_with_both_exports(built, out, capsys)
    frame = out.with_suffix(".frame.onnx")
    frame.write_bytes(frame.read_bytes()[: frame.stat().st_size // 2])

    def failing(model, path, check=True):
        raise CaptureError(f"{path}: onnxruntime's normal map differs from PyTorch's full-frame path by 0.2 deg")

    monkeypatch.setattr(onnx_fullframe, "export_full_frame", failing)
    caplog.set_level(logging.WARNING)
    assert main(["train", str(built), "--out", str(out), "--hidden", "4", *TRAIN]) == 0
    assert f"{out}: reused" in capsys.readouterr().err
    check_export(out.with_suffix(".onnx"), load_model(out))
    assert not frame.exists()
    said = [line for line in _warnings(caplog) if line.startswith(f"{frame}: ")]
    assert len(said) == 1, _warnings(caplog)
    assert "beside the reused model, records no model digest (cut short" in said[0], said
    assert "differs from PyTorch's full-frame path by 0.2 deg" in said[0], said
    assert said[0].endswith(f"`nlips export {out} --full-frame` writes the model's"), said
    assert not _left(tmp_path)
