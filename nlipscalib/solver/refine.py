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

LEDs that emit from disks (the solve's ``led_radius``, ``nlips solve --led-model disks``) are fitted with their mean
light vector over the disk (:func:`nlipscalib.core.leds.disk_shading`'s quadrature): the disk model itself wherever
the whole disk lights the pixel, as the brightest LEDs do; the max(0, .) is then the whole disk's, not each point's.

A pixel keeps the depth's normal unless the refined one fits those samples better by
:data:`~nlipscalib.core.tolerances.REFINE_GATE` (Cauchy energy / lambda^2): per pixel the fit is noisier than the
depth's normal, which the whole surface constrains (ungated: the sphere press's contact 0.52 -> 1.0 deg), so it
replaces it only where the images reject the latter.

Cost (benchmarks/RESULTS.md, s16-h): a pixel is fitted only when a cheap bound on the gate's gain (the depth
normal's least-squares residual on its support) leaves it a chance, only on its brightest LEDs' samples, with the
model factored per LED rather than per (LED, channel); blocks of pixels run on the thread pool. The skip and the
choice of samples change no number (the bound is exact; the sums drop only zero terms); the per-LED sums and the
written-out 3x3 solve move the float64 fit by rounding only (the float32 normals and albedo of the twin's coin,
sphere and cube presses were bit-identical to the fit over every sample).
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..core import tolerances
from ..core.leds import SHADING_BLOCK, Leds, disk_shading, led_arrays
from . import robust, threads
from .frame_box import FrameBox, frame_crop
from .nlips import SolveResult
from .options import SolverOptions
from .samples import exclusions


def refine_result(
    result: SolveResult,
    images: np.ndarray | FrameBox,
    saturated: np.ndarray | None,
    leds: Leds,
    options: SolverOptions,
    led_radius: float = 0.0,
) -> SolveResult:
    """``result`` with its normals (and albedo) refined per pixel where its images reject the depth's normals.

    Parameters
    ----------
    result : SolveResult of :func:`nlipscalib.solver.solve` on these images (its report's finest level's
        ``lambda`` and ``intensity_scale`` give the fit's scale).
    images : (L, H, W, 3) float, linear, the images that solve read (minus any indirect light), or a
        :class:`.frame_box.FrameBox` of them.
    saturated : (L, H, W, 3) bool or None.
    leds : sequence of Led, length L, camera frame, mm.
    options : SolverOptions of that solve (its exclusions are the fit's).
    led_radius : float, mm -- that solve's ``led_radius``: > 0, the LEDs emit from disks of this radius
        (:func:`nlipscalib.core.leds.disk_shading`'s model, as the solve's); 0: point LEDs.

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
        usable, report = exclusions(frame_crop(images, box), sat, options, whole=images)
        inside = rec[box]
        lam = result.report["levels"][-1]["lambda"] * result.report["intensity_scale"]
        alive = len(leds) - len(report["dead_leds"])
        n_new, rho_new, changed = refine_normals(
            RefitInputs(
                frame_crop(images, box)[:, inside],
                usable[:, inside],
                result.points[box][inside],
                result.normals[box][inside],
                result.albedo[box][inside],
                leds,
                lam,
                brightest=max(tolerances.MIN_LEDS_PER_PIXEL, round(tolerances.REFINE_LED_SHARE * alive)),
                led_radius=led_radius,
            )
        )
        normals[box][inside] = n_new
        albedo[box][inside] = rho_new
        refined = int(changed.sum())
    report = {**result.report, "refined_pixels": refined, "refine_seconds": time.perf_counter() - t0}
    return dataclasses.replace(result, normals=normals, albedo=albedo, report=report)


@dataclasses.dataclass(frozen=True)
class RefitInputs:
    """What the per-pixel refit of N pixels reads (see the module's docstring)."""

    images: np.ndarray
    """(L, N, 3) float, linear -- the pixels' samples per LED and channel."""
    usable: np.ndarray
    """(L, N, 3) bool -- samples the fit may use (:func:`nlipscalib.solver.exclusions`)."""
    points: np.ndarray
    """(N, 3) float, mm, camera frame -- the solved surface points, kept."""
    normals: np.ndarray
    """(N, 3) float, unit, camera frame, toward the camera -- the depth's normals, where the fit starts."""
    albedo: np.ndarray
    """(N, 3) float, linear units -- the solve's albedo per channel (its ratios are kept)."""
    leds: Leds
    """Sequence of Led, length L."""
    scale: float
    """Linear image units -- lambda of the Cauchy reweighting (the solve's)."""
    brightest: int
    """LEDs fitted at each pixel, the brightest there (summed over its usable channels)."""
    led_radius: float = 0.0
    """mm -- > 0: the LEDs emit from disks of this radius (the solve's ``led_radius``); 0: point LEDs."""

    def pixels(self, part: slice) -> RefitInputs:
        """The same refit on the pixels ``part`` only."""
        return dataclasses.replace(
            self,
            images=self.images[:, part],
            usable=self.usable[:, part],
            points=self.points[part],
            normals=self.normals[part],
            albedo=self.albedo[part],
        )


def refine_normals(fit: RefitInputs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each pixel's normal and albedo refitted to its images at its point (see the module's docstring).

    Parameters
    ----------
    fit : RefitInputs -- the N pixels' samples, points, depth normals and albedo, the LEDs, lambda and how many
        LEDs to fit at each pixel.

    Returns
    -------
    normals : (N, 3) float32, unit -- refined where ``changed``, else as given.
    albedo : (N, 3) float32 -- likewise.
    changed : (N,) bool.
    """
    out_n = np.array(fit.normals, np.float32)
    out_rho = np.array(fit.albedo, np.float32)
    changed = np.zeros(len(fit.points), bool)

    def block(part: slice) -> None:
        # pixels are independent: a block's numbers do not depend on the others or on the thread
        n, rho, ok, idx = _refine_block(fit.pixels(part))
        at = idx[ok] + part.start
        out_n[at], out_rho[at], changed[at] = n[ok], rho[ok], True

    blocks = [slice(start, start + SHADING_BLOCK) for start in range(0, len(fit.points), SHADING_BLOCK)]
    threads.map_items(block, blocks)
    return out_n, out_rho, changed


def _refine_block(fit: RefitInputs) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`refine_normals` on one block of pixels: (normals, albedo, whether the gate lets them replace the
    depth's, which of the block's pixels they are), the first two defined where the third is True.

    Only the pixels :func:`_may_pass_gate` keeps are fitted. The model factors per LED: m_ic = Psi_ic g_i (g: the
    LED's light vector at unit intensity), so I_ic = q_ic (g_i . b) with q_ic = Psi_ic k_c, and the fit's sums
    over (LED, channel) are sums over LEDs of per-LED sums over channels: a third of the products."""
    # channel first, pixels last: a channel's (L, N) plane is contiguous (numpy's sums over a middle axis of
    # length 3 are slow), every per-pixel sum is over the leading axes
    leds, scale = fit.leds, fit.scale
    I = np.asarray(fit.images, np.float64).transpose(2, 0, 1).copy()  # (3, L, N)
    use = np.asarray(fit.usable, bool).transpose(2, 0, 1).copy()
    n0 = np.asarray(fit.normals, np.float64).T  # (3, N)
    rho0 = np.asarray(fit.albedo, np.float64).T
    k = rho0 / np.maximum(rho0.mean(axis=0), 1e-30)  # (3, N) the channels' albedo ratios
    top = _brightest(I, use, fit.brightest)
    support = use & top
    points = np.asarray(fit.points, np.float64)
    g_all, shade0 = _depth_shading(points, n0, leds, fit.led_radius)
    shade0 *= k[:, None]  # max(0, A.n0), the fit's model
    idx = np.flatnonzero(_may_pass_gate(I, support, shade0, scale))
    n0, rho0, k, points = n0[:, idx], rho0[:, idx], k[:, idx], points[idx]
    # only the brightest LEDs' samples can be fitted: each pixel's, in LED order (the sums' order, so their
    # numbers are those over all LEDs, whose other terms are zeros)
    top = top[:, idx]
    order = np.argsort(~top, axis=0, kind="stable")[: int(top.sum(axis=0).max(initial=0))][None]  # (1, K, N)
    I, support = np.take_along_axis(I[..., idx], order, 1), np.take_along_axis(support[..., idx], order, 1)
    g = _light_vectors(points, leds, fit.led_radius) if g_all is None else g_all[..., idx]
    g = np.take_along_axis(g, order, 1)  # (3, K, N)
    q = led_arrays(leds)[3].T[:, order[0]] * k[:, None]  # (3, K, N) Psi_ic k_c
    qq, qI = q * q, q * I
    gg = {(i, j): g[i] * g[j] for i in range(3) for j in range(i, 3)}
    b = n0 * rho0.mean(axis=0)
    for _ in range(tolerances.REFINE_ITERATIONS):
        shade = _along(g, b) * q
        w = support * (shade > 0) * robust.weight(I - shade, scale, "cauchy")
        b = _weighted_fit(g, gg, _channel_sum(w * qq), _channel_sum(w * qI))
    fitted = w > 0
    rho_n = np.sqrt((b * b).sum(axis=0))
    n1 = b / np.maximum(rho_n, 1e-30)
    b0 = n0 * _albedo_along(g, q, I, fitted, n0)
    gain = _energy(g, q, I, b0, fitted, scale) - _energy(g, q, I, b, fitted, scale)
    leds_fitted = fitted.any(axis=0).sum(axis=0)
    facing = (n1 * -points.T).sum(axis=0) > 0  # toward the camera
    ok = (gain > tolerances.REFINE_GATE) & (leds_fitted >= tolerances.MIN_LEDS_PER_PIXEL) & facing
    ok &= np.isfinite(n1).all(axis=0)
    return n1.T.astype(np.float32), (k * rho_n).T.astype(np.float32), ok, idx


def _may_pass_gate(images: np.ndarray, support: np.ndarray, shade: np.ndarray, scale: float) -> np.ndarray:
    """(N,) bool -- False where the gate cannot let a refined normal in, whatever the fit finds.

    The gate's gain is E_f(rho_f n0) - E_f(b) <= E_f(rho_f n0), E_f the Cauchy energy / lambda^2 on the fitted
    samples f (a subset of ``support``), rho_f the depth normal's least-squares albedo on them. With
    log(1 + x) <= x and rho_f the least-squares minimiser on f, that is at most the squared residual / lambda^2 of
    the depth normal at its least-squares albedo on all of ``support``: where that is below the gate, the pixel
    keeps its depth normal without a fit. Exact only for rho_f >= 0 (the model's max(0, .) then commutes with it),
    so a pixel with a negative support sample (noise) is fitted; the relative 1e-9 covers rounding.

    images, support, shade : (3, L, N) -- the samples, the fit's support, max(0, A . n0) of the depth normal.
    """
    s = shade * support
    rho = (s * images).sum(axis=(0, 1)) / np.maximum((s * s).sum(axis=(0, 1)), 1e-300)
    r = (images - s * rho) * support
    bound = (r * r).sum(axis=(0, 1)) / (scale * scale)
    return (bound > tolerances.REFINE_GATE * (1 - 1e-9)) | (support & (images < 0)).any(axis=(0, 1))


def _depth_shading(
    points: np.ndarray, normals: np.ndarray, leds: Leds, radius: float
) -> tuple[np.ndarray | None, np.ndarray]:
    """(the light vectors (3, L, N) or None, the fit's shading max(0, Psi_ic g_i . n) (3, L, N)) of the (3, N)
    ``normals`` at the (N, 3) ``points``: the model the gate's bound (:func:`_may_pass_gate`) must share with the fit.

    Point LEDs: :func:`nlipscalib.core.leds.led_shading` itself (no light vectors: they are read off at the fitted
    pixels only). Disk LEDs: from their mean light vectors (:func:`_light_vectors`), which :func:`disk_shading`
    equals wherever the whole disk lights the point and exceeds where the point's tangent plane cuts the disk."""
    if not radius > 0:
        return None, disk_shading(points, normals.T, leds, 0.0).transpose(2, 0, 1)
    g = _light_vectors(points, leds, radius)
    psi = led_arrays(leds)[3].T[:, :, None]  # (3, L, 1)
    return g, np.maximum(_along(g, normals), 0.0)[None] * psi


def _light_vectors(points: np.ndarray, leds: Leds, radius: float = 0.0) -> np.ndarray:
    """(3, L, N) float64 g by component, g = (n_s . d)^mu (x_s - x) / |x_s - x|^3 at unit intensity (m_ic = Psi_ic
    g_i) -- the shading of a normal n is max(0, Psi_ic g_i . n). Read off the one shading formula
    (:func:`nlipscalib.core.leds.disk_shading`, point LEDs at ``radius`` 0), which is g . e_j for the axis e_j when
    positive and 0 otherwise: g_j = shading(e_j) - shading(-e_j), with Psi = 1. Of disk LEDs (``radius`` > 0, mm)
    that difference is, point by point of the disk's quadrature, its points' mean light vector: the disk's model
    wherever the whole disk lights the point (the brightest LEDs the fit keeps), where it is linear in n."""
    unit = [dataclasses.replace(led, intensity=(1.0, 1.0, 1.0)) for led in leds]
    g = np.empty((3, len(leds), len(points)))
    for j, axis in enumerate(np.eye(3)):
        e = np.broadcast_to(axis, points.shape)
        g[j] = disk_shading(points, e, unit, radius)[..., 0] - disk_shading(points, -e, unit, radius)[..., 0]
    return g


def _along(g: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(L, N) g . b per LED and pixel, without the model's max(0, .) (b: (3, N))."""
    return g[0] * b[0] + g[1] * b[1] + g[2] * b[2]


def _channel_sum(a: np.ndarray) -> np.ndarray:
    """(L, N) the sum of (3, L, N) ``a`` over its channels."""
    return a[0] + a[1] + a[2]


def _brightest(images: np.ndarray, usable: np.ndarray, count: int) -> np.ndarray:
    """(L, N) bool -- each pixel's ``count`` brightest LEDs (usable samples (3, L, N) summed over channels; ties
    kept)."""
    total = _channel_sum(np.where(usable, images, 0.0))
    if count >= len(total):
        return np.ones(total.shape, bool)
    kth = -np.partition(-total, count - 1, axis=0)[count - 1]
    return total >= kth


def _weighted_fit(g: np.ndarray, gg: dict, wqq: np.ndarray, wqI: np.ndarray) -> np.ndarray:
    """(3, N) b minimising sum_ic w_ic (I_ic - q_ic g_i . b)^2 per pixel, from its per-LED sums over channels
    ``wqq`` = sum_c w q^2 and ``wqI`` = sum_c w q I (L, N); ``gg``: g_i g_j by (i, j), i <= j. 3x3 normal
    equations; a relative 1e-12 ridge keeps a pixel with too few samples solvable, the gate's LED count then
    rejects it."""
    M = {ij: (wqq * p).sum(axis=0) for ij, p in gg.items()}
    rhs = [(wqI * gi).sum(axis=0) for gi in g]
    ridge = 1e-12 * np.maximum(M[0, 0] + M[1, 1] + M[2, 2], 1e-300)
    for i in range(3):
        M[i, i] = M[i, i] + ridge
    return _solve_spd3(M, rhs)


def _solve_spd3(M: dict, rhs: list[np.ndarray]) -> np.ndarray:
    """(3, N) x with M x = rhs per pixel, M symmetric positive definite given by its upper triangle M[i, j]
    (N,) -- LDL^T written out: a pixel's 3x3 solve is a dozen array operations instead of LAPACK's per-matrix
    call (np.linalg.solve took a third of the fit)."""
    d1 = M[0, 0]
    l21, l31 = M[0, 1] / d1, M[0, 2] / d1
    d2 = M[1, 1] - l21 * M[0, 1]
    l32 = (M[1, 2] - l31 * M[0, 1]) / d2
    d3 = M[2, 2] - l31 * M[0, 2] - l32 * l32 * d2
    y2 = rhs[1] - l21 * rhs[0]
    y3 = rhs[2] - l31 * rhs[0] - l32 * y2
    x3 = y3 / d3
    x2 = y2 / d2 - l32 * x3
    return np.stack([rhs[0] / d1 - l21 * x2 - l31 * x3, x2, x3])


def _albedo_along(g: np.ndarray, q: np.ndarray, images: np.ndarray, where: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(N,) the least-squares albedo of normal ``n`` (3, N) on the samples ``where`` (3, L, N)."""
    shade = np.maximum(_along(g, n), 0.0) * q * where
    return (shade * images).sum(axis=(0, 1)) / np.maximum((shade * shade).sum(axis=(0, 1)), 1e-300)


def _energy(
    g: np.ndarray, q: np.ndarray, images: np.ndarray, b: np.ndarray, where: np.ndarray, scale: float
) -> np.ndarray:
    """(N,) Cauchy energy / scale^2 of b = rho n (3, N) on the samples ``where``: the model's max(0, .) kept."""
    r = images - np.maximum(_along(g, b), 0.0) * q
    return (robust.rho(r, scale, "cauchy") * where).sum(axis=(0, 1)) / (scale * scale)
