"""The sensor's design: dome, camera and LED ring, shared by the twin (sim/) and the real sensor (device/).

Frames (docs/conventions.md): the **dome frame** has its origin at the centre of the dome's base
and +z along the dome's axis toward the apex; millimetres. The camera sits on the axis at
``camera.position`` looking along +z with its axes parallel to the dome's (OpenCV camera:
x right, y down, z forward), so ``p_camera = p_dome - camera.position``.

The undeformed surface computed from a design is :func:`nlipscalib.core.dome.reference_surface`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Literal

import numpy as np

from .camera import Camera
from .config import OMIT_AT_DEFAULT, check_count, check_range, from_mapping, read_config_file
from .errors import ConfigError, check_kind
from .leds import Led

MIN_IMAGE_SIDE, MAX_IMAGE_SIDE = 8, 16384
"""Image sides, pixels, the camera accepts."""
MAX_EMITTER_DIAMETER_MM = 20.0
"""Largest LED light-emitting diameter, mm, a design may declare (``leds.emitter_diameter``; the twin's
``[led_package] size`` has the same bound): an LED package, not a light panel."""


def shipped_scenes(package: Path) -> Path:
    """The folder of shipped scenes for the package folder ``package``: its ``scenes`` (a link to the repository's
    ``scenes/`` in a checkout, a copy in an install), or the repository's ``scenes/`` itself where that link is not a
    folder. Why: git on Windows without symbolic links (the default) checks the link out as a small text file
    holding ``../scenes``, and every scene name (``--scene nlipstac``) was then unknown."""
    linked = package / "scenes"
    checkout = package.parent / "scenes"
    return checkout if not linked.is_dir() and checkout.is_dir() else linked


SCENES_DIR = shipped_scenes(Path(__file__).resolve().parents[1])
"""The shipped scenes (nlipscalib/scenes links to the repository's scenes/; installs carry a copy): their ``dome``,
``camera`` and ``leds`` sections are the designs ``nlips capture --design NAME`` names."""
EXAMPLE_MESH = SCENES_DIR / "indenters" / "pyramid.stl"
"""The indenter mesh shipped as an example of a user's own (``nlips render --mesh PATH``): a path inside the
installed package, which a wheel's user cannot guess, so a missing ``--mesh pyramid.stl`` prints it."""
DESIGN_SECTIONS = ("dome", "camera", "leds")
"""The sections of a scene file (and of meta.json's ``design``) that make up a :class:`SensorDesign`."""
NO_DESIGN = "no sensor design in the capture: the dome beyond the view is not modelled"
"""What the interreflection fit reports when a capture records no design it can read."""
DomeShape = Literal["hemisphere", "fingertip", "oblate", "capsule", "flat"]


@dataclasses.dataclass(frozen=True)
class DomeConfig:
    """Shape of the gel's outer (coated) surface, which the camera sees from inside."""

    shape: DomeShape = "hemisphere"
    """hemisphere, fingertip (prolate half-ellipsoid), oblate (flattened dome),
    capsule (cylinder with hemispherical cap) or flat (GelSight-like pad)."""
    radius: float = 15.0
    """Base radius, mm (half side length for ``flat``)."""
    height: float = 15.0
    """Apex height above the base, mm (ignored for hemisphere, = radius; pad thickness offset for flat)."""
    thickness: float = 3.0
    """Gel thickness, mm: the deepest indentation the gel allows."""
    edge_length: float = 0.5
    """Target triangle edge of the base mesh, mm (contact regions are refined further)."""
    contact_edge_length: float = 0.08
    """Target triangle edge inside and around a contact, mm."""

    def __post_init__(self):
        for name in ("radius", "height", "thickness", "edge_length", "contact_edge_length"):
            check_range(name, getattr(self, name), 0.0, open_lo=True)
        if self.thickness >= self.radius:
            raise ConfigError(f"thickness ({self.thickness} mm) must be smaller than radius ({self.radius} mm)")


@dataclasses.dataclass(frozen=True)
class CameraConfig:
    """The wide-angle camera inside the dome."""

    width: int = 640
    """Image width, pixels."""
    height: int = 480
    """Image height, pixels."""
    hfov_deg: float = 100.0
    """Horizontal field of view edge to edge, degrees (after distortion)."""
    model: Literal["fisheye", "brown"] = "fisheye"
    """Lens model (OpenCV fisheye or Brown-Conrady)."""
    dist: tuple[float, ...] = (0.05, -0.01, 0.0, 0.0)
    """Distortion coefficients in OpenCV order (4 for fisheye, 5 for brown)."""
    position: tuple[float, float, float] = (0.0, 0.0, -3.0)
    """Camera centre in the dome frame, mm (looks along +z)."""

    def __post_init__(self):
        check_count("width", self.width, minimum=MIN_IMAGE_SIDE)
        check_count("height", self.height, minimum=MIN_IMAGE_SIDE)
        check_range("width", self.width, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)
        check_range("height", self.height, MIN_IMAGE_SIDE, MAX_IMAGE_SIDE)
        check_range("hfov_deg", self.hfov_deg, 0.0, 270.0, open_lo=True)
        # core.Camera's models: OpenCV's fisheye k1..k4 and Brown-Conrady k1, k2, p1, p2, k3 (not OpenCV's 8, 12 or
        # 14 rational and thin-prism terms, which the lens model does not have: they failed in Camera.from_fov)
        expected = {"fisheye": "k1, k2, k3, k4", "brown": "k1, k2, p1, p2, k3"}[self.model]
        if len(self.dist) != expected.count(",") + 1:
            raise ConfigError(
                f"dist: the {self.model} model takes {expected.count(',') + 1} coefficients ({expected}), "
                f"got {len(self.dist)}"
            )

    def camera(self) -> Camera:
        return Camera.from_fov(self.width, self.height, self.hfov_deg, self.model, self.dist)


@dataclasses.dataclass(frozen=True)
class LedConfig:
    """LEDs: a ring around the camera, or an explicit list (positions in the dome frame)."""

    count: int = 12
    """Number of LEDs in the ring (3 to 24)."""
    ring_radius: float = 9.0
    """Ring radius, mm."""
    z: float = 0.0
    """Height of the ring in the dome frame, mm."""
    tilt_deg: float = 20.0
    """Tilt of each LED's principal direction from +z toward the axis, degrees."""
    mu: float = 1.0
    """Anisotropy mu of every LED (WS2812-like ~1)."""
    intensity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Psi per channel (R, G, B) of every LED, relative; the render's exposure sets the scale."""
    start_angle_deg: float = 0.0
    """Angle of LED 1 around the axis, from +x toward +y, degrees."""
    positions: tuple[tuple[float, float, float], ...] = ()
    """Explicit LED positions in the dome frame, mm; when given, overrides the ring."""
    directions: tuple[tuple[float, float, float], ...] = ()
    """Explicit principal directions (dome frame), one per explicit position."""
    emitter_diameter: float = dataclasses.field(default=0.0, metadata={OMIT_AT_DEFAULT: True})
    """Diameter of each LED's round light-emitting area, mm (a WS2812B's light cup: 3.6), perpendicular to its
    principal direction; 0 (the default, and designs written before the field existed): not declared, the LEDs
    taken as points. ``nlips calibrate-leds`` fits the LEDs as disks of this size by default (``--led-diameter``
    overrides it, ``--led-diameter 0`` fits points only). Why it matters: 8-15 mm from the gel a 3.6 mm disk is no
    point; the best point sits ~0.23 mm behind its centre, and a sensor built 2-3 mm / 15-25 deg off its design
    calibrates its worst LED 0.29-0.56 mm off as points, 0.03-0.07 mm as disks (benchmarks/RESULTS.md,
    s28-ledfar). Left out of the scene's mapping at 0 (:data:`~nlipscalib.core.config.OMIT_AT_DEFAULT`)."""

    def __post_init__(self):
        n = len(self.positions) or self.count
        if not 3 <= n <= 24:
            raise ConfigError(f"count: the sensor needs 3 to 24 LEDs, got {n}")
        check_range("ring_radius", self.ring_radius, 0.0)
        check_range("tilt_deg", self.tilt_deg, -90.0, 90.0)
        check_range("mu", self.mu, 0.0)
        for i, psi in enumerate(self.intensity):
            check_range(f"intensity[{i}]", psi, 0.0)
        if not any(self.intensity):
            raise ConfigError("intensity: at least one channel must be > 0")
        if any(not any(d) for d in self.directions):
            raise ConfigError("directions: a zero vector has no direction")
        if self.directions and len(self.directions) != len(self.positions):
            raise ConfigError("leds.directions must have one entry per leds.positions entry")
        check_range("emitter_diameter", self.emitter_diameter, 0.0, MAX_EMITTER_DIAMETER_MM)

    def leds(self, camera_position: tuple[float, float, float]) -> tuple[Led, ...]:
        """The LEDs in the camera frame."""
        cam = np.asarray(camera_position, dtype=float)
        if self.positions:
            pos = np.asarray(self.positions, dtype=float)
            dirs = np.asarray(self.directions, dtype=float) if self.directions else np.tile([0, 0, 1.0], (len(pos), 1))
        else:
            ang = np.radians(self.start_angle_deg) + 2 * np.pi * np.arange(self.count) / self.count
            pos = np.stack(
                [self.ring_radius * np.cos(ang), self.ring_radius * np.sin(ang), np.full_like(ang, self.z)], 1
            )
            t = math.radians(self.tilt_deg)
            dirs = np.stack([-np.sin(t) * np.cos(ang), -np.sin(t) * np.sin(ang), np.full_like(ang, np.cos(t))], 1)
        return tuple(Led(tuple(p - cam), tuple(d), self.mu, self.intensity) for p, d in zip(pos, dirs))


@dataclasses.dataclass(frozen=True)
class SensorDesign:
    """What the sensor is made of, as designed (CAD): enough to compute its undeformed surface."""

    dome: DomeConfig = DomeConfig()
    """The gel's outer surface (shape, size) and thickness, in the dome frame."""
    camera: CameraConfig = CameraConfig()
    """The camera: image size, field of view, lens model, and its position in the dome frame."""
    leds: LedConfig = LedConfig()
    """The LEDs' positions and principal directions in the dome frame (:meth:`led_models`: camera frame)."""

    def camera_model(self) -> Camera:
        """The camera's intrinsics and lens model."""
        return self.camera.camera()

    def led_models(self) -> tuple[Led, ...]:
        """The LEDs in the camera frame."""
        return self.leds.leds(self.camera.position)


UNRENDERED_DESIGN_KEYS = (("leds", "emitter_diameter"),)
"""(section, key) of the design's fields that no twin render reads: the twin draws its LEDs from the scene's
``[led_package]``; ``leds.emitter_diameter`` only tells ``nlips calibrate-leds`` what to fit."""


def rendered_scene(scene: dict) -> dict:
    """A scene mapping (``SceneConfig.to_dict()``, a capture's ``provenance.scene``) without
    :data:`UNRENDERED_DESIGN_KEYS`: what the hashes of renders (``sim.press.render_spec_hash``) and of the experiments'
    tasks are taken of. Why: the shipped scenes declared ``emitter_diameter`` in 2026-12 (s29-ledsize); hashed, every
    rendered press and experiment task of them would have been taken as stale and made again, for a field that
    changes none of their light (and no experiment calibrates with it)."""
    out = dict(scene)
    for section, key in UNRENDERED_DESIGN_KEYS:
        if isinstance(out.get(section), dict) and key in out[section]:
            out[section] = {k: v for k, v in out[section].items() if k != key}
    return out


def shipped_design(name: object) -> SensorDesign | None:
    """The design of the scene shipped as ``name`` (``"nlipstac"``: scenes/nlipstac.toml), or None when ``name`` is
    not the bare name of a shipped scene (a path, a file name, another sensor's own scene file).

    Only bare names: a path recorded by a capture names a file that may have changed or gone since, a shipped
    name names the package's copy (the shipped designs' sections have not changed since they were added)."""
    if not isinstance(name, str) or not name or Path(name).name != name or Path(name).suffix:
        return None
    path = SCENES_DIR / f"{name}.toml"
    if not path.is_file():
        return None
    data = read_config_file(path)
    return from_mapping(SensorDesign, {k: data[k] for k in DESIGN_SECTIONS if k in data}, str(path))


def design_dome(sections: object) -> tuple[DomeConfig, np.ndarray] | None:
    """The dome and the camera's position of a design given as scene-file sections, or None when they hold no
    readable dome (absent, or not a mapping of the dome's fields).

    Returns
    -------
    (DomeConfig, (3,) float64 camera position, mm, dome frame) or None
    """
    if not (isinstance(sections, dict) and isinstance(sections.get("dome"), dict)):
        return None
    try:
        dome = DomeConfig(**sections["dome"])
        position = np.asarray((sections.get("camera") or {}).get("position", CameraConfig.position), float)
    except (TypeError, ValueError):
        return None
    return dome, position


def capture_design(meta: dict) -> tuple[tuple[DomeConfig, np.ndarray] | None, str]:
    """The sensor design a capture was made with (:func:`design_dome` of it), and how it was found, for the report.

    Looks at meta.json's ``design`` (device captures since 2026-12-04), ``provenance.scene`` (the twin, the
    emulated sensor), then ``provenance.design`` when it names a shipped design (:func:`shipped_design`): device
    captures before 2026-12-04 recorded only the name, and their dome is the shipped one, so a lab need not
    capture them again. The named design is taken only when its LED count is the capture's.

    Parameters
    ----------
    meta : dict -- a press folder's meta.json (``core.press_meta.read_meta``).

    Returns
    -------
    (design_dome or None, note): the note is "" for a design recorded whole, says that the design was taken by
    name, or, with None, why there is none (:data:`NO_DESIGN`, naming a named design that does not ship).
    """
    provenance = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    for source in (meta.get("design"), provenance.get("scene")):
        found = design_dome(source)
        if found is not None:
            return found, ""
    name = provenance.get("design")
    if name is None:
        return None, NO_DESIGN
    design = shipped_design(name)
    if design is None:
        return None, f"{NO_DESIGN} (it names the design {name!r}, which does not ship with nlipscalib)"
    n, designed = len(meta["leds"]), len(design.led_models())  # meta's leds: a list (core.press_meta.parse_optics)
    if n != designed:  # not the sensor captured, whatever the name says
        return None, f"{NO_DESIGN} (it names the design {name!r}, whose {designed} LEDs are not its {n})"
    found = design_dome(dataclasses.asdict(design))
    return found, f"sensor design taken by name: the shipped {name!r} (the capture records its name only)"


def capture_led_diameter(meta: dict, where: str = "meta.json") -> tuple[float, str]:
    """The emitting diameter of the LEDs a capture's sensor design declares (``leds.emitter_diameter``, mm), and
    where it was read: what ``nlips calibrate-leds`` fits the LEDs as by default (disks of that size; 0: points).

    Looks where :func:`capture_design` does: meta.json's ``design`` (device captures), ``provenance.scene`` (the twin,
    the emulated sensor), then the shipped design ``provenance.design`` names (device captures before 2026-12-04)
    when its LED count is the capture's. A design recorded without the field (written before it existed) declares
    none: 0.

    Parameters
    ----------
    meta : dict -- a press folder's meta.json (``core.press_meta.read_meta``).
    where : str -- the file, for the error.

    Returns
    -------
    (diameter mm >= 0, source): source names the file and key read ("PRESS/meta.json: design.leds.emitter_diameter"),
    or says why there is none.

    Raises
    ------
    ConfigError
        A recorded value that is no number in [0, :data:`MAX_EMITTER_DIAMETER_MM`] mm, naming ``where`` and the key.
    """
    from .config import is_finite_number

    check_kind(meta, dict, "meta", "a press folder's meta.json as a dict (press.meta, core.press_meta.read_meta)")
    provenance = meta.get("provenance") if isinstance(meta.get("provenance"), dict) else {}
    for key, source in (("design", meta.get("design")), ("provenance.scene", provenance.get("scene"))):
        leds = source.get("leds") if isinstance(source, dict) else None
        if not isinstance(leds, dict):
            continue
        if "emitter_diameter" not in leds:
            return 0.0, f"{where}: its design ({key}) declares no leds.emitter_diameter"
        value = leds["emitter_diameter"]
        name = f"{key}.leds.emitter_diameter"
        if isinstance(value, bool) or not is_finite_number(value):
            raise ConfigError(f"{where}: {name} must be a number of mm, got {value!r}")
        check_range(f"{where}: {name}", float(value), 0.0, MAX_EMITTER_DIAMETER_MM)
        return float(value), f"{where}: {name}"
    name = provenance.get("design")
    design = shipped_design(name)
    if design is None or len(design.led_models()) != len(meta.get("leds") or ()):
        return 0.0, f"{where}: no sensor design recorded"
    return design.leds.emitter_diameter, f"{where}: provenance.design, the shipped design {name!r}"
