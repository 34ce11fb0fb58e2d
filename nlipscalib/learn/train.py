"""Training NLiPsNet on a calibration dataset: split by press, cosine loss, early stopping on validation AAE.

Resumable: every epoch's state goes into a checkpoint named by the run, and a run with the same options on the
same samples continues from it (:mod:`.checkpoint`). A training's files are written into a stage and published
together (:mod:`.publish`), so runs into one model path leave the files of one run, never a mix.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import errno
import functools
import logging
import math
import os
import time
from collections.abc import Callable, Collection, Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.config import OMIT_AT, did_you_mean
from ..core.errors import PATH, ConfigError, check_flag, check_kind
from ..core.press_identity import IDENTITY_KEY
from .checkpoint import (
    check_sampling_record,
    checkpoint_path,
    data_key_of,
    jsonable_config,
    other_code,
    progress_checkpoint_path,
    published_by,
    published_state,
    resume,
    save_checkpoint,
)
from .dataset import CAPTURE_IDENTITY, INDEX_FILE, CalibrationDataset
from .model import (
    COLOUR_INPUTS,
    PAPER_DROPOUT,
    PAPER_HIDDEN,
    build_net,
    cosine_loss,
    input_reference,
    model_inputs,
    save_model,
    set_colour_normalisation,
)
from .prefilter import check_sigma
from .publish import clean_interrupted_writes
from .resolution import INFO_KEY, calibrated_contacts
from .seen import CAPTURES_KEY, IDENTITIES_KEY
from .torch_device import check_device, torch_threads

if TYPE_CHECKING:  # torch is optional and imported where it is used: named for the hints only
    import torch

log = logging.getLogger(__name__)

MAX_HIDDEN_WIDTH = 4096
"""Widest hidden layer TrainConfig accepts: 16x the paper's 256. Two such layers already hold 64 MB of weights
(256 MB with Adam's moments) and a batch of 1024 samples 16 MB of activations per layer; a wider one is a slip
(``--hidden 100000000``), which ran out of memory in the first batch, a traceback after loading the dataset."""
DEFAULT_WEIGHT_DECAY = 0.5
""":attr:`TrainConfig.weight_decay` by default: 0.5, tuned with the colour-ratio input (``colour_input = "ratio"``;
Q2 medium, docs/experiments/RESULTS.md, s37-unseen2): against 0.2 the unseen split went 3.17 / 3.13 / 3.10 ->
2.94 / 2.89 / 2.97 deg vs truth at three training seeds (2.41 / 2.40 / 2.28 -> 2.12 / 2.13 / 2.16 vs the labels,
the coin 5.54 / 5.37 / 5.29 -> 4.99 / 4.96 / 4.99), the seen split 0.93 / 0.97 / 0.95 -> 0.89 / 0.94 / 0.93; at
seed 0 0.05 / 0.35 / 0.7 / 1.0 gave 3.13 / 3.01 / 2.94 / 3.04. With linear colours 0.5 beat 0.2 at the same three
seeds too (unseen 3.32 / 3.44 / 3.31 -> 3.21 / 3.22 / 3.26, seen 0.97 / 1.10 / 0.95 -> 0.94 / 1.08 / 0.92). At full
size the gain is small (Q2 full, ratio, two seeds: unseen 3.052 / 3.031 -> 3.023 / 3.024 vs truth, 2.532 / 2.528 ->
2.497 / 2.501 vs labels, seen 0.845 / 0.853 -> 0.831 / 0.863; docs/experiments/RESULTS.md, the thirty-seventh
session's lead section).
Before, with linear colours (s35-unseen): 0.01 moved the unseen split by -0.04 / -0.05 deg vs truth at two seeds,
0.05 by -0.19 at each of three, 0.2 by -0.51 / -0.36 at two, the seen split no worse at any; at full size, two
seeds, 0.2 against none (the lead's rerun): seen -0.03 / -0.04 vs truth, unseen -0.06 / -0.14 vs the labels and
+0.02 / -0.06 vs truth. 0.5 at full size: not measured yet."""
MAX_WEIGHT_DECAY = 1.0
"""Largest :attr:`TrainConfig.weight_decay`: at the start's learning rate (2e-3) a decay of 1 shrinks the weights by
0.2 % a step, half of a weight in ~350 steps (a Q2 medium epoch is ~240 steps); measured: 0.01, 0.05, 0.2, 0.5, 1."""
MAX_SYNTHETIC_SHARE = 4.0
"""Largest :attr:`TrainConfig.synthetic_share`: four synthetic samples per real one already let the model's light
outweigh what the presses show."""
DEFAULT_REFERENCE_SMOOTHING_PX = 3.0
""":attr:`TrainConfig.reference_smoothing_px` by default: 3 px (docs/experiments/RESULTS.md, s38-unseen3). On Q2 medium
at three training seeds, against the samples' 1 px prefilter: seen 0.89 / 0.95 / 0.93 -> 0.79 / 0.84 / 0.77 deg vs
truth, unseen 2.93 / 2.91 / 2.97 -> 2.88 / 2.87 / 2.87 (vs the labels 2.12 / 2.15 / 2.17 -> 2.04 / 2.03 / 2.09). Q2
full at seeds 0 / 2 (Intel VM): seen 0.82 / 0.84 -> 0.75 / 0.78, unseen 2.99 / 2.98 -> 2.95 / 2.91 vs truth (2.46 /
2.46 -> 2.41 / 2.38 vs the labels)."""
SCHEDULES = ("plateau", "cosine")
"""The learning-rate schedules (:attr:`TrainConfig.schedule`)."""


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
    """Learning-rate schedule. "plateau": multiply the rate by ``lr_factor`` once more than ``lr_patience`` epochs
    in a row bring no better validation AAE (``ReduceLROnPlateau``), down to 1 % of ``lr``. At a fixed rate the
    validation AAE of the paper's net on 50 full-size presses scattered by 0.4 deg from epoch to epoch and early
    stopping kept a lucky epoch; lowering the rate when it stalls kept a better epoch, in fewer epochs
    (benchmarks/RESULTS.md; the scatter, from 10 validation presses, stays). "cosine": annealed to 5 % over
    ``max_epochs`` (the earlier default; with early stopping after ~25 of 200 epochs it stays near ``lr``)."""
    lr_patience: int = 2
    """Epochs in a row without a better validation AAE that the plateau schedule lets pass: it lowers the rate at the
    next one (2: at the third)."""
    lr_factor: float = 0.3
    """Factor the plateau schedule lowers the rate by."""
    seed: int = 0
    """Seed of the split, the initial weights, dropout and shuffling."""
    max_seconds: float = 0.0
    """Stop after this much training time (0: no limit)."""
    threads: int = 1
    """CPU threads for PyTorch while training (``torch.set_num_threads``; the process's count is restored after).
    1 by default, for ``nlips train`` and the experiments alike, whatever the machine or its load: a step is
    hundreds of small ops, each an OpenMP fork/join whose threads spin waiting for each other, so when another
    process holds a core every op waits for a descheduled thread. On the shared 2-core VM a step of the paper's
    net took 16-57 ms on 1 thread and 14-600 ms on 2 (the quick 64-64-64 net at batch 256: 2-9 ms against
    28-470 ms); on the idle machine two threads took 0.73-0.81x the wall of one (2 epochs of the paper's net on
    Q2's dataset: 74-86 s against 101-106 s) for 40 % more CPU (benchmarks/RESULTS.md, s18-i and the lead's runs).
    The count also changes the weights (summation order; after 20 steps they differ by up to 0.03), so a fixed
    default gives the same model on every machine. ``nlips train --threads N`` asks for more. Not part of what a
    checkpoint must match to be resumed (a run resumed on another count goes on with the same training, rounded
    otherwise: each epoch's count is in the history, and the resume says so); the experiments' model key holds it
    (experiments.learning.model_files)."""
    synthetic_share: float = 0.0
    """Model-based samples of steep relief added to the training samples, as a share of them (0: none; 0.25 adds one
    synthetic sample per four real ones): :mod:`.synthetic` makes them from the LED model, the undeformed surface and
    the reference frame, for normals tilted 30-75 deg, beyond what the calibration indenters reach. Training only
    (validation stays on the real presses). Off by default: measured on Q2 (docs/experiments/RESULTS.md, s33)."""
    synthetic_reflectance: float = 0.0
    """The gel's diffuse reflectance for the synthetic samples' indirect light (:mod:`.synthetic`: a tilted facet
    lit by the gel around it; 0: direct light only; a white matte coat: about ``synthetic.GEL_REFLECTANCE``, 0.8).
    Unused when ``synthetic_share`` is 0."""

    weight_decay: float = DEFAULT_WEIGHT_DECAY
    """Decoupled weight decay (``torch.optim.AdamW``: each step shrinks every weight by ``lr * weight_decay`` of
    itself, apart from the gradient's step), on every parameter. Why: the unseen indenters' colours (a coin's
    engraved walls) lie outside every calibration colour, and the net's answer there is its extrapolation; with
    smaller weights it reads those walls' steepness better (decay 0.05: the coin's 20-50 deg -1.4 to -2.8 deg). On
    Q2 medium 0.2 took the unseen split 3.83 / 3.80 -> 3.32 / 3.44 deg vs truth at two training seeds (the coin 6.65
    / 6.59 -> 5.67 / 5.78), the seen split no worse (1.00 / 1.11 -> 0.97 / 1.10); 0.05 gained -0.19 at each of three
    seeds (docs/experiments/RESULTS.md, s35-unseen). With the colour-ratio input 0.5 did better than 0.2 at three
    seeds (unseen 3.17 / 3.13 / 3.10 -> 2.94 / 2.89 / 2.97 vs truth, seen no worse; s37-unseen2): the default since
    the thirty-seventh session (:data:`DEFAULT_WEIGHT_DECAY`). 0: Adam without decay, the training before the
    thirty-fifth session (then left out of the checkpoints' and model keys' options, so
    those of earlier trainings stay theirs)."""

    colour_input: str = dataclasses.field(default="ratio", metadata={OMIT_AT: "linear"})
    """What the network's r, g, b inputs are (``learn.model.COLOUR_INPUTS``): ``"ratio"`` (the default since the
    thirty-seventh session), each filtered colour over the undeformed reference's at the same pixel, filtered alike
    (``learn.model.input_reference``; the model file records it, and inference divides by the reference it carries),
    or ``"linear"``, the filtered linear colours (the paper's, and every model's before the option). Why: with linear
    colours the net must learn how the LEDs' light falls off over the image from (u, v) as well as how the colour
    turns with the normal; the ratio takes the fall-off out, and a tilt changes the inputs alike wherever it lies.
    Measured (docs/experiments/RESULTS.md, s36-ratio and the lead's sections after it): Q2 at full size, two training
    seeds, unseen indenters 2.72 / 2.67 -> 2.53 / 2.53 deg vs the labels and 3.27 / 3.20 -> 3.05 / 3.03 vs truth, each
    unseen indenter better at both seeds, the seen split 0.92 / 0.86 -> 0.84 / 0.85 vs truth; with 5 and 10
    calibration presses at full size seen 1.74 -> 1.65 and 1.48 -> 1.21 vs truth, unseen no worse; Q2 medium unseen
    3.32 / 3.44 -> 3.17 / 3.13 vs truth. What learns less from it is only the tests' regime: a couple of 96x72 twin
    presses and a few epochs (Q2's CI-size check keeps linear colours for that reason, ``experiments.q2.QUICK_NET``).

    Keys: ``"linear"`` is left out of the checkpoints' and model keys' options and of the experiments' records
    (``core.config.OMIT_AT``; ``learn.checkpoint.jsonable_config``), and a model file without the field is of linear
    colours: every key, checkpoint and model file of an earlier linear training stays valid and is reused as it was.
    The ratio is written out, default or not, so the default's keys are those of the runs that asked for
    ``colour_input = "ratio"`` before it became the default (their models are reused too), and never those of a
    linear net."""

    reference_smoothing_px: float = dataclasses.field(default=DEFAULT_REFERENCE_SMOOTHING_PX, metadata={OMIT_AT: 0.0})
    """Sigma (px) of the Gaussian the undeformed reference frame gets before a ratio's colours are divided by it
    (``colour_input = "ratio"``; :func:`learn.model.input_reference`, normalised over the gel; the model file
    records it and inference divides alike). 0: the samples' prefilter (``smoothing_px``, ``smoothing_colour``),
    as before the thirty-eighth session. Why wider: the undeformed dome's shading is smooth, so the reference frame
    needs no edge kept and its noise can go; what the samples' 1 px leaves of it (0.36 % of the colour on the twin's
    reference frames, 1.4 % raw per pixel, at 320x240 and 640x480 alike) is a fixed pattern that every press's ratio
    at that pixel is divided by, beside the press's own noise. At 3 px the reference's noise falls ~3x and the
    Gaussian's flattening of the dome's shading stays at ~0.04 % (Q2 medium, 320x240; a 640x480 frame's shading is
    smoother per pixel). Measured on Q2 medium (:data:`DEFAULT_REFERENCE_SMOOTHING_PX`): the seen split 0.10-0.15
    deg better vs truth at three training seeds, the unseen 0.04-0.10 (the cone and screw most, the coin unchanged:
    its walls' error is extrapolation, not noise), the validation AAE 0.93 / 1.06 / 0.97 -> 0.81 / 0.94 / 0.82.
    Unused with linear colours, and then left out of the checkpoints' and model keys' options, as at 0
    (:func:`learn.checkpoint.jsonable_config`), so those keys stay as they were."""

    def __post_init__(self):
        # every message starts with the field's name: `nlips train` names its option instead (cli/train.py)
        if self.labels not in ("nlips", "true"):
            raise ConfigError(f"labels must be 'nlips' or 'true', got {self.labels!r}")
        if not self.hidden or any(not _is_int(h) or h < 1 for h in self.hidden):
            raise ConfigError(f"hidden must list positive layer widths, got {self.hidden}")
        if max(self.hidden) > MAX_HIDDEN_WIDTH:
            raise ConfigError(f"hidden must list layer widths of at most {MAX_HIDDEN_WIDTH}, got {self.hidden}")
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
        if not (isinstance(self.synthetic_share, (int, float)) and 0 <= self.synthetic_share <= MAX_SYNTHETIC_SHARE):
            raise ConfigError(f"synthetic_share must be in [0, {MAX_SYNTHETIC_SHARE:g}], got {self.synthetic_share!r}")
        if not (isinstance(self.synthetic_reflectance, (int, float)) and 0 <= self.synthetic_reflectance <= 1):
            raise ConfigError(f"synthetic_reflectance must be in [0, 1], got {self.synthetic_reflectance!r}")
        decay = self.weight_decay
        if isinstance(decay, bool) or not (isinstance(decay, (int, float)) and 0 <= decay <= MAX_WEIGHT_DECAY):
            raise ConfigError(f"weight_decay must be in [0, {MAX_WEIGHT_DECAY:g}] (0: none), got {decay!r}")
        check_sigma(self.reference_smoothing_px, "reference_smoothing_px")
        if self.colour_input not in COLOUR_INPUTS:
            raise ConfigError(
                f"colour_input must be one of {', '.join(COLOUR_INPUTS)}, got {self.colour_input!r}"
                + did_you_mean(str(self.colour_input), COLOUR_INPUTS)
            )
        if self.schedule not in SCHEDULES:
            raise ConfigError(
                f"schedule must be 'plateau' or 'cosine', got {self.schedule!r}"
                + did_you_mean(str(self.schedule), SCHEDULES)
            )
        if self.lr_patience < 0 or not 0 < self.lr_factor < 1:
            raise ConfigError(
                f"lr_patience must be >= 0 and lr_factor in (0, 1), got {self.lr_patience}, {self.lr_factor}"
            )


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def split_by_press(
    names: Iterable[str], val_fraction: float, seed: int, val_names: Collection[str] | None = None
) -> tuple[list[str], list[str]]:
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


TRAINING_BARS = {"nlips": "training on NLiPs labels", "true": "training on true normals"}
"""The training bar's description for each kind of labels (:attr:`TrainConfig.labels`)."""


def training_arrays(
    data: dict, labels: str, reference: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inputs (N, 5), targets (N, 3), contact (N,)) of the samples that have a finite label; ``reference``: what the
    colours are divided by (``learn.model.input_reference``; None: linear colours)."""
    target = data["normal"] if labels == "nlips" else data["true_normal"]
    keep = np.all(np.isfinite(target), -1)
    return model_inputs(data["pixel"][keep], data["rgb"][keep], reference), target[keep], data["contact"][keep]


@dataclasses.dataclass
class TrainResult:
    model_path: Path
    history: list
    """One dict per epoch: epoch, train_loss, val_aae_deg, val_contact_aae_deg, seconds."""
    best_epoch: int
    train_presses: list
    val_presses: list
    progress: Path | None = None
    """This run's per-epoch checkpoint while its files wait in a stage: removed by :func:`.publish.publish_model`."""
    reused: bool = False
    """The model at ``model_path`` is this training's, finished before (``train(reuse=True)``): nothing was written."""


def train(
    dataset: CalibrationDataset | str | os.PathLike,
    cfg: TrainConfig,
    out: str | Path,
    val_names: Collection[str] | None = None,
    exclude: Collection[str] = (),
    progress: bool = True,
    stage: Path | None = None,
    reuse: bool = False,
    device: str = "cpu",
) -> TrainResult:
    """Train NLiPsNet on ``dataset`` and write ``out`` (the model file) and ``checkpoint.pt`` beside it.

    Parameters
    ----------
    dataset : CalibrationDataset, or its folder's path (str or Path)
    cfg : TrainConfig
    out : path of the model file (.pt)
    val_names : optional explicit validation presses
    exclude : presses kept out of training and validation (a test set)
    stage : folder from :func:`.publish.model_stage`, optional
        Write the model and a copy of the final checkpoint there, under their names beside ``out``, for
        :func:`.publish.publish_model` to put in place with the other files of this run. The checkpoint of every epoch
        still goes beside ``out`` (what an interrupted run resumes from).
    reuse : when the model at ``out`` is this training's (options and samples) and finished (:func:`_finished`),
        return it as it is (``TrainResult.reused``), writing nothing; else train (resuming what there is).
        Why: a second identical ``nlips train`` waits for the first (:func:`.publish.hold_training`), then had
        nothing left to train but wrote the same model, checkpoint and ONNX file again.
    device : torch device to train on: "cpu" (default), "cuda", "cuda:N" (:func:`.torch_device.check_device`)
        The net and every training and validation sample are moved there once; the files written hold CPU tensors
        (they load anywhere) and a checkpoint of either device resumes on the other. Not a :class:`TrainConfig`
        field: what a checkpoint must match and the experiments' model keys (``dataclasses.asdict`` of the config)
        stay as they were, and the experiments train on the CPU. Like ``cfg.threads`` it decides how the weights
        round, and more: dropout's masks come from the device's generator (CUDA's Philox, not the CPU's Mersenne
        Twister), so a GPU run is another draw of the same training, its validation AAE alike but not its bits.
        Each epoch's device is in the history (``"device"``: "cpu" or "cuda"); a resume on another says so.
    progress : the epochs' bar on stderr, drawn only on a terminal or in a notebook (:mod:`nlipscalib.progress`)
    """
    check_kind(dataset, (CalibrationDataset, str, os.PathLike), "dataset", "a CalibrationDataset or its folder's path")
    check_kind(cfg, TrainConfig, "cfg", "a TrainConfig (TrainConfig() is the paper's)")
    check_flag(progress, "progress")
    check_kind(out, PATH, "out", "the model file's path (str or Path)")
    if Path(out).is_dir():  # the whole training ran, then its model's write failed naming a temporary file
        raise IsADirectoryError(errno.EISDIR, "a folder; give the path of the model file to write (.pt)", str(out))
    dev = check_device(device)
    if isinstance(dataset, (str, os.PathLike)):
        dataset = CalibrationDataset(dataset)
    with torch_threads(cfg.threads), _callers_generators(dev):
        return _train(dataset, cfg, Path(out), val_names, exclude, progress, stage, reuse, dev)


def _callers_generators(device: torch.device) -> contextlib.AbstractContextManager:
    """torch's global generators given back as the caller had them when the training ends: it seeds them (weights'
    initialisation, each epoch's dropout) for a reproducible model, and a notebook's own draws after a training
    came out of the training's seed (``torch.initial_seed()`` was the config's). The CPU's, and the CUDA devices'
    when it trains on one (reading their states starts CUDA: not done for a CPU training)."""
    import torch

    devices = list(range(torch.cuda.device_count())) if device.type == "cuda" else []
    return torch.random.fork_rng(devices=devices)


def _train(
    dataset: CalibrationDataset,
    cfg: TrainConfig,
    out: Path,
    val_names: Collection[str] | None,
    exclude: Collection[str],
    progress: bool,
    stage: Path | None,
    reuse: bool,
    device: torch.device,
) -> TrainResult:
    """:func:`train`'s work, on the threads it set and on ``device``."""
    import torch

    clean_interrupted_writes(out)
    if reuse and (kept := _kept_by_records(dataset, cfg, val_names, exclude, out)) is not None:
        return kept
    data = _training_data(dataset, cfg, val_names, exclude)
    data_key, sampling = data_key_of(*data.arrays()), dataset.index.get("sampling")
    progress_path = progress_checkpoint_path(out, cfg, data_key)
    clean_interrupted_writes(out, progress_path.name)
    key_under = None
    if cfg.colour_input != "linear" or cfg.synthetic_share > 0:  # inputs made with the record's smoothing too
        key_under = functools.partial(_data_key_under, dataset, cfg, val_names, exclude)
    check_sampling_record(out, progress_path, cfg, data_key, dataset.folder, sampling, key_under)
    if reuse and (done := published_state(out, cfg, data_key)) is not None and _finished(done, cfg):
        if not (why := other_code(done)):
            epochs, best_epoch = done["history"], done["best"]["epoch"]
            return TrainResult(out, epochs, best_epoch, data.train_names, data.val_names, reused=True)
        # as `nlips solve` solves a result of other code again: its weights are not what this code makes
        log.warning("%s: %s: trained again, replaced when this run ends (another --out keeps it)", out, why)
    # built once the run is known to train: a reused model needs no net, and the optimiser's first construction
    # imports torch._dynamo (~1.5 s of CPU, most of a kept re-run's); the seed is set here, so its weights are the same
    net, opt, sched = _fresh_training(cfg, dataset.sensor["camera"], data.x_tr, device)
    state = resume(out, progress_path, cfg, data_key, net, opt, sched, device=device.type)
    if out.is_file() and not published_by(out, cfg, data_key):  # a better model would go unnoticed otherwise
        log.warning(
            "%s: a model is already there (not this training's: its checkpoint was made with other options or "
            "samples, or is missing); it is replaced when this run ends: give another --out to keep it",
            out,
        )
    # moved once (~2M samples x 12 floats: ~100 MB); the batches are indexed on the device, never copied per batch
    samples = [torch.from_numpy(a).to(device) for a in data.arrays()]
    samples_key = _verified_samples_key(dataset, data)
    checkpoint = functools.partial(
        save_checkpoint, progress_path, cfg, data_key, net, opt, sched, sampling=sampling, samples_key=samples_key
    )
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
    net.to("cpu").load_state_dict(best_state)  # the model file's tensors and the ONNX export: on the CPU
    model_file = out if stage is None else Path(stage) / out.name
    _save_trained(model_file, net, dataset, cfg, data, (data_key, samples_key), exclude, history, best)
    progress_file = progress_path if stage else None
    return TrainResult(out, history, best["epoch"], data.train_names, data.val_names, progress_file)


def _kept_by_records(
    dataset: CalibrationDataset,
    cfg: TrainConfig,
    val_names: Collection[str] | None,
    exclude: Collection[str],
    out: Path,
) -> TrainResult | None:
    """The finished model at ``out`` reused without reading a sample (``TrainResult.reused``), when the checkpoint
    published with it records this run's options, this training code and the samples' identity from the dataset's
    records (:meth:`.dataset.CalibrationDataset.samples_key`), and the sample files are those recorded
    (:meth:`~.dataset.CalibrationDataset.samples_changed`: sizes, then SHA-256); else None, and the samples are read
    and compared as before (:func:`_train`).

    Why: a kept re-run read and inflated every sample file to recognise its data (Q2 full's 127 MB: ~2.1 s of CPU);
    hashing the files' bytes costs ~0.1 s. Synthetic samples (``synthetic_share``) are made from the press folders
    and the reference capture, which the records do not cover: such a run reads its samples as before."""
    if cfg.synthetic_share > 0 or not out.is_file():
        return None
    train_names, val_presses = _presses(dataset, cfg, val_names, exclude)
    key = dataset.samples_key(train_names, val_presses)
    if key is None:  # a dataset built before 2026-12-07: its samples are read
        return None
    done = published_state(out, cfg, None, key)
    if done is None or not _finished(done, cfg) or other_code(done):  # trained, or said why by the reading path
        return None
    if why := dataset.samples_changed([*train_names, *val_presses]):
        log.info("%s; its samples are read to tell whether %s was trained on them", why, out)
        return None
    return TrainResult(out, done["history"], done["best"]["epoch"], train_names, val_presses, reused=True)


def _verified_samples_key(dataset: CalibrationDataset, data: _TrainingData) -> str | None:
    """The samples' identity from the dataset's records (:meth:`.dataset.CalibrationDataset.samples_key`) when its
    sample files are those recorded, else None (a checkpoint recording None is reused only by reading its samples).

    Why checked here too: a training on a file changed since the build would otherwise record the build's key, and a
    re-run after the file was put back would reuse a model trained on the changed one."""
    key = dataset.samples_key(data.train_names, data.val_names)
    if key is None or dataset.samples_changed([*data.train_names, *data.val_names]):
        return None
    return key


def _data_key_under(
    dataset: CalibrationDataset,
    cfg: TrainConfig,
    val_names: Collection[str] | None,
    exclude: Collection[str],
    sampling: dict,
) -> str:
    """The data key (:func:`.checkpoint.data_key_of`) of this run's samples under the sampling record ``sampling``
    (a checkpoint's) rather than the dataset's: the same samples, their inputs made with the record's smoothing
    (a ratio's reference, the synthetic samples'); "" when the record holds no usable smoothing."""
    try:
        px, colour = float(sampling.get("smoothing_px", 0.0)), float(sampling.get("smoothing_colour", 0.0))
        under = copy.copy(dataset)
        under.smoothing_px, under.smoothing_colour = px, colour
        return data_key_of(*_training_data(under, cfg, val_names, exclude).arrays())
    except (AttributeError, TypeError, ValueError, ConfigError):  # a record no prefilter takes: not this run's
        return ""


def _finished(state: dict, cfg: TrainConfig) -> bool:
    """Whether a checkpoint's ``state`` (its ``history`` and ``best``) leaves no epoch for ``cfg`` to train: it reached
    ``cfg.max_epochs``, or stopped early by ``cfg.patience`` (the rules of :func:`_epochs`). A run stopped by its
    time limit is not finished: run again, it continues, as :func:`.checkpoint.resume` lets it."""
    try:
        done, best = len(state["history"]), int(state["best"]["epoch"])
    except (KeyError, TypeError, ValueError):  # not a finished run's checkpoint: trained (resume says why)
        return False
    return done == cfg.max_epochs or (0 < done < cfg.max_epochs and done - 1 - best >= cfg.patience)


@dataclasses.dataclass(frozen=True)
class _TrainingData:
    """What one training runs on: the presses split for it, the dataset's reference, the labelled samples."""

    train_names: list[str]
    val_names: list[str]
    reference: dict
    """The undeformed reference arrays (``CalibrationDataset.reference``), which the model file carries."""
    x_tr: np.ndarray
    """(N, 5) float32 -- the training inputs (:func:`model_inputs`)."""
    y_tr: np.ndarray
    """(N, 3) float32, unit, camera frame -- the training targets (normals)."""
    x_va: np.ndarray
    """(M, 5) float32 -- the validation inputs."""
    y_va: np.ndarray
    """(M, 3) float32, unit, camera frame -- the validation targets."""
    c_va: np.ndarray
    """(M,) bool -- the validation samples in contact."""
    synthetic: int = 0
    """How many of the training samples (the last ones of ``x_tr``) are synthetic (:mod:`.synthetic`)."""

    def arrays(self) -> tuple[np.ndarray, ...]:
        """x_tr, y_tr, x_va, y_va, c_va: what the epochs run on and the checkpoint's data key digests."""
        return self.x_tr, self.y_tr, self.x_va, self.y_va, self.c_va


def _training_data(
    dataset: CalibrationDataset, cfg: TrainConfig, val_names: Collection[str] | None, exclude: Collection[str]
) -> _TrainingData:
    """The presses split for training (:func:`_presses`) and their labelled samples; ConfigError when too few
    samples are labelled or none is in contact, and (from ``dataset.reference``) when the reference is unreadable."""
    train_names, val_names = _presses(dataset, cfg, val_names, exclude)
    reference = dataset.reference()  # checked now, not after the whole training (the model file carries it)
    divide = input_reference(
        reference, dataset.smoothing_px, dataset.smoothing_colour, cfg.colour_input, cfg.reference_smoothing_px
    )
    x_tr, y_tr, c_tr = training_arrays(dataset.arrays(train_names), cfg.labels, divide)
    x_va, y_va, c_va = training_arrays(dataset.arrays(val_names), cfg.labels, divide)
    synthetic = 0
    if cfg.synthetic_share > 0 and len(x_tr):
        from .synthetic import samples_for_dataset

        count = round(cfg.synthetic_share * len(x_tr))
        syn = samples_for_dataset(dataset, train_names, count, cfg.seed, cfg.synthetic_reflectance)
        synthetic = len(syn["rgb"])
        log.info(
            "%s: %d synthetic samples of steep relief added to %d training samples",
            dataset.folder,
            synthetic,
            len(x_tr),
        )
        x_tr = np.concatenate([x_tr, model_inputs(syn["pixel"], syn["rgb"], divide)])
        y_tr = np.concatenate([y_tr, syn["normal"]])
    if len(x_tr) < 2 or len(x_va) < 1:
        raise ConfigError(f"{dataset.folder}: too few labelled samples to train ({len(x_tr)} train, {len(x_va)} val)")
    if not (c_tr.any() or c_va.any()):
        raise ConfigError(no_contact_error(dataset, len(train_names) + len(val_names), len(x_tr) + len(x_va)))
    return _TrainingData(train_names, val_names, reference, x_tr, y_tr, x_va, y_va, c_va, synthetic)


def _fresh_training(cfg: TrainConfig, camera: dict, x_tr: np.ndarray, device: torch.device):
    """(net, optimiser, scheduler) of a training from scratch on ``device``: torch's seed set from ``cfg`` (the
    weights' initialisation draws from it, on the CPU: the same initial weights on every device), the net sized for
    ``camera``'s image and its colour normalisation taken from the training inputs ``x_tr`` (N, 5)."""
    import torch

    torch.manual_seed(cfg.seed)
    net = build_net(cfg.hidden, cfg.dropout, camera["width"], camera["height"])
    set_colour_normalisation(net, x_tr[:, 2:])
    net.to(device)  # before the optimiser, whose state then lives beside the weights
    if cfg.weight_decay:  # decoupled from the gradient's step (Adam's own weight_decay adds it to the gradient)
        opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    else:
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr)
    return net, opt, _scheduler(opt, cfg)


def _save_trained(
    path: Path,
    net: torch.nn.Module,
    dataset: CalibrationDataset,
    cfg: TrainConfig,
    data: _TrainingData,
    keys: tuple[str, str | None],
    exclude: Collection[str],
    history: list[dict],
    best: dict,
) -> None:
    """Write the model file ``path``: ``net`` (its best weights loaded), the sensor and reference it was trained for,
    and what the training was (``info``: options, presses, samples, best epoch, history).

    The dataset is named by its folder's name and by the digest of the samples trained on (``data_key``,
    :func:`.checkpoint.data_key_of`), not by its absolute path: that changed the file's bytes (and its digest, which
    ``nlips infer`` keys results on) when the data moved, and told whoever received the model the lab's folders.
    ``keys``: (``data_key``, ``samples_key``: :func:`_verified_samples_key`). The capture identities of its
    training and validation presses (``captures``, index.json's ``capture_identity``: null where it records none)
    let ``nlips infer`` tell a press it learnt from from another of the same name (report.json ``trained_on``); their
    identities by content (``press_identities``, index.json's ``press_identity``: null where it records none) tell a
    copy of one with another meta.json, and an image frame of its tri-colour pixels, as the press (:mod:`.seen`)."""
    data_key, samples_key = keys
    names = data.train_names + data.val_names
    info = {
        "labels": cfg.labels,
        "config": jsonable_config(cfg),
        "dataset": dataset.folder.resolve().name,
        "samples_digest": data_key,
        "samples_key": samples_key,
        CAPTURES_KEY: {name: dataset.entry(name).get(CAPTURE_IDENTITY) for name in names},
        IDENTITIES_KEY: {name: dataset.entry(name).get(IDENTITY_KEY) for name in names},  # by content (learn.seen)
        "capture": dataset.capture,  # what `nlips infer` names when a press was taken otherwise
        "train_presses": data.train_names,
        "val_presses": data.val_names,
        "excluded_presses": sorted(exclude),
        "train_samples": int(len(data.x_tr)),
        "synthetic_samples": data.synthetic,  # of train_samples: model-made steep relief (TrainConfig.synthetic_share)
        "best_epoch": best["epoch"],
        "best_val_aae_deg": best["aae"],
        "history": history,
        # how large and steep the taught contacts were: `nlips infer` warns beyond them (learn.resolution)
        INFO_KEY: calibrated_contacts(dataset, data.train_names + data.val_names, cfg.labels),
    }
    save_model(
        path,
        net,
        hidden=cfg.hidden,
        dropout=cfg.dropout,
        sensor=dataset.sensor,
        reference=data.reference,
        info=info,
        smoothing_px=dataset.smoothing_px,
        smoothing_colour=dataset.smoothing_colour,
        colour_input=cfg.colour_input,
        reference_smoothing_px=cfg.reference_smoothing_px,
    )


def no_contact_error(dataset: CalibrationDataset, presses: int, samples: int) -> str:
    """Why a dataset without contact samples is not trained on: the network would learn the undeformed dome alone
    (every validation figure of contact would be NaN)."""
    return (
        f"{dataset.folder}: no contact samples: none of the {samples} samples of its {presses} presses differ from "
        "the reference frame (the tri-colour frames show the undeformed dome), so the network has no press to learn "
        "from: check that the presses were pressed, and exposed like the reference (neither black nor saturated: "
        "`nlips calibrate` prints the contact samples), then capture them again"
    )


def _presses(
    dataset: CalibrationDataset, cfg: TrainConfig, val_names: Collection[str] | None, exclude: Collection[str]
) -> tuple[list[str], list[str]]:
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
    if val_names:
        _check_validation_presses(dataset, set(val_names), names, set(exclude))
    return split_by_press(names, cfg.val_fraction, cfg.seed, val_names)


def _check_validation_presses(
    dataset: CalibrationDataset, val_names: set[str], usable: list[str], exclude: set[str]
) -> None:
    """One line naming the dataset and why ``val_names`` cannot be validated on: a press it does not list, one
    also excluded or without the labels asked for (each was "not in the dataset"), or all the usable presses."""
    where = dataset.folder / INDEX_FILE
    if unknown := sorted(val_names - set(dataset.names)):
        raise ConfigError(
            f"{where}: --val-presses {', '.join(unknown)}: not among its presses ({', '.join(dataset.names)})"
        )
    if both := sorted(val_names & exclude):
        raise ConfigError(f"{where}: {', '.join(both)} given to both --val-presses and --exclude: give each to one")
    if unlabelled := sorted(val_names - set(usable)):
        raise ConfigError(
            f"{where}: --val-presses {', '.join(unlabelled)}: no ground truth to validate on (--labels true)"
        )
    if val_names >= set(usable):
        raise ConfigError(
            f"{where}: --val-presses holds all {len(usable)} presses left to train on"
            f"{f' ({len(exclude)} excluded)' if exclude else ''}: leave at least one for training"
        )


EPOCH_SEED_STRIDE = 7919
"""Epoch k reseeds torch's global generator (dropout) with seed + stride (k + 1): apart from the seeds of the
weights' initialisation (seed) and of the batch order (seed + k)."""


def _epochs(
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    sched: torch.optim.lr_scheduler.LRScheduler,
    samples: Sequence[torch.Tensor],
    cfg: TrainConfig,
    state: dict,
    checkpoint: Callable[..., None],
    progress: bool,
):
    """Train from ``state`` (:func:`.checkpoint.resume`) until early stopping, ``cfg.max_epochs`` or
    ``cfg.max_seconds``, checkpointing every epoch (``checkpoint(history, best, best_state)``); returns (history,
    best, best_state).

    ``samples``: tensors x_train, y_train, x_val, y_val, contact_val."""
    import torch

    from ..progress import FILE_ONLY, progress_bar

    xt, yt, xv, yv, cv = samples
    history, best, best_state = state["history"], state["best"], state["best_state"]
    start = time.perf_counter() - sum(h["seconds"] for h in history)
    # the labels named: q2 trains on NLiPs labels, then on true normals, and two bare "training" bars read as a restart
    desc = TRAINING_BARS.get(cfg.labels, "training")
    # closed on Ctrl-C too (``with``): a notebook keeps the interrupted frames, and a bar left open nests the next one
    with progress_bar(cfg.max_epochs, enabled=progress, initial=len(history), desc=desc, unit="epoch") as bar:
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
                    "threads": cfg.threads,  # the count rounds the weights: a resume on another says so
                    "device": xt.device.type,  # so does the device, and it draws other dropout masks
                }
            )
            if val_aae < best["aae"]:
                best = {"aae": val_aae, "epoch": epoch}
                # a copy on the CPU (a clone there): what the checkpoint and the model file hold, whatever the device
                best_state = {k: v.detach().to("cpu", copy=True) for k, v in net.state_dict().items()}
            checkpoint(history, best, best_state)
            log.info(
                "%s: epoch %d of at most %d: training loss %.4g, validation AAE %.3f deg (contact %.3f), learning rate "
                "%.3g, %.1f s; best epoch %d",
                desc,
                epoch + 1,
                cfg.max_epochs,
                loss,
                val_aae,
                val_contact,
                history[-1]["lr"],
                history[-1]["seconds"],
                best["epoch"] + 1,
                extra=FILE_ONLY,
            )
            bar.update(1)
            bar.set_postfix(val_aae=f"{val_aae:.2f}")
            stop_early = epoch - best["epoch"] >= cfg.patience
            if stop_early or (cfg.max_seconds and time.perf_counter() - start > cfg.max_seconds):
                break
    return history, best, best_state


def _scheduler(opt: torch.optim.Optimizer, cfg: TrainConfig):
    import torch

    if cfg.schedule == "plateau":
        return torch.optim.lr_scheduler.ReduceLROnPlateau(
            opt, factor=cfg.lr_factor, patience=cfg.lr_patience, min_lr=cfg.lr * 0.01
        )
    return torch.optim.lr_scheduler.CosineAnnealingLR(opt, cfg.max_epochs, eta_min=cfg.lr * 0.05)


def _epoch(
    net: torch.nn.Module,
    opt: torch.optim.Optimizer,
    x: torch.Tensor,
    y: torch.Tensor,
    batch_size: int,
    gen: torch.Generator,
) -> float:
    import torch

    net.train()
    # drawn on the CPU (the same order on every device), then on the data's device once per epoch
    order = torch.randperm(len(x), generator=gen).to(x.device)
    # summed on the device in float64 (as Python's float did, so the CPU's sum is bit for bit the earlier one):
    # reading each batch's loss would make the CPU wait for a GPU at every step
    total, count = torch.zeros((), dtype=torch.float64, device=x.device), 0
    for start in range(0, len(x), batch_size):
        idx = order[start : start + batch_size]
        if len(idx) < 2:  # BatchNorm needs two samples
            continue
        opt.zero_grad()
        loss = cosine_loss(net(x[idx]), y[idx])
        loss.backward()
        opt.step()
        total += loss.detach().double() * len(idx)
        count += len(idx)
    return float(total) / max(count, 1)


def _validate(net: torch.nn.Module, x: torch.Tensor, y: torch.Tensor, contact: torch.Tensor) -> tuple[float, float]:
    """Validation AAE over all samples and over the contact samples, degrees."""
    import torch

    net.eval()
    with torch.no_grad():
        cos = (net(x) * y).sum(-1).clamp(-1, 1)
    # core.metrics.angle_deg's angle, on the training device (arccos: a running figure, not the reported AAE)
    ang = torch.rad2deg(torch.arccos(cos))
    contact_aae = float(ang[contact].mean()) if bool(contact.any()) else float("nan")
    return float(ang.mean()), contact_aae
