"""All LEDs in one pass: a path tracer that writes each LED's light to its own AOV channels.

Along each camera path, every vertex sends one shadow ray per LED (point LEDs are delta lights, so
this is exact next-event estimation without emitter sampling noise; an extended LED sends one to each
of an antithetic pair of points of its emitting area, see ``emitter.py``); LED k's contribution goes to AOV
channels ``ledKK.R/G/B``. ``bounces`` diffuse bounces follow (0 = direct light only). The main RGB
output is the sum over LEDs (all LEDs on in white).

With a refracting gel (``refract``: a ``dielectric`` interface between housing and gel) no shadow ray
can reach an LED in a straight line. Camera paths then pass the interface by sampling its BSDF (reflect
or refract, Fresnel-weighted), and each coat vertex estimates each LED's light with one direction drawn
uniformly in a cone around the direction from which that LED's light arrives through the interface
(found by a fixed-point trace), ``cone_margin`` times as wide as the LED seen in a straight line and at
most ``cone_deg``: the direction is traced through the interface (Snell,
transmittance 1 - F, radiance scaled by (n_gel / n_housing)^2) and counts when it lands on the LED's
emitting area, with the area's radiance (Psi / A) (n_s . d)^(mu - 1). Unbiased while the cone covers
the LED as seen through the interface.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from types import ModuleType
    from typing import Any  # the plugin's values are Dr.Jit/Mitsuba types of the variant loaded at run time

PLUGIN = "nlips_multiled"
MAX_SPECULAR = 3
"""Specular (interface) vertices a path may pass between two coat vertices; longer paths are dropped."""
AIM_STEPS = 3
"""Fixed-point steps toward the direction in which an LED is seen through the interface."""
AIM_SLACK_DEG = 1.0
"""Added to the per-LED cone's half-angle, degrees: room for the aim's last error."""


def aov_names(n_leds: int, split: bool = False) -> list[str]:
    """AOV channel names: led01.R, led01.G, led01.B, led02.R, ...; with ``split`` these hold the light of
    the vertex the camera sees and ind01.R, ... follow with the light of the later (bounce) vertices."""
    names = [f"led{k + 1:02d}.{c}" for k in range(n_leds) for c in "RGB"]
    return names + ([f"ind{k + 1:02d}.{c}" for k in range(n_leds) for c in "RGB"] if split else [])


def make_integrator_class(mi: ModuleType, led_class: type) -> type:
    """The multi-LED integrator class for the active variant of ``mi``."""
    import drjit as dr

    class NlipsMultiLed(mi.SamplingIntegrator):
        """Properties: n_leds (int), bounces (int, default 0), refract (bool), eta (n_gel / n_housing),
        cone_deg (half-angle of the per-LED direction cone when refracting), split (bool: the bounces'
        light in AOVs of its own, :func:`aov_names`)."""

        def __init__(self, props: Any):
            mi.SamplingIntegrator.__init__(self, props)
            self.n_leds = int(props.get("n_leds"))
            self.bounces = int(props.get("bounces", 0))
            self.refract = bool(props.get("refract", False))
            self.eta = float(props.get("eta", 1.0))
            self.max_cone = float(dr.deg2rad(float(props.get("cone_deg", 30.0))))
            self.cone_margin = float(props.get("cone_margin", 1.3))
            self.split = bool(props.get("split", False)) and self.bounces > 0

        def aov_names(self):
            return aov_names(self.n_leds, self.split)

        def _leds(self, scene: Any):
            leds = sorted((e for e in scene.emitters() if isinstance(e, led_class)), key=lambda e: e.index)
            if [e.index for e in leds] != list(range(self.n_leds)):
                raise ValueError(f"scene LEDs {[e.index for e in leds]} do not match n_leds={self.n_leds}")
            return leds

        def sample(self, scene: Any, sampler: Any, ray: Any, medium: Any = None, active: Any = True):
            leds = self._leds(scene)
            acc = [mi.Spectrum(0.0) for _ in leds]
            bounced = [mi.Spectrum(0.0) for _ in leds]  # the later vertices' light, when split
            throughput = mi.Spectrum(1.0)
            ray = mi.Ray3f(ray)
            active = mi.Bool(active)
            ctx = mi.BSDFContext()
            # the film's alpha, the pixel's coverage by the gel (scene.sensor_entry): whether the camera ray meets
            # it. Through a refracting gel that is its inner surface, whether or not the walk then reaches the coat
            # (a path reflected at the interface is the pixel's light lost there, not a pixel beside the gel).
            covered = scene.ray_test(ray, active) if self.refract else None
            # Python-unrolled: bounces is small and each vertex needs all LEDs anyway.
            for depth in range(self.bounces + 1):
                si, ray, throughput, active = self._next_coat_vertex(scene, sampler, ray, throughput, active)
                covered = active if covered is None else covered
                bsdf = si.bsdf(ray)
                into = bounced if self.split and depth > 0 else acc
                for k, led in enumerate(leds):
                    into[k] += self._led_light(scene, sampler, si, bsdf, led, throughput, active, depth == 0)
                if depth == self.bounces:
                    break
                bs, bweight = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
                throughput *= bweight
                active &= (bs.pdf > 0) & dr.any(throughput != 0)
                ray = si.spawn_ray(si.to_world(bs.wo))
            total = mi.Spectrum(0.0)
            for a in acc + (bounced if self.split else []):
                total += a
            aovs = [channel for a in acc + (bounced if self.split else []) for channel in (a[0], a[1], a[2])]
            return total, covered, aovs

        def _next_coat_vertex(self, scene: Any, sampler: Any, ray: Any, throughput: Any, active: Any):
            """The coat point ``ray`` reaches: its first hit, or past the interface when refracting."""
            if self.refract:
                return self._walk_to_coat(scene, sampler, ray, throughput, active)
            si = scene.ray_intersect(ray, active)
            return si, ray, throughput, active & si.is_valid()

        def _led_light(
            self, scene: Any, sampler: Any, si: Any, bsdf: Any, led: Any, throughput: Any, active: Any, first: bool
        ):
            """One estimate of the light of ``led`` that coat vertex ``si`` sends back along the path
            (``first``: the vertex the camera sees)."""
            if self.refract:
                return self._led_through_interface(scene, sampler, si, bsdf, led, throughput, active)
            return self._led_direct(scene, sampler, si, bsdf, led, throughput, active, first)

        def _led_direct(
            self, scene: Any, sampler: Any, si: Any, bsdf: Any, led: Any, throughput: Any, active: Any, first: bool
        ):
            """Shadow rays to the LED: its centre (point LED) or points of its area, an antithetic pair at
            the vertex the camera sees and one point at later vertices, whose light the bounce direction's
            own sampling noise already dominates (one shadow ray per LED there, as for a point LED)."""
            ctx = mi.BSDFContext()
            if not led.extended:
                sources = [led.position]
            elif first:
                sources = led.emitting_points(sampler.next_2d(active))
            else:
                sources = [led.emitting_point(sampler.next_2d(active))]
            light = mi.Spectrum(0.0)
            for source in sources:
                weight, d, _ = led.radiance_weight(si.p, active, source)
                shadow = si.spawn_ray_to(source)
                visible = active & (scene.ray_test(shadow, active) ^ True)  # ^True: works for scalar bools too
                f = bsdf.eval(ctx, si, si.to_local(d), visible)  # f * cos, shading frame
                light += dr.select(visible, throughput * f * weight, 0.0)
            return light / len(sources)

        def _walk_to_coat(self, scene: Any, sampler: Any, ray: Any, throughput: Any, active: Any):
            """Follow ``ray`` through specular (interface) vertices to the next coat vertex."""
            ctx = mi.BSDFContext()
            for _ in range(MAX_SPECULAR):
                si = scene.ray_intersect(ray, active)
                active &= si.is_valid()
                bsdf = si.bsdf(ray)
                delta = active & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta)
                bs, weight = bsdf.sample(ctx, si, sampler.next_1d(delta), sampler.next_2d(delta), delta)
                # lanes already on the coat keep their ray, so the next intersection finds the same point
                ray = dr.select(delta, si.spawn_ray(si.to_world(bs.wo)), ray)
                throughput = dr.select(delta, throughput * weight, throughput)
            si = scene.ray_intersect(ray, active)
            active &= si.is_valid() & ~mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.Delta)
            return si, ray, throughput, active

        def _led_through_interface(
            self, scene: Any, sampler: Any, si: Any, bsdf: Any, led: Any, throughput: Any, active: Any
        ):
            """One-sample estimate of the light of ``led`` reaching coat vertex ``si`` through the interface."""
            aim, cos_cone = self._arrival_cone(scene, si, led, active)
            local = mi.warp.square_to_uniform_cone(sampler.next_2d(active), cos_cone)
            pdf = mi.warp.square_to_uniform_cone_pdf(local, cos_cone)
            omega = mi.Frame3f(aim).to_world(local)
            f = bsdf.eval(mi.BSDFContext(), si, si.to_local(omega), active)  # f * cos
            s1 = scene.ray_intersect(si.spawn_ray(omega), active)
            ok = active & s1.is_valid() & mi.has_flag(s1.bsdf().flags(), mi.BSDFFlags.Delta)
            fresnel, cos_t, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(s1.wi), self.eta)
            ok &= fresnel < 1  # total internal reflection sends nothing out
            out = s1.to_world(mi.refract(s1.wi, cos_t, eta_ti))
            # where the refracted ray meets the LED's plane, and whether that is on the emitting area
            towards = dr.dot(out, led.direction)
            cos_e = -towards
            ok &= cos_e > 1e-6
            dist = dr.dot(led.position - s1.p, led.direction) / dr.select(ok, towards, -1.0)
            ok &= dist > 0
            rel = s1.p + out * dist - led.position
            a, b = dr.dot(rel, led.axis_s), dr.dot(rel, led.axis_t)
            if led.shape == "disk":
                ok &= a * a + b * b <= led.half * led.half
            else:
                ok &= (dr.abs(a) <= led.half) & (dr.abs(b) <= led.half)
            shadow = s1.spawn_ray(out)
            shadow.maxt = dist * (1 - 1e-4)
            ok &= ~scene.ray_test(shadow, ok)
            area = dr.pi * led.half * led.half if led.shape == "disk" else 4 * led.half * led.half
            radiance = led.intensity / area * dr.select(led.mu > 0, dr.power(cos_e, led.mu - 1), 1 / cos_e)
            gain = (1 - fresnel) * self.eta * self.eta / pdf
            return dr.select(ok, throughput * f * radiance * gain, 0.0)

        def _arrival_cone(self, scene: Any, si: Any, led: Any, active: Any):
            """Axis (unit, from ``si``) and cosine of the half-angle of a cone holding the LED as seen
            from ``si`` through the interface.

            The axis is the fixed point of: cross the interface at z, take the direction in which the
            light of the LED's centre travels on from z into the gel, trace back from ``si`` against
            it to a new z. ``si`` lies much nearer the interface than the LED does, so each step
            shrinks the error several-fold; ``AIM_STEPS`` steps leave a fraction of a degree. The
            half-angle is the LED's angular radius seen in a straight line from the crossing point,
            an upper bound of the refracted one (rays bend toward the normal entering the gel), times
            ``cone_margin``, and at most ``cone_deg``.
            """
            aim = dr.normalize(led.position - si.p)
            found = mi.Bool(active)
            span = mi.Float(0.0)
            for _ in range(AIM_STEPS):
                s1 = scene.ray_intersect(si.spawn_ray(aim), active)
                cross = active & s1.is_valid() & mi.has_flag(s1.bsdf().flags(), mi.BSDFFlags.Delta)
                to_led = led.position - s1.p
                d_led = dr.norm(to_led)
                wi = s1.to_local(to_led / d_led)  # on the housing side of the interface
                _, cos_t, _, eta_ti = mi.fresnel(mi.Frame3f.cos_theta(wi), self.eta)
                travel = s1.to_world(mi.refract(wi, cos_t, eta_ti))  # the light's direction in the gel
                good = cross & (dr.norm(travel) > 0.5)
                aim = dr.select(good, -travel, aim)
                span = dr.select(good, d_led + dr.norm(s1.p - si.p), span)
                found &= good
            angle = dr.atan(self.cone_margin * led.half / dr.maximum(span, 1e-3)) + dr.deg2rad(AIM_SLACK_DEG)
            cos_cone = dr.select(found, dr.cos(dr.minimum(angle, self.max_cone)), dr.cos(self.max_cone))
            return aim, cos_cone

        def to_string(self):
            return f"NlipsMultiLed[n_leds={self.n_leds}, bounces={self.bounces}, refract={self.refract}]"

    return NlipsMultiLed
