"""Staging and publishing a training's files together.

A training's files (the model, its ONNX export, curve and final checkpoint) are written into one temporary
folder beside the model (:func:`model_stage`) and published together (:func:`publish_model`), so runs into
one model path leave the files of one run, the last to finish, never a mix.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager
from pathlib import Path
from typing import TYPE_CHECKING

from ..core import atomic
from ..core.errors import ConfigError
from .checkpoint import checkpoint_path
from .onnx_fullframe import FULL_FRAME_SUFFIX

if TYPE_CHECKING:
    from ..core.claims import Owner
    from .model import LoadedModel
    from .train import TrainResult

log = logging.getLogger(__name__)


def model_file_names(out: Path) -> tuple[str, ...]:
    """The files one training writes beside the model ``out``: the model, its checkpoint, ONNX export, curve and,
    when one was there, its full-frame graph made again (MODEL.frame.onnx, ``cli.train``)."""
    frame = out.with_suffix(FULL_FRAME_SUFFIX).name
    return (out.name, checkpoint_path(out).name, out.with_suffix(".onnx").name, out.stem + "_curve.png", frame)


def export_names(out: Path) -> tuple[str, ...]:
    """The ONNX files beside the model ``out`` that inference runs (MODEL.onnx, MODEL.frame.onnx): removed first when
    a training publishes, so that a reader in between finds the new model without them, never beside them."""
    return (out.with_suffix(".onnx").name, out.with_suffix(FULL_FRAME_SUFFIX).name)


@dataclasses.dataclass(frozen=True)
class Published:
    """What :func:`publish_model` did."""

    files: list[Path]
    """The files of this training put beside the model, the model first."""
    removed: list[Path]
    """Files of those names that were there and that this training did not make (another run's, or an export of the
    model it replaced: its full-frame graph when it could not be made again), removed."""


PUBLISH_POLL_S = 0.05
"""How often a finished training checks whether another one is still publishing its files into the same place, s."""


def model_stage(out: str | Path) -> AbstractContextManager[Path]:
    """A temporary folder beside the model path ``out`` to write one training's files into, removed afterwards
    (:func:`nlipscalib.core.atomic.scratch_dir`: a killed run's is removed by the next training, a SIGTERM'd
    one removes its own). Fill it with the files of :func:`model_file_names`, then :func:`publish_model`."""
    from ..core.atomic import scratch_dir

    return scratch_dir(out)


def publish_model(stage: str | Path, out: str | Path, result: TrainResult | None = None) -> Published:
    """Put the files of one training (``stage``, from :func:`model_stage`) beside ``out``, together.

    Why: two ``nlips train`` runs into one ``--out`` with different options each wrote their .pt, .onnx and
    curve as they finished, so a .pt of one run could end up beside the .onnx of the other (which inference
    refuses as exported from another model). Now each run publishes under a claim on the model path, so the
    renames of two runs never interleave, and removes the files of :func:`model_file_names` it did not write
    (an .onnx of an earlier run when this one has none): the last run to finish leaves its files, whole, and
    nothing of another run beside them. The old .onnx and full-frame graph go first, so a reader in between finds
    the new model with no export (PyTorch is used) rather than with a stale one.

    ``result``: the training's :class:`TrainResult`; its per-epoch checkpoint is removed once its last state is
    published.
    """
    stage, out = Path(stage), Path(out)
    published, removed = [], []
    with model_files_held(out):
        for name in export_names(out):  # first: see above
            if _removed(out.parent / name) and not (stage / name).exists():  # not replaced: said by the caller
                removed.append(out.parent / name)
        for name in model_file_names(out):  # the model before its exports
            if (stage / name).exists():
                atomic.replace(stage / name, out.parent / name)  # Windows: retried while a program holds it
                published.append(out.parent / name)
            elif _removed(out.parent / name):  # another run's file, or a file of this name made before
                removed.append(out.parent / name)
        if result is not None and result.progress is not None:
            result.progress.unlink(missing_ok=True)
        return Published(published, removed)


def _removed(path: Path) -> bool:
    """Remove ``path``; whether it was there."""
    try:
        path.unlink()
    except FileNotFoundError:
        return False
    return True


@contextlib.contextmanager
def model_files_held(out: str | Path) -> Iterator[None]:
    """Hold the claim on the model path ``out`` (its own, ``.claim-MODEL.pt``) while the block runs, after another
    process's turn: what :func:`publish_model` holds for its renames and ``nlips export`` while it reads the model
    and writes its ONNX file beside it, so that neither runs in the middle of the other."""
    from ..core.claims import claim

    while True:
        with claim(out) as mine:
            if mine:
                yield
                return
        time.sleep(PUBLISH_POLL_S)  # another run is publishing or exporting: seconds at most, then it is this one's


TRAIN_HOLD = "~train"
"""Suffix of the name under which a training holds its model path for its whole run (``.claim-MODEL.pt~train``,
:func:`hold_training`): not the model's own claim, which :func:`model_files_held` takes for seconds."""


@contextlib.contextmanager
def hold_training(out: str | Path, run: dict) -> Iterator[None]:
    """Hold the model path ``out`` for the training ``run`` (:func:`.checkpoint.training_run`) while the block runs.

    Another live process training into ``out``:

    - the same training (``run``'s key: the options that decide the weights, the dataset, the validation and
      excluded presses): waited for, saying so in one line; then the block runs and finds its model (reused,
      :func:`.train.train` ``reuse``) or its progress (resumed, e.g. when the other stopped at its time limit);
    - another training: ConfigError naming what differs, at once.

    Why refuse another training rather than queue it: both cannot keep their model at one path; queued, the second
    would replace the first's model when it ends (and the user would wait to lose it), while refused the user
    trains into another --out straight away, as ``nlips solve`` and ``nlips dataset`` refuse a run of other
    settings. A killed holder's claim goes stale (core.claims): the next run takes it over and resumes its
    progress checkpoint (named by the run, :func:`.checkpoint.progress_checkpoint_path`).
    """
    from ..core.claims import claim, holder, wait_for_release

    target = Path(out).with_name(Path(out).name + TRAIN_HOLD)
    while True:
        with contextlib.ExitStack() as held:
            try:
                mine = held.enter_context(claim(target, note=run))
            except OSError as exc:
                raise _named_as(exc, target, Path(out)) from None
            if mine:
                yield
                return
        other = holder(target)
        if other is None or other.note is None:  # released or died meanwhile, or its claim being written
            time.sleep(PUBLISH_POLL_S)
            continue
        if other.note.get("key") != run["key"]:
            raise ConfigError(_trained_elsewhere(Path(out), other, run))
        log.info(
            "%s: process %d on %s is training the same model (same options and samples); waiting for it, "
            "then its model is reused",
            out,
            other.pid,
            other.host,
        )
        wait_for_release(target)


def _named_as(exc: OSError, hold: Path, out: Path) -> OSError:
    """``exc`` naming the model path ``out`` the user gave where it names its ``hold``'s claim (a read-only disk
    said "x.pt~train: Read-only file system", a name the user never gave); any other error as it is."""
    from ..core.atomic import named_target

    if exc.filename is None or named_target(exc.filename) != hold:
        return exc
    return OSError(exc.errno, exc.strerror, str(out))  # the subclass of its errno, as the original


def _trained_elsewhere(out: Path, other: Owner, run: dict) -> str:
    theirs = other.note or {}
    changed = []
    for k, v in run.get("options", {}).items():
        was = (theirs.get("options") or {}).get(k)
        if was != v:
            changed.append(f"{k} {was} (this run: {v})")
    for k in ("dataset", "val_presses", "excluded_presses"):
        if theirs.get(k) != run.get(k):
            changed.append(f"{k} {theirs.get(k)} (this run: {run.get(k)})")
    return (
        f"{out}: process {other.pid} on {other.host} is training another model into it "
        f"({', '.join(changed) or 'other settings'}); left to it: train into another --out, or run again once it "
        "has ended (its model is then replaced)"
    )


def clean_interrupted_writes(out: Path, *names: str) -> None:
    """Remove temporaries of killed writes of the model, its checkpoint, ONNX file and curve, or of the files
    ``names`` (a run's per-epoch checkpoint) beside ``out`` (owner gone only).

    Every file here is written atomically under an owner-tagged temporary name (core.atomic); a SIGKILL
    in the middle of a write leaves that temporary, which no later write would otherwise remove.
    """
    from ..core.atomic import clean_interrupted, removed_leftover

    for name in names or model_file_names(out):
        for gone in clean_interrupted(out.parent, item=name):
            log.warning("%s: removed %s", gone, removed_leftover(gone))


def reusable_model(out: str | Path, with_onnx: bool) -> tuple[LoadedModel | None, str | None]:
    """The model at ``out``, read in full and checked (None when there is none, or it cannot be reused as it is),
    and why it cannot be reused as it is (the model, or with ``with_onnx`` its ONNX export beside it, when there),
    in one line naming the file, or None.

    Why: a finished training is reused on the strength of the checkpoint published with its model
    (:func:`.checkpoint.published_state`), which says nothing of the model file itself. A model file or export
    left empty or cut short (a power cut soon after the files were published, before the disk had them; a copy
    interrupted) was reused as it was, "reused, trained before ...", exit 0, and only ``nlips infer`` found it
    damaged, each run of ``nlips train`` reusing it again. Read here, such a file is made again from the
    checkpoint instead (no epoch trained again). The model is read in full (kilobytes to a few megabytes), once:
    the reuse takes its digest and record from it (it was read a second time, ~0.1 s of a kept re-run)."""
    from ..core.errors import CaptureError
    from .model import load_model
    from .onnx_export import check_export

    out = Path(out)
    if not out.is_file():
        return None, None
    onnx_path = out.with_suffix(".onnx")
    try:
        model = load_model(out)
        if with_onnx and onnx_path.is_file():
            check_export(onnx_path, model)
    except CaptureError as exc:
        return None, str(exc)
    return model, None
