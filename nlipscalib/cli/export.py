"""``nlips export MODEL.pt``: the ONNX file of a trained NLiPsNet (what ``nlips train`` writes unless --no-onnx).

For a model trained with ``--no-onnx``, an ONNX file lost or left stale beside its model (a model copied without
it, or retrained), or a copy elsewhere (``--out``); checked against PyTorch like ``nlips train``'s export.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # named in hints only: torch is imported when a model is exported
    from ..learn.model import LoadedModel

CHECK_PIXELS = 20000
"""At most this many of the reference frame's gel pixels check the export."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export",
        help="write the ONNX file of a trained NLiPsNet model (for --backend onnx / onnx-int8)",
        description="Export a model file from `nlips train` to ONNX (by default MODEL.onnx beside it, where `nlips "
        "infer` and `nlips live` look for it) and check that onnxruntime gives PyTorch's normals (within 0.1 deg) "
        "on the model's reference frame, its colours as they are and 10 % darker and brighter.",
    )
    p.add_argument("model", help="model file (.pt) from `nlips train`")
    p.add_argument(
        "--out", help="ONNX file to write (default: MODEL.onnx beside the model, MODEL.frame.onnx with --full-frame)"
    )
    p.add_argument(
        "--full-frame",
        action="store_true",
        help="write instead a standalone graph of the whole frame for programs without nlipscalib: the tri-colour "
        "frame as the camera stores it (H, W, 3 uint16) in, the normal map (NaN off the gel) and the gel mask out "
        "(tone curve, dark frame, prefilter and network inside; checked against the PyTorch full-frame path)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from contextlib import nullcontext
    from pathlib import Path

    from ..core.atomic import check_writable
    from ..core.errors import CaptureError, ConfigError
    from ..learn.model import load_model
    from ..learn.onnx_export import export_onnx
    from ..learn.onnx_fullframe import FULL_FRAME_SUFFIX
    from ..learn.publish import model_files_held
    from ..progress import print_result, say
    from .folders import names_a_folder

    suffix = FULL_FRAME_SUFFIX if args.full_frame else ".onnx"
    if args.out and names_a_folder(args.out):  # `--out x.onnx/` wrote the file x.onnx (pathlib drops the slash)
        example = Path(args.out) / Path(args.model).with_suffix(suffix).name
        raise ConfigError(f"--out {args.out}: a folder; give the ONNX file to write (e.g. {example})")
    out = Path(args.out) if args.out else Path(args.model).with_suffix(suffix)
    if out.suffix.lower() != ".onnx":
        raise ConfigError(f"--out {out}: the ONNX file must end in .onnx")
    check_writable(out.parent)  # a read-only disk: one line now, not after loading the model and exporting it
    if args.full_frame:
        if out.resolve() == Path(args.model).resolve().with_suffix(".onnx"):  # `nlips infer` would find another graph
            raise ConfigError(
                f"--out {out}: the per-pixel export's name, which `nlips infer` and `nlips live` read; give another "
                f"(default {Path(args.model).with_suffix(FULL_FRAME_SUFFIX)})"
            )
        return _full_frame(args.model, out)
    beside = out.resolve() == Path(args.model).resolve().with_suffix(".onnx")
    # beside the model, its ONNX file is one of a training's files: read and written while no training publishes
    # its own (learn.publish), or an export of the model it replaced would land beside the new one
    with model_files_held(args.model) if beside else nullcontext():
        model = load_model(args.model)
        if model.table is not None:  # `nlips lut`'s: NumPy and SciPy run it, there is no network to export
            raise CaptureError(
                f"{args.model}: a lookup table (`nlips lut`), not a network: nothing to export; `nlips infer` runs it "
                "as it is"
            )
        angles = []  # checked on the written file before it takes its name: a failed or interrupted check publishes
        # none
        path = export_onnx(model, out, check=lambda tmp: angles.append(parity_deg(model, tmp)))
    angle = angles[0]
    used = "`nlips infer` and `nlips live` use it by default" if beside else _elsewhere(model.path, path)
    print_result(path)  # stdout: the ONNX file alone (scripts); its check on stderr
    say(f"{path}: onnxruntime vs PyTorch max angular difference {angle:.4f} deg; {used}")
    return 0


def _full_frame(model_path: str, out: Path) -> int:
    """``--full-frame``: the standalone graph of the whole frame (``learn.onnx_fullframe``), checked against the
    PyTorch full-frame path before it takes its name. Beside the model (MODEL.frame.onnx, which `nlips infer
    --full-frame` runs and `nlips train` makes again when it replaces the model) it is one of a training's files:
    read and written under the model's claim (``learn.publish``), as the per-pixel export, so that the graph of a
    model a training replaced meanwhile never lands beside the new one."""
    from contextlib import nullcontext

    from ..learn.model import load_model
    from ..learn.onnx_fullframe import export_full_frame, frame_graph_path
    from ..learn.publish import model_files_held
    from ..progress import print_result, say

    beside = out.resolve() == frame_graph_path(Path(model_path).resolve())
    with model_files_held(model_path) if beside else nullcontext():
        path, angle = export_full_frame(load_model(model_path), out)  # a model it cannot hold: one line, no file
    print_result(path)
    where = "" if beside else f"; {_elsewhere(model_path, path, full_frame=True)}"
    say(
        f"{path}: onnxruntime's normal map vs PyTorch's full-frame path: max angular difference {angle:.4f} deg on the "
        "gel (the reference frame, 10 % darker and brighter, and with a synthetic contact); input 'tricolor' "
        "(H, W, 3) uint16 as the camera stores it, outputs 'normals' (NaN off the gel) and 'gel' (docs/formats.md in "
        f"the nlipscalib source distribution or repository){where}"
    )
    return 0


def _elsewhere(model_path: str | Path, path: Path, full_frame: bool = False) -> str:
    """What the export's line says of an ONNX file written elsewhere than beside its model: how `nlips infer` and
    `nlips live` run it (``--onnx``), since ``--backend auto`` looks only beside the model."""
    from ..core.shell_words import shell_word
    from ..learn.exports import beside_export

    full = " --full-frame" if full_frame else ""
    return (
        f"elsewhere: `nlips infer {shell_word(model_path)} ...{full} --onnx {shell_word(path)}` runs it (as `nlips "
        f"live` does), --backend auto looks only for {beside_export(model_path, full_frame)}"
    )


def parity_deg(model: LoadedModel, onnx_path: Path) -> float:
    """Largest angle (degrees) between onnxruntime's and PyTorch's normals on the model's reference gel pixels, their
    colours as they are and 10 % darker and brighter (a contact changes them): the linear colours the export takes
    (a ratio model's graph divides them by its reference, PyTorch is given them divided: ``checked_parity``);
    CaptureError beyond the limit."""
    import numpy as np

    from ..learn.model import model_inputs
    from ..learn.onnx_export import checked_parity

    ref = model.reference
    rows, cols = np.nonzero(ref["valid"].astype(bool))
    pick = np.linspace(0, len(rows) - 1, min(len(rows), CHECK_PIXELS)).astype(int) if len(rows) else []
    rows, cols = rows[pick], cols[pick]
    pixel = np.stack([cols, rows], axis=1)  # (u, v) = (column, row)
    rgb = ref["tricolor"][rows, cols].astype(np.float32)
    x = np.concatenate([model_inputs(pixel, rgb * s) for s in (0.9, 1.0, 1.1)])
    return checked_parity(model, onnx_path, x, threads=1)
