"""Point LEDs with anisotropy and the near-light image model they produce.

The image model (Quéau et al., JMIV 2018), per LED i and colour channel c, at a surface point x with
unit normal n (pointing toward the camera) and albedo rho_c::

    I_ic(x) = Psi_ic * rho_c * (n_s . d)^mu * max(0, (x_s - x) . n) / |x_s - x|^3,   d = (x - x_s)/|x - x_s|

``rho`` here absorbs the Lambertian 1/pi, the camera gain and exposure: the capture stores linear
images, the solver recovers rho up to that scale. Everything is in millimetres, camera frame.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from .config import is_number
from .errors import ConfigError, ShapeError, check_kind
from .metrics import angle_deg
from .tolerances import MAX_LED_DISTANCE_MM, MAX_LED_INTENSITY, MAX_LED_MU, NORMAL_EPS

TRICOLOR_COLORS = np.eye(3)
"""Colour of each tri-colour group: group 0 red, 1 green, 2 blue."""
TRICOLOR_NAMES = ("red", "green", "blue")
"""Name of each tri-colour group (:func:`tricolor_groups`), for warnings."""


@dataclasses.dataclass(frozen=True)
class Led:
    """One point LED, in the camera frame."""

    position: tuple[float, float, float]
    """x_s, mm, camera frame."""
    direction: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """n_s, principal direction, unit vector, camera frame (normalised on construction)."""
    mu: float = 1.0
    """Anisotropy: radiant intensity falls off as (n_s . d)^mu (mu = 0 is isotropic)."""
    intensity: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Psi per colour channel (R, G, B) when lit white, in linear image units x mm^2."""

    def __post_init__(self):
        pos = _vec3(self.position, "led.position")
        d = _vec3(self.direction, "led.direction")
        norm = float(np.linalg.norm(d))
        if norm < NORMAL_EPS:
            raise ConfigError("led.direction must be a non-zero vector")
        psi = _vec3(self.intensity, "led.intensity")
        if not is_number(self.mu):  # else numpy's "ufunc 'isfinite' not supported" names no key
            raise ConfigError(f"led.mu must be a number, got {self.mu!r}")
        if any(p < 0 for p in psi) or not np.isfinite(self.mu) or self.mu < 0:
            raise ConfigError(f"led.intensity must be >= 0 and led.mu >= 0, got {psi}, {self.mu}")
        object.__setattr__(self, "position", tuple(pos))
        object.__setattr__(self, "direction", tuple(float(c) / norm for c in d))
        object.__setattr__(self, "intensity", tuple(psi))
        object.__setattr__(self, "mu", float(self.mu))

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: object) -> Led:
        if not isinstance(d, dict):
            raise ConfigError(f"each led must be a mapping with 'position', ..., got {d!r}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ConfigError(f"led has unknown keys {sorted(unknown)}; expected {sorted(known)}")
        if "position" not in d:
            raise ConfigError("led is missing 'position'")
        led = cls(**d)
        if problem := _implausible(led):
            raise ConfigError(problem)
        return led


def _implausible(led: Led) -> str | None:
    """What makes ``led``, read from a file (it may come from elsewhere), no LED of a visuotactile sensor: a value
    beyond :data:`~nlipscalib.core.tolerances.MAX_LED_DISTANCE_MM`, ``MAX_LED_MU`` or ``MAX_LED_INTENSITY``; None
    when it is one. Why here and not in the constructor: a fit's intermediate LEDs are not held to it."""
    distance = float(np.linalg.norm(led.position))
    if distance > MAX_LED_DISTANCE_MM:
        return f"led.position is {distance:.3g} mm from the camera, more than {MAX_LED_DISTANCE_MM:g} mm"
    if led.mu > MAX_LED_MU:
        return f"led.mu is {led.mu:.3g}, more than {MAX_LED_MU:g}"
    if max(led.intensity) > MAX_LED_INTENSITY:
        return f"led.intensity is {max(led.intensity):.3g}, more than {MAX_LED_INTENSITY:g}"
    return None


Leds = Sequence[Led]
"""The LEDs of one sensor, in order (LED i lights image i): a list or tuple of :class:`Led`."""


def tricolor_groups(n_leds: int) -> np.ndarray:
    """Colour group (0 red, 1 green, 2 blue) of each LED in the tri-colour image.

    LEDs are split into three contiguous runs of (nearly) equal size: 12 LEDs give 1-4 red,
    5-8 green, 9-12 blue as on NLiPsTac; other counts generalise the same way.

    Returns
    -------
    groups : (n_leds,) int
    """
    check_kind(n_leds, (int, np.integer), "n_leds", "a whole number of LEDs (board.n_leds)")
    if n_leds < 3:
        raise ConfigError(f"a tri-colour image needs at least 3 LEDs, got {n_leds}")
    return (np.arange(n_leds) * 3) // n_leds


def tricolor_colors(n_leds: int) -> np.ndarray:
    """Colour of each LED in the tri-colour image: its group's (:func:`tricolor_groups`) unit RGB.

    Returns
    -------
    colors : (n_leds, 3) float, 0 or 1 per channel -- e.g. times a PWM level for the LED controller.
    """
    return TRICOLOR_COLORS[tricolor_groups(n_leds)]


def led_geometry_mismatch(
    positions_a: ArrayLike, directions_a: ArrayLike, positions_b: ArrayLike, directions_b: ArrayLike
) -> str | None:
    """Why two LED sets are not one sensor's LEDs (count, or an LED more than ``tolerances.SAME_LED_MM`` /
    ``SAME_LED_DEG`` away from its counterpart, numbered from 1), or None when they match.

    Parameters
    ----------
    positions_a, positions_b : (L, 3) float, mm, camera frame
    directions_a, directions_b : (L, 3) float, unit, camera frame
    """
    from . import tolerances

    pa, pb = np.asarray(positions_a, float), np.asarray(positions_b, float)
    if pa.shape != pb.shape:
        return f"{len(pb)} LEDs against {len(pa)}"
    gap, turn = led_offsets(pa, directions_a, pb, directions_b)
    # written as "not within" so that an angle without a value (a zero-length direction: NaN) is a mismatch
    off = np.flatnonzero(~(gap <= tolerances.SAME_LED_MM) | ~(turn <= tolerances.SAME_LED_DEG))
    if off.size:
        i = int(off[0])
        return f"LED {i + 1} is {gap[i]:.2f} mm and {turn[i]:.1f} deg from its counterpart"
    return None


def led_offsets(
    positions_a: ArrayLike, directions_a: ArrayLike, positions_b: ArrayLike, directions_b: ArrayLike
) -> tuple[np.ndarray, np.ndarray]:
    """How far each LED of one set lies from its counterpart in another of the same count.

    Parameters
    ----------
    positions_a, positions_b : (L, 3) float, mm, camera frame
    directions_a, directions_b : (L, 3) float, unit, camera frame

    Returns
    -------
    gap : (L,) float64, mm -- distance between the positions.
    turn : (L,) float64, degrees -- angle between the directions (NaN for a zero-length one).
    """
    gap = np.linalg.norm(np.asarray(positions_a, float) - np.asarray(positions_b, float), axis=1)
    return gap, np.asarray(angle_deg(directions_a, directions_b), np.float64)


def led_arrays(leds: Leds) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stack LEDs into arrays.

    Returns
    -------
    positions : (L, 3) float64, mm, camera frame
    directions : (L, 3) float64, unit, camera frame
    mu : (L,) float64
    intensity : (L, 3) float64, Psi per channel
    """
    leds = list(leds)
    return (
        np.array([led.position for led in leds], dtype=np.float64).reshape(-1, 3),
        np.array([led.direction for led in leds], dtype=np.float64).reshape(-1, 3),
        np.array([led.mu for led in leds], dtype=np.float64),
        np.array([led.intensity for led in leds], dtype=np.float64).reshape(-1, 3),
    )


def led_shading(points: np.ndarray, normals: np.ndarray, leds: Leds, out: np.ndarray | None = None) -> np.ndarray:
    """Near-light shading factor of every LED at every point (the image model without albedo).

    Parameters
    ----------
    points : (..., 3) float, mm, camera frame
    normals : (..., 3) float, unit, camera frame, pointing toward the camera
    leds : sequence of Led, length L
    out : (L, ..., 3) float64 or None -- where to write the result (e.g. a block of rows of a larger array);
        each LED's part must be contiguous.

    Returns
    -------
    shading : (L, ..., 3) float64 -- Psi_ic (n_s.d)^mu max(0, cos) / r^2 per LED and channel;
        multiply by rho_c to get the linear image (``out`` when given).
    """
    points, normals = _points_and_normals(points, normals)
    pos, dirs, mu, psi = led_arrays(leds)
    flat_points, flat_normals = points.reshape(-1, 3), normals.reshape(-1, 3)
    shape = (len(pos),) + points.shape
    if out is None:
        out = np.empty(shape, dtype=np.float64)
    elif out.shape != shape or out.dtype != np.float64 or not all(part.flags.c_contiguous for part in out):
        raise ShapeError(f"out must be {shape} float64, contiguous per LED, got {out.shape} {out.dtype}")
    flat_out = [part.reshape(-1, 3) for part in out]  # views: each LED's part is contiguous
    for start in range(0, len(flat_points), SHADING_BLOCK):
        block = slice(start, start + SHADING_BLOCK)
        _shade_block(flat_points[block], flat_normals[block], pos, dirs, mu, psi, [o[block] for o in flat_out])
    return out


SHADING_BLOCK = 16384
"""Points per block of :func:`led_shading`: its temporaries (128 KiB each) then stay in the CPU's cache. Three
times faster than whole-image temporaries at 640x480 with 12 LEDs (0.12 against 0.38 s, the same numbers);
4096 to 65536 time alike."""


def led_falloff(points: np.ndarray, normals: np.ndarray, leds: Leds) -> np.ndarray:
    """:func:`led_shading` without the LEDs' per-channel intensity: ``led_shading = led_falloff[..., None] * Psi``
    (the same products, so the same bits).

    Why: the geometry is the same in the three channels; a reader that averages the shading over pixels (a
    surface's patches, :meth:`nlipscalib.solver.indirect.Surface.replaced`) averages this one plane per LED and
    multiplies by Psi after, a third of the work.

    Parameters
    ----------
    points : (..., 3) float, mm, camera frame
    normals : (..., 3) float, unit, camera frame, pointing toward the camera
    leds : sequence of Led, length L

    Returns
    -------
    (L, ...) float64 -- (n_s.d)^mu max(0, cos) / r^2 per LED.
    """
    points, normals = _points_and_normals(points, normals)
    pos, dirs, mu, _ = led_arrays(leds)
    flat_points, flat_normals = points.reshape(-1, 3), normals.reshape(-1, 3)
    out = np.empty((len(pos), len(flat_points)), dtype=np.float64)
    for start in range(0, len(flat_points), SHADING_BLOCK):
        block = slice(start, start + SHADING_BLOCK)
        x, n = _planes(flat_points[block], flat_normals[block])
        for i in range(len(pos)):
            out[i, block] = _falloff(x, n, pos[i], dirs[i], mu[i])
    return out.reshape((len(pos),) + points.shape[:-1])


def _points_and_normals(points: ArrayLike, normals: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """(..., 3) float64 points and normals of the same shape, or a ShapeError naming both shapes."""
    points = np.asarray(points, dtype=np.float64)
    normals = np.asarray(normals, dtype=np.float64)
    if points.shape[-1:] != (3,) or normals.shape != points.shape:
        raise ShapeError(f"points and normals must both be (..., 3), got {points.shape} and {normals.shape}")
    return points, normals


def _planes(points: np.ndarray, normals: np.ndarray) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """One contiguous (P,) plane per coordinate of (P, 3) points and normals: products summed over a length-3 last
    axis are several times slower in NumPy (this runs over every pixel of every LED image)."""
    return [np.ascontiguousarray(points[:, k]) for k in range(3)], [
        np.ascontiguousarray(normals[:, k]) for k in range(3)
    ]


def _falloff(
    x: list[np.ndarray],
    n: list[np.ndarray],
    pos: np.ndarray,
    direction: np.ndarray,
    mu: float,
    parts: dict | None = None,
) -> np.ndarray:
    """(P,) float64 -- one LED's (n_s.d)^mu max(0, cos) / r^2 at the points ``x`` with normals ``n`` (planes,
    :func:`_planes`); in place where possible. ``pos`` may be (J, 1) planes (J LEDs or points of a disk at once:
    then (J, P)). ``parts``, when given, gets the terms it is made of (d = x_s - x (3), r2, inv_r, cos_surface,
    cos_led): what its derivatives (:mod:`nlipscalib.core.leds_jacobian`) are made of."""
    d = [pos[k] - x[k] for k in range(3)]  # x_s - x
    r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    inv_r = 1.0 / np.sqrt(r2)
    cos_surface = d[0] * n[0] + d[1] * n[1] + d[2] * n[2]
    np.maximum(cos_surface * inv_r, 0.0, out=cos_surface)
    cos_led = d[0] * direction[0] + d[1] * direction[1] + d[2] * direction[2]  # n_s . (x_s - x), negated below
    np.maximum(cos_led * -inv_r, 0.0, out=cos_led)
    if parts is not None:  # cos_surface becomes the falloff below
        parts.update(d=d, r2=r2, inv_r=inv_r, cos_surface=cos_surface.copy(), cos_led=cos_led)
    if mu > 0:
        cos_surface *= cos_led if mu == 1.0 else cos_led**mu
    cos_surface /= r2
    return cos_surface


def _shade_block(
    points: np.ndarray,
    normals: np.ndarray,
    pos: np.ndarray,
    dirs: np.ndarray,
    mu: np.ndarray,
    psi: np.ndarray,
    out: list[np.ndarray],
) -> None:
    """:func:`led_shading` of (P, 3) points and normals into ``out``, L arrays (P, 3)."""
    x, n = _planes(points, normals)
    for i in range(len(pos)):
        np.multiply(_falloff(x, n, pos[i], dirs[i], mu[i])[:, None], psi[i], out=out[i])


# Radon's 7-point rule on the unit disk (exact for polynomials of degree 5): the centre, weight 1/4,
# and six points at radius sqrt(2/3), weight 1/8 each; weights sum to 1 (a mean over the disk)
_RING = np.sqrt(2.0 / 3.0) * np.stack([np.cos(np.arange(6) * np.pi / 3), np.sin(np.arange(6) * np.pi / 3)], axis=1)
DISK_RULE_POINTS = np.vstack([np.zeros((1, 2)), _RING])
"""(7, 2) points of the disk quadrature, unit disk."""
DISK_RULE_WEIGHTS = np.array([0.25] + [0.125] * 6)
"""(7,) their weights, summing to 1."""


def disk_shading(points: np.ndarray, normals: np.ndarray, leds: Leds, radius: float) -> np.ndarray:
    """The image model of LEDs that emit from a flat disk instead of a point (an LED package's light cup).

    Every area element dA of a disk of ``radius`` centred on ``x_s`` and perpendicular to ``n_s`` emits
    ``(Psi / A) (n_s . d)^mu dA`` (the twin's extended LEDs, docs/twin.md): the shading is the mean of
    :func:`led_shading` over the disk, integrated with Radon's 7-point rule. Its error is of the order
    of (radius / distance)^6 (a 3.6 mm disk 8-15 mm from the gel: below 1e-4 of the shading, tested
    against the closed form on the axis), so the point model is the limit ``radius = 0``.

    Parameters
    ----------
    points, normals : (..., 3) float, mm / unit, camera frame (as :func:`led_shading`)
    leds : sequence of Led, length L -- position = the disk's centre, direction = its axis.
    radius : float, mm, >= 0.

    Returns
    -------
    shading : (L, ..., 3) float64 -- as :func:`led_shading`.
    """
    leds = tuple(leds)
    if radius == 0 or not leds:
        _check_radius(radius)
        return led_shading(points, normals, leds)
    psi = led_arrays(leds)[3]
    mean = disk_falloff(points, normals, leds, radius)
    return mean[..., None] * psi.reshape((len(leds),) + (1,) * (mean.ndim - 1) + (3,))


def _check_radius(radius: float) -> None:
    if not radius >= 0:
        raise ConfigError(f"LED disk radius must be >= 0 mm, got {radius}")


def disk_falloff(points: np.ndarray, normals: np.ndarray, leds: Leds, radius: float) -> np.ndarray:
    """:func:`disk_shading` without the LEDs' per-channel intensity (as :func:`led_falloff` of
    :func:`led_shading`): ``disk_shading = disk_falloff[..., None] * Psi``; :func:`led_falloff` at ``radius`` 0.

    Parameters
    ----------
    points, normals : (..., 3) float, mm / unit, camera frame; leds : sequence of Led, length L (disk centres and
    axes); radius : float, mm, >= 0.

    Returns
    -------
    (L, ...) float64 -- the mean over the disk of (n_s.d)^mu max(0, cos) / r^2 per LED.
    """
    _check_radius(radius)
    leds = tuple(leds)
    if radius == 0 or not leds:
        return led_falloff(points, normals, leds)
    points, normals = _points_and_normals(points, normals)
    pos, dirs, mu, _ = led_arrays(leds)
    flat_points, flat_normals = points.reshape(-1, 3), normals.reshape(-1, 3)
    # the weighted mean of the falloff, then times Psi (as led_falloff): arrays, not an Led per quadrature point
    # (building and validating 7 of them per evaluation was 12 % of a disk calibration's CPU, s29-diskcost)
    mean = np.zeros((len(pos), len(flat_points)), dtype=np.float64)
    centres = [_disk_points(p, d, radius) for p, d in zip(pos, dirs)]
    for start in range(0, len(flat_points), SHADING_BLOCK):
        block = slice(start, start + SHADING_BLOCK)
        x, n = _planes(flat_points[block], flat_normals[block])
        for i in range(len(pos)):
            for c, w in zip(centres[i], DISK_RULE_WEIGHTS):
                mean[i, block] += w * _falloff(x, n, c, dirs[i], mu[i])
    return mean.reshape((len(pos),) + points.shape[:-1])


def disk_points(positions: np.ndarray, directions: np.ndarray, radius: float) -> np.ndarray:
    """The quadrature points of each LED's emitting disk (:func:`disk_shading`'s rule, weights
    :data:`DISK_RULE_WEIGHTS`): the NLiPs solver's disk LEDs shade as those points' weighted mean.

    Parameters
    ----------
    positions, directions : (L, 3) float -- the disks' centres (mm) and unit axes, camera frame (:func:`led_arrays`).
    radius : float, mm, > 0.

    Returns
    -------
    (L, 7, 3) float64, mm, camera frame.
    """
    if not radius > 0:
        raise ConfigError(f"LED disk radius must be > 0 mm, got {radius}")
    return np.stack([_disk_points(p, d, radius) for p, d in zip(positions, directions)]).reshape(-1, 7, 3)


def _disk_points(centre: np.ndarray, axis: np.ndarray, radius: float) -> np.ndarray:
    """(7, 3) float64, mm -- the quadrature points (:data:`DISK_RULE_POINTS`) of the disk of ``radius`` centred on
    ``centre`` and perpendicular to the unit ``axis``."""
    u = np.cross(axis, _disk_helper(axis))
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    return centre + radius * (DISK_RULE_POINTS[:, :1] * u + DISK_RULE_POINTS[:, 1:] * v)


def _disk_helper(axis: np.ndarray) -> np.ndarray:
    """(3,) the fixed vector e of :func:`_disk_points`' frame (u along axis x e): one far from the axis."""
    return np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])


def _vec3(v: object, name: str) -> tuple[float, float, float]:
    if not isinstance(v, (list, tuple, np.ndarray)) or not all(is_number(c) for c in np.ravel(np.asarray(v, object))):
        raise ConfigError(f"{name} must be 3 finite numbers, got {v!r}")
    arr = np.asarray(v, dtype=np.float64)
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise ConfigError(f"{name} must be 3 finite numbers, got {v!r}")
    return tuple(float(c) for c in arr)
