"""The ONNX files beside a model file, which ``nlips infer`` and ``nlips live`` run by default (``--backend auto``):
MODEL.onnx (``nlips train``, ``nlips export MODEL``) and MODEL.frame.onnx (``nlips export MODEL --full-frame``), and
whether each is the model's own (its metadata's ``model_digest``) or left from before the model was trained again, or
a ratio model's MODEL.onnx of before 2026-12-07 (:func:`why_stale`); and what ``nlips train`` makes current beside a
model it reuses (:func:`not_current`). An export written elsewhere (``nlips export MODEL --out F``) is not looked for:
``--onnx F`` names it (``learn.infer.onnx_backend``), and it is checked, never skipped.

Why auto skips one of another model where ``--backend onnx`` refuses it: auto means the best runtime available, and a
graph of the model it replaced is not available for this model; PyTorch runs the same network (the normals within
``ONNX_PARITY_DEG``), so the run goes on with one warning naming the file and the command that makes it again. Asked
for by name, the runtime the user chose cannot run: refused, as before. Only the recorded metadata is read here (a
few hundred bytes, no model loaded); a file that records this model's digest is checked whole before it runs
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


def why_stale(export: str | Path, digest: str, full_frame: bool = False) -> str | None:
    """Why ``--backend auto`` skips the ONNX file ``export`` beside a model whose digest is ``digest`` (the model
    file's, ``onnx_export.bytes_digest``), in words (``{model}`` standing for the model's path, for ``str.format``:
    the same words name it in `nlips infer`'s warning and `nlips train`'s), or None when it runs it (its check then
    says if it cannot).

    Two reasons, both from its metadata alone (:func:`.onnx_export.recorded_metadata`): it records another model's
    digest (left from before the model was trained again), or, a per-pixel export (not ``full_frame``), it is a ratio
    model's export of before 2026-12-07, whose graph took the ratios (:func:`.onnx_export.ratio_export_of_before`):
    run, it would be refused, and PyTorch runs the same network. A file that records no digest or cannot be read is
    left to its check (None)."""
    from .onnx_export import RATIO_BEFORE, ratio_export_of_before, recorded_metadata

    metadata = recorded_metadata(export)
    recorded = metadata.get("model_digest")
    if recorded is None:
        return None
    if recorded != digest:
        return "exported from another model than {model} (left from before it was trained again?)"
    if not full_frame and ratio_export_of_before(metadata):
        return RATIO_BEFORE
    return None


def not_current(export: str | Path, digest: str, full_frame: bool = False) -> str | None:
    """Why the ONNX file ``export`` beside a model whose digest is ``digest`` is not that model's current export, in
    words (``{model}`` standing for the model's path), or None when it is (or is not there).

    As :func:`why_stale`, and a file that records no digest too (cut short, or not written by nlipscalib): what
    ``nlips train`` makes again when it reuses the model (``cli.train``), from a few hundred bytes of the file."""
    from .onnx_export import recorded_digest

    if not Path(export).is_file():
        return None
    if recorded_digest(export) is None:
        return "records no model digest (cut short, or not written by `nlips export`)"
    return why_stale(export, digest, full_frame)


def remake_command(model_path: str | Path, full_frame: bool = False) -> str:
    """The command that writes the export beside ``model_path`` again."""
    return f"nlips export {shell_word(model_path)}{' --full-frame' if full_frame else ''}"


def skipped_warning(model_path: str | Path, why: str, full_frame: bool = False) -> str:
    """The line auto says when it skips the export beside ``model_path`` (``why``: :func:`why_stale`'s words)."""
    export = beside_export(model_path, full_frame)
    return (
        f"{export}: {why.format(model=model_path)}: skipped, PyTorch runs the network; "
        f"`{remake_command(model_path, full_frame)}` writes it again"
    )
