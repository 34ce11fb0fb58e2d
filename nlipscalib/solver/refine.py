"""Normals refined per pixel by near-light photometric stereo at the solved surface (``SolverOptions.normals``).

NLiPs takes its normals from the gradient of its log-depth. Across relief whose walls are one or two pixels wide (a
coin's 0.32 mm strokes) that gradient spreads the wall over its neighbours, and cast shadows pull the depth with
them: the 640x480 coin press is 4.7 deg off, its 60-90 deg tilts 11 deg (benchmarks/RESULTS.md). Here, after the
solve, each pixel's normal is fitted to that pixel's own images at the solved 3-D point, the depth kept. With the
light frozen at the point, the near-light model of Quéau et al. (2018; :mod:`nlipscalib.core.leds`) is linear in
b = rho n, as in Woodham's (1980) photometric stereo::

    I_ic = k_c m_ic . b,   m_ic = Psi_ic (n_s . d)^mu (x_s - x) / |x_s - x|^3,   b = rho n

(``k_c``: the channel's share of the solve's albedo at the pixel, which the channels keep; the solve's albedo
ratio does not depend on its normal). The fit is robust, because shadow is what the depth's normal misses:

- only the brightest :data:`~nlipscalib.core.tolerances.REFINE_LED_SHARE` of the LEDs at each pixel are fitted:
  a wall's neighbours are in the cast shadow of the grazing LEDs, which the shadow threshold of the solve keeps;
- samples the fitted normal faces away from (attached shadow: the model's max(0, .)) are dropped;
- the rest are reweighted (Cauchy IRLS) at the solve's own scale lambda, from the depth's normal.

A pixel keeps the depth's normal unless the refined one fits those samples better by
:data:`~nlipscalib.core.tolerances.REFINE_GATE` (Cauchy energy / lambda^2): per pixel the fit is noisier than the
depth's normal, which the whole surface constrains (ungated: the sphere press's contact 0.52 -> 1.0 deg), so it
replaces it only where the images reject the latter.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..core import tolerances
from ..core.leds import SHADING_BLOCK, Leds, led_shading
from . import robust
from .nlips import SolveResult, exclusions
from .options import SolverOptions


def refine_result(
    result: SolveResult,
    images: np.ndarray,
    saturated: np.ndarray | None,
    leds: Leds,
    options: SolverOptions,
) -> SolveResult:
    """``result`` with its normals (and albedo) refined per pixel where its images reject the depth's normals.

    Parameters
    ----------
    result : SolveResult of :func:`nlipscalib.solver.solve` on these images (its report's finest level's
        ``lambda`` and ``intensity_scale`` give the fit's scale).
    images : (L, H, W, 3) float, linear, the images that solve read (minus any indirect light).
    saturated : (L, H, W, 3) bool or None.
    leds : sequence of Led, length L, camera frame, mm.
    options : SolverOptions of that solve (its exclusions are the fit's).

    Returns
    -------
    SolveResult -- depth, points, residual and confidence as ``result``'s; ``report`` adds ``refined_pixels``
    (pixels whose normal changed) and ``refine_seconds``.
    """
    t0 = time.perf_counter()
    rec = result.reconstructed
    rows, cols = np.nonzero(rec)
    normals, albedo = result.normals.copy(), result.albedo.copy()
    refined = 0
    if rows.size:
        box = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
        sat = None if saturated is None else saturated[:, box[0], box[1]]
        usable, report = exclusions(images[:, box[0], box[1]], sat, options, whole=images)
        inside = rec[box]
        lam = result.report["levels"][-1]["lambda"] * result.report["intensity_scale"]
        alive = len(leds) - len(report["dead_leds"])
        n_new, rho_new, changed = refine_normals(
            images[:, box[0], box[1]][:, inside],
            usable[:, inside],
            result.points[box][inside],
            result.normals[box][inside],
            result.albedo[box][inside],
            leds,
            lam,
            brightest=max(tolerances.MIN_LEDS_PER_PIXEL, round(tolerances.REFINE_LED_SHARE * alive)),
        )
        normals[box][inside] = n_new
        albedo[box][inside] = rho_new
        refined = int(changed.sum())
    report = {**result.report, "refined_pixels": refined, "refine_seconds": time.perf_counter() - t0}
    return dataclasses.replace(result, normals=normals, albedo=albedo, report=report)


def refine_normals(
    images: np.ndarray,
    usable: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    albedo: np.ndarray,
    leds: Leds,
    scale: float,
    brightest: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's normal and albedo refitted to its images at its point (see the module's docstring).

    Parameters
    ----------
    images : (L, N, 3) float, linear -- the pixels' samples per LED and channel.
    usable : (L, N, 3) bool -- samples the fit may use (:func:`nlipscalib.solver.exclusions`).
    points : (N, 3) float, mm, camera frame -- the solved surface points, kept.
    normals : (N, 3) float, unit, camera frame, toward the camera -- the depth's normals, where the fit starts.
    albedo : (N, 3) float, linear units -- the solve's albedo per channel (its ratios are kept).
    leds : sequence of Led, length L.
    scale : float, linear image units -- lambda of the Cauchy reweighting (the solve's).
    brightest : LEDs fitted at each pixel, the brightest there (summed over its usable channels).

    Returns
    -------
    normals : (N, 3) float32, unit -- refined where ``changed``, else as given.
    albedo : (N, 3) float32 -- likewise.
    changed : (N,) bool.
    """
    out_n = np.array(normals, np.float32)
    out_rho = np.array(albedo, np.float32)
    changed = np.zeros(len(points), bool)
    for start in range(0, len(points), SHADING_BLOCK):
        block = slice(start, start + SHADING_BLOCK)
        n, rho, ok = _refine_block(
            images[:, block], usable[:, block], points[block], normals[block], albedo[block], leds, scale, brightest
        )
        out_n[block][ok], out_rho[block][ok], changed[block] = n[ok], rho[ok], ok
    return out_n, out_rho, changed


def _refine_block(
    images: np.ndarray,
    usable: np.ndarray,
    points: np.ndarray,
    normals: np.ndarray,
    albedo: np.ndarray,
    leds: Leds,
    scale: float,
    brightest: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`refine_normals` on one block of pixels: (normals, albedo, whether the gate lets them replace the
    depth's), the first two defined where the third is True."""
    # pixels last: every per-pixel sum below is over the leading (LED, channel) axes
    I = np.ascontiguousarray(np.moveaxis(np.asarray(images, np.float64), 1, -1))  # (L, 3, N)
    use = np.ascontiguousarray(np.moveaxis(np.asarray(usable, bool), 1, -1))
    n0 = np.asarray(normals, np.float64).T  # (3, N)
    rho0 = np.asarray(albedo, np.float64).T
    k = rho0 / np.maximum(rho0.mean(axis=0), 1e-30)  # (3, N) the channels' albedo ratios
    A = [m * k for m in _light_vectors(points, leds)]  # per component j: (L, 3, N)
    support = use & _brightest(I, use, brightest)[:, None]
    b = n0 * rho0.mean(axis=0)
    for _ in range(tolerances.REFINE_ITERATIONS):
        shade = _shade(A, b)
        w = support * (shade > 0) * robust.weight(I - shade, scale, "cauchy")
        b = _weighted_fit(A, I, w)
    fitted = w > 0
    rho_n = np.sqrt((b * b).sum(axis=0))
    n1 = b / np.maximum(rho_n, 1e-30)
    b0 = n0 * _albedo_along(A, I, fitted, n0)
    gain = _energy(A, I, b0, fitted, scale) - _energy(A, I, b, fitted, scale)
    leds_fitted = fitted.any(axis=1).sum(axis=0)
    facing = (n1 * -np.asarray(points, np.float64).T).sum(axis=0) > 0  # toward the camera
    ok = (gain > tolerances.REFINE_GATE) & (leds_fitted >= tolerances.MIN_LEDS_PER_PIXEL) & facing
    ok &= np.isfinite(n1).all(axis=0)
    return n1.T.astype(np.float32), (k * rho_n).T.astype(np.float32), ok


def _light_vectors(points: np.ndarray, leds: Leds) -> list[np.ndarray]:
    """m_ic = Psi_ic (n_s . d)^mu (x_s - x) / |x_s - x|^3 by component: three (L, 3, N) float64 -- the shading of a
    normal n is max(0, m_ic . n). Read off the one shading formula (:func:`nlipscalib.core.leds.led_shading`),
    which is m . e_j for the axis e_j when positive and 0 otherwise: m_j = shading(e_j) - shading(-e_j)."""
    points = np.asarray(points, np.float64)
    parts = []
    for axis in np.eye(3):
        e = np.broadcast_to(axis, points.shape)
        m = led_shading(points, e, leds) - led_shading(points, -e, leds)  # (L, N, 3)
        parts.append(np.ascontiguousarray(np.moveaxis(m, 1, -1)))
    return parts


def _shade(A: list[np.ndarray], b: np.ndarray) -> np.ndarray:
    """(L, 3, N) A . b, without the model's max(0, .) (b: (3, N))."""
    return A[0] * b[0] + A[1] * b[1] + A[2] * b[2]


def _brightest(images: np.ndarray, usable: np.ndarray, count: int) -> np.ndarray:
    """(L, N) bool -- each pixel's ``count`` brightest LEDs (usable samples summed over channels; ties kept)."""
    total = np.where(usable, images, 0.0).sum(axis=1)
    if count >= len(total):
        return np.ones(total.shape, bool)
    kth = -np.partition(-total, count - 1, axis=0)[count - 1]
    return total >= kth


def _weighted_fit(A: list[np.ndarray], images: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(3, N) b minimising sum w (I - A . b)^2 per pixel (3x3 normal equations; a relative 1e-12 ridge keeps a
    pixel with too few samples solvable, the gate's LED count then rejects it)."""
    wA = [w * a for a in A]
    M = np.empty((images.shape[-1], 3, 3))
    for i in range(3):
        for j in range(i, 3):
            M[:, i, j] = M[:, j, i] = (wA[i] * A[j]).sum(axis=(0, 1))
    rhs = np.stack([(wa * images).sum(axis=(0, 1)) for wa in wA], axis=-1)
    ridge = 1e-12 * np.maximum(np.trace(M, axis1=1, axis2=2), 1e-300)
    M += ridge[:, None, None] * np.eye(3)
    return np.linalg.solve(M, rhs[..., None])[..., 0].T


def _albedo_along(A: list[np.ndarray], images: np.ndarray, where: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) the least-squares albedo of normal ``n`` (3, N) on the samples ``where`` (L, 3, N)."""
    shade = np.maximum(_shade(A, n), 0.0) * where
    return (shade * images).sum(axis=(0, 1)) / np.maximum((shade * shade).sum(axis=(0, 1)), 1e-300)


def _energy(A: list[np.ndarray], images: np.ndarray, b: np.ndarray, where: np.ndarray, scale: float) -> np.ndarray:
    """(N,) Cauchy energy / scale^2 of b = rho n (3, N) on the samples ``where``: the model's max(0, .) kept."""
    r = images - np.maximum(_shade(A, b), 0.0)
    return (robust.rho(r, scale, "cauchy") * where).sum(axis=(0, 1)) / (scale * scale)
