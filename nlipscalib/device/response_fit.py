"""A camera's tone curve measured from an exposure bracket (``nlips calibrate-camera-response``): OpenCV's
``CalibrateRobertson`` fitted to frames of one still, lit scene at several exposure times, turned into the curve a
capture declares (:mod:`nlipscalib.core.response_curve`), or one line saying why the bracket cannot give one: the
channels' mean, or a curve per channel where they differ; checked against what the bracket itself says of the
camera (frames that brighten with the exposure, light that grows as the times' ratio, a dark frame at black).

Frames of more than 8 bits come binned to 8-bit codes (``cli.camera_response.to_codes``): OpenCV's
``CalibrateRobertson`` asserts 8-bit frames, and the 256-entry curve, interpolated between entries, undoes a 16-bit
camera's values within the fit's own error (benchmarks/RESULTS.md, s31-respcam).

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
    RESPONSE_BLACK_CODES,
    RESPONSE_CHANNEL_SPREAD,
    RESPONSE_CLIPPED_CODE,
    RESPONSE_DARK_CODE,
    RESPONSE_MAX_DIP,
    RESPONSE_MIN_EXPOSURES,
    RESPONSE_MIN_RISE,
    RESPONSE_MIN_WELL_EXPOSED,
    RESPONSE_RATIO_ERROR,
    RESPONSE_RATIO_LOW_CODE,
    RESPONSE_REACH_HIGH,
    RESPONSE_REACH_LOW,
    RESPONSE_RISE_PIXELS,
)

CODES = 256
"""8-bit codes: OpenCV's response calibration takes 8-bit frames only."""
TOP_FIT_CODES = 11
"""Codes below the highest one seen that a straight line is fitted through to extrapolate the curve to white."""
SMOOTH_CODES = 15
"""Consecutive codes the channels' curves are averaged over before they are compared (:func:`channel_difference`)."""
SAMPLED_PIXELS = 20000
"""Pixels the fit residual and the exposure-ratio check are measured on (a fixed, evenly spaced subset: the same
every run; all of a 640x480 bracket's would be 15 x 0.9 M samples, 110 MB an array)."""


@dataclasses.dataclass(frozen=True)
class ResponseFit:
    """A fitted camera response and how well the bracket pinned it."""

    curve: np.ndarray
    """(256,) float64, linear light (fraction of full scale, 0 at code 0, 1 at 255) of each 8-bit code: the channels'
    mean, monotonic."""
    kept: np.ndarray
    """The curve the response file records: :attr:`curve` when the channels agree within
    :data:`~nlipscalib.core.tolerances.RESPONSE_CHANNEL_SPREAD`, else (3, 256) float64, each channel's own curve
    (R, G, B), monotonic."""
    channels: np.ndarray
    """(256, 3) float64, each channel's curve (R, G, B) before the mean, NaN where the channel saw no code."""
    seen: tuple[int, int]
    """The lowest and highest codes below 255 the bracket saw (all channels)."""
    residual: float
    """RMS, fraction of full scale, of each well-exposed sample's linear value (the curve at its code) against its
    pixel's light times its exposure (the bracket's merged estimate): how consistent the bracket and the curve are."""
    channel_spread: float
    """Largest difference between the channels' curves over the codes seen, fraction of full scale."""
    channel_difference: float
    """The same once each curve is averaged over a few codes (:func:`channel_difference`): over
    :data:`~nlipscalib.core.tolerances.RESPONSE_CHANNEL_SPREAD`, each channel keeps its curve."""
    max_dip: float
    """Largest fall of the kept curve (of a channel's) from one code to the next before it was made monotonic."""
    ratio_error: float
    """Largest relative error of the light between two consecutive frames, the kept curve undone, against their
    exposures' ratio (:func:`check_exposure_ratios`): how well the frames' times are the times asked."""
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
        black to near white, a curve that falls, or frames whose light does not grow as their times
        (:func:`check_exposure_ratios`).
    """
    times = np.asarray(exposures_ms, dtype=np.float64)
    if len(frames) != len(times):
        raise ValueError(f"{len(frames)} frames for {len(times)} exposures")
    check_bracket(frames, times, source)
    order = np.argsort(times)
    frames = [np.ascontiguousarray(frames[i]) for i in order]
    times = times[order]
    check_follows(frames, times, source)
    channels = robertson_channels(frames, times, source)
    mean = channels_mean(channels)
    lit = np.isfinite(channels).all(axis=1)
    spread = float(np.nanmax(np.ptp(channels[lit], axis=1))) if lit.any() else 0.0
    # channels that differ beyond the fit's own error each keep their curve (a webcam's R, G and B often do); a
    # channel that missed a code takes the channels' mean there
    difference = channel_difference(channels)
    own = difference > RESPONSE_CHANNEL_SPREAD
    raw_kept = np.stack([_filled(np.where(np.isfinite(channels[:, c]), channels[:, c], mean)) for c in range(3)])
    kept, max_dip = _monotonic(raw_kept if own else mean[None], source)
    kept = kept if own else kept[0]
    seen = np.flatnonzero(np.isfinite(channels[1:-1]).any(axis=1)) + 1
    per_channel = np.broadcast_to(kept, (3, CODES))
    ratio_error = check_exposure_ratios(frames, times, per_channel, source)
    curve = kept.mean(axis=0) if own else kept
    residual, points = _residual(frames, times, per_channel)
    seen = (int(seen[0]), int(seen[-1]))
    return ResponseFit(curve, kept, channels, seen, residual, spread, difference, max_dip, ratio_error, points)


def robertson_channels(frames: Sequence[np.ndarray], times: np.ndarray, source: str) -> np.ndarray:
    """Each channel's curve as OpenCV's ``CalibrateRobertson`` fits it to ``frames`` at ``times``, normalised
    (:func:`_normalised`).

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, RGB (any height and width: a (1, P, 3) row of sampled pixels too)
    times : (E,) float64, ms, one per frame
    source : named in a refusal (codes that do not reach from near black to near white)

    Returns
    -------
    (256, 3) float64, linear light per code and channel (R, G, B), NaN where the channel saw no code
    """
    cv2 = require("cv2", "opencv-python-headless", "Measuring a camera's response")
    # OpenCV takes BGR or RGB alike (per channel), seconds as float32
    raw = cv2.createCalibrateRobertson().process(list(frames), (times / 1000.0).astype(np.float32))
    raw = raw.reshape(CODES, 3).astype(np.float64)
    return np.stack([_normalised(raw[:, c], _seen_codes(frames, c), source) for c in range(3)], axis=1)


def channels_mean(channels: np.ndarray) -> np.ndarray:
    """(256,) float64, the channels' mean curve of :func:`robertson_channels`' (256, 3): a code one channel never
    saw takes the others' curve; one none saw is interpolated between its neighbours."""
    known = np.isfinite(channels)
    count = known.sum(axis=1)
    total = np.where(known, channels, 0.0).sum(axis=1)
    return _filled(np.divide(total, count, out=np.full(CODES, np.nan), where=count > 0))


def channel_difference(channels: np.ndarray) -> float:
    """How far apart the channels' curves are, fraction of full scale: the largest difference between them, over
    the codes every channel saw, once each is averaged over :data:`SMOOTH_CODES` consecutive such codes. A camera's
    channels that respond differently do so over a span of codes; the fit's noise differs from code to code, and
    the average takes most of it out (the emulated sensor's one curve, full stops at 64x48: 0.013 code by code).

    Parameters
    ----------
    channels : (256, 3) float64, each channel's fitted curve, NaN where it saw no code

    Returns
    -------
    float (0 when fewer codes than :data:`SMOOTH_CODES` were seen by every channel)
    """
    lit = channels[np.isfinite(channels).all(axis=1)]
    if len(lit) < SMOOTH_CODES:
        return 0.0
    box = np.ones(SMOOTH_CODES) / SMOOTH_CODES
    smooth = np.stack([np.convolve(lit[:, c], box, mode="valid") for c in range(3)], axis=1)
    return float(np.ptp(smooth, axis=1).max())


def _monotonic(curves: np.ndarray, source: str) -> tuple[np.ndarray, float]:
    """(C, 256) curves made monotonic (the running maximum), 0 at code 0 and 1 at 255, and their largest fall
    before; CaptureError naming ``source`` when one falls by more than
    :data:`~nlipscalib.core.tolerances.RESPONSE_MAX_DIP`."""
    dips = np.diff(curves, axis=1)
    max_dip = float(max(0.0, -dips.min()))
    if max_dip > RESPONSE_MAX_DIP:
        c, at = np.unravel_index(int(np.argmin(dips)), dips.shape)
        which = f" ({'RGB'[c]})" if len(curves) == 3 else ""
        raise CaptureError(
            f"{source}: the fitted response{which} falls by {max_dip:.3f} of full scale at code {at + 1} (a camera's "
            "response never does): the scene moved or its light changed during the bracket, or the camera's "
            "exposure did not follow; keep it still and retake"
        )
    out = np.clip(np.maximum.accumulate(curves, axis=1), 0.0, 1.0)
    out[:, 0], out[:, -1] = 0.0, 1.0
    return out, max_dip


def check_exposure_ratios(frames: Sequence[np.ndarray], times: np.ndarray, curves: np.ndarray, source: str) -> float:
    """The largest relative error of the light between consecutive frames against their exposures' ratio; one line
    naming ``source`` and the frame when it is over :data:`~nlipscalib.core.tolerances.RESPONSE_RATIO_ERROR`.

    Why: a camera that rounds the exposures asked to steps of its own (asked 16.7 ms, took 20; a shutter table not
    the one assumed) still brightens at every step, and the fit takes each frame at the time asked: the curve bends
    to absorb it. With the fitted curve undone, the light of two consecutive frames must differ by their
    exposures' ratio; a frame taken at another time is too bright against the one before it and too dark against
    the one after. Each pixel's light is the bracket's merged estimate (:func:`_merged_light`), which picks the
    pixels compared without the selection bias of one frame's noise. A time error that is a power of the asked
    time at every step (t_real = c * t ** a) is not seen: it is a gamma of the curve (the exponential ambiguity of
    a bracket of unknown exposures), and the curve then absorbs it, as any bracket would.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, sorted by exposure
    times : (E,) float64, ms, ascending
    curves : (3, 256) float64, each channel's fitted curve (R, G, B)
    source : named in the refusal

    Returns
    -------
    float, the largest relative error over the pairs judged (0 when none could be)
    """
    errors = np.nan_to_num(ratio_errors(frames, times, curves, RESPONSE_RATIO_LOW_CODE))
    worst = int(np.argmax(np.abs(errors)))
    if abs(errors[worst]) > RESPONSE_RATIO_ERROR:
        ratio = times[1:] / times[:-1]
        pairs = "; ".join(
            f"the frame at {times[k + 1]:g} ms is {ratio[k] * (1 + errors[k]):.3f} times as bright as at {times[k]:g} "
            f"ms, its exposure {ratio[k]:.3f} times as long"
            for k in np.flatnonzero(np.abs(errors) > RESPONSE_RATIO_ERROR)[:2]
        )
        raise CaptureError(
            f"{source}: with the fitted curve undone, {pairs} (more than {RESPONSE_RATIO_ERROR:.1%} apart): the "
            "camera took another time than asked (it rounds exposures to steps of its own), and a fit at the times "
            "asked bends the curve: give the times it takes (`v4l2-ctl -d /dev/videoN -L` lists them) as "
            "--exposures-ms, or the times it took in the --bracket folder's exposures.csv"
        )
    return float(np.abs(errors).max())


def ratio_errors(frames: Sequence[np.ndarray], times: np.ndarray, curves: np.ndarray, low_code: int) -> np.ndarray:
    """Each pair of consecutive frames' light, the curves undone, against their exposures' ratio: the ratio of the
    two frames' summed linear values over the pixels whose merged light (:func:`_merged_light`) puts them at
    ``low_code`` or above in the darker frame and below clipping in the brighter, over the times' ratio, minus 1.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, sorted by exposure
    times : (E,) float64, ms, ascending
    curves : (3, 256) float64, each channel's curve (R, G, B)
    low_code : 8-bit code

    Returns
    -------
    (E - 1,) float64, relative error per pair; NaN where too few pixels judge it (both frames dark or clipped)
    """
    _, linear, light = _merged_light(frames, times, curves, _sample_step(frames))
    low = curves[np.arange(3), low_code]  # each channel's light at that code
    high = curves[np.arange(3), RESPONSE_CLIPPED_CODE - 1]
    errors = np.full(len(times) - 1, np.nan)
    for k in range(len(times) - 1):
        use = (light * times[k] >= low) & (light * times[k + 1] <= high)
        if use.mean() >= RESPONSE_RISE_PIXELS:
            errors[k] = linear[k + 1][use].sum() / linear[k][use].sum() / (times[k + 1] / times[k]) - 1.0
    return errors


def check_bracket(frames: Sequence[np.ndarray], times: np.ndarray, source: str) -> None:
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


def check_black(dark: np.ndarray, exposure_ms: float | None, source: str, black_dn: float, dn_per_code: float) -> float:
    """The median 8-bit code of a frame with every LED off (at the bracket's shortest exposure, where room light
    adds least), above the black level given; one line naming ``source`` when it is over
    :data:`~nlipscalib.core.tolerances.RESPONSE_BLACK_CODES`.

    Why: a camera that adds a constant (its black level, a pedestal) to every frame gives codes that are no light
    at all; the fit takes the lowest of them for light, its curve's zero moves up to that code without a word, and
    the file says it was measured from a black level the camera does not have (a capture at the camera's real
    --black-level is then refused, one at the wrong one keeps the offset's noise clipped). Read noise around the
    right black gives a median of 0: half the pixels fall below black and are clipped there.

    Parameters
    ----------
    dark : (H, W, 3) uint8, codes above the black level given (``cli.camera_response.to_codes``)
    exposure_ms : the dark frame's exposure, ms (None: not known, a --bracket folder's ``dark.png``)
    source : named in the refusal
    black_dn : the black level given, the camera's DN (--black-level)
    dn_per_code : the camera's DN per 8-bit code, to name the black level to give

    Returns
    -------
    float, the median code
    """
    median = float(np.median(dark))
    if median > RESPONSE_BLACK_CODES:
        black = black_dn + median * dn_per_code
        at = "" if exposure_ms is None else f", {exposure_ms:g} ms"
        raise CaptureError(
            f"{source}: the dark frame (every LED off{at}) reads {median:g} codes of 255 (median) "
            f"above --black-level {black_dn:g}: the camera adds a black level to every frame, which the fit would "
            f"take for light: give --black-level {black:.0f} (its DN) and retake (or light other than the LEDs "
            "reaches the gel: darken the room)"
        )
    return median


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


def _sample_step(frames: Sequence[np.ndarray]) -> int:
    """Every how many pixels one is sampled: :data:`SAMPLED_PIXELS` of a frame, or all of a smaller one."""
    return max(1, frames[0].shape[0] * frames[0].shape[1] // SAMPLED_PIXELS)


def _merged_light(
    frames: Sequence[np.ndarray], times: np.ndarray, curves: np.ndarray, step: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bracket's samples (every ``step``-th pixel), their linear values and each pixel's merged light.

    Each pixel's light (per channel) is the weighted mean of ``curve(code) / time`` over its exposures (hat
    weights: the curve is least sure near black and clipping, as Robertson's fit weighs it).

    Returns
    -------
    codes : (E, P, 3) uint8
    linear : (E, P, 3) float64, each sample's channel's curve at its code
    light : (P, 3) float64, linear value per ms (0 where no sample of the pixel is well exposed)
    """
    stack = np.stack([f.reshape(-1, 3) for f in frames])[:, ::step]  # (E, P, 3)
    linear = np.stack([curves[c][stack[..., c]] for c in range(3)], axis=-1)
    well = (stack > RESPONSE_DARK_CODE) & (stack < RESPONSE_CLIPPED_CODE)
    weight = np.where(well, np.minimum(stack, 255 - stack).astype(np.float64), 0.0)
    t = times[:, None, None]
    total = weight.sum(axis=0)
    light = np.divide((weight * linear / t).sum(axis=0), total, out=np.zeros(total.shape), where=total > 0)
    return stack, linear, light


def _residual(
    frames: Sequence[np.ndarray], times: np.ndarray, curves: np.ndarray
) -> tuple[float, tuple[np.ndarray, np.ndarray]]:
    """RMS misfit (fraction of full scale) of the well-exposed samples of an evenly spaced pixel subset, and the
    green channel's (code, estimated linear value) pairs for the figure: each sample's estimate is its pixel's
    merged light (:func:`_merged_light`, ``curves`` (3, 256) per channel) times its exposure."""
    codes, linear, light = _merged_light(frames, times, curves, _sample_step(frames))
    well = (codes > RESPONSE_DARK_CODE) & (codes < RESPONSE_CLIPPED_CODE)
    estimate = light[None] * times[:, None, None]
    use = well & (light > 0)[None]
    residual = float(np.sqrt(np.mean((linear - estimate)[use] ** 2))) if use.any() else float("nan")
    green = use[..., 1]
    return residual, (codes[..., 1][green].astype(np.uint8), estimate[..., 1][green])
