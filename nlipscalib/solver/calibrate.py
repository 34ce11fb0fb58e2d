"""LED self-calibration from captures of the undeformed dome (known geometry: Press.reference).

Per LED i, non-linear least squares (scipy.optimize.least_squares, robust loss) of
``I_ic(p) = K_ic * (n_s . d)^mu * max(0, (x_s - x) . n) / |x_s - x|^3`` over the reference's pixels,
with K_ic = rho_c Psi_ic. Parameters: log K_ic (3), mu, n_s (polar and azimuth angles), x_s (3).

Gauge (Psi and albedo are only known up to a common scale): the coating's albedo is taken uniform per
channel and the LED intensities are normalised so that **mean_i Psi_ic = 1 for every channel c**; the
common factor rho_c = mean_i K_ic is reported as ``albedo``. The solver recovers albedo relative to it.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.leds import Led, disk_shading, led_shading
from ..errors import CaptureError, ConfigError


@dataclasses.dataclass(frozen=True)
class LedCalibration:
    """Result of :func:`calibrate_leds`."""

    leds: tuple[Led, ...]
    """Calibrated LEDs (camera frame, mm), gauge mean Psi = 1 per channel."""
    albedo: tuple[float, float, float]
    """Uniform coating albedo per channel in the same gauge (image units)."""
    std: list[dict]
    """Per LED 1-sigma uncertainties from the Jacobian: intensity (3,), mu, direction_deg, position_mm (3,)."""
    rms: list[float]
    """Per LED RMS residual, linear image units."""
    interreflection: list = dataclasses.field(default_factory=list)
    """Per capture, the fitted indirect term (``IndirectModel.to_json()``) of the last round."""
    emitters: tuple[Led, ...] = ()
    """With ``led_radius``: each LED as the disk it emits from (centre, axis, mu, Psi in the same gauge),
    fitted with :func:`nlipscalib.core.leds.disk_shading`: the physical LEDs, to compare with the CAD.
    ``leds`` stay the point LEDs that best reproduce the images, which the solver's point model uses (for
    a 3.6 mm disk about 0.2 mm behind its centre). Empty without ``led_radius``."""
    led_radius: float = 0.0
    """The emitting disk's radius the emitters were fitted with, mm (0: none)."""
    reflectance_profile: dict | None = None
    """With ``led_radius`` and no known coating reflectance: how the reflectance was chosen
    (:func:`_profiled_reflectance`): the freely fitted one, the scales of it tried, their disk-fit residuals
    and the chosen reflectance. None otherwise."""

    def to_json(self) -> dict:
        out = {
            "gauge": "mean Psi = 1 per channel, uniform albedo",
            "albedo": list(self.albedo),
            "std": self.std,
            "rms": self.rms,
            "interreflection": self.interreflection,
        }
        if self.emitters:
            out["emitters"] = {"radius_mm": self.led_radius, "leds": [led.to_dict() for led in self.emitters]}
        if self.reflectance_profile is not None:
            out["reflectance_profile"] = self.reflectance_profile
        return out


def _unit(theta, phi):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _led(params) -> Led:
    """The Led a parameter vector (log K (3), mu, polar, azimuth of n_s, x_s (3)) stands for."""
    return Led(
        tuple(params[6:9]), tuple(_unit(params[4], params[5])), max(float(params[3]), 0.0), tuple(np.exp(params[:3]))
    )


def _model(params, x, n):
    """(N, 3) model images of one LED: the one LED image model, ``core.leds.led_shading``."""
    return led_shading(x, n, (_led(params),))[0]


def _disk_model(radius: float):
    """``_model`` for an LED emitting from a disk of ``radius`` mm (``core.leds.disk_shading``)."""

    def model(params, x, n):
        return disk_shading(x, n, (_led(params),), radius)[0]

    return model


def calibrate_leds(
    presses,
    initial=None,
    stride: int = 2,
    loss: str = "cauchy",
    *,
    interreflection: str = "auto",
    bounces: int = 1,
    rounds: int = 3,
    led_radius: float = 0.0,
    coating_reflectance: float | tuple[float, float, float] | None = None,
) -> LedCalibration:
    """Estimate Psi_c, mu, n_s and x_s of every LED from undeformed captures.

    With interreflection (any real sensor) the images hold more than the direct model: the LEDs are
    fitted, the indirect term (:func:`nlipscalib.solver.indirect.fit_indirect`, radiosity gather on the
    known undeformed surface, coating reflectance fitted) is computed with them, subtracted, and the
    LEDs fitted again from where they are, ``rounds`` times.

    Parameters
    ----------
    presses : Press or sequence of Press -- undeformed dome, with ``reference``; same camera and LEDs.
    initial : sequence of Led or None -- starting values (default: the capture's LEDs).
    stride : use every ``stride``-th pixel in u and v (speed).
    loss : scipy robust loss ("cauchy", "soft_l1", "huber", "linear").
    interreflection : "auto" (subtract the indirect term when the data show it), "on", "off".
    bounces : diffuse bounces of the indirect term (1 or 2).
    rounds : LED fit / indirect term alternations (with the term on).
    led_radius : radius of each LED's emitting disk, mm (a WS2812B's light cup: 1.8); > 0 adds a last
        fit of the LEDs as disks (``LedCalibration.emitters``) from the point LEDs, to the same images
        minus the same indirect light. On the twin's bounce-free 3.6 mm disk LEDs the disks come out
        within 0.02 deg and 0.005 mm of the truth, where the best points sit 0.24 mm behind
        (benchmarks/RESULTS.md).
    coating_reflectance : the coating's reflectance (0-1], one value or per channel, when it is known
        (measured, or from the coating's datasheet) instead of fitted. Why it matters: a ring-wide tilt of
        the LED axes and the indirect term's magnitude explain the images almost alike; on the twin the
        fitted reflectance comes out 0.89 for a true 0.8 and the axes ~2 deg too upright, with the true
        reflectance ~1 deg (benchmarks/RESULTS.md). Unknown, with ``led_radius`` and the indirect term on,
        it is profiled instead (:func:`_profiled_reflectance`): the reflectance whose disk fit leaves the
        least residual, then the whole calibration again with it.
    """
    from .indirect import checked_reflectance, fit_indirect

    presses = [presses] if isinstance(presses, Press) else list(presses)
    if not presses:
        raise CaptureError("calibrate_leds needs at least one capture")
    first = presses[0]
    leds0 = leds = tuple(initial) if initial is not None else first.leds
    data = [_samples(p, first, len(leds), stride) for p in presses]
    x, n = np.concatenate([d[0] for d in data]), np.concatenate([d[1] for d in data])
    img, ok = np.concatenate([d[2] for d in data], axis=1), np.concatenate([d[3] for d in data], axis=1)
    # A direct-only fit would absorb the indirect light into wrong LED parameters (up to 17 deg off on
    # the twin), after which nothing correlates with the indirect term any more: the term is fitted
    # with the starting LEDs first, and the LEDs are always fitted to the images minus it.
    if not led_radius >= 0:
        raise ConfigError(f"the LED disk radius must be >= 0 mm, got {led_radius}")
    if coating_reflectance is not None:
        checked_reflectance(coating_reflectance)  # before any fit
    fitted = None
    models = []
    direct = img  # the images minus the indirect light the last LED fit used
    for r in range(rounds if interreflection != "off" else 0):
        if r > 0:
            leds = _to_leds(fitted)[0]
        models = [fit_indirect(p, leds, mode=interreflection, bounces=bounces) for p in presses]
        if r == 0 and interreflection == "auto":
            models = [_decide(m) for m in models]
        if coating_reflectance is not None and r > 0:
            # not in the first round: with the starting LEDs a lower light than fitted let an LED fit run off
            # (seen: one LED 6.6 mm away); from the first round's LEDs the known value only refines
            models = [m.with_reflectance(coating_reflectance) if m.enabled else m for m in models]
        if not any(m.enabled for m in models):
            break
        light = []
        for p, m, (_, _, _, _, sel) in zip(presses, models, data):
            if not m.enabled:
                light.append(np.zeros((len(leds), int(sel.sum()), 3)))
                continue
            # the fitted capture's own indirect light, at its typical albedo
            light.append((m.undeformed_light(p.camera.shape) * np.asarray(m.off_view_albedo, np.float32))[:, sel])
        direct = img - np.concatenate(light, axis=1)
        fitted = _fit_all(leds, x, n, direct, ok, loss)
    if fitted is None or (models and not any(m.enabled for m in models)):
        direct = img
        fitted = _fit_all(leds0, x, n, img, ok, loss)
    models = [m.to_json() for m in models]
    leds, albedo, std = _to_leds(fitted)
    rms = [f[2] for f in fitted]
    emitters = ()
    if led_radius > 0:  # from the points (0.2 mm off at most): the disk fit only refines them
        emitters = _to_leds(_fit_all(leds, x, n, direct, ok, loss, _disk_model(led_radius)))[0]
    fitted_reflectance = _fitted_reflectance(models)
    if led_radius > 0 and coating_reflectance is None and fitted_reflectance is not None:
        profile = _profiled_reflectance(emitters, x, n, img, direct, ok, loss, led_radius, fitted_reflectance)
        again = calibrate_leds(
            presses,
            initial=leds,
            stride=stride,
            loss=loss,
            interreflection=interreflection,
            bounces=bounces,
            rounds=rounds,
            led_radius=led_radius,
            coating_reflectance=tuple(profile["chosen"]),
        )
        return dataclasses.replace(again, reflectance_profile=profile)
    return LedCalibration(leds, albedo, std, rms, models, emitters, float(led_radius))


def _fitted_reflectance(models: list[dict]) -> np.ndarray | None:
    """(3,) the coating reflectance the indirect term was fitted with (the first capture's whose term is on),
    or None when no capture's term is on."""
    for m in models:
        if m.get("enabled"):
            return np.asarray(m["coating_reflectance"], float)
    return None


PROFILE_SCALES = (0.6, 1.15)
"""Range of the reflectance profile, as multiples of the freely fitted reflectance (:func:`_profiled_reflectance`)."""
PROFILE_XTOL = 0.01
"""The profile's tolerance on that multiple."""
PROFILE_SAMPLES = 20_000
"""The profile's disk fits use every k-th sample, k the smallest that leaves at most this many (a 640x480
capture at stride 2 has ~55,000; every second of a 160x120 capture's ~3,400 moved the chosen reflectance from
0.78 to 0.75, and its LED positions by 0.03 mm)."""


def _profiled_reflectance(emitters, x, n, img, direct, ok, loss, radius, fitted) -> dict:
    """The coating reflectance whose LED disk fit leaves the least residual, as a multiple of ``fitted``.

    Why: a ring-wide tilt of the LED axes trades against the indirect term's magnitude, and the alternation
    of LED fit and indirect fit settles on the tilted side (on the twin: 0.89-0.91 for a true 0.8, start
    dependent). The point LEDs cannot arbitrate (a point is not the disk the light comes from: their residual
    keeps falling with the reflectance), but the disk model is the emitter's own: its residual, with the
    indirect light scaled by s (exact for one bounce, linear in the reflectance), is least near the true
    reflectance (twin, 160x120: 0.75-0.80 for 0.8; benchmarks/RESULTS.md). Bounded Brent search over s
    (scipy.optimize.minimize_scalar), each step a disk fit from ``emitters`` on at most
    :data:`PROFILE_SAMPLES` samples.

    Parameters
    ----------
    emitters : sequence of Led -- the disks fitted to ``direct`` (the start of every fit).
    x, n : (N, 3) float, mm / unit, camera frame -- the samples' points and normals.
    img, direct : (L, N, 3) float -- the images, and the images minus the indirect light at ``fitted``.
    ok : (L, N, 3) bool -- usable samples.
    loss : the LED fit's robust loss; radius : the disks' radius, mm.
    fitted : (3,) float -- the freely fitted coating reflectance.

    Returns
    -------
    dict -- fitted (3,), scales, residuals (sum over LEDs of the disk fit's squared RMS, image units), chosen (3,).
    """
    from scipy.optimize import minimize_scalar

    light = img - direct
    every = slice(None, None, -(-len(x) // PROFILE_SAMPLES))
    xs, ns, imgs, lights, oks = x[every], n[every], img[:, every], light[:, every], ok[:, every]
    model = _disk_model(radius)
    tried: dict[float, float] = {}

    def residual(s: float) -> float:
        out = _fit_all(emitters, xs, ns, imgs - s * lights, oks, loss, model)
        tried[float(s)] = float(sum(f[2] ** 2 for f in out))
        return tried[float(s)]

    top = min(PROFILE_SCALES[1], 1.0 / float(np.max(fitted)))
    best = minimize_scalar(residual, bounds=(PROFILE_SCALES[0], top), method="bounded", options={"xatol": PROFILE_XTOL})
    scales = sorted(tried)
    return {
        "fitted": [float(v) for v in fitted],
        "scales": [round(s, 4) for s in scales],
        "residuals": [tried[s] for s in scales],
        "chosen": [float(v) for v in np.minimum(fitted * float(best.x), 1.0)],
    }


CALIBRATION_MIN_SHARE = 0.1
"""LED calibration, interreflection auto: the indirect term is used when, fitted with the starting LEDs,
its share of the direct light is at least this. The starting LEDs' own errors pose as a few % of
indirect light (a nominal ring 0.3 mm / 5 deg off: 3 %); a coated dome interreflects far more (the
twin: 31 %). The images cannot decide it after the fact: a direct-only fit absorbs the indirect light
into wrong LED parameters (17 deg off on the twin) and then fits as well as the right model."""


def _decide(model):
    """The calibration's auto decision (:data:`CALIBRATION_MIN_SHARE`) on a model fitted with the starting LEDs."""
    import dataclasses

    on = model.share >= CALIBRATION_MIN_SHARE
    note = f"; calibration: {'used' if on else 'not used'} (threshold {CALIBRATION_MIN_SHARE} with the starting LEDs)"
    reason = model.reason.replace("interreflection on:", "interreflection off:") if not on else model.reason
    return dataclasses.replace(model, enabled=on, reason=reason + note)


def _samples(p: Press, first: Press, count: int, stride: int):
    """Points, normals, linear images, usable flags and the pixel selection of one capture."""
    if p.reference is None:
        raise CaptureError(f"{p.folder}: LED calibration needs the undeformed reference (reference.npz)")
    if p.camera != first.camera or len(p.leds) != count:
        raise CaptureError(f"{p.folder}: camera or LED count differs from {first.folder}")
    valid = np.isfinite(p.reference.depth)
    sub = np.zeros_like(valid)
    sub[::stride, ::stride] = True
    sel = valid & sub
    rays = p.camera.rays[sel]
    x = depth_to_points(p.reference.depth[sel].astype(np.float64), rays)
    n = p.reference.normals[sel].astype(np.float64)
    return x, n, p.linear(p.led_images)[:, sel].astype(np.float64), ~p.saturated(p.led_images)[:, sel], sel


def _fit_all(leds, x, n, img, ok, loss, model=_model):
    """[(params, std, rms)] per LED: robust non-linear least squares of ``model`` from ``leds``."""
    from scipy.optimize import least_squares  # imported here: ~0.5 s that `nlips solve` never needs

    out = []
    for i, led in enumerate(leds):
        d = np.asarray(led.direction)
        p0 = np.concatenate(
            [
                np.log(np.maximum(led.intensity, 1e-12)),
                [led.mu, np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])],
                led.position,
            ]
        )
        # initial intensity: least-squares scale of the model
        geo = model(p0, x, n) / np.exp(p0[:3])
        k0 = (geo * img[i] * ok[i]).sum(0) / np.maximum((geo * geo * ok[i]).sum(0), 1e-30)
        p0[:3] = np.log(np.maximum(k0, 1e-12))
        use = ok[i] & (img[i] > 0.01 * np.percentile(img[i], 99, axis=0))
        scale = float(np.percentile(img[i][use], 90)) if use.any() else 1.0

        def resid(params, i=i, use=use, scale=scale):
            return ((model(params, x, n) - img[i]) / scale)[use]

        r0 = resid(p0)
        f_scale = max(3 * 1.4826 * float(np.median(np.abs(r0 - np.median(r0)))), 1e-3)
        res = least_squares(resid, p0, loss=loss, f_scale=f_scale, x_scale="jac", method="trf")
        dof = max(len(res.fun) - len(p0), 1)
        s2 = float(np.sum(res.fun**2) / dof)
        try:
            sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(res.jac.T @ res.jac) * s2), 0))
        except np.linalg.LinAlgError:
            sd = np.full(len(p0), np.nan)
        out.append((res.x, sd, float(np.sqrt(np.mean(res.fun**2))) * scale))
    return out


def _to_leds(fitted):
    """(LEDs in the gauge mean Psi = 1 per channel, albedo (3,), std dicts) from per-LED fits."""
    K = np.exp(np.array([f[0][:3] for f in fitted]))  # (L, 3)
    albedo = K.mean(axis=0)
    leds, std = [], []
    for (f, sd, _), k in zip(fitted, K):
        psi = k / albedo
        leds.append(Led(tuple(f[6:9]), tuple(_unit(f[4], f[5])), float(max(f[3], 0.0)), tuple(psi)))
        std.append(
            {
                "intensity": list(psi * sd[:3]),
                "mu": float(sd[3]),
                "direction_deg": float(np.degrees(np.hypot(sd[4], np.sin(f[4]) * sd[5]))),
                "position_mm": list(sd[6:9]),
            }
        )
    return tuple(leds), tuple(float(a) for a in albedo), std
