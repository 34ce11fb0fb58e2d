"""Turning a gel surface mesh into a Mitsuba mesh with per-vertex contact and albedo attributes."""

from __future__ import annotations

from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    import mitsuba

CONTACT_ATTR = "vertex_contact"
COLOR_ATTR = "vertex_color"
_N_WAVES = 6
_ALBEDO_SEED = 12345
"""Fixed: the coating pattern belongs to the sensor, not to a press, so it never changes with the seed."""


def albedo_per_vertex(
    points_dome: np.ndarray, albedo: tuple[float, float, float], variation: float, scale: float
) -> np.ndarray:
    """Smooth spatial albedo variation of the coating.

    Parameters
    ----------
    points_dome : (V, 3) float, mm, dome frame
    albedo : (3,) mean albedo per channel
    variation : relative amplitude (0 = uniform)
    scale : spatial wavelength of the variation, mm

    Returns
    -------
    (V, 3) float32, albedo per vertex, clipped to [0, 1]
    """
    albedo = np.asarray(albedo, dtype=np.float64)
    pts = np.asarray(points_dome, dtype=np.float64)
    rng = np.random.default_rng(_ALBEDO_SEED)
    dirs = rng.normal(size=(_N_WAVES, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    phase = rng.uniform(0, 2 * np.pi, _N_WAVES)
    # Sum of plane waves, normalised to about unit amplitude.
    g = np.cos(pts @ dirs.T * (2 * np.pi / scale) + phase).sum(axis=1) / np.sqrt(_N_WAVES / 2) / 2
    g = np.clip(g, -1, 1)
    return np.clip(albedo * (1 + variation * g[:, None]), 0, 1).astype(np.float32)


def to_mitsuba_mesh(
    mi: ModuleType,
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    contact: np.ndarray,
    colors: np.ndarray | None = None,
    name: str = "gel",
) -> mitsuba.Mesh:
    """Build a ``mi.Mesh`` with vertex normals and attributes.

    Parameters
    ----------
    vertices : (V, 3) float, mm, camera frame
    faces : (F, 3) int, wound toward the camera (``diffuse`` is one-sided)
    normals : (V, 3) float, unit, toward the camera (shading normals)
    contact : (V,) float or bool, 1 where the gel is displaced by the press
    colors : (V, 3) float albedo per vertex, or None (then no colour attribute)
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.uint32)
    normals = np.asarray(normals, dtype=np.float64)
    normals = np.ascontiguousarray(normals / np.linalg.norm(normals, axis=1, keepdims=True), dtype=np.float32)
    mesh = mi.Mesh(name, len(vertices), len(faces), has_vertex_normals=True, has_vertex_texcoords=False)
    params = mi.traverse(mesh)
    # Buffer types differ between JIT (mi.Float) and scalar (dynamic arrays) variants: reuse the mesh's own.
    ftype, utype = type(params["vertex_positions"]), type(params["faces"])
    params["vertex_positions"] = ftype(vertices.ravel())
    params["faces"] = utype(faces.ravel())
    params["vertex_normals"] = ftype(normals.ravel())
    params.update()
    mesh.add_attribute(CONTACT_ATTR, 1, ftype(np.asarray(contact, dtype=np.float32).ravel()))
    if colors is not None:
        mesh.add_attribute(COLOR_ATTR, 3, ftype(np.ascontiguousarray(colors, dtype=np.float32).ravel()))
    return mesh
