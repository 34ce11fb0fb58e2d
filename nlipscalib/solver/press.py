"""Solving a capture (Press): prior from the undeformed reference, ROI, LED subsets and LED files."""

from __future__ import annotations

import numpy as np

from ..core.capture import Press
from ..errors import CaptureError, ShapeError
from .nlips import SolveResult, solve
from .options import SolverOptions


def auto_roi(press: Press, margin: int = 8, min_size: int = 32, threshold: float = 3.0) -> tuple[int, int, int, int]:
    """Bounding box (x0, y0, w, h) of pixels whose images disagree with the undeformed reference.

    Per pixel, the reference's shading is fitted to the LED images with one albedo per channel; the
    relative misfit above ``threshold`` times its median marks the contact.
    """
    from ..core.leds import led_shading

    if press.reference is None:
        raise CaptureError(f"{press.folder}: --roi auto needs the capture's reference (undeformed dome)")
    ref = press.reference
    valid = np.isfinite(ref.depth)
    pts = ref.depth[..., None] / press.camera.rays[..., 2:3] * press.camera.rays
    S = led_shading(np.where(valid[..., None], pts, 0), ref.normals.astype(np.float64), press.leds)
    img = press.linear(press.led_images).astype(np.float64)
    alb = (S * img).sum(0) / np.maximum((S * S).sum(0), 1e-30)
    mis = np.sqrt(((alb * S - img) ** 2).sum((0, 3)) / np.maximum((img**2).sum((0, 3)), 1e-30))
    med = np.median(mis[valid])
    hit = valid & (mis > threshold * max(med, 1e-6))
    if not hit.any():
        raise CaptureError(f"{press.folder}: --roi auto found no contact (images match the undeformed reference)")
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
) -> SolveResult:
    """Solve one press.

    Parameters
    ----------
    press : Press -- load with ``load_press(folder, led_subset=...)`` for an LED ablation.
    roi : (x0, y0, w, h) pixels, "auto", or None for the whole visible gel.
    leds : sequence of Led replacing ``press.leds`` (e.g. from ``calibrate-leds``); same count.
    options, backend, progress : see :func:`nlipscalib.solver.solve`.
    """
    leds = press.leds if leds is None else tuple(leds)
    if len(leds) != len(press.leds):
        raise CaptureError(f"{press.folder}: {len(leds)} LEDs given for {len(press.leds)} LED images")
    H, W = press.camera.shape
    prior = press.reference.depth if press.reference is not None else None
    mask = np.isfinite(prior) if prior is not None else np.ones((H, W), bool)
    if isinstance(roi, str):
        if roi != "auto":
            raise ShapeError(f"roi must be (x0, y0, w, h) or 'auto', got {roi!r}")
        roi = auto_roi(press)
    if roi is not None:
        x0, y0, w, h = (int(v) for v in roi)
        if w < 4 or h < 4 or x0 < 0 or y0 < 0 or x0 + w > W or y0 + h > H:
            raise ShapeError(f"roi {roi} must lie inside the {W}x{H} image and be at least 4x4")
        box = np.zeros((H, W), bool)
        box[y0 : y0 + h, x0 : x0 + w] = True
        mask &= box
    images = press.linear(press.led_images)
    saturated = press.saturated(press.led_images) | press.saturated(press.dark)[None]
    result = solve(
        images, press.camera, leds, prior_depth=prior, mask=mask, saturated=saturated,
        options=options, backend=backend, progress=progress,
    )
    result.report["roi"] = list(roi) if roi is not None else None
    result.report["prior"] = "reference" if prior is not None else "nominal_distance"
    return result
