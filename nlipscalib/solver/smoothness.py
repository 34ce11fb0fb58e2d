"""The NLiPs energy's smoothness term on one pyramid level: gamma times a penalty of the second differences of
log-depth t along u and v (:func:`nlipscalib.solver.operators.level_operators`' ``second``), squared, or
edge-preserving (``SolverOptions.smoothness_edge``): squared up to a scale, logarithmic (Cauchy) beyond it, so the
walls of a relief keep their height. Of t's deformation from the prior t0 where the camera sees past the gel
(``SolverOptions.smooth_deformation``): the dent is smooth, the dome's own curvature is no cost.

Conventions are those of :mod:`nlipscalib.solver.gauss_newton`: the energy is gamma * sum phi(s) with
phi(s) = s^2 for small s, its gradient and Gauss-Newton matrix are given halved (as the data term's blocks are):
gamma * sum_j E_j^T (w_j s_j) and gamma * sum_j E_j^T diag(w_j) E_j, w = phi'(s) / (2 s) the IRLS weights
(1 for the squared penalty)."""

from __future__ import annotations

import numpy as np

from . import threads


def edge_scale(A: np.ndarray, C: np.ndarray, slope_change: float) -> float | None:
    """The second difference of log-depth (unitless, per pixel^2) at which the edge-preserving penalty bends.

    Along a pixel's step t changes by about the surface's slope (tan of its tilt from the ray) times the pixel's
    angular size, which the normal basis gives as |C| / |A| (:func:`nlipscalib.solver.geometry.normal_basis`:
    A ~ q x q_v ~ 1/f, C = q_u x q_v ~ 1/f^2): a slope change of ``slope_change`` per pixel is a second difference of
    ``slope_change`` |C| / |A| (the level's median: the same scale on every level in slope terms).

    Parameters
    ----------
    A, C : (N, 3) float -- the level's normal basis.
    slope_change : ``SolverOptions.smoothness_edge``; 0: None (squared everywhere).
    """
    if slope_change <= 0 or len(A) == 0:
        return None
    ratio = np.linalg.norm(C, axis=1) / np.maximum(np.linalg.norm(A, axis=1), 1e-300)
    return slope_change * float(np.median(ratio))


class Smoothness:
    """gamma * sum phi(second differences of t) on one level.

    Parameters
    ----------
    ops : the level's operators (``lap``: sum_j E_j^T E_j; ``second``: the two (N, N) CSR second differences E_j).
    gamma : the term's weight (``SolverOptions.smoothness`` times the data term's curvature).
    scale : :func:`edge_scale`'s value, or None for the squared penalty (the bits of the solver before s32).
    about : (N,) float64 or None -- the log-depth whose second differences cost nothing (the level's prior t0):
        the term penalises those of t - about. None: of t itself (a flat log-depth costs nothing).

    Why ``about``: a dome's log-depth is curved (a wide 160x120 view: second differences ~6e-4, 40x the default
    view's at 640x480), and a smoothness of t itself pulls it straight wherever the data hold it weakly: at the gel's
    outline in a view that sees the dome down to its base, lit at 0.15 of the gel's median (the data's hold goes as
    its square), the outer 2-4 px came out 5-10 deg off, exact data included (benchmarks/RESULTS.md, s33-rimedge).
    """

    def __init__(self, ops: dict, gamma: float, scale: float | None, about: np.ndarray | None = None):
        self.ops, self.gamma, self.scale, self.about = ops, gamma, scale, about

    def energy(self, t: np.ndarray) -> float:
        """gamma * sum phi(s) at log-depth t (N,)."""
        t = self._deformation(t)
        if self.scale is None:
            # the Laplacian's product by row blocks on the pool (the same bits): one per line-search trial, ~5 ms
            # of one core at 640x480
            return self.gamma * float(t @ threads.RowBlocks(self.ops["lap"]).dot(t))
        c2 = self.scale**2
        return self.gamma * sum(float(np.sum(c2 * np.log1p(s * s / c2))) for s in self._seconds(t))

    def gradient_and_weights(self, t: np.ndarray) -> tuple[np.ndarray, tuple]:
        """(the halved gradient (N,), the weights of ``second`` in the Gauss-Newton matrix: scalars, or (N,) arrays
        for the edge-preserving penalty (:class:`nlipscalib.solver.geometry.NormalMatrix`)) at t."""
        t = self._deformation(t)
        if self.scale is None:
            return self.gamma * (self.ops["lap"] @ t), (self.gamma, self.gamma)
        seconds = self._seconds(t)
        weights = [cauchy_weights(s, self.scale) for s in seconds]
        gradient = sum(E.T @ (w * s) for E, w, s in zip(self.ops["second"], weights, seconds))
        return self.gamma * gradient, tuple(self.gamma * w for w in weights)

    def _deformation(self, t: np.ndarray) -> np.ndarray:
        return t if self.about is None else t - self.about

    def _seconds(self, t: np.ndarray) -> list[np.ndarray]:
        return [threads.RowBlocks(E).dot(t) for E in self.ops["second"]]


def cauchy_weights(s: np.ndarray, scale: float) -> np.ndarray:
    """IRLS weights 1 / (1 + (s / scale)^2) of the penalty scale^2 log(1 + (s / scale)^2), s^2 for small s."""
    return 1.0 / (1.0 + (s / scale) ** 2)
