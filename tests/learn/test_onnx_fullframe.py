"""`nlips export MODEL --full-frame`: a standalone ONNX graph from the stored tri-colour frame to the normal map, the
same normals as the PyTorch full-frame path for linear and ratio models, the Gaussian and the bilateral prefilter,
a linear camera and one with a tone curve (one curve or one per channel); a bilateral filter of too wide a disc is
refused in one line."""

import json

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core.imageio import read_png16
from nlipscalib.core.tolerances import ONNX_PARITY_DEG
from nlipscalib.learn.model import load_model

from .conftest import HELD_OUT

onnx = pytest.importorskip("onnx")
ort = pytest.importorskip("onnxruntime")
torch = pytest.importorskip("torch")


def _variant(model_path, out, **changes):
    """A copy of the model file at ``out`` with payload keys changed (``sensor`` entries merged)."""
    payload = torch.load(model_path, weights_only=False)
    payload["sensor"] = payload["sensor"] | changes.pop("sensor", {})
    payload.update(changes)
    torch.save(payload, out)
    return out


def _run(path, frame):
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return session.run(["normals", "gel"], {"tricolor": frame})


def _torch_normals(model, frame):
    """PyTorch's full-frame path (keep_reference=False, CPU) on a stored frame, its tone curve undone first."""
    from nlipscalib.core.sensor_record import response_table_of
    from nlipscalib.core.sensor_response import undo_tone_curve
    from nlipscalib.learn.fullframe import FullFrame

    full = FullFrame(model, torch.device("cpu"), None, keep_reference=False)
    return full(undo_tone_curve(frame.copy(), response_table_of(model.sensor)), stored=True)[0]


def _angles(a, b):
    from nlipscalib.core.metrics import angle_deg

    return angle_deg(a.reshape(-1, 3), b.reshape(-1, 3))


def _encoded(stored, table):
    """Stored values linear in the light encoded as a camera with the tone curve ``table`` stores them."""
    from nlipscalib.core.sensor_response import redo_tone_curve

    return np.clip(np.rint(redo_tone_curve(stored, table)), 0, 65535).astype(np.uint16)


@pytest.mark.parametrize("kind", ["linear gaussian", "linear bilateral", "ratio bilateral", "ratio gaussian"])
def test_the_full_frame_graph_gives_the_pytorch_full_frame_normals_on_a_pressed_frame(
    kind, trained, trained_ratio, twin_presses, tmp_path
):
    """A held-out press's tri-colour PNG as stored, straight into the graph: within ONNX_PARITY_DEG of PyTorch's
    full-frame path on every gel pixel, NaN off the gel, the gel mask the model's; and the network's work is there
    (the press's normals differ from the reference's)."""
    from nlipscalib.learn.onnx_fullframe import export_full_frame

    source = trained if kind.startswith("linear") else trained_ratio
    changes = {"smoothing_colour": 0.0} if kind.endswith("gaussian") else {}
    model = load_model(_variant(source, tmp_path / "m.pt", **changes))
    assert (model.smoothing_colour > 0) == kind.endswith("bilateral") and model.smoothing_px > 0
    path, angle = export_full_frame(model, tmp_path / "m.frame.onnx")
    assert angle < ONNX_PARITY_DEG
    frame = read_png16(twin_presses / HELD_OUT / "tricolor.png")
    normals, gel = _run(path, frame)
    valid = model.reference["valid"].astype(bool)
    assert normals.shape == frame.shape and normals.dtype == np.float32 and gel.dtype == bool
    assert np.array_equal(gel, valid) and np.isnan(normals[~valid]).all()
    np.testing.assert_allclose(np.linalg.norm(normals[valid], axis=-1), 1, atol=1e-5)
    expected = _torch_normals(model, frame)
    assert _angles(normals[valid], expected[valid]).max() < ONNX_PARITY_DEG
    assert _angles(normals[valid], model.reference["normals"][valid]).max() > 5  # a contact: not the reference's


def test_a_gaussian_models_graph_normalises_over_the_gel_as_the_python_prefilter_does(trained, twin_presses, tmp_path):
    """The graph's colours at the gel's edge are the CPU path's (``learn.prefilter.Prefilter``, OpenCV): the
    normalised Gaussian, not a blur with the dark rim mixed in. Read from inside the graph (its filtered map added
    as an output)."""
    from nlipscalib.core.sensor_response import linearise
    from nlipscalib.learn.onnx_fullframe import full_frame_proto
    from nlipscalib.learn.prefilter import Prefilter

    model = load_model(_variant(trained, tmp_path / "m.pt", smoothing_colour=0.0))
    proto = full_frame_proto(model)
    proto.graph.output.append(onnx.helper.make_tensor_value_info("filtered", onnx.TensorProto.FLOAT, None))
    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    stored = read_png16(twin_presses / HELD_OUT / "tricolor.png")
    filtered = session.run(["filtered"], {"tricolor": stored})[0]
    valid, s = model.reference["valid"].astype(bool), model.sensor
    linear = linearise(stored, model.reference["dark"], s["black_level"], s["white_level"])  # the model's dark frame
    want = Prefilter(valid, model.smoothing_px)(linear)
    got = filtered[0].transpose(1, 2, 0)
    np.testing.assert_allclose(got[valid], want[valid], atol=2e-6)
    edge = valid & ~np.pad(valid, 1)[2:, 1:-1]  # gel pixels whose lower neighbour is off the gel
    assert edge.any() and np.abs(got[edge] - want[edge]).max() < 2e-6


@pytest.mark.parametrize("curve", ["srgb", "per channel"])
def test_the_graph_undoes_the_cameras_tone_curve(curve, trained, twin_presses, tmp_path):
    """A model of a camera with a tone curve takes the frames as that camera encodes them: the graph's normals of
    the encoded frame are PyTorch's of the frame with the curve undone (one table, or one per channel)."""
    from nlipscalib.core.response_curve import curve_id
    from nlipscalib.core.sensor_record import response_table_of
    from nlipscalib.learn.onnx_fullframe import export_full_frame

    if curve == "srgb":
        sensor = {"camera_response": "srgb"}
    else:
        curves = [(np.linspace(0, 1, 256) ** g).tolist() for g in (2.0, 2.2, 2.4)]
        sensor = {"camera_response": curve_id(curves), "response_curve": curves}
    model = load_model(_variant(trained, tmp_path / "m.pt", sensor=sensor))
    table = response_table_of(model.sensor)
    assert table is not None and table.ndim == (1 if curve == "srgb" else 2)
    path, _ = export_full_frame(model, tmp_path / "m.frame.onnx")
    stored = read_png16(twin_presses / HELD_OUT / "tricolor.png")
    frame = _encoded(stored, table)
    normals, gel = _run(path, frame)
    expected = _torch_normals(model, frame)
    assert _angles(normals[gel], expected[gel]).max() < ONNX_PARITY_DEG
    # the curve matters: the encoded frame read as linear gives other normals
    plain = load_model(trained)
    assert _angles(normals[gel], _torch_normals(plain, frame)[gel]).mean() > 1


def test_nlips_export_full_frame_writes_the_graph_beside_the_model_and_states_its_contract(
    trained_ratio, tmp_path, capsys
):
    """`nlips export MODEL --full-frame`: MODEL.frame.onnx beside it (its path on stdout, the check on stderr), the
    per-pixel MODEL.onnx untouched; its metadata names the input and outputs for a program without nlipscalib."""
    model_path = _variant(trained_ratio, tmp_path / "net.pt")
    assert main(["export", str(model_path), "--full-frame"]) == 0
    out, err = capsys.readouterr()
    path = tmp_path / "net.frame.onnx"
    assert out.strip() == str(path) and "max angular difference" in err
    assert not (tmp_path / "net.onnx").exists()
    proto = onnx.load(str(path))
    meta = {p.key: p.value for p in proto.metadata_props}
    model = load_model(model_path)
    assert meta["model_digest"] == model.digest and meta["colour_input"] == "ratio"
    frame = json.loads(meta["frame"])
    height, width = model.shape
    assert frame["input"] == frame["input"] | {"name": "tricolor", "shape": [height, width, 3], "dtype": "uint16"}
    assert frame["outputs"]["normals"]["shape"] == [height, width, 3] and "NaN" in frame["outputs"]["normals"]["values"]
    assert frame["smoothing_px"] == model.smoothing_px and frame["camera_response"] == "linear"
    assert [i.name for i in proto.graph.input] == ["tricolor"]
    assert [o.name for o in proto.graph.output] == ["normals", "gel"]
    assert main(["export", str(model_path), "--full-frame", "--out", str(tmp_path / "copy.onnx")]) == 0
    assert (tmp_path / "copy.onnx").read_bytes() == path.read_bytes()
    capsys.readouterr()
    # never under the per-pixel export's name, which `nlips infer` reads
    assert main(["export", str(model_path), "--full-frame", "--out", str(tmp_path / "net.onnx")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "per-pixel export's name" in err and not (tmp_path / "net.onnx").exists()


def test_a_bilateral_filter_of_too_wide_a_disc_is_refused_in_one_line(trained, tmp_path, capsys):
    """A model whose bilateral prefilter's disc is wider than the graph unrolls: one line naming the model and why,
    exit status 2, nothing written."""
    from nlipscalib.learn.onnx_fullframe import MAX_BILATERAL_OFFSETS
    from nlipscalib.learn.prefilter import bilateral_offsets

    assert len(bilateral_offsets(4.0)) > MAX_BILATERAL_OFFSETS >= len(bilateral_offsets(3.0))
    model_path = _variant(trained, tmp_path / "wide.pt", smoothing_px=4.0, smoothing_colour=0.08)
    assert main(["export", str(model_path), "--full-frame"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert str(model_path) in err and "no full-frame ONNX graph" in err and "offsets" in err
    assert not list(tmp_path.glob("*.onnx"))
    # the same model's Gaussian-only variant of that sigma is exported
    gaussian = _variant(trained, tmp_path / "wide_gaussian.pt", smoothing_px=4.0, smoothing_colour=0.0)
    assert main(["export", str(gaussian), "--full-frame"]) == 0
