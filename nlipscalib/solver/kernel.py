"""Per-pixel image model, residuals and Gauss-Newton blocks, written once for numpy and torch.

Everything here works on flat pixel lists (N pixels inside the solve mask) and is elementwise or a
sum over LEDs, so the same code runs on numpy arrays (CPU) and torch tensors (CPU or GPU). The sparse
assembly and the linear solve stay in scipy/pyamg (see :mod:`nlipscalib.solver.nlips`).

Model (Quéau et al. 2018), LED i, channel c, log-depth t, x = exp(t) q, N = -(t_u A + t_v B + C)::

    I_ic = rho_c * Psi_ic * F_i,   F_i = (n_s . d)^mu * max(0, (x_s - x) . N) / (|N| |x_s - x|^3)
"""

from __future__ import annotations

import numpy as np

from . import robust


class Backend:
    """Array namespace shim: numpy, or torch on a device."""

    def __init__(self, name: str = "numpy", dtype: str = "float64", device: str | None = None):
        self.name = name
        if name == "numpy":
            self.xp = np
            self.dtype = np.dtype(dtype)
        elif name == "torch":
            from ..errors import require

            torch = require("torch", "torch", "The torch solver backend")
            self.xp = torch
            self.dtype = getattr(torch, dtype)
            self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
        else:
            from ..errors import ConfigError

            raise ConfigError(f"backend must be 'numpy' or 'torch', got {name!r}")

    def asarray(self, a):
        if self.name == "numpy":
            return np.ascontiguousarray(a, dtype=self.dtype)
        return self.xp.as_tensor(np.ascontiguousarray(a), dtype=self.dtype, device=self.device)

    def numpy(self, a) -> np.ndarray:
        if self.name == "numpy":
            return np.asarray(a, dtype=np.float64)
        return a.detach().to("cpu", self.xp.float64).numpy()

    def relu(self, a):
        return np.maximum(a, 0) if self.name == "numpy" else self.xp.clamp(a, min=0)

    def total(self, a) -> float:
        """Sum in float64 whatever the working precision."""
        if self.name == "numpy":
            return float(np.sum(a, dtype=np.float64))
        return float(a.sum(dtype=self.xp.float64))


class Model:
    """The image model on one pyramid level, with data held on the backend."""

    def __init__(self, be: Backend, q, A, B, C, positions, directions, mu, psi, images, usable):
        """q, A, B, C : (N, 3); positions, directions : (L, 3); mu : (L,); psi : (L, 3);
        images, usable : (L, 3, N) (usable as 0/1)."""
        self.be = be
        self.q = [be.asarray(q[:, k]) for k in range(3)]
        self.A = [be.asarray(A[:, k]) for k in range(3)]
        self.B = [be.asarray(B[:, k]) for k in range(3)]
        self.C = [be.asarray(C[:, k]) for k in range(3)]
        self.pos = [be.asarray(positions[:, k : k + 1]) for k in range(3)]
        self.dir = [be.asarray(directions[:, k : k + 1]) for k in range(3)]
        self.mu = be.asarray(mu[:, None])
        self.psi = be.asarray(psi[:, :, None])
        self.images = be.asarray(images)
        self.usable = be.asarray(usable)

    def shading(self, t, tu, tv, derivatives: bool = False):
        """F : (L, N) and, if asked, dF/dt, dF/dt_u, dF/dt_v : (L, N) each (zero where unlit)."""
        be, xp = self.be, self.be.xp
        t, tu, tv = be.asarray(t), be.asarray(tu), be.asarray(tv)
        z = xp.exp(t)
        x = [z * qk for qk in self.q]
        nv = [-(tu * a + tv * b + c) for a, b, c in zip(self.A, self.B, self.C)]
        nn2 = nv[0] ** 2 + nv[1] ** 2 + nv[2] ** 2
        nn = xp.sqrt(nn2)
        v = [p - xk for p, xk in zip(self.pos, x)]  # x_s - x, (L, N)
        r2 = v[0] ** 2 + v[1] ** 2 + v[2] ** 2
        r = xp.sqrt(r2)
        vn = v[0] * nv[0] + v[1] * nv[1] + v[2] * nv[2]
        nsv = self.dir[0] * v[0] + self.dir[1] * v[1] + self.dir[2] * v[2]
        cos_led = -nsv / r
        lit = (vn > 0) & (cos_led > 0)
        aniso = be.relu(cos_led) ** self.mu
        F = xp.where(lit, aniso * be.relu(vn) / (nn * r2 * r), 0 * r)
        if not derivatives:
            return F
        safe_vn = xp.where(lit, vn, 0 * vn + 1)
        safe_cos = xp.where(lit, cos_led, 0 * vn + 1)
        vx = v[0] * x[0] + v[1] * x[1] + v[2] * x[2]
        nsx = self.dir[0] * x[0] + self.dir[1] * x[1] + self.dir[2] * x[2]
        xn = x[0] * nv[0] + x[1] * nv[1] + x[2] * nv[2]
        dcos_dt = nsx / r - nsv * vx / (r2 * r)
        dlog_t = self.mu * dcos_dt / safe_cos - xn / safe_vn + 3 * vx / r2
        av = self.A[0] * v[0] + self.A[1] * v[1] + self.A[2] * v[2]
        bv = self.B[0] * v[0] + self.B[1] * v[1] + self.B[2] * v[2]
        na = (nv[0] * self.A[0] + nv[1] * self.A[1] + nv[2] * self.A[2]) / nn2
        nb = (nv[0] * self.B[0] + nv[1] * self.B[1] + nv[2] * self.B[2]) / nn2
        dlog_u = -av / safe_vn + na
        dlog_v = -bv / safe_vn + nb
        return F, F * dlog_t, F * dlog_u, F * dlog_v

    def residuals(self, F, albedo):
        """r : (L, 3, N) = rho_c Psi_ic F_i - I_ic (albedo : (3, N) on the backend)."""
        return albedo[None] * self.psi * F[:, None] - self.images

    def energy(self, F, albedo, lam: float, estimator: str, usable=None) -> float:
        """Robust data energy over the usable samples (``usable`` overrides the model's mask)."""
        r = self.residuals(F, albedo)
        use = self.usable if usable is None else usable
        return self.be.total(use * robust.rho(r, lam, estimator, self.be.xp))

    def weights(self, r, lam: float, estimator: str, usable=None):
        """IRLS weights, zero on excluded samples: (L, 3, N)."""
        use = self.usable if usable is None else usable
        return use * robust.weight(r, lam, estimator, self.be.xp)

    def albedo(self, Fs, ws):
        """Closed-form per-pixel, per-channel albedo minimising the weighted data term: (3, N).

        ``Fs`` and ``ws`` are lists (one per difference stencil) whose terms are summed."""
        xp = self.be.xp
        num = den = 0
        for F, w in zip(Fs, ws):
            S = self.psi * F[:, None]
            num = num + (w * S * self.images).sum(0)
            den = den + (w * S * S).sum(0)
        ok = den > 1e-30
        return xp.where(ok, num / xp.where(ok, den, 0 * den + 1), 0 * den)

    def gauss_newton_blocks(self, dF, r, w, albedo):
        """Per-pixel 3x3 normal-equation blocks and right-hand sides, summed over LEDs and channels.

        Returns (numpy) M : (3, 3, N), b : (3, N) with J^T W J = sum_ab P_a^T diag(M_ab) P_b and
        J^T W r = sum_a P_a^T b_a, where P = (identity, D_u, D_v).
        """
        g = albedo[None] * self.psi  # dr/dF, (L, 3, N)
        K = (w * g * g).sum(1)  # (L, N)
        R = (w * r * g).sum(1)
        be = self.be
        M = np.empty((3, 3, K.shape[1]))
        b = np.empty((3, K.shape[1]))
        for a in range(3):
            b[a] = be.numpy((R * dF[a]).sum(0))
            for c in range(a, 3):
                M[a, c] = M[c, a] = be.numpy((K * dF[a] * dF[c]).sum(0))
        return M, b
