"""`nlips live --model M --onnx F`: the live view runs an ONNX file exported elsewhere (`nlips export M --out F`),
through the same predictor loading as `nlips infer --onnx` (tests/learn/test_named_onnx.py), and refuses one that is
not the model's in one line before any frame is read."""

import numpy as np
import pytest

pytest.importorskip("cv2")
pytest.importorskip("watchdog")
pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core.imageio import read_png16  # noqa: E402

from .watching import drop, main_bounded, tiny_model_frames, writer_once_watching  # noqa: E402


@pytest.fixture(scope="module")
def tiny_model(tmp_path_factory):
    """A tiny model of the exact-data sensor and its presses' frames (:func:`.watching.tiny_model_frames`)."""
    pytest.importorskip("torch")
    return tiny_model_frames(tmp_path_factory, "live_onnx_model")


def _predictors_made(monkeypatch) -> list:
    """Every :class:`~nlipscalib.learn.infer.Predictor` the command builds, kept to ask what it runs."""
    from nlipscalib.learn import infer

    made = []
    init = infer.Predictor.__init__

    def recording(self, *args, **kwargs):
        init(self, *args, **kwargs)
        made.append(self)

    monkeypatch.setattr(infer.Predictor, "__init__", recording)
    return made


def test_live_runs_an_onnx_file_exported_elsewhere(tiny_model, tmp_path, capsys, monkeypatch):
    """The frames' normals come from the named file (the stream's predictor runs onnxruntime on it, where `--backend
    auto` alone finds nothing beside the model) and equal the API's ``Predictor(onnx=F)`` on the same frame."""
    from nlipscalib.learn.infer import Predictor

    model, frames = tiny_model
    deployed = tmp_path / "deploy" / "net.onnx"
    deployed.parent.mkdir()
    assert main(["export", str(model), "--out", str(deployed)]) == 0
    assert not model.with_suffix(".onnx").exists()  # auto alone would run PyTorch
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()
    made = _predictors_made(monkeypatch)
    thread = writer_once_watching(monkeypatch, lambda: drop(watched, "one.png", frames[0]))
    argv = ["--no-progress", "live", "--model", str(model), "--onnx", str(deployed), "--watch", str(watched)]
    code = main_bounded([*argv, "--no-window", "--max-frames", "1", "--out", str(out)], thread)
    err = capsys.readouterr().err
    assert code == 0, err
    assert [p.backend for p in made] == ["onnx"], err
    monkeypatch.undo()
    expected = Predictor(model, backend="onnx", onnx=deployed).predict_stored(read_png16(frames[0]))
    saved = np.load(out / "frame_000000.npz")
    np.testing.assert_allclose(saved["normals"], expected.normals, atol=1e-5)
    np.testing.assert_allclose(saved["depth"], expected.depth, atol=1e-5)


def test_live_refuses_another_models_onnx_file_in_one_line(tiny_model, tmp_path, capsys):
    """A graph exported from another model, named with --onnx, is one line naming the file and exit 2; nothing is
    saved (the same check as `nlips infer --onnx`, reached through the live command)."""
    import torch

    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx

    model, _ = tiny_model
    other = tmp_path / "other.pt"
    payload = torch.load(model, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    graph = tmp_path / "other.onnx"
    export_onnx(load_model(other), graph)
    watched, out = tmp_path / "incoming", tmp_path / "out"
    watched.mkdir()
    argv = ["--no-progress", "live", "--model", str(model), "--onnx", str(graph), "--watch", str(watched)]
    assert main([*argv, "--no-window", "--max-frames", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"nlips live: error: {graph}: exported from another model than {model}"), err
    assert not (out / "frame_000000.npz").exists()
