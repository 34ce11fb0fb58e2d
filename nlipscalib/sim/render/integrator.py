"""All LEDs in one pass: a path tracer that writes each LED's light to its own AOV channels.

Along each camera path, every vertex sends one shadow ray per LED (point LEDs are delta lights, so
this is exact next-event estimation without emitter sampling noise; an extended LED sends it to one
point of its emitting area drawn uniformly); LED k's contribution goes to AOV
channels ``ledKK.R/G/B``. ``bounces`` diffuse bounces follow (0 = direct light only). The main RGB
output is the sum over LEDs (all LEDs on in white).
"""

from __future__ import annotations

PLUGIN = "nlips_multiled"


def aov_names(n_leds: int) -> list[str]:
    """AOV channel names: led01.R, led01.G, led01.B, led02.R, ..."""
    return [f"led{k + 1:02d}.{c}" for k in range(n_leds) for c in "RGB"]


def make_integrator_class(mi, led_class):
    """The multi-LED integrator class for the active variant of ``mi``."""
    import drjit as dr

    class NlipsMultiLed(mi.SamplingIntegrator):
        """Properties: n_leds (int), bounces (int, default 0)."""

        def __init__(self, props):
            mi.SamplingIntegrator.__init__(self, props)
            self.n_leds = int(props.get("n_leds"))
            self.bounces = int(props.get("bounces", 0))

        def aov_names(self):
            return aov_names(self.n_leds)

        def _leds(self, scene):
            leds = sorted((e for e in scene.emitters() if isinstance(e, led_class)), key=lambda e: e.index)
            if [e.index for e in leds] != list(range(self.n_leds)):
                raise ValueError(f"scene LEDs {[e.index for e in leds]} do not match n_leds={self.n_leds}")
            return leds

        def sample(self, scene, sampler, ray, medium=None, active=True):
            leds = self._leds(scene)
            acc = [mi.Spectrum(0.0) for _ in leds]
            throughput = mi.Spectrum(1.0)
            ray = mi.Ray3f(ray)
            active = mi.Bool(active)
            ctx = mi.BSDFContext()
            hit_first = None
            # Python-unrolled: bounces is small and each vertex needs all LEDs anyway.
            for depth in range(self.bounces + 1):
                si = scene.ray_intersect(ray, active)
                active &= si.is_valid()
                hit_first = active if hit_first is None else hit_first
                bsdf = si.bsdf(ray)
                for k, led in enumerate(leds):
                    source = led.emitting_point(sampler.next_2d(active)) if led.extended else led.position
                    weight, d, dist = led.radiance_weight(si.p, active, source)
                    shadow = si.spawn_ray_to(source)
                    visible = active & (scene.ray_test(shadow, active) ^ True)  # ^True: works for scalar bools too
                    f = bsdf.eval(ctx, si, si.to_local(d), visible)  # f * cos, shading frame
                    acc[k] += dr.select(visible, throughput * f * weight, 0.0)
                if depth == self.bounces:
                    break
                bs, bweight = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
                throughput *= bweight
                active &= (bs.pdf > 0) & dr.any(throughput != 0)
                ray = si.spawn_ray(si.to_world(bs.wo))
            total = mi.Spectrum(0.0)
            for a in acc:
                total += a
            aovs = [channel for a in acc for channel in (a[0], a[1], a[2])]
            return total, hit_first, aovs

        def to_string(self):
            return f"NlipsMultiLed[n_leds={self.n_leds}, bounces={self.bounces}]"

    return NlipsMultiLed
