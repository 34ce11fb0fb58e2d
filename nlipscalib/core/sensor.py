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
from typing import Literal

import numpy as np

from .camera import Camera
from .config import check_count, check_range
from .errors import ConfigError
from .leds import Led

MIN_IMAGE_SIDE, MAX_IMAGE_SIDE = 8, 16384
"""Image sides, pixels, the camera accepts."""
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
        expected = {"fisheye": (4,), "brown": (4, 5, 8, 12, 14)}[self.model]
        if len(self.dist) not in expected:
            raise ConfigError(
                f"dist: the {self.model} model takes {' or '.join(map(str, expected))} coefficients, "
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
