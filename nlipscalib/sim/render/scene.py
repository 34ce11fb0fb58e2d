"""Assembling a Mitsuba scene (camera frame, mm) from a camera, LEDs and a gel mesh."""

from __future__ import annotations

import math
from types import ModuleType
from typing import TYPE_CHECKING

import numpy as np

from ...core.camera import Camera
from ...core.leds import Leds
from .emitter import PLUGIN as LED_PLUGIN
from .integrator import PLUGIN as INTEGRATOR_PLUGIN
from .mesh import COLOR_ATTR, to_mitsuba_mesh
from .sensor import PLUGIN as CAMERA_PLUGIN
from .sensor import camera_props

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    import mitsuba

REFRACT_CONE_DEG = 30.0
"""Largest half-angle of the cone in which a coat vertex looks for each LED through a refracting gel, degrees."""
REFRACT_CONE_MARGIN = 1.3
"""That cone's half-angle over the LED's angular radius seen in a straight line (see the integrator)."""


def led_entries(mi: ModuleType, leds: Leds, only: int | None = None, shape: str = "point", size: float = 0.0) -> dict:
    """Scene-dict entries of the LED emitters (``only``: keep just that 0-based LED; ``shape``/``size``: see
    :mod:`.emitter`)."""
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
            "shape": shape,
            "size": float(size),
        }
    return out


def sensor_entry(camera: Camera, spp: int) -> dict:
    """The distorted camera with a box filter so every sample stays in its own pixel, and an alpha channel (after
    R, G, B): the share of the pixel's samples that reach the gel, its coverage (partly covered pixels lie on the
    gel's outline in a view beyond the gel; the bounce light's filter works per unit of it, :mod:`.denoise`)."""
    root = math.isqrt(spp)
    if root * root == spp:
        sampler = {"type": "stratified", "sample_count": spp}
    else:
        sampler = {"type": "independent", "sample_count": spp}
    film = {
        "type": "hdrfilm",
        "width": camera.width,
        "height": camera.height,
        "pixel_format": "rgba",
        "rfilter": {"type": "box"},
    }
    return {"type": CAMERA_PLUGIN, **camera_props(camera), "film": film, "sampler": sampler}


def coating_bsdf(
    colors: np.ndarray | None = None,
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8),
    specular: float = 0.0,
    roughness: float = 0.3,
) -> dict:
    """Scene-dict entry of the coat: Lambertian, plus a rough specular lobe when ``specular`` > 0.

    The lobe is a GGX rough mirror (``roughconductor``, reflectance 1) blended in with weight
    ``specular``: ``(1 - specular) * Lambert(albedo) + specular * GGX(roughness)``, so ``specular = 0`` is the
    NLiPs model exactly and the lobe's strength and width are independent knobs.
    """
    if colors is not None:
        reflectance = {"type": "mesh_attribute", "name": COLOR_ATTR}
    else:
        reflectance = {"type": "rgb", "value": list(map(float, albedo))}
    diffuse = {"type": "diffuse", "reflectance": reflectance}
    if specular <= 0:
        return diffuse
    lobe = {"type": "roughconductor", "material": "none", "distribution": "ggx", "alpha": float(roughness)}
    return {"type": "blendbsdf", "weight": float(specular), "diffuse": diffuse, "lobe": lobe}


def build_scene(
    mi: ModuleType,
    camera: Camera,
    leds: Leds,
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    contact: np.ndarray,
    colors: np.ndarray | None = None,
    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8),
    spp: int = 4,
    bounces: int = 0,
    integrator: str = "multi",
    only_led: int | None = None,
    led_shape: str = "point",
    led_size: float = 0.0,
    specular: float = 0.0,
    roughness: float = 0.3,
    interface: tuple[np.ndarray, np.ndarray, float, float] | None = None,
    split_bounces: bool = False,
) -> mitsuba.Scene:
    """Load the scene.

    Parameters
    ----------
    camera : core Camera ; leds : sequence of core Led (camera frame)
    vertices, faces, normals, contact, colors : see :func:`to_mitsuba_mesh` (camera frame)
    albedo : (3,) uniform albedo used when ``colors`` is None
    integrator : "multi" (one AOV per LED) or "path" (Mitsuba's standard path tracer, cross-checks)
    only_led : keep only this LED in the scene (for single-LED "path" renders)
    led_shape, led_size : emitting area of every LED ("point", "disk", "square"; mm)
    specular, roughness : the coat's specular lobe (see :func:`coating_bsdf`)
    interface : None (index-matched gel) or (vertices (V, 3) mm camera frame, faces (F, 3) wound toward
        the camera, gel_ior, housing_ior): the refracting inner surface of the gel
    split_bounces : "multi" with bounces: the bounce vertices' light in AOVs of its own (``aov_names``)
    """
    bsdf = mi.load_dict(coating_bsdf(colors, albedo, specular, roughness))
    mesh = to_mitsuba_mesh(mi, vertices, faces, normals, contact, colors)
    mesh.set_bsdf(bsdf)
    n_leds = len(leds) if only_led is None else 1
    if integrator == "multi":
        integ = {"type": INTEGRATOR_PLUGIN, "n_leds": n_leds, "bounces": int(bounces), "split": bool(split_bounces)}
        if interface is not None:
            integ |= {"refract": True, "eta": float(interface[2] / interface[3]), "cone_deg": REFRACT_CONE_DEG}
            integ["cone_margin"] = REFRACT_CONE_MARGIN
    else:
        # max_depth counts the camera ray and the light ray: 2 = direct only.
        integ = {"type": "path", "max_depth": int(bounces) + 2, "rr_depth": 1000, "hide_emitters": True}
    scene = {"type": "scene", "integrator": integ, "sensor": sensor_entry(camera, spp), "gel": mesh}
    if interface is not None:
        scene["interface"] = interface_shape(mi, *interface)
    scene |= led_entries(mi, leds, only_led, led_shape, led_size)
    return mi.load_dict(scene)


def interface_shape(
    mi: ModuleType, vertices: np.ndarray, faces: np.ndarray, gel_ior: float, housing_ior: float
) -> mitsuba.Mesh:
    """The gel's inner surface as a smooth ``dielectric``: gel inside, housing on the side its normals face."""
    import trimesh

    normals = trimesh.Trimesh(vertices, faces, process=False).vertex_normals
    mesh = to_mitsuba_mesh(mi, vertices, faces, normals, np.zeros(len(vertices)), name="interface")
    mesh.set_bsdf(mi.load_dict({"type": "dielectric", "int_ior": float(gel_ior), "ext_ior": float(housing_ior)}))
    return mesh
