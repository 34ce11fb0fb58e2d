"""Does the tri-colour frame hold the light of the press's LED images? A check of the LED images' order across the
tri-colour groups, and of the tri-colour frame itself.

Why: the tri-colour frame lights LEDs 1-4 red, 5-8 green and 9-12 blue at once (:func:`.leds.tricolor_groups`), so
each of its channels is the sum of its group's one-LED white images in that channel, times a gain (the tri-colour
exposure over the LED images', the camera's response to that LED colour): the twin renders it so
(``sim.press.tricolor_linear``), and its clean captures fit it within the images' noise: compared as the means of
small blocks (:func:`tricolor_samples`), which hold a fraction of a pixel's noise (0.2 % at the twin's default noise,
under 1 % at 16x its variance; 1.5 % and 6 % on single pixels, s40-trinoise), and the misfit allowed grows with the
noise the capture itself shows (:func:`noise_misfits`, measured between blocks 2 apart), so a noisier camera
(or a smaller frame's smaller blocks, or a Bayer camera's) is not warned. Two
LED images of different groups captured in each other's place break that sum, and exchanging the two back in it
mends it: that names them from the images alone, whatever the LED model (benchmarks/RESULTS.md, s37-swapcheck). In
core beside the capture: the solve wires it (:mod:`nlipscalib.solver.led_checks`), ``nlips capture`` runs it on each
press as it is captured (:func:`captured_tricolor_note`, from ``device.session``) and ``nlips calibrate-leds`` on its
undeformed captures (``solver.calibrate``), where a swapped pair would spoil every LED's calibration.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Collection, Sequence
from pathlib import Path
from typing import NamedTuple

import numpy as np

from . import tolerances
from .camera import Camera
from .capture import Press
from .errors import CaptureError
from .leds import TRICOLOR_NAMES, Led, tricolor_groups
from .press_meta import led_image_name
from .sensor_response import SensorResponse, linearise, undo_tone_curve
from .surface_files import Reference

GEL_SAMPLES = 2000
"""Gel pixels the check samples, at least (every k-th in raster order), as the solve's LED check
(``solver.led_checks.CHECK_PIXELS``: the same samples, so the same verdict at capture and at the solve)."""

GEL_BLOCK_PIXELS = 32_000
"""Pixels of each frame the check reads, at most: every k-th of the blocks holding the gel samples (in raster order)
is kept so that they hold no more (500 blocks of 8x8 px at 640x480, a quarter of those; at 160x120 and smaller
every block). The misfit's noise share is set by the blocks' size, not their number; fewer blocks keep its cost small
(reading 2000 blocks of 64 px in 14 frames cost ~40 ms of CPU, 500 ~10)."""


class TricolorFit(NamedTuple):
    """What :func:`tricolor_fit` found."""

    misfit: np.ndarray
    """(3,) float: each channel's RMS misfit over its RMS, the LED groups as designed."""
    exchanged: tuple[int, int] | None
    """The two LEDs (0-based, of different groups) whose groups exchanged fit the frame within
    :data:`~nlipscalib.core.tolerances.TRICOLOR_MISFIT` in every channel, best of all such pairs; None when the
    design's groups fit, or when no such pair does."""
    exchanged_misfit: float
    """The worst channel's misfit with ``exchanged``'s groups exchanged (nan when ``exchanged`` is None)."""
    sources: tuple[int, ...] = (0, 1, 2)
    """For each channel, the LED group whose light it holds most of (the design: (0, 1, 2), each its own)."""
    allowed: float = tolerances.TRICOLOR_MISFIT
    """The misfit allowed (:func:`allowed_misfit`): a channel's beyond it disagrees, an exchange within it fits."""
    noise: float = float("nan")
    """The worst channel's misfit the capture's own noise leaves (:func:`noise_misfits`; nan where not measured)."""


def channel_misfits(tricolor: np.ndarray, images: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each channel's misfit of the tri-colour frame to the LED images summed by group (:func:`channel_fit`'s
    first)."""
    return channel_fit(tricolor, images, groups)[0]


def channel_fit(tricolor: np.ndarray, images: np.ndarray, groups: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each channel of the tri-colour frame fitted by the LED images summed by group.

    Parameters
    ----------
    tricolor : (N, 3) float -- the tri-colour frame's linear light at N gel samples.
    images : (L, N, 3) float -- the L one-LED white images' linear light at the same samples.
    groups : (L,) int -- each image's tri-colour group (0 red, 1 green, 2 blue).

    Returns
    -------
    misfit : (3,) float64 -- per channel c: RMS of ``tricolor[:, c]`` minus its least-squares fit by the three
        groups' summed images in channel c (one gain each: the camera's colour response to each LED colour, the
        exposures' ratio), over the RMS of ``tricolor[:, c]``; inf for a channel without light.
    shares : (3, 3) float64 -- ``shares[c, g]``: the RMS of group g's fitted light in channel c over the channel's
        (a channel lit by its own group: near 1 on its own, near 0 elsewhere).
    """
    summed = group_sums(images, groups)
    misfit, shares = np.full(3, np.inf), np.zeros((3, 3))
    for c in range(3):
        design, seen = summed[:, :, c], tricolor[:, c]
        gains = channel_gains(design, seen)
        power = float(np.mean(seen * seen))
        if power > 0:
            misfit[c] = np.sqrt(np.mean((seen - design @ gains) ** 2) / power)
            shares[c] = np.abs(gains) * np.sqrt(np.mean(design * design, axis=0) / power)
    return misfit, shares


def group_sums(images: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(N, 3 groups, 3 channels) float: the (L, N, 3) ``images`` summed by their ``groups`` ((L,) int)."""
    return np.stack([images[groups == g].sum(0) for g in range(3)], axis=1)


def channel_gains(design: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """(3,) float: the least-squares gains of the three groups' summed light ``design`` ((N, 3)) in one channel of
    the frame, ``seen`` ((N,))."""
    return np.linalg.lstsq(design, seen, rcond=None)[0]


def tricolor_fit(
    tricolor: np.ndarray, images: np.ndarray, groups: np.ndarray, allowed: float = tolerances.TRICOLOR_MISFIT
) -> TricolorFit:
    """:func:`channel_misfits` of the design's groups and, when a channel misfits beyond ``allowed``
    (:func:`allowed_misfit`; by default :data:`~nlipscalib.core.tolerances.TRICOLOR_MISFIT`), of every pair of LEDs of
    different groups with their groups exchanged (arguments as there): the pair that fits best, when it fits within
    ``allowed``.

    Why every such pair: two images exchanged within a group leave every group's sum as it was (nothing here tells
    them); across groups, the pair's exchange is the one that mends all three channels (48 pairs of 12 LEDs, a few ms
    on 2000 samples)."""
    groups = np.asarray(groups)
    misfit, shares = channel_fit(tricolor, images, groups)
    sources = tuple(int(g) for g in np.argmax(shares, axis=1))
    if not np.max(misfit) > allowed:
        return TricolorFit(misfit, None, float("nan"), sources, allowed)
    best, best_misfit = None, np.inf
    for i, j in itertools.combinations(range(len(groups)), 2):
        if groups[i] == groups[j]:
            continue
        swapped = groups.copy()
        swapped[[i, j]] = groups[[j, i]]
        worst = float(np.max(channel_misfits(tricolor, images, swapped)))
        if worst < best_misfit:
            best, best_misfit = (i, j), worst
    if best_misfit > allowed:
        return TricolorFit(misfit, None, float("nan"), sources, allowed)
    return TricolorFit(misfit, best, best_misfit, sources, allowed)


def tricolor_block(shape: tuple[int, int]) -> int:
    """The side, in pixels, of the square blocks whose mean light :func:`tricolor_samples` compares for a frame of
    ``shape`` (H, W): one :data:`BLOCK_PER_FRAME`-th of its shorter side, at least 1 (8 px at 640x480, 2 at
    160x120, 1 at 64x48)."""
    return max(1, round(min(shape) / BLOCK_PER_FRAME))


BLOCK_PER_FRAME = 60
"""Blocks across a frame's shorter side (:func:`tricolor_block`). Why blocks: the frame's relation to the LED images
is linear, so it holds for any pixels' mean, and the disagreements the check is for (two LED images of different
groups exchanged, channels in another order, another press's frame) are smooth over a block; the pixels' noise is
not, and a block's mean holds 1/side of it. On single pixels the twin's clean presses misfit 1.5 % at its default
noise and 3.1 % / 6.3 % at 4x / 16x its noise variance, over the 3 % threshold (benchmarks/RESULTS.md,
s40-trinoise)."""


def block_pixels(pixels: np.ndarray, shape: tuple[int, int], side: int) -> np.ndarray:
    """(B, side * side) int: the flat indices (row-major) of each square block of ``side`` px that holds one of the
    flat pixel indices ``pixels`` ((N,) int), each block once, in raster order; blocks that cross the frame's
    bottom or right edge are left out."""
    return cell_pixels(block_cells(pixels, shape, side), shape, side)


def block_cells(pixels: np.ndarray, shape: tuple[int, int], side: int) -> np.ndarray:
    """(B,) int: :func:`block_pixels`' blocks as their indices in the frame's grid of whole blocks (row-major)."""
    height, width = shape
    rows, cols = np.divmod(np.asarray(pixels), width)
    rows, cols = rows // side, cols // side
    keep = (rows < height // side) & (cols < width // side)
    return np.unique(rows[keep] * (width // side) + cols[keep])


def cell_pixels(cells: np.ndarray, shape: tuple[int, int], side: int) -> np.ndarray:
    """(B, side * side) int: the flat pixel indices (row-major) of the blocks ``cells`` ((B,) int,
    :func:`block_cells`)."""
    top, left = np.divmod(np.asarray(cells), shape[1] // side)
    dy, dx = np.divmod(np.arange(side * side), side)
    return (top[:, None] * side + dy) * shape[1] + left[:, None] * side + dx


PARTNER_STEP = 2
"""Blocks between a block and each of the two partners whose light it is compared with to measure the noise
(:func:`partner_cells`): one block's gap, so that a Bayer camera's demosaicing, which mixes a pixel's neighbours up to
2 px away into it (the frame's colours interpolated from a quarter or half of its pixels), shares no raw pixel between
them (at 2 px blocks and larger)."""


def partner_cells(cells: np.ndarray, gel: np.ndarray, shape: tuple[int, int], side: int) -> np.ndarray:
    """(B, 2) int: for each block of ``cells`` ((B,) int, :func:`block_cells`), the two blocks :data:`PARTNER_STEP`
    blocks to its left and right, else above and below, where both are of the gel's blocks ``gel`` (sorted (G,) int);
    -1 where neither pair is.

    Why other blocks, not the block's own two halves (until s43): a block's mean less its two partners' mean holds
    1.5x the noise variance of one block's mean whatever the noise's correlation between neighbouring pixels, and a
    disagreement smooth over the dome, linear over the three blocks, cancels in it; the halves of one block shared
    their pixels' raw values through a Bayer camera's demosaicing and measured 0.4x the noise of its blocks' means (2x2
    px cells; 0.3-0.4x in 2 px blocks): every clean press of a noisy Bayer camera was warned (docs/experiments/
    RESULTS.md, s43-bayer)."""
    n_rows, n_cols = shape[0] // side, shape[1] // side
    rows, cols = np.divmod(np.asarray(cells), n_cols)
    out = np.full((len(rows), 2), -1)
    for dy, dx in ((0, PARTNER_STEP), (PARTNER_STEP, 0)):
        pair = []
        for sign in (-1, 1):
            r, c = rows + sign * dy, cols + sign * dx
            inside = (r >= 0) & (r < n_rows) & (c >= 0) & (c < n_cols)
            pair.append(np.where(inside, r * n_cols + c, -1))
        found = (out[:, 0] < 0) & np.isin(pair[0], gel) & np.isin(pair[1], gel)
        out[found] = np.stack(pair, axis=1)[found]
    return out


class BlockSamples(NamedTuple):
    """What :func:`block_samples` read: the frames' mean linear light over blocks of the gel, and the difference of
    pairs of blocks' means (:func:`partner_cells`), which holds their noise."""

    tricolor: np.ndarray
    """(n, 3) float64: the tri-colour frame's mean over each block."""
    images: np.ndarray
    """(L, n, 3) float64: each LED image's."""
    tricolor_pairs: np.ndarray | None
    """(m, 3) float64: the tri-colour frame's mean over a block less the mean of its two partner blocks' means
    (:func:`partner_cells`; None for 1 px blocks)."""
    images_pairs: np.ndarray | None
    """(L, m, 3) float64: each LED image's."""
    weight: float
    """The variance of a block's mean over that of its difference to its partners': 2/3 (blocks of independent
    noise)."""


def tricolor_samples(press: Press, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The tri-colour frame's and every LED image's mean linear light over the blocks (:func:`tricolor_block`,
    :func:`block_pixels`) that hold the flat pixel indices ``pixels`` ((N,) int, row-major; every k-th block, at most
    :data:`GEL_BLOCK_PIXELS` pixels), less the blocks with a pixel saturated in any of them: ((n, 3), (L, n, 3))
    float64, or None when fewer than 10 are left (:func:`block_samples`' first two)."""
    samples = block_samples(press, pixels)
    return None if samples is None else (samples.tricolor, samples.images)


def block_samples(press: Press, pixels: np.ndarray) -> BlockSamples | None:
    """:func:`tricolor_samples` with the difference of each block's mean and its two partner blocks' mean
    (:func:`partner_cells`; :class:`BlockSamples`; those with a pixel saturated in any of the three left out)."""
    shape = press.camera.shape
    side = tricolor_block(shape)
    gel = block_cells(pixels, shape, side)
    cells = gel[:: max(1, gel.size * side * side // GEL_BLOCK_PIXELS)]
    partners = partner_cells(cells, gel, shape, side) if side > 1 else np.full((len(cells), 2), -1)
    paired = partners[:, 0] >= 0
    blocks = cell_pixels(np.concatenate([cells, partners[paired].T.ravel()]), shape, side)  # (B + 2P, S)
    tri_stored, dark = _gather(press.tricolor, blocks), _gather(press.dark, blocks)  # (B + P, S, 3)
    stored = _gather(press.led_images, blocks)  # (L, B + P, S, 3)
    clipped = press.saturated(tri_stored).any(axis=(1, 2)) | press.saturated(stored).any(axis=(0, 2, 3))
    count = len(cells)
    if (~clipped[:count]).sum() < 10:
        return None
    black, white = press.response.black_level, press.response.white_level

    def light(frames: np.ndarray) -> np.ndarray:  # (..., B + 2P, S, 3) -> (..., B + 2P, 3)
        # linearising is linear: the light's means are the stored values' means linearised
        means = frames.sum(-2, dtype=np.float64) / blocks.shape[1]
        return linearise(means, dark.sum(-2, dtype=np.float64) / blocks.shape[1], black, white).astype(np.float64)

    tri, images = light(tri_stored), light(stored)
    kept = ~clipped[:count]
    if side == 1 or not paired.any():
        return BlockSamples(tri[:count][kept], images[:, :count][:, kept], None, None, 0.0)
    middle = np.flatnonzero(paired)  # each block with partners; its k-th partners at count + k, count + P + k
    before, after = count + np.arange(len(middle)), count + len(middle) + np.arange(len(middle))
    unclipped = ~clipped[middle] & ~clipped[before] & ~clipped[after]
    middle, before, after = middle[unclipped], before[unclipped], after[unclipped]

    def differenced(light: np.ndarray) -> np.ndarray:
        return light[..., middle, :] - (light[..., before, :] + light[..., after, :]) / 2

    return BlockSamples(tri[:count][kept], images[:, :count][:, kept], differenced(tri), differenced(images), 2 / 3)


def noise_misfits(samples: BlockSamples, groups: np.ndarray) -> np.ndarray:
    """(3,) float64: per channel, the misfit (as :func:`channel_fit`'s, RMS over the channel's RMS) that the
    capture's own noise leaves in the blocks' means, measured: the fit's residual (the design's groups, its gains)
    differenced between each block and its two partners 2 blocks either side (:func:`partner_cells`), whose noise is
    independent, times :attr:`BlockSamples.weight`'s root. A disagreement of the frame with the images, smooth over
    the dome (linear over the three blocks), cancels in it. nan where not measured (1 px blocks) or for a channel
    without light.

    Why measured, not modelled: shot noise varies with the light, a renderer's noise too, and a camera's with its
    gain and its demosaicing; the twin's clean 640x480 presses misfit 0.92-1.07x the noise measured between each
    block's halves (s41-tricheck), which a Bayer camera's demosaicing correlated (2.3x; 2.3-3.2x in 2 px blocks);
    between blocks and their partners 0.97-1.03x, with or without a Bayer camera (s43-bayer)."""
    if samples.tricolor_pairs is None:
        return np.full(3, np.nan)
    summed, pairs = group_sums(samples.images, groups), group_sums(samples.images_pairs, groups)
    noise = np.full(3, np.nan)
    for c in range(3):
        seen = samples.tricolor[:, c]
        gains = channel_gains(summed[:, :, c], seen)
        power = float(np.mean(seen * seen))
        if power > 0:
            residual = samples.tricolor_pairs[:, c] - pairs[:, :, c] @ gains
            noise[c] = np.sqrt(np.mean(residual * residual) * samples.weight / power)
    return noise


def allowed_misfit(noise: np.ndarray) -> float:
    """The misfit a capture's tri-colour frame may have and still hold its LED images' light:
    :data:`~nlipscalib.core.tolerances.TRICOLOR_NOISE_MARGIN` times the worst channel's ``noise`` ((3,) float,
    :func:`noise_misfits`), at least :data:`~nlipscalib.core.tolerances.TRICOLOR_MISFIT` (that alone where the
    noise is not measured)."""
    finite = noise[np.isfinite(noise)]
    worst = float(finite.max()) if finite.size else 0.0
    return max(tolerances.TRICOLOR_MISFIT, tolerances.TRICOLOR_NOISE_MARGIN * worst)


class TricolorVerdict(NamedTuple):
    """What :func:`tricolor_verdict` found of one press's tri-colour frame against its LED images."""

    kind: str
    """One of :data:`VERDICTS`: ``fits``, ``not judged`` (fewer than 3 LEDs, an LED subset, a frame made in memory, too
    few unsaturated samples, groups whose images do not tell them apart), ``unreadable`` (the frame cannot be
    read), or how it disagrees: ``colours`` (a channel holds another group's light: the camera's colour order, the
    controller's pattern), ``exchanged`` (two LED images of different groups captured in each other's place),
    ``misfit`` (no exchanged pair mends it: another press's frame, ...); ``said`` (the exchange found is of two LEDs
    the caller names as shown elsewhere, ``said``: the solve's LED checks named them, and a solve that used the images
    in the order they show is fitted by the frame)."""
    line: str | None
    """The one warning line naming the press (None when it fits, is not judged, or names a pair in ``said``)."""
    fit: TricolorFit | None = None
    """The fit behind it (None where nothing was fitted)."""

    @property
    def disagrees(self) -> bool:
        """Whether the frame was judged and does not hold the LED images' light."""
        return self.kind in DISAGREE

    def record(self) -> dict:
        """The verdict as JSON values, as a calibration dataset records it per press (docs/formats.md): ``verdict``
        (:attr:`kind`), ``misfit`` (per channel, or null), ``sources`` (each channel's group, or null),
        ``exchanged`` (the two LEDs, 0-based, or null) and, where it disagrees, ``line``. A channel without light
        has a null misfit (JSON has no infinity)."""
        fit = self.fit
        record = {
            "verdict": self.kind,
            "misfit": None if fit is None else [round(float(m), 4) if np.isfinite(m) else None for m in fit.misfit],
            "sources": None if fit is None else list(fit.sources),
            "exchanged": None if fit is None or fit.exchanged is None else list(fit.exchanged),
        }
        return record | ({"line": self.line} if self.disagrees else {})


DISAGREE = ("colours", "exchanged", "misfit")
"""The kinds of :class:`TricolorVerdict` that say the frame does not hold the LED images' light."""
VERDICTS = ("fits", "said", "not judged", "unreadable", *DISAGREE)
"""Every kind of :class:`TricolorVerdict`."""


def tricolor_note(press: Press, pixels: np.ndarray, names: list[str], said: Collection[int] = ()) -> str | None:
    """One warning line naming the press (and the two LED images exchanged, when their exchange mends it) when its
    tri-colour frame does not hold its LED images' light (:func:`tricolor_fit` at the gel samples ``pixels``); None
    when it does, or cannot be judged (fewer than 3 LEDs, an LED subset, too few unsaturated samples, LED groups
    whose images do not tell them apart: :func:`groups_apart`); the reader's line when the frame cannot be read (a
    truncated file): :func:`tricolor_verdict`'s line.

    ``names``: the LED images' file names, LED ``i`` at ``i``; ``said``: LEDs (0-based) already named as showing
    other LEDs' light (no line when the exchange found is theirs)."""
    return tricolor_verdict(press, pixels, names, said).line


def _gather(frames: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """(..., B, S, 3) ``frames``' ((..., H, W, 3)) values at the flat pixel indices ``blocks`` ((B, S) int): each
    pixel's three values taken as one item (a 6-byte void), 4-5x faster than indexing (N, 3) rows (640x480, 12 LEDs,
    2000 blocks of 64 px: 4 ms CPU against 18)."""
    frames = np.ascontiguousarray(frames)
    flat = frames.reshape(*frames.shape[:-3], -1, 3)
    items = flat.view(np.dtype((np.void, 3 * frames.itemsize))).reshape(flat.shape[:-1])
    taken = np.take(items, blocks, axis=-1)
    return taken.view(frames.dtype).reshape(*taken.shape, 3)


def tricolor_verdict(press: Press, pixels: np.ndarray, names: list[str], said: Collection[int] = ()) -> TricolorVerdict:
    """Whether the tri-colour frame of ``press`` holds its LED images' light, and the line that says it does not
    (arguments as :func:`tricolor_note`'s): the one copy of the check, which the solve, ``nlips capture``,
    ``nlips calibrate-leds`` and the calibration dataset's build use."""
    count = len(press.leds)
    listed = (press.meta.get("images") or {}).get("leds")
    if count < 3 or not isinstance(listed, list) or len(listed) != count:  # an LED subset: its groups are not these
        return TricolorVerdict("not judged", None)
    try:
        frame = press.tricolor
    except CaptureError as error:  # the solve does not need the frame: said, not refused
        return TricolorVerdict("unreadable", f"{error}; the tri-colour frame is not compared with the LED images")
    if not isinstance(frame, np.ndarray) or frame.shape != (*press.camera.shape, 3):  # a Press made in memory
        return TricolorVerdict("not judged", None)
    samples = block_samples(press, pixels)
    if samples is None:
        return TricolorVerdict("not judged", None)
    groups = tricolor_groups(count)
    if not groups_apart(samples.images, groups):
        return TricolorVerdict("not judged", None)
    noise = noise_misfits(samples, groups)
    fit = tricolor_fit(samples.tricolor, samples.images, groups, allowed_misfit(noise))
    fit = fit._replace(noise=float(np.nanmax(noise)) if np.isfinite(noise).any() else float("nan"))
    tri = (press.meta.get("images") or {}).get("tricolor", "the tri-colour frame")
    if fit.sources != (0, 1, 2):  # the gains take any colours: a frame lit in others fits as well
        line = (
            f"{press.folder}: {tri} holds the light of LED groups in other colours than LEDs {_groups_said(groups)} "
            f"({sources_said(fit.sources)}): the LED controller's tri-colour pattern, or the camera's colour order "
            "(RGB / BGR); a network trained or run on this press's tri-colour frame would not match its LED images"
        )
        return TricolorVerdict("colours", line, fit)
    if not np.max(fit.misfit) > fit.allowed:
        return TricolorVerdict("fits", None, fit)
    shares = ", ".join(f"{TRICOLOR_NAMES[c]} {100 * fit.misfit[c]:.1f} %" for c in range(3))
    head = (
        f"{press.folder}: {tri} does not hold the light of the LED images lit in its colours (each channel against "
        f"its LED groups' images summed: {shares} of the channel misfit; {allowed_said(fit)})"
    )
    if fit.exchanged is None:
        line = (
            f"{head}: a tri-colour frame of another press, its LED groups lit in other colours than LEDs "
            f"{_groups_said(groups)}, or LED images out of order; the solve uses the LED images, a network trained "
            "or run on this press's tri-colour frame would not match them"
        )
        return TricolorVerdict("misfit", line, fit)
    i, j = fit.exchanged
    if {i, j} <= set(said):
        return TricolorVerdict("said", None, fit)
    line = (
        f"{head}: with {names[i]} ({TRICOLOR_NAMES[groups[i]]} group) and {names[j]} ({TRICOLOR_NAMES[groups[j]]}) "
        f"exchanged it fits ({100 * fit.exchanged_misfit:.1f} %): the two images were captured in each other's place "
        "(the LED wiring, the controller's LED order or the images' order): check them"
    )
    return TricolorVerdict("exchanged", line, fit)


def allowed_said(fit: TricolorFit) -> str:
    """ "3 % allowed, this capture's noise leaves 0.4 %" (or "4.5 % allowed: 1.5x the 3.0 % this capture's noise
    leaves") for ``fit``'s :attr:`~TricolorFit.allowed` and :attr:`~TricolorFit.noise`."""
    if not np.isfinite(fit.noise):
        return f"{100 * fit.allowed:.0f} % allowed"
    if fit.allowed > tolerances.TRICOLOR_MISFIT:
        margin = tolerances.TRICOLOR_NOISE_MARGIN
        return f"{100 * fit.allowed:.1f} % allowed: {margin:g}x the {100 * fit.noise:.1f} % this capture's noise leaves"
    return f"{100 * fit.allowed:.0f} % allowed, this capture's noise leaves {100 * fit.noise:.1f} %"


def sources_said(sources: Sequence[int]) -> str:
    """ "its red channel the blue group's, its blue channel the red group's" for a fit's ``sources`` (each
    channel's group), the channels that hold their own group's light left unsaid."""
    return ", ".join(
        f"its {TRICOLOR_NAMES[c]} channel the {TRICOLOR_NAMES[g]} group's" for c, g in enumerate(sources) if g != c
    )


def groups_apart(images: np.ndarray, groups: np.ndarray) -> bool:
    """Whether the LED groups' summed images ((L, N, 3) ``images`` by ``groups``, as :func:`channel_fit`'s) tell the
    groups apart in every channel (:data:`~nlipscalib.core.tolerances.TRICOLOR_GROUPS_APART`): where they do not
    (frames lit evenly) any gains fit the frame and its colours cannot be told."""
    summed = group_sums(images, groups)
    for c in range(3):
        norms = np.linalg.norm(summed[:, :, c], axis=0)
        if not np.all(norms > 0):
            return False
        values = np.linalg.svd(summed[:, :, c] / norms, compute_uv=False)
        if not values[-1] >= tolerances.TRICOLOR_GROUPS_APART * values[0]:
            return False
    return True


def gel_samples(reference: Reference | None, shape: tuple[int, int]) -> np.ndarray:
    """(N,) int: every k-th gel pixel (flat, row-major) of ``reference`` (the whole ``shape`` (H, W) frame when None),
    at least :data:`GEL_SAMPLES` of them."""
    gel = np.ones(shape, bool) if reference is None else np.isfinite(reference.depth)
    index = np.flatnonzero(gel)
    return index[:: max(1, index.size // GEL_SAMPLES)]


def press_tricolor_note(press: Press, said: Collection[int] = ()) -> str | None:
    """:func:`tricolor_note` of ``press`` at its :func:`gel_samples`, its LED images named as its meta.json names
    them (``nlips calibrate-leds``' check of its undeformed captures)."""
    return press_tricolor_verdict(press, said).line


def press_tricolor_verdict(press: Press, said: Collection[int] = ()) -> TricolorVerdict:
    """:func:`tricolor_verdict` of ``press`` at its :func:`gel_samples`, its LED images named as its meta.json names
    them (the calibration dataset's check of each press and of its undeformed capture)."""
    listed = (press.meta.get("images") or {}).get("leds")
    names = list(listed) if isinstance(listed, list) else [led_image_name(i) for i in range(len(press.leds))]
    return tricolor_verdict(press, gel_samples(press.reference, press.camera.shape), names, said)


def captured_tricolor_note(
    folder: str | Path,
    frames: dict[str, np.ndarray],
    camera: Camera,
    leds: Sequence[Led],
    response: SensorResponse,
    reference: Reference | None,
) -> str | None:
    """:func:`tricolor_note` of a press just captured, from its frames in memory (nothing decoded), for
    ``nlips capture`` to say at once, before more presses are taken with the LEDs wired wrong.

    Parameters
    ----------
    folder : the press folder the frames are written to (for the message).
    frames : name -> (H, W, 3) uint16 stored frame as the camera encoded it: ``dark``, ``tricolor``, ``led_01`` ...
        (``device.session.capture_frames``; a declared tone curve, ``response.tone_curve()``, is undone on copies).
    camera, leds, response, reference : the session's (``device.session.Rig``).
    """
    names = [led_image_name(i) for i in range(len(leds))]
    stored = {"dark": frames["dark"], "tricolor": frames["tricolor"]}
    stored["leds"] = np.stack([frames[name.removesuffix(".png")] for name in names])
    if (curve := response.tone_curve()) is not None:  # judged in the light, as the solve reads the written press
        stored = {key: undo_tone_curve(frame.copy(), curve) for key, frame in stored.items()}
        response = dataclasses.replace(response, camera_response="linear", response_curve=None)
    press = Press(
        folder=Path(folder),
        camera=camera,
        leds=tuple(leds),
        response=response,
        dark=stored["dark"],
        led_images=stored["leds"],
        tricolor=stored["tricolor"],
        meta={"images": {"dark": "dark.png", "leds": names, "tricolor": "tricolor.png"}},
        reference=reference,
    )
    return tricolor_note(press, gel_samples(reference, camera.shape), names)


def _groups_said(groups: np.ndarray) -> str:
    """ "1-4 red, 5-8 green, 9-12 blue" for ``groups`` ((L,) int, contiguous runs)."""
    runs = []
    for g in range(3):
        members = np.flatnonzero(groups == g) + 1
        runs.append(f"{members[0]}-{members[-1]} {TRICOLOR_NAMES[g]}")
    return ", ".join(runs)
