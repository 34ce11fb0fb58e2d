"""Whether a frame offered as the sensor's undeformed frame now (``nlips infer --reference``) shows a press.

Why: the refresh (``learn.infer.Predictor.refresh``) multiplies every later frame by the calibration's reference
frame over the one given. A frame taken while something touched the gel carries its dent into that gain: every
later frame is judged against a dented reference, and its unchanged pixels keep the reference normals, wrong ones.
Nothing said so.

What tells a press from what the refresh is for (benchmarks/RESULTS.md, s34-inferref), compared with the
calibration's reference frame that the model file carries:

- a press changes the pixels of a compact patch far beyond the rest of the frame: the change rule that finds a
  frame's contact (:class:`.change.ChangeDetector`, the same rule, the same thresholds) finds it; dimmed LEDs, a
  drifted exposure and noise change the frame smoothly and find nothing there, but a scuffed coating does
  (it darkens a patch);
- a press tilts the surface, so the mix of the three LED groups' light changes: the patch's *colour* moves, not
  only its brightness. A scuff darkens all three alike; an LED dimmed with age moves the colour, but as its
  share of its colour's light on the undeformed dome does (the image model, :class:`LedShares`), and smoothly.
  :func:`colour_patch` fits each LED's gain to that share, takes each pixel's brightness out, then a broad smooth
  field, and keeps what stands out of its own noise.

A press is where both agree, in one piece of at least :data:`~nlipscalib.core.tolerances.REFERENCE_PRESS_SHARE` of
the gel."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core import masks
from ..core.camera import Camera, depth_to_points
from ..core.errors import ShapeError, require
from ..core.leds import Led, led_shading
from ..core.robust_scale import mad_scale
from ..core.tolerances import (
    REFERENCE_COLOUR_FIELD,
    REFERENCE_COLOUR_MIN,
    REFERENCE_COLOUR_SIGMAS,
    REFERENCE_PRESS_SHARE,
    REFRESH_SMOOTHING_PX,
)
from .change import ChangeDetector

CHECK_WIDTH = 160
"""The colour rule runs on the frames shrunk to about this width (:func:`_colour_patch_at_check_width`)."""
FIELD_PASSES = 2
"""Fits of the smooth colour field: the second leaves out what the first found (grown by :data:`FIELD_MARGIN_PX`),
so a large press does not pull the field toward itself."""
FIELD_MARGIN_PX = 6
"""Pixels around what the first pass found that the second fit leaves out too (a contact's soft rim)."""


@dataclasses.dataclass(frozen=True)
class LedShares:
    """Where each LED lights the undeformed gel: what an LED that aged on its own does to the colours.

    Why: an LED dims the light of its colour by its share of that colour's light at each pixel, which changes fast
    near it; a smooth field alone could not follow one LED at half its light and left patches of 0.6-2.9 % of the
    gel by it (s34-inferref). Made from the model file's record of its sensor and undeformed dome."""

    camera: Camera
    depth: np.ndarray
    """(H, W) float, mm -- camera-frame z of the undeformed gel (NaN off it)."""
    normals: np.ndarray
    """(H, W, 3) float, unit, toward the camera."""
    leds: tuple[Led, ...]
    """The LEDs (positions and directions; the image model's defaults otherwise)."""
    groups: np.ndarray
    """(L,) int -- each LED's colour in the tri-colour frame (0 red, 1 green, 2 blue)."""

    @classmethod
    def of_model(cls, sensor: dict, reference: dict) -> LedShares | None:
        """From a model file's ``sensor`` and ``reference`` records (``learn.model.LoadedModel``); None for a
        model that records no LED positions (made before they were recorded)."""
        if "led_positions" not in sensor or "led_directions" not in sensor:
            return None
        leds = tuple(Led(tuple(p), tuple(d)) for p, d in zip(sensor["led_positions"], sensor["led_directions"]))
        return cls(
            Camera.from_dict(sensor["camera"]),
            np.asarray(reference["depth"], np.float64),
            np.asarray(reference["normals"], np.float64),
            leds,
            np.asarray(sensor["tricolor_groups"], int),
        )

    def shares(self, factor: int, shape: tuple[int, int]) -> np.ndarray:
        """(L, h, w) float32: each LED's share of its colour's light at the centres of ``factor``-pixel blocks
        (``shape`` (h, w) of them), 0 off the gel."""
        h, w = shape
        rows, cols = np.mgrid[0:h, 0:w]
        centre = factor * np.stack([cols, rows], -1).astype(np.float64) + (factor - 1) / 2
        near = np.clip(np.rint(centre).astype(int), 0, [self.depth.shape[1] - 1, self.depth.shape[0] - 1])
        depth = self.depth[near[..., 1], near[..., 0]]
        on_gel = np.isfinite(depth)
        points = depth_to_points(np.where(on_gel, depth, 1.0), self.camera.unproject(centre))
        normals = np.where(on_gel[..., None], self.normals[near[..., 1], near[..., 0]], (0.0, 0.0, 1.0))
        light = led_shading(points[on_gel], normals[on_gel], self.leds)[..., 0]  # (L, N): albedo and colour alike
        out = np.zeros((len(self.leds), h, w), np.float32)
        for colour in np.unique(self.groups):
            group = self.groups == colour
            with np.errstate(divide="ignore", invalid="ignore"):
                part = light[group] / light[group].sum(0)
            out[np.flatnonzero(group)[:, None], on_gel] = np.nan_to_num(part)
        return out


@dataclasses.dataclass(frozen=True)
class PressInFrame:
    """A press found in a frame offered as the undeformed one."""

    share: float
    """The patch's area over the gel's, 0-1."""
    box: tuple[int, int, int, int]
    """(x0, y0, width, height), pixels: the patch's bounding box in the image."""
    mask: np.ndarray
    """(H, W) bool -- the patch."""


def press_in_frame(
    calibration: np.ndarray, frame: np.ndarray, valid: np.ndarray, leds: LedShares | None = None
) -> PressInFrame | None:
    """The press a frame of the undeformed sensor shows, or None (the module docstring says how it is told).

    Parameters
    ----------
    calibration : (H, W, 3) float32, linear -- the calibration's reference frame (the model file's)
    frame : (H, W, 3) float32, linear -- the frame offered as the undeformed sensor now
    valid : (H, W) bool -- pixels that see the gel
    leds : the sensor's LEDs on its undeformed dome (:meth:`LedShares.of_model`); None: the smooth field alone

    Returns
    -------
    The largest patch both rules find, when it covers at least ``REFERENCE_PRESS_SHARE`` of the gel; else None.
    """
    if calibration.shape != frame.shape or frame.shape[:2] != valid.shape or frame.shape[-1:] != (3,):
        raise ShapeError(f"frames {calibration.shape} and {frame.shape} and the gel {valid.shape} must match")
    valid = np.asarray(valid, bool)
    gel = int(valid.sum())
    if gel == 0:
        return None
    # each colour brought to the calibration's level first: an LED group dimmed, or another exposure, changes the
    # whole gel, and the change rule then finds no patch against it (a 10 % dimmer red hid a press)
    with np.errstate(divide="ignore", invalid="ignore"):
        level = np.nanmedian(np.where(valid[..., None], calibration / frame, np.nan).reshape(-1, 3), axis=0)
    level = np.where(np.isfinite(level) & (level > 0), level, 1.0).astype(np.float32)
    changed = ChangeDetector(calibration, valid)(frame * level)
    both = changed & _colour_patch_at_check_width(calibration, frame, valid, leds)
    if not both.any():
        return None
    cv2 = require("cv2", "opencv-python-headless", "Checking a reference frame")
    count, labels, stats, _ = cv2.connectedComponentsWithStats(both.view(np.uint8), connectivity=8)
    largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    share = float(stats[largest, cv2.CC_STAT_AREA]) / gel
    if share < REFERENCE_PRESS_SHARE:
        return None
    x, y, w, h = (
        int(stats[largest, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT)
    )
    return PressInFrame(share, (x, y, w, h), labels == largest)


def _colour_patch_at_check_width(
    calibration: np.ndarray, frame: np.ndarray, valid: np.ndarray, leds: LedShares | None
) -> np.ndarray:
    """:func:`colour_patch` on the frames shrunk by a whole factor to about :data:`CHECK_WIDTH` pixels across (area
    means), brought back to their size (each pixel its block's answer; the rows and columns the factor leaves over
    at the right and bottom are never found).

    Why: the smooth field's Gaussian spans a tenth of the image; at 640x480 its passes took 0.7-0.9 s, 70-90 ms
    shrunk, with the same verdicts on the 640x480 twin (sphere1 10.1 % of the gel at full size, 10.9 % shrunk; the
    thresholds were measured at 160x120)."""
    factor = max(1, valid.shape[1] // CHECK_WIDTH)
    h, w = (n // factor for n in valid.shape)
    shares = None if leds is None else (leds.shares(factor, (h, w)), leds.groups)
    if factor == 1:
        return colour_patch(calibration, frame, valid, shares)
    cv2 = require("cv2", "opencv-python-headless", "Checking a reference frame")
    crop = (slice(0, h * factor), slice(0, w * factor))

    def shrink(image: np.ndarray) -> np.ndarray:
        return cv2.resize(image[crop], (w, h), interpolation=cv2.INTER_AREA)

    gel = shrink(valid.astype(np.float32)) == 1  # blocks wholly on the gel
    small = colour_patch(shrink(calibration), shrink(frame), gel, shares)
    out = np.zeros(valid.shape, bool)
    out[crop] = np.repeat(np.repeat(small, factor, 0), factor, 1)
    return out & valid


def colour_patch(
    calibration: np.ndarray,
    frame: np.ndarray,
    valid: np.ndarray,
    shares: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """(H, W) bool -- gel pixels whose colour (not brightness) moved from the calibration's frame by more than a
    smooth field over the gel explains (the module docstring: a press's tilt, not an aged LED or a scuff).

    The colour: each channel's log ratio of the two frames (each smoothed by ``REFRESH_SMOOTHING_PX``, as the
    refresh smooths them), less that of the LED gains that best explain the ratio (``shares``: (L, H, W) each LED's
    share of its colour's light, (L,) its colour, :meth:`LedShares.shares`; least squares per colour), less the three
    colours' mean. The field: that colour smoothed over the gel by
    ``REFERENCE_COLOUR_FIELD`` of the image's width (:data:`FIELD_PASSES`). A pixel stands out when its distance
    from the field exceeds the gel's median by ``REFERENCE_COLOUR_SIGMAS`` robust sigmas and
    ``REFERENCE_COLOUR_MIN``; isolated pixels are dropped (an opening)."""
    cv2 = require("cv2", "opencv-python-headless", "Checking a reference frame")
    # the gel less its outermost pixels, whose smoothed values mix in the dark beyond it
    gel = cv2.erode(valid.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & valid
    if not gel.any():  # a gel a few pixels across: no colour to compare
        return gel
    old, new = (smooth_on_gel(f, valid, REFRESH_SMOOTHING_PX) for f in (calibration, frame))
    tiny = np.float32(1e-6)
    ratio = np.maximum(new, tiny) / np.maximum(old, tiny)
    sigma = REFERENCE_COLOUR_FIELD * valid.shape[1]
    fitted, found = gel, np.zeros_like(gel)
    for _ in range(FIELD_PASSES):
        colour = np.log(ratio / _led_gains(ratio, shares, fitted)) if shares is not None else np.log(ratio)
        colour -= colour.mean(-1, keepdims=True)  # brightness out: a scuff, an exposure, LEDs dimmed alike
        distance = np.linalg.norm(colour - smooth_on_gel(colour, fitted, sigma), axis=-1)
        sample = distance[gel]
        median = float(np.median(sample))
        spread = mad_scale(sample, center=median)
        found = gel & (distance > median + REFERENCE_COLOUR_SIGMAS * spread) & (distance > REFERENCE_COLOUR_MIN)
        found = masks.dilate(masks.erode(found))
        if not found.any():
            break
        fitted = gel & ~masks.dilate(found, iterations=FIELD_MARGIN_PX)
    return found


def _led_gains(ratio: np.ndarray, shares: tuple[np.ndarray, np.ndarray], fitted: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: each colour's ratio that per-LED gains explain, sum of gain x share over the colour's
    LEDs, the gains fitted by least squares to ``ratio`` ((H, W, 3)) at the ``fitted`` pixels; 1 where it is not
    positive (a colour no LED of the record lights)."""
    share, groups = shares
    out = np.ones_like(ratio)
    for colour in range(ratio.shape[-1]):
        group = np.flatnonzero(groups == colour)
        if not len(group):
            continue
        gains, *_ = np.linalg.lstsq(share[group][:, fitted].T, ratio[..., colour][fitted], rcond=None)
        explained = np.tensordot(gains.astype(np.float32), share[group], 1)
        out[..., colour] = np.where(explained > 0, explained, 1.0)
    return out


def smooth_on_gel(image: np.ndarray, valid: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W, C) float32: ``image`` ((H, W, C) float) Gaussian-smoothed (``sigma``, pixels) over ``valid`` only,
    normalised by its own weight there, so the pixels beyond it do not darken its rim; 0 where no ``valid`` pixel
    is near."""
    cv2 = require("cv2", "opencv-python-headless", "Smoothing a frame on the gel")
    weight = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), sigma)
    blurred = cv2.GaussianBlur(np.where(valid[..., None], image, 0).astype(np.float32), (0, 0), sigma)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(weight[..., None] > 0, blurred / weight[..., None], 0).astype(np.float32)
