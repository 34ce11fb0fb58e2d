"""Rendering any gel surface mesh with a scene's camera, LEDs and coating."""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import re
import time
from collections.abc import Iterator
from typing import TYPE_CHECKING

import numpy as np

from ...core import atomic
from ...core.surface_files import GroundTruth
from .denoise import denoise_indirect
from .groundtruth import trace_ground_truth
from .interruptible import call_interruptibly
from .mesh import albedo_per_vertex
from .scene import build_scene
from .variant import load_mitsuba

log = logging.getLogger(__name__)

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    from types import ModuleType

    import mitsuba
    import trimesh

    from ..scene import SceneConfig


@dataclasses.dataclass(frozen=True)
class RenderResult:
    """Linear, noise-free images of one surface and its ground truth."""

    images: np.ndarray | None
    """(L, H, W, 3) float32, one image per LED lit alone in white. Units: linear radiance,
    i.e. albedo/pi * led_shading (Psi (n_s.d)^mu cos / r^2), before exposure and noise.
    None when only the ground truth was asked for."""
    gt: GroundTruth
    """Pixel-centre ground truth, camera frame, mm."""
    variant: str
    spp: int
    bounces: int
    seed: int
    seconds: float
    """Wall time of scene build + render + ground truth."""
    coverage: np.ndarray | None = None
    """(H, W) float32 in [0, 1]: the share of each pixel's samples whose camera ray meets the gel (the film's
    alpha; through a refracting gel, its inner surface); below 1 on the gel's outline in a view beyond it (and,
    rarely, inside where a sample slips between the mesh's triangles). None when only the ground truth was asked
    for."""


def render_surface(
    scene_cfg: SceneConfig,
    mesh: trimesh.Trimesh,
    contact_per_vertex: np.ndarray | None = None,
    *,
    spp: int | None = None,
    bounces: int | None = None,
    variant: str | None = None,
    threads: int | None = None,
    seed: int | None = None,
    integrator: str = "multi",
    only_led: int | None = None,
    images: bool = True,
) -> RenderResult:
    """Render every LED's image of ``mesh`` in one pass, plus the ground truth.

    The one render path of the twin: presses and the undeformed dome (``images=False`` for its ground
    truth alone) both come through here.

    Parameters
    ----------
    scene_cfg : SceneConfig -- camera, LEDs, coating and default render settings
    mesh : trimesh.Trimesh, dome frame, mm, faces wound toward the camera
    contact_per_vertex : (V,) bool/float or None (no contact)
    spp, bounces, variant, threads, seed : override ``scene_cfg.render``
    integrator : "multi" (default) or "path" (Mitsuba's path tracer; then ``only_led`` picks the LED
        and ``images`` holds that single image, shape (1, H, W, 3))
    images : False: trace the ground truth only (no radiance render)
    """
    r = scene_cfg.render
    spp = r.spp if spp is None else int(spp)
    bounces = r.bounces if bounces is None else int(bounces)
    seed = r.seed if seed is None else int(seed)
    mi, chosen = load_mitsuba(variant or r.variant, r.threads if threads is None else threads)
    t0 = time.perf_counter()
    work = functools.partial(
        _render_and_trace, mi, scene_cfg, mesh, contact_per_vertex, spp, bounces, seed, integrator, only_led, images
    )
    # off the main thread: a render holds the thread that calls it for tens of seconds, and Ctrl-C or SIGTERM is
    # handled by the main thread alone (see .interruptible). Mitsuba's log is redirected here, in the main thread,
    # so that an interrupted render leaves no log file behind (the abandoned thread would never remove it).
    with _warnings_relayed(mi):
        stack, gt, coverage = call_interruptibly(work)
    return RenderResult(stack, gt, chosen, spp, bounces, seed, time.perf_counter() - t0, coverage)


def _render_and_trace(
    mi: ModuleType,
    scene_cfg: SceneConfig,
    mesh: trimesh.Trimesh,
    contact_per_vertex: np.ndarray | None,
    spp: int,
    bounces: int,
    seed: int,
    integrator: str,
    only_led: int | None,
    images: bool,
) -> tuple[np.ndarray | None, GroundTruth, np.ndarray | None]:
    """:func:`render_surface`'s work once Mitsuba is loaded: the scene built, the images and their coverage
    rendered (``images``; else None, None) and the ground truth traced. Writes nothing (it may be abandoned,
    :func:`call_interruptibly`)."""
    r = scene_cfg.render
    # the bounce light comes in AOVs of its own to be denoised (RenderConfig.denoise_indirect)
    split = r.denoise_indirect and bounces > 0 and integrator == "multi"
    camera = scene_cfg.camera_model()
    leds = scene_cfg.led_models()
    verts_dome = np.asarray(mesh.vertices, dtype=np.float64)
    verts = verts_dome - np.asarray(scene_cfg.camera.position, dtype=np.float64)
    contact = np.zeros(len(verts)) if contact_per_vertex is None else np.asarray(contact_per_vertex, np.float32)
    c, pkg = scene_cfg.coating, scene_cfg.led_package
    colors = albedo_per_vertex(verts_dome, c.albedo, c.variation, c.variation_scale) if c.variation > 0 else None
    scene = build_scene(
        mi,
        camera,
        leds,
        verts,
        mesh.faces,
        mesh.vertex_normals,
        contact,
        colors,
        c.albedo,
        spp=spp,
        bounces=bounces,
        integrator=integrator,
        only_led=only_led,
        led_shape=pkg.shape if pkg.enabled else "point",
        led_size=pkg.size if pkg.enabled else 0.0,
        specular=c.specular,
        roughness=c.roughness,
        interface=_interface(scene_cfg),
        split_bounces=split,
    )
    stack, coverage = _render_images(mi, scene, camera.shape, spp, seed, integrator) if images else (None, None)
    optics = scene_cfg.gel_optics
    gt = trace_ground_truth(mi, scene, camera, optics.gel_ior / optics.housing_ior if optics.enabled else None)
    if split and stack is not None:  # the direct light, then every LED's bounce light filtered along the surface
        n = len(stack) // 2
        stack = stack[:n] + denoise_indirect(stack[n:], gt.normals, gt.depth, gt.valid, r.denoise, coverage)
    return stack, gt, coverage


def _render_images(
    mi: ModuleType, scene: mitsuba.Scene, shape: tuple[int, int], spp: int, seed: int, integrator: str
) -> tuple[np.ndarray, np.ndarray]:
    """(L, H, W, 3) float32 linear images (one per LED from the AOVs, or the path tracer's one image) and the
    (H, W) float32 coverage of each pixel by the gel (the film's alpha: the share of its samples that reach it)."""
    out = np.array(mi.render(scene, spp=spp, seed=seed), dtype=np.float32)
    h, w = shape
    coverage = np.ascontiguousarray(out[..., 3])  # the film is R, G, B, A, then the AOVs (scene.sensor_entry)
    if integrator == "multi":
        return np.ascontiguousarray(out[..., 4:].reshape(h, w, -1, 3).transpose(2, 0, 1, 3)), coverage
    return np.ascontiguousarray(out[None, ..., :3]), coverage


MITSUBA_INTERRUPT_NOTICE = "Received interrupt signal, winding down"
"""The warning Mitsuba's own Ctrl-C handler logs as it cancels a render; ``nlips`` says its one line instead."""
_MITSUBA_LINE = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d (?:TRACE|DEBUG|INFO|WARN|ERROR)\s+(?:\[[^]]*\]\s*)?(.*)$")
"""The start of a message in Mitsuba's log (DefaultFormatter: date, time, level, ``[file:line] text``): its text
is kept, without the source location (one warning from two places is one to the user)."""
_RELAYED: set[str] = set()
"""Mitsuba's render warnings this process has logged (each is logged once, not once a press)."""


@contextlib.contextmanager
def _warnings_relayed(mi: ModuleType) -> Iterator[None]:
    """Mitsuba's warnings of a render (the scene's build, the images, the ground truth) logged as ours
    (``log.warning``), each once per process, after it.

    Mitsuba puts a Ctrl-C handler of its own in place around a render (``Integrator.render``'s binding): it
    cancels the render, hands the signal on to Python (``nlips`` then prints its one line "interrupted; ...",
    exit 130), and first logs :data:`MITSUBA_INTERRUPT_NOTICE` as a warning, in ANSI colours on stdout (even
    into a file). Python cannot filter it there (it would run inside a C signal handler), so while Mitsuba
    renders its log goes to a file, by its own C++ appender, and is read once the render has ended: the
    notice dropped, every other warning logged -- they used to be held back with it (the log level raised to
    errors). Errors are raised as exceptions, not logged. Mitsuba's logger is the process's, so the render may run
    on another thread (:func:`call_interruptibly`) while this runs in the caller's.
    """
    logger = mi.logger() if hasattr(mi, "logger") else mi.Thread.thread().logger()
    if logger is None:
        yield
        return
    shown = [logger.appender(i) for i in range(logger.appender_count())]
    # a scratch folder of core.atomic, not a TemporaryDirectory: SIGTERM's handler removes it before os._exit, and
    # a killed render's is removed by the next render
    with atomic.system_scratch_dir("nlips-mitsuba-log") as folder:
        path = folder / "render.log"
        logger.clear_appenders()
        logger.add_appender(mi.StreamAppender(str(path)))
        try:
            yield
        finally:
            logger.clear_appenders()  # the file's appender goes (closing the file), stdout's comes back
            for appender in shown:
                logger.add_appender(appender)
            _relay(path.read_text(errors="replace", encoding="utf-8") if path.exists() else "")


def _relay(text: str) -> None:
    """Log each warning of Mitsuba's log ``text`` not logged before, but the interrupt notice."""
    messages: list[str] = []
    for line in text.splitlines():
        start = _MITSUBA_LINE.match(line)
        if start is not None:
            messages.append(start.group(1).strip())
        elif messages and line.strip():  # a message of several lines
            messages[-1] += "\n" + line.rstrip()
    for message in messages:
        if MITSUBA_INTERRUPT_NOTICE not in message and message not in _RELAYED:
            _RELAYED.add(message)
            log.warning("Mitsuba: %s", message)


def _interface(scene_cfg: SceneConfig):
    """(vertices camera frame, faces, gel_ior, housing_ior) of the refracting inner surface, or None."""
    optics = scene_cfg.gel_optics
    if not optics.enabled:
        return None
    from ..dome import inner_surface

    inner = inner_surface(scene_cfg.dome)
    verts = np.asarray(inner.vertices, dtype=np.float64) - np.asarray(scene_cfg.camera.position, dtype=np.float64)
    return verts, np.asarray(inner.faces), optics.gel_ior, optics.housing_ior
