"""The ONNX file's model digest is that of the weights exported, even when the model file is replaced meanwhile."""

import os
import shutil

import pytest

from nlipscalib.core.errors import CaptureError
from tests.learn.test_fast_paths import _reference, _sensor, _trained_like_net


def _save(path, scale: float = 1.0):
    import torch

    from nlipscalib.learn.model import save_model

    net = _trained_like_net()
    with torch.no_grad():
        for p in net.parameters():
            p.mul_(scale)
    return save_model(
        path, net, hidden=(32, 16), dropout=0.2, sensor=_sensor(64, 48), reference=_reference(64, 48), info={}
    )


def test_an_export_racing_a_model_update_records_the_digest_of_the_weights_it_exported(tmp_path):
    """`nlips export m.pt` while `nlips train --out m.pt` published a new model: the ONNX file held the old weights
    but the digest of the new file (read again from the path at write time), and `nlips infer` used it with the
    new model without a word (normals up to 55 deg off). The digest is now that of the bytes loaded."""
    onnx = pytest.importorskip("onnx")
    pytest.importorskip("onnxruntime")
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx, file_digest

    old, new, path = _save(tmp_path / "a.pt"), _save(tmp_path / "b.pt", scale=1.5), tmp_path / "m.pt"
    shutil.copy(old, path)
    loaded = load_model(path)
    shutil.copy(new, tmp_path / "publishing.pt")
    os.replace(tmp_path / "publishing.pt", path)  # the training run publishes its model meanwhile
    out = export_onnx(loaded, tmp_path / "m.onnx")
    digest = {p.key: p.value for p in onnx.load(str(out)).metadata_props}["model_digest"]
    assert digest == file_digest(old) != file_digest(new)
    OnnxNet(out, loaded)  # the weights loaded and their export go together
    with pytest.raises(CaptureError, match="exported from another model"):
        OnnxNet(out, load_model(path))  # the new model is not served by the old export


def test_inference_compares_the_export_with_the_model_it_loaded_not_the_file_there_now(tmp_path):
    """`nlips infer` loads the .pt, then opens the ONNX file: its digest was compared with whatever file was at the
    path by then, so a model published in between paired the old model's reference with the new network."""
    pytest.importorskip("onnxruntime")
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx

    old, path = _save(tmp_path / "a.pt"), tmp_path / "m.pt"
    shutil.copy(_save(tmp_path / "b.pt", scale=1.5), path)
    export_onnx(load_model(path), tmp_path / "m.onnx")  # the new model's export, beside it
    shutil.copy(old, tmp_path / "old.pt")
    os.replace(tmp_path / "old.pt", path)
    loaded = load_model(path)  # the old model, loaded by an inference ...
    shutil.copy(tmp_path / "b.pt", tmp_path / "publishing.pt")
    os.replace(tmp_path / "publishing.pt", path)  # ... while the new one is published again
    with pytest.raises(CaptureError, match="exported from another model"):
        OnnxNet(tmp_path / "m.onnx", loaded)


def test_the_onnx_metadata_is_json_a_labs_tool_can_read(tmp_path):
    """The ONNX file's `hidden` entry was Python's tuple text, "(32, 16)", beside a JSON `sensor`: a tool reading
    the metadata had to parse Python. Every entry but the digest is JSON now."""
    import json

    onnx = pytest.importorskip("onnx")
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx

    out = export_onnx(load_model(_save(tmp_path / "m.pt")), tmp_path / "m.onnx")
    meta = {p.key: p.value for p in onnx.load(str(out)).metadata_props}
    assert json.loads(meta["hidden"]) == [32, 16]
    assert json.loads(meta["sensor"])["camera"]["width"] == 64


def test_the_recorded_digest_is_read_from_the_files_top_level_fields_as_onnx_reads_it(tmp_path):
    """`--backend auto` reads an export's `model_digest` to skip one of another model without loading anything
    (learn.onnx_export.recorded_digest walks the file's top-level protobuf fields): the value onnx itself reads, for
    the per-pixel export and the full-frame graph, metadata written in any order; None for a file cut before its
    metadata, garbage, a model file and no file."""
    onnx = pytest.importorskip("onnx")
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import export_onnx, recorded_digest
    from nlipscalib.learn.onnx_fullframe import export_full_frame

    model = load_model(_save(tmp_path / "m.pt"))
    pixel = export_onnx(model, tmp_path / "m.onnx")
    frame = export_full_frame(model, tmp_path / "m.frame.onnx", check=False)[0]
    for path in (pixel, frame):
        assert recorded_digest(path) == model.digest
        assert {p.key: p.value for p in onnx.load(str(path)).metadata_props}["model_digest"] == model.digest
    proto = onnx.load(str(pixel))
    entries = [(p.key, p.value) for p in proto.metadata_props][::-1]
    del proto.metadata_props[:]
    for key, value in [("note", "x" * 300), *entries]:  # reordered, a longer entry first
        proto.metadata_props.add(key=key, value=value)
    onnx.save(proto, str(tmp_path / "reordered.onnx"))
    assert recorded_digest(tmp_path / "reordered.onnx") == model.digest
    data = pixel.read_bytes()
    (tmp_path / "cut.onnx").write_bytes(data[: len(data) // 2])
    (tmp_path / "garbage.onnx").write_bytes(bytes(range(256)) * 40)
    for other in ("cut.onnx", "garbage.onnx", "m.pt", "none.onnx"):
        assert recorded_digest(tmp_path / other) is None, other
