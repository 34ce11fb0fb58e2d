"""A camera's tone curve measured from an exposure bracket (``nlips calibrate-camera-response``): OpenCV's
``CalibrateRobertson`` fitted to frames of one still, lit scene at several exposure times, turned into the curve a
capture declares (:mod:`nlipscalib.core.response_curve`), or one line saying why the bracket cannot give one.

Why Robertson, not Debevec: on the emulated sensor's bracket Debevec's 70 random samples and its smoothness prior
left ripples of 1-2 % of full scale (up to 5 % with the gel lit evenly); Robertson's maximum-likelihood fit over
every pixel recovers gamma 2.2 within 0.5 % (benchmarks/RESULTS.md, s30-response). Named here, not in core: the fit
needs OpenCV, as the camera does."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..core.errors import CaptureError, require
from ..core.tolerances import (
    RESPONSE_CLIPPED_CODE,
    RESPONSE_DARK_CODE,
    RESPONSE_MAX_DIP,
    RESPONSE_MIN_EXPOSURES,
    RESPONSE_MIN_RISE,
    RESPONSE_MIN_WELL_EXPOSED,
    RESPONSE_REACH_HIGH,
    RESPONSE_REACH_LOW,
    RESPONSE_RISE_PIXELS,
)

CODES = 256
"""8-bit codes: OpenCV's response calibration takes 8-bit frames only."""
TOP_FIT_CODES = 11
"""Codes below the highest one seen that a straight line is fitted through to extrapolate the curve to white."""
RESIDUAL_PIXELS = 20000
"""Pixels the fit residual is measured on (a fixed, evenly spaced subset: the same every run)."""


@dataclasses.dataclass(frozen=True)
class ResponseFit:
    """A fitted camera response and how well the bracket pinned it."""

    curve: np.ndarray
    """(256,) float64, linear light (fraction of full scale, 0 at code 0, 1 at 255) of each 8-bit code: the channels'
    mean, monotonic."""
    channels: np.ndarray
    """(256, 3) float64, each channel's curve (R, G, B) before the mean, NaN where the channel saw no code."""
    seen: tuple[int, int]
    """The lowest and highest codes below 255 the bracket saw (all channels)."""
    residual: float
    """RMS, fraction of full scale, of each well-exposed sample's linear value (the curve at its code) against its
    pixel's light times its exposure (the bracket's merged estimate): how consistent the bracket and the curve are."""
    channel_spread: float
    """Largest difference between the channels' curves over the codes seen, fraction of full scale."""
    max_dip: float
    """Largest fall of the mean curve from one code to the next before it was made monotonic (0: none)."""
    points: tuple[np.ndarray, np.ndarray]
    """(codes (M,) uint8, linear (M,) float64): measured samples (green channel) for the figure, the bracket's
    estimate of each sample's light times its exposure over the curve's full scale."""


def fit_response(frames: Sequence[np.ndarray], exposures_ms: Sequence[float], source: str) -> ResponseFit:
    """The camera response of an exposure bracket.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, RGB, one frame of the same still scene per exposure, as the camera encoded
        it (its 8-bit codes)
    exposures_ms : the exposure time of each frame, ms (> 0, all different)
    source : what the frames came from, named in every refusal (a camera, ``--emulate SCENE``)

    Returns
    -------
    ResponseFit

    Raises
    ------
    CaptureError -- one line naming ``source``: too few exposures, the scene black or clipped in too many of them,
        frames that do not brighten as the exposure grows (:func:`check_follows`), codes not reaching from near
        black to near white, or a curve that falls.
    """
    cv2 = require("cv2", "opencv-python-headless", "Measuring a camera's response")
    times = np.asarray(exposures_ms, dtype=np.float64)
    if len(frames) != len(times):
        raise ValueError(f"{len(frames)} frames for {len(times)} exposures")
    _check_bracket(frames, times, source)
    order = np.argsort(times)
    frames = [np.ascontiguousarray(frames[i]) for i in order]
    times = times[order]
    check_follows(frames, times, source)
    # OpenCV takes BGR or RGB alike (per channel), seconds as float32
    raw = cv2.createCalibrateRobertson().process(frames, (times / 1000.0).astype(np.float32))
    raw = raw.reshape(CODES, 3).astype(np.float64)
    channels = np.stack([_normalised(raw[:, c], _seen_codes(frames, c), source) for c in range(3)], axis=1)
    known = np.isfinite(channels)
    count = known.sum(axis=1)
    total = np.where(known, channels, 0.0).sum(axis=1)
    # a code one channel never saw: the others' curve; none saw it: interpolated between its neighbours
    mean = _filled(np.divide(total, count, out=np.full(CODES, np.nan), where=count > 0))
    dips = np.diff(mean)
    max_dip = float(max(0.0, -dips.min()))
    if max_dip > RESPONSE_MAX_DIP:
        at = int(np.argmin(dips)) + 1
        raise CaptureError(
            f"{source}: the fitted response falls by {max_dip:.3f} of full scale at code {at} (a camera's response "
            "never does): the scene moved or its light changed during the bracket, or the camera's exposure did "
            "not follow; keep it still and retake"
        )
    curve = np.clip(np.maximum.accumulate(mean), 0.0, 1.0)
    curve[0], curve[-1] = 0.0, 1.0
    seen = np.flatnonzero(np.isfinite(channels[1:-1]).any(axis=1)) + 1
    lit = np.isfinite(channels).all(axis=1)
    spread = float(np.nanmax(np.ptp(channels[lit], axis=1))) if lit.any() else 0.0
    residual, points = _residual(frames, times, curve)
    return ResponseFit(curve, channels, (int(seen[0]), int(seen[-1])), residual, spread, max_dip, points)


def _check_bracket(frames: Sequence[np.ndarray], times: np.ndarray, source: str) -> None:
    """One line naming ``source`` when the bracket cannot give a curve: too few exposures, repeated ones, frames
    that are no 8-bit images of one size, or too few frames that are neither black nor clipped on the gel."""
    check_exposures(times, source)
    shape = frames[0].shape
    if any(f.dtype != np.uint8 or f.shape != shape or f.ndim != 3 or f.shape[2] != 3 for f in frames):
        raise ValueError("bracket frames must be (H, W, 3) uint8 of one size")
    well = [((f > RESPONSE_DARK_CODE) & (f < RESPONSE_CLIPPED_CODE)).mean() >= 0.5 for f in frames]
    if sum(well) < RESPONSE_MIN_WELL_EXPOSED:
        black = sum(bool((f <= RESPONSE_DARK_CODE).mean() >= 0.5) for f in frames)
        clipped = sum(bool((f >= RESPONSE_CLIPPED_CODE).mean() >= 0.5) for f in frames)
        raise CaptureError(
            f"{source}: only {sum(well)} of {len(frames)} exposures are well exposed ({black} black, {clipped} "
            f"saturated), at least {RESPONSE_MIN_WELL_EXPOSED} are needed: give exposures from where the lit gel is "
            "dark to where it just clips (--exposures-ms), or change the LED level (--level)"
        )


def rises(frames: Sequence[np.ndarray]) -> list[float | None]:
    """How much brighter each frame is than the one before it: the mean of their difference, 8-bit codes, over the
    samples whose mean code of the two is neither black nor clipped (a symmetric mask: two frames of one exposure
    rise by their noise's mean, ~0). None where too few samples are (both frames black or both clipped).

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, in the order of their exposure times

    Returns
    -------
    list of len(frames) - 1 floats (codes) or None
    """
    out: list[float | None] = []
    for low, high in zip(frames[:-1], frames[1:], strict=True):
        lo, hi = low.astype(np.int16), high.astype(np.int16)
        middle = lo + hi  # twice the pair's mean code
        use = (middle > 2 * RESPONSE_DARK_CODE) & (middle < 2 * RESPONSE_CLIPPED_CODE)
        out.append(float((hi - lo)[use].mean()) if use.mean() >= RESPONSE_RISE_PIXELS else None)
    return out


def check_follows(frames: Sequence[np.ndarray], times: np.ndarray, source: str) -> None:
    """One line naming ``source`` when the frames do not brighten as the exposure grows: the camera ignored the
    exposure asked (auto exposure it cannot turn off, a backend that drops the property: every frame equally
    bright), took two asked exposures as one (it quantises them), or its frames lag the setting (the first frames
    repeat). A fit would take them at the times asked and write a wrong curve.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, sorted by exposure
    times : (E,) float64, ms, ascending
    source : named in the refusal
    """
    steps = rises(frames)
    judged = [k for k, r in enumerate(steps) if r is not None]
    flat = [k for k in judged if steps[k] < RESPONSE_MIN_RISE]
    if not flat:
        return
    if len(flat) == len(judged):
        raise CaptureError(
            f"{source}: the bracket's frames are all equally bright from {times[0]:g} to {times[-1]:g} ms (mean "
            f"rise {max(steps[k] for k in judged):.2f} codes a step at most): the camera did not take the exposures "
            "asked (its auto exposure is on, or it ignores OpenCV's exposure): switch auto exposure off (Linux: "
            "`v4l2-ctl -d /dev/videoN -c auto_exposure=1`, older drivers exposure_auto=1; else the vendor's tool) "
            "and retake"
        )
    falls = [k for k in flat if steps[k] < -RESPONSE_MIN_RISE]
    if falls:
        k = falls[0]
        raise CaptureError(
            f"{source}: the bracket's frame at {times[k + 1]:g} ms is darker than at {times[k]:g} ms ({steps[k]:+.2f} "
            "codes): its frames lag the exposure setting (a larger --flush), its exposure did not follow (auto "
            "exposure on?), or the scene moved or its light changed during the bracket; keep it still and retake"
        )
    pairs = ", ".join(f"{times[k]:g} and {times[k + 1]:g} ms ({steps[k]:+.2f} codes)" for k in flat)
    raise CaptureError(
        f"{source}: the bracket's frames at {pairs} are equally bright (a longer exposure brightens by at least "
        f"{RESPONSE_MIN_RISE:g} codes): the camera took them at one exposure, so a fit at the times asked is wrong: "
        "the frames lag the exposure setting (a larger --flush), or the camera quantises its exposure (list its "
        "steps, e.g. `v4l2-ctl -d /dev/videoN -L`, and give --exposures-ms it honours), or the exposures are too "
        "close (space them wider)"
    )


def check_exposures(exposures_ms: Sequence[float], source: str) -> None:
    """One line naming ``source`` when a bracket of these exposures (ms) cannot give a curve: fewer than
    :data:`~nlipscalib.core.tolerances.RESPONSE_MIN_EXPOSURES` different ones, or one not > 0. Called before a
    bracket is taken, too: nothing is lit or rendered for a bracket refused anyway."""
    times = np.asarray(exposures_ms, dtype=np.float64)
    if len(set(times.tolist())) < RESPONSE_MIN_EXPOSURES or not (times > 0).all():
        raise CaptureError(
            f"{source}: a bracket needs at least {RESPONSE_MIN_EXPOSURES} different exposures > 0 ms, got "
            f"{', '.join(f'{t:g}' for t in times)}"
        )


def _seen_codes(frames: Sequence[np.ndarray], channel: int) -> np.ndarray:
    """(256,) bool: which codes of ``channel`` the bracket holds."""
    seen = np.zeros(CODES, bool)
    for f in frames:
        seen[np.unique(f[..., channel])] = True
    return seen


def _normalised(raw: np.ndarray, seen: np.ndarray, source: str) -> np.ndarray:
    """One channel's Robertson response (arbitrary scale, NaN where no sample fell) as linear fractions of full
    scale: 0 at code 0 (zero light is black), 1 at 255, extrapolated from the highest codes seen below 255 (255
    itself collects every clipped sample, so its value is no response). NaN where the channel saw no code."""
    usable = seen & np.isfinite(raw) & (np.arange(CODES) < CODES - 1) & (np.arange(CODES) > 0)
    codes = np.flatnonzero(usable)
    if len(codes) < TOP_FIT_CODES or codes[0] > RESPONSE_REACH_LOW or codes[-1] < RESPONSE_REACH_HIGH:
        lo, hi = (int(codes[0]), int(codes[-1])) if len(codes) else (None, None)
        raise CaptureError(
            f"{source}: the bracket's codes reach from {lo} to {hi}; a curve needs codes from "
            f"{RESPONSE_REACH_LOW} or below to {RESPONSE_REACH_HIGH} or above (below and above them it is "
            "guessed): add shorter and longer exposures (--exposures-ms)"
        )
    top = codes[-TOP_FIT_CODES:]
    slope, offset = np.polyfit(top.astype(np.float64), raw[top], 1)
    white = slope * (CODES - 1) + offset
    out = np.full(CODES, np.nan)
    out[0] = 0.0
    out[codes] = raw[codes] / white
    out[CODES - 1] = 1.0
    return out


def _filled(curve: np.ndarray) -> np.ndarray:
    """``curve`` with its NaN codes (seen by no channel) interpolated linearly between the codes around them."""
    known = np.isfinite(curve)
    codes = np.arange(CODES)
    return np.interp(codes, codes[known], curve[known])


def _residual(
    frames: Sequence[np.ndarray], times: np.ndarray, curve: np.ndarray
) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """RMS misfit (fraction of full scale) of the well-exposed samples of an evenly spaced pixel subset, and the
    green channel's (code, estimated linear value) pairs for the figure.

    Each pixel's light is the weighted mean of ``curve(code) / time`` over its exposures (hat weights: the curve is
    least sure near black and clipping, as Robertson's fit weighs it), then each sample's estimate is that light
    times its exposure."""
    stack = np.stack([f.reshape(-1, 3) for f in frames])  # (E, P, 3)
    step = max(1, stack.shape[1] // RESIDUAL_PIXELS)
    codes = stack[:, ::step]
    linear = curve[codes]
    well = (codes > RESPONSE_DARK_CODE) & (codes < RESPONSE_CLIPPED_CODE)
    weight = np.where(well, np.minimum(codes, 255 - codes).astype(np.float64), 0.0)
    t = times[:, None, None]
    total = weight.sum(axis=0)
    light = np.divide((weight * linear / t).sum(axis=0), total, out=np.zeros(total.shape), where=total > 0)
    estimate = light[None] * t
    use = well & (total > 0)[None]
    residual = float(np.sqrt(np.mean((linear - estimate)[use] ** 2))) if use.any() else float("nan")
    green = use[..., 1]
    return residual, (codes[..., 1][green].astype(np.uint8), estimate[..., 1][green])
