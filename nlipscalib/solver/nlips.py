"""Near-light photometric stereo on a distorted camera: reweighted Gauss-Newton on log-depth.

Unknown: log-depth t = log z on a mask of pixels. Energy::

    E(t, rho) = sum_{p, i, c usable} phi(rho_c(p) Psi_ic F_i(p; t) - I_ic(p))
                + zeta sum_p (t_p - t0_p)^2 + gamma |second differences of t|^2

The albedo is eliminated (variable projection): it is the closed-form (IRLS-weighted) fit at every
depth, and each Gauss-Newton step on t uses the Jacobian projected orthogonally to the shading, so
depth and albedo move together instead of alternating -- alternation crawls along the depth scale that
the albedo absorbs and left small regions of interest far from convergence. The sparse SPD system is
solved inexactly (Eisenstat-Walker forcing term) by conjugate gradient, Jacobi-preconditioned for loose
solves and smoothed-aggregation AMG (pyamg) otherwise; a backtracking line search on the joint energy
rejects any step that would raise it. Coarse-to-fine over an image pyramid (cv2.resize INTER_AREA,
Camera.scaled). Per-pixel work runs in ``SolverOptions.dtype`` (float32 by default), the sparse system
in float64.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING

import numpy as np

from ..core import masks
from ..core.camera import Camera
from ..core.errors import ConfigError
from ..core.leds import Leds, led_arrays
from ..core.metrics import angle_deg
from ..core.pages import ordinary_pages
from ..core.reconstruction import Reconstruction
from ..core.robust_scale import mad_scale
from . import geometry, reuse, threads
from .blas import blas_threads
from .inputs import check_inputs
from .kernel import PARALLEL_MIN_PIXELS, Array, Backend, ChunkedModel, Model, Parts, make_model
from .krylov import Krylov, forcing
from .options import SolverOptions
from .pyramid import build_pyramid, checked_prior_weights, resize

if TYPE_CHECKING:  # named in hints only: tqdm is imported where a progress bar is asked for
    from pathlib import Path

    from tqdm import tqdm

log = logging.getLogger(__name__)


SolveResult = Reconstruction
"""The solver's output is the core reconstruction format (:class:`nlipscalib.core.reconstruction.Reconstruction`)."""


def exclusions(
    images: np.ndarray, saturated: np.ndarray | None, options: SolverOptions, whole: np.ndarray | None = None
) -> tuple[np.ndarray, dict]:
    """Which (LED, pixel, channel) samples the data term may use, and why others are excluded.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1, finite
    saturated : (L, H, W, 3) bool or None
    options : SolverOptions
    whole : (L, H', W', 3) float or None -- the whole images when ``images`` is a crop of them: the
        dead-LED and shadow thresholds are statistics of the whole images (default ``images``).

    Returns
    -------
    usable : (L, H, W, 3) bool
    report : dict -- dead_leds (0-based list), dead_pixels, saturated_samples, shadow_samples (counts)
    """
    L = images.shape[0]
    per_led_high, per_channel_high = _bright_ends(images if whole is None else whole, images.dtype)
    dead_leds = [i for i in range(L) if per_led_high[i] < options.dead_led_level]
    # Shadow threshold per LED and channel, relative to that image's bright end.
    shadow_level = options.shadow_level * per_channel_high  # (L, 3)
    usable = np.empty(images.shape, bool)

    def rows(part: slice) -> tuple[int, int, int]:
        sat = None if saturated is None else saturated[:, part]
        return _usable_rows(images[:, part], sat, shadow_level, options.dead_pixel_level, usable[:, part])

    # elementwise over (L, H, W, 3): row blocks on the thread pool, the counts (integers) added up
    counts = np.sum(threads.map_items(rows, threads.chunks(images.shape[1])), axis=0, dtype=np.int64)
    usable[dead_leds] = False
    report = {
        "dead_leds": dead_leds,
        "dead_pixels": int(counts[0]),
        "saturated_samples": int(counts[1]),
        "shadow_samples": int(counts[2]),
    }
    return usable, report


def _bright_ends(images: np.ndarray, dtype: np.typing.DTypeLike) -> tuple[np.ndarray, np.ndarray]:
    """The 99th percentile of each image over its pixels and channels, (L,), and per channel, (L, 3).

    ``images`` (L, H, W, 3) float, linear; the percentiles are taken in ``dtype``. Image statistics: a regular
    subgrid of the pixels gives the same 99th percentiles as all of them at a fraction of the cost (this dominated
    small ROI solves). One LED per pool task: the gather and the two percentiles took ~15 ms of one core per
    solve at 640x480 with 12 LEDs, once per outer-loop pass, while the other waited. Each LED's percentiles are
    the same numbers whether taken alone or along an axis of the stack (the same order statistics and
    interpolation), so the same bits."""
    index = np.flatnonzero(masks.sample_grid(np.ones(images.shape[1:3], bool)))

    def one_led(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        sample = image.reshape(-1, 3)[index].astype(dtype, copy=False)
        return np.percentile(sample, 99), np.percentile(sample, 99, axis=0)

    per_led = threads.map_items(one_led, images)
    return np.array([high for high, _ in per_led]), np.stack([channels for _, channels in per_led])


def _usable_rows(
    images: np.ndarray, saturated: np.ndarray | None, shadow_level: np.ndarray, dead_level: float, out: np.ndarray
) -> tuple[int, int, int]:
    """:func:`exclusions`' samples on a block of rows, written to ``out``; (dead pixels, saturated samples,
    shadow samples not saturated) counted there.

    Parameters
    ----------
    images : (L, h, W, 3) float; saturated : (L, h, W, 3) bool or None
    shadow_level : (L, 3) float -- a sample below its LED's and channel's level is in shadow.
    dead_level : a pixel no LED lights above this in any channel is dead.
    out : (L, h, W, 3) bool, written.
    """
    L, h, w, c = images.shape
    # max over LEDs first (a reduction along the contiguous leading axis), then over the channels one by one
    # (a reduction along the 3-long last axis took 12 ms of a whole frame's 15)
    brightest = images.max(axis=0)
    dead_px = functools.reduce(np.maximum, [brightest[..., k] for k in range(c)]) <= dead_level
    # The per-channel levels repeated along a row, so that NumPy's loops run along whole (w, c) rows: broadcast
    # along a 3-long last axis they took 30 ms of a whole frame's 40. In ``out`` itself, counted as it goes
    # (count_nonzero, no temporaries); the images are finite, so not in shadow is ``>=`` the level.
    np.greater_equal(images, np.tile(shadow_level, (1, w)).reshape(L, 1, w, c), out=out)
    if saturated is None:
        n_sat, shadow = 0, out.size - np.count_nonzero(out)
    else:
        np.greater(out, saturated, out=out)  # lit and not saturated (booleans: a > b is a and not b)
        n_sat = np.count_nonzero(saturated)
        shadow = out.size - n_sat - np.count_nonzero(out)  # shadow and not saturated: neither lit nor saturated
    out &= np.repeat(~dead_px, c, axis=-1).reshape(1, h, w, c)
    return int(dead_px.sum()), int(n_sat), int(shadow)


def solve(
    images: np.ndarray,
    camera: Camera,
    leds: Leds,
    *,
    prior_depth: np.ndarray | None = None,
    prior_weights: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    saturated: np.ndarray | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    progress: bool = False,
    init_depth: np.ndarray | None = None,
    unrefined: int = 0,
    where: str | Path | None = None,
) -> SolveResult:
    """Recover depth, normals and albedo from one image per LED.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1, RGB
        One image per LED lit alone.
    camera : Camera -- its exact per-pixel rays are used (no pinhole assumption).
    leds : sequence of Led, length L, camera frame, mm.
    prior_depth : (H, W) float, mm, or None
        Depth prior z0 (e.g. the undeformed dome, ``Press.reference.depth``); NaN where not gel.
        None: ``options.nominal_distance`` along every ray.
    prior_weights : (H, W) float >= 0 or None
        Per-pixel multiplier of the prior weight zeta (default 1): e.g. large where the gel is known
        to be undeformed, which pins the absolute depth that near light determines only weakly.
    mask : (H, W) bool or None -- pixels to solve (default: where the prior is finite).
    saturated : (L, H, W, 3) bool or None -- samples to exclude as saturated.
    options : SolverOptions
    backend : "numpy" or "torch" (per-pixel maths on a GPU when present; same equations).
    progress : show a tqdm bar.
    init_depth : (H, W) float, mm, or None
        A close solution to start from (e.g. the previous pass of the outer interreflection loop,
        whose images differ only by a small change of the indirect light): the finest level alone is
        solved from it, no pyramid (with ``unrefined`` k > 0: the level k below the finest, from it
        averaged down). NaN pixels start from the prior.
    unrefined : how many of the finest levels are not iterated (0: all are). The finest level's depth is then
        the finest iterated level's brought up (bilinear), its normals that depth's, and its albedo, residual
        and confidence the iterated level's brought up too (:func:`_brought_up`); the levels between are
        skipped -- a pass of the outer interreflection loop before its last, whose indirect light is gathered
        on patches several pixels wide, needs no more. The coarsest level is always iterated. From the prior (no
        ``init_depth``) its levels stop at ``options.seed_energy_rtol`` instead of ``options.energy_rtol``.
    where : what the warnings name first (the press folder, so that a batch's lines say which press); None: nothing.
    """
    opts = options or SolverOptions()
    leds = tuple(leds)
    images, prior_depth, mask = check_inputs(images, camera, leds, prior_depth, mask, saturated, opts)
    if unrefined < 0:
        raise ConfigError(f"unrefined must be >= 0 levels, got {unrefined}")
    if unrefined and init_depth is None:  # the outer loop's first pass: it only seeds the passes after it
        opts = dataclasses.replace(opts, energy_rtol=opts.seed_energy_rtol)
    t_start = time.perf_counter()
    with ordinary_pages():  # this VM's transparent huge pages cost a third of a whole frame's CPU (pages.py)
        result = _solve_checked(
            images,
            camera,
            leds,
            prior_depth,
            prior_weights,
            mask,
            saturated,
            opts,
            backend,
            progress,
            init_depth,
            unrefined,
        )
    refined = opts.normals == "refined" and unrefined == 0  # an unrefined pass only feeds the next one
    if refined:
        from .refine import refine_result  # refine imports this module

        result = refine_result(result, images, saturated, leds, opts)
    report = result.report
    report.update(
        {"backend": backend, "seconds": time.perf_counter() - t_start, "normals": "refined" if refined else "depth"}
    )
    if unrefined == 0:  # said of the result, not of each pass of the outer interreflection loop feeding it
        named = f"{where}: " if where is not None else ""
        if n := report["pixels_too_few_leds"]:
            pixels = f"{n} pixel has" if n == 1 else f"{n} pixels have"
            log.warning("%s%s fewer than %d usable LEDs: not reconstructed (NaN)", named, pixels, opts.min_leds)
        if report["dead_leds"]:
            log.warning("%sdead LEDs excluded (1-based): %s", named, [i + 1 for i in report["dead_leds"]])
    return result


def _solve_checked(
    images: np.ndarray,
    camera: Camera,
    leds: tuple,
    prior_depth: np.ndarray,
    prior_weights: np.ndarray | None,
    mask: np.ndarray,
    saturated: np.ndarray | None,
    opts: SolverOptions,
    backend: str,
    progress: bool,
    init_depth: np.ndarray | None,
    unrefined: int,
) -> SolveResult:
    """:func:`solve` on checked inputs (see there), without its timer and warnings."""
    # Solve on the mask's bounding box only: a crop of the camera is the same lens, shifted.
    crop, cam = _crop_to_mask(mask, camera)
    data = _LevelData.of(images, saturated, mask, crop, prior_depth, prior_weights, leds, opts)
    # the sensor's whole gel: every whole-frame press solves on it, so its levels' rays and large levels'
    # operators recur
    whole_gel = bool(np.array_equal(mask, np.isfinite(prior_depth)))
    levels, t_first = _pyramid(cam, data, init_depth, crop, opts, unrefined, whole_gel)
    for lv in levels:
        lv["recurs"] = whole_gel
    report = data.report
    report["levels"] = []
    bar = None
    if progress:
        from tqdm import tqdm

        # no total: a level stops on convergence, mostly long before opts.max_iters, so a bar to levels x max_iters
        # stopped at 3-10 % with an ETA of tens of seconds (a 1280x960 whole frame's "1/30 [00:01<00:36]")
        bar = tqdm(desc="NLiPs", leave=False, bar_format=LEVEL_BAR)
    be = Backend(backend, opts.dtype)
    with blas_threads(1):
        t_state, out = _coarse_to_fine(levels, data.leds, opts, be, bar, report, t_first, unrefined == 0)
    if bar is not None:
        bar.close()
    report.update({"leds_used": [int(i) for i in data.kept], "pixels_solved": int(mask.sum())})
    result = _full_image(t_state, out, levels[-1], data, mask, crop, opts)
    report["intensity_scale"] = data.scale
    return result


def _crop_to_mask(mask: np.ndarray, camera: Camera) -> tuple[tuple[slice, slice], Camera]:
    """The mask's bounding box as (rows, cols) slices, and the camera of that crop (the same lens, shifted)."""
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    cam = dataclasses.replace(camera, width=int(c1 - c0), height=int(r1 - r0), cx=camera.cx - c0, cy=camera.cy - r0)
    return (slice(r0, r1), slice(c0, c1)), cam


@dataclasses.dataclass
class _LevelData:
    """What the finest level is built from, on the mask's bounding box: the normalised images of the LEDs
    kept (dead ones dropped), their usable samples, the log-depth prior and its weights."""

    images: np.ndarray
    """(L', h, w, 3) float, as given: the pyramid's levels hold them divided by ``scale`` (:func:`build_pyramid`)."""
    usable: np.ndarray
    """(L', h, w, 3) bool."""
    mask: np.ndarray
    """(h, w) bool -- the solve mask on the crop."""
    t0: np.ndarray
    """(h, w) float64 -- log prior depth (0 off the mask)."""
    w0: np.ndarray
    """(h, w) float -- the prior weights' multipliers."""
    leds: tuple
    """(positions, directions, mu, psi) of the LEDs kept (:func:`nlipscalib.core.leds.led_arrays`)."""
    kept: list
    """0-based indices of the LEDs kept."""
    usable_leds: np.ndarray
    """(H, W) int16 -- usable LEDs per pixel of the whole image (0 outside the crop)."""
    scale: float
    """The images' 99th percentile over usable samples, by which they were divided."""
    report: dict
    """:func:`exclusions`' report (its counts are the crop's)."""

    @classmethod
    def of(
        cls,
        images: np.ndarray,
        saturated: np.ndarray | None,
        mask: np.ndarray,
        crop: tuple[slice, slice],
        prior_depth: np.ndarray,
        prior_weights: np.ndarray | None,
        leds: Leds,
        opts: SolverOptions,
    ) -> _LevelData:
        whole = images
        H, W = mask.shape
        # Per-pixel work runs in opts.dtype; the images need no more precision than that (16-bit data).
        dtype = np.float32 if opts.dtype == "float32" else np.float64
        images = images[:, crop[0], crop[1]].astype(dtype, copy=False)
        sat = None if saturated is None else saturated[:, crop[0], crop[1]]
        # the exclusions' thresholds are statistics of the whole images; outside the mask nothing is usable
        use, report = exclusions(images, sat, opts, whole=whole)
        m = mask[crop]
        if not m.all():
            use &= m[None, :, :, None]
        usable_leds = np.zeros((H, W), np.int16)
        usable_leds[crop] = (use[..., 0] | use[..., 1] | use[..., 2]).sum(axis=0, dtype=np.int16)
        scale = _high_level(images, use)  # usable lies inside the crop
        kept = [i for i in range(len(leds)) if i not in report["dead_leds"]]
        every = len(kept) == len(leds)  # then no copy of the images and samples
        pos, dirs, mu, psi = led_arrays(leds)
        return cls(
            images=images if every else images[kept],
            usable=use if every else use[kept],
            mask=m,
            t0=np.log(np.where(m, prior_depth[crop], 1.0)),
            w0=checked_prior_weights(prior_weights, (H, W))[crop],
            leds=(pos[kept], dirs[kept], mu[kept], psi[kept]),
            kept=kept,
            usable_leds=usable_leds,
            scale=scale,
            report=report,
        )


def _high_level(images: np.ndarray, usable: np.ndarray) -> float:
    """The images' 99th percentile over the usable samples (1 where there is none or it is not positive): the
    value of ``np.percentile(images[usable], 99)``, to the bit.

    Parameters
    ----------
    images : (L, h, w, 3) float; usable : (L, h, w, 3) bool
    """
    n = int(np.count_nonzero(usable))
    if n == 0:
        return 1.0
    # numpy's linear method: the order statistics at floor(v) and the next, v = (n - 1) q, interpolated
    virtual = (n - 1) * (99 / 100)
    below = int(np.floor(virtual))
    top, n_under = _top_samples(images, usable, n, below)
    ranks = sorted({below - n_under, min(below + 1, n - 1) - n_under})
    top.partition(ranks)
    scale = float(_lerp(top[ranks[0]], top[ranks[-1]], virtual - below))
    return scale if scale > 0 else 1.0


def _top_samples(images: np.ndarray, usable: np.ndarray, n: int, rank: int) -> tuple[np.ndarray, int]:
    """The usable samples from a bound at or below the one of order ``rank`` (0-based, of ``n``) up, and how many
    usable samples lie under that bound: an order statistic of the few percent at the top is that of all of them.

    A partition of every usable sample of a 640x480 frame (~10^7) took 0.05 s of each NLiPs call, and gathering
    them 0.03 s more; the bound is a lower percentile of a 1-in-64 subsample. Where it is not low enough (a sample
    unlike the whole), every usable sample is returned, under a bound of 0.

    Returns
    -------
    (k,) float, a new array (any order); the count of usable samples under it.
    """
    sub = images[:, ::8, ::8][usable[:, ::8, ::8]]
    if sub.size:
        bound = np.percentile(sub, 98)
        above = images >= bound
        above &= usable
        top = images[above]
        if n - top.size <= rank:
            return top, n - top.size
    # a flat boolean index: indexing the (L, h, w, 3) array with a mask that selects every sample took 0.11 s
    # at 640x480 against 0.01 s
    return images.reshape(-1)[usable.reshape(-1)], 0


def _lerp(a: np.floating, b: np.floating, t: float) -> np.floating:
    """numpy's interpolation of a percentile between its order statistics ``a <= b`` at ``t`` in [0, 1), in their
    dtype, the same bits (``numpy.lib._function_base_impl._lerp``: from the nearer end)."""
    diff = b - a
    return b - diff * (1 - t) if t >= 0.5 else a + diff * t


def _pyramid(
    cam: Camera,
    data: _LevelData,
    init_depth: np.ndarray | None,
    crop: tuple[slice, slice],
    opts: SolverOptions,
    unrefined: int,
    whole_gel: bool = False,
):
    """The levels to solve, and the log-depth the first of them starts from (None: the prior).

    A warm start (``init_depth``) solves the finest level from it; with ``unrefined`` levels, the one below
    them, from it brought down (the start's change from the prior, averaged inside the mask). ``whole_gel``: the
    mask is the sensor's whole gel (:func:`build_pyramid` keeps its levels' rays on disk)."""
    m, t0 = data.mask, data.t0
    t_first = None
    if init_depth is not None:
        init = np.asarray(init_depth, np.float64)[crop]
        t_first = np.where(m & np.isfinite(init) & (init > 0), np.log(np.where(init > 0, init, 1.0)), t0)
    levels = build_pyramid(
        cam,
        data.images,
        data.usable,
        m,
        t0,
        data.w0,
        opts if t_first is None else dataclasses.replace(opts, pyramid_levels=unrefined + 1),
        skip=range(1, unrefined),
        scale=data.images.dtype.type(data.scale),
        whole_gel=whole_gel,
        bare=(0,) if unrefined else (),  # the finest level is then brought up (:func:`_brought_up`), not solved
    )
    if t_first is not None and len(levels) > 1:
        shape = levels[0]["camera"].shape
        change = resize(np.where(m, t_first - t0, 0.0), shape) / np.maximum(resize(m.astype(np.float32), shape), 1e-9)
        t_first = levels[0]["t0"] + np.where(levels[0]["mask"], change, 0.0)
    return levels, t_first


def _full_image(
    t_state: np.ndarray,
    out: dict,
    lv: dict,
    data: _LevelData,
    mask: np.ndarray,
    crop: tuple[slice, slice],
    opts: SolverOptions,
) -> SolveResult:
    """The finest level's solution pasted into the whole image (NaN where not reconstructed: off the mask,
    no gradient, fewer than ``opts.min_leds`` usable LEDs); adds the pixel counts to ``data.report``."""
    H, W = mask.shape
    lm = lv["mask"]
    n_ok = out["has_gradient"] & (data.usable_leds[crop][lm] >= opts.min_leds)
    rec = np.zeros((H, W), bool)
    sub = np.zeros(lm.shape, bool)
    sub[lm] = n_ok
    rec[crop] = sub

    lost = None if n_ok.all() else ~n_ok

    def paste(values: np.ndarray, fill: float = np.nan):
        return _pasted(values, fill, (H, W), crop, lm, lost)

    depth = np.exp(t_state[lm])
    data.report.update(
        {
            "pixels_reconstructed": int(rec.sum()),
            "pixels_too_few_leds": int((mask & (data.usable_leds < opts.min_leds)).sum()),
            "pixels_no_gradient": int((~out["has_gradient"]).sum()),
        }
    )
    return SolveResult(
        depth=paste(depth),
        # core.camera.depth_to_points with the rays pre-divided by their z (q = ray / ray_z, geometry.py)
        points=paste(depth[:, None] * lv["q"]),
        normals=paste(out["normals"]),
        albedo=paste(out["albedo"].T * data.scale),
        residual=paste(out["residual"] * data.scale),
        confidence=paste(np.nan_to_num(out["confidence"]), 0.0),  # 0 outside: the same as after the paste
        usable_leds=data.usable_leds,
        mask=mask,
        reconstructed=rec,
        report=data.report,
    )


def _pasted(
    values: np.ndarray,
    fill: float,
    shape: tuple[int, int],
    crop: tuple[slice, slice],
    mask: np.ndarray,
    lost: np.ndarray | None,
) -> np.ndarray:
    """(H, W, ...) float32 image of a level's per-pixel ``values`` (N, ...) on ``mask`` (h, w) of the ``crop`` of an
    image of ``shape`` (H, W); ``fill`` elsewhere and at the pixels ``lost`` (N,) bool (None: none).

    Why not a filled image and a masked assignment: every pixel is written once (the crop's values cast straight into
    it where the mask is the whole crop, the ROI's usual case), with no float32 copy of ``values`` and no masks
    (a pass's six images: ~9 against ~3 ms of one core, 336 x 332 in 640 x 480; benchmarks/RESULTS.md, s21-cpu)."""
    full = np.empty(shape + values.shape[1:], np.float32)
    rows, cols = crop
    full[: rows.start], full[rows.stop :] = fill, fill
    full[rows, : cols.start], full[rows, cols.stop :] = fill, fill
    block = full[crop]  # a view: written through
    if mask.all():
        np.copyto(block, values.reshape(block.shape), casting="same_kind")  # astype's cast
        if lost is not None:
            block[lost.reshape(mask.shape)] = fill
        return full
    block[...] = fill
    vals = values.astype(np.float32)
    if lost is not None:
        vals[lost] = fill
    block[mask] = vals
    return full


LEVEL_BAR = "{desc}: {n_fmt} iterations so far, {elapsed}"
"""The solve's terminal line (tqdm ``bar_format``): the level being solved and the iterations so far, no ETA."""


def _coarse_to_fine(
    levels: list[dict],
    leds: tuple,
    opts: SolverOptions,
    be: Backend,
    bar: tqdm | None,
    report: dict,
    t_first: np.ndarray | None = None,
    refine_finest: bool = True,
):
    """Solve every level, coarse to fine, each from the previous one's depth change; returns the finest.

    ``leds``: (positions, directions, mu, psi) of the LEDs kept (``_LevelData.leds``).
    ``t_first``: log-depth to start the first level from (a warm start; no least-squares pre-solve).
    ``refine_finest``: False: the finest level (of several) is not iterated but brought up from the one before it
    (:func:`_brought_up`)."""
    t_state = out = None
    if not refine_finest and len(levels) > 1:
        _operators_ahead(levels[-1])
    for k, lv in enumerate(levels):
        if bar is not None:
            bar.set_description_str(
                f"NLiPs level {k + 1} of {len(levels)} ({lv['camera'].width}x{lv['camera'].height})"
            )
        if t_state is None:
            t_init = lv["t0"] if t_first is None else t_first
        else:
            prev = levels[k - 1]
            delta = np.where(prev["mask"], t_state - prev["t0"], 0.0)
            delta = resize(delta, lv["camera"].shape, linear=True)
            t_init = lv["t0"] + delta
        if k > 0 and not refine_finest and k == len(levels) - 1:
            t_state, out, info = _brought_up(levels[k - 1], lv, t_init, out, opts.estimator)
            report["levels"].append(info)
            break
        if k == 0 and opts.estimator != "ls" and t_first is None:
            # Least squares first on the coarsest level: from the undeformed prior, the contact's
            # residuals are large and a robust estimator would treat the dent itself as outliers.
            t_init, _, info = _solve_level(lv, t_init, leds, opts, be, bar, "ls", coarse=True)
            report["levels"].append(info)
        coarse = k < len(levels) - 1
        t_state, out, info = _solve_level(lv, t_init, leds, opts, be, bar, opts.estimator, coarse)
        report["levels"].append(info)
    return t_state, out


def _brought_up(prev: dict, lv: dict, t_init: np.ndarray, out: dict, estimator: str):
    """Level ``lv``'s result without iterating or evaluating its model: the depth ``t_init`` (the coarser level
    ``prev``'s brought up), the normals of that depth, and ``prev``'s per-pixel results ``out`` (albedo, residual,
    confidence) brought up to ``lv``'s mask (:func:`_upsampled`). An outer pass before the last needs no more:
    its light is gathered on patches several pixels wide, and the last pass starts from its depth alone.

    Why not the level's model at that depth (as before, s19-b): the albedo fit there took three IRLS refits of the
    level's (L, 3, N) samples, 0.65 s of CPU (~0.35 s of wall on 2 cores) of a 640x480 whole frame's first pass;
    the default twin's one-bounce sphere and cube presses came out within 0.0012 deg of contact AAE of it
    (benchmarks/RESULTS.md, s19-b). The residual and confidence are those of the coarser level's averaged images
    (lower than the level's own): only the last pass's, always iterated, reach a saved result.

    Returns
    -------
    (H, W) float64 log-depth (0 off the mask), the per-pixel results (as :func:`_solve_level`'s), the level's
    report entry (no iterations, no energy).
    """
    t0 = time.perf_counter()
    mk = lv["mask"]
    ops = _operators(lv)
    t = t_init[mk]
    result = {
        "normals": _normals(ops, t, *lv["ABC"]),
        "albedo": _upsampled(out["albedo"].T, prev["mask"], mk).T,
        "residual": _upsampled(out["residual"], prev["mask"], mk),
        "confidence": _upsampled(out["confidence"], prev["mask"], mk),
        "has_gradient": ops["has_grad"],
    }
    info = {
        "shape": list(mk.shape),
        "estimator": estimator,
        "gamma": None,
        "pixels": len(t),
        "lambda": None,
        "energy": [],
        "cg_iters": [],
        "cg_rtol": [],
        "normal_change_deg": [],
        "rejected_steps": 0,
        "expanded_steps": 0,
        "stop": "brought_up",
        "iterations": 0,
        "amg_setups": 0,
        "seconds": {"brought_up": round(time.perf_counter() - t0, 4)},
    }
    return _embed(t, mk), result, info


def _upsampled(values: np.ndarray, coarse_mask: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-pixel values of a coarse level brought up to a finer level's mask: bilinear, after the coarse pixels off
    the mask (or without a finite value) took their valid neighbours' values (:func:`_filled`), so that the fine
    mask's edge, which the coarse mask leaves out (a coarse pixel is in only where all of its fine pixels are), reads
    valid values.

    Parameters
    ----------
    values : (n,) or (n, k) float, k <= 4 -- on ``coarse_mask``'s pixels, row-major; NaN: no value.
    coarse_mask : (h, w) bool; mask : (H, W) bool -- the finer level's.

    Returns
    -------
    (N,) or (N, k) float64 on ``mask``'s pixels (NaN where the coarse level has no valid pixel at all).
    """
    grid = np.full(coarse_mask.shape + values.shape[1:], np.nan)
    grid[coarse_mask] = values
    valid = np.isfinite(grid) if grid.ndim == 2 else np.isfinite(grid).all(axis=-1)
    if not valid.any():
        return np.full((int(mask.sum()),) + values.shape[1:], np.nan)
    return resize(_filled(grid, valid), mask.shape, linear=True)[mask]


def _filled(grid: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """``grid`` (h, w) or (h, w, k) float with its invalid pixels filled ring by ring from the valid ones: each takes
    the mean of its valid 3x3 neighbours, until none is left (``valid`` (h, w) bool, at least one True). OpenCV's box
    filter on the level's small grid: SciPy's nearest-pixel distance transform would import scipy.ndimage (~0.05-0.08
    s) into a command that has no other use for it."""
    import cv2

    shape = grid.shape
    grid = np.where(valid if grid.ndim == 2 else valid[..., None], grid, 0.0).reshape(shape[0], shape[1], -1)
    valid = valid.copy()
    while not valid.all():
        weight = valid.astype(np.float64)
        sums = cv2.boxFilter(grid * weight[..., None], -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        counts = cv2.boxFilter(weight, -1, (3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
        ring = ~valid & (counts > 0)
        grid[ring] = sums.reshape(grid.shape)[ring] / counts[ring][:, None]
        valid |= ring
    return grid.reshape(shape)


# ---------------------------------------------------------------------- one level
class _Timer:
    """Accumulates wall time per named stage (reported per level, for profiling)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self._t
        self._t = now


OPERATOR_LEVELS = 8
"""Levels whose operators a process keeps (solver.reuse): a pyramid's four to six, and a spare. A 640x480 level's
take 160 MB (its pyramid's 210 MB); an auto ROI's a tenth of that."""
OPERATOR_PERSIST_PIXELS = 50_000
"""Levels of the sensor's whole gel (a solve whose mask is everywhere the prior is finite: every whole-frame
press of the sensor solves on those masks) with at least this many pixels keep their operators on disk for the
next process (:mod:`nlipscalib.core.diskcache`) and assemble their normal matrix with a fixed-pattern map
(:class:`nlipscalib.solver.geometry.NormalMatrix`): at 640x480 the finest level's operators and map take ~1.6 s
to build and ~0.15 s to read back, and its assemblies then take 0.04 s instead of 0.4 s; the 320x240 level's
0.01 s instead of 0.07 s. An ROI's masks (auto ROI: one per press) are built in the process as before: their
map would cost more than the few assemblies it saves, and they rarely recur."""


def _operators(lv: dict) -> dict:
    """Difference operators and the normal-matrix assembler of a level (cached in ``lv``).

    They depend on the level's mask alone and cost 0.5-0.9 s at 640x480: kept for the next solve on the
    same mask (the outer interreflection loop's passes, the next press of a whole-frame dataset; a large
    level of the sensor's whole gel on disk too, see :data:`OPERATOR_PERSIST_PIXELS`)."""
    if "ops" not in lv:
        mk = lv["mask"]
        recurs = _persists(lv)
        ahead = lv.pop("ops_ahead", None)  # made on a thread of its own (:func:`_operators_ahead`)
        lv["ops"] = reuse.reused(
            "operators",
            (reuse.digest(mk), recurs),
            ahead.result if ahead is not None else lambda: _make_operators(mk, fixed=recurs),
            most=OPERATOR_LEVELS,
            persist=recurs,
        )
    return lv["ops"]


def _persists(lv: dict) -> bool:
    """Whether a level's operators are kept on disk (:data:`OPERATOR_PERSIST_PIXELS`)."""
    return lv.get("recurs", False) and int(lv["mask"].sum()) >= OPERATOR_PERSIST_PIXELS


def _operators_ahead(lv: dict) -> None:
    """Start making level ``lv``'s operators on a thread of its own (:func:`_operators` then waits for them),
    while the coarser levels are solved; nothing when they are kept (in this process or on disk) or when the
    solve has one core.

    Why: an outer pass before the last solves a coarse level, then brings the finest one up
    (:func:`_brought_up`), which needs the finest level's operators: 0.08-0.1 s of one core on the cube press's
    336x332 auto ROI or its whole frame's 368x364 focus (0.025 s on the sphere's 210x218), built while the
    second core idled. SciPy's sparse kernels release the GIL, and the operators are the same bits on any
    thread."""
    if threads.workers() == 1 or "ops" in lv or _persists(lv):
        return
    mk = lv["mask"]
    if reuse.stored("operators", (reuse.digest(mk), False)):
        return
    pool = ThreadPoolExecutor(1, "nlips-operators")
    lv["ops_ahead"] = pool.submit(_make_operators, mk)
    pool.shutdown(wait=False)  # its one task runs on; its thread ends with it


def _make_operators(mk: np.ndarray, fixed: bool = False) -> dict:
    """Difference operators of a level's mask and its normal-matrix assembler (``fixed``: with the
    fixed-pattern map, :class:`nlipscalib.solver.geometry.NormalMatrix`)."""
    import scipy.sparse as sp

    forward = geometry.difference_operators(mk)
    backward = geometry.difference_operators(mk, backward=True)
    Du, Dv, has_grad = geometry.gradient_operators(mk, forward, backward)
    (du_f, dv_f, _), (du_b, dv_b, _) = forward, backward
    # Second differences (forward minus backward; zero at edges): the checkerboard modes central
    # differences cannot see. A weak penalty on them couples the sub-lattices (and lets AMG work).
    second = [(du_f - du_b).tocsr(), (dv_f - dv_b).tocsr()]
    lap = (second[0].T @ second[0] + second[1].T @ second[1]).tocsr()
    eye = sp.identity(Du.shape[0], format="csr")
    # Central differences: one-sided ones put the normal half a pixel off the data and bias the
    # fit by about a degree on this lens.
    return {
        "Du": Du,
        "Dv": Dv,
        "has_grad": has_grad,
        "lap": lap,
        "normal": geometry.NormalMatrix((eye, Du, Dv), second, fixed=fixed),
    }


def _solve_level(
    lv: dict,
    t_init: np.ndarray,
    leds: tuple,
    opts: SolverOptions,
    be: Backend,
    bar: tqdm | None,
    est: str,
    coarse: bool = False,
):
    """Minimise the energy on one pyramid level from log-depth ``t_init`` (H, W) of that level.

    On a ``coarse`` level (one whose result only starts the next), linear solves stop at a relative
    residual of sqrt(cg_rtol): tighter solves there bought nothing the next level keeps.

    Each iteration (:meth:`_Level.iterate`): variable-projection Gauss-Newton step on t (albedo eliminated),
    solved inexactly by AMG-preconditioned CG, then a backtracking line search on the joint energy with the
    albedo refitted (IRLS) at the trial depth: the energy never increases.

    Returns
    -------
    (H, W) float64 log-depth (0 off the mask), the per-pixel results (normals, albedo, residual, confidence,
    has_gradient), the level's report entry.
    """
    level = _Level(lv, t_init, leds, opts, be, est)
    pcg = Krylov(opts)
    for _ in range(opts.max_iters):
        stop = level.iterate(pcg, coarse)
        if bar is not None:
            bar.update(1)
        if stop:
            level.info["stop"] = stop
            break
    level.info["iterations"] = len(level.info["normal_change_deg"])  # one per accepted step
    level.info["amg_setups"] = pcg.setups
    return level.finish()


class _Level:
    """One pyramid level's energy and the Gauss-Newton state on it: log-depth t on the mask's pixels, the
    shading F and its derivatives dF, the albedo, the residuals r, the energy, the normals."""

    def __init__(self, lv: dict, t_init: np.ndarray, leds: tuple, opts: SolverOptions, be: Backend, est: str):
        self.tm = _Timer()
        self.lv, self.opts, self.be, self.est = lv, opts, be, est
        self.mk = mk = lv["mask"]
        self.A, self.B, self.C = lv["ABC"]
        self.ops = _operators(lv)
        self.t0 = lv["t0"][mk]
        self.zeta = lv["zeta"]
        t = t_init[mk].copy()
        self.model = model = make_model(be, lv["q"], self.A, self.B, self.C, *leds, lv["images"], lv["usable"])
        self._gradient_of: tuple = (None,)
        """(t, t_u, t_v) of the depth shaded last (:meth:`shade`)."""
        self.tm.lap("setup")

        F, dF = self.shade(t, True)
        self.lam = None
        # least squares' energy does not depend on the scale lambda (not known yet): taken in this refit
        albedo, r, e_data = self.refit(F, None, energy=est == "ls")
        self.lam = _robust_scale(be, model, r, lv["images"], lv["usable"], opts)
        # The smoothness weight is relative to the data term's curvature along the gradient of t (least
        # squares, starting depth).
        self.gamma = opts.smoothness * float(np.median(model.gradient_curvature(dF, albedo, model.usable)))
        if est != "ls":
            albedo, r, e_data = self.refit(F, albedo, energy=True)
        self.M, self.b = model.irls_blocks(F, dF, r, albedo, self.lam, est)
        # the derivatives and residuals are in the blocks now: not held through the linear solve and the line search
        # (:meth:`_newton_step`); the level's result is refitted from F and the albedo (:meth:`finish`)
        self.t, self.F, self.dF, self.albedo, self.r = t, F, None, albedo, None
        self.e_cur = e_data + self.prior(t)
        self.info = {
            "shape": list(mk.shape),
            "estimator": est,
            "gamma": self.gamma,
            "pixels": len(t),
            "lambda": self.lam,
            "energy": [self.e_cur],
            "cg_iters": [],
            "cg_rtol": [],
            "normal_change_deg": [],
            "rejected_steps": 0,
            "expanded_steps": 0,
            "stop": "max_iters",
        }
        self.nrm = self.normals(t)
        self.g_prev = self.eta = None
        self._full_step = None
        """The line search's full-step trial depth (the only one :meth:`_expanded` doubles), or None."""
        self.tm.lap("init")

    # ------------------------------------------------------------------ the energy's parts
    def shade(self, tt: np.ndarray, derivatives: bool = False):
        # the gradient kept for the normals of the same depth (:meth:`normals`: the level's start, an accepted step)
        self._gradient_of = (tt, *_gradient(self.ops, tt))
        out = self.model.shading(tt, *self._gradient_of[1:], derivatives)
        return (out[0], out[1:]) if derivatives else (out, None)

    def prior(self, tt: np.ndarray) -> float:
        # the Laplacian's product by row blocks on the pool (the same bits): one per line-search trial, ~5 ms of
        # one core at 640x480
        lap_t = threads.RowBlocks(self.ops["lap"]).dot(tt)
        return float(np.sum(self.zeta * (tt - self.t0) ** 2)) + self.gamma * float(tt @ lap_t)

    def refit(self, F: Array | Parts, alb: Array | Parts | None, energy: bool = False):
        """Albedo at shading F: exact for least squares, one IRLS step from ``alb`` otherwise; (albedo,
        residuals, the data energy there or None) (:meth:`nlipscalib.solver.kernel.Model.refit`)."""
        start = None if self.est == "ls" else alb
        return self.model.refit(F, start, self.lam, self.est, energy)

    def normals(self, tt: np.ndarray):
        if self._gradient_of[0] is tt:  # shaded last: its gradient, not two sparse products again (the same bits)
            return _unit_normals(*self._gradient_of[1:], self.A, self.B, self.C)
        return _normals(self.ops, tt, self.A, self.B, self.C)

    # ------------------------------------------------------------------ one iteration
    def iterate(self, pcg: Krylov, coarse: bool) -> str | None:
        """One Gauss-Newton iteration; the reason to stop (a report ``stop`` value) or None."""
        delta, g, Hm = self._newton_step(pcg, coarse)
        # When the model predicts less than energy_rtol of decrease, the level has converged by that
        # criterion: the full step is taken if it does not raise the energy, and no halvings are tried.
        # Hm's product by row blocks on the pool (the same bits): ~2.5 ms of one core at 640x480
        predicted = -float(g @ delta) - 0.5 * float(delta @ threads.RowBlocks(Hm).dot(delta))
        converged = predicted < self.opts.energy_rtol * self.e_cur
        step = self._line_search(delta, converged)
        if step is not None and not converged:
            step = self._expanded(delta, predicted, step)
        if step is None:
            return "energy_rtol" if converged else "no_descent"
        return self._accept(*step, converged)

    def _newton_step(self, pcg: Krylov, coarse: bool):
        """The Gauss-Newton step on log-depth with the IRLS weights of the current residuals, solved inexactly
        (the forcing term loosens CG while the gradient is still large); (step, gradient, normal matrix)."""
        model, ops, opts, t = self.model, self.ops, self.opts, self.t
        if self.M is None:
            if self.dF is None:  # the accepted step's derivatives, deferred until a step needs them
                self.F, self.dF = self.shade(t, True)
            self.M, self.b = model.irls_blocks(self.F, self.dF, self.r, self.albedo, self.lam, self.est)
            # What the blocks are made from is not held through the assembly, the linear solve (AMG's set-up) and
            # the line search (a trial's shading, derivatives and residuals), where a whole frame's memory peaks:
            # the derivatives and the residuals, 44 MB each at 640x480 with 12 LEDs. The next blocks come from the
            # accepted depth's (:meth:`_accept`).
            self.dF = self.r = None
            self.tm.lap("blocks")
        M, b, zeta, gamma = self.M, self.b, self.zeta, self.gamma
        self.M = self.b = None  # used; the next iteration's blocks come from the accepted depth
        g = b[0] + ops["Du"].T @ b[1] + ops["Dv"].T @ b[2] + zeta * (t - self.t0) + gamma * (ops["lap"] @ t)
        M[0, 0] += zeta + 1e-12 * max(float(np.mean(M[0, 0])), 1e-30)  # the prior; definite if zeta = 0
        Hm = ops["normal"].assemble(M, (gamma, gamma))
        del M, b  # (3, 3, N) and (3, N) float64: in Hm and g now
        self.tm.lap("assemble")
        g_norm = float(np.linalg.norm(g))
        eta = forcing(g_norm, self.g_prev, self.eta, opts)
        self.eta = max(eta, np.sqrt(opts.cg_rtol)) if coarse else eta
        self.g_prev = g_norm
        delta, iters = pcg.solve(Hm, -g, self.eta)
        self.info["cg_iters"].append(iters)
        self.info["cg_rtol"].append(self.eta)
        self.tm.lap("cg")
        return delta, g, Hm

    def _line_search(self, delta: np.ndarray, converged: bool):
        """Backtracking on the joint energy, the albedo refitted at each trial depth: (t, F, dF or None,
        albedo, r, energy) of the first step that does not raise the energy, or None."""
        for k in range(1 if converged else self.opts.line_search_steps + 1):
            t_new = self.t + 0.5**k * delta
            self._full_step = t_new if k == 0 else None
            # the full step's derivatives with its shading (one pass); none after a converged step, which ends
            # the level
            F_new, dF_new = self.shade(t_new, derivatives=k == 0 and not converged)
            alb_new, r_new, e_data = self.refit(F_new, self.albedo, energy=True)
            e_new = e_data + self.prior(t_new)
            if e_new <= self.e_cur:
                self.tm.lap("line_search")
                return t_new, F_new, dF_new, alb_new, r_new, e_new
            self.info["rejected_steps"] += 1
        self.tm.lap("line_search")
        return None

    def _expanded(self, delta: np.ndarray, predicted: float, step: tuple) -> tuple:
        """The line search's accepted ``step`` (t, F, dF, albedo, r, energy), or the doubled step's where
        :func:`expanded_step` takes it (its derivatives then left to the next step). Only a full step is doubled.
        The doubled trial refits the albedo from the same start as the full one: the energies compare like for
        like."""
        if step[0] is not self._full_step:
            return step

        def trial(alpha: float) -> tuple:
            t_far = self.t + alpha * delta
            F_far, _ = self.shade(t_far)
            alb_far, r_far, e_data = self.refit(F_far, self.albedo, energy=True)
            return t_far, F_far, None, alb_far, r_far, e_data + self.prior(t_far)

        out = expanded_step(trial, step, self.e_cur, predicted, self.opts.line_search_expand)
        self.info["expanded_steps"] += out is not step
        self.tm.lap("line_search")
        return out

    def _accept(
        self,
        t_new: np.ndarray,
        F_new: Array | Parts,
        dF_new: Sequence[Array | Parts] | None,
        alb_new: Array | Parts,
        r_new: Array | Parts,
        e_new: float,
        converged: bool,
    ) -> str | None:
        """Move to the accepted depth; the reason to stop there (energy or normals no longer change) or None."""
        # dF_new None (a halved step, or one that ends the level): derived in the next step, if there is one
        self.t, self.F, self.dF, self.albedo, self.r = t_new, F_new, dF_new, alb_new, r_new
        nrm_new = self.normals(t_new)
        change = float(np.median(_pixelwise(lambda p: angle_deg(self.nrm[p], nrm_new[p]), len(t_new))))
        self.nrm = nrm_new
        self.info["normal_change_deg"].append(change)
        rel = (self.e_cur - e_new) / max(self.e_cur, 1e-300)
        self.e_cur = e_new
        self.info["energy"].append(e_new)
        self.tm.lap("line_search")
        if rel < self.opts.energy_rtol or converged:
            return "energy_rtol"
        if change < self.opts.normal_tol_deg:
            return "normal_tol"
        return None

    # ------------------------------------------------------------------ the result
    def finish(self):
        """Final albedo and per-pixel diagnostics at the accepted depth (the refit cannot raise the energy):
        (log-depth (H, W), per-pixel results, the level's report entry)."""
        albedo, r, _ = self.refit(self.F, self.albedo)
        albedo = self.model.whole(albedo)
        u_np = self.lv["usable"]
        cnt = u_np.sum(axis=(0, 1))
        sq, wsum = self.model.fit_sums(r, self.lam, self.est)  # per chunk: no whole (L, 3, N) residual array
        rms = np.sqrt(sq / np.maximum(cnt, 1))
        conf = (cnt / (u_np.shape[0] * u_np.shape[1])) * (wsum / np.maximum(cnt, 1))
        result = {
            "normals": self.nrm,
            "albedo": self.be.numpy(albedo),
            "residual": np.where(cnt > 0, rms, np.nan),
            "confidence": np.clip(conf, 0, 1),
            "has_gradient": self.ops["has_grad"],
        }
        self.tm.lap("finish")
        self.info["seconds"] = {k: round(v, 4) for k, v in self.tm.seconds.items()}
        return _embed(self.t, self.mk), result, self.info


def expanded_step(
    trial: Callable[[float], tuple], full: tuple, e_start: float, predicted: float, ratio: float
) -> tuple:
    """The doubled step's trial where the full step's energy decrease beat its model's prediction by more than
    ``ratio`` times and the doubled step lowers the energy further; ``full`` otherwise.

    Parameters
    ----------
    trial : callable
        ``trial(alpha)``: a tuple whose last item is the energy at the step scaled by ``alpha``.
    full : tuple
        ``trial(1.0)``'s tuple (the full step, accepted by the line search).
    e_start : float
        Energy before the step.
    predicted : float
        The decrease the Gauss-Newton model predicts for the full step (> 0 for a descent step).
    ratio : float
        The factor of ``predicted`` the actual decrease must exceed; 0 = never expand.

    Notes
    -----
    IRLS weights give a robust loss a quadratic model whose curvature bounds the loss's from above (the Cauchy
    loss is concave in r^2), so the model's step falls short where residuals sit in the loss's bend; where its
    model is exact (least squares at the solution's weights) the actual decrease equals the prediction and the
    doubled step is never tried. One more energy evaluation, only where it is tried.
    """
    if not ratio or e_start - full[-1] <= ratio * max(predicted, 0.0):
        return full
    far = trial(2.0)
    return far if far[-1] < full[-1] else full


def _robust_scale(
    be: Backend,
    model: Model | ChunkedModel,
    r: Array | Parts,
    images: np.ndarray,
    usable: np.ndarray,
    opts: SolverOptions,
) -> float:
    """Estimator scale lambda from the residuals of the usable samples, floored relative to the images.

    Parameters
    ----------
    model : the level's model; r : (L, 3, N) residuals on the backend, as ``model`` returned them (chunks too)
    images : (L, 3, N) normalised images; usable : (L, 3, N) usable samples as 0/1
    """
    # Medians over a regular subsample: up to 10^7 samples at full resolution, and a median of
    # 2 10^5 is as good a scale estimate as it needs to be. Only the subsample is read (no whole copies).
    step = max(1, usable.size // 200_000)
    u = usable.reshape(-1)[::step] > 0
    if not u.any():
        return 1e-12
    med_i = float(np.median(images.reshape(-1)[::step][u]))
    r_sub = be.numpy(model.every(r, step))[u]
    return max(opts.robust_scale * mad_scale(r_sub), opts.robust_floor * med_i, 1e-12)


PIXELWISE_PIXELS = 65_536
"""Pixels per task of a level's per-pixel work outside its model (:func:`_pixelwise`): normals and their change
per iteration. Levels under :data:`nlipscalib.solver.kernel.PARALLEL_MIN_PIXELS` pixels run it in one piece."""


def _pixelwise(fn: Callable[[slice], np.ndarray], n: int) -> np.ndarray:
    """``fn(slice(0, n))`` of a per-pixel ``fn`` (its result's first axis the pixels'), by pixel blocks on the thread
    pool on a large level: the same bits. On a 640x480 level an iteration's normals and their change from the last
    ones took ~15-20 ms of one core."""
    if n < PARALLEL_MIN_PIXELS:
        return fn(slice(0, n))
    return np.concatenate(threads.map_items(fn, threads.chunks(n, max(threads.workers(), -(-n // PIXELWISE_PIXELS)))))


def _gradient(ops: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t_u, t_v), (N,) each, of a level's log-depth t (N,): its difference operators' products (``ops``:
    :func:`_operators`), by row blocks on the pool on a large level (:class:`threads.RowBlocks`, the same bits)."""
    return threads.RowBlocks(ops["Du"]).dot(t), threads.RowBlocks(ops["Dv"]).dot(t)


def _normals(ops: dict, t: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals of a level's log-depth t (N,) (:func:`geometry.normals_from_gradient`, by pixel blocks)."""
    return _unit_normals(*_gradient(ops, t), A, B, C)


def _unit_normals(tu: np.ndarray, tv: np.ndarray, A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(N, 3) unit normals of a level's log-depth gradient (tu, tv) (N,) each (:func:`geometry.normals_from_gradient`,
    by pixel blocks)."""
    return _pixelwise(lambda p: geometry.normals_from_gradient(tu[p], tv[p], A[p], B[p], C[p]), len(tu))


def _embed(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    full = np.zeros(mask.shape)
    full[mask] = values
    return full
