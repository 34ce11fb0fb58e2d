"""Depth from normals on the dome: integrate along the camera's real rays, the undeformed gel as boundary.

Every surface point lies on its pixel's viewing ray, x(u, v) = rho(u, v) d(u, v) (``Camera.rays``, unit,
distortion included; rho is the range, mm). A surface with normal n is tangent to x_u and x_v, so
n . (rho_u d + rho d_u) = 0, i.e. the log-range has the gradient

    d log(rho) / du = -(n . d_u) / (n . d),     d log(rho) / dv = -(n . d_v) / (n . d)

which is linear in log(rho) for any lens (no pinhole or flat-sensor assumption; d_u, d_v are
finite differences of the real rays). The pixels that changed are unknown; the undeformed
reference's log-range is the Dirichlet boundary around them, and the least-squares problem over all
pixel pairs touching an unknown is a discrete Poisson equation in log(rho).

Two exact solvers of that same equation:

- ``"box"`` (default when it applies): the unknowns are the changed pixels' bounding box (grown by
  one pixel, all on the gel); unchanged pixels inside it carry the reference normals, so their
  gradients agree with the dome. The 5-point Dirichlet Laplacian of a rectangle is diagonalised by
  the type-I discrete sine transform (scipy.fft.dstn), an O(n log n) solve of a few milliseconds.
  (This is a fast solver for the curved-surface equation above, not a flat-sensor height-from-
  gradient integration: the gradients are of log-range along the real rays.)
- ``"sparse"``: only the changed pixels are unknown, any shape, SuperLU (scipy.sparse) on the
  normal equations; used when no box below applies. A region of :data:`SPARSE_AMG_MIN_UNKNOWNS` pixels or more
  (a cross of bands over the view, the flat pad's whole gel changed) is solved by conjugate gradients with a
  Ruge-Stuben AMG preconditioner (pyamg) instead, to a residual whose depth is SuperLU's within a few 1e-6 mm
  (:data:`~nlipscalib.core.tolerances.INTEGRATION_AMG_RTOL`); its hierarchy depends on the region's shape
  alone and is kept for the next frames of that shape.

The image border is not the gel's boundary: nothing is known beyond it, and the least-squares problem has
no pixel pair across it, so a changed pixel on the border row has one neighbour fewer -- a natural (Neumann)
side, not a Dirichlet one. A box reaching the border (an "edge box") keeps that side: its arrays are
mirrored across the border (the ray's derivative across the border changes sign, so the gradient across
the mirror line is exactly 0), the doubled box has a Dirichlet ring all round and the same sine solve, and
its solution is even about the border: each border pixel's equation is then the sparse path's. A box that
spans an axis (a ridge across the whole width or height: the border on both sides) has a natural side at both
ends of it, no fixed pixel: that axis is diagonalised by the type-II cosine transform (scipy.fft.dct; the
Neumann path Laplacian), the other by the sine transform as before. Its first eigenvalue is 0 along the
cosine axis only, so the other axis's fixed ring sets the level; a box spanning both axes has none.

A box that holds pixels off the gel (a contact near the rim of a gel that does not fill the image, the flat
pad's) is a "rim box": its gel pixels are the unknowns, and a gel pixel next to an off-gel one has no pixel
pair across that side (a natural side along the gel's outline, as on the sparse path). Its equation is the box's
Laplacian changed in the rows of those rim pixels only (a low-rank change), solved by the capacitance-matrix
method (Buzbee, Dorr, George & Golub, SIAM J. Numer. Anal. 8(4), 1971): two sine solves of the box and one
dense (r, r) solve, r the rim pixels in the box. The capacitance matrix's entries are values of the box's
Green's function, summed per frame from its sine modes (:func:`_box_green`), with no box solve per rim pixel.
A rim box may reach the image border: that side is natural as an edge box's (mirrored; its axis's modes are the
doubled path's odd sines, :func:`_axis_modes`), and an axis at both borders takes cosines. A box with no fixed
pixel at all (a frame changed on the whole gel, or a whole gel island) is solved where every pixel of it is
changed: the sparse path then anchors every unknown (:data:`ANCHOR_WEIGHT` on the diagonal), which adds the
weight to every eigenvalue of the box -- the same equation, the cosine-cosine box's zero eigenvalue included.

``"auto"`` takes one box around all changed pixels where it applies; else it splits them into their
4-connected regions (no equation joins two), each group a box, an edge box where its box reaches the
image border (a contact pressed at the edge of the view: 5-9 ms at 640x480, not the 0.16-0.37 s of SuperLU;
across the image: 14-31 ms, not 0.34-1.0 s, at load 9), a rim box where its box holds off-gel pixels (also at
the image border) or spans both axes with every pixel changed, and the sparse path where none applies: a region
across both axes with unchanged pixels in its box (a cross or ridges over the whole view: anchoring the box would
let a dent lift the unchanged surface, which the sparse path holds at the reference), a box with no fixed pixel
and unchanged pixels, a mix of gel parts with and without one, or a rim too long for the Green's sum
(:data:`MAX_RIM_GREEN_VALUES`: the flat pad's whole gel, 992 rim pixels).
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import threading
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from ..core.camera import depth_to_points, pixel_derivatives
from ..core.errors import ShapeError
from ..core.tolerances import INTEGRATION_MIN_FACING

if TYPE_CHECKING:  # torch is optional (the full-frame path passes tensors): named for the type checker only
    import torch
    from scipy.sparse import csr_matrix as sparse_matrix

Array: TypeAlias = "np.ndarray | torch.Tensor"
"""A numpy array, or a torch tensor where :mod:`.fullframe` calls the shared arithmetic."""
Bounds: TypeAlias = "Sequence[int]"
"""Pixel bounds [r0, r1, c0, c1): rows r0 to r1 - 1, columns c0 to c1 - 1."""

ANCHOR_WEIGHT = 1e-4
"""Weak pull toward the reference log-range, on the unknown regions that touch no known pixel only (their
Poisson equation fixes the shape but not the level). Never on a region with a known neighbour: a fixed
weight there is a real bias, against the Laplacian's smallest eigenvalue ~2 (pi / L)^2 of a region L pixels
across; at 1e-4 on every pixel, contacts 50-150 px across at 640x480 came out 4-14 % too shallow."""


@dataclasses.dataclass(frozen=True)
class RayGeometry:
    """Per-sensor arrays the integration needs, computed once per model/camera."""

    rays: np.ndarray
    """(H, W, 3) float64, unit, camera frame -- viewing ray of every pixel centre."""
    d_u: np.ndarray
    """(H, W, 3) float64 -- derivative of the ray along u (per pixel)."""
    d_v: np.ndarray
    """(H, W, 3) float64 -- derivative of the ray along v (per pixel)."""
    log_range: np.ndarray
    """(H, W) float64 -- log of the undeformed reference's range along the ray, log(mm); NaN off the gel."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame -- the undeformed surface (NaN off the gel)."""

    @classmethod
    def from_reference(cls, rays: np.ndarray, reference_depth: np.ndarray) -> RayGeometry:
        """From ``Camera.rays`` and the reference depth ((H, W) mm, z; NaN off the gel)."""
        if rays.shape != reference_depth.shape + (3,):
            raise ShapeError(f"rays {rays.shape} and reference depth {reference_depth.shape} do not match")
        d_u, d_v = pixel_derivatives(rays)
        with np.errstate(invalid="ignore", divide="ignore"):
            log_range = np.log(reference_depth / rays[..., 2])
            points = depth_to_points(reference_depth, rays).astype(np.float32)
        return cls(rays, d_u, d_v, log_range, points)

    # float32 copies for the per-frame box solver, made once per sensor
    @functools.cached_property
    def rays32(self) -> np.ndarray:
        return self.rays.astype(np.float32)

    @functools.cached_property
    def d_u32(self) -> np.ndarray:
        return self.d_u.astype(np.float32)

    @functools.cached_property
    def d_v32(self) -> np.ndarray:
        return self.d_v.astype(np.float32)


def log_range_gradient(normals: np.ndarray, geo: RayGeometry) -> tuple[np.ndarray, np.ndarray]:
    """(p, q): d log(rho)/du and d log(rho)/dv, each (H, W) float64, from normals ((H, W, 3) unit, camera frame)."""
    return _gradient64(normals, geo.rays, geo.d_u), _gradient64(normals, geo.rays, geo.d_v)


def _gradient64(normals: np.ndarray, rays: np.ndarray, d: np.ndarray) -> np.ndarray:
    """-(n . d) / (n . ray) per pixel, float64 (``d`` the ray's derivative along u or v; (..., 3) each)."""
    den = np.minimum(np.einsum("...k,...k->...", normals, rays), -INTEGRATION_MIN_FACING)
    return -np.einsum("...k,...k->...", normals, d) / den


def integrate_on_dome(
    normals: np.ndarray, unknown: np.ndarray, geo: RayGeometry, method: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the surface whose normals are ``normals`` where ``unknown``, the reference elsewhere.

    Parameters
    ----------
    normals : (H, W, 3) float, unit, camera frame, toward the camera (finite where ``unknown``)
    unknown : (H, W) bool -- pixels to solve for (the changed pixels); must lie on the gel
    geo : RayGeometry of the sensor
    method : "auto" (box, else per region a box, an edge box or sparse), "box" or "sparse" (module docstring)

    Returns
    -------
    depth : (H, W) float32, mm, camera-frame z (the reference depth outside the solved pixels; NaN off the gel)
    points : (H, W, 3) float32, mm, camera frame
    """
    H, W = unknown.shape
    if normals.shape != (H, W, 3) or geo.rays.shape != (H, W, 3):
        raise ShapeError(f"normals {normals.shape}, unknown {unknown.shape} and the sensor's rays must match")
    known_lr = geo.log_range
    on_gel = np.isfinite(known_lr)
    unknown = unknown & on_gel
    if method not in ("auto", "box", "sparse"):
        raise ShapeError(f"method must be 'auto', 'box' or 'sparse', got {method!r}")
    points = geo.points.copy()
    if unknown.any():
        boxes, edge_boxes, sparse = _regions(unknown, on_gel, method)  # solved apart: no equation joins two
        # only the solved pixels change: the rest keeps the reference surface
        for box, edges in [(box, (0, 0)) for box in boxes] + edge_boxes:
            log_range = _solve_box(normals, geo, box, edges)
            points[box] = np.exp(log_range.astype(np.float32))[..., None] * geo.rays32[box]
        for i, crop in enumerate(sparse):
            others = [box for box, _ in edge_boxes] + boxes + sparse[:i] + sparse[i + 1 :]
            crop, solved, solved_points = solve_region_group(normals, unknown, on_gel, geo, crop, others, method)
            points[crop][solved] = solved_points
    return points[..., 2], points


def solve_region_group(
    normals: np.ndarray,
    unknown: np.ndarray,
    on_gel: np.ndarray,
    geo: RayGeometry,
    crop: Box,
    others: Sequence[Box],
    method: str = "auto",
) -> tuple[Box, np.ndarray, np.ndarray]:
    """One region group that no box of :func:`_regions` solves (its bounds ``crop``; ``others`` the frame's other
    boxes and groups), as :func:`integrate_on_dome` solves it: a rim box where one applies ("auto"), else the sparse
    path. The torch path (:mod:`.integrate_torch`) calls it on the host for the groups it does not solve itself.

    Returns
    -------
    box : the bounds solved (a rim box may grow past ``crop``)
    solved : (h, w) bool over ``box`` -- the pixels solved
    points : (n, 3) float, mm, camera frame -- their surface points, in ``solved`` order
    """
    edges = _crop_edges(unknown, crop)
    anchor = _rim_box_anchor(unknown, on_gel, crop, edges) if method == "auto" else None
    if anchor is not None:
        crop = _faster_rim_box(unknown, on_gel, crop, others, edges, anchor)
        solved = _interior_mask(on_gel[crop], edges)
        log_range = _solve_rim_box(normals, geo, on_gel, crop, edges, anchor)[solved]
        return crop, solved, np.exp(log_range.astype(np.float32))[:, None] * geo.rays32[crop][solved]
    log_range = _solve_sparse(normals, unknown, on_gel, geo, crop)
    return crop, unknown[crop], np.exp(log_range)[:, None] * geo.rays[crop][unknown[crop]]


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
    ring on one side of an axis (module docstring), else on the sparse path. Bounds (grown by the ring) that
    share a pixel are merged first: one box's solved interior must not be another's fixed ring or a sparse
    region's known neighbour, so a region whose box does not apply takes every box it overlaps with it.
    """
    if method == "sparse":
        return [], [], [_grown_bounds(unknown)]
    box = _box(unknown, on_gel)
    if box is not None:
        return [box], [], []
    if method == "box":
        raise ShapeError("the changed pixels' box leaves the gel or touches the image border: use 'sparse'")
    from scipy import ndimage

    labels, count = ndimage.label(unknown)
    if count > MAX_SPLIT_REGIONS:
        return [], [], [_grown_bounds(unknown)]
    # each region's bounds grown by one pixel (its ring): [r0, r1, c0, c1), with the regions it holds
    groups = [
        [s[0].start - 1, s[0].stop + 1, s[1].start - 1, s[1].stop + 1, [k + 1]]
        for k, s in enumerate(ndimage.find_objects(labels))
    ]
    groups = _merge_overlapping(groups)
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


def _solve_box(normals: np.ndarray, geo: RayGeometry, box: tuple[slice, slice], edges: Edges = (0, 0)) -> np.ndarray:
    """Log-range over the box: Poisson solve on its interior, the outer ring fixed at the reference (DST-I);
    on an edge box's border sides (``edges``) no ring, a natural side (mirrored, module docstring); along an axis
    that spans the image (:data:`BOTH_SIDES`) a natural side at both ends: the type-II cosine transform there."""
    from scipy.fft import dct, dst, dstn, idct

    # float32 like the transforms below: a gradient of log-range needs no more than 1e-7 relative
    x = geo.log_range[box].astype(np.float32)
    f = edge_box_rhs(np.asarray(normals[box], np.float32), geo.rays32[box], geo.d_u32[box], geo.d_v32[box], x, edges)
    neumann = tuple(edge == BOTH_SIDES for edge in edges)
    lam = box_eigenvalues(*f.shape, neumann=neumann).astype(np.float32)
    # float32 transforms: twice as fast, and 1e-7 relative error of a log-range is 1e-6 mm
    if not any(neumann):
        f = dstn(dstn(f, type=1, norm="ortho") / lam, type=1, norm="ortho")
    else:  # one axis spans the image (_edge_fits: never both): its eigenvalues start at 0, the other's above it
        (cos_axis,) = (axis for axis in (0, 1) if neumann[axis])
        f = dst(dct(f, type=2, norm="ortho", axis=cos_axis), type=1, norm="ortho", axis=1 - cos_axis) / lam
        f = idct(dst(f, type=1, norm="ortho", axis=1 - cos_axis), type=2, norm="ortho", axis=cos_axis)
    own, interior = edge_box_parts(x.shape, edges)
    x[interior] = f[own]
    return x


def edge_box_rhs(normals: Array, rays: Array, d_u: Array, d_v: Array, x: Array, edges: Edges = (0, 0)) -> Array:
    """:func:`box_rhs` of a box, or of an edge box's doubled box (mirrored across the image border on its
    ``edges`` sides, module docstring; a :data:`BOTH_SIDES` axis mirrored at both ends, not doubled): the
    right-hand side of the box solve; numpy or torch (shared with :mod:`.integrate_torch`). Arguments as
    :func:`box_rhs`'s, over the box; :func:`edge_box_parts` takes the box's log-range from the solve."""
    arrays = [normals, rays, d_u, d_v, x]
    for axis, edge in enumerate(edges):
        for side in (-1, 1) if edge == BOTH_SIDES else (edge,) if edge else ():
            arrays = _mirror_line(arrays, axis, side)
    f = box_rhs(*arrays)
    for axis, edge in enumerate(edges):  # the doubled box's right-hand side is even about the border
        if edge in (-1, 1):
            f = _concat((_flip(f, axis), f) if edge < 0 else (f, _flip(f, axis)), axis)
    return f


def edge_box_parts(shape: tuple[int, int], edges: Edges = (0, 0)) -> tuple[Box, Box]:
    """(own, interior): where the box of ``shape`` (h, w) finds its solved pixels in the solve of
    :func:`edge_box_rhs` (the box's own half of the doubled box: the last along an axis mirrored before it, the
    first after it; all of a :data:`BOTH_SIDES` axis), and where they go in the box (its interior: no ring on a
    border side)."""
    half = tuple(k if edge == BOTH_SIDES else k - 1 if edge else k - 2 for k, edge in zip(shape, edges))
    own = tuple(slice(-k, None) if edge == -1 else slice(0, k) for k, edge in zip(half, edges))
    return own, tuple(_interior(edge) for edge in edges)


def _interior(edge: int) -> slice:
    """The solved part of a box's axis: all but the ring, which an :data:`Edges` side at the border lacks."""
    return {0: slice(1, -1), -1: slice(0, -1), 1: slice(1, None), BOTH_SIDES: slice(None)}[edge]


def _concat(parts: Sequence[Array], axis: int) -> Array:
    """numpy's concatenate, or torch's cat for tensors (no copy to the host)."""
    if isinstance(parts[0], np.ndarray):
        return np.concatenate(parts, axis=axis)
    import torch

    return torch.cat(tuple(parts), dim=axis)


def _flip(a: Array, axis: int) -> Array:
    """``a`` reversed along ``axis``; numpy or torch."""
    return np.flip(a, axis) if isinstance(a, np.ndarray) else a.flip(axis)


def _where(condition: Array, a: Array, b: Array) -> Array:
    """numpy's where, or torch's for tensors."""
    if isinstance(condition, np.ndarray):
        return np.where(condition, a, b)
    import torch

    return torch.where(condition, a, b)


def _mirror_line(arrays: list[Array], axis: int, edge: int) -> list[Array]:
    """normals, rays, d_u, d_v and log-range over a box with one line beyond the image border joined (``edge`` -1:
    before index 0 along ``axis``, +1: after the last): the border line's mirror image, in the place of a ring.

    Its log-range is 0, so :func:`box_rhs` moves nothing known to the border pixels. Its ray derivative across
    the border (d_v for rows, d_u for columns) is negated: the mirrored surface's log-range gradient across the
    border is the negative, and the averaged gradient on the border pair exactly 0 -- the border pixels' rows
    of the right-hand side are those of the doubled box, whose other half is their mirror image. numpy or torch."""
    across = 3 if axis == 0 else 2
    line = (
        (slice(0, 1) if edge < 0 else slice(-1, None),)
        if axis == 0
        else (slice(None), slice(0, 1) if edge < 0 else slice(-1, None))
    )
    out = []
    for k, a in enumerate(arrays):
        mirror = -a[line] if k == across else 0 * a[line] if k == len(arrays) - 1 else a[line]
        out.append(_concat((mirror, a) if edge < 0 else (a, mirror), axis))
    return out


def box_rhs(normals: Array, rays: Array, d_u: Array, d_v: Array, x: Array, on_gel: Array | None = None) -> Array:
    """Right-hand side of the box's interior equation, 4 x_i - sum of neighbours = f_i, with the box's outer ring
    (of ``x``, the reference) moved to it.

    Written with slicing and arithmetic only, so numpy arrays and torch tensors (:mod:`.fullframe`) share it.

    Parameters
    ----------
    normals, rays, d_u, d_v : (h, w, 3) float32 over the box (the normals unit, toward the camera)
    x : (h, w) float32 -- the reference log-range over the box (its outer ring is used; 0 where off the gel)
    on_gel : (h, w) bool, or None (every pixel) -- a pair with a pixel off the gel has no equation (a rim box)

    Returns
    -------
    (h - 2, w - 2) float32
    """
    p, q = _gradient32(normals, rays, d_u, d_v)
    gu = 0.5 * (p[:, :-1] + p[:, 1:])  # edge (r, c) -> (r, c + 1)
    gv = 0.5 * (q[:-1, :] + q[1:, :])  # edge (r, c) -> (r + 1, c)
    if on_gel is not None:
        gu, gv = gu * (on_gel[:, :-1] & on_gel[:, 1:]), gv * (on_gel[:-1, :] & on_gel[1:, :])
    # 4 x_i - sum of neighbours = (incoming edge gradients) - (outgoing edge gradients)
    f = gu[1:-1, :-1] - gu[1:-1, 1:] + gv[:-1, 1:-1] - gv[1:, 1:-1]
    f[0, :] += x[0, 1:-1]
    f[-1, :] += x[-1, 1:-1]
    f[:, 0] += x[1:-1, 0]
    f[:, -1] += x[1:-1, -1]
    return f


def box_eigenvalues(m: int, n: int, neumann: tuple[bool, bool] = (False, False)) -> np.ndarray:
    """(m, n) float64 eigenvalues of the 5-point Laplacian of an (m, n) box, in its transforms' basis.

    Per axis (rows, columns): zero beyond both ends (Dirichlet; the type-I DST basis), or with ``neumann`` no
    neighbour beyond them (natural boundary; the type-II DCT basis, whose first eigenvalue, the constant's, is 0).
    """
    return _path_eigenvalues(m, neumann[0])[:, None] + _path_eigenvalues(n, neumann[1])[None, :]


def _path_eigenvalues(n: int, neumann: bool) -> np.ndarray:
    """(n,) float64 eigenvalues of the 1-D 3-point Laplacian on n points (:func:`box_eigenvalues`)."""
    return _axis_eigenvalues(n, BOTH_SIDES if neumann else 0)


def _axis_eigenvalues(n: int, edge: int) -> np.ndarray:
    """(n,) float64 eigenvalues of the 1-D 3-point Laplacian on n points whose ends are fixed (``edge`` 0), natural
    (:data:`BOTH_SIDES`), or natural at one end only (-1, +1: an edge box's mirrored axis, the odd modes of the
    doubled path's sines); in the order of :func:`_axis_modes`."""
    if edge == BOTH_SIDES:
        return 2 - 2 * np.cos(np.pi * np.arange(n) / n)
    if edge:
        return 2 - 2 * np.cos(np.pi * np.arange(1, 2 * n, 2) / (2 * n + 1))
    return 2 - 2 * np.cos(np.pi * np.arange(1, n + 1) / (n + 1))


def _gradient32(normals: Array, rays: Array, d_u: Array, d_v: Array) -> tuple[Array, Array]:
    """:func:`log_range_gradient` in float32 over a box (every argument cropped to it); numpy or torch."""
    n0, n1, n2 = normals[..., 0], normals[..., 1], normals[..., 2]

    def dot(v: Array) -> Array:
        return n0 * v[..., 0] + n1 * v[..., 1] + n2 * v[..., 2]

    den = dot(rays).clip(max=-INTEGRATION_MIN_FACING)
    return -dot(d_u) / den, -dot(d_v) / den


MAX_RIM_GREEN_VALUES = 1 << 22
"""Most values of the box's Green's function that one rim box may sum (:func:`_box_green`: the modes of one axis
times the rim's points and columns; 32 MiB of float64 each of its two largest arrays). A region beyond it (a rim
box thousands of rim pixels long, such as the flat pad's whole gel) keeps the sparse path."""


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


def _interior_mask(on_gel: np.ndarray, edges: Edges = (0, 0)) -> np.ndarray:
    """(h, w) bool: a rim box's solved pixels -- the gel pixels of its interior (all but the ring, which its sides
    at the image border, ``edges``, lack)."""
    solved = np.zeros_like(on_gel)
    interior = tuple(_interior(edge) for edge in edges)
    solved[interior] = on_gel[interior]
    return solved


def _rim_box_applies(unknown: np.ndarray, on_gel: np.ndarray, crop: Box, edges: Edges = (0, 0)) -> bool:
    """Whether the region group in ``crop`` is solved as a rim box (:func:`_rim_box_anchor`)."""
    return _rim_box_anchor(unknown, on_gel, crop, edges) is not None


def _rim_box_anchor(unknown: np.ndarray, on_gel: np.ndarray, crop: Box, edges: Edges = (0, 0)) -> float | None:
    """The anchor weight of the rim box of the region group in ``crop`` (its bounds grown by the ring,
    :func:`_regions`; ``edges`` its sides at the image border, :func:`_crop_edges`), or None where the sparse path
    must solve it.

    It applies where its ring (the sides off the image border) holds no changed pixel, its rim is small enough
    (:data:`MAX_RIM_GREEN_VALUES`), and either every connected part of the interior's gel touches a gel pixel of
    the ring (which fixes its level: anchor 0), or none does and every one of its pixels is a changed pixel (the
    sparse path then anchors every unknown, the same equation: :data:`ANCHOR_WEIGHT`; e.g. a frame changed on the
    whole gel). A mix, or an unchanged pixel in a box without a fixed pixel, keeps the sparse path: anchoring
    pixels that the sparse path holds at the reference would be another equation."""
    from scipy import ndimage

    changed, gel = unknown[crop], on_gel[crop]
    interior = tuple(_interior(edge) for edge in edges)
    if min(gel[interior].shape) < 1:
        return None
    solved = _interior_mask(gel, edges)
    if (changed & ~solved).any():  # a changed pixel on the ring
        return None
    labels, count = ndimage.label(solved)
    held = ndimage.binary_dilation(gel & ~solved) & solved  # solved pixels next to a gel pixel of the ring
    touching = len(np.unique(labels[held]))
    if touching == count:
        anchor = 0.0
    elif touching == 0 and not (solved & ~changed).any():
        anchor = ANCHOR_WEIGHT
    else:
        return None
    rim = _rim_rows(_beyond_border(gel, edges, True))[1]
    cost = _green_cost(*np.nonzero(rim), *np.nonzero(rim), *rim.shape)
    return anchor if cost <= MAX_RIM_GREEN_VALUES else None


def _faster_rim_box(
    unknown: np.ndarray,
    on_gel: np.ndarray,
    crop: Box,
    others: Sequence[Box],
    edges: Edges = (0, 0),
    anchor: float = 0.0,
) -> Box:
    """A rim box (``edges`` its sides at the image border) grown to FFT-friendly sides (:func:`_faster`) within the
    image, clear of the boxes solved apart (``others``), where it still applies with the same ``anchor``
    (:func:`_rim_box_anchor`); else ``crop``. Its sine solves are most of its time: the ridge across the flat pad's
    box, 148 x 536 inside its ring, has the prime factors 149 and 179 in its transform lengths."""
    rect = (crop[0].start, crop[0].stop, crop[1].start, crop[1].stop)
    bounds = [(b[0].start, b[0].stop, b[1].start, b[1].stop) for b in others]
    grown = _faster(rect, np.ones_like(on_gel), bounds, edges)
    return grown if grown != crop and _rim_box_anchor(unknown, on_gel, grown, edges) == anchor else crop


def _beyond_border(a: np.ndarray, edges: Edges, value: object) -> np.ndarray:
    """``a`` ((h, w, ...) over a box) with one line of ``value`` joined beyond each of its sides at the image
    border (``edges``), in the place of the ring those sides lack."""
    pad = [(int(edge in (-1, BOTH_SIDES)), int(edge in (1, BOTH_SIDES))) for edge in edges]
    return np.pad(a, pad + [(0, 0)] * (a.ndim - 2), constant_values=value)


def _rim_rows(on_gel: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Off-gel neighbours of a rim box's interior pixels, per side (up, down, left, right: (m, n) bool each), and
    the rim: (m, n) bool, the interior's gel pixels with at least one off-gel neighbour."""
    off = ~on_gel
    sides = [off[:-2, 1:-1], off[2:, 1:-1], off[1:-1, :-2], off[1:-1, 2:]]
    return sides, on_gel[1:-1, 1:-1] & (sides[0] | sides[1] | sides[2] | sides[3])


def _solve_rim_box(
    normals: np.ndarray, geo: RayGeometry, on_gel: np.ndarray, box: Box, edges: Edges = (0, 0), anchor: float = 0.0
) -> np.ndarray:
    """(h, w) float64 log-range over a rim box (module docstring): its interior's gel pixels solved, the rest the
    reference (NaN off the gel); the sparse path's equation with those pixels unknown, up to rounding.

    The box's Laplacian L (DST-I; on ``edges`` sides at the image border a natural side, :func:`_box_solve`), plus
    ``anchor`` on its diagonal, becomes the rim box's matrix M = L + U V^T: the rows of the rim pixels (U: their
    unit columns) lose their off-gel neighbours (V^T: minus their count on the diagonal, plus one at each off-gel
    interior neighbour, whose own rows stay L's: M is block triangular, its gel block the sparse path's).
    Woodbury: M x = f is x = L^-1 (f - U s) with the capacitance system (I + V^T L^-1 U) s = V^T L^-1 f, L^-1's
    entries at the rim and its neighbours from :func:`_box_green`
    (:func:`rim_box_capacitance`; :func:`rim_box_rhs` and :func:`rim_box_solve` are shared with the torch path).
    """
    from scipy.linalg import lu_factor, lu_solve

    from ..core.blas import blas_threads

    gel = on_gel[box]
    x = np.where(gel, geo.log_range[box], 0.0)
    # beyond a side at the image border, a line with no pixel pair (off the gel for box_rhs) and nothing known
    arrays = [_beyond_border(a, edges, 0.0) for a in (normals[box], geo.rays[box], geo.d_u[box], geo.d_v[box], x)]
    f = rim_box_rhs(*arrays, _beyond_border(gel, edges, False))
    solved = _interior_mask(gel, edges)[tuple(_interior(edge) for edge in edges)]
    f[solved] += anchor * arrays[-1][1:-1, 1:-1][solved]
    rim, points, v_t, capacitance = rim_box_capacitance(gel, edges, anchor)
    with blas_threads(1):  # a small dense factorisation: a second BLAS thread only waits on a shared machine
        factor = lu_factor(capacitance) if len(rim) else None
    y = rim_box_solve(f, lambda rhs: _box_solve(rhs, edges, anchor), rim, points, v_t, lambda b: lu_solve(factor, b))
    out = np.where(gel, geo.log_range[box], np.nan)
    out[tuple(_interior(edge) for edge in edges)][solved] = y[solved]
    return out


def _box_solve(f: np.ndarray, edges: Edges = (0, 0), anchor: float = 0.0) -> np.ndarray:
    """(m, n) float64: (L + anchor I)^-1 f, L the 5-point Laplacian of an (m, n) box (:func:`_axis_eigenvalues`
    per axis): fixed beyond both ends (DST-I), natural at both (:data:`BOTH_SIDES`: DCT-II; its zero eigenvalue
    needs the anchor where both axes are), or at the image border only (-1, +1: the DST-I of the array mirrored
    across it, as :func:`_solve_box`'s edge box)."""
    from scipy.fft import dct, dst, dstn, idct

    if edges == (0, 0):  # the plain rim box: one call per direction
        return dstn(dstn(f, type=1, norm="ortho") / (box_eigenvalues(*f.shape) + anchor), type=1, norm="ortho")
    shape = f.shape
    for axis, edge in enumerate(edges):
        if edge in (-1, 1):
            f = np.concatenate((np.flip(f, axis), f) if edge < 0 else (f, np.flip(f, axis)), axis)
    neumann = (edges[0] == BOTH_SIDES, edges[1] == BOTH_SIDES)
    lam = box_eigenvalues(*f.shape, neumann=neumann) + anchor
    for axis in (0, 1):
        f = dct(f, type=2, norm="ortho", axis=axis) if neumann[axis] else dst(f, type=1, norm="ortho", axis=axis)
    f = f / lam
    for axis in (0, 1):
        f = idct(f, type=2, norm="ortho", axis=axis) if neumann[axis] else dst(f, type=1, norm="ortho", axis=axis)
    return f[tuple(slice(-k, None) if edge == -1 else slice(0, k) for k, edge in zip(shape, edges))]


def _axis_modes(index: np.ndarray, n: int, edge: int = 0) -> np.ndarray:
    """(len(index), n) float64: the orthonormal eigenvectors of the 1-D Laplacian of :func:`_axis_eigenvalues` at
    the points ``index`` -- type-I sines (rows of ``scipy.fft.dst(eye(n), type=1, norm="ortho")``), type-II cosines
    (:data:`BOTH_SIDES`), or the doubled path's odd sines on the box's half of it (-1: its second half, +1: its
    first; sqrt(2) for the half's norm)."""
    i = np.asarray(index, float)
    if edge == BOTH_SIDES:
        scale = np.where(np.arange(n) == 0, np.sqrt(1.0 / n), np.sqrt(2.0 / n))
        return scale * np.cos(np.pi * np.outer(i + 0.5, np.arange(n)) / n)
    if edge:
        at = i + 1 + (n if edge < 0 else 0)  # 1-based place on the doubled path
        return 2 / np.sqrt(2 * n + 1) * np.sin(np.pi * np.outer(at, np.arange(1, 2 * n, 2)) / (2 * n + 1))
    return np.sqrt(2.0 / (n + 1)) * np.sin(np.pi * np.outer(i + 1, np.arange(1, n + 1)) / (n + 1))


def rim_box_rhs(normals: Array, rays: Array, d_u: Array, d_v: Array, x: Array, gel: Array) -> Array:
    """Right-hand side of a rim box's solve (:func:`_solve_rim_box`); numpy or torch (shared with
    :mod:`.integrate_torch`).

    Parameters
    ----------
    normals, rays, d_u, d_v : (h, w, 3) over the box (the normals unit, toward the camera, where ``gel``)
    x : (h, w) -- the reference log-range over the box, 0 off the gel
    gel : (h, w) bool -- the box's gel pixels

    Returns
    -------
    (h - 2, w - 2): :func:`box_rhs` with no pair across the gel's outline, 0 in an off-gel pixel's row (L's own,
    decoupled from the gel's)
    """
    facing = _where(gel[..., None], normals, -rays)  # any finite normal off the gel: no pair uses it
    f = box_rhs(facing, rays, d_u, d_v, x, gel)
    return _where(gel[1:-1, 1:-1], f, 0 * f)


def rim_box_capacitance(
    gel: np.ndarray, edges: Edges = (0, 0), anchor: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The low-rank change of a rim box's Laplacian (:func:`_solve_rim_box`), from its gel pixels alone.

    Parameters
    ----------
    gel : (h, w) bool -- the box's gel pixels
    edges : its sides at the image border (no rim there: the box's Laplacian has that side, :func:`_box_solve`)
    anchor : added to the Laplacian's diagonal (:func:`_rim_box_anchor`)

    Returns
    -------
    rim : (r,) int64 -- flat indices (in the (h - 2, w - 2) interior) of the rim pixels
    points : (P,) int64 -- flat interior indices where V^T has entries (the rim and its off-gel neighbours)
    v_t : (r, P) float64 -- V^T on ``points``
    capacitance : (r, r) float64 -- I + V^T L^-1 U
    """
    from ..core.blas import blas_threads

    sides, rim_mask = _rim_rows(_beyond_border(gel, edges, True))  # the image border is no rim: L has it
    m, n = rim_mask.shape
    rim = np.flatnonzero(rim_mask)
    rr, rc = np.divmod(rim, n)
    # V^T's entries: (rim row, interior pixel, value); the rim pixel itself, then its off-gel neighbours
    rows, pixels, values = [np.arange(len(rim))], [rim], [-sum(side.ravel()[rim] for side in sides).astype(float)]
    for (dr, dc), side in zip(((-1, 0), (1, 0), (0, -1), (0, 1)), sides):
        nr, nc = rr + dr, rc + dc
        inside = side.ravel()[rim] & (nr >= 0) & (nr < m) & (nc >= 0) & (nc < n)
        rows.append(np.flatnonzero(inside))
        pixels.append(nr[inside] * n + nc[inside])
        values.append(np.ones(int(inside.sum())))
    points, column = np.unique(np.concatenate(pixels), return_inverse=True)
    v_t = np.zeros((len(rim), len(points)))
    np.add.at(v_t, (np.concatenate(rows), column), np.concatenate(values))
    if not len(rim):
        return rim, points, v_t, np.eye(0)
    with blas_threads(1):  # small dense products: a second BLAS thread only waits on a shared machine
        green = _box_green(*np.divmod(points, n), rr, rc, m, n, edges, anchor)
        capacitance = np.eye(len(rim)) + v_t @ green
    return rim, points, v_t, capacitance


def rim_box_solve(
    f: Array,
    solve: Callable[[Array], Array],
    rim: Array,
    points: Array,
    v_t: Array,
    solve_capacitance: Callable[[Array], Array],
) -> Array:
    """(m, n) solution of a rim box's equation M y = f (:func:`_solve_rim_box`) by two box solves and one
    capacitance solve; numpy or torch.

    Parameters
    ----------
    f : (m, n) -- :func:`rim_box_rhs` (changed in place)
    solve : the box's solve, L^-1 of an (m, n) array (:func:`_box_solve`, or the torch path's)
    rim, points, v_t : of :func:`rim_box_capacitance` (as arrays of ``f``'s kind)
    solve_capacitance : s with (I + V^T L^-1 U) s = b, of a (r,) b
    """
    y = solve(f)
    if len(rim):
        s = solve_capacitance(v_t @ y.reshape(-1)[points])
        f.reshape(-1)[rim] -= s  # a view of f: contiguous (box_rhs's arithmetic made it)
        y = solve(f)
    return y


def _green_cost(pr: np.ndarray, pc: np.ndarray, qr: np.ndarray, qc: np.ndarray, m: int, n: int) -> int:
    """Values :func:`_box_green` holds at once in its largest array, summing over the cheaper axis's modes."""
    return min(_green_rows_cost(pr, pc, qr, m, n), _green_rows_cost(pc, pr, qc, n, m))


def _box_green(
    pr: np.ndarray,
    pc: np.ndarray,
    qr: np.ndarray,
    qc: np.ndarray,
    m: int,
    n: int,
    edges: Edges = (0, 0),
    anchor: float = 0.0,
) -> np.ndarray:
    """(P, Q) float64: the (m, n) box's Green's function G(p, q), the inverse of its 5-point Laplacian plus
    ``anchor`` on the diagonal (:func:`_box_solve`; ``edges`` its natural sides), between interior pixels
    p = (pr, pc) and q = (qr, qc).

    G(p, q) = sum_k sum_l S_k(pr) S_k(qr) T_l(pc) T_l(qc) / (mu_k + nu_l + anchor), S and T the modes of the two
    axes (:func:`_axis_modes`). The inner sum, per row mode k, is a 1-D Green's function along the columns, needed
    only between the distinct columns of p and of q; the outer sum is then one matrix product per distinct column
    of p. The axes are swapped where that is cheaper (a rim along the rows, few distinct rows)."""
    if _green_rows_cost(pr, pc, qr, m, n) > _green_rows_cost(pc, pr, qc, n, m):
        return _box_green(pc, pr, qc, qr, n, m, (edges[1], edges[0]), anchor)
    columns_p, at_p = np.unique(pc, return_inverse=True)
    columns_q, at_q = np.unique(qc, return_inverse=True)
    eigenvalues = _axis_eigenvalues(m, edges[0])[:, None] + _axis_eigenvalues(n, edges[1])[None, :]
    inverse = 1.0 / (eigenvalues + anchor)  # (m, n)
    modes_p, modes_q = _axis_modes(columns_p, n, edges[1]), _axis_modes(columns_q, n, edges[1])
    along = np.matmul(modes_p[None] * inverse[:, None, :], modes_q.T)  # (m, distinct columns of p, of q)
    # (distinct columns of p, m, Q): contiguous per column of p, gathered by take (half the time of along[..., at_q])
    weighted = np.take(along.transpose(1, 0, 2), at_q, axis=2)
    weighted *= _axis_modes(qr, m, edges[0]).T
    green = np.empty((len(pr), len(qr)))
    order = np.argsort(at_p, kind="stable")
    starts = np.searchsorted(at_p[order], np.arange(len(columns_p) + 1))
    for a in range(len(columns_p)):
        rows = order[starts[a] : starts[a + 1]]
        green[rows] = _axis_modes(pr[rows], m, edges[0]) @ weighted[a]
    return green


def _green_rows_cost(pr: np.ndarray, pc: np.ndarray, qr: np.ndarray, m: int, n: int) -> int:
    """:func:`_green_cost` summing over the row modes: (m, distinct columns of p, n or Q) values."""
    return m * len(np.unique(pc)) * max(n, len(qr))


def _solve_sparse(
    normals: np.ndarray,
    unknown: np.ndarray,
    on_gel: np.ndarray,
    geo: RayGeometry,
    crop: tuple[slice, slice] | None = None,
) -> np.ndarray:
    """Log-range of the changed pixels ((n,) in ``unknown`` order): least squares on them only (any shape),
    SuperLU on the normal equations (AMG-preconditioned CG from :data:`SPARSE_AMG_MIN_UNKNOWNS` pixels up).

    Built on ``crop`` (default: the changed pixels' bounds grown by one pixel, where every pair of pixels that
    touches one lies), not the whole image: the same equations in the same order, and a group of noise specks
    at a 1280x960 frame's border (:func:`_regions`) costs what its size says. Solves the changed pixels in
    ``crop`` (in their order there); none of their neighbours may be changed pixels outside it.
    """
    from scipy.sparse import coo_matrix, diags
    from scipy.sparse.linalg import splu

    crop = _grown_bounds(unknown) if crop is None else crop
    unknown, on_gel = unknown[crop], on_gel[crop]
    known_lr = geo.log_range[crop]
    normals64 = np.asarray(normals[crop], np.float64)
    p = _gradient64(normals64, geo.rays[crop], geo.d_u[crop])
    q = _gradient64(normals64, geo.rays[crop], geo.d_v[crop])
    index = np.full(unknown.size, -1, np.int64)
    index[np.flatnonzero(unknown)] = np.arange(int(unknown.sum()))
    rows, cols, vals, rhs = _equations(unknown, on_gel, index, known_lr, p, q)
    n = int(unknown.sum())
    A = coo_matrix((vals, (rows, cols)), shape=(len(rhs), n)).tocsr()
    anchor = ANCHOR_WEIGHT * _unbounded(unknown, on_gel)[unknown]
    normal_matrix = (A.T @ A + diags(anchor)).tocsr()
    b = A.T @ rhs + anchor * known_lr[unknown]
    if n >= SPARSE_AMG_MIN_UNKNOWNS:
        solution = _solve_amg(normal_matrix, b, known_lr[unknown], (unknown, on_gel))
        if solution is not None:
            return solution
    return splu(normal_matrix.tocsc(), permc_spec="MMD_AT_PLUS_A").solve(b)


SPARSE_AMG_MIN_UNKNOWNS = 20_000
"""Fewest changed pixels of a sparse-path region that :func:`_solve_sparse` solves by AMG-preconditioned CG
(:func:`_solve_amg`) rather than SuperLU. The crossover, SuperLU vs AMG CPU ms (median of 3 cold solves,
s27-amgpath, 2-core Xeon at load 4-8): compact regions (a flat-pad gel disc) 5,013 px 12 vs 14, 15,361 px 55 vs
37, 31,397 px 177 vs 69; thin crosses of bands over the default dome (little SuperLU fill) 13,296 px 19 vs 32,
22,000 px 41 vs 49, 32,700 px 71 vs 74, 48,375 px 127 vs 103. SuperLU's cost grows as its fill (n^1.5 on a
compact region), AMG's as n."""
AMG_HIERARCHY_CACHE_SIZE = 2
"""Most AMG hierarchies kept, one per region shape (its changed and gel pixels: the normal matrix depends on them
alone, not on the normals). A stream repeats them (a frame whose lighting drifted flags the same whole gel; a
contact held still keeps its mask): the set-up, a third to a half of a cold solve, is then skipped. Each holds
its levels' matrices: 57 MiB for the flat pad's whole gel at 640x480, 15 MiB for the default dome's cross."""
_amg_cache: collections.OrderedDict[bytes, object] = collections.OrderedDict()
_amg_cache_lock = threading.Lock()


def _solve_amg(
    normal_matrix: sparse_matrix, b: np.ndarray, guess: np.ndarray, shape_masks: tuple[np.ndarray, np.ndarray]
) -> np.ndarray | None:
    """(n,) float64 solution of the sparse path's normal equations by conjugate gradients preconditioned with a
    classical (Ruge-Stuben) AMG V-cycle (pyamg), from ``guess`` (the reference log-range), to the relative residual
    :data:`~nlipscalib.core.tolerances.INTEGRATION_AMG_RTOL`; None where CG did not reach it (SuperLU then).

    Why Ruge-Stuben, not smoothed aggregation: on this 5-point M-matrix it took 6-9 CG steps to SA's 7-16 and half
    SA's CPU time at the same depth error (s27-amgpath). The hierarchy depends on ``shape_masks`` (the crop's changed
    and gel pixels) alone, and is kept per shape (:data:`AMG_HIERARCHY_CACHE_SIZE`).
    """
    import hashlib

    import pyamg

    from ..core.blas import blas_threads
    from ..core.tolerances import INTEGRATION_AMG_RTOL

    unknown, on_gel = shape_masks
    digest = hashlib.blake2b(repr(unknown.shape).encode(), digest_size=16)
    for mask in shape_masks:
        digest.update(np.packbits(mask).tobytes())
    key = digest.digest()
    with _amg_cache_lock:
        hierarchy = _amg_cache.get(key)
        if hierarchy is not None:
            _amg_cache.move_to_end(key)
    # one BLAS thread: CG's norms and dot products of ~1e5 values took 16 ms each, not 0.03, with a second
    # thread waiting on a shared machine (load 5, s27-amgpath)
    with blas_threads(1):
        if hierarchy is None:
            hierarchy = pyamg.ruge_stuben_solver(normal_matrix.tocsr())
            with _amg_cache_lock:
                _amg_cache[key] = hierarchy
                while len(_amg_cache) > AMG_HIERARCHY_CACHE_SIZE:
                    _amg_cache.popitem(last=False)
        x, info = hierarchy.solve(b, x0=guess.copy(), tol=INTEGRATION_AMG_RTOL, accel="cg", return_info=True)
    return x if info == 0 else None


def _grown_bounds(unknown: np.ndarray) -> tuple[slice, slice]:
    """(rows, cols) slices of the bounds of ``unknown``'s pixels grown by one pixel, within the image."""
    rows, cols = np.flatnonzero(unknown.any(1)), np.flatnonzero(unknown.any(0))
    H, W = unknown.shape
    return slice(max(rows[0] - 1, 0), min(rows[-1] + 2, H)), slice(max(cols[0] - 1, 0), min(cols[-1] + 2, W))


def _unbounded(unknown: np.ndarray, on_gel: np.ndarray) -> np.ndarray:
    """(H, W) bool -- the unknown pixels whose 4-connected region has no known on-gel neighbour (nothing
    fixes its level: e.g. a region that covers the whole gel)."""
    from scipy import ndimage

    labels, count = ndimage.label(unknown)
    touching = ndimage.binary_dilation(on_gel & ~unknown) & unknown
    bounded = np.zeros(count + 1, bool)
    bounded[np.unique(labels[touching])] = True
    return unknown & ~bounded[labels]


def _equations(
    unknown: np.ndarray, on_gel: np.ndarray, index: np.ndarray, known_lr: np.ndarray, p: np.ndarray, q: np.ndarray
):
    """Rows of the least-squares system x_j - x_i = (g_i + g_j) / 2 over neighbour pairs touching an unknown."""
    rows, cols, vals, rhs = [], [], [], []
    n_eq = 0
    flat_lr = known_lr.ravel()
    for axis, grad in ((1, p), (0, q)):
        a = (slice(None), slice(None, -1)) if axis == 1 else (slice(None, -1), slice(None))
        b = (slice(None), slice(1, None)) if axis == 1 else (slice(1, None), slice(None))
        lin = np.arange(unknown.size).reshape(unknown.shape)
        ia, ib = lin[a].ravel(), lin[b].ravel()
        use = (on_gel[a] & on_gel[b] & (unknown[a] | unknown[b])).ravel()
        ia, ib = ia[use], ib[use]
        g = 0.5 * (grad.ravel()[ia] + grad.ravel()[ib])
        ua, ub = index[ia], index[ib]
        eq = n_eq + np.arange(len(ia))
        # x_b - x_a = g ; a known endpoint moves to the right-hand side
        r = g.copy()
        r += np.where(ua < 0, flat_lr[ia], 0.0)
        r -= np.where(ub < 0, flat_lr[ib], 0.0)
        for sign, u_idx in ((-1.0, ua), (1.0, ub)):
            m = u_idx >= 0
            rows.append(eq[m])
            cols.append(u_idx[m])
            vals.append(np.full(int(m.sum()), sign))
        rhs.append(r)
        n_eq += len(ia)
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals), np.concatenate(rhs)
