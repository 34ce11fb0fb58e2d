"""Simple analytic gel surfaces (dome frame, mm, faces wound toward the camera on the -z side).

Used by tests and as a stand-in when the full dome generator (``sim.dome``) is unavailable.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # trimesh is imported where a surface is made: named for the hints only
    import trimesh


def _grid_faces(rows: int, cols: int) -> np.ndarray:
    i, j = np.mgrid[0 : rows - 1, 0 : cols - 1]
    a = (i * cols + j).ravel()
    b, c, d = a + 1, a + cols, a + cols + 1
    return np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])


def plate(z: float = 10.0, half: float = 40.0, n: int = 41) -> trimesh.Trimesh:
    """Flat square plate at height ``z`` facing -z (toward a camera below it).

    Returns
    -------
    trimesh.Trimesh, dome frame, mm, vertex normals (0, 0, -1)
    """
    import trimesh

    g = np.linspace(-half, half, n)
    x, y = np.meshgrid(g, g)
    verts = np.stack([x.ravel(), y.ravel(), np.full(x.size, float(z))], 1)
    faces = _grid_faces(n, n)
    e1, e2 = verts[faces[0, 1]] - verts[faces[0, 0]], verts[faces[0, 2]] - verts[faces[0, 0]]
    if np.cross(e1, e2)[2] > 0:  # wind toward -z
        faces = faces[:, ::-1]
    return trimesh.Trimesh(verts, np.ascontiguousarray(faces), process=False)


def hemisphere(radius: float = 15.0, n_polar: int = 48, n_azimuth: int = 96) -> trimesh.Trimesh:
    """Hemisphere of ``radius`` centred at the origin, apex at +z, faces wound inward.

    Returns
    -------
    trimesh.Trimesh, dome frame, mm; its vertex normals point toward the centre
    """
    import trimesh

    polar = np.linspace(0, np.pi / 2, n_polar + 1)[1:]
    az = np.linspace(0, 2 * np.pi, n_azimuth, endpoint=False)
    p, a = np.meshgrid(polar, az, indexing="ij")
    ring = radius * np.stack([np.sin(p) * np.cos(a), np.sin(p) * np.sin(a), np.cos(p)], -1).reshape(-1, 3)
    verts = np.concatenate([[[0, 0, radius]], ring])
    faces = []
    for j in range(n_azimuth):  # apex fan
        faces.append([0, 1 + j, 1 + (j + 1) % n_azimuth])
    for i in range(n_polar - 1):
        for j in range(n_azimuth):
            a0 = 1 + i * n_azimuth + j
            a1 = 1 + i * n_azimuth + (j + 1) % n_azimuth
            b0, b1 = a0 + n_azimuth, a1 + n_azimuth
            faces += [[a0, b0, a1], [a1, b0, b1]]
    faces = np.array(faces)
    tri = verts[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    if np.mean(np.sum(normal * tri.mean(axis=1), axis=1)) > 0:  # outward: flip to inward
        faces = faces[:, ::-1]
    return trimesh.Trimesh(verts, np.ascontiguousarray(faces), process=False)
