"""The derivatives of one LED's falloff (the image model of :mod:`nlipscalib.core.leds`, point or disk) with respect to
its parameters: what the LED fit (:mod:`nlipscalib.solver.led_fit`) hands its least squares instead of finite
differences (9 model evaluations a step).

The value is the model's own (:func:`~nlipscalib.core.leds._falloff`, at the disk's quadrature points); the
derivatives are those of its logarithm, from the terms it is made of: with d = x_s - x, r = |d|, the cosines
c_s = d.n / r and c_l = -d.n_s / r, and f = c_s c_l^mu / r^2, where f > 0::

    df/dx_s = f (n / (r c_s) - mu n_s / (r c_l) - (3 + mu) d / r^2)
    df/dn_s = -f mu d / (r c_l)
    df/dmu  = f log(c_l)

and 0 where f is 0 (the kinks at c_s = 0 and c_l = 0 are the model's: its finite differences see them too). A
disk's quadrature points move with its centre and turn with its axis (:func:`~nlipscalib.core.leds._disk_points`),
so its derivative with respect to the axis also carries each point's position derivative through that turn.
"""

from __future__ import annotations

import numpy as np

from .leds import (
    DISK_RULE_POINTS,
    DISK_RULE_WEIGHTS,
    Led,
    _disk_helper,
    _disk_points,
    _falloff,
    _planes,
    _points_and_normals,
)

GRADIENT_PARAMETERS = ("mu", "axis_x", "axis_y", "axis_z", "position_x", "position_y", "position_z")
"""The columns of :func:`falloff_gradient`'s derivative, in order."""
GRADIENT_BLOCK = 32768
"""Values (points x quadrature points) per block of :func:`falloff_gradient`: its temporaries are (quadrature
points, points) arrays. On 9,600 samples of the 640x480 reference, one BLAS thread (as the LED fit runs), a 3.6 mm
disk's gradient took 2.2-3.0 ms in blocks of 2,048-4,096 values, 1.7-1.8 ms at 8,192 and 1.5 ms from 32,768 to the
whole set in one block (one disk evaluation 0.63-0.66 ms); a point's 0.34-0.39 ms from 16,384 up (one evaluation
0.16 ms; benchmarks/RESULTS.md, s31-diskjac)."""


def falloff_gradient(
    points: np.ndarray, normals: np.ndarray, led: Led, radius: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """One LED's falloff (:func:`~nlipscalib.core.leds.led_falloff`, or with ``radius`` the disk mean of
    :func:`~nlipscalib.core.leds.disk_shading` without Psi) and its derivatives.

    Parameters
    ----------
    points : (N, 3) float, mm, camera frame
    normals : (N, 3) float, unit, camera frame, pointing toward the camera
    led : Led -- its intensity is not used (the shading is Psi times the falloff).
    radius : float, mm, >= 0 -- the disk's radius (0: the point LED).

    Returns
    -------
    falloff : (N,) float64 -- (n_s.d)^mu max(0, cos) / r^2, mm^-2 (the disk's mean when ``radius`` > 0): the
        model's within rounding (the disk mean is summed in another order).
    gradient : (N, 7) float64 -- its derivatives with respect to :data:`GRADIENT_PARAMETERS`: mu; the axis n_s as
        a free 3-vector (the model does not normalise it: only its part across n_s is a turn of the axis); the
        position x_s (the disk's centre), per mm.
    """
    points, normals = _points_and_normals(points, normals)
    pos, axis, mu = np.asarray(led.position), np.asarray(led.direction), led.mu
    if radius > 0:
        centres, weights = _disk_points(pos, axis, radius), DISK_RULE_WEIGHTS
        # turns[k, m, j] = w_j d c_jm / d n_sk: the quadrature points' turn with the axis, weighted
        turns = np.einsum("j,jmk->kmj", weights, _disk_turns(axis, radius))
    else:
        centres, weights, turns = pos[None], np.ones(1), None
    value, gradient = np.empty(len(points)), np.empty((len(points), 7))
    size = max(GRADIENT_BLOCK // len(centres), 1)
    for start in range(0, len(points), size):
        block = slice(start, start + size)
        x, n = _planes(points[block], normals[block])
        value[block], gradient[block] = _block_gradient(x, n, centres, weights, turns, axis, mu)
    return value, gradient


def _block_gradient(
    x: list[np.ndarray],
    n: list[np.ndarray],
    centres: np.ndarray,
    weights: np.ndarray,
    turns: np.ndarray | None,
    axis: np.ndarray,
    mu: float,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`falloff_gradient` of one block of points (planes, :func:`_planes`), all J quadrature points
    (``centres`` (J, 3), ``weights`` (J,)) at once as (J, P) arrays; ``turns`` (3, 3, J) or None for a point."""
    parts: dict = {}
    f = _falloff([c[None] for c in x], [c[None] for c in n], centres.T[:, :, None], axis, mu, parts)
    d, r2, inv_r, cos_s, cos_l = (parts[k] for k in ("d", "r2", "inv_r", "cos_surface", "cos_led"))
    f_r = f * inv_r
    over_s = np.divide(f_r, cos_s, out=np.zeros_like(f), where=cos_s > 0)  # f / (r c_s)
    over_l = np.divide(f_r * mu, cos_l, out=np.zeros_like(f), where=cos_l > 0)  # f mu / (r c_l)
    over_r2 = f * ((3.0 + mu) / r2)
    log_l = np.log(cos_l, out=np.zeros_like(f), where=cos_l > 0)
    d_pos = np.empty((3,) + f.shape)  # (3, J, P): df_j / dc_j
    for k in range(3):
        np.multiply(over_s, n[k], out=d_pos[k])
        d_pos[k] -= over_l * axis[k]
        d_pos[k] -= over_r2 * d[k]
    out = np.empty((7, f.shape[1]))
    out[0] = weights @ (f * log_l)
    out[4:7] = weights @ d_pos
    # df/dn_s = -f mu d / (r c_l) summed over the points: d_j = c_j - x, so sum_j w_j over_l_j (c_j - x)
    held = weights @ over_l
    out[1:4] = -((weights[:, None] * centres).T @ over_l - np.stack(x) * held)
    if turns is not None:
        out[1:4] += turns.reshape(3, -1) @ d_pos.reshape(-1, f.shape[1])
    return weights @ f, out.T


def _disk_turns(axis: np.ndarray, radius: float) -> np.ndarray:
    """(7, 3, 3) float64 -- d c_j / d n_s of each quadrature point c_j of :func:`_disk_points` (its frame follows
    the axis: u = (n_s x e) / |n_s x e|, v = n_s x u, e fixed: :func:`_disk_helper`)."""
    helper = _disk_helper(axis)
    w = np.cross(axis, helper)
    u = w / np.linalg.norm(w)
    du = (np.eye(3) - np.outer(u, u)) / np.linalg.norm(w) @ -_cross_matrix(helper)  # d(n_s x e) = -[e]x dn_s
    dv = -_cross_matrix(u) + _cross_matrix(axis) @ du  # d(n_s x u) = dn_s x u + n_s x du
    a, b = DISK_RULE_POINTS[:, 0], DISK_RULE_POINTS[:, 1]
    return radius * (a[:, None, None] * du + b[:, None, None] * dv)


def _cross_matrix(a: np.ndarray) -> np.ndarray:
    """(3, 3) [a]x, the matrix of a x b."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
