"""Anchoring to the reference where a press's gel looks undeformed: the prior's weights (:func:`anchor_weights`; on a
view past the gel its undeformed outline held to the reference),
``--roi auto``'s box widened until it holds enough such gel (:func:`widen_to_anchor`), and a solve's depth (a box's,
``--roi auto`` or ``--roi X0 Y0 W H``, or the whole gel's) scaled onto the reference at its anchored pixels
(:func:`rescale_to_anchors`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core import tolerances
from ..core.masks import components
from .contact import ContactMap
from .nlips import SolveResult
from .outline import gel_outline, outline_rings

ANCHOR_MIN_FRACTION = 0.02
"""Anchoring is off (weak evidence) when fewer than this fraction of the gel's pixels fit the undeformed model at noise
level (:func:`anchor_weights`); the auto ROI is then not widened for anchors either (:func:`widen_to_anchor`)."""

OUTLINE_HOLD = 1e5
"""An anchored pixel of the gel's outline (:func:`.outline.gel_outline`, a view past the gel), or of the ring inside
it (:data:`OUTLINE_HOLD_WIDTH`), weighs this many times an anchor (``anchor_weight``): its depth is held to the
reference's. Why: the outline's light is the gel's over only a part of the pixel, mixed by the lens's defocus with
the black beyond, and its bounce light (2.3x its direct light) is scaled by that coverage where the image model's is
not; at an anchor's weight its data pulled its depth off the reference, and the outline's and its neighbours'
normals with it (``nlipstac_wide`` 160x120, one bounce, a sphere away from the outline, whole frame: the outline's
AAE 1.74 deg with calibrated disks, 4.17 with the design LEDs, against 0.57 / 1.36 in the gel's middle). Its data
left out without the hold moved its depth further (+26 um: only the smoothness held it; outline 2.02 deg), and its
light divided by its true coverage (the render's alpha through the lens's blur) solved worse than as it is (1.92).
1e4 and 1e5 held alike, ~1e3 a little less. Benchmarks/RESULTS.md, s37-outline."""

OUTLINE_HOLD_WIDTH = 2
"""Rings held from the outline in at the full :data:`OUTLINE_HOLD`: the outline and the ring inside it. Why two: a
pixel's normal is its depth's slope to its neighbours, and the outline's inner neighbour kept the solve's say over it.
The same solves with the outline alone held: outline 0.87 / 1.13 deg, next ring 1.10 / 2.03, whole gel 0.682 / 1.947;
with two rings 0.47 / 0.43, 0.35 / 0.62, 0.644 / 1.890 (base 1.74 / 4.17, 1.33 / 3.92, 0.713 / 2.038)."""

OUTLINE_HOLD_TAPER = 6
"""Rings inside the :data:`OUTLINE_HOLD_WIDTH` whose anchored pixels are held :data:`OUTLINE_HOLD_TAPER_STEP` times
less a ring further in (2e4, 4e3, 800, 160, 32, 6.4 x an anchor), down to near an anchor's weight. Why: a hold that
stepped from 1e5 to 1 x an anchor made the first ring beyond it take up all the disagreement between the held depth
and the data's -- the rim band's bounce light (1.9x its direct light at ring 2, 1.7x at ring 3), a design-LED solve's
rim bulge (+33 um at rings 3-4), the flank of a dent that reaches the outline (320x240 ``nlipstac_wide``, a cube at
polar 70, disks: its contact's pixels in rings 3-4 9.84 -> 12.46 deg with the step, 9.57 tapered a decade a ring over
4 rings; benchmarks/RESULTS.md, s38-outline34)."""

OUTLINE_HOLD_TAPER_STEP = 5.0
"""How many times less each ring of the taper (:data:`OUTLINE_HOLD_TAPER`) is held than the ring outside it. Why 5
over 6 rings: of the tapers that end near an anchor's weight, measured on 18 solves at 160x120 (the flat pad and the
wide view, spheres and cubes, whole frame and ``--roi auto``, design LEDs and calibrated disks; benchmarks/RESULTS.md,
s39-outline), x30 over 3 rings was worse than x10 over 4 (s38's) in 15 (whole gel up to +0.16 deg), x7 over 5 better
in 15, **x5 over 6 better in 16** (the design-LED wide sphere 1.686 -> 1.341 deg, the disks' 0.584 -> 0.536), x4 over
7 better in 16 but past the turn of a dent at the outline (the polar-70 cube's auto box, disks: 1.442 / 1.389 / 1.404),
x3 over 10 worse in 3 (that box 1.675). The one row x5 lost (+0.014) is a box the outline does not reach, no longer
held (:data:`OUTLINE_HOLD_MIN_SHARE`). Its known cost, the design-LED whole frames' contact depth (76.0 -> 88.1 um on
the wide view's polar-20 sphere): not the dent's shape (its spread 29.9 -> 30.5 um) nor its level as solved (61.1 um
RMSE before the rescale, 64.7 with x10 over 4) but :func:`rescale_to_anchors`: the taper flattens the point model's rim
bulge, so the anchors' median falls in the trough inside it and scales the depth by 1.00138 (x10 over 4: 1.00058),
17 um more at the dent (benchmarks/RESULTS.md, s40-outline); with the median weighed by nearness to the contact
(:data:`RESCALE_FALLOFF`, s40-rescale) 74.6 um, below the untapered 76.0."""

OUTLINE_HOLD_MIN_SHARE = 0.02
"""The outline is held only where its anchored pixels are at least this share of the solve region's own border
(:func:`outline_share`: on a whole-frame solve the gel's outline, in a box its edges and the outline within them).
Why: the held depth pins the depth level where it lies. A ``--roi auto`` box whose corner reached only the rings inside
the outline (the flat pad's sphere: none of the outline in its 354-pixel border, 5 pixels of the next ring and 187 of
the taper held) pinned the level at that corner against the design LEDs' level (0.7 % off) and the box bent to it:
contact 0.874 -> 0.945 deg, whole gel 0.891 -> 0.963. Over 21 presses' auto boxes (42 solves, s39-outline) every
share from the smallest met, 0.043, up held with gains where the box reaches a dent at the outline (the wide view's
sphere at polar 57, 9 of 212: whole gel 2.834 -> 2.018 deg unheld -> held with the design LEDs, 1.397 -> 1.066 with
disks); 2 % (7 of a 354-pixel border) lies between none and that. What no share separates: the flat pad's sphere
with the design LEDs loses contact AAE held at every share met, 0.085-0.355 (+0.05-0.10 deg; its disks lose none).
Why: a box's hold is on one side. Unheld, those boxes' depth is off +46-70 um at the held pixels and +88-116 um on the
far side (the point model's level, its error growing away from the pad's edge); pinned at 0 on one side only, the
box tilts 33-59 % more the same way and the contact's normals with it (a tilt common to the contact +0.08-0.22 deg,
the rest -0.04 to +0.06). Where the unheld error grows toward the outline (the flat cubes: +129-223 um held side, -19
to -105 far side) the same hold untilts the box. No truth-free measure of an unheld solve (the held pixels' depth off
the reference against the plain anchors', the residual) separates the two (benchmarks/RESULTS.md, s40-outline)."""


RESCALE_FALLOFF = 0.1
"""The depth rescale (:func:`rescale_to_anchors`) weighs an anchored pixel ``1 / (1 + d / (RESCALE_FALLOFF * W))``,
d its distance in pixels from the solve's contact (the largest connected patch of solved pixels not anchored), W the
image's width: the median of reference over solved depth is taken mostly near the contact, and the far gel still
counts (a ring of anchors at distance d holds ~d pixels at ~1/d weight each). Why: the solved depth's error off
the reference is a radial wave about the image's centre (the point LED model's; the 640x480 bench renders, whole
frame: log(reference / solved) -4.3 permille at the centre, -2.2 at a third of the width out, -3 at the gel's edge),
so the median over all anchors lands where the far gel puts it, not where the contact lies (cube1 whole frame: its
contact wants -4.9, the anchors near it say -4.4, all of them -3.2: contact depth RMSE 29.6 um). Anchors near the
contact alone (within 10 px) follow the wave there but lose where the contact's own solved depth sits off the wave
(sphere1 and coin1: +0.3 to +1.3 permille over the wave at the same radius, a bias of the dent's solve no anchor
sees): sphere1 whole 10.5 -> 13.1 um, coin1 --roi auto 55.5 -> 59.2. On 29 solves (the 22 twin rows of s40-outline
and the README's seven bench cases, through the CLI; benchmarks/RESULTS.md, s40-rescale) a fall-off of 0.1 W was
better than the plain median in 19 rows (sphere1 whole 10.5 -> 7.9 um, cube1 whole 29.6 -> 25.4), within 3 % in 8
(no bench case worse than +0.9 %), worse in 2 (+4.2, +5.4 %: the wide view's polar-70 whole frames with the design
LEDs, whose contact reaches the held outline); 0.05 W kept more of the near anchors' gains but lost 2.1 % on a bench
case, 0.2 W kept less."""


def anchor_weights(
    contact: ContactMap,
    mask: np.ndarray,
    weight: float,
    factor: float,
    min_fraction: float = ANCHOR_MIN_FRACTION,
    max_relative: float = 0.05,
) -> tuple[np.ndarray | None, str]:
    """Prior weight multipliers and a report line: ``1 + weight`` where the data show the gel undeformed, ``1 + weight
    * OUTLINE_HOLD`` where such a pixel is on the gel's outline or the ring inside it (a view past the gel:
    :data:`OUTLINE_HOLD`), :data:`OUTLINE_HOLD_TAPER_STEP` times less a ring further in for
    :data:`OUTLINE_HOLD_TAPER` rings; no hold where the outline's anchored pixels are under
    :data:`OUTLINE_HOLD_MIN_SHARE` of the region's border.

    Parameters
    ----------
    contact : ContactMap
    mask : (H, W) bool -- the solve mask.
    weight : SolverOptions.anchor_weight (0: off).
    factor : a pixel is undeformed when its misfit is within ``factor`` times the noise-only misfit.
    min_fraction : evidence is weak -- no anchoring -- when fewer than this fraction of the gel's
        pixels fit at noise level (the undeformed model does not explain the data at all, e.g. strong
        unmodelled interreflection or a wrong LED model).
    max_relative : a pixel's verdict counts only when its threshold, ``factor`` times the noise-only
        misfit, is at most this fraction of its image level: with more noise a real dent (a 1 deg
        tilt changes the shading by ~2 %) would pass as undeformed.

    Returns
    -------
    weights : (H, W) float64 or None
    note : str -- what was decided and why.
    """
    if weight <= 0:
        return None, "anchoring off (anchor_weight = 0)"
    gel = np.isfinite(contact.misfit)
    sharp = factor * contact.expected <= max_relative * np.nan_to_num(contact.level)
    undeformed = contact.undeformed(factor) & gel & sharp
    fraction = float(undeformed.sum()) / max(int(gel.sum()), 1)
    if contact.noise <= 0 or fraction < min_fraction:
        return None, (
            f"anchoring off: weak evidence (only {100 * fraction:.1f} % of the gel fits the undeformed model within "
            f"{factor:g} x the noise level {contact.noise:.2g} at a threshold below {100 * max_relative:g} % of the "
            f"image)"
        )
    pins = undeformed & mask
    weights = np.ones(mask.shape)
    weights[pins] += weight
    note = f"anchored {int(pins.sum())} of {int(mask.sum())} pixels (misfit within {factor:g} x noise)"
    ring = outline_rings(gel, OUTLINE_HOLD_WIDTH + OUTLINE_HOLD_TAPER)  # none on a gel-filling view: as it was
    held = pins & (ring >= 0)
    if not held.any():
        return weights, note
    share = outline_share(pins & (ring == 0), mask & gel)
    if share < OUTLINE_HOLD_MIN_SHARE:  # a corner of the outline, or none of it: the hold would pin a level there
        return weights, note + (
            f"; the gel's outline not held: its anchored pixels are {100 * share:.1f} % of the region's border "
            f"(under {100 * OUTLINE_HOLD_MIN_SHARE:g} %)"
        )
    steps = np.maximum(ring[held] - (OUTLINE_HOLD_WIDTH - 1), 0)  # 0 on the two outer rings, 1, 2, ... inside
    weights[held] = 1 + weight * OUTLINE_HOLD / OUTLINE_HOLD_TAPER_STEP**steps
    full = int((held & (ring < OUTLINE_HOLD_WIDTH)).sum())
    note += (
        f", {full} of them at the gel's outline held to the reference ({int(held.sum()) - full} more within "
        f"{OUTLINE_HOLD_WIDTH + OUTLINE_HOLD_TAPER} px of it, less)"
    )
    return weights, note


def outline_share(outline: np.ndarray, region: np.ndarray) -> float:
    """The share of ``region``'s border (:func:`.outline.gel_outline` of it: its pixels beside a pixel off it) that
    ``outline`` covers; 0 for an empty region.

    outline : (H, W) bool -- the gel's outline pixels to count (those anchored in the region);
    region : (H, W) bool -- the solve's pixels on the gel (the whole gel, or a box's part of it).
    """
    border = int(gel_outline(region).sum())
    return float((outline & region).sum()) / border if border else 0.0


def widen_to_anchor(
    contact: ContactMap, box: tuple[int, int, int, int], shape: tuple[int, int], step: int = 8
) -> tuple[tuple[int, int, int, int], float, float]:
    """``box`` (x0, y0, w, h, pixels) widened by ``step`` pixels at a time, within the image of ``shape`` (H, W),
    until :data:`tolerances.ROI_MIN_UNDEFORMED_SHARE` of its gel pixels look undeformed (the pixels anchoring pins to
    the reference), or it is the whole image; not where anchoring is off (:data:`ANCHOR_MIN_FRACTION`: a noise-free
    render, whose model error leaves next to no pixel within noise), nor where the whole image holds no larger share
    than ``box``: most of the gel misfits the undeformed model (the realistic twin's corners: vignetting, the view
    through the refracting gel), so widening adds misfit, not anchors (the realistic twin's sphere press: 3.3 % in the
    dent's box, 2.8 % in the whole image, whose solve scored 3.95 deg over the contact against the box's 3.14;
    benchmarks/RESULTS.md, s32-docwalk).

    Returns
    -------
    box : (x0, y0, w, h) pixels -- ``box`` itself when it holds enough, or when widening cannot raise its share.
    before, after : float -- the share of undeformed gel pixels in ``box`` and in the returned box.
    """
    H, W = shape
    valid = np.isfinite(contact.misfit)
    undeformed = contact.undeformed(tolerances.ANCHOR_NOISE_FACTOR) & valid
    x0, y0, w, h = box
    x1, y1 = x0 + w, y0 + h

    def share() -> float:
        return float(undeformed[y0:y1, x0:x1].sum()) / max(int(valid[y0:y1, x0:x1].sum()), 1)

    first = now = share()
    if float(undeformed.sum()) < ANCHOR_MIN_FRACTION * max(int(valid.sum()), 1):
        return box, first, first  # anchoring is off (anchor_weights): nothing to widen for
    while now < tolerances.ROI_MIN_UNDEFORMED_SHARE and (x0, y0, x1, y1) != (0, 0, W, H):
        x0, y0, x1, y1 = max(x0 - step, 0), max(y0 - step, 0), min(x1 + step, W), min(y1 + step, H)
        now = share()
    if now < tolerances.ROI_MIN_UNDEFORMED_SHARE and now <= first:
        return box, first, first  # the whole image anchors no better than the box: keep the box
    return (int(x0), int(y0), int(x1 - x0), int(y1 - y0)), first, now


def rescale_to_anchors(
    result: SolveResult, reference_depth: np.ndarray, weights: np.ndarray | None
) -> tuple[SolveResult, float | None]:
    """``result`` with its depth and points scaled about the camera's centre by the median over the anchored pixels
    (``weights`` > 1, reconstructed) of reference over solved depth, each weighed by its nearness to the contact
    (:data:`RESCALE_FALLOFF`, :func:`contact_distance`), and that scale (None, ``result`` unchanged: no anchored
    pixel).

    Why: the data pull the depth scale off the reference against the anchors, in a box (``--roi auto``'s or an
    explicit one: 0.1-0.5 %, cube1's outer ring 0.074 mm too far, its contact's depth RMSE 0.069 mm) and on the whole
    gel (0.2-0.3 %); a uniform scale about the camera's centre leaves every normal as it is, so the depth alone moves
    (benchmarks/RESULTS.md, s31-rimdepth, s31-roiscale, s31-wholescale). Weighing the anchors more instead (3x in a
    box) moved normals: 0.02-0.04 deg better on the one-bounce twin presses, 0.01-0.06 deg worse on the demo's
    direct-light presses and a small sphere at 160x120: left out (the lead's check, thirty-first session). The
    albedo stays the solve's.

    Parameters
    ----------
    result : SolveResult of the box or the whole gel.
    reference_depth : (H, W) float, mm -- the undeformed surface's z (the prior; NaN off the gel).
    weights : (H, W) float or None -- :func:`anchor_weights`'s multipliers.

    Returns
    -------
    result : SolveResult -- ``depth`` and ``points`` times the scale; ``report["anchor_scale"]`` the scale.
    scale : float or None -- unitless.
    """
    if weights is None:
        return result, None
    solved = result.reconstructed & np.isfinite(reference_depth)
    anchored = (weights > 1) & solved
    if not anchored.any():
        return result, None
    ratio = np.log(reference_depth[anchored]) - np.log(result.depth[anchored].astype(np.float64))
    near = 1.0 / (1.0 + contact_distance(solved & (weights <= 1))[anchored] / (RESCALE_FALLOFF * weights.shape[1]))
    scale = float(np.exp(weighted_median(ratio, near)))
    report = {**result.report, "anchor_scale": scale}
    depth, points = (
        (result.depth * scale).astype(result.depth.dtype),
        (result.points * scale).astype(result.points.dtype),
    )
    return dataclasses.replace(result, depth=depth, points=points, report=report), scale


def contact_distance(free: np.ndarray) -> np.ndarray:
    """(H, W) float, pixels -- each pixel's distance from the largest 4-connected patch of ``free`` (the solve's
    contact: its solved pixels not anchored); zero everywhere where ``free`` is empty (every anchor then weighs alike).

    free : (H, W) bool -- solved pixels that anchoring left free (the data do not show them undeformed).
    """
    labels, sizes = components(free)
    if not sizes.size:
        return np.zeros(free.shape)
    import cv2  # here, as core.masks does: importing the solver imports no OpenCV (nor scipy.ndimage, ~0.05 s)

    off = (labels != 1 + int(np.argmax(sizes))).astype(np.uint8)
    return cv2.distanceTransform(off, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).astype(np.float64)  # exact Euclidean


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The lower weighted median: the smallest of ``values`` (N,) at which the cumulative ``weights`` (N,) > 0 reach
    half their sum (numpy's ``quantile(..., weights=)`` is numpy >= 2.0; the package supports 1.26)."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
