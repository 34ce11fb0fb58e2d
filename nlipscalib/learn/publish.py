"""Staging and publishing a training's files together.

A training's files (the model, its ONNX export, curve and final checkpoint) are written into one temporary
folder beside the model (:func:`model_stage`) and published together (:func:`publish_model`), so runs into
one model path leave the files of one run, the last to finish, never a mix.
"""

from __future__ import annotations

import logging
import os
import time
from contextlib import AbstractContextManager
from pathlib import Path
from typing import TYPE_CHECKING

from .checkpoint import checkpoint_path

if TYPE_CHECKING:
    from .train import TrainResult

log = logging.getLogger(__name__)


def model_file_names(out: Path) -> tuple[str, ...]:
    """The files one training writes beside the model ``out``: the model, its checkpoint, ONNX export and curve."""
    return (out.name, checkpoint_path(out).name, out.with_suffix(".onnx").name, out.stem + "_curve.png")


PUBLISH_POLL_S = 0.05
"""How often a finished training checks whether another one is still publishing its files into the same place, s."""


def model_stage(out: str | Path) -> AbstractContextManager[Path]:
    """A temporary folder beside the model path ``out`` to write one training's files into, removed afterwards
    (:func:`nlipscalib.core.atomic.scratch_dir`: a killed run's is removed by the next training, a SIGTERM'd
    one removes its own). Fill it with the files of :func:`model_file_names`, then :func:`publish_model`."""
    from ..core.atomic import scratch_dir

    return scratch_dir(out)


def publish_model(stage: str | Path, out: str | Path, result: TrainResult | None = None) -> list[Path]:
    """Put the files of one training (``stage``, from :func:`model_stage`) beside ``out``, together.

    Why: two ``nlips train`` runs into one ``--out`` with different options each wrote their .pt, .onnx and
    curve as they finished, so a .pt of one run could end up beside the .onnx of the other (which inference
    refuses as exported from another model). Now each run publishes under a claim on the model path, so the
    renames of two runs never interleave, and removes the files of :func:`model_file_names` it did not write
    (an .onnx of an earlier run when this one has none): the last run to finish leaves its files, whole, and
    nothing of another run beside them. The old .onnx goes first, so a reader in between finds the new model
    with no export (PyTorch is used) rather than with a stale one.

    ``result``: the training's :class:`TrainResult`; its per-epoch checkpoint is removed once its last state is
    published.

    Returns the published paths.
    """
    from ..core.claims import claim

    stage, out = Path(stage), Path(out)
    while True:
        with claim(out) as mine:
            if mine:
                out.with_suffix(".onnx").unlink(missing_ok=True)  # first: see above
                published = []
                for name in model_file_names(out):  # the model before its export
                    if (stage / name).exists():
                        os.replace(stage / name, out.parent / name)
                        published.append(out.parent / name)
                    else:  # another run's file, or a file of this name made before
                        (out.parent / name).unlink(missing_ok=True)
                if result is not None and result.progress is not None:
                    result.progress.unlink(missing_ok=True)
                return published
        time.sleep(PUBLISH_POLL_S)  # another run is publishing: a few renames, then it is this run's turn


def clean_interrupted_writes(out: Path, *names: str) -> None:
    """Remove temporaries of killed writes of the model, its checkpoint, ONNX file and curve, or of the files
    ``names`` (a run's per-epoch checkpoint) beside ``out`` (owner gone only).

    Every file here is written atomically under an owner-tagged temporary name (core.atomic); a SIGKILL
    in the middle of a write leaves that temporary, which no later write would otherwise remove.
    """
    from ..core.atomic import clean_interrupted

    for name in names or model_file_names(out):
        for gone in clean_interrupted(out.parent, item=name):
            log.warning("%s: removed an interrupted write", gone)
