"""NLiPsNet to ONNX (torch.onnx) and inference with onnxruntime.

The ONNX graph takes the same raw (N, 5) input as the PyTorch model (normalisation is inside the
graph) and returns (N, 3) unit normals. The sensor description and the model file's digest travel
in the ONNX metadata, so an .onnx file is never used with another model's reference.
"""

from __future__ import annotations

import hashlib
import json
import warnings
from pathlib import Path

import numpy as np

from ..errors import CaptureError, require

OPSET = 17


def file_digest(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16]


def export_onnx(model, out) -> Path:
    """Write ``model`` (a LoadedModel) as an ONNX file ``out`` atomically; returns its path."""
    import io

    import torch

    from ..core.atomic import write_bytes

    onnx = require("onnx", "onnx", "ONNX export")
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the TorchScript exporter is deprecated but needs no onnxscript
        torch.onnx.export(
            model.net.eval(),
            (torch.zeros(8, 5),),
            buf,
            input_names=["uvrgb"],
            output_names=["normal"],
            dynamic_axes={"uvrgb": {0: "pixels"}, "normal": {0: "pixels"}},
            opset_version=OPSET,
            dynamo=False,
        )
    proto = onnx.load_from_string(buf.getvalue())
    meta = {"sensor": json.dumps(model.sensor), "model_digest": file_digest(model.path), "hidden": str(model.hidden)}
    for key, value in meta.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    return write_bytes(out, proto.SerializeToString())


class OnnxNet:
    """onnxruntime session of an exported NLiPsNet: ``(N, 5) float32 -> (N, 3)`` unit normals."""

    def __init__(self, path, model=None, threads: int = 0):
        ort = require("onnxruntime", "onnxruntime", "ONNX inference")
        path = Path(path)
        if not path.is_file():
            raise CaptureError(f"{path}: ONNX model is missing (export it with `nlips train` or `nlips export`)")
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for bad files
            raise CaptureError(f"{path}: not a readable ONNX model ({type(exc).__name__})") from None
        props = self.session.get_modelmeta().custom_metadata_map
        if model is not None and props.get("model_digest") != file_digest(model.path):
            raise CaptureError(f"{path}: exported from another model than {model.path}; export it again")
        self.path = path

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"uvrgb": np.ascontiguousarray(x, np.float32)})[0]


def max_angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Largest angle between corresponding unit vectors of (N, 3) arrays, degrees."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    # atan2(|a x b|, a . b) stays accurate for tiny angles, where arccos of a rounded cosine does not
    ang = np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, -1))
    return float(np.degrees(ang).max()) if len(ang) else 0.0
