"""Solving a capture (Press): prior from the undeformed reference, ROI, LED subsets and LED files."""

from __future__ import annotations

import numpy as np

from ..core.capture import Press
from ..errors import CaptureError, ConfigError, ShapeError
from .nlips import SolveResult, solve
from .options import SolverOptions


def contact_misfit(
    press: Press, indirect: np.ndarray | None = None, reference: Press | None = None, window=(slice(None), slice(None))
) -> np.ndarray:
    """Per-pixel relative misfit of the undeformed dome's shading to the LED images.

    Per pixel, the undeformed shading is fitted to the LED images with one scale per channel; where
    the gel is not displaced it fits to rendering/sensor noise (and to what the model lacks).

    Parameters
    ----------
    press : Press -- with ``reference``.
    indirect : (L, H, W, 3) float or None -- interreflection estimate to subtract first (linear units).
    reference : Press or None -- a capture of the undeformed dome (same camera, LEDs, exposure): its
        images are the undeformed shading, interreflections included, so the contact stands out even
        where the direct model does not explain the light (bounces >= 1, real sensor). ``indirect``
        is then ignored. None: the direct model on ``press.reference``.
    window : (rows, cols) slices -- evaluate only there (a crop, or a strided sample for statistics).

    Returns
    -------
    (h, w) float64 -- RMS misfit over LEDs and channels relative to the images' RMS over ``window``
    (the whole (H, W) image by default); NaN off the gel.
    """
    from ..core.leds import led_shading

    if press.reference is None:
        raise CaptureError(f"{press.folder}: --roi auto needs the capture's reference (undeformed dome)")
    ref = press.reference
    win = (slice(None),) + tuple(window)  # the same window on every (L, H, W, ...) stack
    depth, rays = ref.depth[window], press.camera.rays[window]
    valid = np.isfinite(depth)
    pts = np.nan_to_num(depth)[..., None] / rays[..., 2:3] * rays
    img = press.linear(press.led_images[win], window).astype(np.float64)
    if reference is not None:
        S = reference.linear(reference.led_images[win], window).astype(np.float64)
    else:
        S = led_shading(np.where(valid[..., None], pts, 0), ref.normals[window].astype(np.float64), press.leds)
        if indirect is not None:
            img = img - indirect[win]
    alb = (S * img).sum(0) / np.maximum((S * S).sum(0), 1e-30)
    mis = np.sqrt(((alb * S - img) ** 2).sum((0, 3)) / np.maximum((img**2).sum((0, 3)), 1e-30))
    return np.where(valid, mis, np.nan)


def auto_roi(
    press: Press,
    margin: int = 8,
    min_size: int = 32,
    threshold: float = 3.0,
    min_component: float = 0.05,
    indirect: np.ndarray | None = None,
    reference: Press | None = None,
) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, w, h) of pixels whose images disagree with the undeformed reference.

    Pixels whose :func:`contact_misfit` exceeds ``threshold`` times its median are candidates; of
    their connected components only those at least ``min_component`` times the largest are kept, so
    isolated misfits (cast shadows far from the dent, silhouette aliasing, hot pixels) do not
    stretch the box over the whole image. ``indirect`` and ``reference``: see :func:`contact_misfit`.
    """
    from scipy import ndimage

    mis = contact_misfit(press, indirect, reference)
    valid = np.isfinite(mis)
    med = np.median(mis[valid])
    hit = valid & (np.nan_to_num(mis) > threshold * max(med, 1e-6))
    if not hit.any():
        raise CaptureError(f"{press.folder}: --roi auto found no contact (images match the undeformed reference)")
    labels, count = ndimage.label(hit)
    sizes = ndimage.sum(hit, labels, np.arange(1, count + 1))
    keep = np.flatnonzero(sizes >= min_component * sizes.max()) + 1
    hit = np.isin(labels, keep)
    rows, cols = np.nonzero(hit)
    H, W = press.camera.shape
    y0, y1 = max(rows.min() - margin, 0), min(rows.max() + 1 + margin, H)
    x0, x1 = max(cols.min() - margin, 0), min(cols.max() + 1 + margin, W)
    if x1 - x0 < min_size:
        c = (x0 + x1) // 2
        x0, x1 = max(c - min_size // 2, 0), min(c + min_size // 2, W)
    if y1 - y0 < min_size:
        c = (y0 + y1) // 2
        y0, y1 = max(c - min_size // 2, 0), min(c + min_size // 2, H)
    return int(x0), int(y0), int(x1 - x0), int(y1 - y0)


def solve_press(
    press: Press,
    *,
    roi: tuple[int, int, int, int] | str | None = None,
    leds=None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    progress: bool = False,
    indirect: np.ndarray | Press | None = None,
    dent_interreflection: bool = True,
    coating_albedo: float | tuple[float, float, float] = 0.8,
) -> SolveResult:
    """Solve one press.

    Parameters
    ----------
    press : Press -- load with ``load_press(folder, led_subset=...)`` for an LED ablation.
    roi : (x0, y0, w, h) pixels, "auto", or None for the whole visible gel.
    leds : sequence of Led replacing ``press.leds`` (e.g. from ``calibrate-leds``); same count.
    options, backend, progress : see :func:`nlipscalib.solver.solve`.
    indirect : interreflection compensation (:mod:`nlipscalib.solver.interreflection`): None (off),
        a Press of the undeformed dome (same camera, LEDs, LED subset and exposure) to estimate it
        from, or an (L, H, W, 3) float array from ``estimate_indirect`` (linear units), subtracted
        from the LED images before solving.
    dent_interreflection : with ``indirect``, also correct for the dent's own interreflection: the
        press is solved once compensated with the reference's indirect light, the change of one
        diffuse bounce between the solved and the undeformed surface is added to it
        (:func:`~nlipscalib.solver.interreflection.dent_indirect`), and the press is solved again.
        About twice the solve time. Ignored without ``indirect`` or ``press.reference``.
    coating_albedo : the coating's reflectance (dimensionless, per channel or one value) for
        ``dent_interreflection``; the twin's coating is 0.8.
    """
    from .interreflection import compensate, dent_indirect, estimate_indirect

    leds = press.leds if leds is None else tuple(leds)
    if len(leds) != len(press.leds):
        raise CaptureError(f"{press.folder}: {len(leds)} LEDs given for {len(press.leds)} LED images")
    ref_capture = None
    if isinstance(indirect, Press):
        if indirect.camera != press.camera or len(indirect.leds) != len(press.leds):
            raise CaptureError(f"{indirect.folder}: camera or LED count differs from {press.folder}")
        ref_capture, indirect = indirect, estimate_indirect(indirect, leds)
    H, W = press.camera.shape
    prior = press.reference.depth if press.reference is not None else None
    mask = np.isfinite(prior) if prior is not None else np.ones((H, W), bool)
    if isinstance(roi, str):
        if roi != "auto":
            raise ShapeError(f"roi must be (x0, y0, w, h) or 'auto', got {roi!r}")
        roi = auto_roi(press, indirect=indirect, reference=ref_capture)
    if roi is not None:
        x0, y0, w, h = (int(v) for v in roi)
        if w < 4 or h < 4 or x0 < 0 or y0 < 0 or x0 + w > W or y0 + h > H:
            raise ShapeError(f"roi {roi} must lie inside the {W}x{H} image and be at least 4x4")
        box = np.zeros((H, W), bool)
        box[y0 : y0 + h, x0 : x0 + w] = True
        mask &= box
    images = press.linear(press.led_images)
    saturated = press.saturated(press.led_images) | press.saturated(press.dark)[None]
    options = options or SolverOptions()
    # the direct model minus the indirect estimate: the same classification whether the indirect
    # light came as a capture or as an array
    weights = _anchor_weights(press, mask, options, indirect)

    def run(light):
        data = images if light is None else compensate(images, light)
        return solve(
            data,
            press.camera,
            leds,
            prior_depth=prior,
            prior_weights=weights,
            mask=mask,
            saturated=saturated,
            options=options,
            backend=backend,
            progress=progress,
        )

    result = run(indirect)
    dent = dent_interreflection and indirect is not None and press.reference is not None
    if dent:
        if not np.all((np.asarray(coating_albedo) > 0) & (np.asarray(coating_albedo) <= 1)):
            raise ConfigError(f"coating_albedo must be in (0, 1], got {coating_albedo}")
        # One outer iteration: a second one did not help on the twin (320x240 contact AAE: sphere
        # 3.44 -> 3.85 deg, cube 3.60 -> 3.66 deg).
        first = result.report
        result = run(indirect + dent_indirect(press.camera, leds, press.reference, result, coating_albedo))
        result.report["dent_first_solve_seconds"] = first.get("seconds")
    result.report["roi"] = list(roi) if roi is not None else None
    result.report["prior"] = "reference" if prior is not None else "nominal_distance"
    result.report["indirect_compensation"] = indirect is not None
    result.report["dent_interreflection"] = bool(dent)
    result.report["anchored_pixels"] = int((weights > 1).sum()) if weights is not None else 0
    return result


def _anchor_weights(press: Press, mask, options: SolverOptions, indirect) -> np.ndarray | None:
    """Prior weight multipliers: ``options.anchor_weight`` where the gel is seen undeformed, else 1.

    The misfit to the undeformed dome is evaluated on the solve mask's bounding box only; its median,
    the noise level the threshold is relative to, comes from a strided sample of the whole gel, so
    that a box mostly filled by the contact does not raise the threshold.
    """
    if press.reference is None or options.anchor_weight <= 0 or not mask.any():
        return None
    rows, cols = np.nonzero(mask)
    box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    sample = contact_misfit(press, indirect, None, (slice(None, None, 4), slice(None, None, 4)))
    median = float(np.nanmedian(sample))
    weights = np.ones(mask.shape)
    misfit = np.nan_to_num(contact_misfit(press, indirect, None, box), nan=np.inf)
    weights[box] += options.anchor_weight * (misfit <= options.anchor_threshold * median)
    return weights
