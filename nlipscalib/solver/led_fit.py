"""The LED model's fit (:func:`nlipscalib.solver.calibrate.calibrate_leds`): one capture's samples on the
reference surface, the robust non-linear least squares of each LED's parameters (a point LED, or a disk of a given
radius), and the LEDs in the gauge mean Psi = 1 per channel."""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.blas import blas_threads
from ..core.camera import depth_to_points
from ..core.capture import Press
from ..core.errors import CaptureError, ConfigError
from ..core.leds import Led, Leds, disk_shading
from ..core.leds_jacobian import falloff_gradient
from ..core.robust_scale import mad_scale
from .outline import gel_outline
from .press_checks import _other_sensor, optics_difference

if TYPE_CHECKING:  # named in hints only: scipy is imported when an LED is fitted
    from scipy.optimize import OptimizeResult

log = logging.getLogger(__name__)


def _unit(theta: float, phi: float):
    return np.array([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])


def _led(params: np.ndarray) -> Led:
    """The Led a parameter vector (log K (3), mu, polar, azimuth of n_s, x_s (3)) stands for."""
    with np.errstate(over="ignore"):  # an overflow is refused by Led, then said once (_ran_off_said), not numpy's
        intensity = tuple(np.exp(params[:3]))
    return Led(tuple(params[6:9]), tuple(_unit(params[4], params[5])), max(float(params[3]), 0.0), intensity)


@dataclasses.dataclass(frozen=True)
class LedModel:
    """The LED image model of one LED's parameter vector (log K (3), mu, polar, azimuth of n_s, x_s (3)): a point
    (``core.leds.led_shading``) or a disk of ``radius`` (``core.leds.disk_shading``), with its Jacobian."""

    radius: float = 0.0
    """The LED's emitting disk's radius, mm; 0: a point LED."""

    def __call__(self, params: np.ndarray, x: np.ndarray, n: np.ndarray) -> np.ndarray:
        """(N, 3) model images of one LED at the points ``x`` (N, 3) with normals ``n`` (N, 3), mm, camera frame."""
        return disk_shading(x, n, (_led(params),), self.radius)[0]

    def gradient(self, params: np.ndarray, x: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(falloff (N,), its derivatives (N, 6) with respect to params[3:9]: mu, polar, azimuth, x_s) -- the model
        images are exp(log K) times the falloff per channel (``core.leds_jacobian.falloff_gradient``), so the log K
        columns of their Jacobian are the images themselves, the others these times K (:meth:`_LedProblem.jacobian`).

        Why not finite differences (scipy's default): 9 model evaluations a trf step, most of a disk fit's CPU
        (s29-diskcost); this costs 2.2-2.4 (benchmarks/RESULTS.md, s31-diskjac)."""
        falloff, gradient = falloff_gradient(x, n, _led(params), self.radius)
        polar, azimuth = params[4:6]
        # d n_s / d (polar, azimuth) of _unit
        turn = np.array(
            [
                [np.cos(polar) * np.cos(azimuth), -np.sin(polar) * np.sin(azimuth)],
                [np.cos(polar) * np.sin(azimuth), np.sin(polar) * np.cos(azimuth)],
                [-np.sin(polar), 0.0],
            ]
        )
        derivative = np.empty((len(x), 6))
        derivative[:, 0] = gradient[:, 0] if params[3] >= 0 else 0.0  # _led clips mu at 0
        derivative[:, 1:3] = gradient[:, 1:4] @ turn
        derivative[:, 3:6] = gradient[:, 4:7]
        return falloff, derivative


Model = LedModel
"""An LED image model: (params (9,), points (N, 3), normals (N, 3)) -> (N, 3) images, and its Jacobian."""

point_model = LedModel()
"""The LED image model of a point LED: ``core.leds.led_shading``, the one LED image model."""


def disk_model(radius: float) -> LedModel:
    """``point_model`` for an LED emitting from a disk of ``radius`` mm (``core.leds.disk_shading``)."""
    return LedModel(radius)


@dataclasses.dataclass(frozen=True)
class Samples:
    """The samples of every capture, pooled: what the LED fits run on."""

    x: np.ndarray
    """(N, 3) float64, mm, camera frame -- the samples' points on the reference surface."""
    n: np.ndarray
    """(N, 3) float64, unit, camera frame -- their normals."""
    img: np.ndarray
    """(L, N, 3) float64, linear image units -- the LED images at the samples."""
    ok: np.ndarray
    """(L, N, 3) bool -- usable (not saturated) samples."""
    selections: list
    """Per capture, (H, W) bool -- its pixels among the samples, in order."""


def capture_samples(
    p: Press, first: Press, count: int, stride: int, left_out: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Points, normals, linear images, usable flags and the pixel selection of one capture (without the pixels
    ``left_out``, (H, W) bool, when given)."""
    if p.reference is None:
        raise CaptureError(f"{p.folder}: LED calibration needs the undeformed reference (reference.npz)")
    if p.camera != first.camera or len(p.leds) != count:
        why = optics_difference(p, first) or f"it has {len(p.leds)} LEDs, the starting LEDs {count}"
        raise CaptureError(f"{p.folder}: not a capture of the sensor of {first.folder} ({why})")
    # the LED ring and the dome too: two sensors of one camera were fitted together and refused as "a press"
    why = _other_sensor(first, p) if p is not first else None
    if why:
        raise CaptureError(f"{p.folder}: not a capture of the sensor of {first.folder} ({why})")
    valid = np.isfinite(p.reference.depth)
    sub = np.zeros_like(valid)
    sub[::stride, ::stride] = True
    # the gel's outline (a view past the gel) left out: the robust LED fits shrug its partly covered pixels off, but
    # the reflectance profile's plain squared residual was a tenth theirs, and its least moved to 1.06x the true
    # reflectance and the LED disks 0.056 mm along the camera's axis (benchmarks/RESULTS.md, s36-diskfit)
    sel = valid & ~gel_outline(valid) & sub
    if left_out is not None:
        sel &= ~left_out
    rays = p.camera.rays[sel]
    x = depth_to_points(p.reference.depth[sel].astype(np.float64), rays)
    n = p.reference.normals[sel].astype(np.float64)
    # the press's linear images, made once for it (nothing_to_fit, _led_noise and fit_indirect read them too); the
    # usable samples are the press's own (saturated, and a band an LED image holds none of its light in:
    # calibration_bands), as the indirect term's fit reads them
    return x, n, p.linear_led_images[:, sel].astype(np.float64), ~p.saturated_led_images[:, sel], sel


def fit_leds(
    leds: Leds,
    x: np.ndarray,
    n: np.ndarray,
    img: np.ndarray,
    ok: np.ndarray,
    loss: str,
    model: Model = point_model,
) -> list[tuple[np.ndarray, np.ndarray, float]]:
    """[(params, std, rms)] per LED: robust non-linear least squares of ``model`` from ``leds``.

    The unknowns are the parameters' offsets from the start: trf's first trust region is the start's norm in its
    scaled units (scipy's ``Delta = norm(x0 * scale_inv)``), so with positions in camera coordinates (the ring 9 mm
    off the axis) its first step could carry an LED 9.8 mm, behind the camera, into another minimum: on the
    bounce-free twin at 80x60, from LEDs 0.4-0.8 mm / 5-10 deg off, 6 of 24 starts left one LED 11-97 deg and
    4-7 mm off at a median quality like a good fit's (160x120 with noise: that LED 1.08x the noise, the others
    0.99-1.02x). From offsets the first region is 1 (its norm when zero): none of them (benchmarks/RESULTS.md).

    An LED whose fit still ends far above the others' misfit (:func:`_stuck`) is fitted again from other axes
    (:meth:`_LedProblem.restarts`) and the least misfit kept: from LEDs 2 mm / 80 deg off their design one LED stopped
    6.9 mm / 65 deg off (benchmarks/RESULTS.md, s27-ledstarts)."""
    out, costs = {}, {}
    # one BLAS thread: trf's SVD of each step's (N, 9) Jacobian took 4-6x the CPU on 2 threads of a loaded
    # machine, the same bits (s17-d, benchmarks/RESULTS.md)
    with blas_threads(1):
        problems = [_LedProblem.of(led, img[i], ok[i], x, n, model) for i, led in enumerate(leds)]
        for i, problem in enumerate(problems):
            if problem.use.any():  # an LED without a usable sample (its image a stale copy) is held: held_fit
                res = _ran_off_said(problem.solve, problem.p0, loss, i)
                costs[i] = problem.misfit(res)
                out[i] = res
        level = float(np.median(list(costs.values())))
        for k in _stuck(list(costs.values())):
            i = list(costs)[k]
            log.info("LED %d: fit %.1fx the median LED's misfit; fitted again from other axes", i + 1, costs[i] / level)
            tries = [out[i]] + [_ran_off_said(problems[i].solve, p, loss, i) for p in problems[i].restarts()]
            out[i] = min(tries, key=problems[i].misfit)
    fitted = {i: problems[i].result(res) for i, res in out.items()}
    return [fitted[i] if i in fitted else held_fit(led, fitted, leds) for i, led in enumerate(leds)]


def held_fit(
    led: Led, fitted: dict[int, tuple[np.ndarray, np.ndarray, float]], leds: Leds
) -> tuple[np.ndarray, np.ndarray, float]:
    """(params, std, rms) of an LED held at its start ``led`` (no usable sample to fit it on: every capture's image
    of it repeats the image before it, :func:`.calibration_bands.without_repeated_images`): its place, axis and mu
    as started, its brightness its start's relative to the fitted LEDs' (``fitted``: 0-based LED -> its fit; ``leds``
    their starts), per channel the median fitted K over start Psi, so that the gauge (mean Psi = 1) keeps its share;
    std and rms NaN (nothing was fitted)."""
    d = np.asarray(led.direction)
    scale = np.median([np.exp(f[0][:3]) / np.maximum(leds[i].intensity, 1e-12) for i, f in fitted.items()], axis=0)
    params = np.concatenate(
        [
            np.log(np.maximum(np.multiply(led.intensity, scale), 1e-12)),
            [led.mu, np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])],
            led.position,
        ]
    )
    return params, np.full(9, np.nan), float("nan")


class LedFitRanOff(CaptureError):
    """An LED's fit left finite numbers (its brightness or place overflowed): ``led`` the LED, 0-based."""

    def __init__(self, led: int) -> None:
        super().__init__(f"the fit of LED {led + 1} ran off (not finite)")
        self.led = led


def _ran_off_said(
    solve: Callable[[np.ndarray, str], OptimizeResult], p0: np.ndarray, loss: str, led: int
) -> OptimizeResult:
    """``solve(p0, loss)``, or :class:`LedFitRanOff` naming the LED when a step of it left finite numbers.

    Why: a trf step that overflows exp(log K) made the Led (``core.leds``) refuse "led.intensity must be 3 finite
    numbers", a line that named neither the capture nor the LED (the twin's LED 5 dark in rows 0-129, s31-darkleft);
    :func:`nlipscalib.solver.calibrate.calibrate_leds` says which and why."""
    try:
        return solve(p0, loss)
    except ConfigError as error:
        raise LedFitRanOff(led) from error


RESTART_TILT_DEG = 45.0
"""Tilt, deg, of the axes :meth:`_LedProblem.restarts` starts a stuck LED's fit from, around its starting axis."""
STUCK_MISFIT = 2.0
"""An LED whose fit ends with this many times the median LED's relative misfit (:meth:`_LedProblem.misfit`) is
fitted again from other axes (:func:`_stuck`). Why 2: a converged fit's LEDs lie within 0.97-1.13x the noise on the
twin's references (the table in :func:`.calibration_quality.fit_quality`); the wrong minima found from LEDs 2 mm /
80 deg or 4 mm / 40 deg off their design ended 1.6-92x (benchmarks/RESULTS.md, s27-ledstarts)."""


def _stuck(costs: Sequence[float]) -> list[int]:
    """The LEDs (indices) whose misfit is more than :data:`STUCK_MISFIT` times the median LED's: each LED sees the
    same surface with the same camera, so one far above the rest has stopped in a wrong minimum (or is not the
    model's LED: then the restarts change nothing and the quality check says so)."""
    level = float(np.median(costs))
    return [i for i, c in enumerate(costs) if c > STUCK_MISFIT * level]


@dataclasses.dataclass(frozen=True)
class _LedProblem:
    """One LED's robust least squares: the starting parameters and what the residual is scaled by."""

    p0: np.ndarray
    """(9,) the starting parameters: log K (3, from a linear fit of the start's shading), mu, polar, azimuth, x_s."""
    img: np.ndarray
    """(N, 3) the LED's linear samples."""
    use: np.ndarray
    """(N, 3) bool, :func:`fit_samples`."""
    scale: float
    """90th percentile of the used samples: the residual's unit."""
    x: np.ndarray
    n: np.ndarray
    model: Model
    rows: tuple[np.ndarray, np.ndarray]
    """(M,) int each: the sample and channel of each residual row (``np.nonzero(use)``)."""

    @classmethod
    def of(cls, led: Led, img: np.ndarray, ok: np.ndarray, x: np.ndarray, n: np.ndarray, model: Model) -> _LedProblem:
        d = np.asarray(led.direction)
        p0 = np.concatenate(
            [
                np.log(np.maximum(led.intensity, 1e-12)),
                [led.mu, np.arccos(np.clip(d[2], -1, 1)), np.arctan2(d[1], d[0])],
                led.position,
            ]
        )
        use = fit_samples(img, ok)
        scale = float(np.percentile(img[use], 90)) if use.any() else 1.0
        return cls(_scaled(p0, img, ok, x, n, model), img, use, scale, x, n, model, np.nonzero(use))

    def residual(self, params: np.ndarray) -> np.ndarray:
        return ((self.model(params, self.x, self.n) - self.img) / self.scale)[self.use]

    def jacobian(self, params: np.ndarray) -> np.ndarray:
        """(M, 9) -- :meth:`residual`'s derivatives (a step's are the parameters': the unknowns are offsets), its
        rows the used samples' channels in :meth:`residual`'s order."""
        sample, channel = self.rows
        falloff, derivative = self.model.gradient(params, self.x, self.n)
        k = np.exp(params[:3])[channel] / self.scale  # (M,): each row's K, in the residual's unit
        jac = np.zeros((len(sample), 9))
        jac[np.arange(len(sample)), channel] = falloff[sample] * k  # d/d log K_c: the row's model image
        np.multiply(derivative[sample], k[:, None], out=jac[:, 3:])
        return jac

    def solve(self, p0: np.ndarray, loss: str) -> OptimizeResult:
        """scipy's result of the fit from ``p0``, its unknowns the offsets from it (:func:`fit_leds`' why); ``p0``
        kept on it as ``start``."""
        from scipy.optimize import least_squares  # imported here: ~0.5 s that `nlips solve` never needs

        def resid(step: np.ndarray) -> np.ndarray:
            return self.residual(p0 + step)

        def jac(step: np.ndarray) -> np.ndarray:
            return self.jacobian(p0 + step)

        f_scale = max(3 * mad_scale(resid(np.zeros_like(p0))), 1e-3)
        res = least_squares(resid, np.zeros_like(p0), jac=jac, loss=loss, f_scale=f_scale, x_scale="jac", method="trf")
        res.start = p0
        return res

    def misfit(self, res: OptimizeResult) -> float:
        """Robust scale (MAD) of the fit's residual: comparable between LEDs (each in its own brightness unit) and
        between starts (the robust loss's own cost is not: its f_scale follows each start's residual)."""
        return float(mad_scale(res.fun))

    def restarts(self) -> list[np.ndarray]:
        """Starts for a stuck LED (:func:`_stuck`): its start with the axis tilted by :data:`RESTART_TILT_DEG` toward
        4 azimuths, and with the axis toward its samples' brightness-weighted centroid (where an LED's light
        lands is the first thing its images say of its axis), each with the intensity fitted anew."""
        polar, azimuth = self.p0[4:6]
        axis = _unit(polar, azimuth)
        side = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        side /= np.linalg.norm(side)
        tilt = np.radians(RESTART_TILT_DEG)
        axes = []
        for turn in np.radians([0, 90, 180, 270]):
            across = np.cos(turn) * side + np.sin(turn) * np.cross(axis, side)
            axes.append(np.cos(tilt) * axis + np.sin(tilt) * across)
        weight = np.where(self.use, self.img, 0.0).sum(1)
        if weight.sum() > 0:
            toward = (weight[:, None] * self.x).sum(0) / weight.sum() - self.p0[6:9]
            axes.append(toward / np.linalg.norm(toward))
        starts = []
        for a in axes:
            p = self.p0.copy()
            p[4:6] = np.arccos(np.clip(a[2], -1, 1)), np.arctan2(a[1], a[0])
            starts.append(_scaled(p, self.img, self.use, self.x, self.n, self.model))
        return starts

    def result(self, res: OptimizeResult) -> tuple[np.ndarray, np.ndarray, float]:
        """(params, std, rms) of the fit ``res``: std from its Jacobian, rms in linear image units."""
        dof = max(len(res.fun) - len(res.x), 1)
        s2 = float(np.sum(res.fun**2) / dof)
        try:
            sd = np.sqrt(np.maximum(np.diag(np.linalg.inv(res.jac.T @ res.jac) * s2), 0))
        except np.linalg.LinAlgError:
            sd = np.full(len(res.x), np.nan)
        return res.start + res.x, sd, float(np.sqrt(np.mean(res.fun**2))) * self.scale


def summed_squares(fitted: Sequence[tuple[np.ndarray, np.ndarray, float]]) -> float:
    """The LED fits' squared RMS residuals summed (image units squared; per LED as :func:`fit_leds` returns them),
    over the LEDs fitted: an LED held at its start (:func:`held_fit`, rms NaN) is left out, as it was of the fit (its
    NaN turned every reflectance tried into NaN, and the bounded search then chose one of them blindly)."""
    return float(sum(f[2] ** 2 for f in fitted if not np.isnan(f[2])))


def _scaled(p0: np.ndarray, img: np.ndarray, ok: np.ndarray, x: np.ndarray, n: np.ndarray, model: Model) -> np.ndarray:
    """``p0`` with log K the linear least-squares scale of its shading to the images (per channel)."""
    p0 = p0.copy()
    geo = model(p0, x, n) / np.exp(p0[:3])
    k0 = (geo * img * ok).sum(0) / np.maximum((geo * geo * ok).sum(0), 1e-30)
    p0[:3] = np.log(np.maximum(k0, 1e-12))
    return p0


def to_leds(
    fitted: Sequence[tuple[np.ndarray, np.ndarray, float]],
) -> tuple[tuple[Led, ...], tuple[float, ...], list[dict]]:
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


def fit_samples(img: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(N, 3) bool -- the samples one LED is fitted on: usable and lit (above 1 % of its 99th percentile per
    channel); :func:`.calibration_quality.fit_quality` judges the fit on the same samples.

    img : (N, 3) float -- that LED's samples, linear; ok : (N, 3) bool -- usable.
    """
    return ok & (img > 0.01 * np.percentile(img, 99, axis=0))
