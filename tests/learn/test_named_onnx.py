"""An ONNX file written elsewhere (`nlips export MODEL --out F`) is run when named: `nlips infer` / `nlips live` --onnx
F, ``Predictor(onnx=F)``; checked as the one beside the model is, refused in one line when it is not the model's.
`--backend auto` looks only beside the model, and `nlips export --out` says how to run the file it wrote
(s41-exports2: before, a graph exported elsewhere was never looked for, and nothing said so but "a copy")."""

import json
import logging
import shutil

import pytest

from nlipscalib.cli import main
from nlipscalib.core.errors import ConfigError
from nlipscalib.learn.infer import Predictor
from nlipscalib.learn.model import load_model

from .conftest import HELD_OUT

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")


def _report(folder):
    return json.loads((folder / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))


def _one_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_a_per_pixel_export_elsewhere_runs_with_onnx_and_another_models_is_refused(
    trained, twin_presses, tmp_path, capsys, caplog
):
    """`nlips export --out` elsewhere names `--onnx F` and says auto looks only beside the model; `nlips infer --onnx
    F` runs it (results record onnx; the same run again keeps them), where auto alone runs PyTorch; a missing file,
    --backend torch beside it, and a file of another model are each refused in one line."""
    import torch

    from nlipscalib.learn.onnx_export import export_onnx

    model = tmp_path / "m" / "net.pt"
    model.parent.mkdir()
    shutil.copy(trained, model)
    deployed = tmp_path / "deploy" / "net.onnx"
    deployed.parent.mkdir()
    assert main(["export", str(model), "--out", str(deployed)]) == 0
    said = capsys.readouterr()
    assert said.out == f"{deployed}\n"
    assert f"--onnx {deployed}` runs it" in said.err and f"looks only for {model.with_suffix('.onnx')}" in said.err
    assert not model.with_suffix(".onnx").exists()
    press = str(twin_presses / HELD_OUT)
    caplog.set_level(logging.WARNING)
    assert main(["infer", str(model), press, "--out", str(tmp_path / "auto"), "--no-progress"]) == 0
    assert _report(tmp_path / "auto")["backend"] == "torch"  # auto: nothing beside the model
    named = ["infer", str(model), press, "--onnx", str(deployed), "--out", str(tmp_path / "named"), "--no-progress"]
    assert main(named) == 0
    assert _report(tmp_path / "named")["backend"] == "onnx"
    assert "net.onnx" not in caplog.text
    capsys.readouterr()
    assert main(named) == 0  # the same run again: the settings found before loading are the loaded predictor's
    assert "1 kept" in capsys.readouterr().err

    missing = tmp_path / "deploy" / "gone.onnx"
    assert main([*named[:3], "--onnx", str(missing), "--out", str(tmp_path / "x")]) == 2
    assert _one_error(capsys).endswith(f"--onnx {missing}: no such file (`nlips export MODEL --out FILE` writes one)")
    assert main([*named[:3], "--onnx", str(deployed), "--backend", "torch", "--out", str(tmp_path / "x")]) == 2
    assert "--backend torch runs PyTorch: drop one of them" in _one_error(capsys)
    with pytest.raises(ConfigError, match="backend='torch' runs PyTorch: give backend='onnx' \\(the default is torch"):
        Predictor(model, onnx=deployed)  # the API's default backend
    with pytest.raises(ConfigError, match="onnx=.* runs on the CPU"):
        Predictor(model, backend="auto", onnx=deployed, device="cuda")

    other = tmp_path / "other.pt"
    payload = torch.load(trained, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    export_onnx(load_model(other), deployed)  # named, another model's graph is refused, not skipped
    assert main([*named[:-2], str(tmp_path / "stale"), "--no-progress"]) == 2
    error = _one_error(capsys)
    assert error.startswith(f"nlips infer: error: {deployed}: exported from another model than {model}"), error
    assert f"`nlips export {model} --out {deployed}` writes it" in error, error  # the file named, not MODEL.onnx
    assert not (tmp_path / "stale").exists()


def test_a_full_frame_graph_elsewhere_runs_with_onnx(trained, tmp_path, capsys):
    """`nlips export --full-frame --out F` elsewhere says how to run it; ``Predictor(full_frame=True, onnx=F)`` takes
    its normals from F (auto alone, with nothing beside the model, runs PyTorch's full-frame path)."""
    model = tmp_path / "net.pt"
    shutil.copy(trained, model)
    graph = tmp_path / "deploy" / "whole.onnx"
    graph.parent.mkdir()
    assert main(["export", str(model), "--full-frame", "--out", str(graph)]) == 0
    err = capsys.readouterr().err
    assert f"--full-frame --onnx {graph}` runs it" in err
    assert f"looks only for {model.with_suffix('.frame.onnx')}" in err
    assert Predictor(model, backend="auto", full_frame=True, depth=False).backend == "torch"
    named = Predictor(model, backend="auto", full_frame=True, depth=False, onnx=graph)
    assert named.backend == "onnx" and named._frame_graph.path == graph
