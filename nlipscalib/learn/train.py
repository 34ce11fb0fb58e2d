"""Training NLiPsNet on a calibration dataset: split by press, cosine loss, early stopping on validation AAE.

Resumable: after every epoch the state (weights, optimiser, history, best weights) goes into a checkpoint
beside the model named by the run (``MODEL.<run>.checkpoint.pt``, :func:`progress_checkpoint_path`: the options
and the samples), so trainings of other runs into the same place never overwrite each other's progress; when the
run ends, its last state is published as ``MODEL.checkpoint.pt`` with the model. A run with the same options on
the same training and validation samples continues from its own checkpoint, or from the published one. Any other
run (other options, another dataset, other presses held out for validation or excluded) trains afresh, saying why.

A training's files (the model, its ONNX export, curve and final checkpoint) are written into one temporary
folder beside the model (:func:`model_stage`) and published together (:func:`publish_model`), so runs into
one model path leave the files of one run, the last to finish, never a mix.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import io
import logging
import math
import os
import time
from pathlib import Path

import numpy as np

from ..errors import ConfigError
from .dataset import INDEX_FILE, CalibrationDataset
from .model import (
    PAPER_DROPOUT,
    PAPER_HIDDEN,
    build_net,
    cosine_loss,
    model_inputs,
    save_model,
    set_colour_normalisation,
)

log = logging.getLogger(__name__)
CHECKPOINT_FILE = "checkpoint.pt"


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How to train NLiPsNet."""

    hidden: tuple[int, ...] = PAPER_HIDDEN
    """Hidden layer widths (paper: 256, 256, 128; a fast variant: 64, 64, 64)."""
    dropout: float = PAPER_DROPOUT
    """Dropout after every hidden layer (paper: 0.2)."""
    labels: str = "nlips"
    """Training targets: "nlips" (the NLiPs normals, the calibration) or "true" (the twin's true normals,
    the upper bound)."""
    val_fraction: float = 0.2
    """Fraction of the presses held out for validation (at least one press)."""
    max_epochs: int = 200
    """Upper limit of epochs."""
    patience: int = 8
    """Stop when the validation AAE has not improved for this many epochs."""
    batch_size: int = 1024
    """Samples per optimisation step."""
    lr: float = 2e-3
    """Adam learning rate at the start (then set by ``schedule``)."""
    schedule: str = "plateau"
    """Learning-rate schedule. "plateau": multiply the rate by ``lr_factor`` after ``lr_patience`` epochs
    without a better validation AAE, down to 1 % of ``lr``. At a fixed rate the validation AAE of the paper's
    net on 50 full-size presses scattered by 0.4 deg from epoch to epoch and early stopping kept a lucky
    epoch; lowering the rate when it stalls kept a better epoch, in fewer epochs (benchmarks/RESULTS.md; the
    scatter, from 10 validation presses, stays). "cosine": annealed to 5 % over ``max_epochs`` (the earlier
    default; with early stopping after ~25 of 200 epochs it stays near ``lr``)."""
    lr_patience: int = 2
    """Epochs without a better validation AAE before the plateau schedule lowers the rate."""
    lr_factor: float = 0.3
    """Factor the plateau schedule lowers the rate by."""
    seed: int = 0
    """Seed of the split, the initial weights, dropout and shuffling."""
    max_seconds: float = 0.0
    """Stop after this much training time (0: no limit)."""
    threads: int = 1
    """CPU threads for PyTorch. 1 here, for experiment workers that share a machine; ``nlips train`` passes
    every core the process may use (two threads make a step of the paper's net ~20 % faster on 2 cores).
    Not part of what a checkpoint must match to be resumed."""

    def __post_init__(self):
        # every message starts with the field's name: `nlips train` names its option instead (cli/train.py)
        if self.labels not in ("nlips", "true"):
            raise ConfigError(f"labels must be 'nlips' or 'true', got {self.labels!r}")
        if not self.hidden or any(not _is_int(h) or h < 1 for h in self.hidden):
            raise ConfigError(f"hidden must list positive layer widths, got {self.hidden}")
        if not 0 <= self.dropout < 1:
            raise ConfigError(f"dropout must be in [0, 1), got {self.dropout}")
        for name, minimum in (("max_epochs", 1), ("patience", 0), ("batch_size", 1), ("seed", 0), ("threads", 1)):
            value = getattr(self, name)
            if not _is_int(value) or value < minimum:
                raise ConfigError(f"{name} must be an integer >= {minimum}, got {value!r}")
        if not (isinstance(self.lr, (int, float)) and math.isfinite(self.lr) and self.lr > 0):
            raise ConfigError(f"lr must be a finite number > 0, got {self.lr!r}")
        if not (isinstance(self.max_seconds, (int, float)) and self.max_seconds >= 0):
            raise ConfigError(f"max_seconds must be >= 0 (0: no limit), got {self.max_seconds!r}")
        if not 0 < self.val_fraction < 1:
            raise ConfigError(f"val_fraction must be in (0, 1), got {self.val_fraction}")
        if self.schedule not in ("plateau", "cosine"):
            raise ConfigError(f"schedule must be 'plateau' or 'cosine', got {self.schedule!r}")
        if self.lr_patience < 0 or not 0 < self.lr_factor < 1:
            raise ConfigError(
                f"lr_patience must be >= 0 and lr_factor in (0, 1), got {self.lr_patience}, {self.lr_factor}"
            )


def _is_int(value) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def split_by_press(names, val_fraction: float, seed: int, val_names=None) -> tuple[list[str], list[str]]:
    """Training and validation presses: no press has samples on both sides.

    ``val_names`` chooses the validation presses explicitly; otherwise a seeded random
    ``val_fraction`` of them (at least one, leaving at least one for training).
    """
    names = list(names)
    if len(names) < 2:
        raise ConfigError(f"training needs at least 2 presses (one to validate on), got {len(names)}")
    if val_names:
        unknown = sorted(set(val_names) - set(names))
        if unknown:
            raise ConfigError(f"validation presses {unknown} are not in the dataset")
        val = [n for n in names if n in set(val_names)]
    else:
        k = min(max(1, round(val_fraction * len(names))), len(names) - 1)
        rng = np.random.default_rng(seed)
        val = sorted(rng.choice(names, size=k, replace=False).tolist())
    train = [n for n in names if n not in set(val)]
    if not train:
        raise ConfigError("no training presses left after holding out the validation presses")
    return train, val


def training_arrays(data: dict, labels: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inputs (N, 5), targets (N, 3), contact (N,)) of the samples that have a finite label."""
    target = data["normal"] if labels == "nlips" else data["true_normal"]
    keep = np.all(np.isfinite(target), -1)
    return model_inputs(data["pixel"][keep], data["rgb"][keep]), target[keep], data["contact"][keep]


@dataclasses.dataclass
class TrainResult:
    model_path: Path
    history: list
    """One dict per epoch: epoch, train_loss, val_aae_deg, val_contact_aae_deg, seconds."""
    best_epoch: int
    train_presses: list
    val_presses: list
    progress: Path | None = None
    """This run's per-epoch checkpoint while its files wait in a stage: removed by :func:`publish_model`."""


def train(
    dataset: CalibrationDataset,
    cfg: TrainConfig,
    out,
    val_names=None,
    exclude=(),
    progress: bool = True,
    stage: Path | None = None,
) -> TrainResult:
    """Train NLiPsNet on ``dataset`` and write ``out`` (the model file) and ``checkpoint.pt`` beside it.

    Parameters
    ----------
    dataset : CalibrationDataset
    cfg : TrainConfig
    out : path of the model file (.pt)
    val_names : optional explicit validation presses
    exclude : presses kept out of training and validation (a test set)
    stage : folder from :func:`model_stage`, optional
        Write the model and a copy of the final checkpoint there, under their names beside ``out``, for
        :func:`publish_model` to put in place with the other files of this run. The checkpoint of every epoch
        still goes beside ``out`` (what an interrupted run resumes from).
    """
    import torch

    out = Path(out)
    _clean_interrupted_writes(out)
    train_names, val_names = _presses(dataset, cfg, val_names, exclude)
    reference = dataset.reference()  # checked now, not after the whole training (the model file carries it)
    x_tr, y_tr, c_tr = training_arrays(dataset.arrays(train_names), cfg.labels)
    x_va, y_va, c_va = training_arrays(dataset.arrays(val_names), cfg.labels)
    if len(x_tr) < 2 or len(x_va) < 1:
        raise ConfigError(f"{dataset.folder}: too few labelled samples to train ({len(x_tr)} train, {len(x_va)} val)")
    if not (c_tr.any() or c_va.any()):
        raise ConfigError(no_contact_error(dataset, len(train_names) + len(val_names), len(x_tr) + len(x_va)))
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    cam = dataset.sensor["camera"]
    net = build_net(cfg.hidden, cfg.dropout, cam["width"], cam["height"])
    set_colour_normalisation(net, x_tr[:, 2:])
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    sched = _scheduler(opt, cfg)
    data_key = _data_key(x_tr, y_tr, x_va, y_va, c_va)
    progress_path = progress_checkpoint_path(out, cfg, data_key)
    _clean_interrupted_writes(out, progress_path.name)
    state = _resume(out, progress_path, cfg, data_key, net, opt, sched)
    if out.is_file() and not _published_by(out, cfg, data_key):  # a better model would go unnoticed otherwise
        log.warning(
            "%s: a model is already there (not this training's: its checkpoint was made with other options or "
            "samples, or is missing); it is replaced when this run ends: give another --out to keep it",
            out,
        )
    samples = [torch.from_numpy(a) for a in (x_tr, y_tr, x_va, y_va, c_va)]
    checkpoint = functools.partial(_save_checkpoint, progress_path, cfg, data_key, net, opt, sched)
    history, best, best_state = _epochs(net, opt, sched, samples, cfg, state, checkpoint, progress)
    if best_state is None:  # every epoch's validation error NaN: no weights worth a model file
        raise ConfigError(
            f"{dataset.folder}: training diverged (no finite validation error in {len(history)} epochs); "
            "try a smaller --lr"
        )
    # this run's last state as MODEL.checkpoint.pt: published with its model from the stage, or put there now
    checkpoint(history, best, best_state, stage / checkpoint_path(out).name if stage else checkpoint_path(out))
    if stage is None:
        progress_path.unlink(missing_ok=True)
    net.load_state_dict(best_state)
    info = {
        "labels": cfg.labels,
        "config": _jsonable_config(cfg),
        "dataset": str(dataset.folder.resolve()),
        "train_presses": train_names,
        "val_presses": val_names,
        "excluded_presses": sorted(exclude),
        "train_samples": int(len(x_tr)),
        "best_epoch": best["epoch"],
        "best_val_aae_deg": best["aae"],
        "history": history,
    }
    save_model(
        out if stage is None else Path(stage) / out.name,
        net,
        hidden=cfg.hidden,
        dropout=cfg.dropout,
        sensor=dataset.sensor,
        reference=reference,
        info=info,
        smoothing_px=dataset.smoothing_px,
    )
    return TrainResult(out, history, best["epoch"], train_names, val_names, progress_path if stage else None)


def no_contact_error(dataset: CalibrationDataset, presses: int, samples: int) -> str:
    """Why a dataset without contact samples is not trained on: the network would learn the undeformed dome alone
    (every validation figure of contact would be NaN)."""
    return (
        f"{dataset.folder}: no contact samples: none of the {samples} samples of its {presses} presses differ from "
        "the reference frame (the tri-colour frames show the undeformed dome), so the network has no press to learn "
        "from: check that the presses were pressed, and exposed like the reference (neither black nor saturated: "
        "`nlips calibrate` prints the contact samples), then capture them again"
    )


def _presses(dataset: CalibrationDataset, cfg: TrainConfig, val_names, exclude) -> tuple[list[str], list[str]]:
    """(training presses, validation presses): the dataset's presses with labels of ``cfg.labels`` (true
    normals need a press with ground truth), less ``exclude``, split by press."""
    unknown = sorted(set(exclude) - set(dataset.names))
    if unknown:
        raise ConfigError(f"{dataset.folder}: excluded presses {unknown} are not in the dataset")
    names = [
        e["name"]
        for e in dataset.entries
        if (cfg.labels == "nlips" or e.get("has_truth")) and e["name"] not in set(exclude)
    ]
    if len(names) < 2:  # named here: split_by_press does not know the dataset
        usable = "" if cfg.labels == "nlips" else " with ground truth (true-normal labels)"
        left = f", {len(exclude)} excluded" if exclude else ""
        raise ConfigError(
            f"{dataset.folder / INDEX_FILE}: training needs at least 2 presses (one to validate on); "
            f"{len(names)} of the {len(dataset.names)} it lists can be used{usable}{left}"
        )
    return split_by_press(names, cfg.val_fraction, cfg.seed, val_names)


EPOCH_SEED_STRIDE = 7919
"""Epoch k reseeds torch's global generator (dropout) with seed + stride (k + 1): apart from the seeds of the
weights' initialisation (seed) and of the batch order (seed + k)."""


def _epochs(net, opt, sched, samples, cfg: TrainConfig, state: dict, checkpoint, progress: bool):
    """Train from ``state`` (:func:`_resume`) until early stopping, ``cfg.max_epochs`` or ``cfg.max_seconds``,
    checkpointing every epoch (``checkpoint(history, best, best_state)``); returns (history, best, best_state).

    ``samples``: tensors x_train, y_train, x_val, y_val, contact_val."""
    import torch

    from ..progress import progress_bar

    xt, yt, xv, yv, cv = samples
    history, best, best_state = state["history"], state["best"], state["best_state"]
    start = time.perf_counter() - sum(h["seconds"] for h in history)
    bar = progress_bar(cfg.max_epochs, enabled=progress, initial=len(history), desc="training", unit="epoch")
    for epoch in range(len(history), cfg.max_epochs):
        if history and epoch - 1 - best["epoch"] >= cfg.patience:
            break  # a resumed run that had already stopped early
        t0 = time.perf_counter()
        # every epoch's random draws (batch order; dropout masks from torch's global generator) depend on the
        # seed and the epoch alone, so a resumed training makes the model an uninterrupted one makes
        gen = torch.Generator().manual_seed(cfg.seed + epoch)
        torch.manual_seed(cfg.seed + EPOCH_SEED_STRIDE * (epoch + 1))
        loss = _epoch(net, opt, xt, yt, cfg.batch_size, gen)
        val_aae, val_contact = _validate(net, xv, yv, cv)
        if cfg.schedule == "plateau":
            sched.step(val_aae)
        else:
            sched.step()
        history.append(
            {
                "epoch": epoch,
                "train_loss": loss,
                "val_aae_deg": val_aae,
                "val_contact_aae_deg": val_contact,
                "lr": float(opt.param_groups[0]["lr"]),
                "seconds": time.perf_counter() - t0,
            }
        )
        if val_aae < best["aae"]:
            best = {"aae": val_aae, "epoch": epoch}
            best_state = {k: v.detach().clone() for k, v in net.state_dict().items()}
        checkpoint(history, best, best_state)
        bar.update(1)
        bar.set_postfix(val_aae=f"{val_aae:.2f}")
        stop_early = epoch - best["epoch"] >= cfg.patience
        if stop_early or (cfg.max_seconds and time.perf_counter() - start > cfg.max_seconds):
            break
    bar.close()
    return history, best, best_state


def _scheduler(opt, cfg: TrainConfig):
    import torch

    if cfg.schedule == "plateau":
        return torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, factor=cfg.lr_factor, patience=cfg.lr_patience, min_lr=cfg.lr * 0.01
        )
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.max_epochs, eta_min=cfg.lr * 0.05)


def _epoch(net, opt, x, y, batch_size: int, gen) -> float:
    import torch

    net.train()
    order = torch.randperm(len(x), generator=gen)
    total, count = 0.0, 0
    for start in range(0, len(x), batch_size):
        idx = order[start : start + batch_size]
        if len(idx) < 2:  # BatchNorm needs two samples
            continue
        opt.zero_grad()
        loss = cosine_loss(net(x[idx]), y[idx])
        loss.backward()
        opt.step()
        total += float(loss.detach()) * len(idx)
        count += len(idx)
    return total / max(count, 1)


def _validate(net, x, y, contact) -> tuple[float, float]:
    """Validation AAE over all samples and over the contact samples, degrees."""
    import torch

    net.eval()
    with torch.no_grad():
        cos = (net(x) * y).sum(-1).clamp(-1, 1)
    # core.metrics.angle_deg's angle, on the training device (arccos: a running figure, not the reported AAE)
    ang = torch.rad2deg(torch.arccos(cos))
    contact_aae = float(ang[contact].mean()) if bool(contact.any()) else float("nan")
    return float(ang.mean()), contact_aae


def _jsonable_config(cfg: TrainConfig) -> dict:
    d = dataclasses.asdict(cfg)
    d["hidden"] = list(cfg.hidden)
    return d


def _trajectory_options(cfg: TrainConfig) -> dict:
    """The options that decide the weights epoch by epoch: every option but the thread count (how fast) and the
    stopping limits (``max_seconds``, ``patience``, and ``max_epochs`` unless the cosine schedule is laid out
    over it), which only decide where a run stops. A run stopped by a limit thus continues when only a limit
    changes (``--max-minutes 10`` today, no limit tomorrow; ``--epochs 8`` then ``10``)."""
    limits = {"threads", "max_seconds", "patience"} | ({"max_epochs"} if cfg.schedule != "cosine" else set())
    return {k: v for k, v in _jsonable_config(cfg).items() if k not in limits}


def _config_key(cfg: TrainConfig) -> str:
    """What a checkpoint must match to be resumed: a digest of :func:`_trajectory_options`."""
    return hashlib.sha1(repr(_trajectory_options(cfg)).encode()).hexdigest()[:16]


def _options_changed(recorded, cfg: TrainConfig) -> str:
    """'name old -> new, ...' of the trajectory options a checkpoint recorded and ``cfg`` differ in ("" when the
    checkpoint records none: written before 2026-12-04)."""
    if not isinstance(recorded, dict):
        return ""
    now = _trajectory_options(cfg)
    return ", ".join(f"{k} {recorded.get(k)!r} -> {v!r}" for k, v in now.items() if recorded.get(k) != v)


def _data_key(*arrays) -> str:
    """What a checkpoint's samples must match: the training and validation arrays themselves (inputs, labels,
    contact flags), so another dataset, a rebuilt shard, other validation presses or other excluded presses
    all count as other data. Hashing them costs ~0.03 s per million samples, against seconds per epoch."""
    digest = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        digest.update(f"{a.dtype.str}{a.shape}".encode())
        digest.update(memoryview(a).cast("B"))
    return digest.hexdigest()[:16]


def checkpoint_path(out: Path) -> Path:
    """``MODEL.checkpoint.pt`` beside the model file ``out``."""
    return out.with_name(out.stem + "." + CHECKPOINT_FILE)


def progress_checkpoint_path(out: Path, cfg, data_key: str) -> Path:
    """``MODEL.<run>.checkpoint.pt`` beside the model file ``out``: the checkpoint of every epoch of the run of
    these options on these samples (``<run>``: 12 hex digits of their keys)."""
    run = hashlib.sha1(f"{_config_key(cfg)}:{data_key}".encode()).hexdigest()[:12]
    return out.with_name(f"{out.stem}.{run}.{CHECKPOINT_FILE}")


def model_file_names(out: Path) -> tuple[str, ...]:
    """The files one training writes beside the model ``out``: the model, its checkpoint, ONNX export and curve."""
    return (out.name, checkpoint_path(out).name, out.with_suffix(".onnx").name, out.stem + "_curve.png")


PUBLISH_POLL_S = 0.05
"""How often a finished training checks whether another one is still publishing its files into the same place, s."""


def model_stage(out):
    """A temporary folder beside the model path ``out`` to write one training's files into, removed afterwards
    (:func:`nlipscalib.core.atomic.scratch_dir`: a killed run's is removed by the next training, a SIGTERM'd
    one removes its own). Fill it with the files of :func:`model_file_names`, then :func:`publish_model`."""
    from ..core.atomic import scratch_dir

    return scratch_dir(out)


def publish_model(stage, out, result: TrainResult | None = None) -> list[Path]:
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


def _clean_interrupted_writes(out: Path, *names: str) -> None:
    """Remove temporaries of killed writes of the model, its checkpoint, ONNX file and curve, or of the files
    ``names`` (a run's per-epoch checkpoint) beside ``out`` (owner gone only).

    Every file here is written atomically under an owner-tagged temporary name (core.atomic); a SIGKILL
    in the middle of a write leaves that temporary, which no later write would otherwise remove.
    """
    from ..core.atomic import clean_interrupted

    for name in names or model_file_names(out):
        for gone in clean_interrupted(out.parent, item=name):
            log.warning("%s: removed an interrupted write", gone)


def _save_checkpoint(path: Path, cfg, data_key: str, net, opt, sched, history, best, best_state, to=None) -> None:
    """Write the training state to ``path`` (the run's per-epoch checkpoint), or to ``to``."""
    import torch

    from ..core.atomic import write_bytes

    buf = io.BytesIO()
    torch.save(
        {
            "key": _config_key(cfg),
            "options": _trajectory_options(cfg),  # so a refusal can say which option differs
            "data_key": data_key,
            "net": net.state_dict(),
            "opt": opt.state_dict(),
            "sched": sched.state_dict(),
            "history": history,
            "best": best,
            "best_state": best_state,
        },
        buf,
    )
    write_bytes(path if to is None else Path(to), buf.getvalue())


def _published_by(out: Path, cfg, data_key: str) -> bool:
    """Whether the model at ``out`` is this run's (the checkpoint published with it has this run's options and
    samples): a run resumed from its own progress may still replace another run's model, finished since."""
    from .model import read_torch_file

    try:
        ck = read_torch_file(checkpoint_path(out), "a training checkpoint")
    except Exception:  # missing or damaged: nothing says the model is this run's
        return False
    return isinstance(ck, dict) and ck.get("key") == _config_key(cfg) and ck.get("data_key") == data_key


def _resume(out: Path, progress_path: Path, cfg, data_key: str, net, opt, sched) -> dict:
    """Continue from the run's checkpoint (``progress_path``), else from ``MODEL.checkpoint.pt`` (a finished run's,
    or one written before checkpoints were named by their run) when it was made with the same options on the same
    samples.

    A checkpoint of another run is not resumed (the log says which differs): resuming one trained on other
    presses would report its validation AAE as if measured on this run's validation presses, and one that
    had reached its epoch limit would be saved as the new model without a single epoch on the new data.
    A damaged checkpoint only costs the progress it held (a warning, then training from scratch).
    """
    import copy

    from .model import read_torch_file

    fresh = {"history": [], "best": {"aae": float("inf"), "epoch": -1}, "best_state": None}
    path = progress_path if progress_path.is_file() else checkpoint_path(out)
    if not path.is_file():
        return fresh
    initial = copy.deepcopy((net.state_dict(), opt.state_dict(), sched.state_dict()))
    try:
        ck = read_torch_file(path, "a training checkpoint")
        if not isinstance(ck, dict):
            raise ValueError(f"a {type(ck).__name__}, not a checkpoint")
        if ck.get("key") != _config_key(cfg):
            if "options" not in ck:  # keyed before the stopping limits were left out of the key (2026-12-04)
                log.info("%s: made by an older version of nlipscalib; training from scratch", path)
            else:
                changed = _options_changed(ck["options"], cfg)
                log.info("%s: made with other training options (%s); training from scratch", path, changed)
            return fresh
        if len(ck.get("history") or ()) > cfg.max_epochs:  # a shorter run asked for: resuming would train none
            log.info(
                "%s: trained %d epochs, more than --epochs %d; training from scratch",
                path,
                len(ck["history"]),
                cfg.max_epochs,
            )
            return fresh
        if ck.get("data_key") != data_key:
            log.info(
                "%s: made on other samples (another dataset, other validation or excluded presses); "
                "training from scratch",
                path,
            )
            return fresh
        history, best, best_state = ck["history"], ck["best"], ck["best_state"]
        if not isinstance(history, list) or not history or not isinstance(best, dict) or best_state is None:
            raise ValueError("no finished epoch recorded")
        float(best["aae"]), int(best["epoch"])
        build_net(cfg.hidden, cfg.dropout).load_state_dict(best_state)  # the weights it would save must fit
        net.load_state_dict(ck["net"])
        opt.load_state_dict(ck["opt"])
        sched.load_state_dict(ck["sched"])
    except Exception as exc:  # torch and the checks above raise many kinds; every one means "not usable"
        if isinstance(exc, KeyError):
            why = f"it lacks {exc}"
        else:
            why = str(exc).removeprefix(f"{path}: ") or type(exc).__name__
        log.warning("%s: not resumable (%s); training from scratch", path, why)
        net.load_state_dict(initial[0])  # nothing half-loaded carries over into the fresh run
        opt.load_state_dict(initial[1])
        sched.load_state_dict(initial[2])
        return fresh
    log.info("%s: resuming after epoch %d", path, len(history))
    return {"history": history, "best": best, "best_state": best_state}
