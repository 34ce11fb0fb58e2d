"""Near-light photometric stereo on a distorted camera: reweighted Gauss-Newton on log-depth.

Unknown: log-depth t = log z on a mask of pixels. Energy::

    E(t, rho) = sum_{p, i, c usable} phi(rho_c(p) Psi_ic F_i(p; t) - I_ic(p))
                + zeta sum_p (t_p - t0_p)^2 + gamma sum_s phi_s(second differences s of t - t0)

phi_s(s) = c^2 log(1 + s^2 / c^2): squared for small s, edge-preserving beyond c (``SolverOptions.smoothness_edge``, a
slope change per pixel; ``smoothness.py``), so a relief's walls keep their height; c = 0 (off): s^2. Where the
camera sees past the gel (``SolverOptions.smooth_deformation``) the second differences are the deformation's from the
prior t0, so the dome's own curvature costs nothing.

The albedo is eliminated (variable projection): it is the closed-form (IRLS-weighted) fit at every
depth, and each Gauss-Newton step on t uses the Jacobian projected orthogonally to the shading, so
depth and albedo move together instead of alternating -- alternation crawls along the depth scale that
the albedo absorbs and left small regions of interest far from convergence. The sparse SPD system is
solved inexactly (Eisenstat-Walker forcing term) by conjugate gradient, Jacobi-preconditioned for loose
solves and smoothed-aggregation AMG (pyamg) otherwise; a backtracking line search on the joint energy
rejects any step that would raise it. Coarse-to-fine over an image pyramid (cv2.resize INTER_AREA,
Camera.scaled). Per-pixel work runs in ``SolverOptions.dtype`` (float32 by default), the sparse system
in float64.

This module is the entry (:func:`solve`); each part of a solve lives in a file of its own:

- ``inputs.py``: the input checks; ``samples.py``: which samples the data term uses (exclusions) and the images'
  intensity scale;
- ``crop.py``: the solve on the mask's bounding box, its data there, and the result pasted back into the image;
- ``pyramid.py``: the levels' images, masks, rays and priors; ``coarse_to_fine.py``: the levels solved coarse to
  fine (or the finest brought up);
- ``operators.py``: a level's difference operators and normal-matrix assembler, kept for reuse, and its normals;
- ``gauss_newton.py``: one level's Gauss-Newton iteration and line search; ``smoothness.py``: its smoothness term;
  ``kernel.py``: the per-pixel image model;
  ``krylov.py``: the preconditioned CG; ``geometry.py``: rays, difference operators, normals;
- ``threads.py``: the thread pool (BLAS thread control: ``core/blas.py``, shared with learn/).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from typing import TYPE_CHECKING

import numpy as np

from ..core import tolerances
from ..core.blas import blas_threads
from ..core.camera import Camera
from ..core.errors import ConfigError
from ..core.leds import Leds
from ..core.pages import ordinary_pages
from ..core.reconstruction import Reconstruction
from ..progress import bars_enabled, progress_bar
from .coarse_to_fine import level_pyramid, solve_coarse_to_fine
from .crop import LevelData, crop_to_mask, full_image
from .frame_box import FrameBox
from .gauss_newton import expanded_step
from .inputs import check_arguments, check_inputs
from .kernel import Backend
from .options import SolverOptions
from .samples import exclusions

if TYPE_CHECKING:  # named in hints only
    from pathlib import Path


log = logging.getLogger(__name__)

__all__ = ["SolveResult", "exclusions", "expanded_step", "solve"]

SolveResult = Reconstruction
"""The solver's output is the core reconstruction format (:class:`nlipscalib.core.reconstruction.Reconstruction`)."""


LEVEL_BAR = "{desc}: {n_fmt} iterations so far, {elapsed}"
"""The solve's terminal line (tqdm ``bar_format``): the level being solved and the iterations so far, no ETA."""


def solve(
    images: np.ndarray | FrameBox,
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
    led_radius: float = 0.0,
    finest_later: bool = False,
) -> SolveResult:
    """Recover depth, normals and albedo from one image per LED.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1, RGB
        One image per LED lit alone; or a :class:`.frame_box.FrameBox` of them whose window holds the mask (the
        outer interreflection loop's passes: their images change on the mask's bounding box only).
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
    progress : show a tqdm bar, on a terminal only (:func:`nlipscalib.progress.bars_enabled`): in a notebook or a
        log file it wrote a line per iteration.
    init_depth : (H, W) float, mm, or None
        A close solution to start from (e.g. the previous pass of the outer interreflection loop,
        whose images differ only by a small change of the indirect light): the finest level alone is
        solved from it, no pyramid (with ``unrefined`` k > 0: the level k below the finest, from it
        averaged down). NaN pixels start from the prior.
    unrefined : how many of the finest levels are not iterated (0: all are). The finest level's depth is then
        the finest iterated level's brought up (bilinear), its normals that depth's, and its albedo, residual
        and confidence the iterated level's brought up too (:func:`.coarse_to_fine._brought_up`); the levels between are
        skipped -- a pass of the outer interreflection loop before its last, whose indirect light is gathered
        on patches several pixels wide, needs no more. The coarsest level is always iterated. From the prior (no
        ``init_depth``) its levels stop at ``options.seed_energy_rtol`` instead of ``options.energy_rtol``.
    where : what the warnings name first (the press folder, so that a batch's lines say which press); None: nothing.
    led_radius : float, mm -- > 0: the LEDs emit from disks of this radius centred on their positions, perpendicular
        to their axes (:func:`nlipscalib.core.leds.disk_shading`'s model, e.g. ``calibrate-leds``' fitted
        ``emitters``); 0: point LEDs. Why: where the gel comes within a few LED sizes of an LED (a view that sees the
        dome down to its base) the point model misses a disk's light by up to 8 %, and the whole gel's depth took a
        0.09 mm bump from it (benchmarks/RESULTS.md, s32-rimdepth). Each level shades the disks' centres as points times
        their ratio to the disks fixed at its start (:meth:`.kernel.Model.fix_disk_ratio`): ~1.1x a point solve's
        CPU (s33-diskfast; the 7 points at every evaluation cost 1.3-1.5x).
    finest_later : with ``unrefined``: a later solve on the same ``mask`` iterates the finest level (the outer loop's
        last pass after its first): its normal-matrix assembler is made ahead, beside this solve
        (:func:`.coarse_to_fine.solve_coarse_to_fine`). Results are the same either way.
    """
    check_arguments(images, camera, leds, options, unrefined, led_radius, progress)
    opts = options or SolverOptions()
    leds = tuple(leds)
    opts = dataclasses.replace(opts, smooth_deformation=smoothness_about_prior(opts, prior_depth))
    images, prior_depth, mask = check_inputs(images, camera, leds, prior_depth, mask, saturated, opts)
    if unrefined < 0:
        raise ConfigError(f"unrefined must be >= 0 levels, got {unrefined}")
    if not (np.isfinite(led_radius) and led_radius >= 0):
        raise ConfigError(f"led_radius must be a finite radius >= 0 mm, got {led_radius}")
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
            led_radius,
            finest_later,
        )
    refined = opts.normals == "refined" and unrefined == 0  # an unrefined pass only feeds the next one
    if refined:
        from .refine import refine_result  # refine imports this module

        result = refine_result(result, images, saturated, leds, opts, led_radius)
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
            numbers = ", ".join(str(i + 1) for i in report["dead_leds"])
            many = "s" if len(report["dead_leds"]) > 1 else ""
            log.warning(
                "%sLED%s %s: image dark (no light above the dark frame's noise: dead LED?), left out of the solve",
                named,
                many,
                numbers,
            )
    return result


def smoothness_about_prior(opts: SolverOptions, prior_depth: np.ndarray | None) -> str:
    """``opts.smooth_deformation`` decided for this solve: "on" or "off" (:class:`SolverOptions`).

    prior_depth : (H, W) float, mm, NaN off the gel, or None (the nominal distance: a guess, not a surface: "off").
    """
    if prior_depth is None or opts.smooth_deformation == "off":
        return "off"
    if opts.smooth_deformation == "on":
        return "on"
    gel_share = float(np.mean(np.isfinite(prior_depth)))  # the whole frame's prior: the camera's view of the gel
    return "on" if gel_share < tolerances.GEL_FRAME_SHARE_PAST_GEL else "off"


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
    led_radius: float = 0.0,
    finest_later: bool = False,
) -> SolveResult:
    """:func:`solve` on checked inputs (see there), without its timer and warnings."""
    # Solve on the mask's bounding box only: a crop of the camera is the same lens, shifted.
    crop, cam = crop_to_mask(mask, camera)
    data = LevelData.of(images, saturated, mask, crop, prior_depth, prior_weights, leds, opts, led_radius)
    # the sensor's whole gel: every whole-frame press solves on it, so its levels' rays and large levels'
    # operators recur
    whole_gel = bool(np.array_equal(mask, np.isfinite(prior_depth)))
    levels, t_first = level_pyramid(cam, data, init_depth, crop, opts, unrefined, whole_gel)
    for lv in levels:
        lv["recurs"] = whole_gel
    report = data.report
    report["levels"] = []
    bar = None
    if bars_enabled(progress):
        # no total: a level stops on convergence, mostly long before opts.max_iters, so a bar to levels x max_iters
        # stopped at 3-10 % with an ETA of tens of seconds (a 1280x960 whole frame's "1/30 [00:01<00:36]")
        # drawn at every iteration (each takes 10 ms to seconds): with tqdm's default 0.1 s interval a short solve's
        # line could stay at "0 iterations so far"
        # first_draw=False: no write where the bar is made (tqdm has registered it by then); a Ctrl-C landing in
        # that write (a notebook's stop button, in the kernel's send) left a bar open that nobody could close,
        # and every later bar of the kernel nested under it. The first draw comes with the first level's description,
        # in the try (not progress._drawn's: this line has nothing to say before a level starts)
        bar = progress_bar(
            None, first_draw=False, desc="NLiPs", leave=False, bar_format=LEVEL_BAR, mininterval=0, miniters=1
        )
    be = Backend(backend, opts.dtype)
    try:
        with blas_threads(1):
            t_state, out = solve_coarse_to_fine(
                levels, data.leds, opts, be, bar, report, t_first, unrefined == 0, finest_later
            )
    finally:  # on Ctrl-C too: a notebook keeps the interrupted frames, and a bar left open nests the next one
        if bar is not None:
            bar.close()
    report.update({"leds_used": [int(i) for i in data.kept], "pixels_solved": int(mask.sum())})
    result = full_image(t_state, out, levels[-1], data, mask, crop, opts)
    report["intensity_scale"] = data.scale
    return result
