"""Monte Carlo noise of the rendered interreflections, filtered out before the camera.

A path tracer estimates the light that reaches the coat after a bounce with a few random directions per pixel:
at 16 spp the bounce light carries about 27 % noise per pixel and LED image (RMS over its mean, against a
256-spp render; benchmarks/RESULTS.md, s22-docs3), which on the default twin (indirect light ~24 % of the
image) is more than the camera's own shot and read noise. That noise belongs to the renderer, not to a sensor,
and the solver would read it as shading. The indirect light of a diffuse coat varies smoothly along the
surface, so it is filtered spatially, never across an edge of the geometry: the edge-avoiding a-trous wavelet
filter (Dammertz, Sewtz, Hanika & Lensch, "Edge-Avoiding A-Trous Wavelet Transform for fast Global
Illumination Filtering", HPG 2010) with edge-stopping weights on the true normals and depth of each pixel (the
ground truth the twin traces anyway), as used for the indirect light of real-time path tracers (Schied et al.,
SVGF, HPG 2017).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import numpy as np

from ...core.masks import SQUARE, dilate

_TAPS = np.array([1.0, 4.0, 6.0, 4.0, 1.0]) / 16.0  # B3 spline: the a-trous scaling function


@dataclasses.dataclass(frozen=True)
class DenoiseConfig:
    """Settings of :func:`denoise_indirect` (tolerances of the edge-stopping weights)."""

    iterations: int = 3
    """A-trous levels: taps 1, 2, 4, ... pixels apart (3 levels: a Gaussian-like footprint of sigma ~4.6 px)."""
    normal_deg: float = 4.0
    """A neighbour whose normal is this far (degrees) off the one that the two pixels' normals and their rates of
    change predict weighs exp(-1): the bounce light depends on the receiving normal, so kinks stop the filter,
    while the dome's smooth curvature passes at any resolution. (Normals merely apart stopped it on small frames:
    at 64x48 the dome's normals turn ~2 deg a pixel, the filter left 4-5 times more noise than on a flat
    surface, spatially correlated, and the solver read an undeformed capture as a press; benchmarks/RESULTS.md,
    s27-noiselow.)"""
    depth_rel: float = 0.01
    """A neighbour this far (relative to the depth: 1 % = 0.15 mm at 15 mm) off the surface that the two pixels'
    depth gradients predict weighs exp(-1): slopes and curvature pass, steps (occlusion edges) do not."""

    def __post_init__(self):
        from ...core.errors import ConfigError

        if not 0 <= self.iterations <= 6:
            raise ConfigError(f"denoise.iterations must be 0-6, got {self.iterations}")
        if not (self.normal_deg > 0 and self.depth_rel > 0):
            raise ConfigError("denoise.normal_deg and denoise.depth_rel must be > 0")


def denoise_indirect(
    indirect: np.ndarray,
    normals: np.ndarray,
    depth: np.ndarray,
    valid: np.ndarray,
    cfg: DenoiseConfig = DenoiseConfig(),
    coverage: np.ndarray | None = None,
) -> np.ndarray:
    """Edge-avoiding a-trous filter of the bounce light of every LED image, per unit of each pixel's coverage.

    A pixel on the gel's outline (a view beyond the gel) is partly covered: its light is its covered share of
    the surface's. Filtered as it is, its neighbours' full light and its share were averaged (the outer pixel of
    a wide view came out +17 % of its light, those 1-8 px in 0.2-0.9 % low; benchmarks/RESULTS.md,
    s35-wideedge): on the outline the light is divided by the coverage, filtered, and multiplied by it again. A
    pixel covered whole divides and multiplies by 1: a gel-filling view's images keep their bits. (Weighing each
    pixel by its coverage, the share of its samples on the surface, changed the outline's error by under 0.05 % of
    the light and its noise not at all: not done; s36-twinfilter.)

    Parameters
    ----------
    indirect : (L, H, W, 3) float -- the light of the bounce vertices, linear radiance, one image per LED
    normals : (H, W, 3) float, unit, camera frame -- the surface each pixel sees (ground truth)
    depth : (H, W) float, mm -- z of that surface, NaN where no surface
    valid : (H, W) bool -- pixels whose centre sees the surface
    coverage : (H, W) float in [0, 1] or None (1 on ``valid``) -- the share of each pixel's footprint on the
        surface (the render's alpha: the share of its samples that reach it); read on the outline of ``valid``
        only (its pixels with a neighbour, of 8, off it), 1 inside

    Returns
    -------
    (L, H, W, 3) float32 -- filtered; 0 outside ``valid``. Each output is a normalised weighted mean of
    pixels of the same image (per unit coverage, times the pixel's own), so a constant field is returned
    unchanged.
    """
    L, H, W, _ = indirect.shape
    if normals.shape != (H, W, 3) or depth.shape != (H, W) or valid.shape != (H, W):
        raise ValueError(f"guides {normals.shape}, {depth.shape}, {valid.shape} do not match images {indirect.shape}")
    if coverage is not None and coverage.shape != (H, W):
        raise ValueError(f"coverage {coverage.shape} does not match images {indirect.shape}")
    cover = valid.astype(np.float32)
    if coverage is not None:
        # taken on the outline only, the pixels beside one whose centre misses the surface (a partly covered pixel
        # always is one). Inside, a sample that slipped between the mesh's triangles (single-precision ray tests;
        # groundtruth._retrace_pinholes) is the render's defect, not coverage: such a pixel is taken whole, as
        # before, and a gel-filling view keeps its bits
        outline = valid & dilate(~valid, structure=SQUARE)
        cover[outline] = coverage[outline]
    # channels last, one (H, W, 3L) stack: every tap is one multiply-add over all LEDs; the light per unit
    # coverage (a pixel covered whole divides by 1: its bits are kept)
    img = np.moveaxis(np.asarray(indirect, np.float32), 0, 2).reshape(H, W, 3 * L)
    img = np.where((cover > 0)[..., None], img / np.where(cover > 0, cover, 1.0)[..., None], 0.0).astype(np.float32)
    n = np.where(valid[..., None], normals, 0.0).astype(np.float32)
    z = np.where(valid, depth, 0.0).astype(np.float32)
    inv_n = np.float32(1.0 / (1.0 - np.cos(np.radians(cfg.normal_deg))))
    inv_z = (1.0 / np.maximum(cfg.depth_rel * z, 1e-6)).astype(np.float32)
    gz_y, gz_x = _depth_gradient(z, valid)
    gn_y, gn_x = _normal_gradient(n, valid)
    inside = (cover > 0).astype(np.float32)  # a pixel none of whose samples reached the surface has no estimate
    for level in range(cfg.iterations):
        step = 2**level
        taps = []  # (destination, source, weight): the guides' weights are shared by every channel
        den = np.zeros((H, W), np.float32)
        for dy, wy in zip(range(-2, 3), _TAPS):
            for dx, wx in zip(range(-2, 3), _TAPS):
                oy, ox = dy * step, dx * step
                dst, src = _overlap(H, W, oy, ox)
                # off what the two pixels' own rates of change predict (trapezoid rule: exact on a quadratic
                # field): a dome's curvature passes at any resolution, a kink or a step does not
                dn = _off_trend(n, gn_y, gn_x, dst, src, oy, ox)
                bend = 0.5 * np.einsum("ijk,ijk->ij", dn, dn)  # = 1 - cos for unit normals off no trend
                off_plane = np.abs(_off_trend(z, gz_y, gz_x, dst, src, oy, ox))
                w = np.exp(-bend * inv_n - off_plane * inv_z[dst])
                w *= np.float32(wy * wx) * inside[src] * inside[dst]
                den[dst] += w
                taps.append((dst, src, w[..., None]))
        img = _apply(img, taps, den)
    out = np.moveaxis((img * cover[..., None]).reshape(H, W, L, 3), 2, 0)
    return np.where(valid[None, ..., None], out, 0.0).astype(np.float32)


def _apply(
    img: np.ndarray, taps: list[tuple[tuple[slice, slice], tuple[slice, slice], np.ndarray]], den: np.ndarray
) -> np.ndarray:
    """One a-trous level: the weighted taps summed over channel blocks in two threads (NumPy releases the
    GIL in these loops), normalised by the weights' sum; a pixel with no weight keeps its value."""
    from concurrent.futures import ThreadPoolExecutor

    out = np.empty_like(img)
    inv = np.where(den > 0, 1.0 / np.maximum(den, 1e-30), 0.0).astype(np.float32)[..., None]
    keep = (den <= 0)[..., None]

    def block(ch: slice) -> None:
        part = img[..., ch]
        num = np.zeros_like(part)
        tmp = np.empty_like(part)
        for dst, src, w in taps:
            np.multiply(part[src], w, out=tmp[dst])
            num[dst] += tmp[dst]
        out[..., ch] = np.where(keep, part, num * inv)

    c = img.shape[-1]
    with ThreadPoolExecutor(max_workers=2) as pool:
        list(pool.map(block, [slice(0, c // 2), slice(c // 2, c)]))
    return out


def _depth_gradient(z: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dz/drow, dz/dcol) per pixel, mm per pixel: the smaller one-sided difference in each direction, so a
    pixel next to a step keeps the slope of its own side (0 where a side has no surface)."""
    return _one_sided_gradient(z, valid, np.abs)


def _off_trend(
    f: np.ndarray,
    g_y: np.ndarray,
    g_x: np.ndarray,
    dst: tuple[slice, slice],
    src: tuple[slice, slice],
    oy: int,
    ox: int,
) -> np.ndarray:
    """f[src] - f[dst] less the change that the mean of their gradients (``g_y``, ``g_x``: per pixel) predicts over
    the offset (``oy``, ``ox``) pixels; ``f`` (H, W) or (H, W, 3)."""
    trend = (g_y[dst] + g_y[src]) * np.float32(oy / 2) + (g_x[dst] + g_x[src]) * np.float32(ox / 2)
    return f[src] - f[dst] - trend


def _normal_gradient(n: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(dn/drow, dn/dcol), each (H, W, 3) float32, per pixel: in each direction the one-sided difference of the
    smaller change, so a pixel beside a kink keeps the rate of its own side (0 where neither side has surface)."""
    return _one_sided_gradient(n, valid, lambda d: np.einsum("ijk,ijk->ij", d, d))


def _one_sided_gradient(
    f: np.ndarray, valid: np.ndarray, size: Callable[[np.ndarray], np.ndarray]
) -> tuple[np.ndarray, np.ndarray]:
    """(df/drow, df/dcol) of ``f`` (H, W) or (H, W, C) on the ``valid`` (H, W) pixels, float32: in each direction
    the one-sided difference whose ``size`` (a per-pixel (H, W) measure of a difference) is the smaller, one whose
    neighbour is off ``valid`` never taken, 0 where neither side is valid."""
    out = []
    for axis in (0, 1):
        fwd = np.diff(f, axis=axis, append=np.take(f, [-1], axis=axis))
        bwd = np.diff(f, axis=axis, prepend=np.take(f, [0], axis=axis))
        size_f = np.where(valid & np.roll(valid, -1, axis=axis), size(fwd), np.inf)
        size_b = np.where(valid & np.roll(valid, 1, axis=axis), size(bwd), np.inf)
        take_f, some = size_f < size_b, np.isfinite(np.minimum(size_f, size_b))
        if f.ndim == 3:
            take_f, some = take_f[..., None], some[..., None]
        out.append(np.where(some, np.where(take_f, fwd, bwd), 0.0).astype(np.float32))
    return out[0], out[1]


def _overlap(H: int, W: int, oy: int, ox: int) -> tuple[tuple[slice, slice], tuple[slice, slice]]:
    """(destination, source) windows of an image shifted by (oy, ox): dst[p] reads src[p + offset]."""
    ys, yd = (slice(oy, H), slice(0, H - oy)) if oy >= 0 else (slice(0, H + oy), slice(-oy, H))
    xs, xd = (slice(ox, W), slice(0, W - ox)) if ox >= 0 else (slice(0, W + ox), slice(-ox, W))
    return (yd, xd), (ys, xs)
