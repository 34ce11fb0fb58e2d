"""The emulated sensor: the virtual LED board plus a virtual camera that shows what the twin renders.

This is the one module besides cli/ that imports both sim/ and device/: it lets the whole hardware path
(``nlips capture``: LED protocol, camera flushing, sessions, movement checks) run without hardware.

How a frame is made: each scripted surface (the undeformed dome, each press, a press after it moved)
is rendered once with every LED in its own channel (``sim.render.surface.render_surface``) and seen through
the scene's lens (``sim.camera_effects.apply_lens``: defocus, vignetting), as the twin's own captures are. A frame
is the sum of those images weighted by the colours the LED board has latched right now (``latched / 255``
per channel), scaled by the scene's exposure and passed through the scene's sensor noise model and response
(``sim.noise.apply_noise``, as ``sim.press.camera_capture``; its black level the stated one), with a fresh noise
draw per frame, as a real sensor gives.

Like a real UVC camera, the virtual camera delivers frames with a delay (``latency_frames``): a frame
read right after an LED change still shows the old light, so a session that does not flush fails; a stream's
scripted presses are put in front of it in its own time (:class:`ScriptedStream`), so each shows in its own frames.
Like a webcam that cannot turn its gamma off, it may encode its frames with a tone curve
(:data:`EMULATED_TONE_CURVES`), and its exposure may be stepped (:attr:`EmulatedCamera.exposure_scale`:
``nlips calibrate-camera-response``'s bracket).
"""

from __future__ import annotations

import collections
import dataclasses
import logging
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .core.config import from_mapping, read_config_file, to_mapping
from .core.dome import reference_surface
from .core.errors import ConfigError
from .core.press_meta import EMULATOR_DEVICE
from .core.sensor_response import SensorResponse, linear_to_srgb
from .device.camera import FrameSource
from .device.session import Operator, Rig
from .sim.bayer import apply_crosstalk, bayer_camera
from .sim.camera_effects import apply_lens
from .sim.indent import PressConfig, apply_press
from .sim.noise import apply_noise
from .sim.press import press_seed, render_identity, scene_exposure, undeformed_mesh
from .sim.scene import CameraEffectsConfig, SceneConfig

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class ScriptedPress:
    """One press of the emulated session."""

    press: PressConfig
    """What the operator presses and where."""
    moved: PressConfig | None = None
    """Where the object ends up if it moves during the LED sequence (None: it holds still)."""
    move_after_frames: int = 5
    """Frames read after the press prompt before the object moves (retakes then see ``moved``)."""


def default_script(n_presses: int, move_press: int | None = None) -> list[ScriptedPress]:
    """Sphere presses around the dome, 1.2 mm deep at 15 deg from the apex; press ``move_press`` (1-based)
    slides 1 mm deeper halfway through its sequence."""
    presses = []
    for k in range(1, n_presses + 1):
        press = PressConfig(polar_deg=15.0, azimuth_deg=(k - 1) * 360.0 / max(n_presses, 1) + 30.0, depth=1.2)
        moved = dataclasses.replace(press, depth=2.2) if k == move_press else None
        presses.append(ScriptedPress(press, moved))
    return presses


def load_script(path: str | Path) -> list[ScriptedPress]:
    """A press script file (TOML/YAML): ``[[press]]`` tables of PressConfig fields, each optionally with a
    ``moved`` table (the pose after it moves) and ``move_after_frames``."""
    data = read_config_file(path)
    entries = data.get("press")
    if not isinstance(entries, list) or not entries:
        raise ConfigError(f"{path}: a press script needs one or more [[press]] tables")
    script = []
    for k, entry in enumerate(entries, 1):
        entry = dict(entry)
        moved = entry.pop("moved", None)
        after = entry.pop("move_after_frames", 5)
        press = _press_config(entry, f"{path}: press {k}")
        moved_cfg = _press_config(to_mapping(press) | moved, f"{path}: press {k} moved") if moved else None
        script.append(ScriptedPress(press, moved_cfg, int(after)))
    return script


def _press_config(data: dict, where: str) -> PressConfig:
    if isinstance(data.get("indenter"), str):
        data = data | {"indenter": {"kind": data["indenter"]}}
    return from_mapping(PressConfig, data, where)


class TwinRenders:
    """Per-LED linear images of the scripted surfaces, rendered once each and kept."""

    def __init__(self, scene: SceneConfig):
        self.scene = scene
        self.cache: dict = {}
        self.exposure = scene_exposure(scene)

    def images(self, press: PressConfig | None) -> np.ndarray:
        """(L, H, W, 3) float32 linear radiance of ``press`` (None: the undeformed dome), one image per LED."""
        from .sim.render.surface import render_surface

        key = None if press is None else repr(to_mapping(press))
        if key not in self.cache:
            if press is None:
                mesh, contact, press_dict = undeformed_mesh(self.scene.dome), None, None
            else:
                gel = apply_press(self.scene.dome, press)
                mesh, contact, press_dict = gel.mesh, np.asarray(gel.contact, bool), to_mapping(press)
            # the twin's own seed for this press: the same render a direct `nlips render` would make
            seed = press_seed(self.scene.render.seed, press_dict)
            images = render_surface(self.scene, mesh, contact, seed=seed).images
            # through the lens as the twin's captures (sim.press.camera_capture): linear in the light, so it commutes
            # with the LED weighting of each frame and is applied once per surface. Without it the emulated frames
            # lacked the scene's defocus and vignetting the twin's renders of the same presses have
            self.cache[key] = apply_lens(images, self.scene.camera_model(), self.scene.camera_effects)
        return self.cache[key]


def _gamma22(x: np.ndarray) -> np.ndarray:
    return np.power(x, np.float32(1 / 2.2))


def _vendor_s_curve(x: np.ndarray) -> np.ndarray:
    # a webcam's "contrast" look: gamma 2.2 blended half and half with a smoothstep of it (steeper mid-tones,
    # flatter ends); monotonic, 0 -> 0 and 1 -> 1
    g = np.power(x, np.float32(1 / 2.2))
    return np.float32(0.5) * g * g * (np.float32(3) - np.float32(2) * g) + np.float32(0.5) * g


RGB_GAMMAS = (2.0, 2.2, 2.4)
"""The gammas of the emulated camera whose channels differ (``rgb-gammas``): R, G, B."""


def _rgb_gammas(x: np.ndarray) -> np.ndarray:
    # a webcam whose red, green and blue respond differently: a gamma per channel (the last axis, R, G, B)
    return np.power(x, np.float32(1) / np.asarray(RGB_GAMMAS, np.float32))


EMULATED_TONE_CURVES: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "gamma2.2": _gamma22,
    "s-curve": _vendor_s_curve,
    "srgb": linear_to_srgb,
    "rgb-gammas": _rgb_gammas,
}
"""Tone curves the emulated camera may encode its frames with (``--emulate-tone-curve``): linear light in [0, 1]
(fraction of full scale above black) -> encoded fraction, as a webcam's image processor applies it before its
frames are quantised ("rgb-gammas" takes (..., 3) arrays, R, G, B: a gamma per channel). None of them is declared
to the tools: a capture of them is measured (``nlips calibrate-camera-response --emulate``) or declared ("srgb")."""


def check_tone_curve(name: str | None) -> None:
    """ConfigError naming ``name`` when it is not None nor one of :data:`EMULATED_TONE_CURVES`."""
    if name is not None and name not in EMULATED_TONE_CURVES:
        raise ConfigError(f"--emulate-tone-curve {name}: not one of {', '.join(EMULATED_TONE_CURVES)}")


def encode_frame(
    stored: np.ndarray, bit_depth: int, black_dn: float, curve: Callable[[np.ndarray], np.ndarray]
) -> np.ndarray:
    """A linear camera's stored frame encoded by ``curve`` (:data:`EMULATED_TONE_CURVES`) between its black level
    and full scale, and quantised again to the camera's ``bit_depth``: what a camera applying that curve stores.

    Parameters
    ----------
    stored : (H, W, 3) uint16, stored values ``DN << (16 - bit_depth)``, linear in the light
    bit_depth : int, bits of the camera's values
    black_dn : float, the black level in the camera's DN (zero light; kept there)

    Returns
    -------
    (H, W, 3) uint16, stored values, encoded
    """
    shift = np.uint16(16 - bit_depth)
    top = np.float32((1 << bit_depth) - 1)
    dn = (stored >> shift).astype(np.float32)
    x = np.clip((dn - np.float32(black_dn)) / (top - np.float32(black_dn)), 0, 1)
    encoded = curve(x) * (top - np.float32(black_dn)) + np.float32(black_dn)
    # the noise below black stays (a curve is applied above black): its values pass unchanged
    encoded = np.where(dn < black_dn, dn, encoded)
    return np.clip(np.rint(encoded), 0, top).astype(np.uint16) << shift


class EmulatedCamera(FrameSource):
    """A camera looking at the twin, lit by whatever the LED board latched.

    Parameters
    ----------
    renders : TwinRenders
    latched : callable returning the board's latched colours, (L, 3) uint8
    seed : noise seed of the frame sequence (of each press's frames: :meth:`show` with its ``index``)
    latency_frames : frames between exposure and delivery (a real camera's buffer)
    flush_frames, average : as :class:`nlipscalib.device.camera.CameraSettings`
    tone_curve : name in :data:`EMULATED_TONE_CURVES` the frames are encoded with, or None (linear frames)
    """

    def __init__(
        self,
        renders: TwinRenders,
        latched: Callable[[], np.ndarray],
        seed: int = 0,
        latency_frames: int = 1,
        flush_frames: int = 2,
        average: int = 1,
        tone_curve: str | None = None,
    ) -> None:
        check_tone_curve(tone_curve)
        self.encoding = tone_curve
        self.exposure_scale = 1.0
        """Exposure relative to the scene's (``nlips calibrate-camera-response --emulate``: its exposure in ms over
        the emulated camera's 10 ms); 1.0 for every capture."""
        self.renders = renders
        self.latched = latched
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.latency_frames = int(latency_frames)
        self.flush_frames = int(flush_frames)
        self.average = int(average)
        self.bit_depth = renders.scene.noise.bit_depth
        self.surface: PressConfig | None = None
        self.pending: tuple[int, PressConfig] | None = None
        self.frames_read = 0
        self.press_index: int | None = None
        """The session's press shown (:meth:`show`'s ``index``; None: a stream, whose frames share one noise stream)."""
        self.press_frames = 0
        """Frames read since the press ``press_index`` was shown: with it and the seed, each frame's noise draw."""
        self.pipeline: collections.deque = collections.deque()

    @property
    def shape(self) -> tuple[int, int]:
        return self.renders.scene.camera_model().shape

    def show(
        self, surface: PressConfig | None, moves_to: PressConfig | None = None, after: int = 0, index: int | None = None
    ) -> None:
        """The gel now looks like ``surface``; if ``moves_to``, it changes to that after ``after`` more frames.

        ``index``: the session's press number (0: the reference). Each of its frames' noise is then drawn from the
        seed, that number and the frame's place since the press was shown alone, not from the frames read before:
        a session resumed in a new process (after a kill) captures each press as one uninterrupted run does, where a
        single stream gave every press after the resume other noise. Per frame, not per press: the frames flushed
        after the press differ between the two runs (an uninterrupted run's camera still delivers the press before,
        a new process's the press itself), and a shared stream's draws hang on what a frame shows (dim pixels draw
        Poisson noise, bright ones normal), so the first press after a resume still came out other."""
        if index is not None:
            self.press_index, self.press_frames = index, 0
        self.surface = surface
        self.pending = (self.frames_read + after, moves_to) if moves_to is not None else None

    def read(self) -> np.ndarray:
        if self.pending is not None and self.frames_read >= self.pending[0]:
            self.surface, self.pending = self.pending[1], None
        self.frames_read += 1
        colors = np.asarray(self.latched(), dtype=np.float32) / np.float32(255)
        self.pipeline.append((self.surface, colors))
        while len(self.pipeline) > self.latency_frames + 1:
            self.pipeline.popleft()
        surface, colors = self.pipeline[0]  # the oldest frame in the pipeline is delivered
        images = self.renders.images(surface)
        lit = np.flatnonzero(colors.any(axis=1))  # most frames light one LED or none: skip the dark ones
        linear = np.einsum("lhwc,lc->hwc", images[lit], colors[lit], dtype=np.float32)
        scene, effects = self.renders.scene, self._effects()
        linear = apply_crosstalk(linear, effects.crosstalk)  # of the LEDs' colours mixed: the filters see the sum
        stored = apply_noise(
            linear, self.renders.exposure * self.exposure_scale, scene.noise, self._frame_rng(), effects
        )
        if effects.bayer != "none":  # as the twin's captures (sim.press.camera_capture)
            stored = bayer_camera(stored, effects.bayer, effects.demosaic)
        noise = scene.noise
        if self.encoding is None:
            return stored
        return encode_frame(stored, noise.bit_depth, noise.black_level, EMULATED_TONE_CURVES[self.encoding])

    def _effects(self) -> CameraEffectsConfig:
        """The scene's camera effects on the stored values (its response), as in the twin's captures, but its black
        level exactly the one the session states (``black_level_error`` 0).

        Why not the twin's error too: it is a stated level off from the true one, which the device path's own
        ``--black-level`` stands for; under a tone curve (``--emulate-tone-curve gamma2.2``) its 3 DN became 10 codes
        of 255 and ``nlips calibrate-camera-response --emulate`` refused the emulated camera as one adding a black
        level. The dark frame subtracts it either way."""
        return dataclasses.replace(self.renders.scene.camera_effects, black_level_error=0.0)

    def _frame_rng(self) -> np.random.Generator:
        """The noise generator of the frame being read: its own, from the seed, the press and its place in the
        press (:meth:`show`), or the stream's one (no press shown)."""
        if self.press_index is None:
            return self.rng
        self.press_frames += 1
        return np.random.default_rng((self.seed, self.press_index, self.press_frames - 1))


class ScriptedOperator(Operator):
    """The emulated person: presses what the script says when the session asks for a press."""

    def __init__(
        self, camera: EmulatedCamera, script: list[ScriptedPress], echo: Callable[[str], None] = print
    ) -> None:
        super().__init__(interactive=False, echo=echo)
        self.camera = camera
        self.script = script

    def reference(self) -> None:
        super().reference()
        self.camera.show(None, index=0)

    def press(self, index: int, total: int) -> None:
        super().press(index, total)
        step = self._step(index)
        self.camera.show(step.press, step.moved, step.move_after_frames, index=index)

    def retake(self, index: int, reason: str) -> None:
        super().retake(index, reason)
        step = self._step(index)
        # the object settled where it moved to, and now holds still
        self.camera.show(step.moved or step.press)

    def _step(self, index: int) -> ScriptedPress:
        if not 1 <= index <= len(self.script):
            raise ConfigError(f"the press script has {len(self.script)} presses; press {index} was asked for")
        return self.script[index - 1]


class ScriptedStream:
    """The emulated stream's person (``nlips live/infer --emulate``): each surface in front of the camera for
    ``frames_per_press`` frames, in the frames the stream reads, the first press's first frame included.

    Why ahead of the reads: the camera delivers each frame :attr:`EmulatedCamera.latency_frames` reads after it was
    exposed (a UVC camera's buffer, modelled on purpose: a capture session that does not flush after an LED change
    fails). Changing the gel right before each read, as the stream did, showed every press first in the frame after
    its first (``--frames-per-press 1``: each frame the press before, the last press never). A real person presses
    in the camera's time, not the reads': here each surface is put in front of the camera as the frame that will
    be delivered as its frame is exposed, and the camera is run that many frames before the stream (a real camera
    streams from its opening: its first frame delivered was exposed before the stream's first read). Nothing is to
    flush on the stream's side: the tri-colour LEDs never change during it, and a real camera's frames of a moving
    press are late by its latency whatever the consumer does (fewer buffers: ``CameraSettings.buffer_size``).

    Parameters
    ----------
    camera : the emulated camera, its LEDs lit already
    surfaces : what the gel shows, in order (None: the undeformed dome)
    frames_per_press : frames each surface is shown for
    loop : start again after the last surface (a window shows the stream); else the stream ends after it
        (:class:`~nlipscalib.device.live.StopLive` from the call of the frame past it), as a recording does
    """

    def __init__(
        self, camera: EmulatedCamera, surfaces: list[PressConfig | None], frames_per_press: int, loop: bool
    ) -> None:
        self.camera, self.surfaces, self.frames_per_press, self.loop = camera, surfaces, frames_per_press, loop
        self.frames = len(surfaces) * frames_per_press
        """Frames of the script once."""
        for exposed in range(camera.latency_frames):  # the frames exposed before the stream's first read
            camera.show(self._surface(exposed))
            camera.read()

    def _surface(self, exposed: int) -> PressConfig | None:
        """The surface in front of the camera at its read ``exposed`` (counted from the warm-up's first): the one
        the stream's frame ``exposed`` shows, delivered ``latency_frames`` reads later (the last surface held past
        the script's end, as a person holds a press until the recording stops)."""
        if not self.loop:
            exposed = min(exposed, self.frames - 1)
        return self.surfaces[(exposed // self.frames_per_press) % len(self.surfaces)]

    def __call__(self, frame: int) -> None:
        """Before the stream reads its frame ``frame`` (``device.live.stream``'s ``before_frame``)."""
        from .device.live import StopLive

        if not self.loop and frame >= self.frames:
            raise StopLive  # the script was streamed once: the input ended
        # the frame read now delivers the exposure latency_frames reads ago; the one exposed now is delivered then
        self.camera.show(self._surface(frame + self.camera.latency_frames))


def tricolor_level(renders: TwinRenders) -> int:
    """LED drive of the tri-colour frame giving it the twin's tri-colour exposure at the single-LED exposure."""
    ratio = scene_exposure(renders.scene, tricolor=True) / renders.exposure
    return int(np.clip(round(255 * ratio), 1, 255))


@dataclasses.dataclass
class EmulatedSensor:
    """An emulated sensor ready for a session: the rig, its scripted operator, and what to close."""

    rig: Rig
    operator: ScriptedOperator
    camera: EmulatedCamera
    board: object
    tricolor_level: int

    def prerender(self, progress: bool = False) -> None:
        """Render every scripted surface now (the undeformed dome, each press, each moved pose), so that
        capture times measure the hardware path, not the renderer."""
        from .progress import track

        surfaces = [None] + [s for step in self.operator.script for s in (step.press, step.moved) if s is not None]
        for surface in track(surfaces, enabled=progress, desc="rendering the twin", unit="surface"):
            self.camera.renders.images(surface)

    def close(self) -> None:
        self.rig.controller.close()
        close = getattr(self.board, "close", None)
        if close is not None:
            close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def open_emulated_sensor(
    scene: SceneConfig,
    script: list[ScriptedPress],
    *,
    seed: int = 0,
    latency_frames: int = 1,
    flush_frames: int = 2,
    echo: Callable[[str], None] = print,
    board_id: str | None = None,
    tone_curve: str | None = None,
    response: SensorResponse | None = None,
) -> EmulatedSensor:
    """The virtual LED board (opened through the real host driver) and the virtual camera for ``scene``.

    ``board_id`` names the board's URL (``nlipsemu://<board_id>``; default: the next free number), for a
    command given ``--port nlipsemu://<id>``. ``tone_curve``: the curve the camera encodes with
    (:data:`EMULATED_TONE_CURVES`; None: linear frames); ``response``: the sensor response its captures declare
    (default the scene's, linear: a curve declared, ``--camera-response``, replaces it).
    """
    from .device.controller import LedController
    from .device.virtual_board import VirtualBoard

    check_tone_curve(tone_curve)  # before the board: nothing to close on a bad name
    board = VirtualBoard(len(scene.led_models()), board_id=board_id)
    try:
        controller = LedController.open(board.url)
    except BaseException:
        board.close()
        raise

    def latched():
        return board.latched

    renders = TwinRenders(scene)
    camera = EmulatedCamera(
        renders, latched, seed=seed, latency_frames=latency_frames, flush_frames=flush_frames, tone_curve=tone_curve
    )
    rig = Rig(
        controller=controller,
        source=camera,
        camera=scene.camera_model(),
        leds=scene.led_models(),
        response=response or scene.noise.response(),
        reference=reference_surface(scene.design),
        # the twin code and render libraries (as a rendered press records them): a session resumed after an
        # upgrade tells its earlier presses from this run's (device.session.made_otherwise_line)
        provenance={
            "device": EMULATOR_DEVICE,
            "scene": scene.to_dict(),
            "exposure": renders.exposure,
            **render_identity(),
        }
        | ({"tone_curve": tone_curve} if tone_curve else {}),
    )
    return EmulatedSensor(rig, ScriptedOperator(camera, script, echo), camera, board, tricolor_level(renders))
