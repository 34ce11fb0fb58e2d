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
from scipy.optimize import least_squares

from ..core.capture import Press
from ..core.leds import Led
from ..errors import CaptureError


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

    def to_json(self) -> dict:
        return {
            "gauge": "mean Psi = 1 per channel, uniform albedo",
            "albedo": list(self.albedo),
            "std": self.std,
            "rms": self.rms,
        }


def _unit(theta, phi):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _model(params, x, n):
    logk, mu, theta, phi, pos = params[:3], params[3], params[4], params[5], params[6:9]
    v = pos - x
    r = np.linalg.norm(v, axis=1)
    cos_s = np.maximum(np.sum(v * n, axis=1) / r, 0)
    cos_l = np.maximum(-(v @ _unit(theta, phi)) / r, 0)
    geo = cos_l ** max(mu, 0.0) * cos_s / r**2
    return geo[:, None] * np.exp(logk)[None, :]


def calibrate_leds(presses, initial=None, stride: int = 2, loss: str = "cauchy") -> LedCalibration:
    """Estimate Psi_c, mu, n_s and x_s of every LED from undeformed captures.

    Parameters
    ----------
    presses : Press or sequence of Press -- undeformed dome, with ``reference``; same camera and LEDs.
    initial : sequence of Led or None -- starting values (default: the capture's LEDs).
    stride : use every ``stride``-th pixel in u and v (speed).
    loss : scipy robust loss ("cauchy", "soft_l1", "huber", "linear").
    """
    presses = [presses] if isinstance(presses, Press) else list(presses)
    if not presses:
        raise CaptureError("calibrate_leds needs at least one capture")
    first = presses[0]
    leds0 = tuple(initial) if initial is not None else first.leds
    xs, ns, imgs, oks = [], [], [], []
    for p in presses:
        if p.reference is None:
            raise CaptureError(f"{p.folder}: LED calibration needs the undeformed reference (reference.npz)")
        if p.camera != first.camera or len(p.leds) != len(leds0):
            raise CaptureError(f"{p.folder}: camera or LED count differs from {first.folder}")
        valid = np.isfinite(p.reference.depth)
        valid[::stride] &= True
        sub = np.zeros_like(valid)
        sub[::stride, ::stride] = True
        sel = valid & sub
        rays = p.camera.rays[sel]
        xs.append(p.reference.depth[sel][:, None].astype(np.float64) / rays[:, 2:3] * rays)
        ns.append(p.reference.normals[sel].astype(np.float64))
        imgs.append(p.linear(p.led_images)[:, sel].astype(np.float64))
        oks.append(~p.saturated(p.led_images)[:, sel])
    x, n = np.concatenate(xs), np.concatenate(ns)
    img, ok = np.concatenate(imgs, axis=1), np.concatenate(oks, axis=1)
    fitted, stds, rms = [], [], []
    for i, led in enumerate(leds0):
        d = np.asarray(led.direction)
        p0 = np.concatenate(
            [
                np.zeros(3),
                [led.mu, np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])],
                led.position,
            ]
        )
        # initial intensity: least-squares scale of the nominal model
        geo = _model(p0, x, n)
        k0 = (geo * img[i] * ok[i]).sum(0) / np.maximum((geo * geo * ok[i]).sum(0), 1e-30)
        p0[:3] = np.log(np.maximum(k0, 1e-12))
        use = ok[i] & (img[i] > 0.01 * np.percentile(img[i], 99, axis=0))
        scale = float(np.percentile(img[i][use], 90)) if use.any() else 1.0

        def resid(params, i=i, use=use, scale=scale):
            return ((_model(params, x, n) - img[i]) / scale)[use]

        r0 = resid(p0)
        f_scale = max(3 * 1.4826 * float(np.median(np.abs(r0 - np.median(r0)))), 1e-3)
        res = least_squares(resid, p0, loss=loss, f_scale=f_scale, x_scale="jac", method="trf")
        J = res.jac
        dof = max(len(res.fun) - len(p0), 1)
        s2 = float(np.sum(res.fun**2) / dof)
        try:
            cov = np.linalg.inv(J.T @ J) * s2
            sd = np.sqrt(np.maximum(np.diag(cov), 0))
        except np.linalg.LinAlgError:
            sd = np.full(len(p0), np.nan)
        pr = res.x
        fitted.append(pr)
        stds.append(sd)
        rms.append(float(np.sqrt(np.mean(res.fun**2))) * scale)
    K = np.exp(np.array([f[:3] for f in fitted]))  # (L, 3)
    albedo = K.mean(axis=0)
    leds, std = [], []
    for f, sd, k in zip(fitted, stds, K):
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
    return LedCalibration(tuple(leds), tuple(float(a) for a in albedo), std, rms)
