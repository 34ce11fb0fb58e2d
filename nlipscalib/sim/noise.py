"""Image sensor model: linear radiance -> stored 16-bit values (pure numpy, seeded).

Pipeline per pixel and channel, with ``x = radiance * exposure`` the fraction of full scale::

    x         = max(x, 0) ** gamma                        (response curve; gamma = 1: linear)
    electrons = Poisson(x * full_well)                    (shot noise; skipped when disabled)
    DN        = electrons / full_well * (2^bits - 1 - black) + black + error + Normal(0, read_noise)
    stored    = clip(round(DN), 0, 2^bits - 1) << (16 - bits)

so :meth:`nlipscalib.core.Press.linear` of a stored image (dark-subtracted, divided by
white - black of :meth:`NoiseConfig.response`) is ``x`` again, up to noise and quantisation. ``gamma`` and
``error`` (the black level's departure from the stated one) come from ``CameraEffectsConfig``; the dark
frame carries the true black level, so dark-frame subtraction removes ``error``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..core.leds import Leds, led_shading, tricolor_colors
from .bayer import apply_crosstalk

if TYPE_CHECKING:  # named in hints only: the scene module imports the renderer's
    from .scene import CameraEffectsConfig, NoiseConfig

EXPOSURE_TARGET = 0.8
"""Auto exposure puts the 99.5th percentile of the brightest single-LED image at this fraction."""
EXPOSURE_PERCENTILE = 99.5
_GAUSS_ABOVE = 1000.0
"""Above this many electrons shot noise is drawn from its normal approximation (same mean and variance)."""


def _span(cfg: NoiseConfig) -> float:
    return float((1 << cfg.bit_depth) - 1) - cfg.black_level


def apply_noise(
    linear: np.ndarray,
    exposure: float,
    cfg: NoiseConfig,
    rng: np.random.Generator | None,
    effects: CameraEffectsConfig | None = None,
) -> np.ndarray:
    """Turn linear radiance into stored sensor values.

    Parameters
    ----------
    linear : (..., H, W, 3) float, linear radiance (render units)
    exposure : float, scale from radiance to fraction of full scale
    cfg : NoiseConfig
    rng : numpy Generator (required when ``cfg.enabled``)
    effects : CameraEffectsConfig or None -- response curve and black-level error (None: ideal)

    Returns
    -------
    (..., H, W, 3) uint16, stored values DN << (16 - bit_depth)
    """
    # float32 throughout: 12 full images per press, and 24-bit mantissas far exceed 16-bit output
    x = np.maximum(np.asarray(linear, dtype=np.float32) * np.float32(exposure), np.float32(0))
    gamma = 1.0 if effects is None else effects.response_gamma
    if gamma != 1.0:
        x = np.power(x, np.float32(gamma), out=x)
    black = cfg.black_level + (0.0 if effects is None else effects.black_level_error)
    max_dn = float((1 << cfg.bit_depth) - 1)
    if cfg.enabled:
        dn = sensor_noise(x, cfg, rng, black)
    else:
        dn = x * np.float32(_span(cfg)) + np.float32(black)
    dn = np.clip(np.rint(dn, out=dn), 0, max_dn, out=dn).astype(np.uint16)
    return dn << np.uint16(16 - cfg.bit_depth)


def sensor_noise(x: np.ndarray, cfg: NoiseConfig, rng: np.random.Generator, black: float | None = None) -> np.ndarray:
    """DN (float32, unquantised) of fractions of full scale ``x`` with shot and read noise.

    ``black`` is the true black level in DN (default ``cfg.black_level``).

    Where a pixel collects more than ``_GAUSS_ABOVE`` electrons, shot and read noise are drawn as one
    normal variable with their summed variance (same mean and variance, one draw instead of two);
    dimmer pixels get an exact Poisson draw plus normal read noise.
    """
    black = np.float32(cfg.black_level if black is None else black)
    span = np.float32(_span(cfg))
    gain = span / np.float32(cfg.full_well)  # DN per electron
    electrons = x * np.float32(cfg.full_well)
    sigma = np.sqrt(gain * gain * electrons + np.float32(cfg.read_noise) ** 2)
    dn = x * span + black + sigma * rng.standard_normal(x.shape, dtype=np.float32)
    dim = electrons <= _GAUSS_ABOVE
    if dim.any():
        lam = electrons[dim]
        read = np.float32(cfg.read_noise) * rng.standard_normal(lam.shape, dtype=np.float32)
        dn[dim] = rng.poisson(lam).astype(np.float32) * gain + black + read
    return dn


def dark_frame(
    shape: tuple[int, int],
    cfg: NoiseConfig,
    rng: np.random.Generator | None,
    effects: CameraEffectsConfig | None = None,
) -> np.ndarray:
    """(H, W, 3) uint16: the true black level plus read noise (no light)."""
    return apply_noise(np.zeros(tuple(shape) + (3,)), 1.0, cfg, rng, effects)


def auto_exposure(
    points: np.ndarray,
    normals: np.ndarray,
    leds: Leds,
    albedo: tuple[float, float, float],
    scale: float = 1.0,
    tricolor: bool = False,
    crosstalk: tuple[tuple[float, ...], ...] | None = None,
) -> float:
    """Exposure making the undeformed dome well exposed, the same for every press of a scene.

    Parameters
    ----------
    points : (N, 3) float, mm, camera frame -- valid pixels of the undeformed dome's ground truth
    normals : (N, 3) float, unit, toward the camera
    leds : sequence of Led
    albedo : (3,) coating albedo
    scale : NoiseConfig.exposure (1 = the calibrated exposure)
    tricolor : expose the tri-colour image instead (its channels sum several LEDs, so it needs less)
    crosstalk : (3, 3) the camera's colour crosstalk (``sim.bayer.apply_crosstalk``), None for none: the light the
        channels record, as the user exposes on them

    Returns
    -------
    float -- multiply linear radiance (albedo/pi * led_shading) by it to get the fraction of full scale
    """
    lin = led_shading(points, normals, leds) * (np.asarray(albedo, dtype=np.float64) / np.pi)  # (L, N, 3)
    if tricolor:
        colours = tricolor_colors(len(lin))  # (L, 3)
        lin = np.einsum("lnc,lc->nc", lin, colours)[None]
    if crosstalk is not None:
        lin = apply_crosstalk(lin, crosstalk)
    per_led = np.percentile(lin.max(axis=-1), EXPOSURE_PERCENTILE, axis=1)
    return float(scale * EXPOSURE_TARGET / per_led.max())
