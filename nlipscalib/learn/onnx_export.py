"""NLiPsNet to ONNX (made of ONNX's protobuf messages from the folded weights, as onnx.helper writes them) and
inference with onnxruntime.

The ONNX graph takes one (N, 5) input for every model, (u, v) pixels and their filtered linear r, g, b
(:data:`INPUT`), and returns (N, 3) unit normals. It is the inference form of the network
(:func:`nlipscalib.learn.model.folded_layers`): input normalisation and BatchNorm folded into the linear layers, so the
graph is MatMul+Add (one Gemm to onnxruntime), ReLU, ..., MatMul+Add, then the division by the L2 norm. For a model of
colour ratios (``colour_input`` "ratio") the graph first divides r, g, b by the model's filtered reference colour at
each pixel (:func:`_ratio_nodes`: the map an initializer, read at the pixel (u, v) gives), so the file is standalone:
a caller gives every model the same inputs, and never divides. The sensor description, the model file's digest and
the input contract (:func:`input_contract`) travel in the ONNX metadata, and a file is run only once it is compared
with the export of the model it is run with (:func:`check_export`), so an .onnx file is never used with another
model's reference.
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

from ..core.cpus import usable_cores
from ..core.errors import CaptureError, require
from ..core.metrics import angle_deg
from ..core.shell_words import shell_word
from ..core.tolerances import ONNX_PARITY_DEG, ONNX_WEIGHT_TOL

if TYPE_CHECKING:  # named in hints only: the model module (and torch) are imported where an export needs them
    import onnx

    from .model import LoadedModel

OPSET = 17
IR_VERSION = 8
"""ONNX IR version of the export: the oldest that carries opset 17 (onnxruntime >= 1.13 reads it)."""
INPUT, OUTPUT = "uvrgb", "normal"
"""Names of the export's input, (pixels, 5) float32 raw (u, v, r, g, b): pixel column and row, the linear colours
filtered by the model's prefilter (never divided by the reference: a ratio model's graph does that), and output,
(pixels, 3) float32 unit normals."""
RATIO_INPUT = "uvratio"
"""Inside a ratio model's graph: the input with r, g, b over the reference's, what the first layer reads."""
SIZE_SLACK = 1 << 20
"""Bytes a received ONNX file may hold beyond its model's export (metadata written by another tool, a longer sensor
record): a larger file is refused before it is read."""


def export_hint(model_path: str | Path, again: bool = False, export: str | Path | None = None) -> str:
    """How to get the ONNX file of the model at ``model_path``, for the errors that find it missing or stale
    (``again``: damaged, so it is written again). ``export``: the file that was to run, when it is not MODEL.onnx
    beside the model (named: ``--onnx F``), which ``nlips export MODEL --out F`` writes."""
    if export is not None and Path(export) != Path(model_path).with_suffix(".onnx"):
        command = f"`nlips export {shell_word(model_path)} --out {shell_word(export)}`"
        return f"{command} writes it{' again' if again else ''}, or leave out --onnx"
    if again:
        return f"`nlips export {shell_word(model_path)}` writes it again, or use --backend torch"
    export = f"`nlips export {shell_word(model_path)}`"
    return f"{export} writes it, as `nlips train` does unless --no-onnx; or use --backend torch"


def bytes_digest(data: bytes) -> str:
    """The digest a model file's bytes are known by: the first 16 hex digits of their SHA-256 (an ONNX export
    records its model's, and inference compares it with the model it is run with)."""
    return hashlib.sha256(data).hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    return bytes_digest(Path(path).read_bytes())


def recorded_digest(path: str | Path) -> str | None:
    """The ``model_digest`` an ONNX file of a model records in its metadata (the per-pixel export's and the
    full-frame graph's alike), or None when it records none or cannot be read so (its check names why when it is
    used: :func:`check_export`, ``onnx_fullframe.check_full_frame``).

    Read by walking the file's top-level protobuf fields (:func:`_top_level_metadata`) and seeking past the graph:
    a few hundred bytes read, no protobuf import. Why not protobuf's parser (:func:`onnx_messages`): importing the
    messages and parsing a ratio model's 4 MB export cost 22-26 ms of CPU (a ``nlips infer`` re-run that keeps every
    result, which reads the digest to choose its runtime before anything loads, takes 0.30 s; the walk 0.02 ms:
    benchmarks/RESULTS.md, s40-companions)."""
    return recorded_metadata(path).get("model_digest")


def recorded_metadata(path: str | Path) -> dict[str, str]:
    """The metadata entries of the ONNX file at ``path`` (as :func:`recorded_digest` reads them: the top-level fields
    walked, the graph skipped), empty when it cannot be read so."""
    try:
        with open(path, "rb") as f:
            return _top_level_metadata(f)
    except (OSError, ValueError):  # unreadable, or not protobuf's wire format
        return {}


MAX_TOP_LEVEL_FIELDS = 1000
"""Most top-level fields :func:`_top_level_metadata` walks (an export has ~10, one per metadata entry among them)."""


def _top_level_metadata(f: BinaryIO) -> dict[str, str]:
    """The metadata entries (ModelProto field 14, StringStringEntryProto: key 1, value 2) of the ONNX file open as
    ``f``, walking its top-level fields in the protobuf wire format (varint tags; length-delimited fields skipped by
    seeking, https://protobuf.dev/programming-guides/encoding/); ValueError when the bytes are not that format."""
    entries = {}
    for _ in range(MAX_TOP_LEVEL_FIELDS):
        tag = _varint(f)
        if tag is None:  # the end of the file
            return entries
        field, wire = tag >> 3, tag & 7
        if wire == 0:
            _varint(f)
        elif wire in (1, 5):  # fixed64, fixed32
            f.seek(8 if wire == 1 else 4, 1)
        elif wire == 2:
            size = _varint(f)
            if size is None:
                raise ValueError("cut short")
            if field == 14 and size < 1 << 16:
                entry = _fields(f.read(size))
                entries[entry.get(1, b"").decode("utf-8", "replace")] = entry.get(2, b"").decode("utf-8", "replace")
            else:
                f.seek(size, 1)
        else:
            raise ValueError(f"wire type {wire}")
    raise ValueError("too many top-level fields")


def _varint(f: BinaryIO) -> int | None:
    """The protobuf varint at ``f``'s position; None at the end of the file."""
    value = shift = 0
    while True:
        byte = f.read(1)
        if not byte:
            if shift:
                raise ValueError("cut short")
            return None
        value |= (byte[0] & 0x7F) << shift
        if byte[0] < 0x80:
            return value
        shift += 7
        if shift > 63:
            raise ValueError("varint too long")


def _fields(data: bytes) -> dict[int, bytes]:
    """The length-delimited fields of a small message's bytes (a metadata entry's key and value), by number."""
    import io

    f, fields = io.BytesIO(data), {}
    while (tag := _varint(f)) is not None:
        if tag & 7 != 2:
            raise ValueError(f"wire type {tag & 7} in a metadata entry")
        size = _varint(f)
        if size is None:
            raise ValueError("cut short")
        fields[tag >> 3] = f.read(size)
    return fields


def export_onnx(model: LoadedModel, out: str | Path, check: Callable[[Path], object] | None = None) -> Path:
    """Write ``model`` (a LoadedModel) as an ONNX file ``out`` atomically; returns its path.

    ``check(path)``, when given, runs on the written file before it takes its name (e.g. the parity with
    PyTorch, :func:`checked_parity`): an export that fails it, or is interrupted during it, is never published
    (an interrupted ``nlips export`` used to leave a file whose check never ran, which ``nlips infer`` then used).

    The graph is written directly from the folded weights (:func:`nlipscalib.learn.model.folded_layers`):
    per layer a MatMul named ``layer<k>`` and an Add (onnxruntime fuses the pair into one Gemm), ReLU
    between layers, then the division by the L2 norm (at least 1e-8); for a model of colour ratios, the division of
    the colours by its reference's before them (:func:`_ratio_nodes`). Named layers let the int8
    variant leave chosen layers in float (:func:`quantized_int8`).
    """
    from ..core.atomic import write_by_name, write_bytes

    onnx = require("onnx", "onnx", "ONNX export")
    proto = export_proto(model)
    onnx.checker.check_model(proto)
    data = proto.SerializeToString()
    if check is None:
        return write_bytes(out, data)

    def write_and_check(tmp: Path) -> None:
        tmp.write_bytes(data)
        try:
            check(tmp)
        except CaptureError as exc:  # named by the file the user asked for: the temporary is removed
            raise CaptureError(str(exc).replace(str(tmp), str(out))) from None

    return write_by_name(out, write_and_check)


def onnx_messages() -> ModuleType:
    """The module of ONNX's protobuf messages (``onnx.onnx_ml_pb2``: ModelProto, TensorProto ...), without
    ``import onnx``.

    Why: ``import onnx`` costs about 0.7 s of CPU (mostly ml_dtypes, which it imports for its type tables) at every
    ``nlips infer`` start, where reading and comparing an export needs only the messages: their module, generated
    by protoc into the onnx package, imports protobuf alone (30 ms). Loaded from the installed onnx's file; once
    onnx itself is imported, its own module is used (both register the same descriptors).
    """
    import sys

    loaded = sys.modules.get("onnx.onnx_ml_pb2")  # onnx imported: its own
    return loaded if loaded is not None else _messages_alone()


@functools.cache
def _messages_alone() -> ModuleType:
    """onnx's generated ``onnx_ml_pb2`` module executed from its file, once; ``import onnx`` later executes its own
    copy, which adds the same descriptors to protobuf's pool (allowed: identical) and gets the same classes."""
    import importlib.util

    spec = importlib.util.find_spec("onnx")  # finds the package without executing it
    origin = Path(spec.origin).parent / "onnx_ml_pb2.py" if spec and spec.origin else None
    if origin is None or not origin.is_file():  # no onnx (require names the package to install) or another layout
        return require("onnx", "onnx", "ONNX inference").onnx_ml_pb2
    messages = importlib.util.spec_from_file_location("onnx.onnx_ml_pb2", origin)
    module = importlib.util.module_from_spec(messages)
    messages.loader.exec_module(module)
    return module


def _tensor(pb: ModuleType, values: np.ndarray, name: str) -> onnx.TensorProto:
    """A float32 initializer as onnx.numpy_helper.from_array writes it (dims, FLOAT, little-endian raw_data)."""
    values = np.ascontiguousarray(values, "<f4")
    return pb.TensorProto(name=name, dims=values.shape, data_type=pb.TensorProto.FLOAT, raw_data=values.tobytes())


def _int_tensor(pb: ModuleType, values: list[int], name: str) -> onnx.TensorProto:
    """An int64 initializer as onnx.numpy_helper.from_array writes it (dims, INT64, little-endian raw_data)."""
    array = np.asarray(values, "<i8")
    return pb.TensorProto(name=name, dims=array.shape, data_type=pb.TensorProto.INT64, raw_data=array.tobytes())


def _node(
    pb: ModuleType, op: str, inputs: list[str], outputs: list[str], name: str, **ints: int | list[int]
) -> onnx.NodeProto:
    """A node as onnx.helper.make_node writes it: integer attributes (a list: INTS) sorted by name."""
    node = pb.NodeProto(op_type=op, input=inputs, output=outputs, name=name)
    for key, value in sorted(ints.items()):
        if isinstance(value, list):
            node.attribute.add(name=key, type=pb.AttributeProto.INTS, ints=value)
        else:
            node.attribute.add(name=key, type=pb.AttributeProto.INT, i=value)
    return node


def _value(pb: ModuleType, name: str, width: int) -> onnx.ValueInfoProto:
    """A graph input or output: float32 of shape (``pixels``, width), as onnx.helper.make_tensor_value_info."""
    value = pb.ValueInfoProto(name=name)
    value.type.tensor_type.elem_type = pb.TensorProto.FLOAT
    value.type.tensor_type.shape.dim.add(dim_param="pixels")
    value.type.tensor_type.shape.dim.add(dim_value=width)
    return value


def export_proto(model: LoadedModel) -> onnx.ModelProto:
    """The ONNX model (onnx.ModelProto) :func:`export_onnx` writes for ``model``: its graph, weights and metadata.

    Also what a received ONNX file is compared with before it is run (:func:`check_export`): one copy of the
    graph's layout. Made of ONNX's protobuf messages directly (:func:`onnx_messages`), field by field as
    onnx.helper makes them (tests/learn/test_models_from_others.py compares the bytes), so inference does not
    import onnx.
    """
    from .model import folded_layers

    pb = onnx_messages()
    linear = folded_layers(model.net.state_dict())
    nodes, weights, current = [], [], INPUT
    if model.input_reference is not None:  # a model of colour ratios: divided here, so the file is standalone
        nodes, weights = _ratio_nodes(pb, model.input_reference)
        current = RATIO_INPUT
    layers, layer_weights = network_nodes(pb, linear, current, OUTPUT)
    nodes, weights = nodes + layers, weights + layer_weights
    graph = pb.GraphProto(
        node=nodes, name="nlipsnet", input=[_value(pb, INPUT, 5)], output=[_value(pb, OUTPUT, 3)], initializer=weights
    )
    # IR version 8: the installed onnx would write its newest, which older onnxruntimes refuse
    proto = pb.ModelProto(ir_version=IR_VERSION, producer_name="nlipscalib", graph=graph)
    proto.opset_import.add(domain="", version=OPSET)
    meta = {"sensor": json.dumps(model.sensor), "model_digest": model.digest, "hidden": json.dumps(list(model.hidden))}
    if model.colour_input != "linear":  # the network's r, g, b are ratios, made inside the graph: "input" says so
        meta["colour_input"] = model.colour_input
    meta["input"] = json.dumps(input_contract(model))
    for key, value in meta.items():
        proto.metadata_props.add(key=key, value=value)
    return proto


def network_nodes(
    pb: ModuleType, linear: list[tuple[np.ndarray, np.ndarray]], current: str, output: str
) -> tuple[list[onnx.NodeProto], list[onnx.TensorProto]]:
    """The nodes and initializers of the network itself, from its (N, 5) input ``current`` to its (N, 3) unit
    normals ``output``: per folded layer (``linear``, :func:`nlipscalib.learn.model.folded_layers`) a MatMul named
    ``layer<k>`` and an Add, ReLU between layers, then the division by the L2 norm (at least 1e-8). The one copy of
    the layout: the per-pixel export and the full-frame one (:mod:`.onnx_fullframe`) share it."""
    nodes, weights = [], []
    for k, (W, b) in enumerate(linear):
        weights.append(_tensor(pb, W.T, f"W{k}"))
        weights.append(_tensor(pb, b, f"b{k}"))
        nodes.append(_node(pb, "MatMul", [current, f"W{k}"], [f"matmul{k}"], f"layer{k}"))
        nodes.append(_node(pb, "Add", [f"matmul{k}", f"b{k}"], [f"linear{k}"], f"bias{k}"))
        current = f"linear{k}"
        if k < len(linear) - 1:
            nodes.append(_node(pb, "Relu", [current], [f"relu{k}"], f"relu{k}"))
            current = f"relu{k}"
    weights.append(_tensor(pb, np.array([1e-8], np.float32), "min_norm"))
    nodes += [
        _node(pb, "ReduceL2", [current], ["norm"], "norm", keepdims=1, axes=[-1]),
        _node(pb, "Max", ["norm", "min_norm"], ["norm_clamped"], "clamp"),
        _node(pb, "Div", [current, "norm_clamped"], [output], "unit"),
    ]
    return nodes, weights


def input_contract(model: LoadedModel) -> dict:
    """What the export's input holds, for its metadata's ``input`` (JSON): enough for a program in any language to
    make it from a camera frame without nlipscalib (docs/formats.md).

    Returns
    -------
    dict: ``name``, ``shape``, ``columns`` (u, v, r, g, b), ``pixels`` (u, v: what they are and their range),
    ``colours`` (r, g, b: what they are), ``smoothing_px`` and ``smoothing_colour`` (the prefilter the colours get
    first, :mod:`.prefilter`), ``divided_inside`` (true for a model of colour ratios: the graph divides r, g, b by its
    initializer ``reference`` at the pixel; never divide them before)
    """
    height, width = model.shape
    return {
        "name": INPUT,
        "shape": ["pixels", 5],
        "columns": ["u", "v", "r", "g", "b"],
        "pixels": f"pixel centre (u column, v row) of the {width}x{height} image, integers from 0 (rounded to the "
        "nearest pixel, clamped to the image, when a ratio model reads its reference)",
        "colours": "linear tri-colour values (dark frame subtracted, 1 = the sensor's full range), filtered over the "
        "gel as the model's training samples: smoothing_px (Gaussian sigma, px), smoothing_colour (bilateral colour "
        "sigma, 0: none)",
        "smoothing_px": model.smoothing_px,
        "smoothing_colour": model.smoothing_colour,
        "divided_inside": model.input_reference is not None,
    }


def _ratio_nodes(pb: ModuleType, reference: np.ndarray) -> tuple[list[onnx.NodeProto], list[onnx.TensorProto]]:
    """The nodes and initializers that make :data:`RATIO_INPUT` of :data:`INPUT`: r, g, b over ``reference`` ((H, W,
    3) float32, the model's ``input_reference``) at each pixel, u and v as they are.

    The map is an initializer (H x W x 3 float32: 3.7 MB at 640x480), read with GatherND at the pixel's (row, column)
    -- (v, u) rounded to the nearest integer and clamped to the image -- padded with two ones, and the whole input
    divided by it: the same float32 division as :func:`nlipscalib.learn.model.model_inputs` at integer pixels, so
    the first layer gets the same bits as PyTorch does. Why a stored map and a gather: the map is the prefilter of
    the reference frame (a bilateral filter in OpenCV), which the graph could not redo exactly, and a gather is a few
    memory reads a pixel, against the network's thousands of multiply-adds.
    """
    height, width = reference.shape[:2]
    weights = [
        _int_tensor(pb, [1, 0], "vu_columns"),
        _tensor(pb, np.zeros(2, np.float32), "vu_lowest"),
        _tensor(pb, np.array([height - 1, width - 1], np.float32), "vu_highest"),
        _tensor(pb, reference, "reference"),
        _int_tensor(pb, [0, 2, 0, 0], "ratio_pads"),  # (N, 3) -> (N, 5): two columns of ones before r, g, b
        _tensor(pb, np.array(1.0, np.float32), "one"),
    ]
    nodes = [
        _node(pb, "Gather", [INPUT, "vu_columns"], ["vu"], "pixel", axis=1),
        _node(pb, "Round", ["vu"], ["vu_nearest"], "nearest"),
        _node(pb, "Max", ["vu_nearest", "vu_lowest"], ["vu_above"], "clamp_low"),
        _node(pb, "Min", ["vu_above", "vu_highest"], ["vu_inside"], "clamp_high"),
        _node(pb, "Cast", ["vu_inside"], ["vu_index"], "index", to=pb.TensorProto.INT64),
        _node(pb, "GatherND", ["reference", "vu_index"], ["reference_colour"], "reference_at_pixel"),
        _node(pb, "Pad", ["reference_colour", "ratio_pads", "one"], ["divisor"], "divisor"),
        _node(pb, "Div", [INPUT, "divisor"], [RATIO_INPUT], "ratio"),
    ]
    return nodes, weights


def check_export(path: str | Path, model: LoadedModel) -> bytes:
    """The bytes of the ONNX file at ``path``, once known to be ``model``'s export: before onnxruntime sees them.

    An ONNX file may come from elsewhere (beside a received model), and the model digest in its metadata is
    whatever its sender wrote. It is run only when it is, up to float32 rounding, the graph :func:`export_proto`
    writes for ``model``: the same nodes, input and output (NLiPsNet's ``uvrgb`` (pixels, 5) -> ``normal``
    (pixels, 3)), standard operators of the same opset, and weights within
    :data:`~nlipscalib.core.tolerances.ONNX_WEIGHT_TOL` of the model's folded weights (a ratio model's reference map
    likewise, its integer initializers exactly). A ratio model's export of an earlier release, whose input was the
    ratios (:func:`_ratio_outside`), is refused with the way to write it again. So it computes what the
    model computes; what onnxruntime could be made to do by other graphs (read "external data" files named in
    the graph, anywhere before onnxruntime's December 2025 fix; load custom operators; fold a ConstantOfShape of
    terabytes while it optimises the graph) never starts. Its size is checked before it is read.

    Raises
    ------
    CaptureError naming ``path`` and the first difference found, with how to write the export again.
    """
    path = Path(path)
    expected = export_proto(model)
    again = export_hint(model.path, again=True, export=path)
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise CaptureError(f"{path}: ONNX model cannot be read ({exc.strerror or exc})") from None
    limit = expected.ByteSize() + SIZE_SLACK
    if size > limit:
        raise CaptureError(f"{path}: {size} bytes, more than an export of {model.path} holds ({limit}): {again}")
    data = path.read_bytes()
    try:
        proto = onnx_messages().ModelProto.FromString(data)
    except Exception as exc:  # protobuf's DecodeError (its class depends on the protobuf backend)
        raise CaptureError(f"{path}: not a readable ONNX model ({type(exc).__name__}): {again}") from None
    if not proto.HasField("graph"):  # protobuf parses many byte strings (unknown fields are kept): no graph, no model
        raise CaptureError(f"{path}: not a readable ONNX model (no graph): {again}")
    if {p.key: p.value for p in proto.metadata_props}.get("model_digest") != model.digest:
        raise CaptureError(
            f"{path}: exported from another model than {model.path}; export it again "
            f"({export_hint(model.path, export=path)})"
        )
    old = _ratio_outside(proto, expected)
    if old:  # the model's own export, of an earlier release: named as such, not as a graph of another model
        raise CaptureError(f"{path}: {old}: {again}")
    problem = _graph_difference(proto, expected)
    if problem:
        raise CaptureError(f"{path}: {problem}, not the export of {model.path}: {again}")
    return data


def _graph_difference(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """The first way ``proto`` differs from ``expected`` (:func:`export_proto`), in words; None when it is the same
    graph with weights within ONNX_WEIGHT_TOL (the metadata is not compared: the digest was). The most telling
    differences are looked for first, so a hostile file is named for what it tries."""
    for check in (_external_data, _custom_domain, _contract, _nodes, _weights, _extras):
        problem = check(proto, expected)
        if problem:
            return problem
    return None


def _external_data(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """A weight whose values are in another file: onnxruntime would read it (any path, before its 2025 fix)."""
    graph, external = proto.graph, onnx_messages().TensorProto.EXTERNAL
    for tensor in [*graph.initializer, *(s.values for s in graph.sparse_initializer)]:
        if tensor.data_location == external or tensor.external_data:
            where = {e.key: e.value for e in tensor.external_data}.get("location", "?")
            return f"its weight {tensor.name!r} refers to an external data file ({where!r}), which exports never do"
    return None


def _custom_domain(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """Operators beyond the standard set (onnxruntime would look for a registered custom operator)."""
    domains = ({o.domain for o in proto.opset_import} | {n.domain for n in proto.graph.node}) - {"", "ai.onnx"}
    if domains:
        return f"it uses operators of the domain {sorted(domains)[0]!r} (custom operators are never run)"
    return None


def _contract(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """Inputs and outputs other than NLiPsNet's (u, v, r, g, b) -> n."""
    graph, want = proto.graph, expected.graph
    if [(v.name, v.type) for v in [*graph.input, *graph.output]] == [
        (v.name, v.type) for v in [*want.input, *want.output]
    ]:
        return None
    got = ", ".join(map(_describe, graph.input)) + " -> " + ", ".join(map(_describe, graph.output))
    return f"its graph maps {got}, NLiPsNet maps {_describe(want.input[0])} -> {_describe(want.output[0])}"


RATIO_BEFORE = (
    "exported before 2026-12-07, when a ratio model's ONNX file took the colours over the reference as its input "
    "(now its graph divides them itself and takes the linear colours, as every model's does)"
)
"""What a ratio model's export of before is named by, when it is refused (:func:`check_export`) or skipped
(``learn.exports``)."""


def ratio_export_of_before(metadata: dict[str, str]) -> bool:
    """Whether an export's metadata entries (:func:`recorded_metadata`) are those of a ratio model's export of before
    2026-12-07 (:func:`_ratio_outside`): ``colour_input`` "ratio" and no ``input`` entry, which every export since
    records (:func:`input_contract`). Per-pixel exports only: the full-frame graph records no ``input``."""
    return metadata.get("colour_input") == "ratio" and "input" not in metadata


def _ratio_outside(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """A ratio model's export from before its graph divided the colours (up to 2026-12-07): it took the ratios as its
    input, where the export takes the linear colours. Run as it is with this release's inputs, its normals would be
    wrong without an error (17 deg on average on a twin press), so it is refused with the way to write it again."""
    divides = "reference" in {t.name for t in expected.graph.initializer}
    if not divides or "reference" in {t.name for t in proto.graph.initializer}:
        return None
    if {p.key: p.value for p in proto.metadata_props}.get("colour_input") != "ratio":
        return None
    return RATIO_BEFORE


def _nodes(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """Nodes other than the export's (each compared whole: operator, inputs, outputs, attributes, subgraphs)."""
    nodes, want = list(proto.graph.node), list(expected.graph.node)
    if nodes == want:
        return None
    k = next((i for i, (a, b) in enumerate(zip(nodes, want)) if a != b), min(len(nodes), len(want)))
    got = repr(nodes[k].op_type) if k < len(nodes) else "missing"
    need = repr(want[k].op_type) if k < len(want) else "none"
    return f"its graph is not NLiPsNet's of this model's layers (node {k} is {got}, the export's is {need})"


def _weights(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """Weights of other names, shapes or values than the model's folded weights (within ONNX_WEIGHT_TOL)."""
    weights, want = {t.name: t for t in proto.graph.initializer}, list(expected.graph.initializer)
    if sorted(weights) != sorted(t.name for t in want):
        return f"its weights are named {sorted(weights)}, the export's {sorted(t.name for t in want)}"
    for tensor in want:
        got, need = weights[tensor.name], _values(tensor)
        values = _values(got) if tuple(got.dims) == need.shape and got.data_type == tensor.data_type else None
        if values is None:
            got_type = f"{tuple(got.dims)} of type {got.data_type}"
            return f"its weight {tensor.name!r} is {got_type}, the model's {need.shape} of type {tensor.data_type}"
        if need.dtype.kind in "ib":  # pixel indices, pads and (the full-frame graph's) gel mask: exactly the export's
            if not np.array_equal(values, need):
                return f"its weight {tensor.name!r} is {values.tolist()}, the export's {need.tolist()}"
            continue
        off = float(np.max(np.abs(values.astype(np.float64) - need), initial=0.0))
        scale = float(np.max(np.abs(need), initial=0.0))
        if not off <= ONNX_WEIGHT_TOL * max(scale, np.finfo(np.float32).tiny):
            return f"its weight {tensor.name!r} differs from the model's by {off:.3g} (largest weight {scale:.3g})"
    return None


def _extras(proto: onnx.ModelProto, expected: onnx.ModelProto) -> str | None:
    """Anything else a graph may carry: another IR version or opset, model-local functions, training records."""
    fields = ("ir_version", "opset_import", "functions", "training_info")
    for field in fields:
        if getattr(proto, field) != getattr(expected, field):
            return f"its {field} differs from the export's"
    graph, want = proto.graph, expected.graph
    if list(graph.sparse_initializer) or list(graph.value_info) != list(want.value_info):
        return "its graph holds sparse weights or value records that the export does not"
    return None


def _values(tensor: onnx.TensorProto) -> np.ndarray | None:
    """The float32, int64 or bool values of an initializer, shaped by its dims (in ``raw_data`` little-endian, or
    ``float_data`` / ``int64_data`` / ``int32_data``); None when it is of another type or holds another number of values
    than its dims say."""
    pb = onnx_messages().TensorProto
    kinds = {pb.FLOAT: ("<f4", "float_data"), pb.INT64: ("<i8", "int64_data"), pb.BOOL: ("?", "int32_data")}
    if tensor.data_type not in kinds:
        return None
    dtype, field = kinds[tensor.data_type]
    count = int(np.prod(tensor.dims, dtype=np.int64))
    if tensor.raw_data:
        size = np.dtype(dtype).itemsize
        values = np.frombuffer(tensor.raw_data, dtype) if len(tensor.raw_data) == size * count else None
    else:
        listed = getattr(tensor, field)
        values = np.asarray(listed, dtype) if len(listed) == count else None
    return None if values is None else values.reshape(tuple(tensor.dims))


def _describe(value: onnx.ValueInfoProto) -> str:
    """``name (pixels, 5) FLOAT`` for a graph input or output."""
    data_type = onnx_messages().TensorProto.DataType
    tensor = value.type.tensor_type
    dims = ", ".join(d.dim_param or str(d.dim_value) for d in tensor.shape.dim)
    kind = data_type.Name(tensor.elem_type) if tensor.elem_type in data_type.values() else str(tensor.elem_type)
    return f"{value.name!r} ({dims}) {kind}"


def quantized_int8(model: bytes) -> bytes:
    """The ONNX model ``model`` (its file's bytes, checked: :func:`check_export`) with dynamic int8 quantisation
    (onnxruntime.quantization.quantize_dynamic).

    Weights int8 per output channel, activations quantised per call. The first layer stays float: its
    inputs (pixel coordinates in hundreds, linear colours below 1) would share one 8-bit scale and
    the colours would be lost. The last layer (3 outputs, little work) stays float too. Costs about
    0.05 deg mean (0.3 deg max) against the float network; measured in benchmarks/RESULTS.md.
    """
    from ..core.atomic import system_scratch_dir

    require("onnx", "onnx", "int8 quantisation")
    quantization = require("onnxruntime.quantization", "onnxruntime", "int8 quantisation")
    onnx = require("onnx", "onnx", "int8 quantisation")
    layers = [n.name for n in onnx.load_from_string(model).graph.node if n.op_type == "MatMul"]
    # not a TemporaryDirectory: a killed command's (kill -9 while it quantises) is removed by the next quantisation
    with system_scratch_dir("nlips-onnx-int8") as tmp:
        path, out = tmp / "float.onnx", tmp / "int8.onnx"
        path.write_bytes(model)  # the bytes checked, not the file again (it may have changed meanwhile)
        # No warnings filter here: onnxruntime 1.32's quantize_dynamic warns nothing (a blanket "ignore" hid any
        # deprecation it might start to give from the tests' filterwarnings). Its advice goes to the root logger.
        logging.getLogger().disabled, was = True, logging.getLogger().disabled  # its advice on pre-processing
        try:
            quantization.quantize_dynamic(
                str(path),
                str(out),
                weight_type=quantization.QuantType.QInt8,
                per_channel=True,
                nodes_to_exclude=[layers[0], layers[-1]],
                op_types_to_quantize=["MatMul"],  # the network's layers alone: never a ratio model's reference map
            )
        finally:
            logging.getLogger().disabled = was
        return out.read_bytes()


class OnnxNet:
    """onnxruntime session of an exported NLiPsNet: ``(N, 5) float32 -> (N, 3)`` unit normals, its input the export's
    (:data:`INPUT`: pixels and filtered linear colours, for a ratio model too: its graph divides them).

    With ``threads`` > 1 the pixels are split into that many equal slices run concurrently, each on one
    onnxruntime thread: for these narrow layers that uses the cores far better than onnxruntime's own
    intra-op split of one large call (measured in benchmarks/RESULTS.md). The session does not spin
    between calls, so the other stages of a frame get the cores.

    With ``model`` (the loaded .pt: how inference runs it), the file runs only once :func:`check_export` found it
    to be that model's export, and the session is made from the bytes checked. Without one, the file is trusted
    as it is (a test's or benchmark's own export): never pass a received file so.
    """

    MIN_SLICE = 4096
    """Fewest pixels worth a slice of their own (below, thread hand-over costs more than it saves)."""

    def __init__(self, path: str | Path, model: LoadedModel | None = None, threads: int = 0, int8: bool = False):
        ort = require("onnxruntime", "onnxruntime", "ONNX inference")
        path = Path(path)
        if not path.is_file():
            hint = export_hint(model.path if model else "MODEL.pt", export=path)
            raise CaptureError(f"{path}: ONNX model is missing ({hint})")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        # a model's export only (check_export): a received file is never handed to onnxruntime unchecked, nor read twice
        data = check_export(path, model) if model is not None else str(path)
        try:
            self.session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise CaptureError(
                f"{path}: not a readable ONNX model ({type(exc).__name__}): "
                f"{export_hint(model.path if model else 'MODEL.pt', again=True, export=path)}"
            ) from None
        if int8:  # the checked float file, quantised in memory
            float_model = data if isinstance(data, bytes) else path.read_bytes()
            self.session = ort.InferenceSession(quantized_int8(float_model), opts, providers=["CPUExecutionProvider"])
        self.path = path
        self.int8 = int8
        self.threads = max(1, int(threads) if threads else usable_cores())
        self._pool = ThreadPoolExecutor(self.threads - 1) if self.threads > 1 else None

    def _run(self, x: np.ndarray) -> np.ndarray:
        return self.session.run(None, {INPUT: x})[0]

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.ascontiguousarray(x, np.float32)
        slices = min(self.threads, max(1, len(x) // self.MIN_SLICE))
        if slices == 1:
            return self._run(x)
        parts = np.array_split(x, slices)
        futures = [self._pool.submit(self._run, part) for part in parts[1:]]
        first = self._run(parts[0])  # this thread does a share too
        return np.concatenate([first] + [f.result() for f in futures])


def max_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle between corresponding unit vectors of (N, 3) arrays, degrees."""
    ang = angle_deg(a, b)  # accurate for the tiny angles a parity check measures
    return float(ang.max()) if len(ang) else 0.0


def checked_parity(model: LoadedModel, onnx_path: str | Path, x: np.ndarray, threads: int = 0) -> float:
    """Largest angle (degrees) between onnxruntime's and PyTorch's normals on the export's inputs ``x``.

    Parameters
    ----------
    model : learn.model.LoadedModel -- the PyTorch side, given ``x`` as inference gives it (for a ratio model, its
        colours over the model's reference: ``learn.model.model_inputs``)
    onnx_path : its export
    x : (N, 5) float32 -- the export's input (:data:`INPUT`): (u, v) pixels, filtered linear colours
        (``learn.model.model_inputs`` without a reference)
    threads : onnxruntime threads (0: the usable cores)

    Raises
    ------
    CaptureError naming ``onnx_path`` when the angle reaches :data:`~nlipscalib.core.tolerances.ONNX_PARITY_DEG`.
    """
    import torch

    from .model import model_inputs

    with torch.inference_mode():
        expected = model.net(torch.from_numpy(model_inputs(x[:, :2], x[:, 2:], model.input_reference))).numpy()
    angle = max_angle_deg(OnnxNet(onnx_path, model, threads=threads)(x), expected)
    if not angle < ONNX_PARITY_DEG:
        raise CaptureError(
            f"{onnx_path}: onnxruntime differs from PyTorch by {angle:.3f} deg (limit {ONNX_PARITY_DEG})"
        )
    return angle
