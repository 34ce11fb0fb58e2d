"""The box solve (:mod:`.integrate`'s docstring): the Poisson equation of log-range on a box with its ring at the
reference, by sine transforms (an edge box mirrored across the image border; cosines along an axis it
spans). Its right-hand side is shared with the torch path (numpy or torch).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .integrate_geometry import Array, RayGeometry, _gradient32
from .integrate_regions import BOTH_SIDES, Box, Edges, _interior


def _solve_box(normals: np.ndarray, geo: RayGeometry, box: tuple[slice, slice], edges: Edges = (0, 0)) -> np.ndarray:
    """Log-range over the box: Poisson solve on its interior, the outer ring fixed at the reference (DST-I);
    on an edge box's border sides (``edges``) no ring, a natural side (mirrored, :mod:`.integrate`'s docstring); along
    an axis that spans the image (:data:`.integrate_regions.BOTH_SIDES`) a natural side at both ends: the type-II cosine
    transform there."""
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
    ``edges`` sides, :mod:`.integrate`'s docstring; a :data:`.integrate_regions.BOTH_SIDES` axis mirrored at both ends,
    not doubled): the right-hand side of the box solve; numpy or torch (shared with :mod:`.integrate_torch`). Arguments
    as :func:`box_rhs`'s, over the box; :func:`edge_box_parts` takes the box's log-range from the solve."""
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
    first after it; all of a :data:`.integrate_regions.BOTH_SIDES` axis), and where they go in the box (its interior: no
    ring on a border side)."""
    half = tuple(k if edge == BOTH_SIDES else k - 1 if edge else k - 2 for k, edge in zip(shape, edges))
    own = tuple(slice(-k, None) if edge == -1 else slice(0, k) for k, edge in zip(half, edges))
    return own, tuple(_interior(edge) for edge in edges)


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
    (:data:`.integrate_regions.BOTH_SIDES`), or natural at one end only (-1, +1: an edge box's mirrored axis, the odd
    modes of the doubled path's sines); in the order of :func:`.integrate_green._axis_modes`."""
    if edge == BOTH_SIDES:
        return 2 - 2 * np.cos(np.pi * np.arange(n) / n)
    if edge:
        return 2 - 2 * np.cos(np.pi * np.arange(1, 2 * n, 2) / (2 * n + 1))
    return 2 - 2 * np.cos(np.pi * np.arange(1, n + 1) / (n + 1))
