"""Anisotropic LED as a Mitsuba emitter: radiant intensity Psi_c (n_s . d)^mu, from a point or an area.

Units: positions in mm, intensity Psi in (linear image units) x mm^2, so the irradiance at distance
r is Psi (n_s . d)^mu cos / r^2 and a diffuse surface of albedo a reflects a/pi times that.

An extended LED (``shape`` disk or square of ``size`` mm, in the plane perpendicular to n_s) gives every
area element dA the intensity (Psi / A) (n_s . d)^mu dA. Sampling one emitting point uniformly over the
area (pdf 1/A) and weighting it as a point LED of intensity Psi is then an unbiased estimate of the
extended LED's light, and ``size -> 0`` is the point LED exactly.

At the vertex the camera sees, the integrator sends a pair of shadow rays to an antithetic pair of points:
a uniform point a of the area and its mirror image -a through the centre (uniform too, so the mean stays
unbiased). Across the small emitting area the light a surface point receives is nearly linear in the
emitting point, and the pair cancels that linear part exactly. Measured on the undeformed dome with a 3.6 mm
disk (docs/twin.md): at 4 samples per pixel the per-pixel Monte Carlo noise falls from 2.7 % rms with one
point to 0.5 %, less than one point gives at 16 samples per pixel (0.7 %), for twice the shadow rays of
extended LEDs only.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from types import ModuleType
    from typing import Any  # the plugin's values are Dr.Jit/Mitsuba types of the variant loaded at run time

PLUGIN = "nlips_led"
SHAPES = ("point", "disk", "square")
"""Emitting area of an LED: a point (the NLiPs model), a disk of diameter ``size`` or a square of side ``size``."""


def make_led_class(mi: ModuleType) -> type:
    """The LED emitter class for the active variant of ``mi`` (a subclass of ``mi.Emitter``)."""
    import drjit as dr

    class NlipsLed(mi.Emitter):
        """LED; properties: index (int), position, direction (ScalarVector3f), mu, intensity, shape, size (mm)."""

        def __init__(self, props: Any):
            mi.Emitter.__init__(self, props)
            self.index = int(props.get("index", 0))
            self.m_flags = int(mi.EmitterFlags.DeltaPosition)
            self.scalar_position = mi.ScalarPoint3f(props.get("position"))
            self.position = mi.Point3f(self.scalar_position)
            self.direction = dr.normalize(mi.Vector3f(props.get("direction")))
            self.mu = mi.Float(float(props.get("mu", 1.0)))
            self.intensity = mi.Color3f(props.get("intensity"))
            self.shape = str(props.get("shape", "point"))
            self.size = float(props.get("size", 0.0))
            if self.shape not in SHAPES:
                raise ValueError(f"LED shape must be one of {SHAPES}, got {self.shape!r}")
            # Python-level flag: a point LED draws no sample, so its renders stay as before.
            self.extended = self.shape != "point" and self.size > 0
            frame = mi.Frame3f(self.direction)
            self.axis_s, self.axis_t = mi.Vector3f(frame.s), mi.Vector3f(frame.t)
            self.half = mi.Float(self.size / 2)
            # Opaque: a new LED layout reuses the compiled kernel instead of baking in literals.
            dr.make_opaque(self.position, self.direction, self.mu, self.intensity, self.axis_s, self.axis_t, self.half)

        def emitting_point(self, sample: Any):
            """A point of the emitting area, uniform in area, for a 2D sample in [0, 1)^2 (the centre if a point)."""
            if not self.extended:
                return self.position
            return self.to_world_point(self.local_point(sample))

        def emitting_points(self, sample: Any):
            """An antithetic pair of points of the emitting area for one 2D sample: a uniform point and its
            mirror image through the LED's centre (disk and square map onto themselves)."""
            a = self.local_point(sample)
            return [self.to_world_point(a), self.to_world_point(-a)]

        def local_point(self, sample: Any):
            """Point2f, mm, in the emitting plane's (axis_s, axis_t) coordinates: uniform over the area."""
            if self.shape == "disk":
                return mi.warp.square_to_uniform_disk_concentric(sample) * self.half
            return (sample * 2.0 - 1.0) * self.half

        def to_world_point(self, local: Any):
            """Point3f of emitting-plane coordinates ``local`` (mm)."""
            return self.position + self.axis_s * local.x + self.axis_t * local.y

        def radiance_weight(self, p: Any, active: Any = True, source: Any = None):
            """Psi (n_s . d)^mu / r^2 toward points ``p`` from ``source`` (default: the LED's centre), and the
            unit vector and distance from p to the source."""
            to_led = (self.position if source is None else source) - p
            dist2 = dr.squared_norm(to_led)
            dist = dr.sqrt(dist2)
            d = to_led / dist
            cos_led = dr.maximum(0.0, -dr.dot(self.direction, d))
            # (cos)^mu with 0^0 = 1: mu = 0 is an isotropic LED
            radial = dr.select(self.mu > 0, dr.power(cos_led, self.mu), 1.0)
            return self.intensity * (radial / dist2), d, dist

        def sample_direction(self, it: Any, sample: Any, active: Any = True):
            source = self.emitting_point(sample)
            weight, d, dist = self.radiance_weight(it.p, active, source)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = source
            ds.time = it.time
            ds.pdf = 1.0
            ds.delta = True
            ds.d = d
            ds.dist = dist
            ds.emitter = mi.EmitterPtr(self)
            return ds, dr.select(active, mi.Spectrum(weight), 0.0)

        def pdf_direction(self, it: Any, ds: Any, active: Any = True):
            return mi.Float(0.0)

        def eval_direction(self, it: Any, ds: Any, active: Any = True):
            weight, _, _ = self.radiance_weight(it.p, active)
            return dr.select(active, mi.Spectrum(weight), 0.0)

        def eval(self, si: Any, active: Any = True):
            return mi.Spectrum(0.0)

        def bbox(self):
            box = mi.ScalarBoundingBox3f(self.scalar_position)
            box.expand(self.scalar_position + self.size)
            box.expand(self.scalar_position - self.size)
            return box

        def to_string(self):
            return f"NlipsLed[index={self.index}, {self.shape} {self.size} mm]"

    return NlipsLed
