"""Pixel-exact ground truth: trace one ray per pixel centre of the core camera model.

The rays are the core :attr:`Camera.rays` (pixel centres at integer (u, v)), the normals are the
shading normals the BSDF shades with (interpolated vertex normals), and contact is the per-vertex
contact flag interpolated over the hit triangle, thresholded at 0.5.
"""

from __future__ import annotations

import numpy as np

from ...core.capture import GroundTruth, Reference
from .mesh import CONTACT_ATTR


def trace_ground_truth(mi, scene, camera) -> GroundTruth:
    """Ground truth of ``scene`` as seen by ``camera``.

    Parameters
    ----------
    mi : mitsuba module with the variant of ``scene`` active
    scene : mi.Scene built in the camera frame (mm)
    camera : core Camera

    Returns
    -------
    GroundTruth with depth (H, W) float32 mm (NaN on miss), points (H, W, 3) float32 mm camera frame
    (NaN on miss), normals (H, W, 3) float32 unit toward the camera (0 on miss), valid and contact
    (H, W) bool.
    """
    h, w = camera.shape
    rays = np.ascontiguousarray(camera.rays.reshape(-1, 3), dtype=np.float32)
    trace = _trace_scalar if mi.variant().startswith("scalar") else _trace_vector
    valid, points, normals, contact = trace(mi, scene, rays)
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


def reference_from(gt: GroundTruth) -> Reference:
    """The Reference (depth, normals) of an undeformed-dome ground truth."""
    return Reference(depth=gt.depth.copy(), normals=gt.normals.copy())


def _trace_vector(mi, scene, rays):
    ray = mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(np.ascontiguousarray(rays.T)))
    si = scene.ray_intersect(ray)
    valid = np.array(si.is_valid(), dtype=bool)
    contact = np.zeros(valid.shape, dtype=bool)
    shape = scene.shapes()[0] if scene.shapes() else None
    if shape is not None and shape.has_attribute(CONTACT_ATTR):
        contact = np.array(shape.eval_attribute_1(CONTACT_ATTR, si, si.is_valid()), dtype=np.float32) > 0.5
    return valid, _to_n3(si.p), _to_n3(si.sh_frame.n), contact


def _trace_scalar(mi, scene, rays):
    # scalar_rgb fallback only: one Python call per pixel (seconds at 640x480)
    n = len(rays)
    valid, contact = np.zeros(n, bool), np.zeros(n, bool)
    points, normals = np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32)
    shape = scene.shapes()[0] if scene.shapes() else None
    has_contact = shape is not None and shape.has_attribute(CONTACT_ATTR)
    for i, d in enumerate(rays):
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(0.0), mi.Vector3f(*map(float, d))))
        if si.is_valid():
            valid[i] = True
            points[i], normals[i] = list(si.p), list(si.sh_frame.n)
            contact[i] = has_contact and shape.eval_attribute_1(CONTACT_ATTR, si) > 0.5
    return valid, points, normals, contact


def _to_n3(vec) -> np.ndarray:
    # drjit 3-vectors convert to (3, N) in numpy
    return np.ascontiguousarray(np.array(vec, dtype=np.float32).T)
