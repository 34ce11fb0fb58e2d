"""The misfit the undeformed model's point LEDs alone leave where the LEDs are disks (:func:`point_led_misfit`):
the model's known error, which the contact verdicts and ``--roi auto`` allow for; and how unevenly over the gel
point LEDs miss a design's disks (:func:`point_led_spread`), which decides whether a solve with the capture's own
LEDs is told to model them as disks.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core import tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.errors import ShapeError
from ..core.leds import Leds, disk_shading, led_shading
from .contact import ContactMap, rms_misfit, sum_squares


def point_led_misfit(
    press: Press,
    leds: Leds,
    contact: ContactMap,
    pixels: np.ndarray,
    radius: float = tolerances.LED_EMITTER_RADIUS_MM,
    indirect_light: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """What the undeformed model's point LEDs alone make a pixel misfit: the misfit of the point model to LEDs that
    emit from disks of ``radius`` (:func:`nlipscalib.core.leds.disk_shading`), both on the reference surface, as a
    share of their shading, times the direct light's part of the pixel's image level
    (:attr:`.contact.ContactMap.level`).

    From the design (reference surface, LEDs), not from the images: large where the gel comes within a few LED
    sizes of an LED (the ``capsule`` design's wall at the image border: 2-6 % there, s27-shapes2).

    Parameters
    ----------
    press : Press -- with ``reference``.
    leds : sequence of Led -- the undeformed model's LEDs (all of the press's; ``contact.live_leds`` are used).
    contact : ContactMap -- of that model.
    pixels : (H, W) bool -- where to evaluate it (a few thousand edge pixels: ~5 ms each 1,000 with 12 LEDs).
    radius : float, mm.
    indirect_light : sequence of L (H, W, 3) float or None -- the undeformed model's indirect light per unit
        albedo, per LED (``IndirectModel.undeformed_light_per_led``), when its interreflection term is on; None:
        the images are direct light only. The point-LED error is the direct light's, so it is scaled by each pixel's
        direct share, point shading / (point shading + that light): not the term's median share (the capsule's
        0.885, a direct share of 0.53), since the gel beside an LED takes more direct light than the median pixel.
        With that median share the capsule's image corners misfit 1.5-2 times the error predicted (s28-capsule).

    Returns
    -------
    (H, W) float64 -- linear image units; 0 off ``pixels`` and off the gel.
    """
    out = np.zeros(pixels.shape)
    ref = press.reference
    rows, cols = np.nonzero(pixels & np.isfinite(ref.depth))
    if rows.size == 0:
        return out
    live = [tuple(leds)[i] for i in contact.live_leds]
    points = depth_to_points(ref.depth[rows, cols], press.camera.rays[rows, cols])
    normals = ref.normals[rows, cols]
    point = led_shading(points, normals, live).astype(np.float32)[:, :, None]  # (L, N, 1, 3): a 1-wide image
    disk = disk_shading(points, normals, live, radius).astype(np.float32)[:, :, None]
    count = np.full((rows.size, 1), point.shape[0] * point.shape[3])
    share = rms_misfit(point, disk, None, count)[:, 0] / np.maximum(
        np.sqrt(sum_squares(disk, None) / count)[:, 0], 1e-30
    )
    direct = 1.0
    if indirect_light is not None:
        lit = point.sum(axis=(0, 2, 3), dtype=np.float64)  # (N,): the direct shading over the live LEDs and colours
        bounced = sum(np.asarray(indirect_light[i])[rows, cols].sum(-1, dtype=np.float64) for i in contact.live_leds)
        direct = lit / np.maximum(lit + bounced, 1e-30)
    out[rows, cols] = share * direct * np.nan_to_num(contact.level[rows, cols])
    return out


def point_led_spread(points: np.ndarray, normals: np.ndarray, leds: Leds, radius: float) -> float:
    """How unevenly LEDs taken as points miss the same LEDs as disks of ``radius`` over a surface: per LED the standard
    deviation over the points it lights of log(disk shading / point shading), the median over the LEDs. A uniform
    miss is only an LED's brightness (Psi and the albedo absorb it); its spread over the gel bends the normals.

    On the shipped designs' undeformed gel with their 3.6 mm LEDs (1000 samples): hemisphere 0.0072, fingertip
    0.0096, oblate 0.0135, flat pad 0.0145, capsule 0.0149 (the flat pad's gel 8 mm from the LEDs, lit at grazing
    angles; s42-flatauto, docs/experiments/RESULTS.md). 7-8 ms of CPU for 1000 points and 12 LEDs.

    Parameters
    ----------
    points : (N, 3) float, mm, camera frame -- surface points (a sample of the undeformed gel).
    normals : (N, 3) float, unit, camera frame, toward the camera.
    leds : sequence of Led, length L -- the disks' centres and axes (position, direction, mu).
    radius : float, mm, > 0 -- the LEDs' emitting disk.

    Returns
    -------
    float -- 0 where no LED lights two points.
    """
    points, normals = np.asarray(points, dtype=np.float64), np.asarray(normals, dtype=np.float64)
    if points.ndim != 2 or points.shape[-1] != 3 or normals.shape != points.shape:
        raise ShapeError(f"points and normals must be (N, 3) alike, got {points.shape} and {normals.shape}")
    point = led_shading(points, normals, leds)[..., 0]  # (L, N): one channel; Psi cancels in the ratio
    disk = disk_shading(points, normals, leds, radius)[..., 0]
    spreads = []
    for p, d in zip(point, disk):
        # where the LED lights above a share of its median: at grazing light the ratio of two near-zero shadings is
        # noise, not the model's error
        lit = (p > tolerances.POINT_LED_SPREAD_LIT * np.median(p)) & (d > 0)
        if lit.sum() > 1:
            spreads.append(float(np.std(np.log(d[lit] / p[lit]))))
    return float(np.median(spreads)) if spreads else 0.0
