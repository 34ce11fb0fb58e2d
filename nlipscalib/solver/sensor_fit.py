"""Were a press's images taken with the sensor its meta.json and reference.npz describe?

Why: the images carry no sensor identity, so a press whose meta.json (camera, LEDs) and reference.npz (the dome) were
copied from another sensor was solved without a word, to a wrong surface (s26-mismatch: the default dome's press
with the fingertip design's files: "anchoring off: weak evidence (0.8 % of the gel fits)", exit 0). The images are
evidence all the same: the undeformed part of the gel, lit by each LED, follows that LED's falloff over the
described dome. The contact classification fits the undeformed model to the press already (one albedo per pixel
and channel); here a gain per LED is fitted as well -- a real ring's LEDs differ in power, and that is the sensor's
own, not another sensor's -- and what the model still misses, over the image's brightness, measures how far the
description is from the sensor that took the images (benchmarks/RESULTS.md, s27-sensorfit).

Where the gel fills the view (every shipped design but the flat pad), the dome's silhouette is not in the images, so
the falloff is the only evidence; it tells designs apart whose domes or LED rings differ by millimetres, not a dome
4 mm lower or the capsule from the fingertip (:data:`nlipscalib.core.tolerances.SENSOR_MISFIT_SHARE`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core import tolerances

if TYPE_CHECKING:  # named in hints only
    from ..core.camera import Camera
    from ..core.capture import Press
    from .contact import ContactMap

SENSOR_FIT_SAMPLES = 2000
"""Gel pixels (or blocks) of the classification the fit samples, at least (every k-th in raster order): the
statistic is a median; at 4000 it was the same to a few tenths of a percent (cube1 0.65 %, the default dome's press
with the fingertip's files 11.9 against 12.0 %, LED powers 15 % off 1.73 % both)."""
FIT_PIXELS_QUANTILE = 0.1
"""The quantile of the pixels' misfits that :func:`gain_fitted_misfit` also gives: the best-fitting tenth of the gel
is undeformed even where a press covers most of it (a crop of the view around a dent), and still misfits on images
of another sensor."""
DARK_LEVEL = 0.1
"""Pixels darker than this fraction of the median pixel's brightness are left out of the best-fitting tenth: the
flat pad's images seen through the default dome's files are dark outside the pad, and fitted there exactly (0.03 %)."""
SENSOR_FIT_ITERATIONS = 6
"""Alternations of the per-pixel albedo and per-LED gain fits (LED powers 15 % off their design: 1.73 %, as with
10 alternations)."""


def gel_samples(
    model: np.ndarray, images: np.ndarray, valid: np.ndarray, ok: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray] | None:
    """The undeformed model and the press's images on every k-th usable gel pixel of the classification's grid.

    Parameters
    ----------
    model : (L, h, w, 3) float32 -- the undeformed model (direct shading plus indirect light, or a capture of the
        undeformed dome), linear, on the classification's grid.
    images : (L, h, w, 3) float32 -- the press's LED images (live LEDs), on the same grid.
    valid : (h, w) bool -- the grid's gel pixels.
    ok : (L, h, w, 3) bool or None -- usable samples (None: all); pixels with an unusable one are left out.

    Returns
    -------
    (model, images) : two (L, N, 3) float64 arrays, N ~ :data:`SENSOR_FIT_SAMPLES`, the model lit (> 0) at every
        pixel; None when fewer than 10 pixels are usable.
    """
    usable = valid if ok is None else valid & ok.all(axis=(0, 3))
    index = np.flatnonzero(usable)
    index = index[:: max(1, index.size // SENSOR_FIT_SAMPLES)]
    count = len(model)
    S = model.reshape(count, -1, 3)[:, index].astype(np.float64)
    I = images.reshape(count, -1, 3)[:, index].astype(np.float64)
    lit = np.isfinite(S).all(axis=(0, 2)) & (S > 0).all(axis=(0, 2))
    if lit.sum() < 10:
        return None
    return S[:, lit], I[:, lit]


def gain_fitted_misfit(model: np.ndarray, images: np.ndarray) -> tuple[float, float, float]:
    """Median over the pixels of each one's RMS misfit of the undeformed model to the images, with an albedo per
    pixel and channel and a gain per LED fitted: over the median pixel's RMS brightness, and as is.

    Parameters
    ----------
    model, images : (L, N, 3) float64 -- :func:`gel_samples`.

    Returns
    -------
    share : float -- the median misfit over the median brightness (0-1+).
    best_share : float -- the :data:`FIT_PIXELS_QUANTILE` quantile of the misfits over the median brightness.
    misfit : float -- the median misfit, linear units (full scale 1).
    """
    S, I = model, images
    count = len(S)
    gain = np.ones(count)
    SS, SI = S * S, S * I
    for _ in range(SENSOR_FIT_ITERATIONS):
        # the albedo for these gains, then each LED's least-squares gain for that albedo (over all the pixels: a
        # dent's few count little; the overall scale stays with the albedo)
        albedo = np.einsum("l,lnc->nc", gain, SI) / np.maximum(np.einsum("l,lnc->nc", gain * gain, SS), 1e-30)
        gain = np.einsum("nc,lnc->l", albedo, SI) / np.maximum(np.einsum("nc,lnc->l", albedo * albedo, SS), 1e-30)
        gain /= np.exp(np.mean(np.log(np.maximum(gain, 1e-12))))
    albedo = np.einsum("l,lnc->nc", gain, SI) / np.maximum(np.einsum("l,lnc->nc", gain * gain, SS), 1e-30)
    residual = np.einsum("l,nc,lnc->lnc", gain, albedo, S) - I
    per_pixel = np.sqrt(np.einsum("lnc,lnc->n", residual, residual) / (3 * count))
    levels = np.sqrt(np.einsum("lnc,lnc->n", I, I) / (3 * count))
    level = max(float(np.median(levels)), 1e-12)
    # the best tenth among the lit pixels: a dark one (outside another design's gel) fits any model, with albedo 0
    lit = levels >= DARK_LEVEL * level
    best = np.quantile(per_pixel[lit], FIT_PIXELS_QUANTILE) if lit.any() else np.nan
    return float(np.median(per_pixel)) / level, float(best) / level, float(np.median(per_pixel))


def view_spread_deg(camera: Camera, gel: np.ndarray) -> float:
    """Largest angle, degrees, of the camera's rays through the gel's pixels (``gel``: (H, W) bool) from their mean
    direction, on every k-th gel pixel: how much of the dome the view sees (0 when it sees none)."""
    index = np.flatnonzero(gel)
    if index.size == 0:
        return 0.0
    index = index[:: max(1, index.size // SENSOR_FIT_SAMPLES)]
    rows, cols = np.divmod(index, camera.width)
    rays = camera.unproject(np.stack([cols, rows], axis=-1).astype(np.float64))
    rays = rays / np.maximum(np.linalg.norm(rays, axis=-1, keepdims=True), 1e-12)
    mean = rays.mean(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-12)
    return float(np.degrees(np.arccos(np.clip((rays @ mean).min(), -1.0, 1.0))))


def sensor_mismatch(contact: ContactMap, press: Press, undeformed: Path | None = None) -> str | None:
    """One line naming ``folder`` when its images do not fit the sensor its files describe
    (:data:`~nlipscalib.core.tolerances.SENSOR_MISFIT_SHARE` of their brightness and
    :data:`~nlipscalib.core.tolerances.MODEL_MISFIT_FLOOR` times the noise, with each LED's gain fitted, and the
    best-fitting tenth of the gel by :data:`~nlipscalib.core.tolerances.SENSOR_MISFIT_BEST_SHARE`); None when they
    fit, or when nothing could be measured, or when the view of ``press`` (with ``reference``) sees less of the dome
    than :data:`~nlipscalib.core.tolerances.SENSOR_FIT_VIEW_DEG`.

    ``undeformed``: the folder of the undeformed dome's capture the contact was classified against (``nlips solve
    --reference``), whose images are then the model: the line names that capture, not the press's own files. Why:
    an emulator's press solved with a twin render of other light settings as its --reference was told "its images
    were not taken with the sensor that its meta.json and reference.npz describe ... Were those files copied from
    another sensor?", of a press whose files were its own and which solved without the --reference."""
    folder = press.folder
    share, best, floor = contact.sensor_fit
    if not (share >= tolerances.SENSOR_MISFIT_SHARE and floor >= tolerances.MODEL_MISFIT_FLOOR):
        return None  # NaN compares False: nothing measured, nothing said
    if not best >= tolerances.SENSOR_MISFIT_BEST_SHARE:
        return None  # a tenth of the gel fits: a press over most of it (its misfit is the dent's), not a sensor
    if view_spread_deg(press.camera, np.isfinite(press.reference.depth)) < tolerances.SENSOR_FIT_VIEW_DEG:
        return None  # a view of a patch of the dome (a crop) may be all dent: its misfit says nothing of the sensor
    limit = tolerances.SENSOR_MISFIT_SHARE * 100
    if undeformed is not None:
        return (
            f"{folder}: its images do not fit {undeformed}, the undeformed dome's capture it is solved with: that "
            f"capture's light misses them by {share * 100:.0f} % of their brightness all over the gel with each LED's "
            f"power fitted ({floor:.0f} times the noise; a capture of the same sensor and settings: below "
            f"{limit:.0f} %). Was {undeformed} captured with another sensor or other settings (exposure, gain, LED "
            f"levels; for a render, its bounces or scene)? Give the undeformed capture taken with this press's sensor "
            f"and settings (--reference; `nlips solve` also solves without one); a capture known to fit is used "
            f"anyway with `nlips solve {OVERRIDE_FLAG}` (check_sensor=False in the API)"
        )
    return (
        f"{folder}: its images were not taken with the sensor that its meta.json and reference.npz describe (dome, "
        f"camera, LEDs): the undeformed dome's model misses them by {share * 100:.0f} % of their brightness all over "
        f"the gel with each LED's power fitted ({floor:.0f} times the noise; a sensor's own description: below "
        f"{limit:.0f} %). Were those files copied from another sensor? Put the files of the sensor that took the "
        f"images in the press folder; if they are its own, calibrate its LEDs on its undeformed capture (nlips "
        f"calibrate-leds REF --out leds.json) and solve with --leds leds.json; a sensor known to be built a few "
        f"percent off its description is solved anyway with `nlips solve {OVERRIDE_FLAG}` (check_sensor=False in the "
        f"API)"
    )


OVERRIDE_FLAG = "--allow-sensor-misfit"
"""The command-line flag that solves a press :func:`sensor_mismatch` refuses (``check_sensor=False`` of
:func:`nlipscalib.solver.solve_press`), named by the refusal and recorded in the result's report."""


def sensor_check_note(contact: ContactMap, press: Press) -> str:
    """What a solve told to skip the check (``check_sensor=False``) records in its report (``sensor_check``): the
    misfit it overrode, said as a warning too, or that the images fit their description all the same."""
    share = contact.sensor_fit[0]
    if sensor_mismatch(contact, press) is None:
        fit = f"{share * 100:.1f} %" if np.isfinite(share) else "not measured"
        return f"off ({OVERRIDE_FLAG}); nothing overridden: the images fit their sensor's description (misfit {fit})"
    return (
        f"{press.folder}: solved with {OVERRIDE_FLAG} although its images miss the model of the sensor its "
        f"meta.json and reference.npz describe by {share * 100:.0f} % of their brightness (a sensor's own: below "
        f"{tolerances.SENSOR_MISFIT_SHARE * 100:.0f} %): the surface is that description's"
    )
