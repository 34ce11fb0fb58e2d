"""The exposure times a bracket folder's frames were really taken at, estimated from the frames themselves
(``nlips calibrate-camera-response --bracket FOLDER`` without ``additivity/`` frames): for a camera that rounds the
times named to steps of its own without a word (a 1/n s shutter table: 16, 32, 64 ms taken as 1/60, 1/30, 1/15 s).

How: the curve and the times are fitted in turn (Robertson-style, with unknown exposure ratios, as Mitsunaga and
Nayar estimate them): OpenCV's ``CalibrateRobertson`` at the times so far, then each consecutive pair's light, the
curve undone (``response_fit.ratio_errors``), moves that step's ratio. The curve alone absorbs about half of one
step's error (the 1/n s table's 4.2 % shows as 1.9 %); the rounds take the rest out. What no bracket can tell is a
power of every time (``t_real = c * t ** a``: the curve's gamma absorbs it exactly); each round pins it by keeping
the judged steps' median ratio to the named steps at 1: most steps are as named, a shutter table rounds a few. Steps
too dark or too clipped to be judged keep their named ratio. OpenCV fits with known times only, and a NumPy
Robertson with a time step would be a second copy of the fit: the rounds reuse OpenCV's, on the fit's sampled
pixels (benchmarks/RESULTS.md, s33-bracket)."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np

from ..core.tolerances import RESPONSE_ESTIMATE_LOW_CODE, RESPONSE_ESTIMATE_ROUNDS, RESPONSE_ESTIMATE_STEP
from .response_fit import (
    CODES,
    SAMPLED_PIXELS,
    channels_mean,
    check_bracket,
    check_follows,
    ratio_errors,
    robertson_channels,
)

MIN_JUDGED_STEPS = 3
"""Fewest consecutive pairs the estimate must judge to pin the times' power by their median: fewer, and the times
named are kept (the bracket's ends too dark or too clipped to say)."""
SETTLED = 0.001
"""The rounds stop once no judged step moves by more than this fraction."""


@dataclasses.dataclass(frozen=True)
class TimesEstimate:
    """A bracket folder's exposure times as its frames say they were taken."""

    named_ms: tuple[float, ...]
    """The times the folder names, ms, in its order."""
    estimated_ms: tuple[float, ...]
    """The times estimated, ms, in the folder's order, the shortest as named (only ratios are estimated)."""
    step_errors: tuple[float | None, ...]
    """Per consecutive pair, shortest first: the estimated step's ratio over the named one, minus 1; None where the
    pair could not be judged (its step kept as named)."""
    rounds: int
    """Fit-and-update rounds run."""

    @property
    def largest(self) -> float:
        """The largest |step error| judged (0 when none was)."""
        return max((abs(e) for e in self.step_errors if e is not None), default=0.0)

    @property
    def used(self) -> bool:
        """Whether the estimate differs enough from the names to fit at it
        (:data:`~nlipscalib.core.tolerances.RESPONSE_ESTIMATE_STEP`)."""
        return self.largest > RESPONSE_ESTIMATE_STEP


def estimate_times(frames: Sequence[np.ndarray], exposures_ms: Sequence[float], source: str) -> TimesEstimate:
    """The times ``frames`` were taken at, estimated jointly with the camera's curve.

    Parameters
    ----------
    frames : sequence of (H, W, 3) uint8, RGB, one per exposure, in the folder's order
    exposures_ms : the times named, ms, one per frame
    source : named in a refusal (the bracket's own checks, ``response_fit.check_follows``)

    Returns
    -------
    TimesEstimate (the times as named, every step None, when fewer than :data:`MIN_JUDGED_STEPS` pairs can be
    judged: nothing to pin the power by)

    Raises
    ------
    CaptureError -- the bracket cannot give a curve at all (``response_fit``'s one-line refusals)
    """
    named = np.asarray(exposures_ms, dtype=np.float64)
    check_bracket(frames, named, source)
    order = np.argsort(named)
    sampled = _sampled_row([frames[i] for i in order])
    steps_named = np.diff(np.log(named[order]))
    steps = steps_named.copy()
    judged = np.zeros(len(steps), bool)
    rounds = 0
    for rounds in range(1, RESPONSE_ESTIMATE_ROUNDS + 1):
        times = named[order][0] * np.exp(np.concatenate([[0.0], np.cumsum(steps)]))
        if rounds == 1:
            check_follows(sampled, times, source)
        curve = np.maximum.accumulate(channels_mean(robertson_channels(sampled, times, source)))
        errors = ratio_errors(sampled, times, np.broadcast_to(curve, (3, CODES)), RESPONSE_ESTIMATE_LOW_CODE)
        judged = np.isfinite(errors)
        if judged.sum() < MIN_JUDGED_STEPS:
            return TimesEstimate(tuple(named.tolist()), tuple(named.tolist()), (None,) * len(steps), rounds)
        moved = steps + np.log1p(np.where(judged, errors, 0.0))
        power = np.median(moved[judged] / steps_named[judged])  # the power no bracket can see, pinned
        new = np.where(judged, moved / power, steps_named)
        settled = np.abs(np.expm1(new - steps)).max() < SETTLED
        steps = new
        if settled:
            break
    times = named[order][0] * np.exp(np.concatenate([[0.0], np.cumsum(steps)]))
    estimated = np.empty_like(times)
    estimated[order] = times
    ratio = np.expm1(steps - steps_named)
    step_errors = tuple(float(r) if j else None for r, j in zip(ratio, judged, strict=True))
    return TimesEstimate(tuple(named.tolist()), tuple(estimated.tolist()), step_errors, rounds)


def _sampled_row(frames: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The frames' evenly spaced pixels (:data:`~nlipscalib.device.response_fit.SAMPLED_PIXELS` of each, all of a
    smaller frame) as (1, P, 3) rows: the rounds' fits cost what the fit's residual does, not a whole frame's."""
    step = max(1, frames[0].shape[0] * frames[0].shape[1] // SAMPLED_PIXELS)
    return [np.ascontiguousarray(f.reshape(1, -1, 3)[:, ::step]) for f in frames]
