"""A training's checkpoints: where they go, what they are keyed by, writing them and resuming from them.

After every epoch the state (weights, optimiser, history, best weights) goes into a checkpoint beside the model
named by the run (``MODEL.<run>.checkpoint.pt``, :func:`progress_checkpoint_path`: the options and the samples),
so trainings of other runs into the same place never overwrite each other's progress; when the run ends, its
last state is published as ``MODEL.checkpoint.pt`` with the model. A run with the same options on the same
training and validation samples continues from its own checkpoint, or from the published one (:func:`resume`).
Any other run (other options, another dataset, other presses held out for validation or excluded) trains
afresh, saying why.
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
import io
import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .model import build_net

if TYPE_CHECKING:  # torch is optional and imported where it is used: named for the hints only
    import torch

    from .train import TrainConfig

log = logging.getLogger(__name__)
CHECKPOINT_FILE = "checkpoint.pt"


def jsonable_config(cfg: TrainConfig) -> dict:
    """``cfg`` as JSON values; the synthetic samples' options left out when ``synthetic_share`` is 0 (none made), and
    ``weight_decay`` when 0 (Adam without decay), so the checkpoints and model keys of trainings without them stay
    those made before the options existed; ``colour_input`` likewise when ``"linear"``, and ``reference_smoothing_px``
    when 0 (the samples' prefilter) or of no use (linear colours divide by no reference)."""
    d = dataclasses.asdict(cfg)
    d["hidden"] = list(cfg.hidden)
    if not d.get("synthetic_share"):
        for key in ("synthetic_share", "synthetic_reflectance"):
            d.pop(key, None)
    if not d.get("weight_decay"):
        d.pop("weight_decay", None)
    if d.get("colour_input") == "linear":
        d.pop("colour_input", None)
    if not d.get("reference_smoothing_px") or "colour_input" not in d:
        d.pop("reference_smoothing_px", None)
    return d


def _trajectory_options(cfg: TrainConfig) -> dict:
    """The options that decide the weights epoch by epoch: every option but the thread count (how fast) and the
    stopping limits (``max_seconds``, ``patience``, and ``max_epochs`` unless the cosine schedule is laid out
    over it), which only decide where a run stops. A run stopped by a limit thus continues when only a limit
    changes (``--max-minutes 10`` today, no limit tomorrow; ``--epochs 8`` then ``10``)."""
    limits = {"threads", "max_seconds", "patience"} | ({"max_epochs"} if cfg.schedule != "cosine" else set())
    return {k: v for k, v in jsonable_config(cfg).items() if k not in limits}


def training_code() -> str:
    """Digest of the training code as installed (:data:`~nlipscalib.core.code_version.TRAIN_CODE`: core and learn),
    which a checkpoint records (``code``): a finished model is reused, and a checkpoint resumed, only when its code
    is this one.

    Why: the options and samples alone made two runs the same training, so a model trained by other code (a
    changed loss, initialisation or sampling rule; the version number is "0.1.0" in every commit) was reused
    after an upgrade with no word but for a missing ``info.contacts``; `nlips solve` solves a result of other code
    again (``pipeline.reuse``), and training now follows it. 2-36 ms once per process (benchmarks/RESULTS.md,
    s31-walkleft)."""
    from ..core.code_version import TRAIN_CODE, subpackages_fingerprint

    return subpackages_fingerprint(TRAIN_CODE)


def other_code(ck: dict) -> str:
    """Why checkpoint ``ck`` is of other training code, in words ("" when it is this code's)."""
    recorded = ck.get("code")
    if recorded == training_code():
        return ""
    if recorded is None:
        return "trained by an nlipscalib before 2026-12-06, which recorded no fingerprint of its training code"
    now = training_code()
    return f"trained by other nlipscalib training code (core/ or learn/ differ: {recorded[:8]}, now {now[:8]})"


def config_key(cfg: TrainConfig) -> str:
    """What a checkpoint must match to be resumed: a digest of :func:`_trajectory_options`."""
    return hashlib.sha1(repr(_trajectory_options(cfg)).encode()).hexdigest()[:16]


OMITTED_OPTIONS = {"colour_input": "linear", "weight_decay": 0.0, "synthetic_share": 0.0, "reference_smoothing_px": 0.0}
"""What an option :func:`jsonable_config` leaves out means: a checkpoint's options without it were of this value."""


def _options_changed(recorded: object, cfg: TrainConfig) -> str:
    """'name old -> new, ...' of the trajectory options a checkpoint recorded and ``cfg`` differ in ("" when the
    checkpoint records none: written before 2026-12-04). An option left out on either side (:data:`OMITTED_OPTIONS`)
    is named by the value it meant: a linear checkpoint under the ratio default said "colour_input None -> 'ratio'",
    and a linear run over a ratio checkpoint "()" (the option absent from this run's record)."""
    if not isinstance(recorded, dict):
        return ""
    old, now = ({**OMITTED_OPTIONS, **options} for options in (recorded, _trajectory_options(cfg)))
    if "linear" in (old["colour_input"], now["colour_input"]):  # linear colours divide by no reference: not a change
        for options in (old, now):
            options.pop("reference_smoothing_px", None)
    names = [k for k in now if k in old] + [k for k in now if k not in old]  # this run's order; one side's last
    return ", ".join(f"{k} {old.get(k)!r} -> {now[k]!r}" for k in names if old.get(k) != now[k])


def data_key_of(*arrays: np.ndarray) -> str:
    """What a checkpoint's samples must match: the training and validation arrays themselves (inputs, labels,
    contact flags), so another dataset, a rebuilt shard, other validation presses or other excluded presses
    all count as other data. Hashing them costs ~0.03 s per million samples, against seconds per epoch."""
    digest = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        digest.update(f"{a.dtype.str}{a.shape}".encode())
        digest.update(memoryview(a).cast("B"))
    return digest.hexdigest()[:16]


def training_run(
    cfg: TrainConfig, dataset: str | Path, val_names: Sequence[str] | None, exclude: Sequence[str]
) -> dict:
    """What a training is before its samples are read (``key``: a digest of the rest): the options that decide its
    weights (:func:`_trajectory_options`), the dataset folder, the validation presses asked for (None: the seeded
    split) and the excluded ones. Two runs of one key into one model path are the same training
    (:func:`.publish.hold_training`); their samples are compared when read (:func:`data_key_of`)."""
    record = {
        "options": _trajectory_options(cfg),
        "dataset": str(Path(dataset).resolve()),
        "val_presses": sorted(val_names) if val_names else None,
        "excluded_presses": sorted(exclude),
    }
    return record | {"key": hashlib.sha1(json.dumps(record, sort_keys=True).encode()).hexdigest()[:16]}


def checkpoint_path(out: Path) -> Path:
    """``MODEL.checkpoint.pt`` beside the model file ``out``."""
    return out.with_name(out.stem + "." + CHECKPOINT_FILE)


def progress_checkpoint_path(out: Path, cfg: TrainConfig, data_key: str) -> Path:
    """``MODEL.<run>.checkpoint.pt`` beside the model file ``out``: the checkpoint of every epoch of the run of
    these options on these samples (``<run>``: 12 hex digits of their keys)."""
    run = hashlib.sha1(f"{config_key(cfg)}:{data_key}".encode()).hexdigest()[:12]
    return out.with_name(f"{out.stem}.{run}.{CHECKPOINT_FILE}")


def save_checkpoint(
    path: Path,
    cfg: TrainConfig,
    data_key: str,
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    history: list[dict],
    best: dict,
    best_state: dict | None,
    to: str | Path | None = None,
    *,
    sampling: object = None,
    samples_key: str | None = None,
) -> None:
    """Write the training state to ``path`` (the run's per-epoch checkpoint), or to ``to``; ``sampling``: the
    dataset's sampling record (index.json's), compared by :func:`check_sampling_record`; ``samples_key``: the
    identity of its samples from the dataset's records (``CalibrationDataset.samples_key``, None when it has none
    or its files differ from them), by which a re-run reuses the finished model without reading the samples."""
    import torch

    from ..core.atomic import NO_SPACE_ERRNOS, write_bytes

    buf = io.BytesIO()
    torch.save(
        on_cpu(
            {
                "key": config_key(cfg),
                "code": training_code(),  # a model of other training code is trained again (published_state)
                "options": _trajectory_options(cfg),  # so a refusal can say which option differs
                "data_key": data_key,
                "samples_key": samples_key,  # the dataset's records of these samples: a kept re-run reads none
                "sampling": sampling,
                "net": net.state_dict(),
                "opt": opt.state_dict(),
                "sched": sched.state_dict(),
                "history": history,
                "best": best,
                "best_state": best_state,
            }
        ),
        buf,
    )
    target, data = (path if to is None else Path(to)), buf.getvalue()
    try:
        write_bytes(target, data)
    except OSError as exc:
        if exc.errno not in NO_SPACE_ERRNOS or not target.exists():
            raise
        # the atomic rewrite's price, kept: the last whole checkpoint stays until the new one is whole (with 1.8 MB
        # free a 1.6 MB checkpoint fitted once, and the second epoch's rewrite failed with no word why)
        size = f"{len(data) / 1e6:.1f} MB"
        why = f"{exc.strerror} (rewriting it needs room for a second copy, {size}, while it replaces the first)"
        raise OSError(exc.errno, why, exc.filename) from exc


def on_cpu(state: object) -> object:
    """``state`` (dicts, lists and tuples of tensors and plain data: state dicts, an optimiser's) with every tensor
    on the CPU: a checkpoint of a GPU training loads on a machine without one. Tensors already there are kept as
    they are (no copy), so a CPU training's checkpoint is the one it wrote before."""
    import torch

    if isinstance(state, torch.Tensor):
        return state.detach().cpu()
    if isinstance(state, dict):
        moved = type(state)((k, on_cpu(v)) for k, v in state.items())
        if hasattr(state, "_metadata"):  # a state dict's layer versions, which load_state_dict reads
            moved._metadata = state._metadata
        return moved
    if isinstance(state, (list, tuple)):
        return type(state)(on_cpu(v) for v in state)
    return state


def published_by(out: Path, cfg: TrainConfig, data_key: str) -> bool:
    """Whether the model at ``out`` is this run's (the checkpoint published with it has this run's options and
    samples): a run resumed from its own progress may still replace another run's model, finished since."""
    return published_state(out, cfg, data_key) is not None


def published_state(out: Path, cfg: TrainConfig, data_key: str | None, samples_key: str | None = None) -> dict | None:
    """The checkpoint published with the model at ``out`` (:func:`save_checkpoint`'s fields) when the model is there
    and this run's (its options and samples: ``data_key``, the samples read, or ``samples_key``, their identity
    from the dataset's records, which a checkpoint written before 2026-12-07 lacks), else None."""
    from .model import read_torch_file

    if not out.is_file():
        return None
    try:
        ck = read_torch_file(checkpoint_path(out), "a training checkpoint")
    except Exception:  # missing or damaged: nothing says the model is this run's
        return None
    if not (isinstance(ck, dict) and ck.get("key") == config_key(cfg)):
        return None
    same = (data_key is not None and ck.get("data_key") == data_key) or (
        samples_key is not None and ck.get("samples_key") == samples_key
    )
    return ck if same else None


def check_sampling_record(
    out: Path,
    progress_path: Path,
    cfg: TrainConfig,
    data_key: str,
    dataset: Path,
    sampling: object,
    key_under: Callable[[dict], str] | None = None,
) -> None:
    """ConfigError when this run's checkpoint (its progress, or the one published with the model at ``out``) was
    trained on the same samples while the dataset's sampling record (index.json's ``sampling``) said otherwise.

    Why: the samples were made with the record of their build; a record edited by hand since makes none again,
    yet the model file takes the record's ``smoothing_px`` (inference filters its inputs with it). `nlips train`
    reused the model of the old record without a word; training again would pair the old samples with the new
    record. Checkpoints from before 2026-12-05 recorded none: nothing to compare.

    ``key_under(record)``: the data key this run's samples had under another sampling record, for trainings whose
    inputs follow the record (``TrainConfig.colour_input`` "ratio" divides by the reference filtered with its
    smoothing; the synthetic samples' reference is filtered alike): their checkpoint under the old record has
    another data key (and another progress file), and the edit went unnoticed. Called only for a checkpoint of
    these options whose record differs; None: the inputs do not follow the record (``data_key`` under any).
    """
    from ..core.errors import ConfigError
    from .model import read_torch_file

    paths = [progress_path, checkpoint_path(out)]
    if key_under is not None:  # the progress of this run under the old record is named by its old data key
        runs = out.parent.glob(f"{glob.escape(out.stem)}.*.{CHECKPOINT_FILE}")
        paths += sorted(p for p in runs if p not in paths)
    for path in paths:
        try:
            ck = read_torch_file(path, "a training checkpoint")
        except Exception:  # missing or damaged: resume() says so, if it matters
            continue
        if not (isinstance(ck, dict) and ck.get("key") == config_key(cfg)):
            continue
        if not (changed := sampling_changed(ck, sampling)):
            continue
        samples = data_key if key_under is None or ck.get("data_key") == data_key else key_under(ck["sampling"])
        if ck.get("data_key") == samples:
            raise ConfigError(
                f"{dataset / 'index.json'}: sampling record changed since {out} was trained on these same samples "
                f"({changed}); editing index.json does not make the samples again: make the dataset again with "
                "those options (`nlips calibrate ... --smoothing`) or put the record back (--out ANOTHER.pt trains "
                "with the record as it is)"
            )


def sampling_changed(checkpoint: dict, sampling: object) -> str:
    """How the dataset's sampling record ``sampling`` differs from the one ``checkpoint`` was trained with in what the
    model file takes from it (:data:`MODEL_SAMPLING_FIELDS`): "smoothing_px 1.0, now 2.0"; "" when the same, or
    unknown (a checkpoint from before 2026-12-05 recorded none). Its other options decide only the samples, which
    the data key compares."""
    was, now = checkpoint.get("sampling"), sampling
    if not (isinstance(was, dict) and isinstance(now, dict)):
        return ""
    return "; ".join(f"{k} {was.get(k)}, now {now.get(k)}" for k in MODEL_SAMPLING_FIELDS if was.get(k) != now.get(k))


MODEL_SAMPLING_FIELDS = ("smoothing_px", "smoothing_colour")
"""The sampling options a model file carries (``smoothing_px``, ``smoothing_colour``: inference filters its inputs
with them)."""


def resume(
    out: Path,
    progress_path: Path,
    cfg: TrainConfig,
    data_key: str,
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    *,
    device: str = "cpu",
) -> dict:
    """Continue from the run's checkpoint (``progress_path``), else from ``MODEL.checkpoint.pt`` (a finished run's,
    or one written before checkpoints were named by their run) when it was made with the same options on the same
    samples.

    A checkpoint of another run is not resumed (the log says which differs): resuming one trained on other
    presses would report its validation AAE as if measured on this run's validation presses, and one that
    had reached its epoch limit would be saved as the new model without a single epoch on the new data.
    A damaged checkpoint only costs the progress it held (a warning, then training from scratch).
    ``device`` ("cpu" or "cuda"): the one this run trains on, ``net``'s; a checkpoint (CPU tensors, whatever device
    made it) is loaded into ``net`` and ``opt`` there, and a resume on another device than its epochs' says so.
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
        if ck.get("key") != config_key(cfg):
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
        if why := other_code(ck):  # a whole checkpoint, whose weights are not what this code makes of these samples
            log.info("%s: %s; training from scratch", path, why)
            return fresh
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
    changes = _thread_change(history, cfg.threads) + _device_change(history, device)
    log.info("%s: resuming after epoch %d%s", path, len(history), changes)
    return {"history": history, "best": best, "best_state": best_state}


def _thread_change(history: list[dict], threads: int) -> str:
    """', trained on N thread(s) so far ...' when the epochs resumed ran on another thread count than ``threads``
    (recorded per epoch since 2026-12-05), else "": the count sets the summation order, so the weights go on
    rounded otherwise and the model is not bit for bit the one an uninterrupted run on either count makes (on a
    6-press 160x120 calibration, up to 4e-3 apart after 40 epochs, validation AAE alike to 0.01 deg)."""
    before = history[-1].get("threads") if isinstance(history[-1], dict) else None
    if not isinstance(before, int) or before == threads:
        return ""
    return (
        f", trained on {before} thread(s) so far and on {threads} from here: the weights now round otherwise, so "
        f"the model will differ slightly from one trained on one count throughout (--threads {before} carries on "
        "bit for bit)"
    )


def _device_change(history: list[dict], device: str) -> str:
    """', trained on cpu so far and on cuda from here ...' when the epochs resumed ran on another device type than
    ``device`` (recorded per epoch since 2026-12-05; before, every training ran on the CPU), else "". The device is
    left out of what a checkpoint must match, as the thread count is: a run interrupted on a GPU goes on where there
    is none (and back), but its weights from here round otherwise and its dropout masks come from the other device's
    generator, so the model is not the one an uninterrupted run on either device makes (its validation AAE alike)."""
    before = history[-1].get("device", "cpu") if isinstance(history[-1], dict) else None
    if not isinstance(before, str) or before == device:
        return ""
    return (
        f", trained on {before} so far and on {device} from here: the model will differ slightly from one trained "
        f"on one device throughout (--device {before} carries on as it began)"
    )
