"""The calibration dataset: (u, v, r, g, b) -> n samples from solved presses, one shard per press.

Layout (see docs/formats.md, "Calibration dataset")::

    calib/
      index.json        format, version, sensor, sampling options, one entry per press (written last)
      sensor.npz        the undeformed reference: tri-colour (linear), dark frame, depth, normals, valid
      samples/press_0003.npz   the samples of one press (below)

A shard holds, for N samples of one press:

- ``pixel`` (N, 2) int16: (u, v) = (column, row) of the sample
- ``rgb`` (N, 3) float32: the tri-colour image there, linear (``Press.linear``), low-pass filtered
  with the sampling options' ``smoothing_px`` (and ``smoothing_colour``: :mod:`.prefilter`)
- ``normal`` (N, 3) float32, unit, camera frame: the label (NLiPs normal; reference normal on the
  undeformed rest outside the solved region)
- ``true_normal`` (N, 3) float32: the twin's true normal (NaN when the press has no ground truth)
- ``contact`` (N,) bool: the pixel differs from the undeformed reference frame
- ``source`` (N,) uint8: 0 = NLiPs label, 1 = reference-surface label

and, written by :func:`build_dataset`, ``entry`` (uint8): the press's index.json entry as UTF-8 JSON,
with the ``stamp`` of the reconstruction and options it was made from.

Shards load one press at a time (:meth:`CalibrationDataset.load`), so training holds the samples,
never the 12 LED images of each press. Every file is written atomically (owner-tagged temporary
names, core.atomic), so several builds may share a folder; an interrupted build resumes: a shard
whose recorded stamp matches is kept (index.json is written last, so the shards carry their own
entries), a missing, damaged or outdated one is made again. The builds of one dataset (the same presses,
reference, sampling and solve options) hold the folder together and make each shard once, under its claim;
a build of another dataset into a held folder is refused (:func:`hold_dataset`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import logging
import os
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .. import __version__
from ..core import said_once
from ..core.atomic import write_by_name, write_json
from ..core.claims import wait_for_release
from ..core.config import OMIT_AT, to_mapping
from ..core.errors import PATH, CaptureError, ConfigError, check_flag, check_kind, check_paths
from ..core.file_checks import file_problem
from ..core.formatfile import read_array_headers, read_arrays, read_format_json
from ..core.imageio import save_npz
from ..core.sensor_record import (
    capture_settings,
    check_sensor,
    check_sensor_record,
    common_settings,
    response_mismatch,
    sensor_of,
)
from ..core.shell_words import shell_word
from ..core.tolerances import FRAME_CHANNEL_DRIFT
from ..progress import track
from .change import RULE_VERSION, ChangeDetector
from .dataset_tricolor import KEEP_OPTION, disagrees, index_record, reordered, sort_presses
from .dataset_tricolor import RECORD_KEY as TRICOLOR_KEY
from .prefilter import Prefilter, check_colour_sigma, check_sigma

if TYPE_CHECKING:  # named in hints only: the functions import the capture and reconstruction modules where used
    from ..core.capture import Press
    from ..core.claims import Owner
    from ..core.reconstruction import Reconstruction

DEFAULT_DIR = "calibration"
"""Where ``nlips calibrate PRESSES`` writes the dataset by default: ``PRESSES/calibration``."""
FORMAT_NAME = "nlipscalib.calibration"
FORMAT_VERSION = 1
INDEX_FILE = "index.json"
SENSOR_FILE = "sensor.npz"
SHARD_DIR = "samples"
SHARD_KEYS = {"pixel": 2, "rgb": 2, "normal": 2, "true_normal": 2, "contact": 1, "source": 1}
SENSOR_KEYS = ("tricolor", "dark", "depth", "normals", "valid")
EXPERIMENT_MAKER = "nlips experiment"
"""index.json's ``made_by`` in a dataset that ``nlips experiment`` assembled from its press tasks' samples (absent:
``nlips calibrate``'s): what a refusal tells the user to run again (:func:`remake_advice`)."""
FRAME_GAIN_RULE = 1
"""Version of :func:`contact_pixels`' rule for a press brighter or dimmer than the undeformed capture (its reference
frame scaled by the press's brightness; s28-together, 2026-12-06). Shards made before it kept almost none of such a
press's contact samples; as part of :data:`SAMPLE_RULES` they are made anew."""
SAMPLE_RULES: dict[str, int] = {"rule": RULE_VERSION, "frame_gain": FRAME_GAIN_RULE}
"""Versions of the code that decides a press's samples beyond its reconstruction and the sampling options (name ->
version; today the change-detection rule's, :mod:`.change`, and :data:`FRAME_GAIN_RULE`). The one list: part of
every shard's stamp (:func:`shard_stamp`), of a build's key (:func:`dataset_run`) and of an experiment's press task
(experiments.tasks.Task.hash), so a bumped version remakes the samples wherever they were made. A rule whose code
decides samples adds its version here."""
SOURCE_NLIPS, SOURCE_REFERENCE = 0, 1
ENTRY_KEY = "entry"
"""Shard array holding the press's index entry (UTF-8 JSON bytes), so a build resumes without index.json."""

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SamplingConfig:
    """Which pixels of a solved press become samples."""

    min_confidence: float = 0.5
    """NLiPs pixels with a lower confidence (usable LED fraction x robust weight) are left out."""
    min_leds: int = 4
    """NLiPs pixels lit by fewer usable LEDs are left out."""
    rest_cells: int = 8
    """The undeformed rest is sampled on a rest_cells x rest_cells grid of image cells ..."""
    rest_per_cell: int = 24
    """... with at most this many random pixels per cell (stratified, so every dome region is seen)."""
    seed: int = 0
    """Seed of the stratified sample (mixed with the press name)."""
    smoothing_px: float = 1.0
    """Sigma (pixels) of the Gaussian low-pass applied to the tri-colour image before its colours become
    samples (:mod:`.prefilter`: cuts per-pixel sensor noise ~3.5x); the model file carries it and
    inference filters alike. 0: raw pixels."""
    smoothing_colour: float = dataclasses.field(default=0.08, metadata={OMIT_AT: 0.0})
    """Colour sigma of that low-pass (linear units, the L1 distance of two pixels' r, g, b): > 0 makes it stop at
    colour edges (:mod:`.prefilter`'s bilateral filter), so that a steep wall's colour does not bleed into the flat
    gel beside it (full-size Q2, two training seeds: unseen 3.54 / 3.60 -> 3.25 / 3.26 deg vs truth, the coin
    7.07 -> 6.28, seen unchanged; docs/experiments/RESULTS.md, s34-coinflat; the default since the thirty-fifth
    session). 0: the Gaussian alone, as before; then left out of the sampling record (:func:`sampling_record`), so
    datasets made with it keep their keys. The model file carries it and inference filters alike."""

    def __post_init__(self):
        # every message starts with the field's name: `nlips calibrate` names its option instead
        if not (isinstance(self.min_confidence, (int, float)) and 0 <= self.min_confidence <= 1):
            raise ConfigError(
                f"min_confidence must be in [0, 1] (a pixel's confidence lies there), got {self.min_confidence!r}"
            )
        for name, minimum in (("min_leds", 0), ("rest_cells", 1), ("rest_per_cell", 0), ("seed", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
                raise ConfigError(f"{name} must be an integer >= {minimum}, got {value!r}")
        check_sigma(self.smoothing_px, "smoothing_px")
        check_colour_sigma(self.smoothing_colour, "smoothing_colour")


def sampling_record(cfg: SamplingConfig) -> dict:
    """``cfg`` as JSON values, as index.json records it and the keys of builds, shards and experiment tasks hash it:
    ``smoothing_colour`` left out while it is 0 (the Gaussian alone; ``core.config.OMIT_AT``), so that every
    dataset, shard and task made before the option keeps its record and key, and written out at any other value,
    the default 0.08 included."""
    return to_mapping(cfg)


# ---------------------------------------------------------------------- building
def reference_arrays(reference_press: Press) -> dict:
    """The undeformed reference a calibration keeps: tri-colour (linear), dark frame, depth, normals, valid.

    Parameters
    ----------
    reference_press : core.Press of the undeformed dome, with its reference.npz

    Returns
    -------
    dict: tricolor (H, W, 3) float32 linear; dark (H, W, 3) uint16; depth (H, W) float32 mm (NaN off
    the gel); normals (H, W, 3) float32 unit camera frame; valid (H, W) bool
    """
    ref = reference_press.reference
    if ref is None:
        raise CaptureError(f"{reference_press.folder}: the undeformed reference needs reference.npz (dome surface)")
    return {
        "tricolor": reference_press.linear(reference_press.tricolor),
        "dark": reference_press.dark,
        "depth": ref.depth.astype(np.float32),
        "normals": ref.normals.astype(np.float32),
        "valid": np.isfinite(ref.depth),
    }


def press_samples(press: Press, rec: Reconstruction, ref: dict, cfg: SamplingConfig) -> dict:
    """Samples of one solved press: every reliable NLiPs pixel of the contact, a stratified sample of the rest.

    Parameters
    ----------
    press : core.Press
    rec : core.Reconstruction of that press (full image grid)
    ref : :func:`reference_arrays` of the undeformed dome
    cfg : SamplingConfig

    Returns
    -------
    dict of the shard arrays (module docstring)
    """
    tri = press.linear(press.tricolor)
    valid = ref["valid"] & np.all(np.isfinite(tri), -1)
    contact, gain = contact_pixels(tri, ref["tricolor"], valid)
    if gain is not None:  # the network's colours at its reference frame's brightness (what a refresh maps to)
        _say_gain(press, gain)
        tri = tri / gain.astype(tri.dtype)
    finite = np.all(np.isfinite(rec.normals), -1)
    reliable = rec.reconstructed & finite & (rec.confidence >= cfg.min_confidence) & (rec.usable_leds >= cfg.min_leds)
    take_contact = contact & reliable
    rest = valid & ~contact & ~(rec.mask & ~reliable)  # an unreliable solved pixel never becomes a label
    rng = np.random.default_rng([cfg.seed, int(hashlib.sha1(press.folder.name.encode()).hexdigest()[:8], 16)])
    take_rest = _stratified(rest, cfg.rest_cells, cfg.rest_per_cell, rng)
    rows, cols = np.nonzero(take_contact | take_rest)
    use_nlips = reliable[rows, cols]
    normal = np.where(use_nlips[:, None], rec.normals[rows, cols], ref["normals"][rows, cols])
    gt = press.ground_truth
    true = gt.normals[rows, cols] if gt is not None else np.full((len(rows), 3), np.nan, np.float32)
    if gt is not None:
        true = np.where(gt.valid[rows, cols][:, None], true, np.nan)
    return {
        "pixel": np.stack([cols, rows], -1).astype(np.int16),
        "rgb": Prefilter(ref["valid"], cfg.smoothing_px, cfg.smoothing_colour)(tri)[rows, cols],
        "normal": normal.astype(np.float32),
        "true_normal": true.astype(np.float32),
        "contact": contact[rows, cols],
        "source": np.where(use_nlips, SOURCE_NLIPS, SOURCE_REFERENCE).astype(np.uint8),
    }


def contact_pixels(frame: np.ndarray, reference: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """The pixels of a press's tri-colour ``frame`` that differ from the undeformed ``reference`` frame, the
    reference first scaled by the frame's brightness over it when that strays (LEDs aged, the exposure or gain
    changed between the undeformed capture and the presses).

    Parameters
    ----------
    frame, reference : (H, W, 3) float, linear tri-colour images (``Press.linear``)
    valid : (H, W) bool -- pixels that see the gel

    Returns
    -------
    contact : (H, W) bool
    gain : (3,) float64, the frame's red, green, blue over the reference's on the unchanged gel
        (:attr:`.change.ChangeDetector.channel_ratio`) when one strays by more than
        :data:`~nlipscalib.core.tolerances.FRAME_CHANNEL_DRIFT`, else None (the rule as before, bit for bit)

    Why: the change rule finds what differs from the rest of the frame; presses 10 % dimmer than the undeformed
    capture differ everywhere, and a twin session of 6 presses kept 3,904 of its 36,724 contact samples (the cube
    none), silently (benchmarks/RESULTS.md, s28-together).
    """
    detector = ChangeDetector(reference, valid)
    contact = detector(frame)
    gain = detector.channel_ratio
    if np.all(np.abs(gain - 1) <= FRAME_CHANNEL_DRIFT):
        return contact, None
    return ChangeDetector(reference * gain.astype(reference.dtype), valid)(frame), gain


def _say_gain(press: Press, gain: np.ndarray) -> None:
    """A press's tri-colour frame brighter or dimmer than the undeformed capture's: a WARNING once per session (the
    presses of one folder: LEDs aged, or an exposure changed, for all of them), each press at INFO."""
    colours = ", ".join(f"{name} {g:.2f}" for name, g in zip(("red", "green", "blue"), gain))
    note = (
        f"{press.folder}: its tri-colour frame is {colours} times as bright as the undeformed capture's on the "
        f"unchanged gel (LEDs aged, or the exposure or gain changed between them): its contact told apart and its "
        f"colours sampled at the undeformed capture's brightness, the model's reference frame; frames captured like "
        f"the presses are read as drifted: give `nlips infer --reference` an undeformed capture taken with them"
    )
    if said_once.first_time(f"tri-colour gain\0{press.folder.parent}"):
        log.warning("%s (said once for the presses of %s)", note, press.folder.parent)
    else:
        log.info("%s", note)


def _stratified(candidates: np.ndarray, cells: int, per_cell: int, rng: np.random.Generator) -> np.ndarray:
    """(H, W) bool: at most ``per_cell`` random candidate pixels from each of cells x cells image cells."""
    H, W = candidates.shape
    cell = (np.arange(H)[:, None] * cells // H) * cells + (np.arange(W)[None, :] * cells // W)
    flat = np.flatnonzero(candidates)
    order = rng.permutation(len(flat))
    flat, owner = flat[order], cell.ravel()[flat[order]]
    # rank of each pixel within its cell, in the random order: keep the first per_cell of each
    sort = np.argsort(owner, kind="stable")
    first = np.searchsorted(owner[sort], owner[sort])
    rank = np.empty_like(sort)
    rank[sort] = np.arange(len(sort)) - first
    out = np.zeros(H * W, bool)
    out[flat[rank < per_cell]] = True
    return out.reshape(H, W)


def press_description(press: Press) -> dict:
    """What was pressed where (twin provenance), for the coverage report; null values for device captures, whose
    operator's object is unnamed (the coverage report calls it ``coverage.UNRECORDED_KIND``, "an object")."""
    prov = press.meta.get("provenance") or {}
    desc = prov.get("press") or {}
    indenter = desc.get("indenter") or {}
    return {
        "indenter": indenter.get("kind", prov.get("indenter")),
        "polar_deg": desc.get("polar_deg"),
        "azimuth_deg": desc.get("azimuth_deg"),
        "depth_mm": desc.get("depth"),
    }


def write_shard(path: Path, samples: dict, entry: dict | None = None) -> None:
    """Write arrays (one press's samples, or the reference) as .npz atomically (temporary name, then rename).

    ``entry``: the press's index entry, carried in the shard (``entry``) so that a reader can tell what made it.
    The temporary name carries this process (core.atomic.write_by_name): two builds writing the same
    shard never write into one temporary file, and a killed build's leftover is cleaned by the next.
    """
    arrays = samples if entry is None else samples | {ENTRY_KEY: _entry_bytes(entry)}
    write_by_name(path, lambda tmp: save_npz(tmp, arrays))


def write_index(
    folder: Path,
    sensor: dict,
    cfg: SamplingConfig,
    entries: list[dict],
    reference: str,
    made_by: str | None = None,
    capture: dict | None = None,
    reference_files: dict | None = None,
    tricolor: dict | None = None,
) -> Path:
    """index.json: written last, so its presence marks a usable dataset. ``made_by``: :data:`EXPERIMENT_MAKER` for
    an experiment's dataset (None: ``nlips calibrate``'s), so that its refusals say what makes it anew. ``capture``:
    the capture settings its presses share (``core.sensor_record.common_settings``), which a model trained on it
    keeps; None when unknown. ``reference_files``: the undeformed capture's files as the build read them
    (core.press_checksums.files_as_read), which ``nlips train`` compares with the capture's files now.
    ``tricolor``: the tri-colour frames' check (:func:`.dataset_tricolor.index_record`: the undeformed capture's
    verdict, the presses left out); None where none was made (an experiment's dataset).

    Each sample file's digest is read from the index.json it replaces where the file's stat is the one recorded there
    (:func:`sample_file_record`): a build over kept shards reads none of them for it (Q2 full's 127 MB: ~0.1 s)."""
    known, known_sensor = _old_records(folder)
    index = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "software_version": __version__,
        "sensor": sensor,
        "capture": capture,
        "reference": reference,
        "sampling": sampling_record(cfg),
        "sample_rules": dict(SAMPLE_RULES),
        "presses": [_with_shard_record(folder, entry, known.get(entry.get("name"))) for entry in entries],
    }
    if (folder / SENSOR_FILE).is_file():
        index[SENSOR_RECORD] = sample_file_record(folder / SENSOR_FILE, known_sensor)
    if reference_files is not None:
        index["reference_files"] = reference_files
    if tricolor is not None:
        index[TRICOLOR_KEY] = tricolor
    return write_json(folder / INDEX_FILE, index | ({"made_by": made_by} if made_by else {}))


SHARD_RECORD = "shard"
"""index.json entry key: the press's sample file as the build wrote it (:func:`sample_file_record`)."""
SENSOR_RECORD = "sensor_file"
"""index.json key: sensor.npz as the build wrote it (:func:`sample_file_record`)."""


def sample_file_record(path: Path, known: object = None) -> dict:
    """``{"bytes": N, "sha256": hex, "stat": {...}}`` of a sample file (a shard, sensor.npz): what index.json records
    of it, and what :meth:`CalibrationDataset.samples_changed` compares the file with now (``bytes``, ``sha256``).

    Why a digest of the file's bytes, not of its arrays: it is read at disk speed with no inflating (Q2 full's
    127 MB of shards: ~0.1 s of CPU, against ~2.1 s to inflate and check them), so `nlips train` tells a kept
    re-run from the records (:meth:`CalibrationDataset.samples_key`) and checks the files against them cheaply.

    ``known``: the record an earlier index.json holds of the file (:func:`write_index`'s build over kept shards): its
    digest is taken as it is, the file not read, when the file's ``stat`` is the one recorded (``inode``,
    ``mtime_ns``, ``ctime_ns``) at the size recorded; a file written, replaced or copied since has another (a copy
    that keeps the modification time still sets the change time) and is read. ``stat`` is taken before the read, so
    a file changed while it is read is read again next time."""
    with path.open("rb") as f:
        st = os.fstat(f.fileno())
        stat = {"inode": st.st_ino, "mtime_ns": st.st_mtime_ns, "ctime_ns": st.st_ctime_ns}
        if _is_file_record(known) and known["bytes"] == st.st_size and known.get("stat") == stat:
            return {"bytes": known["bytes"], "sha256": known["sha256"], "stat": stat}
        digest = hashlib.file_digest(f, "sha256").hexdigest()
        size = f.tell()
    return {"bytes": size, "sha256": digest, "stat": stat}


def _with_shard_record(folder: Path, entry: dict, known: object = None) -> dict:
    """``entry`` with its shard's :func:`sample_file_record` (``shard``; ``known``: the earlier index.json's record of
    it), when the shard is there."""
    shard = folder / SHARD_DIR / f"{entry.get('name')}.npz"
    return entry | {SHARD_RECORD: sample_file_record(shard, known)} if shard.is_file() else entry


def _old_records(folder: Path) -> tuple[dict, object]:
    """({press name: shard record}, sensor.npz's record) of the index.json in ``folder`` now (the build's last);
    ({}, None) when there is none or it is unreadable: every file is then read."""
    try:
        index = json.loads((folder / INDEX_FILE).read_text(encoding="utf-8"))
        shards = {e["name"]: e.get(SHARD_RECORD) for e in index["presses"] if isinstance(e, dict)}
        return shards, index.get(SENSOR_RECORD)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}, None


def torn_index(folder: Path, problem: str) -> str:
    """The one line `nlips train` (any reader of the dataset) says of an index.json that is ``problem`` ("empty",
    "cut short or damaged (not valid JSON)": :func:`~nlipscalib.core.file_checks.file_problem`), with the command
    that makes it again.

    Why: a power cut soon after `nlips calibrate` published the dataset can leave index.json cut short (writes are
    atomic, not synced); `nlips train` said only "not valid JSON (Expecting ... char 200)", naming no remedy. Its
    samples (samples/PRESS.npz) are intact then, and `nlips calibrate` run again on the presses keeps them and
    writes the index anew. Where the dataset is the default PRESSES/calibration, the command names PRESSES; its
    maker (``made_by``: an experiment's) is lost with the file, so the calibrate advice is given."""
    return (
        f"{folder / INDEX_FILE}: {problem}: the dataset's index, torn (a crash or power cut soon after it was "
        f"written?); {_calibrate_again(folder)} to write it anew (the samples it indexes are kept where intact)"
    )


def _calibrate_again(folder: Path) -> str:
    """The `nlips calibrate` that makes the dataset ``folder`` again: its presses named where it is the default
    PRESSES/calibration."""
    if folder.name == DEFAULT_DIR:
        return f"run `nlips calibrate {shell_word(folder.parent)}` again"
    return f"run `nlips calibrate PRESSES --out {shell_word(folder)}` again on the presses it was made from"


def no_index(folder: Path) -> str:
    """What a folder without index.json is, for the line `nlips train` says of it: a build interrupted before its
    index (samples/ there), a folder of presses not calibrated yet, a press folder, or anything else.

    Why: each was "FOLDER/index.json: missing; FOLDER is not a calibration dataset (run `nlips calibrate`)": a
    half-built dataset was not told that a rerun finishes it, keeping its samples, nor a folder of presses which
    command to run on it."""
    from ..core.press_folders import find_presses, is_press_folder

    path = folder / INDEX_FILE
    if (folder / SHARD_DIR).is_dir():
        return (
            f"{path}: missing, though {folder} holds {SHARD_DIR}/: a build that was interrupted (or is still "
            f"running); {_calibrate_again(folder)} to finish it (the samples made are kept)"
        )
    if is_press_folder(folder):
        return (
            f"{folder}: a press folder, not a calibration dataset: `nlips calibrate {shell_word(folder.parent)}` "
            "makes one from the folder of presses"
        )
    if folder.is_dir() and find_presses(folder):
        return (
            f"{folder}: a folder of presses, not a calibration dataset: `nlips calibrate {shell_word(folder)}` makes "
            f"one ({folder / DEFAULT_DIR}), the folder to give"
        )
    return f"{path}: missing; {folder} is not a calibration dataset (run `nlips calibrate`)"


def remake_advice(folder: Path, made_by: object) -> str:
    """How the user makes the dataset ``folder`` anew, in the words of what wrote it (index.json's ``made_by``).

    Why: an experiment's dataset is assembled by each run of ``nlips experiment`` from its press tasks' samples;
    ``nlips calibrate`` cannot make it again (the experiment deletes its rendered presses after scoring them, and
    calibrate writes a dataset of its own beside its presses), yet its refusals told the user to run it."""
    if made_by == EXPERIMENT_MAKER:
        return f"run the experiment again on its work folder {folder.parent}"
    return "run `nlips calibrate` on its presses again"


def build_dataset(
    press_folders: Iterable[str | Path],
    reference_folder: str | Path,
    out: str | Path,
    cfg: SamplingConfig | None = None,
    result_dir: str = "nlips",
    progress: bool = True,
    run: dict | None = None,
    failed: dict[str, str] | None = None,
    keep_tricolor: bool = False,
    judged: dict[str, dict] | None = None,
) -> Path:
    """Pair every solved press's tri-colour image with its NLiPs normals into a calibration dataset.

    Parameters
    ----------
    press_folders : press folders solved with NLiPs (``PRESS/<result_dir>/``)
    reference_folder : press folder of the undeformed dome (same sensor)
    out : dataset folder to write (created; existing shards made from the same reconstruction are kept)
    cfg : SamplingConfig
    result_dir : reconstruction folder name inside each press
    progress : the presses' bar on stderr, drawn only on a terminal or in a notebook (:mod:`nlipscalib.progress`)
    run : :func:`dataset_run` the caller holds ``out`` for (``nlips calibrate``: from before its solves, with its
        solve options); None: this build's own. The build holds ``out`` for it (:func:`hold_dataset`)
    failed : where a press that cannot be sampled (a damaged tri-colour image, another sensor: a CaptureError) is
        left out of the dataset, its error logged and its name mapped to it here, as a batch's failed solve is
        (``nlips calibrate``); None: the error is raised
    keep_tricolor : keep the presses whose tri-colour frame does not hold their LED images' light
        (:mod:`nlipscalib.core.tricolor_check`), each warned of; False: each is left out of the index with one line
        (:func:`.dataset_tricolor.sort_presses`), recorded in index.json's ``tricolor``
    judged : presses of ``press_folders`` judged before their solve as left out for their tri-colour frame
        (``nlips calibrate``: :func:`.dataset_tricolor.judged_before_solve`, each said then, and not solved), by
        name, with their verdict's record: their entries hold only that (nothing read), their lines are not said
        again

    Returns
    -------
    Path of the dataset folder. Raises CaptureError naming the press when one is unsolved or from
    another sensor (with ``failed``: only when every press is), ConfigError when another live build of other
    samples holds ``out`` or ``press_folders`` is empty, and (without ``keep_tricolor``) when every capture's
    tri-colour frame disagrees with its LED images the same way (a camera's colour order) or the undeformed
    capture's does.
    """
    from ..core.capture import Press, load_press
    from ..core.press_checksums import files_as_read
    from ..core.press_meta import listed_files, read_meta
    from ..core.tricolor_check import press_tricolor_verdict

    each = "a press folder's path (str or Path) or a loaded Press"
    given = check_paths(press_folders, "press_folders", "a list of press folders", (*PATH, Press), each)
    check_kind(reference_folder, (*PATH, Press), "reference_folder", f"the undeformed capture: {each}")
    check_kind(out, PATH, "out", "the dataset folder's path (str or Path)")
    check_kind(cfg, (SamplingConfig, type(None)), "cfg", "a SamplingConfig, or None (defaults)")
    check_kind(result_dir, str, "result_dir", "the reconstruction folder's name in each press (str)")
    check_flag(progress, "progress")
    reference_folder = getattr(reference_folder, "folder", reference_folder)  # a loaded Press: its folder
    cfg = cfg or SamplingConfig()
    out = Path(out)
    folders = [Path(getattr(f, "folder", f)) for f in given]
    if not folders:  # a glob that matched nothing: it wrote a dataset of no sample, which train then refused
        raise ConfigError(f"{out}: no press folders given (press_folders is empty): nothing to build the dataset from")
    run = run or dataset_run(folders, reference_folder, cfg, result_dir)
    with said_once.scope(), hold_dataset(out, run):  # a session's brightness warned of once per build
        (out / SHARD_DIR).mkdir(parents=True, exist_ok=True)
        _clean_interrupted(out)
        reference_files = files_as_read(reference_folder, listed_files(read_meta(reference_folder)))
        ref_press = load_press(reference_folder)
        check_min_leds(cfg, len(ref_press.leds), reference_folder)
        ref = reference_arrays(ref_press)
        ref_tricolor = press_tricolor_verdict(ref_press).record()
        build = _Build(out, cfg, result_dir, sensor_of(ref_press), ref, failed=failed, keep_tricolor=keep_tricolor)
        if older := _older_rules(out):  # every shard's stamp holds the rules: each is made again, said once
            log.info("%s: %s: each press's samples are made again", out / INDEX_FILE, older)
        write_shard(out / SENSOR_FILE, build.ref)
        judged = judged or {}
        entries = build.entries([f for f in folders if f.name not in judged], progress)
        entries = _in_order(folders, entries, judged)
        if failed and not entries:  # every press left out: their lines were logged, this one ends the build
            raise CaptureError(f"{out}: no press could be sampled (each one's error is above)")
        where = folders[0].parent if len({f.parent for f in folders}) == 1 else out
        entries, left_out = sort_presses(
            entries, ref_tricolor, Path(reference_folder), where, keep_tricolor, said=judged
        )
        if not entries:  # every press disagrees, not all alike: each said above
            raise CaptureError(
                f"{out}: no press left whose tri-colour frame holds its LED images' light (each one's line is above); "
                f"pass {KEEP_OPTION} to keep them"
            )
        indexed = {e["name"] for e in entries}
        folders = [folder for folder in folders if folder.name in indexed]
        if build.kept:  # what a resumed build reused, as solve and experiment say theirs
            names = build.kept
            shown = ", ".join(names[:5]) + (f" and {len(names) - 5} more" if len(names) > 5 else "")
            log.info(
                "%s: samples of %d of %d presses kept (made from the same results and options): %s",
                out,
                len(names),
                len(entries),
                shown,
            )
        capture = common_settings([capture_settings(read_meta(folder)) for folder in folders])  # the presses' alike
        reference = str(Path(reference_folder).resolve())
        write_index(
            out,
            build.sensor,
            cfg,
            entries,
            reference,
            capture=capture,
            reference_files=reference_files,
            tricolor=index_record(ref_tricolor, left_out, keep_tricolor),
        )
    return out


def _in_order(folders: list[Path], entries: list[dict], judged: dict[str, dict]) -> list[dict]:
    """``entries`` with one of each press in ``judged`` (its name, folder and verdict record), in ``folders``'
    order."""
    made = {entry["name"]: entry for entry in entries}
    for folder in folders:
        if folder.name in judged:
            made[folder.name] = {
                "name": folder.name,
                "folder": str(folder.resolve()),
                TRICOLOR_KEY: judged[folder.name],
            }
    return [made[f.name] for f in folders if f.name in made]


def _clean_interrupted(out: Path) -> None:
    """Remove the temporaries and claims of killed builds in ``out`` (only those whose owner is gone)."""
    from ..core.atomic import clean_interrupted, removed_leftover

    for folder in (out, out / SHARD_DIR):
        for gone in clean_interrupted(folder):
            log.warning("%s: removed %s", gone, removed_leftover(gone))


@dataclasses.dataclass
class _Build:
    """One build's samples, press by press: kept when whole and made from the same inputs, else made under the
    shard's claim, so two builds of one dataset sharing the folder make each shard once."""

    out: Path
    cfg: SamplingConfig
    result_dir: str
    sensor: dict
    ref: dict
    kept: list[str] = dataclasses.field(default_factory=list)
    """Names of the presses whose shard was found made (by an earlier build, or another one at work)."""
    failed: dict[str, str] | None = None
    """:func:`build_dataset`'s ``failed``: the presses left out, by name, with their errors (None: raise them)."""
    keep_tricolor: bool = False
    """:func:`build_dataset`'s ``keep_tricolor``: sample a press whose tri-colour frame disagrees with its LED images
    (False: its entry holds only its verdict, no shard is made, and it is left out)."""
    ref_digest: str = dataclasses.field(init=False)
    """:func:`arrays_digest` of ``ref``: part of every shard's stamp."""
    old: dict = dataclasses.field(init=False)
    """The previous index.json's entries by press name (for shards that carry none)."""

    def __post_init__(self) -> None:
        self.ref_digest = arrays_digest(self.ref)
        self.old = _old_entries(self.out)

    def entries(self, folders: list[Path], progress: bool) -> list[dict]:
        """The index entries of ``folders``' shards, in their order; a shard another live build is making is left
        for the end, then waited for (and made here when that build dies or fails). A press left out
        (``failed``) has none."""
        done: dict[Path, dict] = {}
        later = []
        for folder in track(folders, enabled=progress, desc="samples", unit="press"):
            _wait_for_solver(folder / self.result_dir)
            try:
                entry = self.attempt(folder)
            except CaptureError as exc:
                self._leave_out(folder, exc)
                continue
            if entry is None:
                later.append(folder)
            else:
                done[folder] = entry
        for folder in later:
            try:
                done[folder] = self.wait_for(folder)
            except CaptureError as exc:
                self._leave_out(folder, exc)
        return [done[f] for f in folders if f in done]

    def _leave_out(self, folder: Path, exc: CaptureError) -> None:
        """With ``failed``: ``folder`` left out, its error logged once, naming the file (``press/tricolor.png:
        ...``) or else the press; without: ``exc`` raised."""
        if self.failed is None:
            raise exc
        line = str(exc)
        log.error("%s", line if line.startswith(str(folder)) else f"{folder}: {line}")
        self.failed[folder.name] = line

    def wait_for(self, folder: Path) -> dict:
        """``folder``'s entry once no other live process holds its shard (made by it, or here if it died or failed)."""
        shard = self.shard(folder)
        say = lambda: log.info("%s: being sampled by another process; waiting for its shard", shard)  # noqa: E731
        while (entry := self.attempt(folder)) is None:
            wait_for_release(shard, on_wait=say)
            say = None
        return entry

    def shard(self, folder: Path) -> Path:
        return self.out / SHARD_DIR / f"{folder.name}.npz"

    def attempt(self, folder: Path) -> dict | None:
        """``folder``'s entry: its shard kept, or made under its claim; None while another live process holds it."""
        from ..core.claims import claim

        shard, stamp = self.shard(folder), shard_stamp(folder / self.result_dir, self.cfg, self.ref_digest)
        with claim(shard) as mine:
            if not mine:
                return None
            kept = _kept_entry(shard, stamp, self.old.get(folder.name))
            if kept is not None:  # resumed, or made meanwhile by another build of this dataset
                self.kept.append(folder.name)
                # a shard made before they were recorded: the identities now (the press's content, cached per stamp)
                indexed = self.old.get(folder.name)
                return kept | _capture_identity(folder / self.result_dir) | press_identity_entry(folder, kept, indexed)
            return self.make(folder, shard, stamp)

    def make(self, folder: Path, shard: Path, stamp: str) -> dict:
        from ..core.capture import load_press
        from ..core.reconstruction import load_reconstruction
        from ..core.tricolor_check import press_tricolor_verdict

        press = load_press(folder)
        check_sensor(self.sensor, sensor_of(press), folder)
        if why := response_mismatch(self.sensor, sensor_of(press), "the reference's"):
            raise CaptureError(f"{folder}: {why}")
        from ..core.press_checksums import files_as_read
        from ..core.press_meta import listed_files

        files = files_as_read(folder, listed_files(press.meta))  # before its files are read: what they were
        identity = press_identity_entry(folder)  # what was captured (learn.seen), as sampled
        rec = load_reconstruction(folder / self.result_dir, press.camera.shape)
        tricolor = press_tricolor_verdict(press, reordered(rec.report)).record()
        if disagrees(tricolor) and not self.keep_tricolor:  # to be left out (sort_presses): no shard, no samples
            return {"name": folder.name, "folder": str(folder.resolve()), TRICOLOR_KEY: tricolor}
        samples = press_samples(press, rec, self.ref, self.cfg)
        entry = (
            {
                "name": folder.name,
                "folder": str(folder.resolve()),
                "samples": int(len(samples["rgb"])),
                "contact_samples": int(samples["contact"].sum()),
                "has_truth": bool(press.ground_truth is not None),
                "press": press_description(press),
                "stamp": stamp,
                "files": files,
                TRICOLOR_KEY: tricolor,  # carried by the shard: a resumed build knows it
            }
            | _capture_identity(folder / self.result_dir, rec.report)
            | identity
        )
        write_shard(shard, samples, entry)
        return entry


CAPTURE_IDENTITY = "capture_identity"
"""index.json entry key: the identity of the capture the press's labels were solved from (its NLiPs result's
``provenance.inputs.press``, SHA-256 of meta.json, every image and reference.npz), which a model keeps for
its training and validation presses (``info.captures``) and ``nlips infer`` compares with the capture it reads
(report.json ``trained_on``)."""


def _capture_identity(result: Path, report: dict | None = None) -> dict:
    """``{"capture_identity": hex}`` from the NLiPs result ``result``'s report.json (``report``: read already), or
    ``{}`` when it records none (a result saved outside the pipeline, or of an nlipscalib before 2026-12-06).

    Why the recorded identity, not a hash of the press now: learn/ does not solve, and the pipeline that solved
    the press hashed these files then (``pipeline.capture_identity``); a press changed since its solve is solved
    again by `nlips calibrate` before it is sampled, and `nlips train` refuses one changed since its sampling
    (:meth:`CalibrationDataset.changed_presses`)."""
    if report is None:
        from ..core.reconstruction import read_report

        try:
            report = read_report(result)
        except CaptureError:
            return {}
    return recorded_capture_identity(report)


def press_identity_entry(folder: Path, entry: dict | None = None, indexed: dict | None = None) -> dict:
    """``{"press_identity": record}``: the press's identity by what was captured (:mod:`nlipscalib.core.press_identity`:
    its images' content and sensor record, not meta.json's times), which a model keeps (``info.press_identities``) and
    ``nlips infer`` compares with what it reads (:mod:`.seen`): the index entry's key for `nlips calibrate`'s presses
    and the experiments' press tasks alike (``experiments.tasks``).

    ``{}`` when the shard's ``entry`` holds one already, and when the images cannot be read (a kept shard's press
    changed since: ``nlips train`` names what changed). For a kept shard made before it was recorded, the previous
    index.json's ``indexed`` entry's identity when that entry has the shard's ``stamp`` (the same result and options),
    so only the first build of this version hashes its presses (~30 ms a 640x480 press)."""
    from ..core.press_identity import IDENTITY_KEY, is_identity, press_identity

    if entry is not None and is_identity(entry.get(IDENTITY_KEY)):
        return {}
    if entry is not None and isinstance(indexed, dict) and indexed.get("stamp") == entry.get("stamp"):
        if is_identity(indexed.get(IDENTITY_KEY)):
            return {IDENTITY_KEY: indexed[IDENTITY_KEY]}
    try:
        return {IDENTITY_KEY: press_identity(folder)}
    except CaptureError:
        return {}


def recorded_capture_identity(report: object) -> dict:
    """``{"capture_identity": hex}``: the identity of the capture an NLiPs result's labels were solved from, as its
    report.json records it (``provenance.inputs.press``), or ``{}`` when it records none: the index.json entry's key
    for `nlips calibrate`'s presses and the experiments' press tasks alike (``experiments.tasks``)."""
    provenance = report.get("provenance") if isinstance(report, dict) else None
    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    identity = inputs.get("press") if isinstance(inputs, dict) else None
    return {CAPTURE_IDENTITY: identity} if isinstance(identity, str) and identity else {}


# ---------------------------------------------------------------------- holding the folder
HOLD_NAME = "calibration"
"""Target of the claims by which the builds of one dataset hold its folder (:func:`hold_dataset`):
``OUT/.claim-calibration~KEY~TOKEN``, one per build."""


def dataset_run(
    press_folders: Iterable[str | Path],
    reference_folder: str | Path,
    cfg: SamplingConfig,
    result_dir: str = "nlips",
    solve: dict | None = None,
) -> dict:
    """What decides a calibration dataset's samples, for :func:`hold_dataset`.

    Parameters
    ----------
    press_folders, reference_folder, cfg, result_dir : as for :func:`build_dataset`
    solve : JSON-able options that decide the presses' results (``nlips calibrate``: ``normals``, ``leds``), or None

    Returns
    -------
    dict: ``key`` (hex, 16 digits: the same for every build of the same samples), ``options`` (the sampling
    options, the reference folder, ``solve``) and ``presses`` (``count``, ``first`` and ``digest`` of their folders)
    """
    folders = [str(Path(f).resolve()) for f in press_folders]
    options = sampling_record(cfg) | {"reference": str(Path(reference_folder).resolve())} | (solve or {})
    presses = {
        "count": len(folders),
        "first": folders[0] if folders else None,
        "digest": hashlib.sha256(json.dumps(folders).encode()).hexdigest()[:16],
    }
    what = {"options": options, "presses": presses, "result_dir": result_dir, **SAMPLE_RULES}
    return {"key": hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]} | what


@contextlib.contextmanager
def hold_dataset(out: str | Path, run: dict, option_of: dict[str, str] | None = None) -> Iterator[None]:
    """Hold the dataset folder ``out`` for the build ``run`` (:func:`dataset_run`) while the block runs.

    Builds of the same run share the folder: each shard is made by one of them (its claim) and reused by the
    others. A live build of another run holding ``out``: ConfigError at once naming what differs (``option_of``: the
    command-line option of each option's name), before anything is written.

    Why: two builds of different sampling options (or presses, or reference) into one folder each replaced the
    other's shards, and the index.json written last could list shards the other build had made; refused, the
    user builds into another folder straight away, as ``nlips dataset`` and ``nlips train`` refuse another spec or
    training. A killed build's claim goes stale (core.claims) and stops counting. A folder that cannot hold a claim
    file (read-only media, disk full) is not claimed: nothing can be written there either, and the writes say why.
    """
    from ..core.claims import held_for

    out = Path(out)
    refusal = lambda other: _built_elsewhere(out, other, run, option_of or {})  # noqa: E731
    with held_for(out / HOLD_NAME, run["key"], refusal, note=run):
        yield


def _built_elsewhere(out: Path, other: Owner, run: dict, option_of: dict[str, str]) -> str:
    theirs = other.note or {}
    changed = []
    mine, was_all = run.get("options") or {}, theirs.get("options") or {}
    for k in sorted(set(mine) | set(was_all)):
        if was_all.get(k) != mine.get(k):
            changed.append(f"{option_of.get(k, k)} {was_all.get(k)} (this run: {mine.get(k)})")
    ours, was = run.get("presses") or {}, theirs.get("presses") or {}
    if ours.get("digest") != was.get("digest"):
        before, now = (f"{p.get('count')} from {p.get('first')}" for p in (was, ours))
        changed.append(f"presses {before} (this run: {now})")
    return (
        f"{out}: {other.who} is building a calibration dataset of other samples into it "
        f"({', '.join(changed) or 'other settings'}); left to it: write into another --out, or run again once it "
        "has ended (its samples are then replaced)"
    )


def check_min_leds(cfg: SamplingConfig, n_leds: int, where: str | Path) -> None:
    """ConfigError when ``cfg.min_leds`` exceeds the sensor's LEDs: no NLiPs pixel could become a sample."""
    if cfg.min_leds > n_leds:
        raise ConfigError(f"min_leds must be at most the {n_leds} LEDs of {where}, got {cfg.min_leds}")


SAMPLED_GROUND_TRUTH = ("normals.npy", "valid.npy")
"""The members of a press's gt.npz that its samples read (:func:`press_samples`: the true normals where valid)."""


def damaged_sampled_files(folders: Iterable[Path], out: Path) -> dict[str, str]:
    """The presses of ``folders`` whose files only the samples read (the tri-colour image; the ground truth's
    :data:`SAMPLED_GROUND_TRUTH`) are missing, cut short or damaged inside, by name, each with the line naming the
    file and the problem.

    Why: ``nlips calibrate`` solves every press before it samples any, so such a press was solved (minutes at
    640x480) and then left out, its file named only at the end; the solve reads its LED images itself, at the
    start of each press's solve. Checked from all of their bytes (:func:`~nlipscalib.core.file_checks.
    damage_inside`: ~1 ms for a 640x480 tri-colour image, ~30 ms to inflate the ground truth's normals); a press
    whose shard is in ``out`` already is not checked (a resumed build keeps that shard, reading neither file).
    """
    from ..core.file_checks import damage_inside, file_problem
    from ..core.press_meta import read_meta

    damaged = {}
    for folder in folders:
        if (out / SHARD_DIR / f"{folder.name}.npz").is_file():
            continue
        meta = read_meta(folder)
        images = meta.get("images")
        checked = [(images.get("tricolor"), None)] if isinstance(images, dict) else []
        if meta.get("ground_truth"):
            checked.append((meta["ground_truth"], SAMPLED_GROUND_TRUTH))
        for name, members in checked:
            if isinstance(name, str) and (
                problem := file_problem(folder / name) or damage_inside(folder / name, members)
            ):
                damaged[folder.name] = f"{folder / name}: {problem}"
                break
    return damaged


def shard_stamp(result: Path, cfg: SamplingConfig, reference_digest: str) -> str:
    """What made a shard (its resume key, ``stamp``): a digest of the reconstruction's content, the sampling options,
    the undeformed reference's arrays (:func:`arrays_digest`) and the sampling code's versions (:data:`SAMPLE_RULES`).

    Why content, not the file's size and time: a result replaced by another of the same size with its time kept
    (``cp -p``, ``rsync -t``, within the clock's tick) kept the old samples; and the reference decides which pixels
    count as contact and the rest's labels.
    """
    from ..core.reconstruction import RESULT_FILE

    path = result / RESULT_FILE
    if not path.is_file():
        raise CaptureError(f"{path}: press not solved (no NLiPs reconstruction)")
    with path.open("rb") as f:
        content = hashlib.file_digest(f, "sha256").hexdigest()
    rules = ":".join(f"{name}-{version}" for name, version in SAMPLE_RULES.items())
    key = f"{content}:{json.dumps(sampling_record(cfg), sort_keys=True)}:{reference_digest}:{rules}"
    return hashlib.sha256(key.encode()).hexdigest()[:16]


def arrays_digest(arrays: dict) -> str:
    """SHA-256 (hex) of named arrays: names, dtypes, shapes and bytes, in name order."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}:{a.dtype.str}:{a.shape}".encode())
        digest.update(a.tobytes())
    return digest.hexdigest()


def _older_rules(out: Path) -> str | None:
    """Why the dataset index.json in ``out`` records samples made under other sampling rules than today's
    (:data:`SAMPLE_RULES`), in words ("made under other sampling rules (rule 2, now 3)"); None when there is no
    readable index.json or it records today's rules."""
    try:
        index = json.loads((out / INDEX_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(index, dict):
        return None
    rules = index.get("sample_rules")
    return rules_changed(rules if isinstance(rules, dict) else None)


def rules_changed(was: dict | None) -> str | None:
    """How the sampling rules ``was`` (an index.json's ``sample_rules``; None: it records none) differ from today's
    :data:`SAMPLE_RULES`, in words; None when they are today's."""
    if was == SAMPLE_RULES:
        return None
    if was is None:
        return "records no sampling rules: made by an nlipscalib before 2026-12-06"
    changed = ", ".join(f"{k} {was.get(k)}, now {v}" for k, v in SAMPLE_RULES.items() if was.get(k) != v)
    return f"made under other sampling rules ({changed})"


def _old_entries(out: Path) -> dict:
    try:
        return {e["name"]: e for e in json.loads((out / INDEX_FILE).read_text(encoding="utf-8"))["presses"]}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def _entry_bytes(entry: dict) -> np.ndarray:
    return np.frombuffer(json.dumps(entry, sort_keys=True).encode(), np.uint8)


def _kept_entry(shard: Path, stamp: str, indexed: dict | None) -> dict | None:
    """The index entry of ``shard`` when it is whole and was made with ``stamp``; None when it must be made.

    The entry is the one the shard carries (``entry``): what made it, whichever build wrote it (another build of
    other options may have replaced the shard after index.json was written, keeping its sample count); the previous
    index.json's record only for a shard without one. A damaged shard (a disk fault, a hand edit) is made again
    with a warning, as ``nlips solve`` re-computes a damaged result.
    """
    if not shard.is_file():
        return None
    try:
        made, count = shard_entry(shard)
    except CaptureError as exc:
        log.warning("%s; making it again", exc)
        return None
    entry = made or indexed
    if not (isinstance(entry, dict) and TRICOLOR_KEY in entry):  # made before the tri-colour check: judged anew
        return None
    if entry.get("stamp") == stamp and entry.get("samples") == count:
        return entry
    return None


def shard_entry(shard: Path) -> tuple[dict | None, int]:
    """The index entry a shard carries (None: written before shards carried one) and its sample count, read
    in full and checked (:func:`_checked_shard`).

    Raises
    ------
    CaptureError -- naming the file: missing, damaged, truncated or inconsistent.
    """
    arrays = _checked_shard(shard)
    return _shard_entry(arrays), len(arrays["rgb"])


def _shard_entry(arrays: dict) -> dict | None:
    """The index entry a shard carries (``entry``), or None (a shard of an older build, or of an experiment)."""
    if ENTRY_KEY not in arrays:
        return None
    try:
        entry = json.loads(arrays[ENTRY_KEY].tobytes().decode())
    except (UnicodeDecodeError, ValueError):
        return None
    return entry if isinstance(entry, dict) else None


SHARD_KINDS = {"pixel": "iu", "rgb": "f", "normal": "f", "true_normal": "f", "contact": "b", "source": "iu"}
"""numpy dtype kinds each shard array may have: integers, floats, booleans (strings or objects: refused)."""


def _checked_shard(path: Path) -> dict:
    """The arrays of a shard, read in full (so a damaged deflated array shows) and checked for consistency:
    shapes, dtypes, and finite colours and labels (a NaN there reaches the training loss and stops training
    without a model); ``true_normal`` is NaN wherever a press has no ground truth.

    Shapes are checked from the arrays' headers before any is inflated, and only the shard's own arrays are
    inflated: a dataset from elsewhere may declare an array of gigabytes in a small file, or carry another member
    (docs/formats.md, "Files from others")."""
    headers = read_array_headers(path, SHARD_KEYS)
    _check_shard_shapes(path, {key: headers[key][0] for key in SHARD_KEYS})
    arrays = read_arrays(path, SHARD_KEYS, only=[key for key in headers if key in SHARD_KEYS or key == ENTRY_KEY])
    _check_shard_shapes(path, {key: arrays[key].shape for key in SHARD_KEYS})
    n = len(arrays["rgb"])
    for key in SHARD_KEYS:
        a = arrays[key]
        if a.dtype.kind not in SHARD_KINDS[key]:
            raise CaptureError(f"{path}: array '{key}' holds {a.dtype} values, expected {_kind_words(key)}")
    for key in ("rgb", "normal"):
        bad = int(np.count_nonzero(~np.isfinite(arrays[key]).all(-1)))
        if bad:
            raise CaptureError(f"{path}: array '{key}' has NaN or infinite values in {bad} of {n} samples")
    return arrays


def _check_shard_shapes(path: Path, shapes: dict[str, tuple[int, ...]]) -> None:
    """CaptureError naming the shard unless each array's shape (``shapes``: of every key of :data:`SHARD_KEYS`)
    has its number of dimensions and columns, and all have the samples of ``rgb``."""
    n = shapes["rgb"][0] if shapes["rgb"] else 0
    for key, ndim in SHARD_KEYS.items():
        shape = tuple(shapes[key])
        if len(shape) != ndim or shape[0] != n or (ndim == 2 and shape[1] != (2 if key == "pixel" else 3)):
            raise CaptureError(f"{path}: array '{key}' has shape {shape}, inconsistent with {n} samples")


def _kind_words(key: str) -> str:
    return {"iu": "integers", "f": "floating-point numbers", "b": "booleans"}[SHARD_KINDS[key]]


def _check_pixels(pixel: np.ndarray, camera: dict, path: Path) -> None:
    """CaptureError when a sample's (u, v) lies outside the sensor's image (the network's input would be
    meaningless there, and the reference frame is read at it)."""
    w, h = camera["width"], camera["height"]
    outside = (pixel[:, 0] < 0) | (pixel[:, 0] >= w) | (pixel[:, 1] < 0) | (pixel[:, 1] >= h)
    if outside.any():
        u, v = pixel[np.argmax(outside)]
        raise CaptureError(
            f"{path}: array 'pixel' has {int(outside.sum())} samples outside the sensor's {w}x{h} image "
            f"(e.g. u={u}, v={v})"
        )


def _wait_for_solver(result: Path) -> None:
    """Wait while another live process holds the claim on ``result`` (it is solving that press).

    Two ``nlips calibrate`` runs on one folder split the solving: each skips the presses the other is
    solving (pipeline.solve_presses). The samples need every result, so a build waits here for the other
    run to publish it (or to die: its claim then goes stale and the wait ends; a press still unsolved is
    then reported by :func:`_result_stamp`).
    """
    say = lambda: log.info("%s: being solved by another process; waiting for its result", result.parent)  # noqa: E731
    wait_for_release(result, on_wait=say)  # the solver's own staleness and poll: one value for both (core.claims)


# ---------------------------------------------------------------------- reading
def check_reference_values(arrays: dict, where: str | Path) -> None:
    """CaptureError naming ``where`` when the undeformed reference (:func:`reference_arrays`: sensor.npz, a
    model's ``reference``) holds values no capture gives: a tri-colour frame or normals that are NaN or
    infinite (inference would find no pixel changed and return the undeformed dome without a word), or
    arrays that are not numbers. ``depth`` is NaN off the gel by convention."""
    for key in SENSOR_KEYS:
        if key in arrays and np.asarray(arrays[key]).dtype.kind not in "biuf":
            raise CaptureError(f"{where}: reference array '{key}' holds {np.asarray(arrays[key]).dtype} values")
    for key in ("tricolor", "normals"):
        if key in arrays and not np.isfinite(arrays[key]).all():
            bad = int(np.count_nonzero(~np.isfinite(arrays[key]).all(-1)))
            raise CaptureError(f"{where}: reference array '{key}' is NaN or infinite at {bad} pixels")


def _checked_entries(presses: object, path: Path) -> list[dict]:
    """index.json's ``presses``, checked: a list of entries, each with a plain file ``name`` and a ``samples``
    count (what reading the shards relies on); a hand-edited index is named here, not in a traceback."""
    if not isinstance(presses, list):
        raise CaptureError(f"{path}: 'presses' must be a list of press entries, got {type(presses).__name__}")
    names = set()
    for i, entry in enumerate(presses):
        if not isinstance(entry, dict):
            raise CaptureError(f"{path}: presses[{i}] must be a mapping, got {type(entry).__name__}")
        name, samples = entry.get("name"), entry.get("samples")
        if not isinstance(name, str) or not name or Path(name).name != name or name in (".", ".."):
            raise CaptureError(f"{path}: presses[{i}].name must be a press folder's name, got {name!r}")
        if name in names:
            raise CaptureError(f"{path}: press {name!r} is listed twice")
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 0:
            raise CaptureError(f"{path}: presses[{i}] ({name}): 'samples' must be a count, got {samples!r}")
        names.add(name)
    return presses


def _is_file_record(record: object) -> bool:
    """Whether ``record`` is a :func:`sample_file_record` (a hand-edited index.json may hold anything)."""
    return (
        isinstance(record, dict)
        and isinstance(record.get("bytes"), int)
        and isinstance(record.get("sha256"), str)
        and len(record["sha256"]) == 64
    )


def _checked_smoothing(sampling: object, path: Path) -> tuple[float, float]:
    """index.json's ``sampling.smoothing_px`` and ``sampling.smoothing_colour``, checked (0 when the dataset predates
    the option): a bad value is named here, not by inference reading the model that carries it ("prefilter sigma
    must be ...")."""
    if sampling is None:
        return 0.0, 0.0
    if not isinstance(sampling, dict):
        raise CaptureError(f"{path}: 'sampling' must be a mapping of sampling options, got {sampling!r}")
    try:
        return (
            check_sigma(sampling.get("smoothing_px", 0.0), "'sampling.smoothing_px'"),
            check_colour_sigma(sampling.get("smoothing_colour", 0.0), "'sampling.smoothing_colour'"),
        )
    except ConfigError as exc:
        raise CaptureError(f"{path}: {exc}") from None


class CalibrationDataset:
    """A calibration dataset folder, validated on open; shards load on demand."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        path = self.folder / INDEX_FILE
        inside = self.folder / DEFAULT_DIR / INDEX_FILE
        if not path.is_file() and inside.is_file():  # the folder of presses given: `nlips calibrate` wrote inside it
            raise CaptureError(
                f"{self.folder}: a folder of presses, not a calibration dataset; its calibration dataset is "
                f"{inside.parent} (give that folder)"
            )
        if not path.is_file() and (self.folder.parent / INDEX_FILE).is_file():  # its samples/, index.json, ...
            kind = "a file" if self.folder.is_file() else "a folder"  # index.json given: it said "a folder"
            raise CaptureError(
                f"{self.folder}: {kind} inside a calibration dataset, not one; the dataset is {self.folder.parent} "
                "(give that folder)"
            )
        if path.is_file() and (torn := file_problem(path)) is not None:
            raise CaptureError(torn_index(self.folder, torn))
        if self.folder.is_dir() and not path.exists():
            raise CaptureError(no_index(self.folder))
        index = read_format_json(
            path,
            FORMAT_NAME,
            FORMAT_VERSION,
            required=("sensor", "presses"),
            missing_hint=f"{self.folder} is not a calibration dataset (run `nlips calibrate`)",
            remake=lambda data: f"{remake_advice(self.folder, data.get('made_by'))} to make it with this version",
        )
        self.index = index
        self.remake: str = remake_advice(self.folder, index.get("made_by"))
        """How the user makes this dataset anew (:func:`remake_advice`), the remedy its refusals give."""
        remedy = f"{self.remake} to record it (the samples are kept)"
        self.sensor: dict = check_sensor_record(index["sensor"], path, remedy)
        self.entries: list[dict] = _checked_entries(index["presses"], path)
        self.smoothing_px: float
        """Prefilter sigma the samples' colours were filtered with (0 for datasets made before the option)."""
        self.smoothing_colour: float
        """Its colour sigma (:attr:`SamplingConfig.smoothing_colour`; 0: the Gaussian alone, and for datasets made
        before the option)."""
        self.smoothing_px, self.smoothing_colour = _checked_smoothing(index.get("sampling"), path)
        rules = index.get("sample_rules")
        self.sample_rules: dict | None = rules if isinstance(rules, dict) else None
        """The sampling code's versions its samples were made under (:data:`SAMPLE_RULES`); None for datasets made
        before they were recorded (2026-12-06)."""
        capture = index.get("capture")
        self.capture: dict | None = capture if isinstance(capture, dict) else None
        """The capture settings its presses share (``core.sensor_record.common_settings``); None for datasets made
        before they were recorded (2026-12-05) and for the experiments' (their rendered presses may be gone)."""
        tricolor = index.get(TRICOLOR_KEY)
        self.tricolor: dict | None = tricolor if isinstance(tricolor, dict) else None
        """index.json's record of the tri-colour frames' check (:func:`.dataset_tricolor.index_record`); None for
        datasets made before it (2026-12-07) and for the experiments'."""

    @property
    def names(self) -> list[str]:
        return [e["name"] for e in self.entries]

    @property
    def tricolor_left_out(self) -> list[dict]:
        """The presses ``nlips calibrate`` left out because their tri-colour frame does not hold their LED images'
        light (each ``{"name", "folder", "tricolor"}``, the last with the warning's ``line``); empty when none, or
        not recorded."""
        left = (self.tricolor or {}).get("left_out")
        return (
            [g for g in left if isinstance(g, dict) and isinstance(g.get("name"), str)]
            if isinstance(left, list)
            else []
        )

    @property
    def tricolor_kept(self) -> list[str]:
        """The indexed presses whose tri-colour frame does not hold their LED images' light, kept on request
        (``--keep-tricolor-mismatch``)."""
        return [e["name"] for e in self.entries if disagrees(e.get(TRICOLOR_KEY))]

    def older_sampling(self) -> str | None:
        """Why this dataset's samples may not be those this nlipscalib makes of its presses, in one line naming
        index.json and the remedy, or None when they were made under today's :data:`SAMPLE_RULES`.

        Why: `nlips calibrate` makes a shard again when a rule's version changed (its stamp holds them), but
        `nlips train` on a dataset an older nlipscalib made read its samples without a word: one made before
        :data:`FRAME_GAIN_RULE` kept almost none of the contact samples of a press brighter or dimmer than the
        reference."""
        why = rules_changed(self.sample_rules)
        if why is None:
            return None
        path = self.folder / INDEX_FILE
        older_gain = self.sample_rules is None or self.sample_rules.get("frame_gain") != FRAME_GAIN_RULE
        gain = " (before 2026-12-06 a press brighter or dimmer than the reference kept almost no contact samples)"
        return (
            f"{path}: {why}: its samples may differ from this version's{gain if older_gain else ''}; {self.remake} to "
            "make them with this version"
        )

    def changed_presses(self) -> dict[str, str]:
        """The presses (and ``"reference"``, the undeformed capture) whose folders hold other files now than the
        samples were made from, by name, each with one line naming the first such file and the remedy: index.json
        records each press's files as sampled (``files``: sizes, and CRC-32s from the press's checksums.json;
        core.press_checksums.changed_since); a dataset built before it did (2026-12-06) has each press compared with
        its own checksums.json instead (core.press_checksums.changed_files). A press whose folder is not there (a
        dataset copied to another machine, an experiment's deleted renders) is not compared. A stat per file.

        Why: ``nlips train`` read the shards alone, so a dataset built before a press was captured or rendered again,
        or from a press with another image copied over one, trained without a word."""
        from ..core.press_checksums import changed_files, changed_since

        changed = {}
        ref = ("reference", self.index.get("reference"), self.index.get("reference_files"))
        for name, folder, files in [ref, *((e["name"], e.get("folder"), e.get("files")) for e in self.entries)]:
            if not isinstance(folder, str) or not Path(folder).is_dir():
                continue
            problems = changed_since(folder, files) if isinstance(files, dict) else changed_files(folder)
            if not problems:
                continue
            first, problem = next(iter(problems.items()))
            more = f" and {len(problems) - 1} more of its files" if len(problems) > 1 else ""
            if isinstance(files, dict):
                why = f"{problem}{more}: the dataset holds samples of the files as they were then (the press "
                why += f"captured, rendered or copied over since); {self.remake} to sample it anew"
            else:
                why = f"{problem}{more}; {self.folder} was built before datasets recorded their presses' files, so "
                why += "it may hold samples of the changed file: copy, capture or render the press again, then "
                why += self.remake
            changed[name] = f"{Path(folder) / first}: {why}"
        return changed

    def samples_key(self, train: Sequence[str], val: Sequence[str]) -> str | None:
        """The identity of the samples a training of presses ``train`` validated on ``val`` reads, from index.json's
        records alone (ms, nothing inflated): 16 hex digits of SHA-256 over the sensor record, the sampling record,
        sensor.npz's digest and each press's name and shard digest, in order (:func:`sample_file_record`); None when
        index.json lacks a record (a dataset built before 2026-12-07). Equal keys mean equal training inputs while
        the files are those recorded (:meth:`samples_changed`)."""
        records = {e["name"]: e.get(SHARD_RECORD) for e in self.entries}
        sensor = self.index.get(SENSOR_RECORD)
        named = [*train, *val]
        if not all(_is_file_record(r) for r in [sensor, *(records.get(n) for n in named)]):
            return None
        what = {
            "sensor": self.index.get("sensor"),
            "sampling": self.index.get("sampling"),
            "sensor_file": sensor["sha256"],
            "train": [[n, records[n]["sha256"]] for n in train],
            "val": [[n, records[n]["sha256"]] for n in val],
        }
        return hashlib.sha256(json.dumps(what, sort_keys=True).encode()).hexdigest()[:16]

    def samples_changed(self, names: Iterable[str]) -> str | None:
        """Why the sample files of presses ``names`` (and sensor.npz) are not those index.json records, in one line
        naming the first file, or None: each file's size (a stat), then its SHA-256 (~0.1 s for Q2 full's 127 MB).

        Why: a kept re-run of `nlips train` (:meth:`samples_key`) reads no sample; a file cut, replaced or changed
        since the build wrote it would otherwise pass for the samples the model was trained on."""
        paths = [(self.folder / SENSOR_FILE, self.index.get(SENSOR_RECORD))]
        paths += [(self.folder / SHARD_DIR / f"{e['name']}.npz", e.get(SHARD_RECORD)) for e in self._named(names)]
        for path, record in paths:
            if not _is_file_record(record):
                return f"{path}: index.json records no digest of it"
            try:
                size = path.stat().st_size
            except OSError:
                return f"{path}: missing"
            if size != record["bytes"]:
                return f"{path}: {size} bytes, {record['bytes']} when the dataset was built"
            if sample_file_record(path)["sha256"] != record["sha256"]:
                return f"{path}: its content differs from the digest index.json records (changed since it was written)"
        return None

    def _named(self, names: Iterable[str]) -> list[dict]:
        return [self.entry(n) for n in names]

    def entry(self, name: str) -> dict:
        for e in self.entries:
            if e["name"] == name:
                return e
        raise CaptureError(f"{self.folder / INDEX_FILE}: no press named {name!r}")

    def load(self, name: str) -> dict:
        """The samples of one press (module docstring), validated."""
        path = self.folder / SHARD_DIR / f"{name}.npz"
        arrays = _checked_shard(path)
        _check_pixels(arrays["pixel"], self.sensor["camera"], path)
        n, entry = len(arrays["rgb"]), self.entry(name)
        if n != entry["samples"]:
            raise CaptureError(f"{path}: {n} samples, index.json says {entry['samples']}")
        made = (_shard_entry(arrays) or {}).get("stamp")
        if made is not None and entry.get("stamp") is not None and made != entry["stamp"]:
            # a build of other options (or results) replaced it after index.json was written: never mixed in
            raise CaptureError(
                f"{path}: made from other results or sampling options than index.json records (another run "
                f"replaced it); {self.remake}"
            )
        return {k: arrays[k] for k in SHARD_KEYS}

    def arrays(self, names: Iterable[str] | None = None) -> dict:
        """Samples of several presses concatenated, with ``press`` (N,) int16 = position in ``names``."""
        names = self.names if names is None else list(names)
        parts = [self.load(n) for n in names]
        out = {k: np.concatenate([p[k] for p in parts]) for k in SHARD_KEYS}
        out["press"] = np.concatenate([np.full(len(p["rgb"]), i, np.int16) for i, p in enumerate(parts)])
        return out

    def filtered_reference(self) -> np.ndarray:
        """(H, W, 3) float32: the reference tri-colour frame filtered like the samples' colours."""
        ref = self.reference()
        return Prefilter(ref["valid"], self.smoothing_px, self.smoothing_colour)(ref["tricolor"])

    def reference(self) -> dict:
        """The undeformed reference arrays (:func:`reference_arrays`)."""
        path = self.folder / SENSOR_FILE
        cam = self.sensor["camera"]
        shape = (cam["height"], cam["width"])
        # shapes from the headers before anything is inflated, and the sensor's arrays only (a dataset from
        # elsewhere: docs/formats.md, "Files from others")
        headers = read_array_headers(path, SENSOR_KEYS)
        if headers["depth"][0] != shape or headers["tricolor"][0] != shape + (3,):
            raise CaptureError(f"{path}: arrays do not match the sensor's {cam['width']}x{cam['height']} image")
        arrays = read_arrays(path, SENSOR_KEYS, only=SENSOR_KEYS)
        check_reference_values(arrays, path)
        return arrays
