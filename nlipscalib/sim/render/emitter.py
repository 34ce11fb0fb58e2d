"""Anisotropic point LED as a Mitsuba emitter: radiant intensity Psi_c (n_s . d)^mu.

Units: positions in mm, intensity Psi in (linear image units) x mm^2, so the irradiance at distance
r is Psi (n_s . d)^mu cos / r^2 and a diffuse surface of albedo a reflects a/pi times that.
"""

from __future__ import annotations

PLUGIN = "nlips_led"


def make_led_class(mi):
    """The LED emitter class for the active variant of ``mi`` (a subclass of ``mi.Emitter``)."""
    import drjit as dr

    class NlipsLed(mi.Emitter):
        """Point LED; properties: index (int), position, direction (ScalarVector3f), mu, intensity."""

        def __init__(self, props):
            mi.Emitter.__init__(self, props)
            self.index = int(props.get("index", 0))
            self.m_flags = int(mi.EmitterFlags.DeltaPosition)
            self.scalar_position = mi.ScalarPoint3f(props.get("position"))
            self.position = mi.Point3f(self.scalar_position)
            self.direction = dr.normalize(mi.Vector3f(props.get("direction")))
            self.mu = mi.Float(float(props.get("mu", 1.0)))
            self.intensity = mi.Color3f(props.get("intensity"))
            # Opaque: a new LED layout reuses the compiled kernel instead of baking in literals.
            dr.make_opaque(self.position, self.direction, self.mu, self.intensity)

        def radiance_weight(self, p, active=True):
            """Psi (n_s . d)^mu / r^2 toward points ``p`` and the unit vector from p to the LED."""
            to_led = self.position - p
            dist2 = dr.squared_norm(to_led)
            dist = dr.sqrt(dist2)
            d = to_led / dist
            cos_led = dr.maximum(0.0, -dr.dot(self.direction, d))
            # (cos)^mu with 0^0 = 1: mu = 0 is an isotropic LED
            radial = dr.select(self.mu > 0, dr.power(cos_led, self.mu), 1.0)
            return self.intensity * (radial / dist2), d, dist

        def sample_direction(self, it, sample, active=True):
            weight, d, dist = self.radiance_weight(it.p, active)
            ds = dr.zeros(mi.DirectionSample3f)
            ds.p = self.position
            ds.time = it.time
            ds.pdf = 1.0
            ds.delta = True
            ds.d = d
            ds.dist = dist
            ds.emitter = mi.EmitterPtr(self)
            return ds, dr.select(active, mi.Spectrum(weight), 0.0)

        def pdf_direction(self, it, ds, active=True):
            return mi.Float(0.0)

        def eval_direction(self, it, ds, active=True):
            weight, _, _ = self.radiance_weight(it.p, active)
            return dr.select(active, mi.Spectrum(weight), 0.0)

        def eval(self, si, active=True):
            return mi.Spectrum(0.0)

        def bbox(self):
            return mi.ScalarBoundingBox3f(self.scalar_position)

        def to_string(self):
            return f"NlipsLed[index={self.index}]"

    return NlipsLed
