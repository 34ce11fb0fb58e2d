"""Interreflection compensation from a capture of the undeformed dome.

The image model (docs/conventions.md) is direct light only, but the coated dome also lights itself:
light from an LED reflects off one part of the dome onto another (about 17 % of the signal on the
default twin with one bounce). That extra light biases NLiPs toward normals facing the bright side.

On the undeformed dome the geometry is known (``Press.reference``), so the indirect light of every
LED and pixel can be measured as what the direct model does not explain::

    indirect_ic(p) = I_ic(p) - rho_c * S_ic(p)      (S: direct model shading on the reference geometry)

A press changes the indirect light only near the contact (the dent is small next to the dome), so
subtracting the reference's indirect light from the press's images removes most of the bias. The
same procedure works on the real sensor: capture the undeformed dome once, with the press's
exposure and LEDs.

The albedo rho_c (one per channel: the coating is uniform) is not the least-squares fit of
``rho_c S`` to the reference images: indirect light only ever adds, so that fit would absorb part of
it. It is fitted where the direct light dominates most (the samples with the smallest ratio
I / S, which is rho_c plus a non-negative indirect share), see :func:`fit_reference_albedo`.
"""

from __future__ import annotations

import numpy as np

from ..core.capture import Press
from ..core.leds import led_shading
from ..errors import CaptureError, ShapeError


def reference_shading(press: Press, leds=None) -> tuple[np.ndarray, np.ndarray]:
    """Direct model shading of every LED on the reference (undeformed) geometry.

    Parameters
    ----------
    press : Press -- with ``reference``.
    leds : sequence of Led or None -- default ``press.leds``.

    Returns
    -------
    shading : (L, H, W, 3) float64 -- Psi_ic (n_s.d)^mu max(0, cos) / r^2; 0 off the gel.
    valid : (H, W) bool -- pixels that see the gel.
    """
    if press.reference is None:
        raise CaptureError(f"{press.folder}: interreflection compensation needs the reference (reference.npz)")
    leds = press.leds if leds is None else tuple(leds)
    ref = press.reference
    valid = np.isfinite(ref.depth)
    rays = press.camera.rays
    pts = np.where(valid, ref.depth, 0.0)[..., None] / rays[..., 2:3] * rays  # (H, W, 3) mm
    shading = led_shading(pts, ref.normals.astype(np.float64), leds)
    shading[:, ~valid] = 0.0
    return shading, valid


def fit_reference_albedo(images: np.ndarray, shading: np.ndarray, usable: np.ndarray, quantile: float = 0.01):
    """Uniform albedo per channel of the undeformed dome, robust to the (additive) indirect light.

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear reference images.
    shading : (L, H, W, 3) float -- direct model shading (:func:`reference_shading`).
    usable : (L, H, W, 3) bool -- samples to use (lit, unsaturated, on the gel).
    quantile : the albedo is this quantile of I / S over the brightest-lit half of the usable samples.

    Returns
    -------
    (3,) float64 -- rho_c, linear image units per unit shading.
    """
    albedo = np.empty(3)
    for c in range(3):
        s, i = shading[..., c][usable[..., c]], images[..., c][usable[..., c]]
        if s.size == 0:
            raise CaptureError("no usable reference samples to fit the albedo on")
        # Where the LED shines straight onto the surface the direct light dominates the indirect
        # light most; the low quantile of I/S there is rho plus the least indirect share (and noise).
        bright = s >= np.median(s)
        albedo[c] = float(np.quantile(i[bright] / s[bright], quantile))
    return albedo


def estimate_indirect(reference: Press, leds=None, quantile: float = 0.01, smooth_px: float = 2.0) -> np.ndarray:
    """Indirect (interreflected) light of every LED and pixel, from a capture of the undeformed dome.

    Parameters
    ----------
    reference : Press -- the undeformed dome (with ``reference``), same camera, LEDs and exposure as
        the presses it will be subtracted from.
    leds : sequence of Led or None -- the LED model (e.g. from ``calibrate-leds``); default the capture's.
    quantile : see :func:`fit_reference_albedo`.
    smooth_px : Gaussian sigma, pixels, applied to the estimate: indirect light varies slowly over
        the dome, the per-pixel difference also holds the reference's sensor/render noise.

    Returns
    -------
    (L, H, W, 3) float32 -- linear image units (``Press.linear`` scale); 0 off the gel.
    """
    import cv2

    shading, valid = reference_shading(reference, leds)
    images = reference.linear(reference.led_images).astype(np.float64)
    usable = ~reference.saturated(reference.led_images) & (shading > 0) & valid[None, :, :, None]
    albedo = fit_reference_albedo(images, shading, usable, quantile)
    indirect = images - albedo * shading
    indirect[:, ~valid] = 0.0
    if smooth_px > 0:
        # Normalised convolution so the gel's silhouette does not darken the estimate.
        w = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), smooth_px)
        for i in range(len(indirect)):
            blurred = cv2.GaussianBlur(indirect[i].astype(np.float32), (0, 0), smooth_px)
            indirect[i] = np.where(valid[..., None], blurred / np.maximum(w, 1e-6)[..., None], 0.0)
    return indirect.astype(np.float32)


def compensate(images: np.ndarray, indirect: np.ndarray) -> np.ndarray:
    """Subtract the indirect light from linear LED images.

    Parameters
    ----------
    images : (L, H, W, 3) float -- linear, ``Press.linear`` scale.
    indirect : (L, H, W, 3) float -- from :func:`estimate_indirect`.

    Returns
    -------
    (L, H, W, 3) float32 -- clipped at 0 (where the estimate exceeds the image the pixel is in the
    dent's shadow or the estimate is noise; the solver treats near-zero samples as shadow).
    """
    if np.shape(images) != np.shape(indirect):
        raise ShapeError(f"indirect light {np.shape(indirect)} must match the images {np.shape(images)}")
    return np.maximum(np.asarray(images, np.float32) - np.asarray(indirect, np.float32), 0.0)
