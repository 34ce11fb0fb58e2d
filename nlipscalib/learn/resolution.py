"""Whether a frame's contact is like the contacts a model (NLiPsNet, or a lookup table: ``learn.lut``) was calibrated
on: small and steep ones are not trusted.

NLiPsNet maps each pixel's filtered colour to a normal; it learns the solve's labels, which are smoothed over a
few pixels whatever the dent's size (``core.steepness``), and the colours are low-pass filtered too
(:mod:`.prefilter`). A contact whose normals turn steeply within few pixels -- a 1 mm sphere -- then comes out with
its slopes flattened by several degrees (s27-unusual: the fast net 5.58 deg on a 1 mm sphere at 640x480, 1.15 on a
6 mm one), silently. At training, :func:`calibrated_contacts` records per press how large its changed region was
and how far its labels tilt there; at inference, :func:`steepness_warning` compares each frame's changed region and
predicted normals with that and with the solve's rule, measured on the changed region
(:data:`~nlipscalib.core.tolerances.CHANGED_TILT_PER_PX`).
Both use the change rule's region (:mod:`.change`), the same at training and at inference, and one measure of it
(:func:`measure_contact`): a calibration press's two figures differ by its normals alone, labels against the model's
(Q2 full's 50 presses: the frame's 0.945-1.014 times the recorded). A lookup table's results are judged alike, by
its own figure (:data:`~nlipscalib.core.tolerances.TABLE_CHANGED_TILT_PER_PX`: its normals stop at its bins'
steepest) and worded as its own (:func:`model_words`): a table resolves what its bins resolve.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core import masks, tolerances
from ..core.steepness import patch_steepness
from .change import DILATE_BLOCKS

if TYPE_CHECKING:  # named in hints only
    from .dataset import CalibrationDataset
    from .infer import Frame, Predictor
    from .model import LoadedModel

RIM_PX = 2 * DILATE_BLOCKS
"""Pixels the change rule grows its changed region by (:data:`.change.DILATE_BLOCKS` blocks of 2x2), taken off again
before the contact is measured: that margin of flat gel widened a small contact and lowered its tilt (the 1 mm
sphere 0.3 mm deep at 640x480: 34 px / 26 deg with it, against the solve's hits, 28 px / 41 deg)."""
INFO_KEY = "contacts"
"""The model file's ``info`` entry of :func:`calibrated_contacts` (absent in files from before 2026-12-06: no check
against the calibration then, the rule only)."""


def measure_contact(
    region: np.ndarray, normals: np.ndarray, reference_normals: np.ndarray, origin: tuple[int, int] = (0, 0)
) -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of a contact: the one measure a calibration press is recorded by
    (:func:`press_contact`, its labels) and a frame is judged by (:func:`judge_steepness`, the model's normals), so
    that the two cannot drift apart; None without a contact (:func:`nlipscalib.core.steepness.patch_steepness`).

    The region's notches narrower than 2 :data:`RIM_PX` + 1 px (the rim's reach from both sides) are closed by a
    disc (``core.masks.close``) and its holes filled, its :data:`RIM_PX` rim taken off, and the largest patch left
    measured: its size the diameter, the tilt over its pixels of ``region`` alone. Why: a calibration press's region
    is its contact samples, which leave out the pixels whose NLiPs label was unreliable (a coin's steep walls), and
    taking the rim off round each of them cut the steep relief next to them away: inside the contact such pixels are
    holes (Q2's coin measured 173 px / 16.9 deg, 0.097 deg/px, on its labels against 190 px / 21.0 deg, 0.110, with
    the same labels on the change rule's whole region; s39-steepwarn), at its edge a notch open to the outside, which
    the rim ate into (a disc 40 px across with a notch of them 6 px wide and 10 deep at its edge: 30.4 px against
    its frame's 32.6, now 32.4; s40-steep).
    Not the convex hull: it spans a contact's own concave outline (a key, two fingers) and moved Q2's presses 2-8 %
    where the disc's closing moved them 0.3-2.6 % (benchmarks/RESULTS.md, s40-steep).

    Parameters
    ----------
    region : (h, w) bool -- the contact's pixels (the change rule's changed pixels, or a press's contact samples)
        in the window of the image whose first row and column are ``origin``.
    normals : (H, W, 3) float, unit, camera frame -- the whole image's normals (any value outside ``region``).
    reference_normals : (H, W, 3) float, unit, camera frame -- the undeformed surface's normals.
    origin : (row, column) int, px -- where ``region`` lies in the image.
    """
    core = masks.erode(masks.fill_holes(masks.close(region, RIM_PX)), RIM_PX)
    return patch_steepness(core, normals, reference_normals, origin, measured=region)


def press_contact(samples: dict, reference_normals: np.ndarray, labels: str = "nlips") -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of one press's changed region (its shard's ``contact`` samples) and of
    its labels there (:func:`measure_contact`, as a frame is judged); None without a contact.

    Parameters
    ----------
    samples : one shard of the calibration dataset (``CalibrationDataset.load``): ``pixel`` (N, 2) int (u, v),
        ``contact`` (N,) bool, ``normal`` and ``true_normal`` (N, 3) float32, unit, camera frame.
    reference_normals : (H, W, 3) float, unit, camera frame -- the undeformed surface's normals.
    labels : "nlips" (the ``normal`` labels) or "true" (``true_normal``): what the net was trained on.
    """
    shape = reference_normals.shape[:2]
    keep = np.asarray(samples["contact"], bool)
    u, v = samples["pixel"][keep, 0].astype(int), samples["pixel"][keep, 1].astype(int)
    patch = np.zeros(shape, bool)
    patch[v, u] = True
    normals = np.zeros(shape + (3,), np.float32)
    normals[v, u] = samples["true_normal" if labels == "true" else "normal"][keep]
    return measure_contact(patch, normals, reference_normals)


def calibrated_contacts(dataset: CalibrationDataset, names: Iterable[str], labels: str = "nlips") -> dict:
    """What the calibration presses ``names`` covered, for the model file's ``info`` (:data:`INFO_KEY`).

    Returns
    -------
    dict: ``presses`` {name: [diameter px, tilt deg]} (rounded to 0.1; presses without a contact left out),
    ``min_diameter_px``, ``max_tilt_deg`` and ``max_tilt_per_px`` (the steepest press's tilt over its diameter,
    deg/px) over them, None without any.
    """
    reference_normals = dataset.reference()["normals"]
    presses = {}
    for name in names:
        found = press_contact(dataset.load(name), reference_normals, labels)
        if found is not None:
            presses[name] = [round(found[0], 1), round(found[1], 1)]
    sizes = [d for d, _ in presses.values()]
    return {
        "presses": presses,
        "min_diameter_px": min(sizes) if sizes else None,
        "max_tilt_deg": max((t for _, t in presses.values()), default=None),
        "max_tilt_per_px": max((t / d for d, t in presses.values()), default=None),
    }


def recorded_steepness(info: dict) -> float | None:
    """The steepest calibrated tilt per pixel (deg/px) a model file's ``info`` records, or None (an older file, or
    one from elsewhere whose entry is not a positive number: no check against the calibration, never an error)."""
    contacts = info.get(INFO_KEY) if isinstance(info, dict) else None
    value = contacts.get("max_tilt_per_px") if isinstance(contacts, dict) else None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
        return None
    return float(value)


@dataclass(frozen=True)
class ModelWords:
    """How a steepness warning names the model whose normals it judges, and the figure it holds them to
    (:func:`model_words`).

    Attributes
    ----------
    resolves : str -- what resolves :attr:`limit_per_px`, after "the ~0.4 deg/px".
    normals : str -- what the model's normals are in such a contact.
    table : bool -- a lookup table's (:data:`~nlipscalib.core.tolerances.TABLE_CHANGED_TILT_PER_PX`), not a network's.
    """

    resolves: str
    normals: str
    table: bool = False

    @property
    def limit_per_px(self) -> float:
        """The deg/px beyond which the model's normals in a contact are smoothed: a network's
        :data:`~nlipscalib.core.tolerances.CHANGED_TILT_PER_PX`, a table's
        :data:`~nlipscalib.core.tolerances.TABLE_CHANGED_TILT_PER_PX` (read when judged)."""
        return tolerances.TABLE_CHANGED_TILT_PER_PX if self.table else tolerances.CHANGED_TILT_PER_PX


NETWORK_WORDS = ModelWords("NLiPsNet resolves", "NLiPsNet's normals there are smoothed")
"""A network's words (and those of a caller that names no model)."""


def model_words(model: LoadedModel) -> ModelWords:
    """The words of a steepness warning about ``model``'s normals: NLiPsNet's, or a lookup table's (``learn.lut``).

    Why: a table's normals are its bins' means: it resolves what its bins resolve, the step between neighbouring
    bins' normals (:attr:`.lut.LookupTable.bin_step_deg`), said with its levels, and its own figure
    (:data:`~nlipscalib.core.tolerances.TABLE_CHANGED_TILT_PER_PX`, 0.3 deg/px against a network's 0.4: its normals
    stop at its bins' steepest, so a steep contact reads flatter on them; s40-steep); a warning that named NLiPsNet
    for a table's results (s38-lutcli) sent the user to a network they had not run."""
    table = getattr(model, "table", None)
    if table is None:
        return NETWORK_WORDS
    step = table.bin_step_deg
    bins = f"{table.bins} levels per colour channel"
    apart = f"its neighbouring bins' normals ~{step:.1f} deg apart, {bins}" if math.isfinite(step) else f"its {bins}"
    return ModelWords(
        "a lookup table's normals resolve",
        f"the lookup table resolves what its bins resolve ({apart}), and its normals there are smoothed",
        table=True,
    )


@dataclass(frozen=True)
class Steepness:
    """A contact judged too small or steep for the model's normals (:func:`judge_steepness`).

    Attributes
    ----------
    diameter : float, px -- the contact's equivalent diameter (``core.steepness.patch_steepness``).
    tilt : float, degrees -- its predicted normals' tilt from the undeformed surface (75th percentile).
    limits : tuple of str -- the limits it is beyond, in words.
    words : :class:`ModelWords` -- the model whose normals these are.
    uncalibrated : bool -- whether it is beyond the steepest calibration press (not only beyond the model's figure).
    """

    diameter: float
    tilt: float
    limits: tuple[str, ...]
    words: ModelWords = NETWORK_WORDS
    uncalibrated: bool = False

    def line(self, where: str | Path) -> str:
        """The warning for the frame named ``where``: what to do names calibrating with steeper presses only where
        the calibration's steepest press is exceeded (the model's own figure is not lifted by it: a new lab's walk at
        160x120 was told so of frames of its very calibration presses)."""
        per_px = self.tilt / self.diameter
        todo = (
            "capture at a higher resolution, press with a larger indenter, or calibrate with presses as small and steep"
            if self.uncalibrated
            else "capture at a higher resolution or press with a larger indenter"
        )
        return (
            f"{where}: contact about {self.diameter:.0f} px across with its normals tilted ~{self.tilt:.0f} deg "
            f"({per_px:.2f} deg/px): beyond {' and '.join(self.limits)}; {self.words.normals} "
            f"(expect several degrees of error); {todo}"
        )


@dataclass(frozen=True)
class ContactExtent:
    """How many pixels a frame's contact has, where their middle is, and their bounding box: what a stream compares
    to tell a held press from a moving one (:class:`StreamSteepness`) without measuring the contact.

    Attributes
    ----------
    pixels : int -- changed pixels.
    middle : (row, column) float, px -- their centroid.
    box : (top, bottom, left, right) int, px -- their bounding box's first and last row and column (where the
        contact is measured; not compared: one noise speck of the change rule far from the contact moves it by
        hundreds of pixels, and the contact's middle by a fraction of one).
    """

    pixels: int
    middle: tuple[float, float]
    box: tuple[int, int, int, int]

    def near(self, other: ContactExtent, fraction: float) -> bool:
        """Whether ``other`` has within ``fraction`` as many pixels as this and its middle lies within ``fraction``
        of this one's equivalent diameter (at least a pixel) of this one's."""
        diameter = 2.0 * math.sqrt(self.pixels / math.pi)
        moved = math.dist(self.middle, other.middle)
        return abs(other.pixels - self.pixels) <= fraction * self.pixels and moved <= max(1.0, fraction * diameter)

    def slices(self) -> tuple[slice, slice]:
        """The box as an index of (H, W) arrays."""
        top, bottom, left, right = self.box
        return np.s_[top : bottom + 1, left : right + 1]


def contact_extent(changed: np.ndarray) -> ContactExtent | None:
    """The :class:`ContactExtent` of ``changed`` ((H, W) bool), None without a changed pixel."""
    rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
    if rows.size == 0:
        return None
    top, bottom, left, right = int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])
    inside = changed[top : bottom + 1, left : right + 1]  # the box: nothing changed outside it
    per_row, per_col = np.count_nonzero(inside, axis=1), np.count_nonzero(inside, axis=0)
    pixels = int(per_row.sum())
    middle = (
        top + float(per_row @ np.arange(per_row.size)) / pixels,
        left + float(per_col @ np.arange(per_col.size)) / pixels,
    )
    return ContactExtent(pixels, middle, (top, bottom, left, right))


def bend_step(extent: ContactExtent) -> int:
    """Rows and columns :func:`contact_bend` samples a contact at: every this-many-th, for about
    :data:`~nlipscalib.core.tolerances.STREAM_TILT_SAMPLES` of its pixels (a small contact: every one)."""
    return max(1, math.isqrt(extent.pixels // tolerances.STREAM_TILT_SAMPLES))


def contact_bend(
    changed: np.ndarray, normals: np.ndarray, reference_normals: np.ndarray, extent: ContactExtent, step: int
) -> float:
    """How much a contact's normals turn from the undeformed ones, as a stream compares it to tell a held press from
    one that steepens or flattens in place (:class:`StreamSteepness`): the sum of 1 - cos(tilt) over the changed
    pixels of every ``step``-th row and column of the contact's box (:func:`bend_step`; frames compared at one step).

    Why a sum, not a mean: the change rule's isolated noise specks (a few flat pixels, far from the press) come and
    go on a held press; they add next to nothing to it, where they move a mean over a small contact by percents.
    Not the measure's tilt (its largest patch's 75th percentile): a fraction of its cost. NaN when a sampled pixel's
    normals are not finite.

    Parameters
    ----------
    changed : (H, W) bool -- the frame's changed pixels.
    normals, reference_normals : (H, W, 3) float32, unit, camera frame -- predicted and undeformed normals.
    extent : :func:`contact_extent` of ``changed``.
    step : int -- rows and columns sampled, on the image's grid.

    Returns
    -------
    float, >= 0 (unitless; compared relative to another frame's at the same step)
    """
    rows, cols = extent.slices()
    # the image's grid, not the box's: a speck that widens the box leaves the press's own samples as they were
    sampled = np.s_[-(-rows.start // step) * step : rows.stop : step, -(-cols.start // step) * step : cols.stop : step]
    keep, n, r = changed[sampled], normals[sampled], reference_normals[sampled]
    # the window's cosines, then the changed ones summed: a boolean gather of the normals first cost 4 times this
    cosine = n[..., 0] * r[..., 0]
    cosine += n[..., 1] * r[..., 1]
    cosine += n[..., 2] * r[..., 2]
    return float(np.count_nonzero(keep) - cosine[keep].sum(dtype=np.float64))


def judge_steepness(
    changed: np.ndarray,
    normals: np.ndarray,
    reference_normals: np.ndarray,
    calibrated_per_px: float | None,
    extent: ContactExtent | None = None,
    words: ModelWords = NETWORK_WORDS,
) -> Steepness | None:
    """The frame's contact when its normals are not to be trusted, or None.

    The frame's changed region's largest patch and its predicted normals' tilt (:func:`measure_contact`, the
    measure the calibration presses were recorded by) turn by more degrees per pixel than the model resolves
    (:attr:`ModelWords.limit_per_px` of ``words``: a network's
    :data:`~nlipscalib.core.tolerances.CHANGED_TILT_PER_PX`, a table's
    :data:`~nlipscalib.core.tolerances.TABLE_CHANGED_TILT_PER_PX`), or than the steepest calibration press did by
    :data:`~nlipscalib.core.tolerances.UNCALIBRATED_STEEPNESS_FACTOR` (``calibrated_per_px``; None: not checked).

    Parameters
    ----------
    changed : (H, W) bool -- the frame's changed pixels (``Frame.changed``).
    normals : (H, W, 3) float32, unit, camera frame -- the predicted normals.
    reference_normals : (H, W, 3) float32, unit, camera frame -- the undeformed surface's.
    calibrated_per_px : deg/px -- :func:`recorded_steepness` of the model's info.
    extent : :func:`contact_extent` of ``changed`` when known already.
    words : :func:`model_words` of the model that predicted ``normals``.
    """
    extent = extent or contact_extent(changed)
    if extent is None:
        return None
    # the changed pixels' bounding box only: the same patch (outside it nothing changed), a fraction of the pixels
    top, _, left, _ = extent.box
    found = measure_contact(changed[extent.slices()], normals, reference_normals, (top, left))
    if found is None:
        return None
    diameter, tilt = found
    per_px = tilt / diameter
    limits = []
    if per_px > words.limit_per_px:
        limits.append(f"the ~{words.limit_per_px:g} deg/px {words.resolves}")
    uncalibrated = (
        calibrated_per_px is not None and per_px > tolerances.UNCALIBRATED_STEEPNESS_FACTOR * calibrated_per_px
    )
    if uncalibrated:
        limits.append(f"the {calibrated_per_px:.2f} deg/px of the steepest calibration press")
    return Steepness(diameter, tilt, tuple(limits), words, uncalibrated) if limits else None


def steepness_warning(
    changed: np.ndarray,
    normals: np.ndarray,
    reference_normals: np.ndarray,
    where: str | Path,
    calibrated_per_px: float | None,
    words: ModelWords = NETWORK_WORDS,
) -> str | None:
    """Why a frame's normals in its contact are not to be trusted (:func:`judge_steepness`), or None; ``where``
    names the frame in the line, ``words`` the model (:func:`model_words`)."""
    judged = judge_steepness(changed, normals, reference_normals, calibrated_per_px, words=words)
    return None if judged is None else judged.line(where)


def _judged_contact(frame: Frame) -> np.ndarray | None:
    """The change rule's pixels of ``frame`` (``Frame.contact`` of a whole-frame prediction, else ``changed``), None
    for a frame unlike the reference over the whole gel (``infer.mismatch_warning`` says that)."""
    if frame.mismatch > tolerances.FRAME_MISMATCH_FRACTION:
        return None
    return frame.changed if frame.contact is None else frame.contact


def frame_warning(predictor: Predictor, frame: Frame, where: str | Path) -> str | None:
    """:func:`steepness_warning` of one of ``predictor``'s frames (its model's recorded calibration, its reference
    normals) on its change rule's changed pixels (``Frame.contact`` of a whole-frame prediction, ``full_frame``,
    whose ``changed`` is every gel pixel: the rule runs there too, on the device); None for a frame unlike the
    reference over the whole gel (``infer.mismatch_warning`` says that)."""
    contact = _judged_contact(frame)
    if contact is None:
        return None
    calibrated = recorded_steepness(predictor.model.info)
    words = model_words(predictor.model)
    return steepness_warning(contact, frame.normals, predictor.ref_normals, where, calibrated, words)


class StreamSteepness:
    """:func:`frame_warning` of a stream's frames, its contact measured again only when it changed: a held press
    is judged once, not on every frame.

    Why: measuring the contact costs 2-4.5 ms of host CPU per pressed 640x480 frame (24 ms for a 200 px contact
    under load; benchmarks/RESULTS.md, s29-lut8), ~10 % of a CPU changed-pixel frame and about a whole GPU full
    frame; a stream's consecutive frames mostly show the same press. A frame whose changed pixels' count and
    centroid are within :data:`~nlipscalib.core.tolerances.STREAM_CONTACT_CHANGE` of the last judged frame's
    gets that frame's verdict (reworded with its own name; a frame warned so counts as warned), at most
    :data:`~nlipscalib.core.tolerances.STREAM_REJUDGE_FRAMES` frames in a row and not across a frame without a
    contact (the press lifted); any other is measured. Still frames (``nlips infer`` of files) call
    :func:`frame_warning` on each.

    Parameters
    ----------
    predictor : learn.infer.Predictor -- its model's recorded calibration and reference normals.
    """

    def __init__(self, predictor: Predictor) -> None:
        self.predictor = predictor
        self.judged = 0
        """Frames whose contact was measured (the others reused a verdict)."""
        self._extent: ContactExtent | None = None
        self._bend, self._step = math.nan, 1
        """:func:`contact_bend` of the last judged frame, and the step it was sampled at (its :func:`bend_step`)."""
        self._verdict: Steepness | None = None
        self._reused = 0

    def __call__(self, frame: Frame, where: str | Path) -> str | None:
        """:func:`frame_warning` of ``frame``, named ``where``, or the last judged frame's verdict (see above)."""
        contact = _judged_contact(frame)
        if contact is None:  # unlike the reference (mismatch_warning): nothing to judge
            return None
        extent = contact_extent(contact)
        if extent is None:  # nothing changed: the press ended, the next one is measured whatever its place
            self._extent = None
            return None
        ref = self.predictor.ref_normals
        held = self._extent is not None and self._extent.near(extent, tolerances.STREAM_CONTACT_CHANGE)
        bend = contact_bend(contact, frame.normals, ref, extent, self._step) if held else math.nan
        # a press that steepens (or flattens) in place keeps its pixels: its normals tell, at once
        held = held and abs(bend - self._bend) <= tolerances.STREAM_TILT_CHANGE * self._bend
        if held and self._reused < tolerances.STREAM_REJUDGE_FRAMES:
            self._reused += 1
        else:
            calibrated = recorded_steepness(self.predictor.model.info)
            words = model_words(self.predictor.model)
            self._verdict = judge_steepness(contact, frame.normals, ref, calibrated, extent, words)
            self._extent, self._reused = extent, 0
            if not (math.isfinite(bend) and bend_step(extent) == self._step):
                self._step = bend_step(extent)
                bend = contact_bend(contact, frame.normals, ref, extent, self._step)
            self._bend = bend
            self.judged += 1
        return None if self._verdict is None else self._verdict.line(where)
