"""Assembling a Mitsuba scene (camera frame, mm) from a camera, LEDs and a gel mesh."""

from __future__ import annotations

import math

import numpy as np

from .emitter import PLUGIN as LED_PLUGIN
from .integrator import PLUGIN as INTEGRATOR_PLUGIN
from .mesh import COLOR_ATTR, to_mitsuba_mesh
from .sensor import PLUGIN as CAMERA_PLUGIN
from .sensor import camera_props


def led_entries(mi, leds, only=None) -> dict:
    """Scene-dict entries of the LED emitters (``only``: keep just that 0-based LED)."""
    out = {}
    for k, led in enumerate(leds):
        if only is not None and k != only:
            continue
        out[f"led{k + 1:02d}"] = {
            "type": LED_PLUGIN,
            "index": k if only is None else 0,
            "position": mi.ScalarPoint3f(led.position),
            "direction": mi.ScalarVector3f(led.direction),
            "mu": float(led.mu),
            "intensity": mi.ScalarVector3f(led.intensity),
        }
    return out


def sensor_entry(camera, spp: int, pixel_exact: bool = False) -> dict:
    """The distorted camera with a box filter so every sample stays in its own pixel."""
    root = math.isqrt(spp)
    if pixel_exact:
        sampler = {"type": "stratified", "sample_count": 1, "jitter": False}
    elif root * root == spp:
        sampler = {"type": "stratified", "sample_count": spp}
    else:
        sampler = {"type": "independent", "sample_count": spp}
    film = {
        "type": "hdrfilm",
        "width": camera.width,
        "height": camera.height,
        "pixel_format": "rgb",
        "rfilter": {"type": "box"},
    }
    return {"type": CAMERA_PLUGIN, **camera_props(camera), "film": film, "sampler": sampler}


def build_scene(
    mi,
    camera,
    leds,
    vertices,
    faces,
    normals,
    contact,
    colors=None,
    albedo=(0.8, 0.8, 0.8),
    spp=4,
    bounces=0,
    integrator="multi",
    only_led=None,
):
    """Load the scene.

    Parameters
    ----------
    camera : core Camera ; leds : sequence of core Led (camera frame)
    vertices, faces, normals, contact, colors : see :func:`to_mitsuba_mesh` (camera frame)
    albedo : (3,) uniform albedo used when ``colors`` is None
    integrator : "multi" (one AOV per LED) or "path" (Mitsuba's standard path tracer, cross-checks)
    only_led : keep only this LED in the scene (for single-LED "path" renders)
    """
    if colors is not None:
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "mesh_attribute", "name": COLOR_ATTR}})
    else:
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": {"type": "rgb", "value": list(map(float, albedo))}})
    mesh = to_mitsuba_mesh(mi, vertices, faces, normals, contact, colors)
    mesh.set_bsdf(bsdf)
    n_leds = len(leds) if only_led is None else 1
    if integrator == "multi":
        integ = {"type": INTEGRATOR_PLUGIN, "n_leds": n_leds, "bounces": int(bounces)}
    else:
        # max_depth counts the camera ray and the light ray: 2 = direct only.
        integ = {"type": "path", "max_depth": int(bounces) + 2, "rr_depth": 1000, "hide_emitters": True}
    scene = {"type": "scene", "integrator": integ, "sensor": sensor_entry(camera, spp), "gel": mesh}
    scene |= led_entries(mi, leds, only_led)
    return mi.load_dict(scene)


def gel_arrays(mesh_vertices_dome, camera_position) -> np.ndarray:
    """(V, 3) float64 dome-frame vertices moved into the camera frame (axes are parallel)."""
    return np.asarray(mesh_vertices_dome, dtype=np.float64) - np.asarray(camera_position, dtype=np.float64)
