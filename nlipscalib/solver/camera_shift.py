"""Has the camera moved between the undeformed capture and a press? A warning with the measured shift.

Why: the one-bounce twin's cube press with its images 2 px to the right of the undeformed capture's solved to 0.925
deg (0.424 in place) without a word (s26 QA walk). A real lab's camera can creep after a knock; the remedy is a new
undeformed capture. The shift is measured, not corrected: a press solved against a reference that no longer lines
up with its pixels is the user's to recapture (benchmarks/RESULTS.md, s26-degen2).

The images hold no sharp structure (the gel fills the view; its shading is smooth), so OpenCV's phase correlation and
ECC alignment followed the dent or the noise (shifts of 1-100 px on presses that had not moved). A translation
fitted by Gauss-Newton (Lucas-Kanade) on the log images of a few LEDs, block-averaged, with a per-LED offset (an
exposure change) and Cauchy weights (the dent's pixels disagree with any shift), measures 0.01-0.29 px on twin
presses that did not move and 1.66 px on the 2 px one (the dent pulls the cube press's by -0.2 px).

A dent over much of the gel is no outlier to the Cauchy weights, whose scale is the residual's median: a 5 mm cube on
the flat pad displaces 62-75 % of its gel's pixels, on the fingertip 6-13 % in the image's bright, steep corner, and
its face, moved along the axis, changes the shading smoothly, as a shift does. They pulled the measure by up to 1.42
px (flat pad) and 1.25 px (fingertip): 7 of q3's 135 twin presses were warned "the camera moved", and a flat pad's
cube press moved by 2 px measured 0.57 px, unwarned. So the blocks a dent changed are left out first
(:func:`changed_blocks`: more than a 3 px shift explains, by 5 times the noise): the 135 presses in place measure
0.00-0.43 px (median 0.08; before, 0.01-1.42, median 0.12), moved by 2 px 1.53-2.29 px on every design (before
0.57-2.56), by 1 px 0.62-1.29 (benchmarks/RESULTS.md, s41-shiftcube).

Moved by sub-pixel shifts (``cv2.warpAffine``), q3's cube presses still read up to 0.64 px off, for two reasons. A
dent changes the shading outside its contact too (its light spread over the gel): under each LED that change reads
as a shift of up to 1-2 px along the LED's own direction, which the LEDs opposite cancel only in part (leaving out
the truth's contact grown by 32 px still left 0.2-0.3 px); more LEDs cancel it better. And a large move changes the
steep blocks by more than :data:`SHIFT_ALLOWANCE` explains, so they went with the dent and a 3 px move read 2.46-3.27;
a second pass judges the dent's blocks on the press moved back by the first pass's shift. With 6 LEDs and two passes
the error is at most 0.38 px whatever the move (0.5-3 px), so ``tolerances.CAMERA_SHIFT_PX`` is 0.5 px. OpenCV's
phase correlation (Hanning window) and ECC were measured again and dropped: a log-linear shading moved along its slope
is the same image less an offset, so ECC's gain and offset invariance leaves the move unobservable (70-210 px off per
LED) and phase correlation follows the window and the dent (benchmarks/RESULTS.md, s42-shift1px).

That 0.38 px was the dent's light spread over the gel (1): under each LED alone a shift of 1-3 px along the LED's own
direction (where its shading brightens), unequal between opposite LEDs. Leaving out more of the gel around the dent
does not help (the change spans the gel: its deformed part grown by 160 px still read 0.35 px off), so each LED's
shift along its own direction is fitted as its own and the camera's is read from the rest, across the LEDs
(:data:`SHIFT_OWN_KEPT`): the fingertip's cube presses 0.38 -> 0.24 px, the hemisphere's 0.30 -> 0.25, the bench's
coin 0.20 -> 0.07 (docs/experiments/RESULTS.md, s43-shiftdent). The LEDs' true azimuths instead of the shading's
direction read 0.34, the directions of most evidence 1.5: the direction must be the shading's.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..core import masks, tolerances
from ..core.capture import Press
from . import reuse

SHIFT_LEDS = 6
"""LED images the shift is measured on (every k-th of the capture's): each adds the same shift's evidence under
another light, so a dent that mimics a shift under one LED does not under the others. Why 6, not 4: a dent's broad
change of the shading outside its contact (its light spread over the gel) reads under each LED as a shift of up to
1-2 px along that LED's own direction, which the LEDs opposite cancel only in part; on 30 of q3's hardest presses,
with the second pass, the largest error was 0.49 px with 4 LEDs, 0.38 with 6, 0.34 with 12 at twice 6's cost
(s42-shift1px)."""
SHIFT_BLOCK = 4
"""Side, pixels, of the blocks the images are averaged over first (at least 60 blocks along the short side): the
noise averages out, and the linearised shift stays within its range (a 2 px shift is half a block)."""
SHIFT_ITERATIONS = 2
"""Gauss-Newton steps per pass (each warps the press by the shift so far)."""
SHIFT_PASSES = 2
"""Passes of :func:`changed_blocks` and the fit: each after the first judges the press moved back by the shift so far,
so the blocks a large shift changed by more than :data:`SHIFT_ALLOWANCE` explains come back (a 3 px move read 2.46-3.27
px with one pass, 2.69-3.28 with two) and the fit restarts from the shift found (s42-shift1px)."""
SHIFT_MARGIN = 3
"""Blocks left out along the gel's outline and the image's border (see :func:`camera_shift`)."""
SHIFT_LIT = 1e-3
"""Blocks whose image is below this (linear, full scale 1) under one of the LEDs are left out."""
SHIFT_REWEIGHTS = 3
"""Weighted least-squares solves per step, each weighting the residual the previous one leaves."""
SHIFT_ALLOWANCE = 3.0
"""Pixels: a block whose log image changed more than a shift of this size explains (its gradient times it) by more
than :data:`SHIFT_CHANGE_NOISE` times the noise, under any LED, is the dent's and left out (:func:`changed_blocks`)."""
SHIFT_CHANGE_NOISE = 5.0
"""Noise levels (the block images' noise, :func:`block_noise`) a block's change must pass beyond the shift's
allowance to be the dent's."""
SHIFT_NOISE_FLOOR = 1e-3
"""The least noise (log, per block) :func:`changed_blocks` assumes: exact or 16-bit images hold almost none, and a
most common change needs a window of some width."""
SHIFT_OWN_KEPT = 0.5
"""Share of the measured blocks the dent must leave for each LED's own shift along its direction to be fitted too.
Why: a dent changes the shading outside its contact (its light spread over the gel), under each LED alone as a shift
of 1-3 px along the LED's own direction, unequal between opposite LEDs; the joint fit kept their imbalance (q3's
fingertip cubes read 0.38 px off, the hemisphere's 0.30). Each LED's shift along its direction fitted as its own, the
camera's is read from the rest: 0.24 and 0.25 (s43-shiftdent). Where the dent leaves under half the gel (a flat
pad's cube: 19-31 % kept) the rest is the dent's fringe, not spread light, and that rest alone read the flat pad's
cube presses 0.48 px off (0.14 with the joint fit), so they keep the joint fit."""
SHIFT_CHANGE_GROW = 2
"""Blocks the dent's changed blocks are grown by: its fringe, changed by less than the noise bound, goes with it."""


def camera_shift(
    reference: np.ndarray | Callable[[int, int], np.ndarray], images: np.ndarray, valid: np.ndarray
) -> tuple[float, float]:
    """The translation of ``images`` against ``reference``, pixels: ``images(x) ~ reference(x - (dx, dy))``.

    Parameters
    ----------
    reference : (L, H, W, 3) float -- linear LED images of the undeformed capture; or ``(step, block) ->``
        :func:`log_blocks` of its every ``step``-th image (a capture's, kept for the next press).
    images : (L, H, W, 3) float -- linear LED images of the press.
    valid : (H, W) bool -- the gel's pixels.

    Returns
    -------
    (dx, dy) : float -- pixels, x right and y down; (0, 0) when the gel has too few blocks to tell.
    """
    import cv2

    H, W = valid.shape
    block = max(1, min(SHIFT_BLOCK, min(H, W) // 60))
    step = max(1, len(images) // SHIFT_LEDS)
    ref = reference(step, block) if callable(reference) else log_blocks(reference[::step], block)
    img = log_blocks(images[::step], block)
    h, w = ref.shape[1:]
    inner = cv2.resize(valid.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) > 0.999
    inner[:1], inner[-1:], inner[:, :1], inner[:, -1:] = False, False, False, False
    # away from the gel's outline and the image's border by more than a shift to be found, and lit by every LED: the
    # log's jump at an outline (or where an LED does not reach) is no shading to align
    inner = masks.erode(inner, iterations=SHIFT_MARGIN) & (ref > np.log(SHIFT_LIT)).all(axis=0)
    shift = np.zeros(2)
    for _ in range(SHIFT_PASSES):
        # the dent's blocks, judged on the press moved back by the shift so far: a shift's own change is not the dent's
        kept = inner & ~changed_blocks(ref, _moved(img, shift), inner, block)
        if kept.sum() < 100:
            break
        # each LED's own shift needs three directions at least: two opposite LEDs' are one line, along which the
        # camera's would go unread
        own = len(img) >= 3 and kept.sum() >= SHIFT_OWN_KEPT * inner.sum()
        shift = _fit(ref, img, kept, shift, own=own)
    return float(shift[0] * block), float(shift[1] * block)


def _fit(ref: np.ndarray, img: np.ndarray, kept: np.ndarray, shift: np.ndarray, own: bool = True) -> np.ndarray:
    """(2,) blocks -- Gauss-Newton from ``shift`` on the ``kept`` blocks of :func:`log_blocks` ``ref`` and ``img``;
    with ``own``, each LED's shift along its own direction fitted too (:data:`SHIFT_OWN_KEPT`)."""
    gy, gx = np.gradient(ref, axis=(1, 2))
    gx, gy = gx[:, kept], gy[:, kept]
    gu = None
    if own:
        # each LED's own direction: where its shading brightens, its mean log gradient; a dent's light spread over
        # the gel reads under each LED as a shift along it (s42-shift1px), so that part of its evidence is its own
        toward = np.stack([gx.mean(1), gy.mean(1)], 1)
        toward /= np.linalg.norm(toward, axis=1, keepdims=True) + 1e-12
        gu = toward[:, :1] * gx + toward[:, 1:] * gy
    shift = np.array(shift, float)
    for _ in range(SHIFT_ITERATIONS):
        res = (_moved(img, shift) - ref)[:, kept]
        step, weight = np.zeros(2), np.ones_like(res)
        # an offset per LED (its log: an exposure or gain change) and a shift of its own along its direction, fitted
        # with the step: each term centred, then less its part along the LED's direction
        cx, cy, cr = _own_terms_out((gx, gy, res), gu, weight)
        for _ in range(SHIFT_REWEIGHTS):  # weights of what the step leaves: the shift's own residual is not an outlier
            left = cr - step[0] * cx - step[1] * cy
            scale = 1.4826 * float(np.median(np.abs(left))) + 1e-9
            weight = 1.0 / (1.0 + (left / (3.0 * scale)) ** 2)  # Cauchy: the dent's pixels count little
            cx, cy, cr = _own_terms_out((gx, gy, res), gu, weight)
            wx, wy = weight * cx, weight * cy
            normal = np.array([[np.sum(wx * cx), np.sum(wx * cy)], [np.sum(wx * cy), np.sum(wy * cy)]])
            step = np.linalg.solve(normal, np.array([np.sum(wx * cr), np.sum(wy * cr)]))
        shift -= step
    return shift


def _own_terms_out(values: tuple[np.ndarray, ...], along: np.ndarray | None, weight: np.ndarray) -> list[np.ndarray]:
    """Each of ``values`` (L, N) less, per row (each LED's blocks), its ``weight``-ed mean and its ``weight``-ed least
    squares part along ``along`` (L, N) (centred too; None: none): the LED's offset and its own shift along its
    direction eliminated from the shift's normal equations (a Schur complement: the shift fitting them jointly finds).
    """
    if along is None:
        return _centred(values, weight)
    (along,) = _centred((along,), weight)
    power = (weight * along * along).sum(1, keepdims=True) + 1e-12
    return [v - (weight * v * along).sum(1, keepdims=True) / power * along for v in _centred(values, weight)]


def _moved(img: np.ndarray, shift: np.ndarray) -> np.ndarray:
    """(n, h, w) -- ``img`` sampled at x + ``shift`` (blocks): the press moved back by it."""
    import cv2

    if not shift.any():
        return img
    h, w = img.shape[1:]
    rows, cols = np.mgrid[:h, :w].astype(np.float32)
    x, y = cols + np.float32(shift[0]), rows + np.float32(shift[1])
    return np.stack([cv2.remap(im, x, y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE) for im in img])


def shift_note(press: Press, reference: Press) -> str | None:
    """A warning naming the press and its shift against ``reference`` (the undeformed capture) when the shift reaches
    ``tolerances.CAMERA_SHIFT_PX``; None otherwise, or without a reference surface or with other image sizes."""
    if press.reference is None or reference.camera.shape != press.camera.shape:
        return None
    if len(reference.leds) != len(press.leds):
        return None

    def reference_blocks(step: int, block: int) -> np.ndarray:
        # the undeformed capture's, kept on disk under its images' bytes: a warm process need not decode them
        key = (reference.images_digest(), reference.response, step, block)
        return reuse.reused(
            "shift reference", key, lambda: log_blocks(reference.linear_led_images[::step], block), persist=True
        )

    dx, dy = camera_shift(reference_blocks, press.linear_led_images, np.isfinite(press.reference.depth))
    if np.hypot(dx, dy) < tolerances.CAMERA_SHIFT_PX:
        return None
    return (
        f"{press.folder}: the image is shifted by ({dx:+.1f}, {dy:+.1f}) px (x right, y down) against the undeformed "
        f"capture {reference.folder}: the camera moved between them? The solve compares them pixel by pixel: capture "
        f"a new reference (undeformed dome) and solve against it"
    )


def changed_blocks(ref: np.ndarray, img: np.ndarray, inner: np.ndarray, block: int) -> np.ndarray:
    """The blocks a dent changed: more than a camera shift of :data:`SHIFT_ALLOWANCE` pixels explains.

    Why: a cube's dent on the flat pad covers 62-75 % of the gel's pixels (its draping too), on the fingertip 6-13 %
    in the image's brighter, steeper part; its face, moved along the axis, changes its shading smoothly, as a shift
    would, so the Cauchy weights kept it and it pulled the fit by up to 1.4 px (q3's presses, s41-shiftcube). Its
    changes pass 5 % in the log; a shift changes a block by its gradient times the shift (a few tenths of a percent
    per pixel), and the noise of a block's log image is ~0.3 %.

    Parameters
    ----------
    ref, img : (n, h, w) float -- :func:`log_blocks` of the undeformed capture's and the press's LED images.
    inner : (h, w) bool -- the blocks the shift is measured on.
    block : side, pixels, of the blocks.

    Returns
    -------
    (h, w) bool -- the changed blocks among ``inner``, grown by :data:`SHIFT_CHANGE_GROW`.
    """
    change = img - ref
    noise = np.maximum(block_noise(change, inner), SHIFT_NOISE_FLOOR)
    # each LED's offset (an exposure change) is its most common change: the gel left undeformed changes alike, to
    # within the noise, while a dent's change spreads (its median was the dent's where it covers most of the gel)
    offset = [_most_common(c[inner], 2 * SHIFT_CHANGE_NOISE * n) for c, n in zip(change, noise)]
    change = change - np.asarray(offset, np.float32)[:, None, None]
    gy, gx = np.gradient(ref, axis=(1, 2))
    allowance = SHIFT_ALLOWANCE / block  # in blocks: the gradients are per block
    bound = allowance * np.hypot(gx, gy) + SHIFT_CHANGE_NOISE * noise[:, None, None]
    changed = (np.abs(change) > bound).any(axis=0) & inner
    return masks.dilate(changed, iterations=SHIFT_CHANGE_GROW) & inner


def block_noise(change: np.ndarray, inner: np.ndarray) -> np.ndarray:
    """(n,) -- each image's noise in ``change`` (n, h, w): the spread of its differences between neighbouring blocks
    over ``inner``, divided by sqrt 2 (a smooth change, a dent's or a shift's, hardly differs between neighbours;
    the median of their absolute values ignores its edges)."""
    pair = inner[:, 1:] & inner[:, :-1]
    step = (change[:, :, 1:] - change[:, :, :-1])[:, pair]
    step = step - np.median(step, axis=1, keepdims=True)
    return 1.4826 * np.median(np.abs(step), axis=1) / np.sqrt(2)


def _most_common(values: np.ndarray, width: float) -> float:
    """The median of the most ``values`` (N,) that a window ``width`` wide holds."""
    ordered = np.sort(values)
    held = np.searchsorted(ordered, ordered + width, side="right") - np.arange(len(ordered))
    first = int(np.argmax(held))
    return float(np.median(ordered[first : first + held[first]]))


def _centred(values: tuple[np.ndarray, ...], weight: np.ndarray) -> list[np.ndarray]:
    """Each of ``values`` (L, N) less its ``weight``-ed mean over each row (each LED's pixels)."""
    total = weight.sum(1, keepdims=True)
    return [v - (weight * v).sum(1, keepdims=True) / total for v in values]


def log_blocks(stack: np.ndarray, block: int) -> np.ndarray:
    """(n, h, w) float32 -- log of each image's channel mean averaged over ``block`` x ``block`` pixels."""
    import cv2

    out = []
    for image in stack:
        image = np.asarray(image, np.float32)
        if block > 1:  # the block means first: the channel mean then runs on 1 / block^2 of the pixels
            image = cv2.resize(image, None, fx=1 / block, fy=1 / block, interpolation=cv2.INTER_AREA)
        out.append(np.log(np.maximum(image.mean(-1), 1e-4)))
    return np.stack(out)
