"""Exact-data fixtures: an analytic dome with a smooth spherical or flat-faced dent, imaged with the
project's own forward model (core.leds.led_shading) on a small fisheye camera.

Geometry (camera frame, mm): hemisphere of radius 15 centred at (0, 0, 3) (camera 3 mm below the base),
12 LEDs on a ring of radius 9 in the base plane tilted 20 deg toward the axis (the default scene).
The gel surface is the boundary of (dome ball minus indenter), blended with a smooth maximum so it is
C1 like a real gel; depth by ray marching its signed distance, normals from its gradient.
"""

from __future__ import annotations

import math

import numpy as np

from nlipscalib.core import Camera, GroundTruth, Led, Reference, SensorResponse, led_shading, write_press

CENTRE = np.array([0.0, 0.0, 3.0])
RADIUS = 15.0
BASE_Z = 3.0
RESPONSE = SensorResponse(bit_depth=16, black_level=256.0, white_level=65520.0)


def camera(width=96, height=72) -> Camera:
    return Camera.from_fov(width, height, 100.0, "fisheye", (0.05, -0.01, 0.0, 0.0))


def ring_leds(count=12, mu=1.0, tilt_deg=20.0, jitter=None) -> tuple[Led, ...]:
    """Default-scene LEDs; ``jitter`` (a seed) varies Psi, mu and tilt per LED for calibration tests."""
    rng = np.random.default_rng(jitter) if jitter is not None else None
    leds = []
    for k in range(count):
        a = 2 * math.pi * k / count
        t = math.radians(tilt_deg + (rng.uniform(-5, 5) if rng else 0.0))
        d = (-math.sin(t) * math.cos(a), -math.sin(t) * math.sin(a), math.cos(t))
        psi = tuple(rng.uniform(0.8, 1.2, 3)) if rng else (1.0, 1.0, 1.0)
        m = mu * (rng.uniform(0.7, 1.4) if rng else 1.0)
        leds.append(Led((9 * math.cos(a), 9 * math.sin(a), BASE_Z), d, m, psi))
    return tuple(leds)


def _frame(direction):
    e3 = np.asarray(direction, float) / np.linalg.norm(direction)
    tmp = np.array([1.0, 0, 0]) if abs(e3[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(e3, tmp)
    e1 /= np.linalg.norm(e1)
    return np.stack([e1, np.cross(e3, e1), e3])  # rows


def _smax(a, b, k):
    h = np.clip(0.5 + 0.5 * (a - b) / k, 0, 1)
    return a * h + b * (1 - h) + k * h * (1 - h)


def indenter_sdf(kind: str, depth: float, tilt_deg: float = 15.0):
    """Signed distance of the indenter (negative inside), pressed ``depth`` mm into the dome."""
    if kind == "none":
        return None
    tilt = math.radians(tilt_deg)
    axis = np.array([math.sin(tilt) * math.cos(0.7), math.sin(tilt) * math.sin(0.7), math.cos(tilt)])
    if kind == "sphere":
        ri = 4.0
        c = CENTRE + (RADIUS + ri - depth) * axis
        return lambda x: np.linalg.norm(x - c, axis=-1) - ri
    if kind == "cube":
        half, round_r = 2.5, 1.2
        c = CENTRE + (RADIUS + half + round_r - depth) * axis
        rot = _frame(axis)
        ang = math.radians(20)
        spin = np.array([[math.cos(ang), -math.sin(ang), 0], [math.sin(ang), math.cos(ang), 0], [0, 0, 1]])
        rot = spin @ rot

        def box(x):
            p = np.abs((x - c) @ rot.T) - half
            outside = np.linalg.norm(np.maximum(p, 0), axis=-1)
            inside = np.minimum(p.max(axis=-1), 0)
            return outside + inside - round_r

        return box
    raise ValueError(kind)


def surface(cam: Camera, kind: str = "sphere", depth: float = 1.5, blend: float = 1.0):
    """Depth (H, W), points (H, W, 3), normals (H, W, 3), valid (H, W) of the (dented) dome."""
    omega = cam.rays
    ind = indenter_sdf(kind, depth)

    def f(x):
        dome = np.linalg.norm(x - CENTRE, axis=-1) - RADIUS
        return dome if ind is None else _smax(dome, -ind(x), blend)

    t = np.zeros(omega.shape[:2])
    for _ in range(400):
        val = f(t[..., None] * omega)
        t = t - 0.6 * val  # val < 0 inside the gel: step outward by a safe fraction
    for _ in range(5):  # Newton polish with a numerical directional derivative
        x = t[..., None] * omega
        d = (f(x + 1e-6 * omega) - f(x - 1e-6 * omega)) / 2e-6
        t = t - f(x) / d
    pts = t[..., None] * omega
    h = 1e-6
    grad = np.stack([(f(pts + h * e) - f(pts - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
    normals = -grad / np.linalg.norm(grad, axis=-1, keepdims=True)
    valid = pts[..., 2] > BASE_Z + 0.05
    return pts[..., 2], pts, normals, valid


def render(cam, leds, pts, normals, albedo=(0.8, 0.7, 0.6), exposure=None):
    """Linear images (L, H, W, 3) = albedo * led_shading; exposure scales the 99.5th percentile to 0.7."""
    lin = led_shading(pts, normals, leds) * np.asarray(albedo)
    if exposure is None:
        exposure = 0.7 / np.percentile(lin, 99.5)
    return lin * exposure


def to_stored(lin):
    scale = RESPONSE.white_level - RESPONSE.black_level
    return np.clip(np.round(RESPONSE.black_level + lin * scale), 0, 65535).astype(np.uint16)


def crop_camera(full=(480, 360), size=(64, 64), centre=None) -> Camera:
    """A ``size`` crop of a ``full``-sized camera of the default lens, centred on a camera-frame point."""
    import dataclasses

    cam = camera(*full)
    u, v = cam.project(np.asarray(centre, float))
    x0, y0 = int(round(u)) - size[0] // 2, int(round(v)) - size[1] // 2
    return dataclasses.replace(cam, width=size[0], height=size[1], cx=cam.cx - x0, cy=cam.cy - y0)


def dent_centre(tilt_deg: float = 15.0) -> np.ndarray:
    """Camera-frame point of the undeformed dome on the indenters' axis."""
    tilt = math.radians(tilt_deg)
    axis = np.array([math.sin(tilt) * math.cos(0.7), math.sin(tilt) * math.sin(0.7), math.cos(tilt)])
    return CENTRE + RADIUS * axis


def make_press(folder, kind="sphere", depth=1.5, size=(96, 72), leds=None, lin_hook=None, exposure=None, cam=None):
    """Write an exact-data press; ``lin_hook(lin) -> lin`` may corrupt the linear images first;
    ``cam`` replaces the default ``size`` camera (e.g. :func:`crop_camera`)."""
    cam = cam if cam is not None else camera(*size)
    leds = leds or ring_leds()
    z, pts, nrm, valid = surface(cam, kind, depth)
    zr, _, nr, _ = surface(cam, "none")
    lin = render(cam, leds, pts, nrm, exposure=exposure)
    if lin_hook is not None:
        lin = lin_hook(lin)
    dark = np.full(cam.shape + (3,), int(RESPONSE.black_level), np.uint16)
    stored = to_stored(lin)
    groups = (np.arange(len(leds)) * 3) // len(leds)
    tri = np.stack([lin[groups == g, ..., g].sum(0) for g in range(3)], axis=-1)
    nan = np.float32(np.nan)
    ref = Reference(
        depth=np.where(valid, zr, nan).astype(np.float32),
        normals=np.where(valid[..., None], nr, 0).astype(np.float32),
    )
    gt = GroundTruth(
        depth=np.where(valid, z, nan).astype(np.float32),
        points=np.where(valid[..., None], pts, nan).astype(np.float32),
        normals=np.where(valid[..., None], nrm, 0).astype(np.float32),
        valid=valid,
        contact=valid & (np.abs(z - zr) > 1e-3),
    )
    return write_press(
        folder,
        cam,
        leds,
        RESPONSE,
        dark,
        stored,
        to_stored(tri),
        {"source": "tests.solver.synth", "kind": kind},
        reference=ref,
        ground_truth=gt,
    )
