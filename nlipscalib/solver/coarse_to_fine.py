"""The coarse-to-fine driving of a solve: the levels to solve (and a warm start brought down to the first), each
level solved from the previous one's depth change brought up, or the finest brought up unsolved."""

from __future__ import annotations

import dataclasses
import time
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera
from .crop import LevelData
from .gauss_newton import embed, solve_level
from .kernel import Backend
from .operators import depth_normals, level_operators, operators_ahead
from .options import SolverOptions
from .pyramid import build_pyramid, resize

if TYPE_CHECKING:  # named in hints only: tqdm is imported where a progress bar is asked for
    from tqdm import tqdm


def level_pyramid(
    cam: Camera,
    data: LevelData,
    init_depth: np.ndarray | None,
    crop: tuple[slice, slice],
    opts: SolverOptions,
    unrefined: int,
    whole_gel: bool = False,
) -> tuple[list[dict], np.ndarray | None]:
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


def solve_coarse_to_fine(
    levels: list[dict],
    leds: tuple,
    opts: SolverOptions,
    be: Backend,
    bar: tqdm | None,
    report: dict,
    t_first: np.ndarray | None = None,
    refine_finest: bool = True,
    finest_later: bool = False,
) -> tuple[np.ndarray, dict]:
    """Solve every level, coarse to fine, each from the previous one's depth change; returns the finest.

    ``leds``: (positions, directions, mu, psi) of the LEDs kept (``LevelData.leds``).
    ``t_first``: log-depth to start the first level from (a warm start; no least-squares pre-solve).
    ``refine_finest``: False: the finest level (of several) is not iterated but brought up from the one before it
    (:func:`_brought_up`); ``finest_later``: a later solve on the same mask iterates it (the outer loop's last pass):
    its normal-matrix assembler is made ahead with its operators (:func:`.operators.operators_ahead`)."""
    t_state = out = None
    if not refine_finest and len(levels) > 1:
        operators_ahead(levels[-1], assembler=finest_later)
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
            t_init, _, info = solve_level(lv, t_init, leds, opts, be, bar, "ls", coarse=True)
            report["levels"].append(info)
        coarse = k < len(levels) - 1
        warm = k == 0 and t_first is not None  # the finest level from a solved depth: tighter first step
        t_state, out, info = solve_level(lv, t_init, leds, opts, be, bar, opts.estimator, coarse, warm)
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
    (H, W) float64 log-depth (0 off the mask), the per-pixel results (as :func:`solve_level`'s), the level's
    report entry (no iterations, no energy).
    """
    t0 = time.perf_counter()
    mk = lv["mask"]
    ops = level_operators(lv)
    t = t_init[mk]
    result = {
        "normals": depth_normals(ops, t, *lv["ABC"]),
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
    return embed(t, mk), result, info


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
