"""Distorted camera as a Mitsuba sensor: rays come from the core :class:`Camera` lens model exactly.

The film position sample (0..1 over the film) maps to corner-origin pixels ``pos * (W, H)``; OpenCV
puts pixel centres at integers, so the lens sees ``u = pos.x * W - 0.5``. The scene is built in the
camera frame (OpenCV axes), so the ray origin is 0 and the direction needs no transform.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``variant.load_mitsuba``), passed as ``mi``
    import mitsuba

    from ...core.camera import Camera

PLUGIN = "nlips_camera"
NEWTON_ITERS = 12
"""Unrolled Newton steps of the undistortion; converges to float32 precision well before this."""


def camera_props(camera: Camera) -> dict:
    """Scene-dict entries describing ``camera`` (a core Camera) for the sensor plugin."""
    dist = list(camera.dist) + [0.0] * (5 - len(camera.dist))
    props = {"fx": camera.fx, "fy": camera.fy, "cx": camera.cx, "cy": camera.cy, "lens": camera.model}
    props |= {f"k{i}": float(c) for i, c in enumerate(dist)}
    return props


def unproject_fisheye(
    dr: ModuleType, mx: mitsuba.Float, my: mitsuba.Float, k: Sequence[float]
) -> tuple[mitsuba.Float, mitsuba.Float, mitsuba.Float]:
    """Unit ray (x, y, z) of normalised fisheye coordinates (drjit arrays)."""
    theta_d = dr.sqrt(mx * mx + my * my)
    theta = theta_d
    for _ in range(NEWTON_ITERS):
        t2 = theta * theta
        f = theta * (1 + t2 * (k[0] + t2 * (k[1] + t2 * (k[2] + t2 * k[3])))) - theta_d
        df = 1 + t2 * (3 * k[0] + t2 * (5 * k[1] + t2 * (7 * k[2] + t2 * 9 * k[3])))
        theta = theta - f / df
    s = dr.select(theta_d > 1e-12, dr.sin(theta) / dr.maximum(theta_d, 1e-30), 1.0)
    return mx * s, my * s, dr.cos(theta)


def unproject_brown(
    dr: ModuleType, mx: mitsuba.Float, my: mitsuba.Float, k: Sequence[float]
) -> tuple[mitsuba.Float, mitsuba.Float, mitsuba.Float]:
    """Unit ray of normalised Brown-Conrady coordinates; Newton with the analytic Jacobian."""
    k1, k2, p1, p2, k3 = k
    a, b = mx, my
    for _ in range(NEWTON_ITERS):
        r2 = a * a + b * b
        radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)  # d radial / d r2
        ex = a * radial + 2 * p1 * a * b + p2 * (r2 + 2 * a * a) - mx
        ey = b * radial + p1 * (r2 + 2 * b * b) + 2 * p2 * a * b - my
        j11 = radial + 2 * a * a * dradial + 2 * p1 * b + 6 * p2 * a
        j12 = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
        j21 = 2 * a * b * dradial + 2 * p1 * a + 2 * p2 * b
        j22 = radial + 2 * b * b * dradial + 6 * p1 * b + 2 * p2 * a
        det = j11 * j22 - j12 * j21
        a, b = a - (j22 * ex - j12 * ey) / det, b - (-j21 * ex + j11 * ey) / det
    n = dr.sqrt(a * a + b * b + 1)
    return a / n, b / n, 1 / n


def make_camera_class(mi: ModuleType) -> type[mitsuba.Sensor]:
    """The distorted-camera sensor class for the active variant of ``mi``."""
    import drjit as dr

    class NlipsCamera(mi.Sensor):
        """Sensor with properties fx, fy, cx, cy (pixels, OpenCV), lens ("fisheye"/"brown"), k0..k4."""

        def __init__(self, props: mitsuba.Properties):
            mi.Sensor.__init__(self, props)
            self.lens = str(props.get("lens", "fisheye"))
            self.intr = [float(props.get(n)) for n in ("fx", "fy", "cx", "cy")]
            self.k = [float(props.get(f"k{i}", 0.0)) for i in range(5)]
            self.size = self.film().size()

        def sample_ray(
            self,
            time: mitsuba.Float,
            wavelength_sample: mitsuba.Float,
            position_sample: mitsuba.Point2f,
            aperture_sample: mitsuba.Point2f,
            active: mitsuba.Bool | bool = True,
        ) -> tuple[mitsuba.Ray3f, mitsuba.Spectrum]:
            fx, fy, cx, cy = self.intr
            u = position_sample.x * float(self.size[0]) - 0.5
            v = position_sample.y * float(self.size[1]) - 0.5
            mx, my = (u - cx) / fx, (v - cy) / fy
            if self.lens == "fisheye":
                x, y, z = unproject_fisheye(dr, mx, my, self.k[:4])
            else:
                x, y, z = unproject_brown(dr, mx, my, self.k)
            ray = dr.zeros(mi.Ray3f)
            ray.o = mi.Point3f(0.0)
            ray.d = mi.Vector3f(x, y, z)
            ray.maxt = dr.inf
            ray.time = time
            return ray, mi.Spectrum(1.0)

        def sample_ray_differential(
            self,
            time: mitsuba.Float,
            wavelength_sample: mitsuba.Float,
            position_sample: mitsuba.Point2f,
            aperture_sample: mitsuba.Point2f,
            active: mitsuba.Bool | bool = True,
        ) -> tuple[mitsuba.RayDifferential3f, mitsuba.Spectrum]:
            ray, weight = self.sample_ray(time, wavelength_sample, position_sample, aperture_sample, active)
            return mi.RayDifferential3f(ray), weight

        def bbox(self) -> mitsuba.ScalarBoundingBox3f:
            return mi.ScalarBoundingBox3f(mi.ScalarPoint3f(0.0))

        def to_string(self) -> str:
            return f"NlipsCamera[{self.lens}, {self.size}]"

    return NlipsCamera
