"""Gel dome meshes sampling the analytic surface, in the dome frame (mm).

Every dome except ``flat`` is a surface of revolution about +z, meshed as rings of nearly
equilateral triangles at equal arc-length steps along the meridian, so vertices lie exactly on the
analytic surface and the open base rim lies exactly at z = 0. Faces are wound so that their normals
point **inward** (toward the axis and the camera): Mitsuba's ``diffuse`` BSDF is one-sided and the
camera sees the coated surface from inside.

The analytic surface and its shape rules live in :mod:`nlipscalib.core.dome`.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from ..core.dome import check_dome, dome_inward_normals, dome_surface_point, project_to_dome
from ..core.sensor import DomeConfig

__all__ = ["check_dome", "dome_inward_normals", "dome_surface_point", "make_dome", "project_to_dome"]

_MERIDIAN_SAMPLES = 4096  # dense polyline for arc-length parametrisation; chord error ~1e-7 mm


def make_dome(cfg: DomeConfig) -> trimesh.Trimesh:
    """Triangle mesh of the gel's coated surface, open at the base.

    Parameters
    ----------
    cfg : DomeConfig

    Returns
    -------
    trimesh.Trimesh
        Dome frame, mm; face normals point inward (toward the camera). A fresh copy each call.
    """
    return _make_dome_cached(cfg).copy()


@functools.lru_cache(maxsize=16)
def _make_dome_cached(cfg: DomeConfig) -> trimesh.Trimesh:
    check_dome(cfg)
    if cfg.shape == "flat":
        vertices, faces = _flat_pad(cfg)
    else:
        vertices, faces = _revolution_mesh(_meridian(cfg), cfg.edge_length)
        vertices = project_to_dome(cfg, vertices)
    return _orient_inward(cfg, vertices, faces)


def _meridian(cfg: DomeConfig) -> np.ndarray:
    """(K, 2) float, mm: dense (r, z) polyline from the apex down to the base rim."""
    t = np.linspace(0.0, np.pi / 2, _MERIDIAN_SAMPLES)
    a = cfg.radius
    if cfg.shape == "hemisphere":
        return np.stack([a * np.sin(t), a * np.cos(t)], 1)
    if cfg.shape in ("fingertip", "oblate"):
        return np.stack([a * np.sin(t), cfg.height * np.cos(t)], 1)
    # capsule: quarter circle of the cap, then the straight cylinder wall down to z = 0
    zc = cfg.height - a
    cap = np.stack([a * np.sin(t), zc + a * np.cos(t)], 1)
    wall = np.stack([np.full(_MERIDIAN_SAMPLES, a), np.linspace(zc, 0.0, _MERIDIAN_SAMPLES)], 1)
    return np.concatenate([cap, wall[1:]])


def _revolution_mesh(meridian: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Rings at equal arc length along ``meridian``, zipped into triangle strips."""
    seg = np.linalg.norm(np.diff(meridian, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    n_rings = max(2, int(np.ceil(s[-1] / (edge * np.sqrt(3) / 2))))
    s_ring = np.linspace(0.0, s[-1], n_rings + 1)
    r = np.interp(s_ring, s, meridian[:, 0])
    z = np.interp(s_ring, s, meridian[:, 1])
    counts = np.maximum(6, np.round(2 * np.pi * r / edge).astype(int))
    counts[0] = 1  # the apex
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    verts, fracs = [], []
    for k, (rk, zk, n) in enumerate(zip(r, z, counts)):
        # stagger successive rings by an irrational fraction of a step: strips stay close to
        # equilateral and no two edge midpoints of neighbouring rings tie in _zip_rings
        f = (np.arange(n) + (k * 0.6180339887) % 1.0) / n
        fracs.append(f)
        ang = 2 * np.pi * f
        verts.append(np.stack([rk * np.cos(ang), rk * np.sin(ang), np.full(n, zk)], 1))
    faces = [_zip_rings(fracs[k], fracs[k + 1], starts[k], starts[k + 1]) for k in range(n_rings)]
    return np.concatenate(verts), np.concatenate(faces)


def _zip_rings(fa: np.ndarray, fb: np.ndarray, oa: int, ob: int) -> np.ndarray:
    """Triangles between two closed rings given their vertices' angular fractions in [0, 1).

    Each edge of one ring is joined to the vertex of the other ring nearest (in angle) to the
    edge's midpoint; this tiles the band exactly once.
    """
    na, nb = len(fa), len(fb)

    def nearest(frac: np.ndarray, ring: np.ndarray):
        d = np.abs((frac[:, None] - ring[None, :] + 0.5) % 1.0 - 0.5)
        return np.argmin(d, axis=1)

    ia = np.arange(na)
    ib = np.arange(nb)
    mid_a = fa + 0.5 / na
    mid_b = fb + 0.5 / nb
    tri_a = np.stack([oa + ia, oa + (ia + 1) % na, ob + nearest(mid_a, fb)], 1)
    tri_b = np.stack([ob + ib, ob + (ib + 1) % nb, oa + nearest(mid_b, fa)], 1)
    tris = np.concatenate([tri_a, tri_b])
    keep = (tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 0] != tris[:, 2])
    return tris[keep]


def _flat_pad(cfg: DomeConfig) -> tuple[np.ndarray, np.ndarray]:
    n = max(2, int(np.ceil(2 * cfg.radius / cfg.edge_length)))
    g = np.linspace(-cfg.radius, cfg.radius, n + 1)
    x, y = np.meshgrid(g, g, indexing="ij")
    # The camera sits on the axis, so grid and diagonal edges through the axis lie exactly in planes
    # of pixel-centre rays (u - cx = v - cy): such rays graze the shared edge and miss both triangles.
    # A tiny in-plane jitter of the interior vertices (pad stays flat) breaks that degeneracy.
    interior = (np.abs(x) < cfg.radius) & (np.abs(y) < cfg.radius)
    jitter = np.random.default_rng(0).uniform(-0.02, 0.02, size=(2,) + x.shape) * (g[1] - g[0])
    x, y = x + jitter[0] * interior, y + jitter[1] * interior
    vertices = np.stack([x.ravel(), y.ravel(), np.full(x.size, cfg.height)], 1)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    v00 = (i * (n + 1) + j).ravel()
    v10, v01, v11 = v00 + n + 1, v00 + 1, v00 + n + 2
    # alternate the diagonal so the pad has no preferred direction
    flip = ((i + j) % 2 == 1).ravel()
    t1 = np.where(flip[:, None], np.stack([v00, v10, v01], 1), np.stack([v00, v10, v11], 1))
    t2 = np.where(flip[:, None], np.stack([v10, v11, v01], 1), np.stack([v00, v11, v01], 1))
    return vertices, np.concatenate([t1, t2])


def _orient_inward(cfg: DomeConfig, vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """Flip every face whose geometric normal disagrees with the analytic inward normal."""
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    inward = dome_inward_normals(cfg, tri.mean(axis=1))
    flip = np.einsum("ij,ij->i", normal, inward) < 0
    faces = faces.copy()
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(vertices, faces, process=False)


def inner_surface(cfg: DomeConfig) -> trimesh.Trimesh:
    """The gel's inner surface (where it meets the housing): the dome moved inward by ``cfg.thickness``.

    For the curved domes this is the dome shape with radius and height reduced by the thickness (exact
    for the hemisphere, close to the true offset surface for the others); for ``flat`` the plane
    ``thickness`` below the pad. Faces wound inward (toward the camera), dome frame, mm.
    """
    import dataclasses

    t = cfg.thickness
    radius = cfg.radius if cfg.shape == "flat" else cfg.radius - t
    inner = dataclasses.replace(
        cfg,
        radius=radius,
        height=cfg.height - t,
        thickness=min(t, radius / 2),
        edge_length=min(cfg.edge_length, radius / 3),
        contact_edge_length=min(cfg.contact_edge_length, radius / 3),
    )
    return make_dome(inner)
