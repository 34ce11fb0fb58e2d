"""Near-light photometric stereo on a distorted camera: alternating reweighted least squares.

Unknown: log-depth t = log z on a mask of pixels. Energy::

    E(t, rho) = sum_{p, i, c usable} phi(rho_c(p) Psi_ic F_i(p; t) - I_ic(p)) + zeta sum_p (t_p - t0_p)^2

Each iteration: closed-form albedo (IRLS weights), then one Gauss-Newton step on t whose sparse SPD
system is solved by conjugate gradient preconditioned with smoothed-aggregation algebraic multigrid
(pyamg); a backtracking line search rejects any step that would raise E. Coarse-to-fine over an image
pyramid (cv2.resize INTER_AREA, Camera.scaled).
"""

from __future__ import annotations

import dataclasses
import logging
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..core.camera import Camera
from ..core.leds import led_arrays
from ..errors import ShapeError
from . import geometry, robust
from .kernel import Backend, Model
from .options import SolverOptions

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SolveResult:
    """Output of :func:`solve`; every map is (H, W[, 3]) in the full image, NaN where not reconstructed."""

    depth: np.ndarray
    """(H, W) float32, mm -- z in the camera frame."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, toward the camera."""
    albedo: np.ndarray
    """(H, W, 3) float32 -- rho_c in linear image units per unit Psi (relative)."""
    residual: np.ndarray
    """(H, W) float32 -- RMS of the model-minus-image residual over usable LEDs/channels, linear units."""
    confidence: np.ndarray
    """(H, W) float32 in [0, 1] -- usable fraction of LED images times mean robust weight; 0 if not solved."""
    usable_leds: np.ndarray
    """(H, W) int16 -- LEDs with at least one usable (lit, unsaturated, alive) channel at the pixel."""
    mask: np.ndarray
    """(H, W) bool -- pixels that were unknowns of the solve."""
    reconstructed: np.ndarray
    """(H, W) bool -- mask and enough usable LEDs and a valid gradient: the maps are defined here."""
    report: dict
    """What was excluded (dead LEDs, dead/saturated/shadowed/too-few pixels), per-level iterations, energy, time."""

    def arrays(self) -> dict:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "report"}


def exclusions(images: np.ndarray, saturated: np.ndarray | None, options: SolverOptions):
    """Which (LED, pixel, channel) samples the data term may use, and why others are excluded.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1
    saturated : (L, H, W, 3) bool or None
    options : SolverOptions

    Returns
    -------
    usable : (L, H, W, 3) bool
    report : dict -- dead_leds (0-based list), dead_pixels, saturated_samples, shadow_samples (counts)
    """
    L = images.shape[0]
    sat = np.zeros(images.shape, bool) if saturated is None else saturated
    per_led_high = np.array([np.percentile(images[i], 99) for i in range(L)])
    dead_leds = [i for i in range(L) if per_led_high[i] < options.dead_led_level]
    dead_px = np.all(images <= options.dead_pixel_level, axis=(0, 3))
    # Shadow threshold per LED and channel, relative to that image's bright end.
    high_c = np.percentile(images.reshape(L, -1, 3), 99, axis=1)  # (L, 3)
    shadow = images < options.shadow_level * high_c[:, None, None, :]
    usable = ~sat & ~shadow & ~dead_px[None, :, :, None]
    usable[dead_leds] = False
    report = {
        "dead_leds": dead_leds,
        "dead_pixels": int(dead_px.sum()),
        "saturated_samples": int(sat.sum()),
        "shadow_samples": int((shadow & ~sat).sum()),
    }
    return usable, report


def solve(
    images: np.ndarray,
    camera: Camera,
    leds,
    *,
    prior_depth: np.ndarray | None = None,
    mask: np.ndarray | None = None,
    saturated: np.ndarray | None = None,
    options: SolverOptions | None = None,
    backend: str = "numpy",
    progress: bool = False,
) -> SolveResult:
    """Recover depth, normals and albedo from one image per LED.

    Parameters
    ----------
    images : (L, H, W, 3) float, linear, dark-subtracted, full scale 1, RGB
        One image per LED lit alone.
    camera : Camera -- its exact per-pixel rays are used (no pinhole assumption).
    leds : sequence of Led, length L, camera frame, mm.
    prior_depth : (H, W) float, mm, or None
        Depth prior z0 (e.g. the undeformed dome, ``Press.reference.depth``); NaN where not gel.
        None: ``options.nominal_distance`` along every ray.
    mask : (H, W) bool or None -- pixels to solve (default: where the prior is finite).
    saturated : (L, H, W, 3) bool or None -- samples to exclude as saturated.
    options : SolverOptions
    backend : "numpy" or "torch" (per-pixel maths on a GPU when present; same equations).
    progress : show a tqdm bar.
    """
    opts = options or SolverOptions()
    leds = tuple(leds)
    images = np.asarray(images)
    H, W = camera.shape
    if images.ndim != 4 or images.shape[1:] != (H, W, 3):
        raise ShapeError(f"images must be (L, {H}, {W}, 3) for this camera, got {images.shape}")
    if images.shape[0] != len(leds):
        raise ShapeError(f"{images.shape[0]} LED images but {len(leds)} LEDs")
    if len(leds) < opts.min_leds:
        raise ShapeError(f"{len(leds)} LEDs given; the solver needs at least min_leds={opts.min_leds}")
    if not np.all(np.isfinite(images)):
        raise ShapeError(f"images contain {int(np.sum(~np.isfinite(images)))} NaN/inf values; mark bad pixels "
                         "with `mask` or `saturated` instead")
    if saturated is not None and np.shape(saturated) != images.shape:
        raise ShapeError(f"saturated must have the images' shape {images.shape}, got {np.shape(saturated)}")
    if prior_depth is None:
        prior_depth = opts.nominal_distance * camera.rays[..., 2]
    prior_depth = np.asarray(prior_depth, dtype=np.float64)
    if prior_depth.shape != (H, W):
        raise ShapeError(f"prior_depth must be ({H}, {W}), got {prior_depth.shape}")
    finite = np.isfinite(prior_depth) & (np.nan_to_num(prior_depth) > 0)
    if mask is None:
        mask = finite
    mask = np.asarray(mask)
    if mask.shape != (H, W) or mask.dtype != bool:
        raise ShapeError(f"mask must be ({H}, {W}) bool, got {mask.shape} {mask.dtype}")
    mask = mask & finite
    if mask.sum() < 4:
        raise ShapeError("the solve mask holds fewer than 4 pixels with a finite prior depth")

    t_start = time.perf_counter()
    images = images.astype(np.float64)
    usable, report = exclusions(images, saturated, opts)
    usable &= mask[None, :, :, None]
    usable_leds = usable.any(axis=3).sum(axis=0).astype(np.int16)
    scale = float(np.percentile(images[usable], 99)) if usable.any() else 1.0
    scale = scale if scale > 0 else 1.0

    # Solve on the mask's bounding box only: a crop of the camera is the same lens, shifted.
    rows, cols = np.nonzero(mask)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    cam = dataclasses.replace(camera, width=int(c1 - c0), height=int(r1 - r0), cx=camera.cx - c0, cy=camera.cy - r0)
    crop = (slice(r0, r1), slice(c0, c1))
    data = images[:, crop[0], crop[1]] / scale
    use = usable[:, crop[0], crop[1]]
    m = mask[crop]
    t0 = np.log(np.where(m, prior_depth[crop], 1.0))
    pos, dirs, mu, psi = led_arrays(leds)
    keep = [i for i in range(len(leds)) if i not in report["dead_leds"]]
    pos, dirs, mu, psi = pos[keep], dirs[keep], mu[keep], psi[keep]
    data, use = data[keep], use[keep]

    be = Backend(backend, opts.dtype)
    levels = _pyramid(cam, data, use, m, t0, opts)
    report["levels"] = []
    t_state = None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(levels) * opts.max_iters, desc="nlips", unit="it", leave=False)
    for k, lv in enumerate(levels):
        if t_state is None:
            t_init = lv["t0"]
        else:
            prev = levels[k - 1]
            delta = np.where(prev["mask"], t_state - prev["t0"], 0.0)
            delta = _resize(delta, lv["camera"].shape, linear=True)
            t_init = lv["t0"] + delta
        if k == 0 and opts.estimator != "ls":
            # Least squares first on the coarsest level: from the undeformed prior, the contact's
            # residuals are large and a robust estimator would treat the dent itself as outliers.
            t_init, _, info = _solve_level(lv, t_init, pos, dirs, mu, psi, opts, be, bar, "ls")
            report["levels"].append(info)
        t_state, out, info = _solve_level(lv, t_init, pos, dirs, mu, psi, opts, be, bar, opts.estimator)
        report["levels"].append(info)
    if bar is not None:
        bar.close()

    # Back to the full image.
    lv = levels[-1]
    lm = lv["mask"]
    n_ok = out["has_gradient"] & (usable_leds[crop][lm] >= opts.min_leds)
    rec = np.zeros((H, W), bool)
    sub = np.zeros(lm.shape, bool)
    sub[lm] = n_ok
    rec[crop] = sub

    def paste(values, fill=np.nan):
        full = np.full((H, W) + values.shape[1:], fill, np.float32)
        block = np.full(lm.shape + values.shape[1:], fill, np.float32)
        vals = values.astype(np.float32).copy()
        vals[~n_ok] = fill
        block[lm] = vals
        full[crop] = block
        return full

    depth = np.exp(t_state[lm])
    too_few = int((mask & (usable_leds < opts.min_leds)).sum())
    report.update(
        {
            "leds_used": [int(i) for i in keep],
            "pixels_solved": int(mask.sum()),
            "pixels_reconstructed": int(rec.sum()),
            "pixels_too_few_leds": too_few,
            "pixels_no_gradient": int((~out["has_gradient"]).sum()),
            "intensity_scale": scale,
            "backend": backend,
            "seconds": time.perf_counter() - t_start,
        }
    )
    if too_few:
        log.warning("%d pixels have fewer than %d usable LEDs: not reconstructed (NaN)", too_few, opts.min_leds)
    if report["dead_leds"]:
        log.warning("dead LEDs excluded (1-based): %s", [i + 1 for i in report["dead_leds"]])
    return SolveResult(
        depth=paste(depth),
        points=paste(depth[:, None] * lv["q"]),
        normals=paste(out["normals"]),
        albedo=paste(out["albedo"].T * scale),
        residual=paste(out["residual"] * scale),
        confidence=np.nan_to_num(paste(out["confidence"], 0.0)),
        usable_leds=usable_leds,
        mask=mask,
        reconstructed=rec,
        report=report,
    )


# ---------------------------------------------------------------------- pyramid
def _resize(a: np.ndarray, shape: tuple[int, int], linear: bool = False) -> np.ndarray:
    import cv2

    interp = cv2.INTER_LINEAR if linear else cv2.INTER_AREA
    a = np.ascontiguousarray(a, dtype=np.float32)
    if a.ndim == 3 and a.shape[2] > 4:  # OpenCV handles up to 512 channels, but keep it simple
        return np.stack([_resize(a[..., k], shape, linear) for k in range(a.shape[2])], axis=-1)
    return cv2.resize(a, (shape[1], shape[0]), interpolation=interp).astype(np.float64)


def _pyramid(cam: Camera, data, use, mask, t0, opts: SolverOptions) -> list[dict]:
    """Levels from coarse to fine; each: camera, images (L, 3, N), usable, mask, t0, rays."""
    n_levels = opts.pyramid_levels
    if n_levels == 0:
        n_levels = 1
        while min(cam.shape) / 2**n_levels >= 2 * opts.min_level_size:
            n_levels += 1
    levels = []
    for k in range(n_levels):
        c = cam if k == 0 else cam.scaled(0.5**k)
        if k == 0:
            d, u, mk, tk = data, use, mask, t0
        else:
            d = np.stack([_resize(img, c.shape) for img in data])
            u = np.stack([_resize(x.astype(np.float32), c.shape) for x in use]) > 0.999
            mk = _resize(mask.astype(np.float32), c.shape) > 0.999
            tk = np.log(_resize(np.where(mask, np.exp(t0), 0.0), c.shape) / np.maximum(
                _resize(mask.astype(np.float32), c.shape), 1e-9))
            tk = np.where(mk, tk, 0.0)
        if mk.sum() < 16:
            break
        q, qu, qv = geometry.ray_tables(c)
        A, B, C = geometry.normal_basis(q[mk], qu[mk], qv[mk])
        levels.append(
            {
                "camera": c,
                "mask": mk,
                "images": np.moveaxis(d[:, mk], 2, 1),  # (L, 3, N)
                "usable": np.moveaxis(u[:, mk], 2, 1).astype(np.float64),
                "t0": tk,
                "q": q[mk],
                "ABC": (A, B, C),
            }
        )
    return levels[::-1]


# ---------------------------------------------------------------------- one level
def _solve_level(lv, t_init, pos, dirs, mu, psi, opts: SolverOptions, be: Backend, bar, est: str):
    mk = lv["mask"]
    A, B, C = lv["ABC"]
    Du, Dv, has_grad = geometry.gradient_operators(mk)
    du_f, dv_f, _ = geometry.difference_operators(mk)
    du_b, dv_b, _ = geometry.difference_operators(mk, backward=True)
    # Second differences (forward minus backward; zero at edges): the checkerboard modes central
    # differences cannot see. A weak penalty on them couples the sub-lattices (and lets AMG work).
    lap = ((du_f - du_b).T @ (du_f - du_b) + (dv_f - dv_b).T @ (dv_f - dv_b)).tocsr()
    # Central differences: one-sided ones put the normal half a pixel off the data and bias the fit
    # by about a degree on this lens. Central differences alone leave the four pixel sub-lattices
    # weakly coupled; near light ties each pixel's own depth to the data (1/r^2 fall-off), and the
    # prior does the rest.
    stencils = [(Du, Dv)]
    t0 = lv["t0"][mk]
    t = t_init[mk].copy()
    model = Model(be, lv["q"], A, B, C, pos, dirs, mu, psi, lv["images"], lv["usable"])
    uses = [model.usable]
    zeta = opts.prior_weight
    n = len(t)
    eye = sp.identity(n, format="csr")
    Gs = [sp.vstack([eye, du, dv]).tocsr() for du, dv in stencils]

    def shade(tt, derivatives=False):
        return [model.shading(tt, du @ tt, dv @ tt, derivatives) for du, dv in stencils]

    gamma = 0.0  # set below from the data term's own scale

    def prior(tt):
        return zeta * float(np.sum((tt - t0) ** 2)) + gamma * float(tt @ (lap @ tt))

    def energy(Fs, alb, tt):
        return sum(model.energy(F, alb, lam, est, u) for F, u in zip(Fs, uses)) + prior(tt)

    def normals(tt):
        return geometry.normals_from_gradient(Du @ tt, Dv @ tt, A, B, C)

    def fit_albedo(Fs, alb=None):
        """Closed-form albedo under the IRLS weights of the current residuals (plain LS if alb is None)."""
        if alb is None:
            return model.albedo(Fs, uses)
        ws = [model.weights(model.residuals(F, alb), lam, est, u) for F, u in zip(Fs, uses)]
        return model.albedo(Fs, ws)

    out = shade(t, True)
    Fs = [o[0] for o in out]
    dFs = [o[1:] for o in out]
    albedo = fit_albedo(Fs)
    usable_np = lv["usable"] > 0
    r_np = be.numpy(model.residuals(Fs[0], albedo))[usable_np]
    med_i = float(np.median(lv["images"][usable_np])) if usable_np.any() else 1.0
    lam = max(opts.robust_scale * robust.mad_scale(r_np), opts.robust_floor * med_i, 1e-12)
    M0, _ = model.gauss_newton_blocks(dFs[0], model.residuals(Fs[0], albedo), model.usable, albedo)
    gamma = opts.smoothness * float(np.median(M0[1, 1] + M0[2, 2]))
    e_cur = energy(Fs, albedo, t)
    info = {
        "shape": list(mk.shape), "estimator": est, "gamma": gamma, "pixels": n, "lambda": lam,
        "energy": [e_cur], "cg_iters": [], "rejected_steps": 0, "stop": "max_iters",
    }
    amg = None
    nrm = normals(t)
    for _ in range(opts.max_iters):
        # 1. albedo: IRLS majorisation, cannot raise the energy
        albedo = fit_albedo(Fs, albedo)
        e_alb = energy(Fs, albedo, t)
        # 2. Gauss-Newton on log-depth with IRLS weights
        Hm = sp.csr_matrix((n, n))
        g = zeta * (t - t0) + gamma * (lap @ t)
        for F, dF, G, u in zip(Fs, dFs, Gs, uses):
            r = model.residuals(F, albedo)
            w = model.weights(r, lam, est, u)
            M, b = model.gauss_newton_blocks(dF, r, w, albedo)
            Mbig = sp.bmat([[sp.diags(M[a, c]) for c in range(3)] for a in range(3)], format="csr")
            Hm = Hm + G.T @ Mbig @ G
            g = g + G.T @ b.ravel()
        tiny = 1e-12 * max(float(Hm.diagonal().mean()), 1e-30)  # keeps H definite if zeta = 0
        Hm = (Hm + gamma * lap + sp.diags(np.full(n, zeta + tiny))).tocsr()
        delta, amg, iters = _pcg(Hm, -g, amg, opts)
        info["cg_iters"].append(iters)
        accepted = False
        for k in range(opts.line_search_steps + 1):
            t_new = t + 0.5**k * delta
            F_new = shade(t_new)
            e_new = energy(F_new, albedo, t_new)
            if e_new <= e_alb:
                accepted = True
                break
            info["rejected_steps"] += 1
        if bar is not None:
            bar.update(1)
        if not accepted:
            info["energy"].append(e_alb)
            info["stop"] = "no_descent"
            break
        t = t_new
        out = shade(t, True)
        Fs = [o[0] for o in out]
        dFs = [o[1:] for o in out]
        nrm_new = normals(t)
        change = float(np.degrees(np.median(np.arccos(np.clip(np.sum(nrm * nrm_new, 1), -1, 1)))))
        nrm = nrm_new
        rel = (e_cur - e_new) / max(e_cur, 1e-300)
        e_cur = e_new
        info["energy"].append(e_cur)
        if rel < opts.energy_rtol:
            info["stop"] = "energy_rtol"
            break
        if change < opts.normal_tol_deg:
            info["stop"] = "normal_tol"
            break
    info["iterations"] = len(info["energy"]) - 1
    # Final albedo and per-pixel diagnostics at the accepted depth.
    albedo = fit_albedo(Fs, albedo)
    u_np = lv["usable"]
    cnt = u_np.sum(axis=(0, 1))
    cnt_s = sq = wsum = 0
    for F, u in zip(Fs, uses):
        r = model.residuals(F, albedo)
        sq = sq + be.numpy(u * r * r).sum(axis=(0, 1))
        wsum = wsum + be.numpy(model.weights(r, lam, est, u)).sum(axis=(0, 1))
        cnt_s = cnt_s + be.numpy(u).sum(axis=(0, 1))
    rms = np.sqrt(sq / np.maximum(cnt_s, 1))
    conf = (cnt / (u_np.shape[0] * u_np.shape[1])) * (wsum / np.maximum(cnt_s, 1))
    result = {
        "normals": nrm,
        "albedo": be.numpy(albedo),
        "residual": np.where(cnt > 0, rms, np.nan),
        "confidence": np.clip(conf, 0, 1),
        "has_gradient": has_grad,
    }
    return _embed(t, mk), result, info


def _embed(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    full = np.zeros(mask.shape)
    full[mask] = values
    return full


def _pcg(Hm: sp.csr_matrix, rhs: np.ndarray, amg, opts: SolverOptions):
    """Conjugate gradient preconditioned by smoothed-aggregation AMG (hierarchy reused while it works)."""
    import pyamg

    if amg is None:
        amg = pyamg.smoothed_aggregation_solver(
            Hm, symmetry="symmetric", max_coarse=100, coarse_solver="splu"
        ).aspreconditioner(cycle="V")
    count = [0]

    def cb(_):
        count[0] += 1

    x, _ = spla.cg(Hm, rhs, rtol=opts.cg_rtol, maxiter=opts.cg_maxiter, M=amg, callback=cb)
    if count[0] > 30:  # the matrix drifted away from the one the hierarchy was built for
        amg = None
    return x, amg, count[0]
