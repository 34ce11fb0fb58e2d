"""The misfit the undeformed model's point LEDs alone leave where the LEDs are disks (:func:`point_led_misfit`):
the model's known error, which the contact verdicts and ``--roi auto`` allow for.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core import tolerances
from ..core.camera import depth_to_points
from ..core.capture import Press
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
