"""Pixel-exact ground truth: trace one ray per pixel centre of the core camera model.

The rays are the core :attr:`Camera.rays` (pixel centres at integer (u, v)), the normals are the
shading normals the BSDF shades with (interpolated vertex normals), and contact is the per-vertex
contact flag interpolated over the hit triangle, thresholded at 0.5. Through a refracting gel
(a ``dielectric`` interface in the scene) each ray is refracted (Snell) and the ground truth is the
coat point it then meets: the point the pixel really sees.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...core.errors import ConfigError
from ...core.surface_files import GroundTruth, Reference
from .mesh import CONTACT_ATTR

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    from collections.abc import Callable
    from types import ModuleType

    import mitsuba

    from ...core.camera import Camera


def trace_ground_truth(mi: ModuleType, scene: mitsuba.Scene, camera: Camera, eta: float | None = None) -> GroundTruth:
    """Ground truth of ``scene`` as seen by ``camera``.

    Parameters
    ----------
    mi : mitsuba module with the variant of ``scene`` active
    scene : mi.Scene built in the camera frame (mm)
    camera : core Camera
    eta : n_gel / n_housing of the scene's refracting interface, or None when there is none

    Returns
    -------
    GroundTruth with depth (H, W) float32 mm (NaN on miss), points (H, W, 3) float32 mm camera frame
    (NaN on miss), normals (H, W, 3) float32 unit toward the camera (0 on miss), valid and contact
    (H, W) bool.
    """
    h, w = camera.shape
    rays = np.ascontiguousarray(camera.rays.reshape(-1, 3), dtype=np.float32)
    if mi.variant().startswith("scalar"):
        if eta is not None:
            raise ConfigError("gel_optics needs a vectorised Mitsuba variant (llvm_ad_rgb or cuda_ad_rgb)")
        trace = lambda r: _trace_scalar(mi, scene, r)  # noqa: E731
    else:
        trace = lambda r: _trace_vector(mi, scene, r, eta)  # noqa: E731
    valid, points, normals, contact = trace(rays)
    _retrace_pinholes(trace, rays, valid.reshape(h, w), (valid, points, normals, contact))
    points[~valid] = np.nan
    normals[~valid] = 0.0
    normals[valid] /= np.linalg.norm(normals[valid], axis=1, keepdims=True)
    contact &= valid
    return GroundTruth(
        depth=points[:, 2].reshape(h, w).copy(),
        points=points.reshape(h, w, 3),
        normals=normals.reshape(h, w, 3).astype(np.float32),
        valid=valid.reshape(h, w),
        contact=contact.reshape(h, w),
    )


PINHOLE_NUDGE_RAD = 1e-5
"""How far a missed ray is turned to be traced again (:func:`_retrace_pinholes`): 0.2 um at 20 mm."""


def _retrace_pinholes(trace: Callable[[np.ndarray], tuple], rays: np.ndarray, valid: np.ndarray, out: tuple) -> None:
    """Trace again, slightly turned, the rays that missed a surface their four neighbours all hit.

    Single-precision ray-triangle tests are not watertight: a ray through a shared edge or vertex of the
    deformed mesh can slip between its triangles (seen: one pixel inside a 160x120 sphere dent, a black dot
    in the true normals, left out of every score). Each such ray is traced again turned by
    :data:`PINHOLE_NUDGE_RAD` in up to four directions; the first hit fills ``out`` (valid, points, normals,
    contact: flat per-pixel arrays, changed in place).
    """
    inner = np.zeros_like(valid)
    inner[1:-1, 1:-1] = valid[:-2, 1:-1] & valid[2:, 1:-1] & valid[1:-1, :-2] & valid[1:-1, 2:]
    todo = np.flatnonzero(inner & ~valid)
    for axis in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)):
        if not todo.size:
            return
        turned = rays[todo] + np.float32(PINHOLE_NUDGE_RAD) * np.asarray(axis, np.float32)
        hit = trace(np.ascontiguousarray(turned / np.linalg.norm(turned, axis=1, keepdims=True)))
        got = hit[0]
        for whole, part in zip(out, hit):
            whole[todo[got]] = part[got]
        todo = todo[~got]


def reference_from(gt: GroundTruth) -> Reference:
    """The Reference (depth, normals) of an undeformed-dome ground truth."""
    return Reference(depth=gt.depth.copy(), normals=gt.normals.copy())


REFRACTIONS = 2
"""Interface crossings followed per ground-truth ray (in through the gel's inner surface, and a spare)."""


def _gel_shape(scene: mitsuba.Scene):
    """The coated gel mesh of a scene built by ``build_scene`` (other shapes: the refracting interface)."""
    shapes = [s for s in scene.shapes() if s.id() == "gel"] or list(scene.shapes()[:1])
    return shapes[0] if shapes else None


def _trace_vector(mi: ModuleType, scene: mitsuba.Scene, rays: np.ndarray, eta: float | None = None):
    import drjit as dr

    ray = mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(np.ascontiguousarray(rays.T)))
    si = scene.ray_intersect(ray)
    for _ in range(REFRACTIONS if eta is not None else 0):
        delta = si.is_valid() & mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Delta)
        _, cos_t, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(si.wi), eta)
        refracted = si.spawn_ray(si.to_world(mi.refract(si.wi, cos_t, eta_ti)))
        ray = dr.select(delta, refracted, ray)
        si = scene.ray_intersect(ray)
    valid = si.is_valid() & ~mi.has_flag(si.bsdf().flags(), mi.BSDFFlags.Delta)
    contact = np.zeros(dr.width(valid), dtype=bool)
    shape = _gel_shape(scene)
    if shape is not None and shape.has_attribute(CONTACT_ATTR):
        contact = np.array(shape.eval_attribute_1(CONTACT_ATTR, si, valid), dtype=np.float32) > 0.5
    return np.array(valid, dtype=bool), _to_n3(si.p), _to_n3(si.sh_frame.n), contact


def _trace_scalar(mi: ModuleType, scene: mitsuba.Scene, rays: np.ndarray):
    # scalar_rgb fallback only: one Python call per pixel (seconds at 640x480)
    n = len(rays)
    valid, contact = np.zeros(n, bool), np.zeros(n, bool)
    points, normals = np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32)
    shape = _gel_shape(scene)
    has_contact = shape is not None and shape.has_attribute(CONTACT_ATTR)
    for i, d in enumerate(rays):
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(*map(float, d))))
        if si.is_valid():
            valid[i] = True
            points[i], normals[i] = list(si.p), list(si.sh_frame.n)
            contact[i] = has_contact and shape.eval_attribute_1(CONTACT_ATTR, si) > 0.5
    return valid, points, normals, contact


def _to_n3(vec: mitsuba.Point3f | mitsuba.Normal3f) -> np.ndarray:
    # drjit 3-vectors convert to (3, N) in numpy
    return np.ascontiguousarray(np.array(vec, dtype=np.float32).T)
