"""NLiPsNet in the experiments: the press tasks' samples as one calibration dataset, trained models, scores.

Wiring to nlipscalib.learn (dataset format, training, evaluation; the lookup-table baseline is
``learn.lut.fit_lookup_table``, `nlips lut`'s fit); runs in the
process that runs the experiment, after the press tasks. Every model is keyed by its training options
and the identities of its presses' samples: ``learned/<key>.pt`` (+ ``.json`` when finished) is
reused by a later run and by other experiments sharing the work folder; an interrupted training
resumes from its checkpoint (learn.train).
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import write_json
from ..core.errors import CaptureError, ConfigError
from ..core.imageio import read_npz
from .tasks import Task, dataset_entry, digest, reference_folder, samples_problem, stored_result, view_path

if TYPE_CHECKING:  # named in hints only: each function imports the learn/ modules it uses
    from ..learn.dataset import CalibrationDataset
    from ..learn.train import TrainConfig

log = logging.getLogger(__name__)
DATASET_DIR = "calibration"
MODELS_DIR = "learned"
Predictor = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""A calibration method as :func:`score` compares them: (pixel (N, 2) int, u and v; rgb (N, 3) float, the
samples' colours) -> (N, 3) float unit normals, camera frame."""


def assemble_dataset(out: Path, tasks: list[Task], sampling: dict) -> tuple[CalibrationDataset, dict[str, str]]:
    """The finished press tasks' samples as a learn.dataset calibration folder ``OUT/calibration``.

    Returns
    -------
    (CalibrationDataset, stamps) : the dataset and, per press name (task id), the identity of its samples
    """
    from ..core.capture import load_press
    from ..core.sensor_record import sensor_of
    from ..learn.dataset import (
        EXPERIMENT_MAKER,
        CalibrationDataset,
        SamplingConfig,
        reference_arrays,
        write_index,
        write_shard,
    )

    out = Path(out)
    folder = out / DATASET_DIR
    press_tasks = [t for t in tasks if t.kind == "press" and t.samples is not None]
    scenes = {json.dumps(t.scene, sort_keys=True) for t in press_tasks}
    if len(scenes) != 1:
        raise ConfigError(f"an NLiPsNet dataset needs presses of one sensor (scene), got {len(scenes)}")
    entries, stamps = [], {}
    for t in press_tasks:
        result = stored_result(out, t)
        info = (result or {}).get("samples") or {}
        if not info.get("file"):  # task failed or not done (the report lists it), or its label solve failed
            continue
        if problem := samples_problem(out, t, result):
            # checked as the tasks were run: another run of other settings rewrote it since, or the disk damaged it
            raise CaptureError(f"{problem}; run the experiment again to make it anew")
        stamps[t.id] = t.hash
        entries.append(dataset_entry(out, t, info))
    ref_folder = reference_folder(out, press_tasks[0].scene)
    ref_press = load_press(ref_folder)
    write_shard(folder / "sensor.npz", reference_arrays(ref_press))
    cfg = SamplingConfig(**sampling)
    write_index(folder, sensor_of(ref_press), cfg, entries, str(ref_folder.resolve()), made_by=EXPERIMENT_MAKER)
    return CalibrationDataset(folder), stamps


def train_model(
    data: CalibrationDataset, names: list[str], stamps: dict, cfg: TrainConfig, out: Path, progress: bool = True
) -> dict:
    """Train NLiPsNet on the presses ``names`` (split by press into training and validation), or reuse it.

    Returns
    -------
    dict: key, model (path relative to ``out``), train/val presses, epochs, best epoch and validation
    AAE, training seconds, history (per epoch)
    """
    from ..core.claims import claim

    key, path, record = model_files(out, names, stamps, cfg)
    waited = False
    while (done := _finished(path, record, key)) is None:
        # another run sharing the folder may be training this model: wait for its record rather than train it
        # a second time over the same checkpoint and score a model file that the other run then replaces
        with claim(path) as mine:
            if mine:
                return _finished(path, record, key) or _train(data, names, cfg, key, path, record, out, progress)
        if not waited:
            log.info("%s: another run is training this model; waiting for it", path)
            waited = True
        time.sleep(1.0)
    log.info("%s: reused (trained before on the same presses with the same options)", path)
    return done


def model_files(out: Path, names: list[str], stamps: dict, cfg: TrainConfig) -> tuple[str, Path, Path]:
    """Key, model file and record of the model trained with ``cfg`` on the presses ``names``.

    The key hashes the training options and each press's sample identity (``stamps``), so a changed press
    or option never reuses a stale model.
    """
    from ..learn.checkpoint import jsonable_config

    # jsonable_config: the options as asdict has them, less the synthetic ones while synthetic_share is 0 (so the keys
    # of the models that earlier runs trained stay theirs)
    options = jsonable_config(cfg)
    key = digest({"train": options, "presses": [[n, stamps[n]] for n in names]}, 16)
    folder = Path(out) / MODELS_DIR
    return key, folder / f"nlipsnet-{key}.pt", folder / f"nlipsnet-{key}.json"


def _finished(path: Path, record: Path, key: str) -> dict | None:
    """The stored record of the model ``key`` when its training has finished, else None."""
    if not (path.is_file() and record.is_file()):
        return None
    try:
        done = json.loads(record.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError):
        return None
    return done if done.get("key") == key else None


def _train(
    data: CalibrationDataset,
    names: list[str],
    cfg: TrainConfig,
    key: str,
    path: Path,
    record: Path,
    out: Path,
    progress: bool,
) -> dict:
    """Train the model ``key`` (resuming its checkpoint) and write its record; the caller holds its claim."""
    from ..learn.train import train

    path.parent.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    others = [n for n in data.names if n not in set(names)]
    # on cfg.threads as configured (1 unless the config says), which the key holds: every core of the client was
    # 2.5-25x slower on a shared machine, and made a model that differs with the machine's core count
    res = train(data, cfg, path, exclude=others, progress=progress)
    done = {
        "key": key,
        "model": path.relative_to(out).as_posix(),  # / on every system: a folder moves between them
        "labels": cfg.labels,
        "hidden": list(cfg.hidden),
        "train_presses": res.train_presses,
        "val_presses": res.val_presses,
        "epochs": len(res.history),
        "best_epoch": res.best_epoch,
        "best_val_aae_deg": res.history[res.best_epoch]["val_aae_deg"] if res.history else None,
        "train_seconds": round(time.perf_counter() - start, 1),
        "history": res.history,
    }
    write_json(record, done)
    return done


def undeformed_predictor(data: CalibrationDataset) -> Predictor:
    """(pixel, rgb) -> the undeformed dome's normals there: what "no calibration at all" predicts."""
    normals = data.reference()["normals"]
    return lambda pixel, rgb: normals[pixel[:, 1], pixel[:, 0]]


def score(data: CalibrationDataset, predictors: dict[str, Predictor], test_sets: dict[str, list[str]]) -> list[dict]:
    """AAE of every predictor on the contact samples of every test set, against NLiPs labels and true normals.

    Parameters
    ----------
    data : CalibrationDataset
    predictors : method name -> callable (pixel (N, 2), rgb (N, 3)) -> (N, 3) unit normals
    test_sets : split name -> press names

    Returns
    -------
    list of rows: split, method, presses, contact_samples, aae_vs_nlips_deg, aae_vs_true_deg; plus
    a row "NLiPs (the labels)" scored against the true normals on the contact samples NLiPs labelled
    """
    from ..core.metrics import aae
    from ..learn.evaluate import sample_scores

    rows = []
    for split, names in test_sets.items():
        if not names:
            continue
        s = data.arrays(names)
        for method, predict in predictors.items():
            scores = sample_scores(predict(s["pixel"], s["rgb"]), s)
            rows.append({"split": split, "method": method, "presses": len(names)} | scores)
        labelled = s["contact"] & (s["source"] == 0) & np.all(np.isfinite(s["true_normal"]), -1)
        rows.append(
            {
                "split": split,
                "method": "NLiPs (the labels)",
                "presses": len(names),
                "contact_samples": int(labelled.sum()),
                "aae_vs_nlips_deg": 0.0,
                "aae_vs_true_deg": aae(s["normal"][labelled], s["true_normal"][labelled]) if labelled.any() else None,
            }
        )
    return rows


def press_scores(data: CalibrationDataset, predict: Predictor, names: list[str]) -> list[dict]:
    """Each press's AAE on its own contact samples, as :func:`score` scores a split (one press a split).

    Parameters
    ----------
    data : CalibrationDataset
    predict : callable (pixel (N, 2), rgb (N, 3)) -> (N, 3) unit normals
    names : press names

    Returns
    -------
    list of dicts, one per name: contact_samples, aae_vs_nlips_deg, aae_vs_true_deg (NaN where none scored)
    """
    from ..learn.evaluate import sample_scores

    rows = []
    for name in names:
        s = data.arrays([name])
        rows.append(sample_scores(predict(s["pixel"], s["rgb"]), s))
    return rows


def steepness(data: CalibrationDataset, groups: dict[str, list[str]], tilts_deg: tuple[float, ...]) -> list[dict]:
    """How steep the true normals of each group's contact samples are, relative to the undeformed surface.

    NLiPsNet maps colour to normal pixel by pixel and extrapolates past the tilts its calibration presses
    taught; this table shows where a test split leaves them (``learn.coverage`` asks for such presses).

    Parameters
    ----------
    data : CalibrationDataset
    groups : "split/indenter" -> press names
    tilts_deg : tilts (deg from the undeformed normal) whose exceedance is reported

    Returns
    -------
    list of rows: split, indenter, contact_samples, tilt_p99_deg and, per t of ``tilts_deg``,
    ``beyond_<t>_pct`` (% of the samples tilted more than t deg)
    """
    from ..learn.coverage import tilt_deg

    ref = data.reference()["normals"]
    rows = []
    for key, names in groups.items():
        if not names:
            continue
        split, indenter = key.split("/", 1)
        s = data.arrays(names)
        keep = s["contact"] & np.all(np.isfinite(s["true_normal"]), -1)
        u, v = s["pixel"][keep, 0].astype(int), s["pixel"][keep, 1].astype(int)
        tilt = tilt_deg(s["true_normal"][keep], ref[v, u])
        row = {"split": split, "indenter": indenter, "contact_samples": int(keep.sum())}
        row["tilt_p99_deg"] = float(np.percentile(tilt, 99)) if tilt.size else None
        for t in tilts_deg:
            row[f"beyond_{t:.0f}_pct"] = float(100 * np.mean(tilt > t)) if tilt.size else None
        rows.append(row)
    return rows


def net_predictor(out: Path, record: dict, threads: int) -> Predictor:
    """(pixel, rgb) -> normals of a trained model (its record from :func:`train_model`), on ``threads`` PyTorch
    threads (the training's ``TrainConfig.threads``), then the process's count again.

    Why not the process's count (every core): on the shared 2-core VM 200,000 samples took 1.1-1.7 s of wall on 2
    threads against 0.3-0.4 s on 1 (64-64-64 net; paper net 3.6 against 2.4-2.6 s; load ~7), for the same bits;
    and the scores no longer depend on how many cores the machine running the report has."""
    from ..learn.evaluate import net_predict
    from ..learn.model import load_model
    from ..learn.torch_device import torch_threads

    model = load_model(Path(out) / record["model"])

    def predict(pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        with torch_threads(threads):
            return net_predict(model, pixel, rgb)

    return predict


def predicted_views(out: Path, predict: Predictor, names: list[str]) -> list[tuple[str, dict]]:
    """Per press name with a stored crop: object image, true and predicted normals, angular error (degrees)."""
    from ..core.metrics import angular_error_map

    views = []
    for name in names:
        path = view_path(out, name)
        if not path.is_file():
            continue
        # a damaged crop (a copied or cut-short folder) is one line naming it, not numpy's traceback
        z = read_npz(path, ("rgb", "true", "origin"), "damaged or truncated figure crop")
        rgb, true, (x0, y0) = z["rgb"], z["true"], z["origin"]
        colours = z.get("input", rgb)  # the network's (filtered) input colours
        h, w = true.shape[:2]
        rows, cols = np.mgrid[0:h, 0:w]
        pixel = np.stack([cols.ravel() + x0, rows.ravel() + y0], -1)
        shown = np.all(np.isfinite(true), -1) & np.all(np.isfinite(rgb), -1)
        pred = np.full((h * w, 3), np.nan, np.float32)
        shown &= np.all(np.isfinite(colours), -1)
        pred[shown.ravel()] = predict(pixel[shown.ravel()], colours.reshape(-1, 3)[shown.ravel()])
        pred = pred.reshape(h, w, 3)
        views.append((name, {"rgb": rgb, "true": true, "estimate": pred, "error": angular_error_map(pred, true)}))
    return views
