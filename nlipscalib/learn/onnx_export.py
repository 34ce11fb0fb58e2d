"""NLiPsNet to ONNX (written with onnx.helper from the folded weights) and inference with onnxruntime.

The ONNX graph takes the same raw (N, 5) input as the PyTorch model and returns (N, 3) unit normals.
It is the inference form of the network (:func:`nlipscalib.learn.model.fused_net`): input
normalisation and BatchNorm folded into the linear layers, so the graph is Gemm-ReLU-...-Gemm. The
sensor description and the model file's digest travel in the ONNX metadata, so an .onnx file is
never used with another model's reference.
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.cpus import usable_cores
from ..core.errors import CaptureError, require
from ..core.metrics import angle_deg
from ..core.tolerances import ONNX_PARITY_DEG

if TYPE_CHECKING:  # named in hints only: the model module (and torch) are imported where an export needs them
    from .model import LoadedModel

OPSET = 17
IR_VERSION = 8
"""ONNX IR version of the export: the oldest that carries opset 17 (onnxruntime >= 1.13 reads it)."""


def export_hint(model_path: str | Path, again: bool = False) -> str:
    """How to get the ONNX file of the model at ``model_path``, for the errors that find it missing or stale
    (``again``: damaged, so it is written again)."""
    if again:
        return f"`nlips export {model_path}` writes it again, or use --backend torch"
    return f"`nlips export {model_path}` writes it, as `nlips train` does unless --no-onnx; or use --backend torch"


def bytes_digest(data: bytes) -> str:
    """The digest a model file's bytes are known by: the first 16 hex digits of their SHA-256 (an ONNX export
    records its model's, and inference compares it with the model it is run with)."""
    return hashlib.sha256(data).hexdigest()[:16]


def file_digest(path: str | Path) -> str:
    return bytes_digest(Path(path).read_bytes())


def export_onnx(model: LoadedModel, out: str | Path, check: Callable[[Path], object] | None = None) -> Path:
    """Write ``model`` (a LoadedModel) as an ONNX file ``out`` atomically; returns its path.

    ``check(path)``, when given, runs on the written file before it takes its name (e.g. the parity with
    PyTorch, :func:`checked_parity`): an export that fails it, or is interrupted during it, is never published
    (an interrupted ``nlips export`` used to leave a file whose check never ran, which ``nlips infer`` then used).

    The graph is written directly from the folded weights (:func:`nlipscalib.learn.model.fused_net`):
    per layer a MatMul named ``layer<k>`` and an Add (onnxruntime fuses the pair into one Gemm), ReLU
    between layers, then the division by the L2 norm (at least 1e-8). Named layers let the int8
    variant leave chosen layers in float (:func:`quantized_int8`).
    """
    import torch

    from ..core.atomic import write_by_name, write_bytes
    from .model import fused_net

    onnx = require("onnx", "onnx", "ONNX export")
    helper, numpy_helper = onnx.helper, onnx.numpy_helper
    linear = [m for m in fused_net(model.net.eval()).mlp if isinstance(m, torch.nn.Linear)]
    nodes, weights, current = [], [], "uvrgb"
    for k, layer in enumerate(linear):
        weights.append(numpy_helper.from_array(layer.weight.detach().numpy().T.copy(), f"W{k}"))
        weights.append(numpy_helper.from_array(layer.bias.detach().numpy().copy(), f"b{k}"))
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
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", OPSET)], producer_name="nlipscalib")
    proto.ir_version = IR_VERSION  # the installed onnx would write its newest, which older onnxruntimes refuse
    onnx.checker.check_model(proto)
    meta = {"sensor": json.dumps(model.sensor), "model_digest": model.digest, "hidden": json.dumps(list(model.hidden))}
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
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


def quantized_int8(path: str | Path) -> bytes:
    """The ONNX model at ``path`` with dynamic int8 quantisation (onnxruntime.quantization.quantize_dynamic).

    Weights int8 per output channel, activations quantised per call. The first layer stays float: its
    inputs (pixel coordinates in hundreds, linear colours below 1) would share one 8-bit scale and
    the colours would be lost. The last layer (3 outputs, little work) stays float too. Costs about
    0.05 deg mean (0.3 deg max) against the float network; measured in benchmarks/RESULTS.md.
    """
    import tempfile

    require("onnx", "onnx", "int8 quantisation")
    quantization = require("onnxruntime.quantization", "onnxruntime", "int8 quantisation")
    onnx = require("onnx", "onnx", "int8 quantisation")
    layers = [n.name for n in onnx.load(str(path), load_external_data=False).graph.node if n.op_type == "MatMul"]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "int8.onnx"
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
            )
        finally:
            logging.getLogger().disabled = was
        return out.read_bytes()


class OnnxNet:
    """onnxruntime session of an exported NLiPsNet: ``(N, 5) float32 -> (N, 3)`` unit normals.

    With ``threads`` > 1 the pixels are split into that many equal slices run concurrently, each on one
    onnxruntime thread: for these narrow layers that uses the cores far better than onnxruntime's own
    intra-op split of one large call (measured in benchmarks/RESULTS.md). The session does not spin
    between calls, so the other stages of a frame get the cores.
    """

    MIN_SLICE = 4096
    """Fewest pixels worth a slice of their own (below, thread hand-over costs more than it saves)."""

    def __init__(self, path: str | Path, model: LoadedModel | None = None, threads: int = 0, int8: bool = False):
        ort = require("onnxruntime", "onnxruntime", "ONNX inference")
        path = Path(path)
        if not path.is_file():
            raise CaptureError(f"{path}: ONNX model is missing ({export_hint(model.path if model else 'MODEL.pt')})")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise CaptureError(
                f"{path}: not a readable ONNX model ({type(exc).__name__}): "
                f"{export_hint(model.path if model else 'MODEL.pt', again=True)}"
            ) from None
        props = self.session.get_modelmeta().custom_metadata_map
        if model is not None and props.get("model_digest") != model.digest:
            raise CaptureError(
                f"{path}: exported from another model than {model.path}; export it again ({export_hint(model.path)})"
            )
        if int8:  # the checked float file, quantised in memory
            self.session = ort.InferenceSession(quantized_int8(path), opts, providers=["CPUExecutionProvider"])
        self.path = path
        self.int8 = int8
        self.threads = max(1, int(threads) if threads else usable_cores())
        self._pool = ThreadPoolExecutor(self.threads - 1) if self.threads > 1 else None

    def _run(self, x: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"uvrgb": x})[0]

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
    """Largest angle (degrees) between onnxruntime's and PyTorch's normals on network inputs ``x``.

    Parameters
    ----------
    model : learn.model.LoadedModel -- the PyTorch side
    onnx_path : its export
    x : (N, 5) float32 -- normalised network inputs (``learn.model.model_inputs``)
    threads : onnxruntime threads (0: the usable cores)

    Raises
    ------
    CaptureError naming ``onnx_path`` when the angle reaches :data:`~nlipscalib.core.tolerances.ONNX_PARITY_DEG`.
    """
    import torch

    with torch.inference_mode():
        expected = model.net(torch.from_numpy(x)).numpy()
    angle = max_angle_deg(OnnxNet(onnx_path, model, threads=threads)(x), expected)
    if not angle < ONNX_PARITY_DEG:
        raise CaptureError(
            f"{onnx_path}: onnxruntime differs from PyTorch by {angle:.3f} deg (limit {ONNX_PARITY_DEG})"
        )
    return angle
