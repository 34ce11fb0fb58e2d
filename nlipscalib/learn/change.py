"""Which pixels of a tri-colour frame differ from the undeformed reference frame.

Used twice with the same rule: the calibration dataset separates the contact from the undeformed
rest with it, and real-time inference sends only the changed pixels through the network.

The difference is evaluated on 2x2 pixel blocks (a quarter of the work per frame, and sensor noise
already halves), box-averaged over a few blocks (a smooth shading change of a shallow, wide
deformation stays, noise averages out), compared with a robust noise estimate (median absolute
deviation over the gel, so no absolute threshold needs tuning), cleaned of isolated specks by a
morphological opening and grown by a margin, then brought back to full resolution.

The rule runs twice. The first pass, on the frame as it is, gives the frame's own figures (its median difference,
:attr:`ChangeDetector.mismatch`, and each colour's ratio to the reference on the gel it left unchanged,
:attr:`ChangeDetector.channel_ratio`, which warn of another exposure and of drifted LEDs). The second, whose pixels
are the result, runs on the frame with its per-colour gain taken out (:func:`rule_gain`). Why: a uniform colour
shift is no contact, but the robust noise estimate takes it for noise, and its size varies with the dome's shading;
an 8-bit MJPG stream's ~1 % shift (its YCbCr round trip) doubled the threshold with JPEG's own noise, cut 10-30 % of
each contact's flat rim and made contacts read steeper (benchmarks/RESULTS.md, s41-walkleft and s43-mjpg). The gain
comes from the blocks the first pass left unchanged, and again from those of them near its first value, so a large
contact does not pull it toward its own colours; it is held within
:data:`~nlipscalib.core.tolerances.FRAME_CHANNEL_DRIFT`, so a contact over most of the gel, which the first pass
cannot tell from the rest, does not shift the rest by more than a frame may drift unwarned (a larger drift is
warned about, and a calibration press's is taken out by :func:`~nlipscalib.learn.dataset.contact_pixels`).
"""

from __future__ import annotations

import numpy as np

from ..core import masks
from ..core.errors import ShapeError, require
from ..core.robust_scale import MAD_TO_SIGMA, mad_scale
from ..core.tolerances import CHANGE_GAIN_TRIM_SIGMAS, CHANGE_MIN_REL, CHANGE_NOISE_SIGMAS, FRAME_CHANNEL_DRIFT

RULE_VERSION = 3
"""Bumped whenever the rule changes, so calibration datasets re-sample their presses (3: the frame's per-colour gain
taken out before the second pass, 2026-12-08)."""
SMOOTH_BLOCKS = 3
"""Side of the box (in 2x2 blocks, i.e. 6 pixels) the signed difference is averaged over."""
DILATE_BLOCKS = 2
"""Changed regions grow by this many blocks (4 pixels), so a contact's soft rim is not cut off."""
NOISE_STRIDE = 4
"""The noise level is estimated on every NOISE_STRIDE-th gel block (plenty of samples, less work)."""


class ChangeDetector:
    """The change rule for one reference frame; precomputes what does not depend on the frame.

    Parameters
    ----------
    reference : (H, W, 3) float, linear tri-colour image of the undeformed sensor
    valid : (H, W) bool -- pixels that see the gel
    """

    def __init__(self, reference: np.ndarray, valid: np.ndarray):
        if reference.ndim != 3 or reference.shape[:2] != valid.shape or reference.shape[2] != 3:
            raise ShapeError(f"reference {reference.shape} and valid {valid.shape} must be (H, W, 3) and (H, W)")
        self.shape = valid.shape
        self.valid = valid.astype(bool)
        h2, w2 = self.shape[0] // 2, self.shape[1] // 2
        self._crop = (slice(0, 2 * h2), slice(0, 2 * w2))
        self._ref_blocks = _blocks(np.where(self.valid[..., None], reference, 0).astype(np.float32), self._crop)
        self._valid_blocks = _blocks(self.valid.astype(np.float32), self._crop) == 1  # all four pixels on the gel
        self._level = self._ref_blocks.sum(-1)
        self._sample = np.flatnonzero(self._valid_blocks)[::NOISE_STRIDE]
        self._sample_level = float(np.median(self._level.ravel()[self._sample])) if self._sample.size else 0.0
        self._ref_sample = self._ref_blocks.reshape(-1, 3)[self._sample]
        self.mismatch = 0.0
        """The last frame's median difference from the reference over the gel, as a fraction of the reference's
        median brightness (see :data:`nlipscalib.core.tolerances.FRAME_MISMATCH_FRACTION`)."""
        self.channel_ratio = np.ones(3)
        """(3,) the last frame's :func:`channel_ratio` (1s before the first, and on a gel too small to sample)."""
        self.gain = np.ones(3)
        """(3,) the per-colour gain the last frame's second pass took out (:func:`rule_gain`; 1s before the first)."""

    def __call__(self, frame: np.ndarray) -> np.ndarray:
        """(H, W) bool -- pixels of ``frame`` ((H, W, 3) float, linear) that differ from the reference."""
        if frame.shape != self.shape + (3,):
            raise ShapeError(f"frame {frame.shape} does not match the reference {self.shape + (3,)}")
        if self._sample.size == 0:
            return np.zeros(self.shape, bool)
        cv2 = _cv2()
        blocks = _blocks(frame.astype(np.float32, copy=False), self._crop)
        signed = blocks - self._ref_blocks
        signed[~self._valid_blocks] = 0
        hit, median = self._hits(signed)
        # the rule below finds what differs from the rest of the frame: when the whole frame differs (another
        # exposure, LEDs off, channels swapped), nothing does, and the caller is told through this figure
        self.mismatch = median / self._sample_level if self._sample_level > 0 else 0.0
        rest = ~hit.ravel()[self._sample]
        if rest.any():  # the frame's figure and the gain from one set of ratios
            ratio = _ratios(signed.reshape(-1, 3)[self._sample], self._ref_sample, rest)
            centre = _middle(ratio)
            self.channel_ratio, self.gain = 1.0 + centre.astype(np.float64), _trimmed_gain(ratio, centre)
        else:
            self.channel_ratio, self.gain = np.ones(3), np.ones(3)
        # the second pass: the frame's colours in the reference's gain (module docstring); OpenCV's per-channel
        # product, a third of NumPy's broadcast one's time, each value the same correctly rounded float32
        inverse = tuple(float(g) for g in (1 / self.gain).astype(np.float32))
        signed = cv2.subtract(cv2.multiply(blocks, inverse), self._ref_blocks)
        signed[~self._valid_blocks] = 0
        hit, _ = self._hits(signed)
        out = np.zeros(self.shape, bool)
        out[self._crop] = cv2.resize(hit.view(np.uint8), None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST).view(bool)
        return out & self.valid

    def _hits(self, signed: np.ndarray) -> tuple[np.ndarray, float]:
        """The changed blocks ((H/2, W/2) bool) of a frame whose 2x2-block means differ from the reference's by
        ``signed`` (0 off the gel), and the median of its smoothed difference over the sampled gel blocks."""
        cv2 = _cv2()
        # OpenCV's box filter and morphology (core.masks): the same operations as scipy.ndimage's (replicated
        # border for the mean, zero outside for the binary ones), several times faster on a live frame
        smooth = cv2.blur(signed, (SMOOTH_BLOCKS, SMOOTH_BLOCKS), borderType=cv2.BORDER_REPLICATE)
        diff = cv2.transform(np.abs(smooth), _ONES)  # sum over the colours, (H/2, W/2)
        sample = diff.ravel()[self._sample]
        median = float(np.median(sample))
        sigma = mad_scale(sample, center=median, dtype=np.float32) + 1e-6
        hit = self._valid_blocks & (diff > median + CHANGE_NOISE_SIGMAS * sigma) & (diff > CHANGE_MIN_REL * self._level)
        hit = masks.dilate(masks.erode(hit))  # opening: isolated blocks are noise
        if DILATE_BLOCKS > 0:
            hit = masks.dilate(hit, iterations=DILATE_BLOCKS)
        return hit, median


def channel_ratio(signed: np.ndarray, reference: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Each colour's median of a frame over the reference frame on the sampled gel blocks the change rule left
    unchanged (:attr:`ChangeDetector.channel_ratio`, and the device path's, :mod:`.fullframe`).

    A press's own colours moved the whole gel's medians by up to 4.5 % on the twin's presses; a block's ratio, not a
    ratio of medians, so the press pixels the rule leaves in the rest do not tip it.

    Parameters
    ----------
    signed : (N, 3) float32 -- the frame's 2x2-block means minus the reference's, linear, at the sampled gel blocks
    reference : (N, 3) float32 -- the reference frame's block means there
    rest : (N,) bool -- the blocks the change rule left unchanged

    Returns
    -------
    (3,) float64 -- red, green, blue; 1s when every sampled block changed
    """
    if not rest.any():
        return np.ones(3)
    return 1.0 + _middle(_ratios(signed, reference, rest)).astype(np.float64)


def rule_gain(signed: np.ndarray, reference: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """The per-colour gain the change rule's second pass takes out of a frame (the module docstring): each colour's
    median of the frame over the reference on the sampled gel blocks its first pass left unchanged, again over those
    of them within :data:`~nlipscalib.core.tolerances.CHANGE_GAIN_TRIM_SIGMAS` robust sigmas of the first median in
    every colour, held within 1 +- :data:`~nlipscalib.core.tolerances.FRAME_CHANNEL_DRIFT`.

    Why the second median: the first pass, its threshold raised by the very shift, misses the dim part of a large
    contact, whose blocks then pull the first median toward the contact's colours (a contact over 35 % of a test gel
    cost three quarters of its region); they lie many sigmas out and the second median leaves them out. Why the
    bound: a contact over most of the gel is the first pass's rest (nothing is told from it) and would shift the
    real rest by its colours; a larger drift is warned about, and a calibration press's is taken out by
    :func:`~nlipscalib.learn.dataset.contact_pixels`. The device path (:mod:`.fullframe`) computes the same.

    Parameters
    ----------
    signed, reference, rest : as :func:`channel_ratio`'s, of the first pass

    Returns
    -------
    (3,) float64 -- red, green, blue; 1s when every sampled block changed (or a colour's figure is not finite)
    """
    if not rest.any():
        return np.ones(3)
    ratio = _ratios(signed, reference, rest)
    return _trimmed_gain(ratio, _middle(ratio))


def _trimmed_gain(ratio: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """:func:`rule_gain` of the ratios ``ratio`` ((3, n) float32, frame / reference - 1) whose middle values are
    ``centre`` ((3,))."""
    off = np.abs(ratio - centre[:, None])
    inside = np.all(off <= _middle(off)[:, None] * np.float32(CHANGE_GAIN_TRIM_SIGMAS * MAD_TO_SIGMA), axis=0)
    # (none inside: a colour's spread 0 where the blocks agree in no colour, e.g. quantised values; the first median)
    again = _middle(np.ascontiguousarray(ratio[:, inside])) if inside.any() else centre
    gain = 1.0 + again.astype(np.float64)
    gain = np.where(np.isfinite(gain), gain, 1.0)
    return np.clip(gain, 1 - FRAME_CHANNEL_DRIFT, 1 + FRAME_CHANNEL_DRIFT)


def _ratios(signed: np.ndarray, reference: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """(3, n) float32 contiguous -- frame / reference - 1 (= difference / reference) of the ``rest`` blocks."""
    return np.ascontiguousarray((signed[rest] / np.maximum(reference[rest], np.float32(1e-12))).T)


def _middle(rows: np.ndarray) -> np.ndarray:
    """(3,) -- each row's value at index n // 2 of it sorted (the median of an odd count, the upper middle of an
    even one): one partition of each contiguous row (half the time of np.median over (N, 3) columns: 0.5 ms a
    640x480 frame)."""
    middle = rows.shape[1] // 2
    return np.partition(rows, middle, axis=1)[:, middle]


def changed_pixels(frame: np.ndarray, reference: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Pixels whose tri-colour value differs from the undeformed reference frame (module docstring).

    Parameters
    ----------
    frame, reference : (H, W, 3) float, linear tri-colour images (``Press.linear``)
    valid : (H, W) bool -- pixels that see the gel

    Returns
    -------
    (H, W) bool
    """
    if frame.shape != reference.shape:
        raise ShapeError(f"frame {frame.shape} and reference {reference.shape} must match")
    return ChangeDetector(reference, valid)(frame)


_ONES = np.ones((1, 3), np.float32)


def _cv2():
    return require("cv2", "opencv-python-headless", "Detecting changed pixels")


def _blocks(image: np.ndarray, crop: tuple[slice, slice]) -> np.ndarray:
    """Means over 2x2 pixel blocks: (H, W[, C]) float32 -> (H // 2, W // 2[, C]).

    OpenCV's area resampling at an exact factor of 2 is that mean, four times faster than strided adds.
    Means rather than sums: the rule compares differences with their own noise and with the reference's
    level, both scaled alike.
    """
    a = image[crop]
    return _cv2().resize(a, (a.shape[1] // 2, a.shape[0] // 2), interpolation=_cv2().INTER_AREA)
