"""Per-pixel image model, residuals and Gauss-Newton blocks, written once for numpy and torch.

Everything here works on flat pixel lists (N pixels inside the solve mask) and is elementwise or a
sum over LEDs, so the same code runs on numpy arrays (CPU) and torch tensors (CPU or GPU). The sparse
assembly and the linear solve stay in scipy/pyamg (see :mod:`nlipscalib.solver.gauss_newton`).

Model (Quéau et al. 2018), LED i, channel c, log-depth t, x = exp(t) q, N = -(t_u A + t_v B + C)::

    I_ic = rho_c * Psi_ic * F_i,   F_i = (n_s . d)^mu * max(0, (x_s - x) . N) / (|N| |x_s - x|^3)
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType
from typing import TYPE_CHECKING, TypeAlias

import numpy as np

from ..core.leds import DISK_RULE_WEIGHTS
from . import robust

if TYPE_CHECKING:  # torch is optional and slow to import: named for the type checker only
    import torch

Array: TypeAlias = "np.ndarray | torch.Tensor"
"""An array on a :class:`Backend`: a numpy array (numpy backend) or a torch tensor (torch backend)."""


class Backend:
    """Array namespace shim: numpy, or torch on a device."""

    def __init__(self, name: str = "numpy", dtype: str = "float64", device: str | None = None):
        self.name = name
        if name == "numpy":
            self.xp = np
            self.dtype = np.dtype(dtype)
        elif name == "torch":
            from ..core.errors import require

            torch = require("torch", "torch", "The torch solver backend")
            self.xp = torch
            self.dtype = getattr(torch, dtype)
            self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        else:
            from ..core.errors import ConfigError

            raise ConfigError(f"backend must be 'numpy' or 'torch', got {name!r}")

    def asarray(self, a: np.ndarray) -> Array:
        if self.name == "numpy":
            # rows contiguous is enough for the element-wise work: a pixel chunk of an (L, 3, N) array stays
            # a view (a copy of a 640x480 level's images and usable samples per chunk costs ~0.2 s)
            a = np.asarray(a, dtype=self.dtype)
            return a if a.ndim == 0 or a.strides[-1] == a.itemsize else np.ascontiguousarray(a)
        return self.xp.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

    def numpy(self, a: Array) -> np.ndarray:
        if self.name == "numpy":
            return np.asarray(a, dtype=np.float64)
        return a.detach().to("cpu", self.xp.float64).numpy()

    def pixel_sums(self, a: Array) -> np.ndarray:
        """(N,) float64 numpy -- ``a`` (L, 3, N) summed over LEDs and channels in float64 (no float64 copy of
        ``a`` itself: 88 MB at 640x480 with 12 LEDs)."""
        if self.name == "numpy":
            return np.sum(a, axis=(0, 1), dtype=np.float64)
        return a.sum(dim=(0, 1), dtype=self.xp.float64).detach().to("cpu").numpy()

    def relu(self, a: Array) -> Array:
        return np.maximum(a, 0) if self.name == "numpy" else self.xp.clamp(a, min=0)

    def total(self, a: Array) -> float:
        """Sum in float64 whatever the working precision."""
        if self.name == "numpy":
            return float(np.sum(a, dtype=np.float64))
        return float(a.sum(dtype=self.xp.float64))


class _Emitters:
    """Point LEDs on a backend, as :meth:`Model._point_shading` reads them: positions and axes as three (K, 1)
    columns each (mm, camera frame), mu (K, 1)."""

    __slots__ = ("pos", "dir", "mu", "mu_ones")

    def __init__(self, be: Backend, positions: np.ndarray, directions: np.ndarray, mu: np.ndarray):
        self.pos = [be.asarray(positions[:, k : k + 1]) for k in range(3)]
        self.dir = [be.asarray(directions[:, k : k + 1]) for k in range(3)]
        self.mu = be.asarray(mu[:, None])
        # a factor of 1 multiplies nothing (see Model's flags)
        self.mu_ones = bool(np.all(np.asarray(mu) == 1))


class Model:
    """The image model on one pyramid level, with data held on the backend."""

    def __init__(
        self,
        be: Backend,
        q: np.ndarray,
        A: np.ndarray,
        B: np.ndarray,
        C: np.ndarray,
        positions: np.ndarray,
        directions: np.ndarray,
        mu: np.ndarray,
        psi: np.ndarray,
        images: np.ndarray,
        usable: np.ndarray,
    ):
        """q, A, B, C : (N, 3); positions, directions : (L, 3); mu : (L,); psi : (L, 3);
        images, usable : (L, 3, N) (usable as 0/1).

        ``positions`` (L, 7, 3) instead: LEDs that emit from disks, given by their quadrature points
        (:func:`nlipscalib.core.leds.disk_points`, the first of each its centre); their shading is the model of
        :func:`nlipscalib.core.leds.disk_shading` through :attr:`disk_ratio` (see :meth:`shading`)."""
        self.be = be
        self.disks = None
        """The disk LEDs' quadrature points as point emitters, one :class:`_Emitters` of every disk's k-th point
        (of its disk's axis and mu) for each point k of the rule, or None: point LEDs."""
        self.disk_ratio = None
        """(L, N) -- of disk LEDs: their shading over their centres' as point LEDs, at the surface last given to
        :meth:`fix_disk_ratio` (None: not yet); 1 where the centre is unlit."""
        self.disk_offset = None
        """(L, N) -- of disk LEDs fixed where some samples' centres are unlit: the disks' shading there, 0 elsewhere
        (None: every centre lit)."""
        if positions.ndim == 3:  # each point of a disk shades as a point LED of the disk's axis and profile
            self.disks = [_Emitters(be, positions[:, k], directions, mu) for k in range(positions.shape[1])]
            positions = positions[:, 0]  # the rule's first point: the disk's centre
        self.leds = _Emitters(be, positions, directions, mu)
        """The point LEDs the shading evaluates (of disk LEDs their centres)."""
        self.q = [be.asarray(q[:, k]) for k in range(3)]
        self.A = [be.asarray(A[:, k]) for k in range(3)]
        self.B = [be.asarray(B[:, k]) for k in range(3)]
        self.C = [be.asarray(C[:, k]) for k in range(3)]
        self.psi = be.asarray(psi[:, :, None])
        self.images = be.asarray(images)
        self.usable = be.asarray(usable)
        # Factors of 1 multiply nothing: the products they would take a pass over (L, 3, N) for are skipped, with
        # the same bits (x * 1 == x, x ** 1 == x). The default twin's LEDs and most pixel chunks are so.
        self.psi_ones = bool(np.all(np.asarray(psi) == 1))
        self.all_usable = bool(np.all(np.asarray(usable) == 1))

    def shading(
        self, t: np.ndarray, tu: np.ndarray, tv: np.ndarray, derivatives: bool = False
    ) -> Array | tuple[Array, Array, Array, Array]:
        """F : (L, N) and, if asked, dF/dt, dF/dt_u, dF/dt_v : (L, N) each (zero where unlit).

        Of disk LEDs: their centres' point shading times :attr:`disk_ratio`, fixed at the first surface shaded
        unless :meth:`fix_disk_ratio` fixed it before: the disks' exact shading there, and near it as the
        ratio changes slowly with the surface; the derivatives are the points' times the ratio (its own change
        left out). Why not the disks' shading at every call: 7 point LEDs a disk made a whole solve 2x the
        points' (benchmarks/RESULTS.md, s32-rimdepth); the ratio costs one 7-point shading, without derivatives,
        per fix (s33-diskfast)."""
        out = self._point_shading(self.leds, t, tu, tv, derivatives)
        if self.disks is None:
            return out
        if self.disk_ratio is None:
            self.fix_disk_ratio(t, tu, tv)
        F = out[0] if derivatives else out
        for a in out if derivatives else (out,):
            a *= self.disk_ratio
        if self.disk_offset is not None:
            F += self.disk_offset
        return out

    def fix_disk_ratio(self, t: np.ndarray, tu: np.ndarray, tv: np.ndarray) -> None:
        """Fix :attr:`disk_ratio` at the surface (t, t_u, t_v): each disk's shading (the weighted mean of its
        quadrature points', each lit or not on its own: :func:`nlipscalib.core.leds.disk_shading`'s model) over its
        centre's, and where the centre is unlit (a few % of the samples, at the edge of an LED's light) 1 and the
        disk's shading as :attr:`disk_offset`."""
        xp = self.be.xp
        # point by point of the rule, L rows at a time: the temporaries of all 7 L rows at once left the CPU's
        # cache (3.5x this loop's CPU at 320x240, s33-diskfast)
        centre = exact = None
        for weight, points in zip(DISK_RULE_WEIGHTS, self.disks):
            F = self._point_shading(points, t, tu, tv)
            if centre is None:
                centre, exact = F, F * float(weight)
            else:
                F *= float(weight)
                exact += F
        lit = centre > 0
        ratio = xp.where(lit, exact / xp.where(lit, centre, 1), 1)
        self.disk_ratio = ratio
        # where the centre is unlit and some of the disk is not (its edge's samples), the disk's light as it is
        self.disk_offset = None if bool(lit.all()) else xp.where(lit, 0 * exact, exact)

    def _point_shading(
        self, leds: _Emitters, t: np.ndarray, tu: np.ndarray, tv: np.ndarray, derivatives: bool = False
    ) -> Array | tuple[Array, Array, Array, Array]:
        """:meth:`shading` of point LEDs ``leds`` (one per row of ``leds.pos``).

        Written with in-place operations in the order of the formulas' plain expressions (the same bits): an
        (L, N) temporary is a pass over memory, and the fewer of them, the more of a chunk stays in cache."""
        be, xp = self.be, self.be.xp
        t, tu, tv = be.asarray(t), be.asarray(tu), be.asarray(tv)
        z = xp.exp(t)
        x = [z * qk for qk in self.q]
        nv = [-(tu * a + tv * b + c) for a, b, c in zip(self.A, self.B, self.C)]
        nn2 = nv[0] ** 2 + nv[1] ** 2 + nv[2] ** 2
        nn = xp.sqrt(nn2)
        v = [p - xk for p, xk in zip(leds.pos, x)]  # x_s - x, (L, N)
        r2 = _dot3(xp, v, v)
        r = xp.sqrt(r2)
        vn = _dot3(xp, v, nv)
        nsv = _dot3(xp, leds.dir, v)
        cos_led = -nsv
        cos_led /= r
        lit = vn > 0
        lit &= cos_led > 0
        # where lit, cos_led and vn are positive: no clamp needed on what is kept
        F = cos_led * vn if leds.mu_ones else be.relu(cos_led) ** leds.mu * vn
        den = nn * r2
        den *= r
        F /= den
        # a chunk lit by every LED (most of a level's) needs no masking: np.where is 3x a product's time
        all_lit = bool(lit.all())
        if not all_lit:
            F = xp.where(lit, F, 0)
        if not derivatives:
            return F
        safe_vn = vn if all_lit else xp.where(lit, vn, 1)
        safe_cos = cos_led if all_lit else xp.where(lit, cos_led, 1)
        del vn, cos_led, lit
        vx = _dot3(xp, v, x)
        dlog_t = _dot3(xp, leds.dir, x)  # n_s . x
        dlog_t /= r  # d cos_led / dt = n_s . x / r - nsv vx / r^3
        nsv *= vx
        xp.multiply(r2, r, out=den)
        nsv /= den
        dlog_t -= nsv
        del nsv, r, den
        if not leds.mu_ones:
            dlog_t *= leds.mu
        dlog_t /= safe_cos  # mu dcos/dt / cos - x.N / vn + 3 vx / r^2
        dlog_t -= _dot3(xp, x, nv) / safe_vn
        vx *= 3
        vx /= r2
        dlog_t += vx
        del vx, r2, safe_cos
        dlogs = [dlog_t]
        for M in (self.A, self.B):  # -(M.v) / vn + (N.M) / |N|^2 for M = A, B
            dlog = _dot3(xp, M, v)
            xp.negative(dlog, out=dlog)
            dlog /= safe_vn
            dlog += _dot3(xp, nv, M) / nn2
            dlogs.append(dlog)
        for dlog in dlogs:
            dlog *= F
        return (F, *dlogs)

    def residuals(self, F: Array, albedo: Array) -> Array:
        """r : (L, 3, N) = rho_c Psi_ic F_i - I_ic (albedo : (3, N) on the backend)."""
        if self.psi_ones:
            r = albedo[None] * F[:, None]
        else:
            r = albedo[None] * self.psi
            r *= F[:, None]
        r -= self.images
        return r

    def data_energy(self, r: Array, lam: float, estimator: str) -> float:
        """Robust data energy of residuals ``r`` (L, 3, N) over the usable samples, summed in float64."""
        return self.be.total(self._usable_times(robust.rho(r, lam, estimator, self.be.xp)))

    def energy(self, F: Array, albedo: Array, lam: float, estimator: str) -> float:
        """Robust data energy at shading ``F`` (L, N) and albedo (3, N)."""
        return self.data_energy(self.residuals(F, albedo), lam, estimator)

    def weights(self, r: Array, lam: float, estimator: str) -> Array:
        """IRLS weights, zero on excluded samples: (L, 3, N)."""
        return self._usable_times(robust.weight(r, lam, estimator, self.be.xp))

    def _usable_times(self, a: Array) -> Array:
        """``usable * a`` for an (L, 3, N) array ``a`` that no one else holds: ``a`` itself where every sample is
        usable (a product by 1s), else zeroed in place on the excluded samples."""
        if not self.all_usable:
            a *= self.usable
        return a

    def albedo(self, F: Array, w: Array) -> Array:
        """Closed-form per-pixel, per-channel albedo minimising the data term weighted by ``w``: (3, N).

        Parameters
        ----------
        F : (L, N) shading; w : (L, 3, N) sample weights (0 on excluded samples).
        """
        xp = self.be.xp
        # sum_i w S I and sum_i w S^2 (S = Psi F) as three-operand einsums: the same products, summed over LEDs in
        # the same order as (w * S * I).sum(0), with no (L, 3, N) temporaries (6x faster on a chunk)
        if self.psi_ones:
            num = xp.einsum("lcn,ln,lcn->cn", w, F, self.images)
            den = xp.einsum("lcn,ln,ln->cn", w, F, F)
        else:
            S = self.psi * F[:, None]
            num = xp.einsum("lcn,lcn,lcn->cn", w, S, self.images)
            den = xp.einsum("lcn,lcn,lcn->cn", w, S, S)
        ok = den > 1e-30
        return xp.where(ok, num / xp.where(ok, den, 0 * den + 1), 0 * den)

    def refit(
        self, F: Array, albedo: Array | None, lam: float | None, estimator: str, energy: bool = False
    ) -> tuple[Array, Array, float | None]:
        """The albedo at shading ``F``, its residuals and (``energy``) the robust data energy there.

        ``albedo`` None: the exact least-squares fit over the usable samples; else one IRLS step from it (the
        weights of its residuals). One call, so that a :class:`ChunkedModel` runs the whole sequence on a chunk
        while its arrays are in cache, in one hand-off to the pool.

        Returns
        -------
        albedo : (3, N); r : (L, 3, N); the data energy (float) or None.
        """
        w = self.usable if albedo is None else self.weights(self.residuals(F, albedo), lam, estimator)
        fit = self.albedo(F, w)
        r = self.residuals(F, fit)
        return fit, r, self.data_energy(r, lam, estimator) if energy else None

    def gradient_curvature(self, dF: Sequence[Array], albedo: Array, w: Array) -> np.ndarray:
        """Data-term curvature along the log-depth gradient, (N,) float64 numpy: the plain (not
        projected) Gauss-Newton diagonal sum over LEDs and channels of w (rho Psi)^2 (dF_u^2 + dF_v^2)."""
        g2 = (w * (albedo[None] * self.psi) ** 2).sum(1)  # (L, N)
        return self.be.numpy((g2 * (dF[1] * dF[1] + dF[2] * dF[2])).sum(0))

    def fit_sums(self, r: Array, lam: float, estimator: str) -> tuple[np.ndarray, np.ndarray]:
        """(N,) float64 numpy each: the usable samples' squared residuals and their IRLS weights, summed over
        LEDs and channels (a level's residual and confidence maps)."""
        sq = r * r if self.all_usable else self.usable * r
        if not self.all_usable:
            sq *= r
        return self.be.pixel_sums(sq), self.be.pixel_sums(self.weights(r, lam, estimator))

    @staticmethod
    def whole(a: Array | tuple) -> Array | tuple:
        """``a`` as one array (a :class:`ChunkedModel` keeps its results in chunks; this model does not)."""
        return a

    @staticmethod
    def every(a: Array, step: int) -> Array:
        """``a.reshape(-1)[::step]`` of an (L, 3, N) per-sample array: a regular subsample of it."""
        return a.reshape(-1)[::step]

    def gauss_newton_blocks(
        self,
        F: Array,
        dF: Sequence[Array],
        r: Array,
        w: Array,
        albedo: Array,
        out: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Variable-projection Gauss-Newton blocks of the data term, summed over LEDs and channels.

        The albedo is eliminated (it is the closed-form weighted least-squares fit at every depth), so
        the model's Jacobian along t, t_u, t_v is projected, per pixel and channel, orthogonally (in
        the metric of ``w``) to the shading vector over LEDs (Kaufman's variable projection). Without
        it, depth and albedo are fitted alternately and the mode they share -- a common change of
        depth that the albedo absorbs, which near light pins only through ratios of 1/r^2 between
        LEDs -- converges at the slow rate of alternating minimisation (small regions of interest
        needed hundreds of iterations).

        Parameters
        ----------
        F : (L, N) shading; dF : 3 arrays (L, N), its derivatives along t, t_u, t_v.
        r, w : (L, 3, N) residuals and IRLS weights; albedo : (3, N).
        out : (M, b) arrays of the shapes returned, written and returned (None: new ones).

        Returns
        -------
        M : (3, 3, N) float64 numpy, b : (3, N) float64 numpy, with J^T W J = sum_ab P_a^T diag(M_ab) P_b
        and J^T W r = sum_a P_a^T b_a, where P = (identity, D_u, D_v).
        """
        xp, be = self.be.xp, self.be
        Wp = w if self.psi_ones else w * self.psi * self.psi  # (L, 3, N): weights of the products of s = Psi F
        # The W-weighted sums over LEDs of the products of F and its derivatives, each a three-operand einsum: the
        # same products (s_i s_j) W summed in the same order as einsum(W, s_i * s_j), with no (L, N) temporaries.
        shades = (F, *dF)
        sums = {(i, j): xp.einsum("ln,ln,lcn->cn", shades[i], shades[j], Wp) for i, j in _PAIRS}
        d = sums[0, 0]  # (3, N): |s|_W^2, s = Psi F
        a = [sums[0, i + 1] for i in range(3)]  # <s, ds_a>_W
        inv_d = xp.where(d > 1e-30, 1 / xp.where(d > 1e-30, d, 1), 0)
        rho2 = albedo * albedo
        wr = w * r  # (L, 3, N)
        if not self.psi_ones:
            wr *= self.psi
        e = xp.einsum("lcn,ln->cn", wr, F)  # (3, N): <r, s>_W, zero when rho is the exact fit
        N = F.shape[1]
        M, b = out if out is not None else (np.empty((3, 3, N)), np.empty((3, N)))
        for i in range(3):
            # projected gradient: <r, rho (ds_a - s <s, ds_a>/<s, s>)>_W
            gi = albedo * (xp.einsum("lcn,ln->cn", wr, dF[i]) - e * a[i] * inv_d)
            b[i] = be.numpy(gi.sum(0))
            for j in range(i, 3):
                Aij = sums[i + 1, j + 1]
                mij = (rho2 * (Aij - a[i] * a[j] * inv_d)).sum(0)
                M[i, j] = M[j, i] = be.numpy(mij)
        return M, b

    def irls_blocks(
        self,
        F: Array,
        dF: Sequence[Array],
        r: Array,
        albedo: Array,
        lam: float,
        estimator: str,
        out: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`gauss_newton_blocks` with the IRLS weights of the residuals ``r`` (:meth:`weights`), made here:
        a :class:`ChunkedModel` makes each chunk's weights while its residuals are in cache, and no level-sized
        weights array (44 MB at 640x480 with 12 LEDs) is written and read back."""
        return self.gauss_newton_blocks(F, dF, r, self.weights(r, lam, estimator), albedo, out)


_PAIRS = [(i, j) for i in range(4) for j in range(i, 4)]
"""The products (i <= j) of the shading (0) and its derivatives along t, t_u, t_v (1-3) in the Gauss-Newton blocks."""

PARALLEL_MIN_PIXELS = 8192
"""Levels with at least this many pixels run the model on pixel chunks (numpy backend), in threads where
there are several cores. (20,000 before s20: a whole frame's passes solve 19,200- and 8,372-pixel levels
on one core, ~0.25 s of their model's wall, while the pool's hand-off costs ~0.1 ms a call.)"""
CHUNK_PIXELS = 8192
"""Pixels per chunk of :class:`ChunkedModel`, many chunks per thread: the (L, chunk) temporaries of its array
expressions then stay in the CPU's cache. The model's calls of a line-search step took 0.21 s instead of
0.38 s with one chunk per thread (307,200 pixels, 12 LEDs; 8192-32768 time alike, 2048 as before). Since the
model's expressions run in place (fewer live temporaries), 8192 takes ~10 % less CPU than 16384 (4096 as 8192,
but :meth:`ChunkedModel.every` slows with the chunk count; s20 on the 2-core Xeon, benchmarks/RESULTS.md)."""


class Parts:
    """A per-pixel result of :class:`ChunkedModel` kept as its chunks' arrays (``arrays[k]`` of chunk k).

    The model's next call cuts its inputs into the same chunks, so a result that only flows from one model
    call into the next (shading, residuals, weights, albedo) is never joined into a whole-level array and cut
    again: at 307,200 pixels and 12 LEDs those joins copied ~0.8 s worth of arrays per whole-frame solve.
    :meth:`ChunkedModel.whole` joins one where a whole array is needed."""

    __slots__ = ("arrays",)

    def __init__(self, arrays: list):
        self.arrays = arrays


class ChunkedModel:
    """:class:`Model` on contiguous pixel chunks of :data:`CHUNK_PIXELS`, on the thread pool
    (:mod:`nlipscalib.solver.threads`).

    Every method of the model is per pixel (sums run over LEDs and channels only), so cutting the pixel
    axis gives the same numbers; energies are summed over the chunks. Large levels spend most of their
    per-pixel time in memory-bound array expressions that one core leaves half the machine idle for.
    Per-pixel results come back as :class:`Parts` (see there), the Gauss-Newton blocks and the curvature
    as whole arrays.
    """

    def __init__(self, be: Backend, q: np.ndarray, *args: np.ndarray):
        """The arguments of :class:`Model`; each chunk's model gets the per-pixel ones cut to its pixels."""
        from . import threads

        A, B, C, positions, directions, mu, psi, images, usable = args
        self._threads = threads
        self.n = q.shape[0]
        self.slices = threads.chunks(self.n, max(threads.workers(), -(-self.n // CHUNK_PIXELS)))
        self.parts = [
            Model(be, q[s], A[s], B[s], C[s], positions, directions, mu, psi, images[..., s], usable[..., s])
            for s in self.slices
        ]
        self.be = be
        self.images = be.asarray(images)
        self.usable = be.asarray(usable)
        self.disks = self.parts[0].disks
        """The first chunk's (None: point LEDs; see :attr:`Model.disks`)."""

    def _cut(self, a: object, k: int):
        """Chunk ``k`` of an argument: a :class:`Parts`' own array, a slice of a per-pixel array."""
        if isinstance(a, Parts):
            return a.arrays[k]
        if isinstance(a, np.ndarray) and a.ndim and a.shape[-1] == self.n:
            return a[..., self.slices[k]]
        if isinstance(a, (list, tuple)):
            return [self._cut(x, k) for x in a]
        return a

    def _map(self, name: str, *args):
        return self._threads.map_items(
            lambda k: getattr(self.parts[k], name)(*(self._cut(a, k) for a in args)),
            range(len(self.parts)),
        )

    @staticmethod
    def _join(outs: Sequence[Array | tuple]):
        if isinstance(outs[0], tuple):
            return tuple(np.concatenate(group, axis=-1) for group in zip(*outs))
        return np.concatenate(outs, axis=-1)

    @staticmethod
    def _parts(outs: Sequence[Array | tuple]):
        if isinstance(outs[0], tuple):
            return tuple(Parts(list(group)) for group in zip(*outs))
        return Parts(outs)

    def whole(self, a: Array | Parts | tuple) -> Array | tuple:
        """``a`` as one array (a :class:`Parts` joined; tuples element-wise; anything else as it is)."""
        if isinstance(a, Parts):
            return np.concatenate(a.arrays, axis=-1)
        if isinstance(a, tuple):
            return tuple(self.whole(x) for x in a)
        return a

    def every(self, a: Array | Parts, step: int) -> Array:
        """:meth:`Model.every` of an (L, 3, N) array or its :class:`Parts`, the same values: read from the chunks
        where they lie, not from a joined copy (44 MB of fresh pages per level at 640x480 with 12 LEDs)."""
        if not isinstance(a, Parts):
            return a.reshape(-1)[::step]
        planes = a.arrays[0].shape[0] * a.arrays[0].shape[1]
        out = np.empty(-(-planes * self.n // step), a.arrays[0].dtype)
        # Sample j is element j * step of the whole (planes, n) array: a chunk's samples in one plane are a strided
        # slice of its rows and a contiguous run of ``out``. Not masks of every sample's plane and pixel per chunk:
        # 38 chunks' masks over 200,000 samples took ~35 ms of the main thread per 640x480 level.
        for s, part in zip(self.slices, a.arrays):
            rows = part.reshape(planes, -1)
            for plane in range(planes):
                first, end = plane * self.n + s.start, plane * self.n + s.stop  # this chunk's part of the plane
                j0, j1 = -(-first // step), -(-end // step)  # the samples in [first, end)
                if j1 > j0:
                    out[j0:j1] = rows[plane, j0 * step - first :: step]
        return out

    def shading(
        self, t: np.ndarray, tu: np.ndarray, tv: np.ndarray, derivatives: bool = False
    ) -> Parts | tuple[Parts, Parts, Parts, Parts]:
        return self._parts(self._map("shading", t, tu, tv, derivatives))

    def fix_disk_ratio(self, t: np.ndarray, tu: np.ndarray, tv: np.ndarray) -> None:
        self._map("fix_disk_ratio", t, tu, tv)

    def residuals(self, F: Array | Parts, albedo: Array | Parts) -> Parts:
        return self._parts(self._map("residuals", F, albedo))

    def data_energy(self, r: Array | Parts, lam: float, estimator: str) -> float:
        return float(sum(self._map("data_energy", r, lam, estimator)))

    def energy(self, F: Array | Parts, albedo: Array | Parts, lam: float, estimator: str) -> float:
        return float(sum(self._map("energy", F, albedo, lam, estimator)))

    def weights(self, r: Array | Parts, lam: float, estimator: str) -> Parts:
        return self._parts(self._map("weights", r, lam, estimator))

    def albedo(self, F: Array | Parts, w: Array | Parts) -> Parts:
        return self._parts(self._map("albedo", F, w))

    def refit(
        self, F: Array | Parts, albedo: Array | Parts | None, lam: float | None, estimator: str, energy: bool = False
    ) -> tuple[Parts, Parts, float | None]:
        """:meth:`Model.refit` chunk by chunk, in one pass over the chunks: 0.115 s instead of 0.148 s of CPU
        for an IRLS refit and energy on 307,200 pixels (12 LEDs, float32, 2 threads), the same bits (the energy
        summed over the chunks in their order, as :meth:`data_energy`)."""
        outs = self._map("refit", F, albedo, lam, estimator, energy)
        fit, r = Parts([o[0] for o in outs]), Parts([o[1] for o in outs])
        return fit, r, float(sum(o[2] for o in outs)) if energy else None

    def gradient_curvature(self, dF: Sequence[Array | Parts], albedo: Array | Parts, w: Array | Parts) -> np.ndarray:
        return self._join(self._map("gradient_curvature", dF, albedo, w))

    def fit_sums(self, r: Array | Parts, lam: float, estimator: str) -> tuple[np.ndarray, np.ndarray]:
        return self._join(self._map("fit_sums", r, lam, estimator))

    def gauss_newton_blocks(
        self,
        F: Array | Parts,
        dF: Sequence[Array | Parts],
        r: Array | Parts,
        w: Array | Parts,
        albedo: Array | Parts,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Model.gauss_newton_blocks`, each chunk's written into its pixels of the whole blocks (no chunk
        arrays joined: 29 MB of float64 at 640x480 made twice, where a whole frame's memory peaks)."""
        return self._blocks("gauss_newton_blocks", F, dF, r, w, albedo)

    def irls_blocks(
        self,
        F: Array | Parts,
        dF: Sequence[Array | Parts],
        r: Array | Parts,
        albedo: Array | Parts,
        lam: float,
        estimator: str,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Model.irls_blocks` chunk by chunk, written into the whole blocks as :meth:`gauss_newton_blocks`."""
        return self._blocks("irls_blocks", F, dF, r, albedo, lam, estimator)

    def _blocks(self, name: str, *args) -> tuple[np.ndarray, np.ndarray]:
        """Model method ``name`` (a blocks method taking ``out``) of each chunk, into its pixels of whole blocks."""
        M, b = np.empty((3, 3, self.n)), np.empty((3, self.n))
        self._threads.map_items(
            lambda k: getattr(self.parts[k], name)(
                *(self._cut(a, k) for a in args), out=(M[..., self.slices[k]], b[:, self.slices[k]])
            ),
            range(len(self.parts)),
        )
        return M, b


def make_model(be: Backend, q: np.ndarray, *args: np.ndarray) -> Model | ChunkedModel:
    """:class:`ChunkedModel` for large levels on the numpy backend, else :class:`Model`."""
    if be.name == "numpy" and q.shape[0] >= PARALLEL_MIN_PIXELS:
        return ChunkedModel(be, q, *args)
    return Model(be, q, *args)


def _dot3(xp: ModuleType, a: Sequence[Array], b: Sequence[Array]) -> Array:
    """``a[0] * b[0] + a[1] * b[1] + a[2] * b[2]`` (broadcast), summed in that order into one new array."""
    out = a[0] * b[0]
    term = a[1] * b[1]
    out += term
    xp.multiply(a[2], b[2], out=term)
    out += term
    return out
