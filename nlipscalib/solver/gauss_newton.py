"""One pyramid level's Gauss-Newton iteration on log-depth (:mod:`nlipscalib.solver.nlips` gives the energy): the
variable-projection step with the albedo eliminated, solved inexactly by CG (:class:`.krylov.Krylov`), the
backtracking and expanding line search on the joint energy, the robust scale, and the level's result."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core.metrics import angle_deg
from ..core.robust_scale import mad_scale
from . import threads
from .kernel import Array, Backend, ChunkedModel, Model, Parts, make_model
from .krylov import Krylov, forcing, warm_first_step
from .operators import depth_normals, level_operators, log_depth_gradient, pixelwise, unit_normals
from .options import SolverOptions
from .smoothness import Smoothness, edge_scale

if TYPE_CHECKING:  # named in hints only: tqdm is imported where a progress bar is asked for
    from tqdm import tqdm


def solve_level(
    lv: dict,
    t_init: np.ndarray,
    leds: tuple,
    opts: SolverOptions,
    be: Backend,
    bar: tqdm | None,
    est: str,
    coarse: bool = False,
    warm: bool = False,
) -> tuple[np.ndarray, dict, dict]:
    """Minimise the energy on one pyramid level from log-depth ``t_init`` (H, W) of that level.

    On a ``coarse`` level (one whose result only starts the next), linear solves stop at a relative
    residual of sqrt(cg_rtol): tighter solves there bought nothing the next level keeps.
    ``warm``: ``t_init`` is a solved depth brought up to this, the finest, level (the outer loop's last pass): its
    first linear solve is tighter, by AMG (:func:`.krylov.warm_first_step`).

    Each iteration (:meth:`_Level.iterate`): variable-projection Gauss-Newton step on t (albedo eliminated),
    solved inexactly by AMG-preconditioned CG, then a backtracking line search on the joint energy with the
    albedo refitted (IRLS) at the trial depth: the energy never increases.

    Returns
    -------
    (H, W) float64 log-depth (0 off the mask), the per-pixel results (normals, albedo, residual, confidence,
    has_gradient), the level's report entry.
    """
    level = _Level(lv, t_init, leds, opts, be, est, warm and not coarse)
    pcg = Krylov(opts)
    for _ in range(opts.max_iters):
        stop = level.iterate(pcg, coarse)
        if bar is not None:
            bar.update(1)
        if stop and not coarse and level.disks_moved():  # a level from the prior goes on from the disks' new ratio
            continue
        if stop:
            level.info["stop"] = stop
            break
    level.info["iterations"] = len(level.info["normal_change_deg"])  # one per accepted step
    level.info["amg_setups"] = pcg.setups
    return level.finish()


class _Level:
    """One pyramid level's energy and the Gauss-Newton state on it: log-depth t on the mask's pixels, the
    shading F and its derivatives dF, the albedo, the residuals r, the energy, the normals."""

    def __init__(
        self, lv: dict, t_init: np.ndarray, leds: tuple, opts: SolverOptions, be: Backend, est: str, warm: bool = False
    ):
        self.tm = _Timer()
        self.lv, self.opts, self.be, self.est = lv, opts, be, est
        self.mk = mk = lv["mask"]
        self.A, self.B, self.C = lv["ABC"]
        self.ops = level_operators(lv)
        self.t0 = lv["t0"][mk]
        self.zeta = lv["zeta"]
        t = t_init[mk].copy()
        self.model = model = make_model(be, lv["q"], self.A, self.B, self.C, *leds, lv["images"], lv["usable"])
        self._gradient_of: tuple = (None,)
        """(t, t_u, t_v) of the depth shaded last (:meth:`shade`)."""
        self.tm.lap("setup")

        F, dF = self.shade(t, True)
        self.lam = None
        # least squares' energy does not depend on the scale lambda (not known yet): taken in this refit
        albedo, r, e_data = self.refit(F, None, energy=est == "ls")
        self.lam = _robust_scale(be, model, r, lv["images"], lv["usable"], opts)
        # The smoothness weight is relative to the data term's curvature along the gradient of t (least
        # squares, starting depth).
        self.gamma = opts.smoothness * float(np.median(model.gradient_curvature(dF, albedo, model.usable)))
        about = self.t0 if opts.smooth_deformation == "on" else None  # "auto" is decided by nlips.solve
        self.smooth = Smoothness(self.ops, self.gamma, edge_scale(self.A, self.C, opts.smoothness_edge), about)
        if est != "ls":
            albedo, r, e_data = self.refit(F, albedo, energy=True)
        self.M, self.b = model.irls_blocks(F, dF, r, albedo, self.lam, est)
        # the derivatives and residuals are in the blocks now: not held through the linear solve and the line search
        # (:meth:`_newton_step`); the level's result is refitted from F and the albedo (:meth:`finish`)
        self.t, self.F, self.dF, self.albedo, self.r = t, F, None, albedo, None
        self.e_cur = e_data + self.prior(t)
        self.info = {
            "shape": list(mk.shape),
            "estimator": est,
            "gamma": self.gamma,
            "pixels": len(t),
            "lambda": self.lam,
            "energy": [self.e_cur],
            "cg_iters": [],
            "cg_rtol": [],
            "normal_change_deg": [],
            "rejected_steps": 0,
            "expanded_steps": 0,
            "stop": "max_iters",
        }
        if model.disks is not None:  # fixed again at the level's converged depth (:meth:`disks_moved`)
            self.info["disk_ratio_fixes"] = 0
        self.from_prior = model.disks is not None and bool(np.array_equal(self.t0, t))
        """The level starts from the depth prior, not from a depth solved on a coarser level or an earlier pass."""
        self.nrm = self.normals(t)
        self.g_prev = self.eta = None
        self._full_step = None
        """The line search's full-step trial depth (the only one :meth:`_expanded` doubles), or None."""
        self.first_rtol = warm_first_step(len(t), opts) if warm else None
        """The first linear solve's tolerance, by AMG alone (:func:`.krylov.warm_first_step`); None: the forcing
        term's, Jacobi tried first."""
        self.tm.lap("init")

    # ------------------------------------------------------------------ the energy's parts
    def shade(self, tt: np.ndarray, derivatives: bool = False):
        # the gradient kept for the normals of the same depth (:meth:`normals`: the level's start, an accepted step)
        self._gradient_of = (tt, *log_depth_gradient(self.ops, tt))
        out = self.model.shading(tt, *self._gradient_of[1:], derivatives)
        return (out[0], out[1:]) if derivatives else (out, None)

    def prior(self, tt: np.ndarray) -> float:
        """The energy's terms on t alone at ``tt``: the depth prior's and the smoothness's."""
        return float(np.sum(self.zeta * (tt - self.t0) ** 2)) + self.smooth.energy(tt)

    def refit(self, F: Array | Parts, alb: Array | Parts | None, energy: bool = False):
        """Albedo at shading F: exact for least squares, one IRLS step from ``alb`` otherwise; (albedo,
        residuals, the data energy there or None) (:meth:`nlipscalib.solver.kernel.Model.refit`)."""
        start = None if self.est == "ls" else alb
        return self.model.refit(F, start, self.lam, self.est, energy)

    def normals(self, tt: np.ndarray):
        if self._gradient_of[0] is tt:  # shaded last: its gradient, not two sparse products again (the same bits)
            return unit_normals(*self._gradient_of[1:], self.A, self.B, self.C)
        return depth_normals(self.ops, tt, self.A, self.B, self.C)

    # ------------------------------------------------------------------ one iteration
    def iterate(self, pcg: Krylov, coarse: bool) -> str | None:
        """One Gauss-Newton iteration; the reason to stop (a report ``stop`` value) or None."""
        delta, g, Hm = self._newton_step(pcg, coarse)
        # When the model predicts less than energy_rtol of decrease, the level has converged by that
        # criterion: the full step is taken if it does not raise the energy, and no halvings are tried.
        # Hm's product by row blocks on the pool (the same bits): ~2.5 ms of one core at 640x480
        predicted = -float(g @ delta) - 0.5 * float(delta @ threads.RowBlocks(Hm).dot(delta))
        converged = predicted < self.opts.energy_rtol * self.e_cur
        step = self._line_search(delta, converged)
        if step is not None and not converged:
            step = self._expanded(delta, predicted, step)
        if step is None:
            return "energy_rtol" if converged else "no_descent"
        return self._accept(*step, converged)

    def _newton_step(self, pcg: Krylov, coarse: bool):
        """The Gauss-Newton step on log-depth with the IRLS weights of the current residuals, solved inexactly
        (the forcing term loosens CG while the gradient is still large); (step, gradient, normal matrix)."""
        model, ops, opts, t = self.model, self.ops, self.opts, self.t
        if self.M is None:
            if self.dF is None:  # the accepted step's derivatives, deferred until a step needs them
                self.F, self.dF = self.shade(t, True)
            self.M, self.b = model.irls_blocks(self.F, self.dF, self.r, self.albedo, self.lam, self.est)
            # What the blocks are made from is not held through the assembly, the linear solve (AMG's set-up) and
            # the line search (a trial's shading, derivatives and residuals), where a whole frame's memory peaks:
            # the derivatives and the residuals, 44 MB each at 640x480 with 12 LEDs. The next blocks come from the
            # accepted depth's (:meth:`_accept`).
            self.dF = self.r = None
            self.tm.lap("blocks")
        M, b, zeta = self.M, self.b, self.zeta
        self.M = self.b = None  # used; the next iteration's blocks come from the accepted depth
        smooth_g, smooth_w = self.smooth.gradient_and_weights(t)
        g = b[0] + ops["Du"].T @ b[1] + ops["Dv"].T @ b[2] + zeta * (t - self.t0) + smooth_g
        M[0, 0] += zeta + 1e-12 * max(float(np.mean(M[0, 0])), 1e-30)  # the prior; definite if zeta = 0
        Hm = ops["normal"].assemble(M, smooth_w)
        del M, b  # (3, 3, N) and (3, N) float64: in Hm and g now
        self.tm.lap("assemble")
        g_norm = float(np.linalg.norm(g))
        first_warm = self.g_prev is None and self.first_rtol is not None
        eta = self.first_rtol if first_warm else forcing(g_norm, self.g_prev, self.eta, opts)
        self.eta = max(eta, np.sqrt(opts.cg_rtol)) if coarse else eta
        self.g_prev = g_norm
        delta, iters = pcg.solve(Hm, -g, self.eta, jacobi=not first_warm)
        self.info["cg_iters"].append(iters)
        self.info["cg_rtol"].append(self.eta)
        self.tm.lap("cg")
        return delta, g, Hm

    def _line_search(self, delta: np.ndarray, converged: bool):
        """Backtracking on the joint energy, the albedo refitted at each trial depth: (t, F, dF or None,
        albedo, r, energy) of the first step that does not raise the energy, or None."""
        for k in range(1 if converged else self.opts.line_search_steps + 1):
            t_new = self.t + 0.5**k * delta
            self._full_step = t_new if k == 0 else None
            # the full step's derivatives with its shading (one pass); none after a converged step, which ends
            # the level
            F_new, dF_new = self.shade(t_new, derivatives=k == 0 and not converged)
            alb_new, r_new, e_data = self.refit(F_new, self.albedo, energy=True)
            e_new = e_data + self.prior(t_new)
            if e_new <= self.e_cur:
                self.tm.lap("line_search")
                return t_new, F_new, dF_new, alb_new, r_new, e_new
            self.info["rejected_steps"] += 1
        self.tm.lap("line_search")
        return None

    def _expanded(self, delta: np.ndarray, predicted: float, step: tuple) -> tuple:
        """The line search's accepted ``step`` (t, F, dF, albedo, r, energy), or the doubled step's where
        :func:`expanded_step` takes it (its derivatives then left to the next step). Only a full step is doubled.
        The doubled trial refits the albedo from the same start as the full one: the energies compare like for
        like."""
        if step[0] is not self._full_step:
            return step

        def trial(alpha: float) -> tuple:
            t_far = self.t + alpha * delta
            F_far, _ = self.shade(t_far)
            alb_far, r_far, e_data = self.refit(F_far, self.albedo, energy=True)
            return t_far, F_far, None, alb_far, r_far, e_data + self.prior(t_far)

        out = expanded_step(trial, step, self.e_cur, predicted, self.opts.line_search_expand)
        self.info["expanded_steps"] += out is not step
        self.tm.lap("line_search")
        return out

    def _accept(
        self,
        t_new: np.ndarray,
        F_new: Array | Parts,
        dF_new: Sequence[Array | Parts] | None,
        alb_new: Array | Parts,
        r_new: Array | Parts,
        e_new: float,
        converged: bool,
    ) -> str | None:
        """Move to the accepted depth; the reason to stop there (energy or normals no longer change) or None."""
        # dF_new None (a halved step, or one that ends the level): derived in the next step, if there is one
        self.t, self.F, self.dF, self.albedo, self.r = t_new, F_new, dF_new, alb_new, r_new
        nrm_new = self.normals(t_new)
        change = float(np.median(pixelwise(lambda p: angle_deg(self.nrm[p], nrm_new[p]), len(t_new))))
        self.nrm = nrm_new
        self.info["normal_change_deg"].append(change)
        rel = (self.e_cur - e_new) / max(self.e_cur, 1e-300)
        self.e_cur = e_new
        self.info["energy"].append(e_new)
        self.tm.lap("line_search")
        if rel < self.opts.energy_rtol or converged:
            return "energy_rtol"
        if change < self.opts.normal_tol_deg:
            return "normal_tol"
        return None

    def disks_moved(self) -> bool:
        """Of disk LEDs, at the converged depth of a level that started from the prior: their ratio to the points
        (:meth:`.kernel.Model.fix_disk_ratio`, fixed at the level's start) fixed again there, with that model's
        shading, albedo and energy; True where the model's change alone (the energy at the same albedo) moved the
        energy by more than ``energy_rtol`` of itself (the level then iterates on from there) and no more than
        :data:`DISK_RATIO_FIXES` fixes were made, else False (point LEDs too).

        Why only from the prior: a level that starts from a solved depth (the pyramid's finer levels, the outer
        loop's last pass) ends 0.03-0.25 mm from it, where the ratio fixed again moved the energy by 0.009-0.08 %
        (s33-diskfast, the wide view's and the default twin's presses: none would iterate on), and the fix costs a
        7-point shading of the level; from the prior the dent moves by the press's depth."""
        if self.model.disks is None or not self.from_prior or self.info["disk_ratio_fixes"] >= DISK_RATIO_FIXES:
            return False
        self.model.fix_disk_ratio(self.t, *log_depth_gradient(self.ops, self.t))
        self.info["disk_ratio_fixes"] += 1
        F, _ = self.shade(self.t)
        # the model's change alone: the energy at the same albedo (a refit would lower it by an IRLS step too)
        e_same = self.model.energy(F, self.albedo, self.lam, self.est) + self.prior(self.t)
        moved = abs(e_same - self.e_cur) > self.opts.energy_rtol * self.e_cur
        self.albedo, self.r, e_data = self.refit(F, self.albedo, energy=True)
        self.F, self.dF, self.e_cur = F, None, e_data + self.prior(self.t)
        self.M = self.b = None  # the next step's blocks: from this model's shading and residuals
        self.tm.lap("disk_ratio")
        return moved

    # ------------------------------------------------------------------ the result
    def finish(self):
        """Final albedo and per-pixel diagnostics at the accepted depth (the refit cannot raise the energy):
        (log-depth (H, W), per-pixel results, the level's report entry)."""
        albedo, r, _ = self.refit(self.F, self.albedo)
        albedo = self.model.whole(albedo)
        u_np = self.lv["usable"]
        cnt = u_np.sum(axis=(0, 1))
        sq, wsum = self.model.fit_sums(r, self.lam, self.est)  # per chunk: no whole (L, 3, N) residual array
        rms = np.sqrt(sq / np.maximum(cnt, 1))
        conf = (cnt / (u_np.shape[0] * u_np.shape[1])) * (wsum / np.maximum(cnt, 1))
        result = {
            "normals": self.nrm,
            "albedo": self.be.numpy(albedo),
            "residual": np.where(cnt > 0, rms, np.nan),
            "confidence": np.clip(conf, 0, 1),
            "has_gradient": self.ops["has_grad"],
        }
        self.tm.lap("finish")
        self.info["seconds"] = {k: round(v, 4) for k, v in self.tm.seconds.items()}
        return embed(self.t, self.mk), result, self.info


DISK_RATIO_FIXES = 2
"""A finest level of disk LEDs fixes their ratio to point LEDs again (:meth:`_Level.disks_moved`) at most this many
times."""


def expanded_step(
    trial: Callable[[float], tuple], full: tuple, e_start: float, predicted: float, ratio: float
) -> tuple:
    """The doubled step's trial where the full step's energy decrease beat its model's prediction by more than
    ``ratio`` times and the doubled step lowers the energy further; ``full`` otherwise.

    Parameters
    ----------
    trial : callable
        ``trial(alpha)``: a tuple whose last item is the energy at the step scaled by ``alpha``.
    full : tuple
        ``trial(1.0)``'s tuple (the full step, accepted by the line search).
    e_start : float
        Energy before the step.
    predicted : float
        The decrease the Gauss-Newton model predicts for the full step (> 0 for a descent step), in the units of
        the solver's halved gradient and normal matrix: half the model's decrease of the energy (s40-relief).
    ratio : float
        The factor of ``predicted`` the actual decrease must exceed; 0 = never expand.

    Notes
    -----
    IRLS weights give a robust loss a quadratic model whose curvature bounds the loss's from above (the Cauchy
    loss is concave in r^2), so the model's step falls short where residuals sit in the loss's bend; where its
    model is exact (least squares at the solution's weights) the actual decrease equals the prediction and the
    doubled step is never tried. One more energy evaluation, only where it is tried.
    """
    if not ratio or e_start - full[-1] <= ratio * max(predicted, 0.0):
        return full
    far = trial(2.0)
    return far if far[-1] < full[-1] else full


def _robust_scale(
    be: Backend,
    model: Model | ChunkedModel,
    r: Array | Parts,
    images: np.ndarray,
    usable: np.ndarray,
    opts: SolverOptions,
) -> float:
    """Estimator scale lambda from the residuals of the usable samples, floored relative to the images.

    Parameters
    ----------
    model : the level's model; r : (L, 3, N) residuals on the backend, as ``model`` returned them (chunks too)
    images : (L, 3, N) normalised images; usable : (L, 3, N) usable samples as 0/1
    """
    # Medians over a regular subsample: up to 10^7 samples at full resolution, and a median of
    # 2 10^5 is as good a scale estimate as it needs to be. Only the subsample is read (no whole copies).
    step = max(1, usable.size // 200_000)
    u = usable.reshape(-1)[::step] > 0
    if not u.any():
        return 1e-12
    med_i = float(np.median(images.reshape(-1)[::step][u]))
    r_sub = be.numpy(model.every(r, step))[u]
    return max(opts.robust_scale * mad_scale(r_sub), opts.robust_floor * med_i, 1e-12)


class _Timer:
    """Accumulates wall time per named stage (reported per level, for profiling)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._t = time.perf_counter()

    def lap(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self._t
        self._t = now


def embed(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    full = np.zeros(mask.shape)
    full[mask] = values
    return full
