"""GelSight-style lookup-table baseline (Yuan et al. 2017): binned colour change -> normal, per image region.

The colour of a pixel minus the undeformed reference frame's colour there is quantised into
``bins`` levels per channel (range: the training samples' 0.5-99.5 percentiles); every image region
(``cells x cells``) has its own table holding the mean training normal of each filled bin. A query
falls back to the nearest filled bin of its region (in bin-index space), so the table answers every
colour.

The table's model file (``nlips lut CALIB --out TABLE.pt``, docs/formats.md "Lookup-table model file") is the
NLiPsNet model file's container (``learn.model``: a ``torch.save`` dict read with ``weights_only=True``, the sensor
and undeformed reference it was calibrated for, the samples' prefilter) holding the table's arrays
(:meth:`LookupTable.arrays`) instead of weights: ``nlips infer``, ``nlips live`` and ``nlips eval`` run it as they run
a network, through ``learn.infer.Predictor``.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CaptureError, ShapeError
from ..core.tolerances import NORMAL_EPS, UNIT_NORMAL_TOL

if TYPE_CHECKING:  # named in hints only
    from .dataset import CalibrationDataset

DEFAULT_BINS = 16
"""Levels per colour channel (the experiments' Q2 baseline: 5.75 / 8.08 deg vs truth, seen / unseen, full size)."""
DEFAULT_CELLS = 8
"""Image regions per side."""
MAX_BINS = 256
"""Most levels per channel a table file may declare (its keys are int16, a region's table at most 256^3 bins)."""
MAX_CELLS = 64
"""Most regions per side a table file may declare."""
DENSE_ANSWERS = 1 << 21
"""Most bins (regions x levels^3) whose answers :meth:`LookupTable.predict` keeps in one array (48 MB of float64)."""
TABLE_ARRAYS = ("lo", "hi", "region", "keys", "normals")
"""The arrays of a table's file entry (:meth:`LookupTable.arrays`)."""


@dataclasses.dataclass
class LookupTable:
    """A fitted lookup table; build with :meth:`fit`."""

    lo: np.ndarray
    """(3,) float -- lower end of the colour-change range per channel (linear units)."""
    hi: np.ndarray
    """(3,) float -- upper end."""
    bins: int
    """Levels per channel."""
    cells: int
    """Image regions per side."""
    shape: tuple[int, int]
    """(H, W) of the sensor's images."""
    reference: np.ndarray
    """(H, W, 3) float32 -- the undeformed reference tri-colour frame (linear)."""
    tables: dict
    """region index -> (keys (K, 3) int bin indices, normals (K, 3) unit, scipy cKDTree over keys)."""
    _answers: np.ndarray | None = dataclasses.field(default=None, repr=False)
    """(cells^2, bins^3, 3) float64: every region's answer to every bin, made at the first :meth:`predict` when it
    holds at most :data:`DENSE_ANSWERS` bins (:meth:`_dense_answers`); None: not made (yet)."""

    @classmethod
    def fit(
        cls,
        pixel: np.ndarray,
        rgb: np.ndarray,
        normal: np.ndarray,
        reference: np.ndarray,
        cells: int = 8,
        bins: int = 16,
    ) -> LookupTable:
        """Fit from samples.

        Parameters
        ----------
        pixel : (N, 2) int, (u, v) ; rgb : (N, 3) float linear ; normal : (N, 3) unit, camera frame
        reference : (H, W, 3) float32, the undeformed reference tri-colour frame (linear)
        """
        if reference.ndim != 3 or len(pixel) != len(rgb) or len(rgb) != len(normal):
            raise ShapeError("LookupTable.fit: pixel, rgb, normal must have the same length; reference (H, W, 3)")
        delta = rgb - reference[pixel[:, 1], pixel[:, 0]]
        lo, hi = np.percentile(delta, 0.5, axis=0), np.percentile(delta, 99.5, axis=0)
        lut = cls(lo, hi + 1e-9, bins, cells, reference.shape[:2], reference.astype(np.float32), {})
        keys, region = lut._keys(pixel, rgb), lut._region(pixel)
        lut.tables = {r: lut._table(keys[region == r], normal[region == r]) for r in np.unique(region)}
        lut.tables[-1] = lut._table(keys, normal)  # all regions pooled: for regions without samples
        return lut

    def predict(self, pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        """(N, 3) unit normals for samples at ``pixel`` ((N, 2) (u, v)) with colours ``rgb`` ((N, 3) linear)."""
        keys, region = self._keys(pixel, rgb), self._region(pixel)
        if self.cells**2 * self.bins**3 <= DENSE_ANSWERS:
            if self._answers is None:
                self._answers = self._dense_answers()
            return self._answers[region, (keys[:, 0] * self.bins + keys[:, 1]) * self.bins + keys[:, 2]]
        out = np.empty((len(keys), 3))
        for r in np.unique(region):
            m = region == r
            out[m] = self._nearest(int(r), keys[m])
        return out

    def _nearest(self, region: int, keys: np.ndarray) -> np.ndarray:
        """(N, 3) the normals of the filled bins of ``region`` (the pooled table's for a region without samples)
        nearest to ``keys`` ((N, 3) bin indices)."""
        _, normals, tree = self.tables.get(region, self.tables[-1])
        return normals[tree.query(keys)[1]]

    def _dense_answers(self) -> np.ndarray:
        """Every region's :meth:`_nearest` answer to every bin, at once: a frame's pixels are then looked up, not
        searched, the same normals (20,000 pixels of a 640x480 table: 1.3 ms against the k-d trees' 95 ms, on the
        2-core VM at load ~29; benchmarks/bench_lut_predict.py). 6 MB and 1.6 s at that load for the default 16
        levels and 8x8 regions, once (the Predictor's warm-up)."""
        grid = np.stack(np.unravel_index(np.arange(self.bins**3), (self.bins,) * 3), -1)
        pooled = self._nearest(-1, grid)
        present = {int(r) for r in self.tables}
        return np.stack([self._nearest(r, grid) if r in present else pooled for r in range(self.cells**2)])

    @functools.cached_property
    def bin_step_deg(self) -> float:
        """What the table's bins resolve: the median angle, degrees, between the normals of two filled bins of one
        region that are neighbours (one level apart in one colour channel); NaN when no two filled bins are.

        Why: a table answers a colour with its bin's mean normal, so its normals come in steps of this (a 640x480
        twin calibration's 16 levels, 8x8 regions: 3.5 deg, benchmarks/RESULTS.md s39-lutwords); the steepness
        warning names it for a table's results (:mod:`.resolution`). The pooled table is left out: a region's own
        bins are what its pixels read."""
        regions = [r for r in self.tables if r != -1]
        if not regions:
            return math.nan
        region = np.concatenate([np.full(len(self.tables[r][0]), r, np.int64) for r in regions])
        keys = np.concatenate([self.tables[r][0] for r in regions]).astype(np.int64)
        normals = np.concatenate([self.tables[r][1] for r in regions])
        flat = ((region * self.bins + keys[:, 0]) * self.bins + keys[:, 1]) * self.bins + keys[:, 2]
        order = np.argsort(flat)
        ordered = flat[order]
        angles = []
        for channel, stride in enumerate((self.bins**2, self.bins, 1)):
            below = keys[:, channel] + 1 < self.bins  # a neighbour one level up lies in the same region
            wanted = flat[below] + stride
            at = np.minimum(np.searchsorted(ordered, wanted), len(ordered) - 1)
            found = ordered[at] == wanted
            cosine = np.sum(normals[below][found] * normals[order[at[found]]], axis=-1)
            angles.append(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))
        angles = np.concatenate(angles)
        return float(np.median(angles)) if angles.size else math.nan

    # ------------------------------------------------------------------ file entry
    def arrays(self) -> dict:
        """The table as plain arrays and numbers (a model file's ``table``): ``bins``, ``cells``, ``lo`` and ``hi``
        (3,) float64 (exact: they decide every key), ``region`` (K,) int32 (-1: every region pooled), ``keys`` (K, 3)
        int16 bin indices, ``normals`` (K, 3) float32 unit. The reference frame is not in it: the model file carries
        the calibration's, and :meth:`from_arrays` filters it as the samples were."""
        regions = sorted(self.tables)
        return {
            "bins": int(self.bins),
            "cells": int(self.cells),
            "lo": np.asarray(self.lo, np.float64),
            "hi": np.asarray(self.hi, np.float64),
            "region": np.concatenate([np.full(len(self.tables[r][0]), r, np.int32) for r in regions]),
            "keys": np.concatenate([self.tables[r][0] for r in regions]).astype(np.int16),
            "normals": np.concatenate([self.tables[r][1] for r in regions]).astype(np.float32),
        }

    @classmethod
    def from_arrays(cls, arrays: Mapping, reference: np.ndarray, where: object = "table") -> LookupTable:
        """The table of :meth:`arrays`' entry, checked; CaptureError naming ``where`` (the file) for an entry no
        fit makes (a damaged or hand-edited file).

        Parameters
        ----------
        arrays : mapping of :data:`TABLE_ARRAYS`, ``bins`` and ``cells`` (numpy arrays)
        reference : (H, W, 3) float32, the undeformed reference frame filtered as the samples' colours
        """
        from scipy.spatial import cKDTree

        bins, cells = arrays.get("bins"), arrays.get("cells")
        if type(bins) is not int or not 2 <= bins <= MAX_BINS:
            raise CaptureError(f"{where}: 'bins' must be an integer in [2, {MAX_BINS}], got {bins!r}")
        if type(cells) is not int or not 1 <= cells <= MAX_CELLS:
            raise CaptureError(f"{where}: 'cells' must be an integer in [1, {MAX_CELLS}], got {cells!r}")
        lo, hi, region, keys, normals = (np.asarray(arrays[k]) for k in TABLE_ARRAYS)
        k = len(region)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(hi > lo)):
            raise CaptureError(f"{where}: 'lo' and 'hi' must be 3 finite colour limits each, hi above lo")
        if region.ndim != 1 or keys.shape != (k, 3) or normals.shape != (k, 3) or region.dtype.kind != "i":
            raise CaptureError(f"{where}: 'region' (K,), 'keys' (K, 3) and 'normals' (K, 3) disagree in shape")
        if keys.dtype.kind != "i" or k == 0 or keys.min() < 0 or keys.max() >= bins:
            raise CaptureError(f"{where}: 'keys' must be bin indices in [0, {bins}) (and the table not empty)")
        if region.min() < -1 or region.max() >= cells * cells or not np.any(region == -1):
            raise CaptureError(f"{where}: 'region' must index the {cells}x{cells} regions, with -1 (pooled) among them")
        if not np.all(np.abs(np.linalg.norm(normals, axis=-1) - 1) < UNIT_NORMAL_TOL):
            raise CaptureError(f"{where}: 'normals' must be finite unit vectors")
        lut = cls(lo, hi, bins, cells, reference.shape[:2], reference.astype(np.float32), {})
        keys, normals = keys.astype(np.int64), normals.astype(np.float64)
        for r in np.unique(region):
            m = region == r
            lut.tables[int(r)] = (keys[m], normals[m], cKDTree(keys[m]))
        return lut

    # ------------------------------------------------------------------ internals
    def _keys(self, pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        pixel = pixel.astype(np.intp)  # a shard's int16, a frame's float32 columns
        delta = rgb - self.reference[pixel[:, 1], pixel[:, 0]]
        q = np.floor((delta - self.lo) / (self.hi - self.lo) * self.bins).astype(np.int64)
        return np.clip(q, 0, self.bins - 1)

    def _region(self, pixel: np.ndarray) -> np.ndarray:
        H, W = self.shape
        pixel = pixel.astype(np.int64)  # int16 * cells overflows at large images
        return (pixel[:, 1] * self.cells // H) * self.cells + pixel[:, 0] * self.cells // W

    def _table(self, keys: np.ndarray, normals: np.ndarray) -> tuple:
        from scipy.spatial import cKDTree

        flat = (keys[:, 0] * self.bins + keys[:, 1]) * self.bins + keys[:, 2]
        uniq, inv = np.unique(flat, return_inverse=True)
        sums = np.zeros((len(uniq), 3))
        np.add.at(sums, inv, normals)
        mean = sums / np.maximum(np.linalg.norm(sums, axis=-1, keepdims=True), NORMAL_EPS)
        ukeys = np.stack([uniq // self.bins**2, (uniq // self.bins) % self.bins, uniq % self.bins], -1)
        return ukeys, mean, cKDTree(ukeys)


def fit_lookup_table(
    data: CalibrationDataset,
    names: Sequence[str],
    labels: str = "nlips",
    cells: int = DEFAULT_CELLS,
    bins: int = DEFAULT_BINS,
) -> LookupTable:
    """The lookup table fitted on the samples of the presses ``names`` of a calibration dataset: the one fit of
    ``nlips lut`` and the experiments' baseline.

    Parameters
    ----------
    data : CalibrationDataset
    names : press names whose samples it is fitted on
    labels : "nlips" (the NLiPs normals the dataset holds) or "true" (the ground truth, samples without it left out)
    cells, bins : regions per side, levels per colour channel
    """
    if labels not in ("nlips", "true"):
        raise ShapeError(f"labels must be 'nlips' or 'true', got {labels!r}")
    s = data.arrays(names)
    target = s["normal"] if labels == "nlips" else s["true_normal"]
    keep = np.all(np.isfinite(target), -1)
    if not keep.any():
        raise CaptureError(f"{data.folder}: no sample of {', '.join(names) or 'no press'} has a {labels} label")
    return LookupTable.fit(
        s["pixel"][keep].astype(np.int64), s["rgb"][keep], target[keep], data.filtered_reference(), cells, bins
    )


def fit_table_file(
    data: CalibrationDataset,
    out: str | Path,
    exclude: Sequence[str] = (),
    labels: str = "nlips",
    cells: int = DEFAULT_CELLS,
    bins: int = DEFAULT_BINS,
) -> tuple[LookupTable, dict]:
    """Fit a lookup table on a calibration dataset's presses (less ``exclude``) and write its model file ``out``
    (``learn.model.save_table``, atomically): what ``nlips lut`` does.

    The file carries the sensor and undeformed reference the dataset records, the samples' prefilter and ``info``:
    ``labels``, ``config`` (``bins``, ``cells``, ``labels``), ``dataset`` (the folder's name), ``samples_digest``
    (of the samples fitted on, ``learn.checkpoint.data_key_of``), ``capture``, ``train_presses``, ``captures``
    (``{press name: capture identity}`` of ``train_presses``, index.json's ``capture_identity``, None where it records
    none: as a network's, what ``nlips infer`` compares a press with for report.json ``trained_on``,
    :mod:`.seen`), ``press_identities`` (their identities by content, index.json's ``press_identity``, compared
    first), ``excluded_presses``, ``train_samples``, ``contact_samples``, ``filled_bins`` and ``contacts``
    (``learn.resolution.calibrated_contacts``: ``nlips infer`` warns of steeper contacts, as for a network). No
    time in it: the same fit writes the same bytes, so ``nlips infer`` keeps the results it made with it.

    Returns
    -------
    (LookupTable, info)
    """
    from ..core.errors import ConfigError
    from ..core.press_identity import IDENTITY_KEY
    from .checkpoint import data_key_of
    from .dataset import CAPTURE_IDENTITY, INDEX_FILE
    from .model import save_table
    from .resolution import INFO_KEY, calibrated_contacts
    from .seen import CAPTURES_KEY, IDENTITIES_KEY

    if type(bins) is not int or not 2 <= bins <= MAX_BINS:
        raise ConfigError(f"bins must be an integer in [2, {MAX_BINS}], got {bins!r}")
    if type(cells) is not int or not 1 <= cells <= MAX_CELLS:
        raise ConfigError(f"cells must be an integer in [1, {MAX_CELLS}], got {cells!r}")
    if unknown := sorted(set(exclude) - set(data.names)):
        raise ConfigError(f"{data.folder}: excluded presses {unknown} are not in the dataset")
    names = [
        e["name"] for e in data.entries if (labels == "nlips" or e.get("has_truth")) and e["name"] not in set(exclude)
    ]
    if not names:
        usable = "" if labels == "nlips" else " with ground truth (true-normal labels)"
        raise ConfigError(f"{data.folder / INDEX_FILE}: no press{usable} is left to fit the table on")
    table = fit_lookup_table(data, names, labels, cells, bins)
    s = data.arrays(names)
    target = s["normal"] if labels == "nlips" else s["true_normal"]
    keep = np.all(np.isfinite(target), -1)
    info = {
        "labels": labels,
        "config": {"bins": bins, "cells": cells, "labels": labels},
        "dataset": data.folder.resolve().name,
        "samples_digest": data_key_of(s["pixel"][keep], s["rgb"][keep], target[keep]),
        "capture": data.capture,
        "train_presses": names,
        # the table learnt from these captures: its results tell them from the others (report.json trained_on)
        CAPTURES_KEY: {name: data.entry(name).get(CAPTURE_IDENTITY) for name in names},
        IDENTITIES_KEY: {name: data.entry(name).get(IDENTITY_KEY) for name in names},  # by content (learn.seen)
        "excluded_presses": sorted(exclude),
        "train_samples": int(keep.sum()),
        "contact_samples": int((keep & s["contact"]).sum()),
        "filled_bins": int(sum(len(t[0]) for r, t in table.tables.items() if r != -1)),
        INFO_KEY: calibrated_contacts(data, names, labels),
    }
    save_table(
        out,
        table,
        sensor=data.sensor,
        reference=data.reference(),
        info=info,
        smoothing_px=data.smoothing_px,
        smoothing_colour=data.smoothing_colour,
    )
    return table, info
