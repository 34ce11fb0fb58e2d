"""Light adds: a camera-response curve checked, and its one free exponent pinned, by LEDs lit apart and together
(``nlips calibrate-camera-response``).

Why: a bracket fixes a curve only up to a power. A camera whose real exposure times are a power of the asked ones
(``t_real = c * t ** a``: a shutter table of another log base) gives frames that the curve ``g ** (1 / a)`` fits at
the asked times exactly as ``g`` fits at the real ones; every exposure ratio agrees and the curve is wrong
(benchmarks/RESULTS.md, s31-respcam: a = 0.9, 4 % off, not caught). Light needs no times: with the curve undone,
the frame with LEDs A and B lit together is the frame with A plus the frame with B, less the dark frame once. A
curve off by a power ``p`` breaks that most where A and B light a pixel alike (``(x + y) ** p`` against ``x ** p +
y ** p``), so the power that makes the pairs add is the one the bracket could not see: the curve is raised to it
when it makes every pair add (:func:`pin_power`), and the calibration refused in one line when no power does (the
LEDs dim each other when lit together, or the light changed between the frames).

Each pixel is compared where every frame of the pair is neither black nor clipped, in two bins of how alike A's and
B's light is there (:data:`ALIKE`, :data:`UNALIKE`): a power error differs between them, a common dimming of the
pair does not."""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.errors import CaptureError
from ..core.tolerances import (
    RESPONSE_ADDITIVITY_ERROR,
    RESPONSE_ADDITIVITY_GAP,
    RESPONSE_ADDITIVITY_POWERS,
    RESPONSE_CLIPPED_CODE,
    RESPONSE_DARK_CODE,
    RESPONSE_RISE_PIXELS,
)
from .response_fit import SAMPLED_PIXELS

ALIKE = (0.5, 1.0)
"""The smaller of A's and B's light over the larger, at a pixel of the first bin: lit alike by both, where a curve
off by a power errs most (2 ** (p - 1) at equal light)."""
UNALIKE = (0.1, 0.4)
"""The same ratio for the second bin: one LED's light mostly, where a power errs less (the emulated sensor, opposite
LEDs, power 1.11: 8.0 % alike, 6.0 % here), and a common dimming of the pair as much."""


@dataclasses.dataclass(frozen=True)
class AdditivityFrames:
    """Frames of the undeformed gel at one exposure for the additivity check, as 8-bit codes above black."""

    exposure_ms: float | None
    """Their exposure, ms (the bracket's longest that two LEDs' light does not clip: :func:`pair_exposure`); None
    for a ``--bracket`` folder's whose names give none."""
    dark: np.ndarray
    """(H, W, 3) uint8, every LED off."""
    singles: dict
    """LED number (1-based) -> (H, W, 3) uint8, that LED lit alone."""
    pairs: tuple
    """((LED a, LED b, (H, W, 3) uint8 the two lit together), ...)."""


@dataclasses.dataclass(frozen=True)
class Additivity:
    """How well the curve makes the pairs' light add, and the power that pins it."""

    errors: tuple
    """((LED a, LED b, alike-bin error, unalike-bin error), ...): each pair's light lit together over the sum of its
    light lit apart, less 1, the fitted curve undone (NaN where a bin held too few pixels)."""
    power: float
    """The power the fitted curve was raised to (1.0: the curve added as fitted)."""
    after: float
    """The largest error of any pair and bin once raised to :attr:`power`."""
    gap: float
    """The largest difference of a pair's two bins' errors once raised to :attr:`power`: ~0 when a power explains
    the misfit, the misfit itself when the pair dims (or brightens) as a whole."""

    @property
    def before(self) -> float:
        """The largest error of any pair and bin with the curve as fitted."""
        return _largest([e for pair in self.errors for e in pair[2:]])

    @property
    def common(self) -> float:
        """The median of every pair's and bin's error with the curve as fitted, with its sign (NaN when none was
        judged): what the pairs share. A pair dimmed (or brightened) as a whole moves it alike in both bins; a
        right camera's noise leaves it near 0 (:data:`~nlipscalib.core.tolerances.RESPONSE_ADDITIVITY_COMMON`)."""
        finite = [e for pair in self.errors for e in pair[2:] if np.isfinite(e)]
        return float(np.median(finite)) if finite else float("nan")

    @property
    def signed(self) -> float:
        """The error of largest magnitude of any pair and bin with the curve as fitted, with its sign."""
        return max((e for pair in self.errors for e in pair[2:] if np.isfinite(e)), key=abs)


def pair_exposure(frames: list[np.ndarray], times: list[float] | np.ndarray) -> float:
    """The exposure, ms, to take the additivity frames at: the longest of the bracket's whose frame at twice it (or
    the next longer one) has fewer than :data:`~nlipscalib.core.tolerances.RESPONSE_RISE_PIXELS` of its samples
    clipped, so two LEDs lit together stay mostly below clipping; the shortest when none does.

    Parameters
    ----------
    frames : (H, W, 3) uint8 codes of one LED lit, one per exposure
    times : ms, each frame's
    """
    times = np.asarray(times, dtype=np.float64)
    clipped = np.array([(f >= RESPONSE_CLIPPED_CODE).mean() for f in frames])
    best = float(times.min())
    for t in times:
        longer = np.flatnonzero(times >= 2 * t - 1e-9)
        if len(longer) and clipped[longer[np.argmin(times[longer])]] < RESPONSE_RISE_PIXELS:
            best = max(best, float(t))
    return best


def pair_errors(curves: np.ndarray, shots: AdditivityFrames, bins: dict | None = None) -> list[tuple]:
    """Each pair's additivity error per bin with ``curves`` (3, 256) undone (:attr:`Additivity.errors`); ``bins``:
    each pair's pixels of each bin (:func:`pair_bins`), by default those of ``curves``."""
    linear = {key: _lookup(curves, frame) for key, frame in _codes(shots).items()}
    bins = pair_bins(curves, shots) if bins is None else bins
    out = []
    for a, b, _ in shots.pairs:
        x, y, both = (linear[key] - linear["dark"] for key in (a, b, (a, b)))
        errors = [both[use].sum() / (x + y)[use].sum() - 1.0 if use is not None else np.nan for use in bins[a, b]]
        out.append((a, b, *(float(e) for e in errors)))
    return out


def pair_bins(curves: np.ndarray, shots: AdditivityFrames) -> dict:
    """(a, b) -> (alike pixels, unalike pixels): (P, 3) bool masks of the samples (:func:`_codes`) where no frame
    of the pair is black or clipped and the smaller of A's and B's light (``curves`` undone) over the larger is within
    :data:`ALIKE` / :data:`UNALIKE`; None for a bin of fewer than
    :data:`~nlipscalib.core.tolerances.RESPONSE_RISE_PIXELS` of the samples. Fixed once from the fitted curve, so
    that the power pinned is judged on the same pixels at every power tried."""
    codes = _codes(shots)
    dark = _lookup(curves, codes["dark"])
    out = {}
    for a, b, _ in shots.pairs:
        frames = (codes[a], codes[b], codes[a, b])
        well = np.logical_and.reduce([(f > RESPONSE_DARK_CODE) & (f < RESPONSE_CLIPPED_CODE) for f in frames])
        x, y = _lookup(curves, codes[a]) - dark, _lookup(curves, codes[b]) - dark
        alike = np.minimum(x, y) / np.maximum(np.maximum(x, y), 1e-12)
        masks = [well & (alike >= lo) & (alike <= hi) for lo, hi in (ALIKE, UNALIKE)]
        out[a, b] = tuple(m if m.mean() >= RESPONSE_RISE_PIXELS else None for m in masks)
    return out


def pin_power(curves: np.ndarray, shots: AdditivityFrames, source: str) -> tuple[np.ndarray, Additivity]:
    """``curves`` raised to the power that makes the pairs' light add, and how well it does; one line naming
    ``source`` when the curve as fitted does not add and no power within
    :data:`~nlipscalib.core.tolerances.RESPONSE_ADDITIVITY_POWERS` makes it.

    Parameters
    ----------
    curves : (3, 256) float64, each channel's fitted curve (R, G, B), 0 at code 0 and 1 at 255
    shots : the additivity frames
    source : named in the refusal

    Returns
    -------
    (3, 256) float64 curves (``curves`` itself when it adds within
    :data:`~nlipscalib.core.tolerances.RESPONSE_ADDITIVITY_ERROR`, or when no pair has pixels to judge: then
    :attr:`Additivity.before` is NaN), and the :class:`Additivity` measured
    """
    bins = pair_bins(curves, shots)
    errors = tuple(pair_errors(curves, shots, bins))
    before = _largest([e for pair in errors for e in pair[2:]])
    if not np.isfinite(before):  # nothing to judge: the caller says so, the curve kept as fitted
        return curves, Additivity(errors, 1.0, before, 0.0)
    if before <= RESPONSE_ADDITIVITY_ERROR:
        return curves, Additivity(errors, 1.0, before, _gap(errors))
    from scipy.optimize import minimize_scalar  # only when the curve does not add as fitted

    low, high = RESPONSE_ADDITIVITY_POWERS

    def misfit(power: float) -> float:
        values = [e for pair in pair_errors(curves**power, shots, bins) for e in pair[2:]]
        return float(np.nansum(np.square(values)))

    power = float(minimize_scalar(misfit, bounds=(low, high), method="bounded", options={"xatol": 1e-4}).x)
    raised = curves**power
    pinned = pair_errors(raised, shots, bins)
    after, gap = _largest([e for pair in pinned for e in pair[2:]]), _gap(pinned)
    if after > RESPONSE_ADDITIVITY_ERROR or gap > RESPONSE_ADDITIVITY_GAP or not low + 1e-3 < power < high - 1e-3:
        a, b, *worst = max(errors, key=lambda pair: _largest(pair[2:]))
        together = 1.0 + max((e for e in worst if np.isfinite(e)), key=abs)
        raise CaptureError(
            f"{source}: with the fitted curve undone, LEDs {a} and {b} lit together give {together:.3f} times their "
            f"light lit apart (more than {RESPONSE_ADDITIVITY_ERROR:.1%} off 1, and no power of the curve within "
            f"{low:g}-{high:g} makes every pair add alike where both LEDs light a pixel and where one does: power "
            f"{power:.3f} leaves {after:.1%}, the two {gap:.1%} apart): light adds, so the LEDs dim each other "
            "when lit together (a shared supply that sags: power the board from its own supply), the light "
            "changed between the frames (room light, the gel moved), or the camera took some exposures at times of "
            "its own that bent the curve (a shutter table: 1/60 s for 16 ms; give the times it takes as "
            "--exposures-ms); fix that and retake"
        )
    return raised, Additivity(errors, power, after, gap)


def _codes(shots: AdditivityFrames) -> dict:
    """The frames by key ("dark", an LED's number, or (a, b) for a pair lit together), as (P, 3) samples of
    every pixel, or of :data:`~nlipscalib.device.response_fit.SAMPLED_PIXELS` evenly spaced ones of a larger frame
    (the power's search undoes every frame some 25 times: 2 s a 640x480 set, 0.1 s sampled)."""
    step = max(1, shots.dark.shape[0] * shots.dark.shape[1] // SAMPLED_PIXELS)
    frames: dict = {"dark": shots.dark, **shots.singles}
    frames.update({(a, b): frame for a, b, frame in shots.pairs})
    return {key: frame.reshape(-1, 3)[::step] for key, frame in frames.items()}


def _lookup(curves: np.ndarray, codes: np.ndarray) -> np.ndarray:
    """(P, 3) float64 linear light of (P, 3) 8-bit ``codes``, each channel through its curve."""
    return np.stack([curves[c][codes[:, c]] for c in range(3)], axis=-1)


def _gap(errors: list | tuple) -> float:
    """The largest difference between a pair's alike and unalike bins' errors (0 where a bin is NaN)."""
    gaps = [abs(pair[2] - pair[3]) for pair in errors if np.isfinite(pair[2]) and np.isfinite(pair[3])]
    return max(gaps, default=0.0)


def _largest(values: list | tuple) -> float:
    """The largest magnitude of ``values`` ignoring NaN; NaN when all are."""
    finite = [abs(v) for v in values if np.isfinite(v)]
    return max(finite) if finite else float("nan")
