"""Entry checks of :func:`nlipscalib.solver.solve`: shapes, finiteness, the prior and the mask."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..core.camera import Camera
from ..core.errors import NUMBER, ShapeError, check_flag, check_kind, check_whole
from ..core.leds import Led, Leds
from . import threads
from .frame_box import FrameBox
from .options import SolverOptions


def check_arguments(
    images: object,
    camera: object,
    leds: object,
    options: object,
    unrefined: object,
    led_radius: object,
    progress: object,
) -> None:
    """ShapeError naming the argument of :func:`nlipscalib.solver.solve` given another kind than it takes, before
    anything is made of it (the shapes are :func:`check_inputs`').

    Why: ``solve(images, {"fx": ...}, leds)``, ``options={"max_iters": 2}``, ``unrefined=1.5`` or a list of numbers
    for the LEDs failed in Python's AttributeError or TypeError deep inside, or took the list's length for an LED
    count (s38-apikinds)."""
    check_kind(images, (np.ndarray, FrameBox), "images", "an (L, H, W, 3) float array (one image per LED)")
    check_kind(camera, Camera, "camera", "a Camera (press.camera)")
    listed = isinstance(leds, Sequence) and all(isinstance(led, Led) for led in leds)
    if not listed:
        check_kind(leds, (), "leds", "a sequence of Led (press.leds, read_led_file(path).leds)")
    check_kind(options, (SolverOptions, type(None)), "options", "a SolverOptions, or None (defaults)")
    check_whole(unrefined, "unrefined", minimum=0)
    check_kind(led_radius, NUMBER, "led_radius", "a number of mm (0: point LEDs)")
    check_flag(progress, "progress")


def check_inputs(
    images: np.ndarray | FrameBox,
    camera: Camera,
    leds: Leds,
    prior_depth: np.ndarray | None,
    mask: np.ndarray | None,
    saturated: np.ndarray | None,
    opts: SolverOptions,
) -> tuple[np.ndarray | FrameBox, np.ndarray, np.ndarray]:
    """Validate the solver's inputs; returns (images ndarray, or the :class:`.frame_box.FrameBox` given, prior_depth
    (H, W) float64, mask (H, W) bool).

    Raises ShapeError naming the offending argument.
    """
    leds = tuple(leds)
    images = images if isinstance(images, FrameBox) else np.asarray(images)
    H, W = camera.shape
    if len(images.shape) != 4 or images.shape[1:] != (H, W, 3):
        raise ShapeError(f"images must be (L, {H}, {W}, 3) for this camera, got {images.shape}")
    if images.shape[0] != len(leds):
        raise ShapeError(f"{images.shape[0]} LED images but {len(leds)} LEDs")
    if len(leds) < opts.min_leds:
        raise ShapeError(f"{len(leds)} LEDs given; the solver needs at least min_leds={opts.min_leds}")
    if not all(threads.map_items(_finite_reader(images), range(images.shape[0]))):
        raise ShapeError(
            f"images contain {_not_finite(images)} NaN/inf values; mark bad pixels with `mask` or `saturated` instead"
        )
    if saturated is not None and np.shape(saturated) != images.shape:
        raise ShapeError(f"saturated must have the images' shape {images.shape}, got {np.shape(saturated)}")
    if prior_depth is None:
        prior_depth = opts.nominal_distance * camera.rays[..., 2]
    prior_depth = np.asarray(prior_depth, dtype=np.float64)
    if prior_depth.shape != (H, W):
        raise ShapeError(f"prior_depth must be ({H}, {W}), got {prior_depth.shape}")
    finite = np.isfinite(prior_depth) & (np.nan_to_num(prior_depth) > 0)
    if mask is None:
        mask = finite
    mask = np.asarray(mask)
    if mask.shape != (H, W) or mask.dtype != bool:
        raise ShapeError(f"mask must be ({H}, {W}) bool, got {mask.shape} {mask.dtype}")
    mask = mask & finite
    if mask.sum() < 4:
        raise ShapeError("the solve mask holds fewer than 4 pixels with a finite prior depth")

    return images, prior_depth, mask


def _finite_reader(images: np.ndarray | FrameBox) -> Callable[[int], bool]:
    """``finite(i)``: whether LED ``i``'s image holds no NaN or inf: an array's; of a frame box, its box's and its
    frame's (all of it, as when the two were one array: a scan costs less than picking the pixels the solve reads)."""
    if isinstance(images, FrameBox):
        return lambda i: _all_finite(images.box[i]) and _all_finite(images.frame[i])
    return lambda i: _all_finite(images[i])


def _not_finite(images: np.ndarray | FrameBox) -> int:
    """How many values of ``images`` (:func:`_finite_reader`'s) are NaN or inf."""
    parts = [images.box, images.frame] if isinstance(images, FrameBox) else [images]
    return sum(int(np.sum(~np.isfinite(part))) for part in parts)


def _all_finite(image: np.ndarray) -> bool:
    """Whether one LED's image (H, W, 3) holds no NaN or inf: :func:`check_inputs` checks the LEDs on the thread
    pool (:func:`threads.map_items`). Why: the whole (L, H, W, 3) stack at once, ~6 ms of one core at 640x480 with
    12 LEDs, ran on the main thread at every solve (three per press) while the other core waited."""
    return bool(np.isfinite(image).all())
