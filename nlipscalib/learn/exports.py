"""The ONNX files beside a model file, which ``nlips infer`` and ``nlips live`` run by default (``--backend auto``):
MODEL.onnx (``nlips train``, ``nlips export MODEL``) and MODEL.frame.onnx (``nlips export MODEL --full-frame``), and
whether each is the model's own (its metadata's ``model_digest``) or left from before the model was trained again.

Why auto skips one of another model where ``--backend onnx`` refuses it: auto means the best runtime available, and a
graph of the model it replaced is not available for this model; PyTorch runs the same network (the normals within
``ONNX_PARITY_DEG``), so the run goes on with one warning naming the file and the command that makes it again. Asked
for by name, the runtime the user chose cannot run: refused, as before. Only the recorded digest is compared here (a
file read, no model loaded); a file that records this model's digest is checked whole before it runs
(``onnx_export.check_export``, ``onnx_fullframe.check_full_frame``), and a damaged or foreign one is refused then.
"""

from __future__ import annotations

from pathlib import Path

from ..core.shell_words import shell_word


def beside_export(model_path: str | Path, full_frame: bool = False) -> Path:
    """The ONNX file auto runs beside the model file ``model_path``: MODEL.frame.onnx with ``full_frame``, else
    MODEL.onnx."""
    from .onnx_fullframe import frame_graph_path

    return frame_graph_path(model_path) if full_frame else Path(model_path).with_suffix(".onnx")


def of_another_model(export: str | Path, digest: str) -> bool:
    """Whether the ONNX file ``export`` records another model's digest than ``digest`` (the model file's,
    ``onnx_export.bytes_digest``): left from before the model was trained again. False when it records none or
    cannot be read (its check says why when it runs)."""
    from .onnx_export import recorded_digest

    recorded = recorded_digest(export)
    return recorded is not None and recorded != digest


def remake_command(model_path: str | Path, full_frame: bool = False) -> str:
    """The command that writes the export beside ``model_path`` again."""
    return f"nlips export {shell_word(model_path)}{' --full-frame' if full_frame else ''}"


def skipped_warning(model_path: str | Path, full_frame: bool = False) -> str:
    """The line auto says when it skips the export beside ``model_path`` for being another model's."""
    export = beside_export(model_path, full_frame)
    return (
        f"{export}: exported from another model than {model_path} (left from before it was trained again?): skipped, "
        f"PyTorch runs the network; `{remake_command(model_path, full_frame)}` writes it again"
    )
