"""Point cloud / mesh export as binary PLY (a plain writer: no mesh library needed at inference time)."""

from __future__ import annotations

import errno
from pathlib import Path

import numpy as np

from ..core.atomic import write_bytes
from ..core.errors import PATH, ShapeError, check_kind


def grid_faces(valid: np.ndarray) -> np.ndarray:
    """Triangles over the pixel grid: two per 2x2 block of valid pixels.

    Parameters
    ----------
    valid : (H, W) bool

    Returns
    -------
    faces : (F, 3) int32 -- indices into the flattened (H*W) grid, wound so that the normal points
        toward the camera (image x right, y down, camera z forward)
    """
    H, W = valid.shape
    idx = np.arange(H * W).reshape(H, W)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    ok = (valid[:-1, :-1] & valid[:-1, 1:] & valid[1:, :-1] & valid[1:, 1:]).ravel()
    tri1 = np.stack([a.ravel(), c.ravel(), b.ravel()], -1)[ok]
    tri2 = np.stack([b.ravel(), c.ravel(), d.ravel()], -1)[ok]
    return np.concatenate([tri1, tri2]).astype(np.int32)


def write_ply(path: str | Path, points: np.ndarray, normals: np.ndarray | None = None, mesh: bool = False) -> Path:
    """Write the finite points (and their normals) of an (H, W, 3) map as a binary PLY, atomically.

    Parameters
    ----------
    points : (H, W, 3) float, mm, camera frame (NaN where there is no surface)
    normals : (H, W, 3) float, unit, or None
    mesh : also write the grid triangles (:func:`grid_faces`) between neighbouring points
    """
    check_kind(path, PATH, "path", "the .ply file's path (str or Path)")
    check_kind(points, np.ndarray, "points", "an (H, W, 3) array, mm (rec.points, frame.points)")
    check_kind(normals, (np.ndarray, type(None)), "normals", "an (H, W, 3) array of unit normals, or None")
    check_kind(mesh, bool, "mesh", "True or False")
    shapes = f"points {np.shape(points)}" + ("" if normals is None else f", normals {np.shape(normals)}")
    if np.ndim(points) != 3 or np.shape(points)[-1] != 3 or (normals is not None and normals.shape != points.shape):
        raise ShapeError(f"write_ply needs (H, W, 3) points (and normals of their shape), got {shapes}")
    if Path(path).is_dir():  # the write's own error named its temporary file
        raise IsADirectoryError(errno.EISDIR, "a folder; give the path of the .ply file to write", str(path))
    valid = np.all(np.isfinite(points), -1)
    keep = np.flatnonzero(valid)
    cols = [points.reshape(-1, 3)[keep].astype(np.float32)]
    props = ["x", "y", "z"]
    if normals is not None:
        cols.append(normals.reshape(-1, 3)[keep].astype(np.float32))
        props += ["nx", "ny", "nz"]
    vertices = np.ascontiguousarray(np.concatenate(cols, 1))
    header = ["ply", "format binary_little_endian 1.0", "comment nlipscalib, mm, camera frame"]
    header += [f"element vertex {len(keep)}"] + [f"property float {p}" for p in props]
    body = vertices.astype("<f4").tobytes()
    if mesh:
        remap = np.full(valid.size, -1, np.int64)
        remap[keep] = np.arange(len(keep))
        faces = remap[grid_faces(valid)]
        header += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
        rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
        rec["n"], rec["i"] = 3, faces
        body += rec.tobytes()
    header.append("end_header")
    return write_bytes(path, ("\n".join(header) + "\n").encode() + body)
