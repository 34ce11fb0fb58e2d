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
  normal equations; used when no box below applies. A region of :data:`.integrate_sparse.SPARSE_AMG_MIN_UNKNOWNS` pixels
  or more (a cross of bands over the view, the flat pad's whole gel changed) is solved by conjugate gradients with a
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
Green's function, summed per frame from its sine modes (:func:`.integrate_green._box_green`), with no box solve per rim
pixel. A rim box may reach the image border: that side is natural as an edge box's (mirrored; its axis's modes are the
doubled path's odd sines, :func:`.integrate_green._axis_modes`), and an axis at both borders takes cosines. A box with
no fixed pixel at all (a frame changed on the whole gel, or a whole gel island) is solved where every pixel of it is
changed: the sparse path then anchors every unknown (:data:`.integrate_sparse.ANCHOR_WEIGHT` on the diagonal), which
adds the weight to every eigenvalue of the box -- the same equation, the cosine-cosine box's zero eigenvalue included.

``"auto"`` takes one box around all changed pixels where it applies; else it splits them into their
4-connected regions (no equation joins two), each group a box, an edge box where its box reaches the
image border (a contact pressed at the edge of the view: 5-9 ms at 640x480, not the 0.16-0.37 s of SuperLU;
across the image: 14-31 ms, not 0.34-1.0 s, at load 9), a rim box where its box holds off-gel pixels (also at
the image border) or spans both axes with every pixel changed, and the sparse path where none applies: a region
across both axes with unchanged pixels in its box (a cross or ridges over the whole view: anchoring the box would
let a dent lift the unchanged surface, which the sparse path holds at the reference), a box with no fixed pixel
and unchanged pixels, a mix of gel parts with and without one, or a rim too long for the Green's sum
(:data:`.integrate_rim.MAX_RIM_GREEN_VALUES`: the flat pad's whole gel, 992 rim pixels).

This module is the entry (:func:`integrate_on_dome`, and :func:`solve_region_group`, which the torch path calls for
the groups it leaves to the host); each part lives in a file of its own:

- ``integrate_geometry.py``: the sensor's rays (:class:`.integrate_geometry.RayGeometry`) and the log-range gradient;
- ``integrate_regions.py``: the changed pixels split into boxes, edge boxes and region groups;
- ``integrate_box.py``: the box and edge box solve (sines, cosines) and its right-hand side;
- ``integrate_rim.py``: the rim box (capacitance matrix);
- ``integrate_green.py``: the inverse of a box's Laplacian that the rim box is built on (Green's function);
- ``integrate_sparse.py``: the sparse path (SuperLU; AMG-preconditioned CG for large regions).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..core.errors import ShapeError
from .integrate_box import _solve_box
from .integrate_geometry import RayGeometry
from .integrate_regions import Box, _crop_edges, _regions
from .integrate_rim import _faster_rim_box, _interior_mask, _rim_box_anchor, _solve_rim_box
from .integrate_sparse import _solve_sparse


def integrate_on_dome(
    normals: np.ndarray, unknown: np.ndarray, geo: RayGeometry, method: str = "auto"
) -> tuple[np.ndarray, np.ndarray]:
    """Depth of the surface whose normals are ``normals`` where ``unknown``, the reference elsewhere.

    Parameters
    ----------
    normals : (H, W, 3) float, unit, camera frame, toward the camera; finite where ``unknown`` and around it on the
        gel (each region is solved on a box around it, which reads the normals of the box's other pixels): the
        reference's normals outside ``unknown`` (``press.reference.normals``; a Reconstruction's are NaN there:
        ``np.where(rec.reconstructed[..., None], rec.normals, press.reference.normals)``)
    unknown : (H, W) bool -- pixels to solve for (the changed pixels); must lie on the gel
    geo : RayGeometry of the sensor
    method : "auto" (box, else per region a box, an edge box or sparse), "box" or "sparse" (module docstring)

    Returns
    -------
    depth : (H, W) float32, mm, camera-frame z (the reference depth outside the solved pixels; NaN off the gel)
    points : (H, W, 3) float32, mm, camera frame

    Raises
    ------
    ShapeError -- arrays of other shapes, ``unknown`` not bool, or normals not finite where a region's solve reads
        them (its depth came back NaN without a word)
    """
    if not isinstance(unknown, np.ndarray) or unknown.dtype != np.bool_:
        raise ShapeError(f"unknown must be an (H, W) bool array, got {getattr(unknown, 'dtype', type(unknown))}")
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
            _check_finite(normals, on_gel, box)
            log_range = _solve_box(normals, geo, box, edges)
            points[box] = np.exp(log_range.astype(np.float32))[..., None] * geo.rays32[box]
        for i, crop in enumerate(sparse):
            others = [box for box, _ in edge_boxes] + boxes + sparse[:i] + sparse[i + 1 :]
            _check_finite(normals, on_gel, crop)
            crop, solved, solved_points = solve_region_group(normals, unknown, on_gel, geo, crop, others, method)
            points[crop][solved] = solved_points
    return points[..., 2], points


def _check_finite(normals: np.ndarray, on_gel: np.ndarray, box: Box) -> None:
    """ShapeError unless ``normals`` are finite on the gel's pixels of ``box`` (what a region's solve reads). Checked
    on the box alone, the gel mask only when something in it is not finite (off the gel): 5-40 us for a 100-200 px
    square box, where the masked check took 0.25-1 ms (a frame's integration at 640x480: a few ms)."""
    in_box = normals[box]
    if not np.isfinite(in_box).all() and not np.isfinite(in_box[on_gel[box]]).all():
        raise ShapeError(
            "normals are not finite around the pixels to solve (NaN outside a Reconstruction's reconstructed pixels?): "
            "give the reference's normals there, np.where(rec.reconstructed[..., None], rec.normals, reference normals)"
        )


def solve_region_group(
    normals: np.ndarray,
    unknown: np.ndarray,
    on_gel: np.ndarray,
    geo: RayGeometry,
    crop: Box,
    others: Sequence[Box],
    method: str = "auto",
) -> tuple[Box, np.ndarray, np.ndarray]:
    """One region group that no box of :func:`.integrate_regions._regions` solves (its bounds ``crop``; ``others`` the
    frame's other boxes and groups), as :func:`integrate_on_dome` solves it: a rim box where one applies ("auto"), else
    the sparse path. The torch path (:mod:`.integrate_torch`) calls it on the host for the groups it does not solve
    itself.

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
