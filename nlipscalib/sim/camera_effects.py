"""Departures of the twin's camera from the ideal linear camera: defocus blur and vignetting.

Both act on linear radiance images before the sensor (:mod:`.noise`), which adds the response curve
and the black-level error. Everything here is a per-pixel map or a convolution: numpy + OpenCV.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera
from ..core.errors import require

if TYPE_CHECKING:  # named in hints only
    from .scene import CameraEffectsConfig

SUPERSAMPLE = 8
"""Sub-pixel grid per pixel when rasterising the disk PSF: a radius of 0.3 px still blurs a little."""


def vignetting_map(camera: Camera, cfg: CameraEffectsConfig) -> np.ndarray:
    """Relative illumination of every pixel (1 = no falloff).

    Parameters
    ----------
    camera : core Camera
    cfg : CameraEffectsConfig

    Returns
    -------
    (H, W) float32, in (0, 1]: multiply linear images by it
    """
    return _vignetting_map(camera, cfg.vignetting, cfg.vignetting_coeffs)


@functools.lru_cache(maxsize=8)
def _vignetting_map(camera: Camera, kind: str, coeffs: tuple[float, float, float]) -> np.ndarray:
    h, w = camera.shape
    if kind == "none":
        out = np.ones((h, w))
    elif kind == "cos4":
        cos = camera.rays[..., 2] / np.linalg.norm(camera.rays, axis=-1)  # ray angle to the optical axis
        out = np.clip(cos, 0.0, 1.0) ** 4
    else:
        u, v = camera.pixel_grid()
        r2 = ((u - camera.cx) ** 2 + (v - camera.cy) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
        c1, c2, c3 = coeffs
        out = 1 + r2 * (c1 + r2 * (c2 + r2 * c3))
    out = np.clip(out, 1e-6, None).astype(np.float32)
    out.setflags(write=False)
    return out


def disk_psf(radius_px: float) -> np.ndarray:
    """Normalised uniform-disk point-spread function of ``radius_px`` pixels.

    Returns
    -------
    (K, K) float32, sums to 1; pixel coverage rasterised on a ``SUPERSAMPLE``-fold sub-grid
    """
    half = int(np.ceil(radius_px))
    n = (2 * half + 1) * SUPERSAMPLE
    sub = (np.arange(n) + 0.5) / SUPERSAMPLE - (half + 0.5)
    inside = (sub[:, None] ** 2 + sub[None, :] ** 2) <= radius_px**2
    kernel = inside.reshape(2 * half + 1, SUPERSAMPLE, 2 * half + 1, SUPERSAMPLE).mean(axis=(1, 3))
    if kernel.sum() == 0:  # radius below the sub-grid: no blur
        kernel[half, half] = 1.0
    return (kernel / kernel.sum()).astype(np.float32)


def defocus(images: np.ndarray, radius_px: float) -> np.ndarray:
    """Blur linear images with a disk PSF (borders reflected).

    Parameters
    ----------
    images : (..., H, W, 3) float, linear
    radius_px : PSF radius, pixels (0: returned as is)

    Returns
    -------
    (..., H, W, 3) float32
    """
    images = np.asarray(images, dtype=np.float32)
    if radius_px <= 0:
        return images
    cv2 = require("cv2", "opencv-python-headless", "Defocus blur")
    kernel = disk_psf(radius_px)
    flat = images.reshape((-1,) + images.shape[-3:])
    out = np.stack([cv2.filter2D(im, -1, kernel, borderType=cv2.BORDER_REFLECT) for im in flat])
    return out.reshape(images.shape)


def apply_lens(images: np.ndarray, camera: Camera, cfg: CameraEffectsConfig) -> np.ndarray:
    """Defocus, then vignetting, of linear images (what reaches the sensor).

    Parameters
    ----------
    images : (..., H, W, 3) float, linear radiance
    camera : core Camera
    cfg : CameraEffectsConfig

    Returns
    -------
    (..., H, W, 3) float32
    """
    out = defocus(images, cfg.defocus_px)
    if cfg.vignetting != "none":
        out = out * vignetting_map(camera, cfg)[:, :, None]
    return out
