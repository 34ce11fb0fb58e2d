"""Model files from other labs (docs/formats.md, "Files from others"): a received ONNX file is run only when it is
its model's export, and a model file's archive is not inflated beyond its size.

Each hostile or broken file is made here with the onnx, torch and zipfile libraries from a real small model, and
must be one CaptureError line naming the file and the problem, before onnxruntime or torch.load reads it.
"""

import re
from types import SimpleNamespace

import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from tests.learn.test_onnx_digest import _save

onnx = pytest.importorskip("onnx")
pytest.importorskip("onnxruntime")


@pytest.fixture
def exported(tmp_path):
    """(model path, its loaded model, the export's ModelProto) of a small model with its export beside it."""
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx

    model = load_model(_save(tmp_path / "m.pt"))
    out = export_onnx(model, tmp_path / "m.onnx")
    return model, onnx.load(str(out))


def _refused(model, proto, match: str) -> str:
    """The one-line CaptureError of OnnxNet for ``proto`` written beside ``model`` (None: the file there now);
    checks that it names the file and how to write the export again."""
    from nlipscalib.learn.onnx_export import OnnxNet

    path = model.path.with_suffix(".onnx")
    if proto is not None:
        path.write_bytes(proto.SerializeToString())
    with pytest.raises(CaptureError) as caught:
        OnnxNet(path, model, threads=1)
    message = str(caught.value)
    assert message.startswith(f"{path}: ") and "\n" not in message, message
    assert re.search(match, message), message
    assert message.endswith(f"`nlips export {model.path}` writes it again, or use --backend torch"), message
    return message


def test_the_export_and_float_rounding_of_its_weights_are_accepted(exported):
    """Another machine's folding (float32 rounding of a float64 product) must not refuse a lab's own export."""
    from nlipscalib.learn.onnx_export import OnnxNet

    model, proto = exported
    OnnxNet(model.path.with_suffix(".onnx"), model, threads=1)
    weight = proto.graph.initializer[0]
    values = onnx.numpy_helper.to_array(weight)
    weight.CopyFrom(onnx.numpy_helper.from_array(np.nextafter(values, np.float32(np.inf)), weight.name))
    model.path.with_suffix(".onnx").write_bytes(proto.SerializeToString())
    x = np.random.default_rng(0).uniform(0, 1, (64, 5)).astype(np.float32) * [64, 48, 1, 1, 1]
    assert np.isfinite(OnnxNet(model.path.with_suffix(".onnx"), model, threads=1)(x)).all()


def test_external_data_outside_the_models_folder_is_never_read(exported, tmp_path):
    """onnxruntime before its December 2025 fix read an initializer's "external data" from any path (a file of
    the user's, /dev/zero); the check refuses any external data: exports hold none."""
    model, proto = exported
    weight = proto.graph.initializer[0]
    weight.ClearField("raw_data")
    weight.data_location = onnx.TensorProto.EXTERNAL
    for key, value in (("location", "../secret.bin"), ("offset", "0"), ("length", "640")):
        entry = weight.external_data.add()
        entry.key, entry.value = key, value
    _refused(model, proto, r"weight 'W0' refers to an external data file \('\.\./secret\.bin'\)")


def test_a_custom_operator_domain_is_refused_by_name(exported):
    model, proto = exported
    node = proto.graph.node[-1]
    node.op_type, node.domain = "Evil", "com.example.evil"
    proto.opset_import.append(onnx.helper.make_opsetid("com.example.evil", 1))
    _refused(model, proto, r"operators of the domain 'com\.example\.evil' \(custom operators are never run\)")


def test_a_graph_off_the_nlipsnet_contract_names_both_sides(exported):
    """(u, v, r) in, or a normal of two components out: not NLiPsNet's (u, v, r, g, b) -> n."""
    model, proto = exported
    proto.graph.input[0].type.tensor_type.shape.dim[1].dim_value = 3
    message = _refused(model, proto, r"its graph maps 'uvrgb' \(pixels, 3\) FLOAT -> 'normal' \(pixels, 3\) FLOAT")
    assert "NLiPsNet maps 'uvrgb' (pixels, 5) FLOAT -> 'normal' (pixels, 3) FLOAT" in message


def test_a_constant_of_terabytes_is_refused_before_onnxruntime_folds_it(exported):
    """onnxruntime folds constants while it optimises the graph: a ConstantOfShape of 2^40 floats would ask for 4
    TB at session start. Any node the export does not have is refused before a session exists."""
    model, proto = exported
    shape = onnx.numpy_helper.from_array(np.array([1 << 40], np.int64), "bomb_shape")
    proto.graph.initializer.append(shape)
    bomb = onnx.helper.make_node("ConstantOfShape", ["bomb_shape"], ["bomb"], name="bomb")
    proto.graph.node.insert(0, bomb)
    _refused(model, proto, r"node 0 is 'ConstantOfShape', the export's is 'MatMul'")


def test_another_models_weights_under_this_models_digest_are_refused(exported, tmp_path):
    """The digest in the metadata is what the sender wrote: another sensor's export relabelled with this model's
    digest ran this model's reference with the other network's normals."""
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_proto

    model, _ = exported
    other = export_proto(load_model(_save(tmp_path / "other.pt", scale=1.5)))
    for entry in other.metadata_props:
        if entry.key == "model_digest":
            entry.value = model.digest
    _refused(model, other, r"its weight 'W0' differs from the model's by [0-9.e+-]+ \(largest weight")


def test_an_oversized_file_is_refused_from_its_size_before_it_is_read(exported, monkeypatch):
    """A sparse 3 GiB file beside the model (onnx files may hold up to 2 GB of protobuf): refused by its size,
    never read into memory."""
    from pathlib import Path

    model, proto = exported
    path = model.path.with_suffix(".onnx")
    path.write_bytes(proto.SerializeToString())
    with path.open("r+b") as f:
        f.truncate(3 << 30)  # sparse: no disk used
    read = Path.read_bytes

    def refuse_this_one(self):
        assert self != path, "the oversized file was read"
        return read(self)

    monkeypatch.setattr(Path, "read_bytes", refuse_this_one)
    _refused(model, None, rf"^\S+: {3 << 30} bytes, more than an export of \S+ holds \([0-9]+\)")


def test_bytes_protobuf_parses_without_a_graph_are_not_a_model(exported):
    """Protobuf keeps unknown fields, so a few bytes of another format parse as an empty ModelProto (no graph)."""
    model, _ = exported
    model.path.with_suffix(".onnx").write_bytes(b"\x08\x07onnx-ish")
    _refused(model, None, r"not a readable ONNX model \((no graph|DecodeError)\)")


def test_a_model_file_deflated_to_a_thousandth_is_refused_before_torch_inflates_it(tmp_path):
    """torch.save stores entries uncompressed, torch.load inflates deflated ones: a 64 MB tensor of zeros in a
    file of ~70 KB. Refused from the archive's directory (torch.load never runs)."""
    import zipfile

    import torch

    from nlipscalib.learn.model import load_model, read_torch_file

    plain = tmp_path / "plain.pt"
    torch.save({"bomb": torch.zeros(16 << 20)}, plain)
    bomb = tmp_path / "bomb.pt"
    with zipfile.ZipFile(plain) as src, zipfile.ZipFile(bomb, "w", zipfile.ZIP_DEFLATED) as out:
        for entry in src.infolist():
            out.writestr(entry.filename, src.read(entry.filename))
    assert bomb.stat().st_size < 200_000
    for read in (lambda p: read_torch_file(p, "an NLiPsNet model file"), load_model):
        with pytest.raises(CaptureError) as caught:
            read(bomb)
        message = str(caught.value)
        assert message.startswith(f"{bomb}: its entries inflate to ") and "\n" not in message, message
        assert message.endswith("(torch.save stores them uncompressed): not usable as an NLiPsNet model file")
    assert read_torch_file(plain, "a model")["bomb"].shape == (16 << 20,)  # the same file, stored: read


def test_the_export_is_written_as_onnx_helper_writes_it_and_infer_does_not_import_onnx(tmp_path):
    """export_proto makes the messages itself (inference then needs no `import onnx`, 0.7 s of CPU): its bytes are
    those of onnx.helper's model, field for field, so exports of earlier releases are the graph compared with."""
    import subprocess
    import sys

    from nlipscalib.learn.model import folded_layers, load_model
    from nlipscalib.learn.onnx_export import export_proto

    model = load_model(_save(tmp_path / "m.pt"))
    helper, numpy_helper = onnx.helper, onnx.numpy_helper
    # the folded weights: the module-built ones bit for bit (test_fast_paths.py)
    linear = folded_layers(model.net.state_dict())
    nodes, weights, current = [], [], "uvrgb"
    for k, (W, b) in enumerate(linear):  # the graph as export_onnx wrote it up to 2026-12-05, with onnx.helper
        weights.append(numpy_helper.from_array(W.T.copy(), f"W{k}"))
        weights.append(numpy_helper.from_array(b.copy(), f"b{k}"))
        nodes.append(helper.make_node("MatMul", [current, f"W{k}"], [f"matmul{k}"], name=f"layer{k}"))
        nodes.append(helper.make_node("Add", [f"matmul{k}", f"b{k}"], [f"linear{k}"], name=f"bias{k}"))
        current = f"linear{k}"
        if k < len(linear) - 1:
            nodes.append(helper.make_node("Relu", [current], [f"relu{k}"], name=f"relu{k}"))
            current = f"relu{k}"
    weights.append(numpy_helper.from_array(np.array([1e-8], np.float32), "min_norm"))
    nodes += [
        helper.make_node("ReduceL2", [current], ["norm"], keepdims=1, axes=[-1], name="norm"),
        helper.make_node("Max", ["norm", "min_norm"], ["norm_clamped"], name="clamp"),
        helper.make_node("Div", [current, "norm_clamped"], ["normal"], name="unit"),
    ]
    graph = helper.make_graph(
        nodes,
        "nlipsnet",
        [helper.make_tensor_value_info("uvrgb", onnx.TensorProto.FLOAT, ["pixels", 5])],
        [helper.make_tensor_value_info("normal", onnx.TensorProto.FLOAT, ["pixels", 3])],
        weights,
    )
    old = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="nlipscalib")
    old.ir_version = 8
    ours = export_proto(model)
    del ours.metadata_props[:]
    assert ours.SerializeToString() == old.SerializeToString()
    code = (
        "import sys; from nlipscalib.learn.model import load_model; from nlipscalib.learn.onnx_export import "
        f"OnnxNet, export_onnx; m = load_model({str(model.path)!r}); "
        "OnnxNet(export_onnx(m, m.path.with_suffix('.onnx')), m); import onnx"  # writing imports onnx: a new process
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    check = (
        "import sys; from nlipscalib.learn.model import load_model; from nlipscalib.learn.onnx_export import OnnxNet; "
        f"m = load_model({str(model.path)!r}); OnnxNet(m.path.with_suffix('.onnx'), m, threads=1); "
        "print('ml_dtypes' in sys.modules, 'onnx' in sys.modules)"
    )
    assert subprocess.run([sys.executable, "-c", check], check=True, capture_output=True, text=True).stdout.split() == [
        "False",
        "False",
    ]


def test_a_model_file_larger_than_any_model_made_is_refused_before_it_is_read(tmp_path, monkeypatch):
    """A received .pt is read whole: a 10 GB one filled memory first. Refused from its size (a sparse file: no
    gigabytes on disk), and one that grows past the limit while it is read is read no further than the limit."""
    import torch

    from nlipscalib.core import tolerances
    from nlipscalib.learn import model as model_module
    from nlipscalib.learn.model import load_model, read_torch_file

    huge = tmp_path / "huge.pt"
    with huge.open("wb") as f:
        f.write(b"PK\x03\x04")
        f.truncate(10 << 30)  # 10 GiB, sparse
    for read in (lambda p: read_torch_file(p, "an NLiPsNet model file"), load_model):
        with pytest.raises(CaptureError) as caught:
            read(huge)
        message = str(caught.value)
        assert message.startswith(f"{huge}: 10.0 GiB, more than the 2 GiB that an NLiPsNet model file") and (
            "\n" not in message
        ), message
    assert tolerances.MAX_TORCH_FILE_BYTES >= 2 * 0.82e9  # twice the largest model a user can make (its docstring)

    small = tmp_path / "small.pt"
    torch.save({"w": torch.zeros(1000)}, small)
    assert read_torch_file(small, "a model")["w"].shape == (1000,)
    # stat says the file is small, its bytes keep coming (written meanwhile): read no further than the limit
    monkeypatch.setattr(tolerances, "MAX_TORCH_FILE_BYTES", 100)
    monkeypatch.setattr(model_module.os, "fstat", lambda fd: SimpleNamespace(st_size=10))
    assert small.stat().st_size > 100
    with pytest.raises(CaptureError, match=r"more than the 0 GiB"):
        read_torch_file(small, "a model")
