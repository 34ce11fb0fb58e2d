"""How :func:`.integrate.integrate_on_dome` splits the changed pixels: one box, else per 4-connected region group
a box, an edge box (with its :data:`Edges`) or bounds for the other paths, each grown to FFT-friendly sides.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeAlias

import numpy as np

from ..core.errors import ShapeError

Bounds: TypeAlias = "Sequence[int]"
"""Pixel bounds [r0, r1, c0, c1): rows r0 to r1 - 1, columns c0 to c1 - 1."""


MAX_SPLIT_REGIONS = 256
"""Most 4-connected regions of changed pixels that "auto" sorts into boxes one by one when their common box does
not apply; beyond it (a frame flagged all over) every changed pixel takes the sparse path at once."""


Box: TypeAlias = "tuple[slice, slice]"
"""(rows, cols) slices of a box: its interior and the ring of fixed reference pixels around it."""


Edges: TypeAlias = "tuple[int, int]"
"""Per axis (rows, columns), where an edge box meets the image border: -1 at index 0, +1 at the last, 0 not,
:data:`BOTH_SIDES` at both (the box spans that axis: a natural side at each end, a type-II cosine transform)."""


BOTH_SIDES = 2
"""The :data:`Edges` value of an axis whose box spans the whole image (a contact across its width or height)."""


def _regions(
    unknown: np.ndarray, on_gel: np.ndarray, method: str
) -> tuple[list[Box], list[tuple[Box, Edges]], list[Box]]:
    """The boxes to solve with sines, the edge boxes (with their :data:`Edges`), and the bounds whose changed
    pixels to solve with SuperLU (each on its own; no changed pixel of one is in another's, nor any of their
    neighbours).

    One box around every changed pixel where it applies. Where it does not ("auto": a contact pressed at the
    edge of the view, a speck of noise at the image border), the changed pixels split into 4-connected regions:
    the least-squares equations of one region share no unknown with another's, so each region group is solved
    on its own -- in a box where its box applies, in an edge box where its bounds pass the image border by the
    ring on one side of an axis (:mod:`.integrate`'s docstring), else on the sparse path. Bounds (grown by the ring)
    that share a pixel are merged first: one box's solved interior must not be another's fixed ring or a sparse
    region's known neighbour, so a region whose box does not apply takes every box it overlaps with it.
    """
    if method == "sparse":
        return [], [], [_grown_bounds(unknown)]
    box = _box(unknown, on_gel)
    if box is not None:
        return [box], [], []
    if method == "box":
        raise ShapeError("the changed pixels' box leaves the gel or touches the image border: use 'sparse'")
    groups = _region_groups(unknown)
    if groups is None:
        return [], [], [_grown_bounds(unknown)]
    # merged bounds share no pixel: a group whose bounds do not fit took every group it overlapped with it
    H, W = unknown.shape
    rects = [(max(g[0], 0), min(g[1], H), max(g[2], 0), min(g[3], W)) for g in groups]  # within the image
    edges = [(0, 0) if _fits(g[:4], on_gel) else _edge_fits(g[:4], on_gel) for g in groups]
    boxes, edge_boxes = [], []
    for i in [i for i, e in enumerate(edges) if e is not None]:  # grown one by one, clear of the others as they are
        box = _faster(rects[i], on_gel, rects[:i] + rects[i + 1 :], edges[i])
        rects[i] = (box[0].start, box[0].stop, box[1].start, box[1].stop)
        if edges[i] == (0, 0):
            boxes.append(box)
        else:
            edge_boxes.append((box, edges[i]))
    sparse = [(slice(r0, r1), slice(c0, c1)) for (r0, r1, c0, c1), e in zip(rects, edges) if e is None]
    return boxes, edge_boxes, sparse


def _region_groups(unknown: np.ndarray) -> list[list] | None:
    """The 4-connected regions of ``unknown``'s pixels as groups [r0, r1, c0, c1, labels] (bounds grown by the ring,
    may pass the image border), merged until no two share a pixel; None beyond :data:`MAX_SPLIT_REGIONS` regions."""
    from scipy import ndimage

    labels, count = ndimage.label(unknown)
    if count > MAX_SPLIT_REGIONS:
        return None
    # each region's bounds grown by one pixel (its ring): [r0, r1, c0, c1), with the regions it holds
    groups = [
        [s[0].start - 1, s[0].stop + 1, s[1].start - 1, s[1].stop + 1, [k + 1]]
        for k, s in enumerate(ndimage.find_objects(labels))
    ]
    return _merge_overlapping(groups)


def _merge_overlapping(groups: list[list]) -> list[list]:
    """Groups ([r0, r1, c0, c1, labels]) merged until no two bounds share a pixel."""
    merged = True
    while merged:
        merged = False
        out: list[list] = []
        for g in groups:
            for o in out:
                if _overlap(g, o):
                    o[0], o[1], o[2], o[3] = min(o[0], g[0]), max(o[1], g[1]), min(o[2], g[2]), max(o[3], g[3])
                    o[4] = o[4] + g[4]
                    merged = True
                    break
            else:
                out.append(g)
        groups = out
    return groups


def _overlap(a: Bounds, b: Bounds) -> bool:
    """Whether bounds a and b ([r0, r1, c0, c1), half-open) share a pixel."""
    return a[0] < b[1] and b[0] < a[1] and a[2] < b[3] and b[2] < a[3]


def _fits(rect: Bounds, on_gel: np.ndarray) -> bool:
    """Whether bounds [r0, r1, c0, c1) lie inside the image and on the gel (a box solve applies)."""
    r0, r1, c0, c1 = rect
    H, W = on_gel.shape
    return r0 >= 0 and c0 >= 0 and r1 <= H and c1 <= W and bool(on_gel[r0:r1, c0:c1].all())


def _edge_fits(rect: Bounds, on_gel: np.ndarray) -> Edges | None:
    """The :data:`Edges` of bounds [r0, r1, c0, c1) (changed pixels' bounds grown by the ring) that pass the image
    border, each side by the ring only, and lie on the gel within the image; else None (also where both axes
    pass both of their sides: that box would have no fixed pixel at all)."""
    H, W = on_gel.shape
    edges = tuple(
        BOTH_SIDES if lo == -1 and hi == size + 1 else -1 if lo == -1 else 1 if hi == size + 1 else 0
        for lo, hi, size in ((rect[0], rect[1], H), (rect[2], rect[3], W))
    )
    inside = all(lo >= -1 and hi <= size + 1 for lo, hi, size in ((rect[0], rect[1], H), (rect[2], rect[3], W)))
    if not inside or edges == (BOTH_SIDES, BOTH_SIDES) or edges == (0, 0):
        return None
    r0, r1, c0, c1 = max(rect[0], 0), min(rect[1], H), max(rect[2], 0), min(rect[3], W)
    return edges if bool(on_gel[r0:r1, c0:c1].all()) else None


def _box(unknown: np.ndarray, on_gel: np.ndarray):
    """(rows, cols) slices of the changed pixels' bounding box grown by one pixel, or None when that
    box touches the image border or holds a pixel off the gel.

    The box is grown further (when it stays on the gel) to sides whose DST-I length is FFT-friendly:
    a prime-sized transform is several times slower.
    """
    rows, cols = np.flatnonzero(unknown.any(1)), np.flatnonzero(unknown.any(0))  # no per-pixel index arrays
    rect = (int(rows[0]) - 1, int(rows[-1]) + 2, int(cols[0]) - 1, int(cols[-1]) + 2)
    if not _fits(rect, on_gel):
        return None
    return _faster(rect, on_gel)


def _faster(
    rect: Bounds, on_gel: np.ndarray, others: Sequence[Bounds] = (), edges: Edges = (0, 0)
) -> tuple[slice, slice]:
    """(rows, cols) slices of bounds [r0, r1, c0, c1) grown to FFT-friendly sides (:func:`_fast_span`; an edge
    box's mirrored axis :func:`_fast_mirrored_span`) where the grown box stays on the gel and shares no pixel
    with any of ``others`` (bounds solved apart)."""
    r0, r1, c0, c1 = rect
    H, W = on_gel.shape
    grown = tuple(
        x
        for lo, hi, size, edge in ((r0, r1, H, edges[0]), (c0, c1, W, edges[1]))
        for x in (
            (0, size)  # already the whole axis
            if edge == BOTH_SIDES
            else _fast_mirrored_span(lo, hi, size, edge)
            if edge
            else _fast_span(lo, hi, size)
        )
    )
    if on_gel[grown[0] : grown[1], grown[2] : grown[3]].all() and not any(_overlap(grown, o) for o in others):
        r0, r1, c0, c1 = grown
    return (slice(r0, r1), slice(c0, c1))


def _fast_span(lo: int, hi: int, size: int) -> tuple[int, int]:
    """[lo, hi) grown (centred, within [0, size)) so that the interior length n has a fast DST-I (2(n+1) 5-smooth)."""
    from scipy.fft import next_fast_len

    n = hi - lo - 2
    target = n
    while next_fast_len(2 * (target + 1), real=True) != 2 * (target + 1):
        target += 1
    grow = target - n
    new_lo = max(0, lo - grow // 2)
    new_hi = min(size, new_lo + target + 2)
    new_lo = new_hi - target - 2
    return (new_lo, new_hi) if new_lo >= 0 else (lo, hi)


def _fast_mirrored_span(lo: int, hi: int, size: int, edge: int) -> tuple[int, int]:
    """[lo, hi) of an edge box's axis (at the image border on the ``edge`` side, the ring on the other) grown
    inward so that the mirrored interior 2n has a fast DST-I: 2(2n + 1), with 2n + 1 odd, 11-smooth (pocketfft's
    radix-7 and -11 passes cost little more than 2, 3, 5 ones; a large prime factor several times more)."""
    from scipy.fft import next_fast_len

    n = hi - lo - 1
    target = n
    while next_fast_len(2 * (2 * target + 1)) != 2 * (2 * target + 1):
        target += 1
    if target + 1 > size:
        return lo, hi
    return (0, target + 1) if edge < 0 else (size - target - 1, size)


def _grown_bounds(unknown: np.ndarray) -> tuple[slice, slice]:
    """(rows, cols) slices of the bounds of ``unknown``'s pixels grown by one pixel, within the image."""
    rows, cols = np.flatnonzero(unknown.any(1)), np.flatnonzero(unknown.any(0))
    H, W = unknown.shape
    return slice(max(rows[0] - 1, 0), min(rows[-1] + 2, H)), slice(max(cols[0] - 1, 0), min(cols[-1] + 2, W))


def _crop_edges(unknown: np.ndarray, crop: Box) -> Edges:
    """The :data:`Edges` of a region group's bounds ``crop`` (grown by the ring, within the image): a side at the
    image border where a changed pixel lies on it (there the bounds had no room for a ring)."""
    changed = unknown[crop]
    edges = []
    for axis, size in enumerate(unknown.shape):
        lines = changed if axis == 0 else changed.T
        low = crop[axis].start == 0 and bool(lines[0].any())
        high = crop[axis].stop == size and bool(lines[-1].any())
        edges.append(BOTH_SIDES if low and high else -1 if low else 1 if high else 0)
    return (edges[0], edges[1])


def _interior(edge: int) -> slice:
    """The solved part of a box's axis: all but the ring, which an :data:`Edges` side at the border lacks."""
    return {0: slice(1, -1), -1: slice(0, -1), 1: slice(1, None), BOTH_SIDES: slice(None)}[edge]
