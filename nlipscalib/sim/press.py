"""Rendering one press of the digital twin into a press folder (the capture format of core/).

A press = dark frame + one white image per LED + the tri-colour image, each with its own sensor
noise, plus ground truth and the undeformed dome's Reference. :func:`render_press` reads as its
steps: the gel surface (undeformed dome or indented gel), the render (all LED images and the ground
truth through :func:`nlipscalib.sim.render.render_surface`, the one render path), the camera (lens
effects, exposure, sensor noise), and writing. Exposure is chosen once per scene
(:func:`scene_exposure`), so every press of a scene shares it and the solver can compare them.
"""

from __future__ import annotations

import dataclasses
import errno
import functools
import json
import logging
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.capture import write_press
from ..core.errors import PATH, ConfigError, check_flag, check_kind, check_whole
from ..core.leds import tricolor_colors
from ..core.press_folders import check_render_out, is_press_folder
from .bayer import IDENTITY_CROSSTALK, apply_crosstalk, bayer_camera
from .camera_effects import apply_lens
from .dome import make_dome
from .noise import apply_noise, auto_exposure, dark_frame
from .render.groundtruth import reference_from

if TYPE_CHECKING:  # names in hints only: the functions import the scene and render modules where they use them
    import trimesh

    from ..core.sensor import DomeConfig, LedConfig
    from ..core.surface_files import GroundTruth
    from .indent import PressConfig
    from .render.surface import RenderResult
    from .scene import SceneConfig

log = logging.getLogger(__name__)
CACHE_SIZE = 8
"""Scenes whose undeformed ground truth and exposures stay in memory (a dataset uses one scene)."""


def undeformed_mesh(dome_cfg: DomeConfig) -> trimesh.Trimesh:
    """The undeformed gel mesh (dome frame, mm, faces wound inward)."""
    return make_dome(dome_cfg)


def reference_ground_truth(scene: SceneConfig) -> GroundTruth:
    """Ground truth of the undeformed dome: the Reference every press carries and the exposure's source.

    Rendered through the same path as the presses (``render_surface`` without images) and cached per
    geometry (dome, camera, gel optics), so scenes that differ only in LEDs, coat or noise share it.

    Returns
    -------
    core GroundTruth (read-only: shared between callers)
    """
    return _reference_ground_truth(_geometry(scene))


def _geometry(scene: SceneConfig):
    """The scene reduced to what its ground truth depends on (a small, hashable cache key)."""
    from .scene import LedPackageConfig, RenderConfig, SceneConfig

    render = RenderConfig(variant=scene.render.variant, threads=scene.render.threads)
    return SceneConfig(
        dome=scene.dome,
        camera=scene.camera,
        render=render,
        led_package=scene.led_package if scene.gel_optics.enabled else LedPackageConfig(enabled=False),
        gel_optics=scene.gel_optics,
    )


@functools.lru_cache(maxsize=CACHE_SIZE)
def _reference_ground_truth(geometry: SceneConfig):
    from .render.surface import render_surface

    gt = render_surface(geometry, undeformed_mesh(geometry.dome), images=False).gt
    for field in dataclasses.fields(gt):
        value = getattr(gt, field.name)
        if isinstance(value, np.ndarray):
            value.setflags(write=False)
    return gt


def scene_exposure(scene: SceneConfig, tricolor: bool = False) -> float:
    """Scale from linear radiance to fraction of full scale for this scene (see ``noise.auto_exposure``).

    The tri-colour image (``tricolor=True``) gets its own, shorter exposure: each of its channels sums
    a third of the LEDs and would otherwise saturate. A camera's colour crosstalk (``camera_effects.crosstalk``)
    brightens its channels, and is exposed for as a user exposes the camera on its own frames.
    """
    mix = scene.camera_effects.crosstalk
    mix = None if mix == IDENTITY_CROSSTALK else mix  # none: the exposure to the bit as before crosstalk existed
    return _exposure(_geometry(scene), scene.leds, scene.coating.albedo, scene.noise.exposure, tricolor, mix)


@functools.lru_cache(maxsize=4 * CACHE_SIZE)
def _exposure(
    geometry: SceneConfig,
    leds_cfg: LedConfig,
    albedo: tuple[float, float, float],
    scale: float,
    tricolor: bool,
    crosstalk: tuple[tuple[float, ...], ...] | None = None,
) -> float:
    # ~1 s of numpy at 640x480: once per scene, not per press
    gt = _reference_ground_truth(geometry)
    v = gt.valid
    leds = dataclasses.replace(geometry, leds=leds_cfg).led_models()
    optics = geometry.gel_optics
    if optics.enabled:
        # a diffuse coat seen from a lower-index housing looks (n_housing / n_gel)^2 as bright (the rest is
        # totally internally reflected): a user would expose for it
        scale *= (optics.gel_ior / optics.housing_ior) ** 2
    return auto_exposure(gt.points[v], gt.normals[v], leds, albedo, scale, tricolor=tricolor, crosstalk=crosstalk)


def tricolor_linear(images: np.ndarray) -> np.ndarray:
    """Tri-colour image from single-LED images: sum_k colour_k * image_k.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear

    Returns
    -------
    (H, W, 3) float64, linear
    """
    colours = tricolor_colors(len(images))  # (L, 3)
    return np.einsum("lhwc,lc->hwc", images, colours, dtype=np.float64)


def press_seed(scene_seed: int, press_dict: dict | None) -> int:
    """Deterministic seed of one press: the scene's seed mixed with a digest of the press description.

    Two renders of the same press repeat exactly; two different presses (say a press and the
    undeformed reference it is compared with) get independent sensor noise, as real captures do.
    """
    digest = zlib.crc32(json.dumps(press_dict, sort_keys=True).encode())
    return int(np.random.SeedSequence([int(scene_seed), digest]).generate_state(1)[0])


def render_identity() -> dict:
    """What renders here: ``{"libraries": {mitsuba, drjit: version}, "code": digest of sim/ and core/}``
    (core.libraries.RENDER_LIBRARIES, core.code_version.RENDER_CODE), recorded in a rendered press's provenance."""
    from ..core.code_version import RENDER_CODE, subpackages_fingerprint
    from ..core.libraries import RENDER_LIBRARIES, library_versions

    return {"libraries": library_versions(RENDER_LIBRARIES), "code": subpackages_fingerprint(RENDER_CODE)}


def rendered_elsewhere(provenance: dict) -> bool:
    """Whether a rendered press's ``provenance`` names other render libraries or twin code than this installation's
    (:func:`render_identity`), or none (rendered before 2026-12-06): its images may differ from what a render here
    makes."""
    here = render_identity()
    return any(provenance.get(key) != value for key, value in here.items())


def render_spec_hash(scene: SceneConfig, press: PressConfig | None = None, seed: int | None = None) -> str:
    """Hash of everything that determines a render (scene, press, seed; not the thread count).

    Stored as ``provenance.spec_hash`` so re-runs can tell a matching press folder from a stale one. A user
    mesh indenter (``kind = "mesh"``) adds its file's content (:func:`mesh_file_digest`): the press names only
    the file's path, and an edited mesh must not reuse the press rendered from the old one. Every other
    press's hash is what it was before meshes were hashed, so existing datasets are not rendered again.
    """
    from ..core.config import to_mapping

    press_dict = None if press is None else to_mapping(press)
    seed = press_seed(scene.render.seed, press_dict) if seed is None else int(seed)
    return _spec_digest(scene.to_dict(), press_dict, seed, mesh_file_digest(press))


def mesh_file_digest(press: PressConfig | None) -> str | None:
    """SHA-256 (hex, first 16 digits) of the file of a press's mesh indenter; None for any other press.

    Parameters
    ----------
    press : PressConfig or None -- its ``indenter.mesh`` already resolved (beside the press file or spec)

    Returns
    -------
    str or None; None too when the file cannot be read (rendering it reports that, naming the file)
    """
    import hashlib
    from pathlib import Path

    if press is None or press.indenter.kind != "mesh" or not press.indenter.mesh:
        return None
    try:
        return hashlib.sha256(Path(press.indenter.mesh).expanduser().read_bytes()).hexdigest()[:16]
    except OSError:
        return None


def recorded_spec_hash(provenance: dict) -> str | None:
    """The spec hash of a rendered press: recorded, or recomputed from older folders' provenance.

    Older folders of mesh presses recorded no mesh content: their recomputed hash matches no current
    mesh press, so they are taken as stale (rendered again), never as matching an edited mesh.
    """
    if provenance.get("spec_hash"):
        return provenance["spec_hash"]
    try:
        return _spec_digest(provenance["scene"], provenance["press"], int(provenance["seed"]))
    except (KeyError, TypeError, ValueError):
        return None


def _spec_digest(scene_dict: dict, press_dict: dict | None, seed: int, mesh_digest: str | None = None) -> str:
    from ..core.config import digest

    spec = hashed_spec(scene_dict, press_dict, seed)
    if mesh_digest is not None:  # mesh presses only: no other press's hash changes
        spec["mesh_file"] = mesh_digest
    return digest(spec)


def hashed_spec(scene_dict: dict, press_dict: dict | None, seed: int) -> dict:
    """What a render's ``spec_hash`` is taken of (a mesh file's content aside): the scene as rendered (without
    ``render.threads`` and ``core.sensor.UNRENDERED_DESIGN_KEYS``), the press and the seed. Compared key by key, it
    says why a press folder is not of a spec (``sim.dataset_folder.spec_change``)."""
    from ..core.sensor import rendered_scene

    data = rendered_scene(scene_dict)
    data["render"] = {k: v for k, v in data["render"].items() if k != "threads"}
    return {"scene": data, "press": press_dict, "seed": seed}


def render_press(
    scene: SceneConfig,
    press: PressConfig | None = None,
    out_folder: str | Path | None = None,
    seed: int | None = None,
    overwrite: bool = False,
    return_result: bool = False,
) -> Path | tuple[Path, RenderResult]:
    """Render one press (or the undeformed dome when ``press`` is None) into a press folder.

    Parameters
    ----------
    scene : SceneConfig
    press : PressConfig or None
    out_folder : path of the press folder to write
    seed : render and noise seed (default: derived from ``scene.render.seed`` and the press, so
        different presses -- and the undeformed dome -- never share a noise realisation)
    overwrite : replace an existing press folder (a twin's; one captured on a sensor, a file or a folder of other
        things is a ConfigError, with or without it: :func:`nlipscalib.core.press_folders.check_render_out`)
    return_result : also return the noise-free RenderResult (for tests)

    Returns
    -------
    Path of the folder, or (Path, RenderResult) with ``return_result``

    Raises
    ------
    FileExistsError
        ``out_folder`` is a press folder already (another process's, published meanwhile, too) and not
        ``overwrite``
    """
    from .indent import PressConfig
    from .render.surface import render_surface
    from .scene import SceneConfig

    if out_folder is None:
        raise ConfigError("render_press needs out_folder")
    check_kind(scene, SceneConfig, "scene", "a SceneConfig (load_scene(...))")
    check_kind(press, (PressConfig, type(None)), "press", "a PressConfig, or None for the undeformed dome")
    check_kind(out_folder, PATH, "out_folder", "the press folder's path (str or Path)")
    if seed is not None:  # 1.5 failed inside Mitsuba (a SystemError), "1" rendered (s38-apikinds)
        check_whole(seed, "seed", minimum=0)
    check_flag(overwrite, "overwrite")
    check_flag(return_result, "return_result")
    check_render_out(out_folder, overwrite)  # before the render: a folder of other things is never replaced
    if not overwrite and is_press_folder(out_folder):  # said before the render, not after it (as atomic_dir would)
        raise FileExistsError(errno.EEXIST, "a press folder already: overwrite=True renders it again", str(out_folder))
    # hashed before the mesh file is read: a mesh edited during the render leaves a stale hash, rendered again
    spec_hash = render_spec_hash(scene, press, seed)
    # 1. the surface: the undeformed dome, or the gel under the press
    mesh, contact, press_dict = gel_surface(scene, press)
    seed = press_seed(scene.render.seed, press_dict) if seed is None else int(seed)
    # 2. the render: every LED's linear image and the ground truth, in one pass
    result = render_surface(scene, mesh, contact, seed=seed)
    if press is not None:
        _warn_if_unseen(out_folder, press, result.gt)
    # 3. the camera: lens, exposure, sensor noise
    dark, leds, tri, exposure, tri_exposure = camera_capture(scene, result.images, seed)
    # 4. writing the press folder
    provenance = {
        "source": "sim",
        "spec_hash": spec_hash,
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
        # the renderer's release moves the images (and so every result from them), as the twin's code does: said
        # by what made them, and compared before a rendered press is reused (rendered_elsewhere)
        **render_identity(),
    }
    path = write_press(
        out_folder,
        scene.camera_model(),
        scene.led_models(),
        scene.noise.response(),
        dark,
        leds,
        tri,
        provenance=provenance,
        reference=reference_from(reference_ground_truth(scene)),
        ground_truth=result.gt,
        overwrite=overwrite,
    )
    return (path, result) if return_result else path


def _warn_if_unseen(folder: str | Path, press: PressConfig, gt: GroundTruth) -> None:
    """One warning when no pixel shows the press's contact: the capture then looks like the undeformed gel.

    Why: a press beyond the camera's view (the default fisheye sees the hemisphere up to a polar angle of about
    60 deg in its corners) or too shallow to move the gel by ``CONTACT_MM`` renders without error, and a dataset of such
    presses teaches and scores nothing.
    """
    if np.any(gt.contact & gt.valid):
        return
    log.warning(
        "%s: no pixel shows the contact of this press (%s at polar %g deg, azimuth %g deg, depth %g mm): it lies "
        "outside the camera's view or is too shallow; the images show the undeformed gel",
        folder,
        press.indenter.kind,
        press.polar_deg,
        press.azimuth_deg,
        press.depth,
    )


def camera_capture(
    scene: SceneConfig, images: np.ndarray, seed: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """What the camera stores of linear LED images: dark frame, LED images, tri-colour image.

    The lens (defocus, vignetting), the filters' colour crosstalk (of the tri-colour frame's LED colours, and of
    each white LED image's), the sensor's noise and response, and, for a Bayer camera, its mosaic and demosaicing
    (:mod:`.bayer`), in that order.

    Parameters
    ----------
    scene : SceneConfig -- camera effects, noise model, exposure
    images : (L, H, W, 3) float32, linear radiance, one per LED
    seed : noise seed

    Returns
    -------
    dark : (H, W, 3) uint16 ; leds : (L, H, W, 3) uint16 ; tricolor : (H, W, 3) uint16 ;
    exposure, tricolor_exposure : float
    """
    exposure, tri_exposure = scene_exposure(scene), scene_exposure(scene, tricolor=True)
    effects, cfg = scene.camera_effects, scene.noise
    camera = scene.camera_model()
    seen = apply_lens(images, camera, effects)
    rng = np.random.default_rng(seed)
    dark = dark_frame(camera.shape, cfg, rng, effects)
    leds = apply_noise(apply_crosstalk(seen, effects.crosstalk), exposure, cfg, rng, effects)
    tri = apply_noise(apply_crosstalk(tricolor_linear(seen), effects.crosstalk), tri_exposure, cfg, rng, effects)
    if effects.bayer != "none":
        dark, leds, tri = (bayer_camera(frames, effects.bayer, effects.demosaic) for frames in (dark, leds, tri))
    return dark, leds, tri, exposure, tri_exposure


def gel_surface(scene: SceneConfig, press: PressConfig | None) -> tuple[trimesh.Trimesh, np.ndarray, dict | None]:
    """The gel's surface: (mesh, per-vertex contact (V,) bool, press description or None).

    The mesh is in the dome frame (mm), faces wound inward; the undeformed dome when ``press`` is None.
    """
    if press is None:
        mesh = undeformed_mesh(scene.dome)
        return mesh, np.zeros(len(mesh.vertices), dtype=bool), None
    from ..core.config import to_mapping
    from .indent import apply_press

    gel = apply_press(scene.dome, press)
    return gel.mesh, np.asarray(gel.contact, dtype=bool), to_mapping(press)
