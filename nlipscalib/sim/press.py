"""Rendering one press of the digital twin into a press folder (the capture format of core/).

A press = dark frame + one white image per LED + the tri-colour image, each with its own sensor
noise, plus ground truth and the undeformed dome's Reference. Exposure is chosen once per scene
(:func:`scene_exposure`), so every press of a scene shares it and the solver can compare them.
"""

from __future__ import annotations

import json
import logging
import zlib

import numpy as np

from ..core.capture import write_press
from ..core.leds import TRICOLOR_COLORS, tricolor_groups
from ..errors import ConfigError
from .noise import apply_noise, auto_exposure, dark_frame
from .render.groundtruth import reference_from, trace_ground_truth

log = logging.getLogger(__name__)
_reference_cache: dict = {}
_exposure_cache: dict = {}


def undeformed_mesh(dome_cfg):
    """The undeformed gel mesh (dome frame, inward faces) from ``sim.dome``, or a stand-in hemisphere."""
    try:
        from .dome import make_dome
    except ModuleNotFoundError as exc:
        if exc.name != f"{__package__}.dome":
            raise
        if dome_cfg.shape != "hemisphere":
            raise ConfigError(f"dome shape {dome_cfg.shape!r} needs nlipscalib.sim.dome, which is missing") from None
        from .render.shapes import hemisphere

        log.warning("nlipscalib.sim.dome is missing: using a stand-in hemisphere mesh")
        return hemisphere(dome_cfg.radius)
    return make_dome(dome_cfg)


def reference_ground_truth(scene):
    """Ground truth of the undeformed dome (cached per dome + camera): the Reference and exposure source."""
    key = (scene.dome, scene.camera)
    if key not in _reference_cache:
        from .render.scene import build_scene
        from .render.variant import load_mitsuba

        mi, _ = load_mitsuba(scene.render.variant, scene.render.threads)
        mesh = undeformed_mesh(scene.dome)
        verts = np.asarray(mesh.vertices) - np.asarray(scene.camera.position)
        built = build_scene(
            mi,
            scene.camera_model(),
            scene.led_models(),
            verts,
            mesh.faces,
            mesh.vertex_normals,
            np.zeros(len(verts)),
            spp=1,
        )
        _reference_cache[key] = (mesh, trace_ground_truth(mi, built, scene.camera_model()))
    return _reference_cache[key]


def scene_exposure(scene, tricolor: bool = False) -> float:
    """Scale from linear radiance to fraction of full scale for this scene (see ``noise.auto_exposure``).

    The tri-colour image (``tricolor=True``) gets its own, shorter exposure: each of its channels sums
    a third of the LEDs and would otherwise saturate.
    """
    key = (scene.dome, scene.camera, scene.leds, scene.coating.albedo, scene.noise.exposure, tricolor)
    if key not in _exposure_cache:  # ~1 s of numpy at 640x480: once per scene, not per press
        _, gt = reference_ground_truth(scene)
        v = gt.valid
        leds, albedo = scene.led_models(), scene.coating.albedo
        _exposure_cache[key] = auto_exposure(
            gt.points[v], gt.normals[v], leds, albedo, scene.noise.exposure, tricolor=tricolor
        )
    return _exposure_cache[key]


def tricolor_linear(images: np.ndarray) -> np.ndarray:
    """Tri-colour image from single-LED images: sum_k colour_k * image_k.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear

    Returns
    -------
    (H, W, 3) float64, linear
    """
    colours = TRICOLOR_COLORS[tricolor_groups(len(images))]  # (L, 3)
    return np.einsum("lhwc,lc->hwc", images, colours, dtype=np.float64)


def press_seed(scene_seed: int, press_dict: dict | None) -> int:
    """Deterministic seed of one press: the scene's seed mixed with a digest of the press description.

    Two renders of the same press repeat exactly; two different presses (say a press and the
    undeformed reference it is compared with) get independent sensor noise, as real captures do.
    """
    digest = zlib.crc32(json.dumps(press_dict, sort_keys=True).encode())
    return int(np.random.SeedSequence([int(scene_seed), digest]).generate_state(1)[0])


def render_spec_hash(scene, press=None, seed=None) -> str:
    """Hash of everything that determines a render (scene, press, seed; not the thread count).

    Stored as ``provenance.spec_hash`` so re-runs can tell a matching press folder from a stale one.
    """
    from ..config import to_mapping

    press_dict = None if press is None else to_mapping(press)
    seed = press_seed(scene.render.seed, press_dict) if seed is None else int(seed)
    return _spec_digest(scene.to_dict(), press_dict, seed)


def recorded_spec_hash(provenance: dict) -> str | None:
    """The spec hash of a rendered press: recorded, or recomputed from older folders' provenance."""
    if provenance.get("spec_hash"):
        return provenance["spec_hash"]
    try:
        return _spec_digest(provenance["scene"], provenance["press"], int(provenance["seed"]))
    except (KeyError, TypeError, ValueError):
        return None


def _spec_digest(scene_dict: dict, press_dict: dict | None, seed: int) -> str:
    from ..config import digest

    data = dict(scene_dict)
    data["render"] = {k: v for k, v in data["render"].items() if k != "threads"}
    return digest({"scene": data, "press": press_dict, "seed": seed})


def render_press(scene, press=None, out_folder=None, seed=None, overwrite=False, return_result=False):
    """Render one press (or the undeformed dome when ``press`` is None) into a press folder.

    Parameters
    ----------
    scene : SceneConfig
    press : PressConfig or None
    out_folder : path of the press folder to write
    seed : render and noise seed (default: derived from ``scene.render.seed`` and the press, so
        different presses -- and the undeformed dome -- never share a noise realisation)
    overwrite : replace an existing folder
    return_result : also return the noise-free RenderResult (for tests)

    Returns
    -------
    Path of the folder, or (Path, RenderResult) with ``return_result``
    """
    from .render.surface import render_surface

    if out_folder is None:
        raise ConfigError("render_press needs out_folder")
    mesh, contact, press_dict = _surface(scene, press)
    seed = press_seed(scene.render.seed, press_dict) if seed is None else int(seed)
    ref_mesh, ref_gt = reference_ground_truth(scene)
    exposure, tri_exposure = scene_exposure(scene), scene_exposure(scene, tricolor=True)
    result = render_surface(scene, mesh, contact, seed=seed)
    rng = np.random.default_rng(seed)
    cfg = scene.noise
    dark = dark_frame(scene.camera_model().shape, cfg, rng)
    leds = apply_noise(result.images, exposure, cfg, rng)
    tri = apply_noise(tricolor_linear(result.images), tri_exposure, cfg, rng)
    provenance = {
        "source": "sim",
        "spec_hash": render_spec_hash(scene, press, seed),
        "scene": scene.to_dict(),
        "press": press_dict,
        "seed": seed,
        "variant": result.variant,
        "spp": result.spp,
        "bounces": result.bounces,
        "exposure": exposure,
        "tricolor_exposure": tri_exposure,
        "exposure_note": "Press.linear(led image) = exposure * albedo/pi * led_shading (+ interreflections); "
        "Press.linear(tricolor) = tricolor_exposure * sum_k colour_k * (albedo/pi * led_shading_k)",
        "render_seconds": round(result.seconds, 4),
    }
    path = write_press(
        out_folder,
        scene.camera_model(),
        scene.led_models(),
        cfg.response(),
        dark,
        leds,
        tri,
        provenance=provenance,
        reference=reference_from(ref_gt),
        ground_truth=result.gt,
        overwrite=overwrite,
    )
    return (path, result) if return_result else path


def _surface(scene, press):
    if press is None:
        mesh, _ = reference_ground_truth(scene)
        return mesh, np.zeros(len(mesh.vertices), dtype=bool), None
    from ..config import to_mapping
    from .indent import apply_press

    gel = apply_press(scene.dome, press)
    return gel.mesh, np.asarray(gel.contact, dtype=bool), to_mapping(press)
