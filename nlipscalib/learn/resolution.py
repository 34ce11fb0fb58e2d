"""Whether a frame's contact is like the contacts NLiPsNet was calibrated on: small and steep ones are not trusted.

NLiPsNet maps each pixel's filtered colour to a normal; it learns the solve's labels, which are smoothed over a
few pixels whatever the dent's size (``core.steepness``), and the colours are low-pass filtered too
(:mod:`.prefilter`). A contact whose normals turn steeply within few pixels -- a 1 mm sphere -- then comes out with
its slopes flattened by several degrees (s27-unusual: the fast net 5.58 deg on a 1 mm sphere at 640x480, 1.15 on a
6 mm one), silently. At training, :func:`calibrated_contacts` records per press how large its changed region was
and how far its labels tilt there; at inference, :func:`steepness_warning` compares each frame's changed region and
predicted normals with that and with the solve's rule, measured on the changed region
(:data:`~nlipscalib.core.tolerances.CHANGED_TILT_PER_PX`).
Both use the change rule's region (:mod:`.change`), the same at training and at inference.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core import masks, tolerances
from ..core.steepness import patch_steepness
from .change import DILATE_BLOCKS

if TYPE_CHECKING:  # named in hints only
    from .dataset import CalibrationDataset
    from .infer import Frame, Predictor

RIM_PX = 2 * DILATE_BLOCKS
"""Pixels the change rule grows its changed region by (:data:`.change.DILATE_BLOCKS` blocks of 2x2), taken off again
before the contact is measured: that margin of flat gel widened a small contact and lowered its tilt (the 1 mm
sphere 0.3 mm deep at 640x480: 34 px / 26 deg with it, against the solve's hits, 28 px / 41 deg)."""
INFO_KEY = "contacts"
"""The model file's ``info`` entry of :func:`calibrated_contacts` (absent in files from before 2026-12-06: no check
against the calibration then, the rule only)."""


def press_contact(samples: dict, reference_normals: np.ndarray, labels: str = "nlips") -> tuple[float, float] | None:
    """(equivalent diameter px, tilt deg) of one press's changed region (its shard's ``contact`` samples) and of
    its labels there (:func:`nlipscalib.core.steepness.patch_steepness`); None without a contact.

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
    return patch_steepness(masks.erode(patch, RIM_PX), normals, reference_normals)


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


def steepness_warning(
    changed: np.ndarray,
    normals: np.ndarray,
    reference_normals: np.ndarray,
    where: str | Path,
    calibrated_per_px: float | None,
) -> str | None:
    """Why a frame's normals in its contact are not to be trusted, or None.

    The frame's changed region's largest patch and its predicted normals' tilt
    (:func:`nlipscalib.core.steepness.patch_steepness`) turn by more degrees per pixel than NLiPsNet resolves
    (:data:`~nlipscalib.core.tolerances.CHANGED_TILT_PER_PX`), or than the steepest calibration press did by
    :data:`~nlipscalib.core.tolerances.UNCALIBRATED_STEEPNESS_FACTOR` (``calibrated_per_px``; None: not checked).

    Parameters
    ----------
    changed : (H, W) bool -- the frame's changed pixels (``Frame.changed``).
    normals : (H, W, 3) float32, unit, camera frame -- the predicted normals.
    reference_normals : (H, W, 3) float32, unit, camera frame -- the undeformed surface's.
    where : the frame's name, for the line.
    calibrated_per_px : deg/px -- :func:`recorded_steepness` of the model's info.
    """
    rows, cols = np.flatnonzero(changed.any(axis=1)), np.flatnonzero(changed.any(axis=0))
    if rows.size == 0:
        return None
    # the changed pixels' bounding box only: the same patch (outside it nothing changed), a fraction of the pixels
    box = np.s_[rows[0] : rows[-1] + 1, cols[0] : cols[-1] + 1]
    found = patch_steepness(masks.erode(changed[box], RIM_PX), normals[box], reference_normals[box])
    if found is None:
        return None
    diameter, tilt = found
    per_px = tilt / diameter
    limits = []
    if per_px > tolerances.CHANGED_TILT_PER_PX:
        limits.append(f"the ~{tolerances.CHANGED_TILT_PER_PX:g} deg/px NLiPsNet resolves")
    if calibrated_per_px is not None and per_px > tolerances.UNCALIBRATED_STEEPNESS_FACTOR * calibrated_per_px:
        limits.append(f"the {calibrated_per_px:.2f} deg/px of the steepest calibration press")
    if not limits:
        return None
    return (
        f"{where}: contact about {diameter:.0f} px across with its normals tilted ~{tilt:.0f} deg "
        f"({per_px:.2f} deg/px): beyond {' and '.join(limits)}; NLiPsNet's normals there are smoothed (expect "
        f"several degrees of error); capture at a higher resolution, press with a larger indenter, or calibrate "
        f"with presses as small and steep"
    )


def frame_warning(predictor: Predictor, frame: Frame, where: str | Path) -> str | None:
    """:func:`steepness_warning` of one of ``predictor``'s frames (its model's recorded calibration, its reference
    normals) on its change rule's changed pixels (``Frame.contact`` of a whole-frame prediction, ``full_frame``,
    whose ``changed`` is every gel pixel: the rule runs there too, on the device); None for a frame unlike the
    reference over the whole gel (``infer.mismatch_warning`` says that)."""
    if frame.mismatch > tolerances.FRAME_MISMATCH_FRACTION:
        return None
    calibrated = recorded_steepness(predictor.model.info)
    contact = frame.changed if frame.contact is None else frame.contact
    return steepness_warning(contact, frame.normals, predictor.ref_normals, where, calibrated)
