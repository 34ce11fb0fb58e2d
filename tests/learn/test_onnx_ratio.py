"""A ratio model's ONNX file is standalone: it takes every model's inputs (pixels and filtered linear colours) and
divides the colours by its reference inside the graph; exports of earlier releases, which took the ratios, are skipped
by --backend auto and refused by --backend onnx, with the way to write them again."""

import copy
import json
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press, load_reconstruction
from nlipscalib.core.errors import CaptureError
from nlipscalib.core.tolerances import ONNX_PARITY_DEG
from nlipscalib.learn.evaluate import net_predict
from nlipscalib.learn.model import load_model, model_inputs
from nlipscalib.learn.prefilter import Prefilter

from .conftest import HELD_OUT

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")


def _whole_capture(model, press_folder):
    """(pixel (H*W, 2) (u, v), colours (H*W, 3)) of every pixel of a capture, its colours filtered as inference
    filters them (the model's prefilter over the gel): what a program of a lab gives the ONNX file."""
    press = load_press(press_folder)
    valid = model.reference["valid"].astype(bool)
    colours = Prefilter(valid, model.smoothing_px, model.smoothing_colour)(press.linear(press.tricolor))
    rows, cols = np.indices(valid.shape)
    return np.stack([cols.ravel(), rows.ravel()], 1), colours.reshape(-1, 3)


def _angles(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))


def test_a_ratio_models_onnx_file_gives_pytorchs_normals_from_the_linear_colours_on_every_pixel(
    trained_ratio, twin_presses, tmp_path
):
    """Every pixel of a held-out capture (on and off the gel), the inputs a linear model's file takes: within 0.1 deg
    of PyTorch given the ratios, and the graph's first layer reads the ratios `model_inputs` makes, bit for bit."""
    from nlipscalib.learn.onnx_export import RATIO_INPUT, OnnxNet, export_onnx, max_angle_deg

    model = load_model(trained_ratio)
    path = export_onnx(model, tmp_path / "ratio.onnx")
    pixel, colours = _whole_capture(model, twin_presses / HELD_OUT)
    x = model_inputs(pixel, colours)  # no reference: the export's input is every model's
    want = net_predict(model, pixel, colours)  # PyTorch on the colours over the reference
    assert max_angle_deg(OnnxNet(path, model, threads=1)(x), want) < ONNX_PARITY_DEG
    # the division inside the graph is the one inference made outside it: the same float32 ratios
    proto = onnx.load(str(path))
    proto.graph.output.append(onnx.helper.make_tensor_value_info(RATIO_INPUT, onnx.TensorProto.FLOAT, ["pixels", 5]))
    import onnxruntime

    session = onnxruntime.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    ratios = session.run([RATIO_INPUT], {"uvrgb": x})[0]
    np.testing.assert_array_equal(ratios, model_inputs(pixel, colours, model.input_reference))
    assert np.abs(ratios[:, 2:] - x[:, 2:]).max() > 0.1  # divided: the reference is no map of ones
    # the old recipe (the caller divides) now divides twice: normals far off, which is why the inputs are documented
    twice = OnnxNet(path, model, threads=1)(model_inputs(pixel, colours, model.input_reference))
    gel = model.reference["valid"].ravel().astype(bool)
    assert _angles(twice, want)[gel].mean() > 1.0


def test_the_onnx_metadata_states_the_input_contract(trained, trained_ratio, tmp_path):
    """A lab's C++ or phone program reads what to give the file from its metadata: the columns, the prefilter the
    colours get, and whether the graph divides them by its reference (never divide them before)."""
    from nlipscalib.learn.onnx_export import export_onnx

    for fixture, divides in ((trained, False), (trained_ratio, True)):
        model = load_model(fixture)
        path = export_onnx(model, tmp_path / fixture.with_suffix(".onnx").name)
        meta = {p.key: p.value for p in onnx.load(str(path)).metadata_props}
        contract = json.loads(meta["input"])
        assert contract["name"] == "uvrgb" and contract["shape"] == ["pixels", 5]
        assert contract["columns"] == ["u", "v", "r", "g", "b"]
        assert contract["smoothing_px"] == model.smoothing_px > 0
        assert contract["smoothing_colour"] == model.smoothing_colour > 0
        assert contract["divided_inside"] is divides
        assert "linear" in contract["colours"] and "96x72" in contract["pixels"]
        assert meta.get("colour_input") == ("ratio" if divides else None)
        names = {t.name for t in onnx.load(str(path)).graph.initializer}
        assert ("reference" in names) is divides  # a linear model's graph is the one of before: no map


def test_a_ratio_models_int8_variant_divides_inside_too(trained_ratio, twin_presses, tmp_path):
    """--backend onnx-int8 quantises the network's inner layers only: the reference map stays float32 (quantised by
    a Gather's rule it would cost every ratio up to 1/255 of the map's range)."""
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx, quantized_int8

    model = load_model(trained_ratio)
    path = export_onnx(model, tmp_path / "ratio.onnx")
    quantised = onnx.load_from_string(quantized_int8(path.read_bytes()))
    reference = {t.name: t for t in quantised.graph.initializer}["reference"]
    assert reference.data_type == onnx.TensorProto.FLOAT
    np.testing.assert_array_equal(onnx.numpy_helper.to_array(reference), model.input_reference)
    pixel, colours = _whole_capture(model, twin_presses / HELD_OUT)
    gel = model.reference["valid"].ravel().astype(bool)
    int8 = OnnxNet(path, model, threads=1, int8=True)(model_inputs(pixel[gel], colours[gel]))
    angle = _angles(int8, net_predict(model, pixel[gel], colours[gel]))
    assert angle.mean() < 0.5 and np.percentile(angle, 99) < 2.0, (angle.mean(), angle.max())


def _export_of_before(model, path):
    """The ONNX file `nlips export` wrote for a ratio model up to 2026-12-07: the graph of a linear model's (the
    ratios its input) with the ratio model's metadata and no ``input`` entry."""
    from nlipscalib.learn.onnx_export import export_proto

    as_before = copy.copy(model)
    as_before.input_reference = None  # its graph did not divide
    proto = export_proto(as_before)
    kept = [p for p in proto.metadata_props if p.key != "input"]
    del proto.metadata_props[:]
    proto.metadata_props.extend(kept)
    assert {p.key: p.value for p in proto.metadata_props}["colour_input"] == "ratio"
    path.write_bytes(proto.SerializeToString())
    return path


def test_a_ratio_models_export_of_before_is_skipped_by_auto_refused_by_backend_onnx_and_export_mends_it(
    trained_ratio, twin_presses, tmp_path, capsys, caplog
):
    """An .onnx written before the graph divided (its input the ratios): run with this release's inputs its normals
    would be wrong without a word, so it never runs. `nlips infer` (by default --backend auto: the .onnx beside the
    model) skips it with one warning naming it and `nlips export MODEL`, and PyTorch runs the network, as for an
    export of another model (it stopped in one line before: s41-exports2); --backend onnx, asked by name, stops in one
    line saying how to write it again; `nlips export` does, and auto then runs it."""
    import logging

    from nlipscalib.learn.onnx_export import OnnxNet

    model_path = tmp_path / "ratio.pt"
    shutil.copy(trained_ratio, model_path)
    model = load_model(model_path)
    old = _export_of_before(model, model_path.with_suffix(".onnx"))
    with pytest.raises(CaptureError) as caught:
        OnnxNet(old, model, threads=1)
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"{old}: exported before 2026-12-07, "), message
    assert message.endswith(f"`nlips export {model_path}` writes it again, or use --backend torch"), message
    press = str(twin_presses / HELD_OUT)
    onnx_args = ["infer", str(model_path), press, "--backend", "onnx", "--out", str(tmp_path / "o"), "--no-progress"]
    assert main(onnx_args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"nlips infer: error: {old}: exported before 2026-12-07"), err
    assert not (tmp_path / "o").exists()
    caplog.set_level(logging.WARNING)
    auto_args = ["infer", str(model_path), press, "--out", str(tmp_path / "auto"), "--no-progress"]
    assert main(auto_args) == 0
    said = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING and "ratio.onnx" in r.getMessage()]
    assert len(said) == 1, said
    assert said[0].startswith(f"{old}: exported before 2026-12-07, when a ratio model's ONNX file took"), said
    assert said[0].endswith(f"skipped, PyTorch runs the network; `nlips export {model_path}` writes it again"), said
    report = json.loads((tmp_path / "auto" / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["backend"] == "torch"
    assert main(["export", str(model_path)]) == 0
    caplog.clear()
    assert main(["infer", str(model_path), press, "--out", str(tmp_path / "mended"), "--no-progress"]) == 0
    report = json.loads((tmp_path / "mended" / HELD_OUT / "nlipsnet" / "report.json").read_text(encoding="utf-8"))
    assert report["backend"] == "onnx" and "ratio.onnx" not in caplog.text


def test_nlips_infer_divides_a_ratio_models_colours_once_with_either_backend(trained_ratio, twin_presses, tmp_path):
    """`nlips infer --backend onnx` gives the standalone graph the linear colours (its graph divides them) and
    `--backend torch` divides them before the network: the same normals, those of PyTorch on the ratios; divided
    twice (the ONNX file given the ratios) they would be degrees off."""
    model_path = tmp_path / "ratio.pt"
    shutil.copy(trained_ratio, model_path)
    assert main(["export", str(model_path)]) == 0
    normals = {}
    for backend in ("onnx", "torch"):
        out = tmp_path / backend
        args = ["infer", str(model_path), str(twin_presses / HELD_OUT), "--backend", backend, "--out", str(out)]
        assert main([*args, "--no-progress", "--figures", "none"]) == 0
        press = load_press(twin_presses / HELD_OUT)
        normals[backend] = load_reconstruction(out / HELD_OUT / "nlipsnet", press.camera.shape).normals
    model = load_model(model_path)
    changed = np.any(normals["onnx"] != model.reference["normals"], -1) & model.reference["valid"].astype(bool)
    assert changed.sum() > 50
    rows, cols = np.nonzero(changed)
    press = load_press(twin_presses / HELD_OUT)
    colours = Prefilter(model.reference["valid"].astype(bool), model.smoothing_px, model.smoothing_colour)(
        press.linear(press.tricolor)
    )[rows, cols]
    want = net_predict(model, np.stack([cols, rows], 1), colours)
    for backend in ("onnx", "torch"):
        assert _angles(normals[backend][rows, cols], want).max() < ONNX_PARITY_DEG, backend


def test_nlips_train_run_again_writes_a_ratio_models_export_of_before_again(calib, tmp_path, caplog, capsys):
    """The same `nlips train` again (it would reuse the finished model) finds the export of before beside it, says so
    and writes the standalone one, from the training's checkpoint: no epoch trained again."""
    import logging

    from nlipscalib.learn.onnx_export import check_export

    out = tmp_path / "m.pt"
    args = ["train", str(calib.folder), "--out", str(out), "--hidden", "8", "--epochs", "1", "--exclude", HELD_OUT]
    assert main([*args, "--no-progress"]) == 0
    model = load_model(out)
    assert model.colour_input == "ratio"  # the default
    _export_of_before(model, out.with_suffix(".onnx"))
    capsys.readouterr()
    caplog.set_level(logging.INFO)
    assert main([*args, "--no-progress"]) == 0
    assert f"{out.with_suffix('.onnx')}: exported before 2026-12-07" in caplog.text and "made again" in caplog.text
    assert "reused" not in capsys.readouterr().err
    check_export(out.with_suffix(".onnx"), load_model(out))  # the standalone graph, this model's
