"""`nlips infer --full-frame` / `nlips live --full-frame` with the full-frame ONNX graph (MODEL.frame.onnx, `nlips
export MODEL --full-frame`): its normals those of the PyTorch full-frame path within the export check's tolerance,
through the command line, for a press (a linear frame, stored again for the graph) and a stream of stored frames, the
backend recorded; a graph of another model (left from before a retrain) and a missing one are one line each."""

import json
import logging
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.metrics import angle_deg
from nlipscalib.core.tolerances import ONNX_PARITY_DEG

from .conftest import HELD_OUT

pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")


def _exported(model_path, folder):
    """A copy of the model in ``folder`` with its full-frame graph beside it (the session's fixture model keeps none:
    `--full-frame`'s auto would take it in the other tests)."""
    folder.mkdir()
    copy = folder / "net.pt"
    shutil.copy(model_path, copy)
    assert main(["export", str(copy), "--full-frame"]) == 0
    assert (folder / "net.frame.onnx").is_file()
    return copy


def _max_angle(a, b, gel):
    return float(angle_deg(a[gel], b[gel]).max())


@pytest.mark.parametrize("fixture", ["trained", "trained_ratio"])
def test_the_graph_gives_the_pytorch_full_frame_result_of_a_press(fixture, request, twin_presses, tmp_path, capsys):
    """A press (its linear frame stored again for the graph): the same normals within ONNX_PARITY_DEG on the gel and
    the same whole-gel depth (the integration is the PyTorch path's); report.json says which backend ran, and auto
    takes the graph beside the model."""
    model = _exported(request.getfixturevalue(fixture), tmp_path / "m")
    press = str(twin_presses / HELD_OUT)
    results = {}
    for backend in ("torch", "onnx", "auto"):
        out = tmp_path / backend
        assert main(["infer", str(model), press, "--full-frame", "--backend", backend, "--out", str(out)]) == 0
        folder = out / HELD_OUT / "nlipsnet"
        results[backend] = np.load(folder / "result.npz")
        report = json.loads((folder / "report.json").read_text(encoding="utf-8"))
        assert report["full_frame"] is True
        assert report["backend"] == ("torch" if backend == "torch" else "onnx")
    capsys.readouterr()
    gel = results["torch"]["mask"].astype(bool)
    assert gel.sum() > 1000
    for backend in ("onnx", "auto"):
        assert _max_angle(results[backend]["normals"], results["torch"]["normals"], gel) < ONNX_PARITY_DEG
        depth, want = results[backend]["depth"][gel], results["torch"]["depth"][gel]
        assert np.isfinite(depth).all()
        assert np.abs(depth - want).max() < 1e-3  # mm, on a dome of ~20 mm: the normals' 1e-4 deg integrated


def test_a_stream_through_the_graph_saves_the_pytorch_full_frame_normals(trained_ratio, twin_presses, tmp_path, capsys):
    """An image sequence of stored frames (the graph's input as the camera stored them): each saved frame's normals
    the PyTorch full-frame path's within ONNX_PARITY_DEG, stream.json's backend onnx; `nlips live` takes it by
    default (auto)."""
    import cv2

    from nlipscalib.core import load_press

    model = _exported(trained_ratio, tmp_path / "m")
    frames = load_press(twin_presses / HELD_OUT).tricolor
    for i in range(2):
        cv2.imwrite(str(tmp_path / f"img_{i:04d}.png"), frames[..., ::-1])  # RGB stored as PNG (OpenCV writes BGR)
    pattern = str(tmp_path / "img_%04d.png")
    saved = {}
    for backend in ("torch", "onnx"):
        out = tmp_path / f"stream-{backend}"
        assert main(["infer", str(model), pattern, "--full-frame", "--backend", backend, "--out", str(out)]) == 0
        stream = json.loads((out / "stream.json").read_text(encoding="utf-8"))
        assert stream["backend"] == backend and stream["frames"] == 2
        saved[backend] = np.load(out / "frame_000001.npz")
    live = tmp_path / "live"
    argv = ["live", "--model", str(model), "--camera", pattern, "--full-frame", "--no-window", "--out", str(live)]
    assert main(["--no-progress", *argv]) == 0
    capsys.readouterr()
    normals, want = saved["onnx"]["normals"], saved["torch"]["normals"]
    # auto took the graph beside the model: `nlips infer --backend onnx`'s normals to the bit, not PyTorch's
    np.testing.assert_array_equal(np.load(live / "frame_000001.npz")["normals"], normals)
    assert not np.array_equal(normals, want)
    gel = np.isfinite(want).all(-1)
    assert gel.sum() > 1000 and np.array_equal(np.isfinite(normals).all(-1), gel)
    assert _max_angle(normals, want, gel) < ONNX_PARITY_DEG


def test_a_graph_of_another_model_is_skipped_by_auto_and_refused_by_backend_onnx(
    trained, twin_presses, tmp_path, capsys, caplog
):
    """The model trained again (another digest) beside the graph of the old one: auto (the best runtime available)
    skips it with one warning naming the file and the command that writes it again, and PyTorch's full-frame path
    runs (exit 0, the result records torch); --backend onnx, asked by name, is refused in one line saying the same."""
    model = _exported(trained, tmp_path / "m")
    payload = torch.load(model, weights_only=False)
    # another file (as after a retrain), another digest
    payload["info"] = payload["info"] | {"best_epoch": payload["info"]["best_epoch"] + 1}
    torch.save(payload, model)
    capsys.readouterr()
    press = str(twin_presses / HELD_OUT)
    caplog.set_level(logging.WARNING)
    assert main(["infer", str(model), press, "--full-frame", "--out", str(tmp_path / "auto")]) == 0
    lines = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    said = [line for line in lines if "net.frame.onnx" in line]
    assert len(said) == 1, lines
    assert "another model" in said[0] and "skipped, PyTorch runs the network" in said[0], said
    assert f"nlips export {model} --full-frame" in said[0], said
    report = json.loads((tmp_path / "auto" / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["backend"] == "torch" and report["full_frame"] is True
    capsys.readouterr()  # the run's closing lines
    args = ["infer", str(model), press, "--full-frame", "--backend", "onnx", "--out", str(tmp_path / "onnx")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "net.frame.onnx" in err[0] and "another model" in err[0], err
    assert f"nlips export {model} --full-frame" in err[0], err


def test_a_missing_graph_with_backend_onnx_says_how_to_make_it(trained, twin_presses, tmp_path, capsys):
    folder = tmp_path / "m"
    folder.mkdir()
    model = folder / "net.pt"
    shutil.copy(trained, model)
    args = ["infer", str(model), str(twin_presses / HELD_OUT), "--full-frame", "--backend", "onnx"]
    assert main([*args, "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "net.frame.onnx" in err[0] and "missing" in err[0] and f"nlips export {model} --full-frame" in err[0], err


def test_a_foreign_graph_under_the_models_digest_is_refused_before_onnxruntime_reads_it(
    trained, trained_ratio, twin_presses, tmp_path, capsys
):
    """Another model's graph whose metadata names this model's digest (edited by hand, or sent so): compared with
    the graph this model's export writes, refused in one line; never run."""
    import onnx

    from nlipscalib.learn.model import load_model

    other = _exported(trained_ratio, tmp_path / "other")
    folder = tmp_path / "m"
    folder.mkdir()
    model = folder / "net.pt"
    shutil.copy(trained, model)
    proto = onnx.load(str(other.with_suffix(".frame.onnx")))
    for entry in proto.metadata_props:
        if entry.key == "model_digest":
            entry.value = load_model(model).digest
    onnx.save(proto, str(folder / "net.frame.onnx"))
    capsys.readouterr()
    args = ["infer", str(model), str(twin_presses / HELD_OUT), "--full-frame", "--out", str(tmp_path / "o")]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "net.frame.onnx" in err[0] and "not the full-frame graph of" in err[0], err


def test_every_kind_of_frame_of_a_tone_curve_camera_gets_the_pytorch_normals(trained, twin_presses, tmp_path):
    """A model of an sRGB camera: the graph undoes the curve itself, so a stored frame goes in as the camera encoded
    it, and a frame whose curve the reader undid (a stream's), a linear one (a press's) and one refreshed by an aged
    sensor's reference (its gain) are stored again with the curve first; each gives PyTorch's full-frame normals."""
    from nlipscalib.core.imageio import read_png16
    from nlipscalib.core.sensor_record import response_table_of
    from nlipscalib.core.sensor_response import redo_tone_curve
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model

    folder = tmp_path / "m"
    folder.mkdir()
    payload = torch.load(trained, weights_only=False)
    payload["sensor"] = payload["sensor"] | {"camera_response": "srgb"}
    torch.save(payload, folder / "net.pt")
    model = _exported(folder / "net.pt", tmp_path / "srgb")
    table = response_table_of(load_model(model).sensor)
    in_light = read_png16(twin_presses / HELD_OUT / "tricolor.png")
    encoded = np.clip(np.rint(redo_tone_curve(in_light, table)), 0, 65535).astype(np.uint16)
    graph, pytorch = (Predictor(model, backend=b, full_frame=True) for b in ("onnx", "torch"))
    assert graph.backend == "onnx" and pytorch.backend == "torch"
    gel = graph.valid
    for predictor in (graph, pytorch):
        predictor.results = [
            predictor.predict_stored(encoded),
            predictor.predict_stored(predictor.in_light(encoded), in_light=True),
            predictor.predict(predictor.linear(encoded)),
        ]
        predictor.refresh(predictor.linear(encoded) * np.float32(0.9))  # an aged sensor: 10 % dimmer
        predictor.results.append(predictor.predict_stored(encoded))
    for got, want in zip(graph.results, pytorch.results):
        assert _max_angle(got.normals, want.normals, gel) < ONNX_PARITY_DEG
        assert np.abs(got.depth[gel] - want.depth[gel]).max() < 1e-3
    # the refresh's gain reached the graph's input: its normals moved with PyTorch's
    assert _max_angle(graph.results[3].normals, graph.results[0].normals, gel) > 10 * ONNX_PARITY_DEG
