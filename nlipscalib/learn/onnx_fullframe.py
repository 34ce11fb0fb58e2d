"""A standalone full-frame ONNX graph of an NLiPsNet model: the tri-colour frame as the camera stores it in, the normal
map and the gel mask out (``nlips export MODEL --full-frame``).

The per-pixel export (:mod:`.onnx_export`) leaves the frame's preparation to its caller: the camera's tone curve,
the dark frame and levels, the model's prefilter over the gel, the gathering of the gel's pixels. A lab's C++, ROS or
Unity program would have to copy each of them exactly. This graph holds them all, as :mod:`.fullframe`'s PyTorch path
(``keep_reference=False``) runs them, in standard ONNX operators (opset 17):

1. the tone curve (a camera that declared one): a ``Gather`` of the stored value in the 65536-entry table
   (``core.sensor_response.tone_curve_table``; a per-channel curve indexed at ``3 value + channel``);
2. linearisation: ``(value - dark) / (white_level - black_level)`` with the reference's dark frame;
3. the prefilter over the gel: the normalised Gaussian as two depthwise ``Conv`` of OpenCV's kernel on the reflected
   (``Pad`` "reflect", OpenCV's BORDER_REFLECT_101) frame set to 0 off the gel, divided by the blurred gel mask (the
   Python path's normalisation at the gel's edge); or the model's bilateral filter (``smoothing_colour``) as
   :mod:`.fullframe` runs it: per offset of its disc a ``Slice`` of the reflected frame weighted by its spatial
   Gaussian times ``exp(-d^2 / (2 colour^2))`` (d the L1 colour distance), the weighted sum over the sum of weights;
4. the gel's pixels gathered (``Gather`` of the flat gel indices), for a ratio model divided by its filtered reference
   there, their (u, v) prepended;
5. the network as the per-pixel export writes it (:func:`.onnx_export.network_nodes`: MatMul + Add per folded layer,
   ReLU, the division by the L2 norm);
6. scattered back (``ScatterND``) into a map of NaN: the normal map, NaN off the gel, and the gel mask beside it.

Fixed shapes: the sensor's image. A bilateral filter of a wide disc is refused (:data:`MAX_BILATERAL_OFFSETS`).
"""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CaptureError, ConfigError, require
from ..core.tolerances import ONNX_PARITY_DEG

if TYPE_CHECKING:
    import onnx

    from .model import LoadedModel

FRAME_INPUT, NORMALS_OUTPUT, GEL_OUTPUT = "tricolor", "normals", "gel"
"""Names of the graph's input, (H, W, 3) uint16 stored values, and outputs, (H, W, 3) float32 unit normals (NaN off
the gel) and (H, W) bool gel mask."""
FULL_FRAME_SUFFIX = ".frame.onnx"
"""The full-frame graph's file beside its model: MODEL.frame.onnx (``nlips export MODEL --full-frame``), where
``nlips infer --full-frame`` and ``nlips live --full-frame`` look for it."""
MAX_BILATERAL_OFFSETS = 400
"""Most offsets of a bilateral filter's disc the graph unrolls (12 nodes each): 29 at the default sigma of 1 px, 253
at 3 px, 441 above 11/3 px. The graph's filter grows with them: Q2's 640x480 model took 0.95 s of one CPU core a
frame at 1 px (349 nodes, the network most of it) and 2.5 s at 3.6 px (377 offsets, 4,177 nodes; load 14,
s39-onnxfull); beyond, a graph of thousands more nodes and seconds more a frame, so its export is refused."""


def frame_graph_path(model_path: str | Path) -> Path:
    """MODEL.frame.onnx beside the model file ``model_path``."""
    return Path(model_path).with_suffix(FULL_FRAME_SUFFIX)


def full_frame_refusal(model: LoadedModel) -> str | None:
    """Why ``model`` has no full-frame graph, in words (None: it has one)."""
    from .prefilter import bilateral_offsets

    if model.table is not None:
        return "a lookup table (`nlips lut`), not a network: there is no graph to export"
    if model.smoothing_colour and len(bilateral_offsets(model.smoothing_px)) > MAX_BILATERAL_OFFSETS:
        count = len(bilateral_offsets(model.smoothing_px))
        sigmas = f"smoothing_px {model.smoothing_px:g}, smoothing_colour {model.smoothing_colour:g}"
        return (
            f"its bilateral prefilter ({sigmas}) has {count} offsets in its disc, more than the "
            f"{MAX_BILATERAL_OFFSETS} a full-frame graph unrolls (a branch of nodes each, seconds a frame); the "
            "per-pixel export (`nlips export` without --full-frame) takes colours filtered by the caller"
        )
    return None


def full_frame_proto(model: LoadedModel) -> onnx.ModelProto:
    """The full-frame ONNX model of ``model`` (module docstring): graph, weights and metadata; ConfigError when
    :func:`full_frame_refusal` names a reason."""
    onnx = require("onnx", "onnx", "ONNX export")
    from ..core.sensor_record import camera_response_of, response_table_of
    from .model import folded_layers
    from .onnx_export import IR_VERSION, OPSET, network_nodes

    problem = full_frame_refusal(model)
    if problem:
        raise ConfigError(f"{model.path}: no full-frame ONNX graph: {problem}")
    helper, tp = onnx.helper, onnx.TensorProto
    height, width = model.shape
    valid = model.reference["valid"].astype(bool)
    g = _Graph(onnx)
    current = _linear_frame(g, model, response_table_of(model.sensor))  # (1, 3, H, W) float32
    current = _prefiltered(g, model, valid, current)
    flat = np.flatnonzero(valid)
    rows, cols = np.divmod(flat, width)
    g.init("gel_index", flat.astype(np.int64))
    g.init("colour_rows", np.array([3, height * width], np.int64))
    g.node("Reshape", [current, "colour_rows"], "colour_rows_out")
    g.node("Gather", ["colour_rows_out", "gel_index"], "gel_colours_t", axis=1)
    g.node("Transpose", ["gel_colours_t"], "gel_colours", perm=[1, 0])  # (N, 3)
    colours = "gel_colours"
    if model.input_reference is not None:  # a model of colour ratios: over the reference's, as model_inputs divides
        g.init("gel_reference", model.input_reference[rows, cols].astype(np.float32))
        g.node("Div", [colours, "gel_reference"], "gel_ratios")
        colours = "gel_ratios"
    g.init("gel_uv", np.stack([cols, rows], 1).astype(np.float32))  # (u, v) = (column, row)
    g.node("Concat", ["gel_uv", colours], "gel_input", axis=1)
    layers, weights = network_nodes(onnx.onnx_ml_pb2, folded_layers(model.net.state_dict()), "gel_input", "gel_normals")
    g.nodes += layers
    g.weights += weights
    g.init("map_shape", np.array([height * width, 3], np.int64))
    g.nodes.append(
        helper.make_node(
            "ConstantOfShape",
            ["map_shape"],
            ["empty_map"],
            name="empty_map",
            value=helper.make_tensor("nan", tp.FLOAT, [1], [float("nan")]),
        )
    )
    g.init("cell_axis", np.array([1], np.int64))
    g.node("Unsqueeze", ["gel_index", "cell_axis"], "gel_cells")  # (N, 1): ScatterND's rows
    g.node("ScatterND", ["empty_map", "gel_cells", "gel_normals"], "normal_rows")
    g.init("normals_shape", np.array([height, width, 3], np.int64))
    g.node("Reshape", ["normal_rows", "normals_shape"], NORMALS_OUTPUT)
    g.init("gel_mask", valid)
    g.node("Identity", ["gel_mask"], GEL_OUTPUT)
    graph = helper.make_graph(
        g.nodes,
        "nlipsnet_full_frame",
        [helper.make_tensor_value_info(FRAME_INPUT, tp.UINT16, [height, width, 3])],
        [
            helper.make_tensor_value_info(NORMALS_OUTPUT, tp.FLOAT, [height, width, 3]),
            helper.make_tensor_value_info(GEL_OUTPUT, tp.BOOL, [height, width]),
        ],
        g.weights,
    )
    proto = helper.make_model(graph, producer_name="nlipscalib", opset_imports=[helper.make_opsetid("", OPSET)])
    proto.ir_version = IR_VERSION  # the per-pixel export's: onnxruntime >= 1.13 reads it
    meta = {
        "sensor": json.dumps(model.sensor),
        "model_digest": model.digest,
        "hidden": json.dumps(list(model.hidden)),
        "colour_input": model.colour_input,
        "frame": json.dumps(frame_contract(model, camera_response_of(model.sensor))),
    }
    for key, value in meta.items():
        proto.metadata_props.add(key=key, value=value)
    return proto


def frame_contract(model: LoadedModel, camera_response: str) -> dict:
    """What the full-frame graph takes and gives, for its metadata's ``frame`` (JSON; docs/formats.md)."""
    height, width = model.shape
    return {
        "input": {
            "name": FRAME_INPUT,
            "shape": [height, width, 3],
            "dtype": "uint16",
            "values": "the tri-colour frame as the camera stores it (the capture format's 16-bit PNG, RGB; an 8-bit "
            "camera's values shifted up 8 bits), encoded with the calibration's camera response: the graph undoes it, "
            "subtracts the dark frame and filters",
        },
        "outputs": {
            NORMALS_OUTPUT: {
                "shape": [height, width, 3],
                "dtype": "float32",
                "values": "unit normals, camera frame (OpenCV: x right, y down, z forward), toward the camera; NaN off "
                "the gel",
            },
            GEL_OUTPUT: {"shape": [height, width], "dtype": "bool", "values": "the pixels that see the gel"},
        },
        "camera_response": camera_response,
        "smoothing_px": model.smoothing_px,
        "smoothing_colour": model.smoothing_colour,
    }


class _Graph:
    """Nodes and initializers being made (onnx.helper's), each node named by its output."""

    def __init__(self, onnx: ModuleType):
        self.onnx, self.nodes, self.weights = onnx, [], []

    def init(self, name: str, values: np.ndarray) -> str:
        self.weights.append(self.onnx.numpy_helper.from_array(np.ascontiguousarray(values), name))
        return name

    def node(self, op: str, inputs: list[str], output: str, **attrs) -> str:
        self.nodes.append(self.onnx.helper.make_node(op, inputs, [output], name=output, **attrs))
        return output


def _linear_frame(g: _Graph, model: LoadedModel, table: np.ndarray | None) -> str:
    """Nodes from the stored (H, W, 3) uint16 frame to the linear (1, 3, H, W) float32 one: the tone curve undone
    (``table``), the dark frame subtracted, divided by the sensor's range (``core.sensor_response.linearise``)."""
    s = model.sensor
    if table is None:
        light = g.node("Cast", [FRAME_INPUT], "light", to=g.onnx.TensorProto.FLOAT)
    else:
        g.node("Cast", [FRAME_INPUT], "stored_index", to=g.onnx.TensorProto.INT64)
        index = "stored_index"
        if table.ndim == 2:  # a curve per channel: row-major (65536, 3) flattened, at 3 value + channel
            g.init("three", np.array(3, np.int64))
            g.init("channel", np.arange(3, dtype=np.int64))
            g.node("Mul", [index, "three"], "stored_index3")
            index = g.node("Add", ["stored_index3", "channel"], "table_index")
        g.init("tone_table", table.astype(np.float32).ravel())
        light = g.node("Gather", ["tone_table", index], "light", axis=0)
    g.init("dark", model.reference["dark"].astype(np.float32))
    g.init("full_scale", np.array(s["white_level"] - s["black_level"], np.float32))
    g.node("Sub", [light, "dark"], "above_dark")
    g.node("Div", ["above_dark", "full_scale"], "linear_hwc")
    g.init("gel_float", model.reference["valid"].astype(np.float32)[..., None])
    g.node("Mul", ["linear_hwc", "gel_float"], "on_gel_hwc")  # 0 off the gel (stored values are never NaN)
    g.node("Transpose", ["on_gel_hwc"], "on_gel_chw", perm=[2, 0, 1])
    g.init("batch_axis", np.array([0], np.int64))
    return g.node("Unsqueeze", ["on_gel_chw", "batch_axis"], "on_gel")


def _prefiltered(g: _Graph, model: LoadedModel, valid: np.ndarray, frame: str) -> str:
    """Nodes of the model's prefilter (module docstring) of ``frame`` ((1, 3, H, W), 0 off the gel)."""
    from .prefilter import Prefilter, gaussian_kernel, kernel_radius

    r = kernel_radius(model.smoothing_px)
    if not r:  # trained unfiltered
        return frame
    g.init("reflect_pads", np.array([0, 0, r, r, 0, 0, r, r], np.int64))
    padded = g.node("Pad", [frame, "reflect_pads"], "reflected", mode="reflect")
    if model.smoothing_colour:
        return _bilateral(g, model, padded, frame, valid.shape)
    kernel = gaussian_kernel(model.smoothing_px).astype(np.float32)
    g.init("kernel_rows", np.tile(kernel[None, None, :, None], (3, 1, 1, 1)))
    g.init("kernel_cols", np.tile(kernel[None, None, None, :], (3, 1, 1, 1)))
    g.node("Conv", [padded, "kernel_rows"], "blurred_rows", group=3)
    g.node("Conv", ["blurred_rows", "kernel_cols"], "blurred", group=3)
    g.init("gel_weight", Prefilter(valid, model.smoothing_px).gel_weight()[None, None])
    return g.node("Div", ["blurred", "gel_weight"], "filtered")


def _bilateral(g: _Graph, model: LoadedModel, padded: str, frame: str, shape: tuple[int, int]) -> str:
    """Nodes of the bilateral filter, as :class:`.fullframe._GelFilter` runs it: per offset of the disc the shifted
    frame, weighted by its spatial Gaussian times exp(-d^2 / (2 colour^2)), summed, over the sum of the weights."""
    from .prefilter import bilateral_offsets, kernel_radius

    r, (height, width) = kernel_radius(model.smoothing_px), shape
    g.init("colour_scale", np.array(-0.5 / model.smoothing_colour**2, np.float32))
    g.init("image_axes", np.array([2, 3], np.int64))
    g.init("colour_axis", np.array([1], np.int64))
    total = weight = None
    for k, (dy, dx, near) in enumerate(bilateral_offsets(model.smoothing_px)):
        g.init(f"start{k}", np.array([r + dy, r + dx], np.int64))
        g.init(f"end{k}", np.array([r + dy + height, r + dx + width], np.int64))
        g.init(f"near{k}", np.array(near, np.float32))
        shifted = g.node("Slice", [padded, f"start{k}", f"end{k}", "image_axes"], f"shifted{k}")
        g.node("Sub", [shifted, frame], f"diff{k}")
        g.node("Abs", [f"diff{k}"], f"absdiff{k}")
        apart = g.node("ReduceSum", [f"absdiff{k}", "colour_axis"], f"apart{k}", keepdims=1)
        g.node("Mul", [apart, apart], f"apart_sq{k}")
        g.node("Mul", [f"apart_sq{k}", "colour_scale"], f"exponent{k}")
        g.node("Exp", [f"exponent{k}"], f"colour_weight{k}")
        w = g.node("Mul", [f"near{k}", f"colour_weight{k}"], f"weight{k}")
        term = g.node("Mul", [w, shifted], f"term{k}")
        total = term if total is None else g.node("Add", [total, term], f"total{k}")
        weight = w if weight is None else g.node("Add", [weight, w], f"weights{k}")
    return g.node("Div", [total, weight], "filtered")


def export_full_frame(model: LoadedModel, out: str | Path, check: bool = True) -> tuple[Path, float | None]:
    """Write ``model``'s full-frame graph to ``out`` atomically; with ``check``, first compare onnxruntime's normals
    with PyTorch's full-frame path on :func:`check_frames` (an export that fails, or is interrupted during it, is
    never published). Returns (path, the largest angle in degrees, or None unchecked)."""
    from ..core.atomic import write_by_name

    onnx = require("onnx", "onnx", "ONNX export")
    proto = full_frame_proto(model)
    onnx.checker.check_model(proto)
    data = proto.SerializeToString()
    angles = []

    def write_and_check(tmp: Path) -> None:
        tmp.write_bytes(data)
        if check:
            try:
                angles.append(full_frame_parity_deg(model, tmp, check_frames(model)))
            except CaptureError as exc:  # named by the file the user asked for: the temporary is removed
                raise CaptureError(str(exc).replace(str(tmp), str(out))) from None

    path = write_by_name(out, write_and_check)
    return path, (angles[0] if angles else None)


def check_frames(model: LoadedModel) -> list[np.ndarray]:
    """(H, W, 3) uint16 frames as the camera stores them for the export's check, encoded with the sensor's tone curve:
    the model's reference frame as it is, 10 % darker and brighter (a contact changes the light), and with a
    synthetic contact: a disc of a quarter of the image's height at the gel's centre whose colours tilt across it
    (red up to 1.3x on one side, blue on the other), its edge a step (what the bilateral filter stops at)."""
    from ..core.sensor_record import response_table_of
    from ..core.sensor_response import redo_tone_curve

    ref, s = model.reference, model.sensor
    table = response_table_of(s)
    light = ref["tricolor"].astype(np.float64)
    rows, cols = np.nonzero(ref["valid"])
    centre = (np.median(rows), np.median(cols)) if len(rows) else (0.0, 0.0)
    v, u = np.indices(light.shape[:2])
    radius = light.shape[0] / 8
    across = np.clip((u - centre[1]) / radius, -1, 1)
    inside = (v - centre[0]) ** 2 + (u - centre[1]) ** 2 <= radius**2
    tilt = np.stack([1 + 0.3 * across, np.ones_like(across), 1 - 0.3 * across], -1)
    contact = light * np.where(inside[..., None], tilt, 1.0)
    frames = []
    for frame in (light, light * 0.9, light * 1.1, contact):
        values = np.clip(np.rint(frame * (s["white_level"] - s["black_level"]) + ref["dark"]), 0, 65535)
        frames.append(np.clip(np.rint(redo_tone_curve(values, table)), 0, 65535).astype(np.uint16))
    return frames


def full_frame_parity_deg(model: LoadedModel, onnx_path: str | Path, frames: list[np.ndarray]) -> float:
    """Largest angle (degrees) between onnxruntime's normal map from the full-frame graph at ``onnx_path`` and PyTorch's
    full-frame path's (:class:`.fullframe.FullFrame`, ``keep_reference=False``, on the CPU) on the gel of each of
    ``frames`` ((H, W, 3) uint16 stored, as the camera encodes them); CaptureError naming ``onnx_path`` at or beyond
    :data:`~nlipscalib.core.tolerances.ONNX_PARITY_DEG`, or when the map off the gel is not NaN or the gel mask not
    the model's."""
    from ..core.sensor_record import response_table_of
    from ..core.sensor_response import undo_tone_curve
    from .fullframe import FullFrame, _torch
    from .onnx_export import max_angle_deg

    ort = require("onnxruntime", "onnxruntime", "ONNX inference")
    torch = _torch()
    valid = model.reference["valid"].astype(bool)
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    full = FullFrame(model, torch.device("cpu"), None, keep_reference=False)
    table = response_table_of(model.sensor)
    worst = 0.0
    for frame in frames:
        normals, gel = session.run([NORMALS_OUTPUT, GEL_OUTPUT], {FRAME_INPUT: frame})
        expected = full(undo_tone_curve(np.array(frame, np.uint16), table), stored=True)[0]
        if not np.array_equal(gel, valid) or not np.isnan(normals[~valid]).all():
            raise CaptureError(f"{onnx_path}: its gel mask or its map off the gel is not the model's")
        worst = max(worst, max_angle_deg(normals[valid], expected[valid]))
    if not worst < ONNX_PARITY_DEG:
        raise CaptureError(
            f"{onnx_path}: onnxruntime's normal map differs from PyTorch's full-frame path by {worst:.3f} deg "
            f"(limit {ONNX_PARITY_DEG})"
        )
    return worst


def full_frame_hint(model_path: str | Path, graph: str | Path | None = None) -> str:
    """How to write the full-frame graph of the model at ``model_path`` (missing, stale or damaged); ``graph``: the
    file that was to run, when it is not MODEL.frame.onnx beside the model (named: ``--onnx F``)."""
    from ..core.shell_words import shell_word

    if graph is not None and Path(graph) != frame_graph_path(model_path):
        command = f"`nlips export {shell_word(model_path)} --full-frame --out {shell_word(graph)}`"
        return f"{command} writes it; or leave out --onnx"
    return f"`nlips export {shell_word(model_path)} --full-frame` writes it; or use --backend torch"


def check_full_frame(path: str | Path, model: LoadedModel) -> bytes:
    """The bytes of the full-frame graph at ``path``, once known to be ``model``'s (before onnxruntime sees them).

    As :func:`.onnx_export.check_export` for the per-pixel export: its size, its metadata's ``model_digest`` (a graph
    left beside a model trained again is refused, with the command that writes it again), then the graph itself
    compared with :func:`full_frame_proto` of ``model`` (the same nodes, input and outputs, standard operators, no
    external data, weights within ``ONNX_WEIGHT_TOL``; its integer initializers and gel mask exactly).

    Raises
    ------
    CaptureError naming ``path`` and the first difference found, with the way to write it again.
    """
    from .onnx_export import SIZE_SLACK, _graph_difference, onnx_messages

    path, hint = Path(path), full_frame_hint(model.path, path)
    expected = full_frame_proto(model)  # a model without one (a lookup table, a wide bilateral disc): why, one line
    try:
        size = path.stat().st_size
    except FileNotFoundError:
        raise CaptureError(f"{path}: the full-frame ONNX graph of {model.path} is missing: {hint}") from None
    except OSError as exc:
        raise CaptureError(f"{path}: full-frame ONNX graph cannot be read ({exc.strerror or exc})") from None
    if size > expected.ByteSize() + SIZE_SLACK:  # checked before it is read
        raise CaptureError(f"{path}: {size} bytes, more than the full-frame graph of {model.path} holds: {hint}")
    try:
        data = path.read_bytes()
        proto = onnx_messages().ModelProto.FromString(data)
    except Exception as exc:  # protobuf's DecodeError (its class depends on the protobuf backend)
        raise CaptureError(f"{path}: not a readable ONNX model ({type(exc).__name__}): {hint}") from None
    if not proto.HasField("graph"):
        raise CaptureError(f"{path}: not a readable ONNX model (no graph): {hint}")
    if {p.key: p.value for p in proto.metadata_props}.get("model_digest") != model.digest:
        raise CaptureError(
            f"{path}: exported from another model than {model.path} (left from before it was trained again?): {hint}"
        )
    problem = _graph_difference(proto, expected)
    if problem:
        raise CaptureError(f"{path}: {problem}, not the full-frame graph of {model.path}: {hint}")
    return data


class FrameGraph:
    """onnxruntime session of a model's full-frame graph: a stored frame ((H, W, 3) uint16, encoded with the
    calibration's camera response) -> (H, W, 3) float32 unit normals, 0 off the gel (as ``learn.infer.Frame`` holds
    them; the graph's NaN there replaced).

    The file runs only once :func:`check_full_frame` found it to be ``model``'s graph; the session is made from the
    bytes checked. ``threads``: onnxruntime's intra-op threads (0: its default, the usable cores); it does not spin
    between frames.
    """

    def __init__(self, path: str | Path, model: LoadedModel, threads: int = 0):
        ort = require("onnxruntime", "onnxruntime", "ONNX inference")
        data = check_full_frame(path, model)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = int(threads)
        opts.inter_op_num_threads = 1
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            hint = full_frame_hint(model.path, path)
            raise CaptureError(f"{path}: not a readable ONNX model ({type(exc).__name__}): {hint}") from None
        self.path = Path(path)

    def __call__(self, stored: np.ndarray) -> np.ndarray:
        normals = self.session.run([NORMALS_OUTPUT], {FRAME_INPUT: np.ascontiguousarray(stored, np.uint16)})[0]
        return np.nan_to_num(normals, nan=0.0, copy=False)
