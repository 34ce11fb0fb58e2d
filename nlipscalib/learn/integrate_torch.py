"""Normal integration on the dome in PyTorch, on any device: the changed pixels' box, or the whole gel.

Both solve the equation of :mod:`.integrate` (5-point Poisson in the log-range along the camera's real
rays, gradients averaged on each pixel pair; :func:`.integrate.box_rhs` is shared).

- :class:`BoxIntegrator`: the CPU's box solver (the changed pixels' box, its outer ring at the reference),
  its type-I sine transforms by torch's FFT on a CPU and by dense matrix products on a GPU (no cuFFT plan per
  box size).
- :class:`DomeIntegrator`: every gel pixel whose four neighbours are on the gel; the gel's outermost pixel
  ring is the Dirichlet boundary, held at the undeformed reference (the gel is fixed where it meets the
  dome's base; where the gel fills the image, the ring is the image border). Where that domain is not a
  rectangle, the fast sine-transform solver of its bounding box is corrected on the boundary ring with a
  precomputed capacitance matrix -- the capacitance-matrix method for the discrete Poisson equation on
  irregular regions (Buzbee, Dorr, George & Golub, SIAM J. Numer. Anal. 8(4), 1971): per frame two box
  solves and one (b, b) matrix-vector product (b: ring pixels inside the box), exact up to rounding, no
  iterations; set up once per sensor with b box solves (batched: under a second on a GPU, about a minute
  on two CPU cores at 640x480). A gel that fills the image needs one box solve and no set-up.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import ShapeError, require
from .integrate import MIN_FACING, RayGeometry, _box, box_eigenvalues, box_rhs

RECORD_AFTER = 3
"""A box size is recorded as a CUDA graph when it comes the third time, solved eagerly before: a contact that
moves or grows brings a new box size nearly every frame, and recording one costs several eager solves (its
warm-up runs and a memory pool of its own; benchmarks/RESULTS.md), while a held contact repeats its size."""
SETUP_BATCH_BYTES = 1 << 29
"""Memory of one batch of box solves while the capacitance matrix is set up (float64 boxes)."""


def _torch():
    return require("torch", "torch", "Normal integration in PyTorch")


def dst1(x, dim: int):
    """Orthonormal type-I discrete sine transform of a torch tensor along ``dim`` (its own inverse).

    Through a real FFT of the odd extension [0, x, 0, -reversed x] (length 2(n + 1)): torch has no DST;
    equals ``scipy.fft.dst(x, type=1, norm="ortho", axis=dim)``.
    """
    torch = _torch()
    x = x.movedim(dim, -1)
    n = x.shape[-1]
    zero = torch.zeros(x.shape[:-1] + (1,), dtype=x.dtype, device=x.device)
    odd = torch.cat([zero, x, zero, -x.flip(-1)], dim=-1)
    out = torch.fft.rfft(odd, dim=-1).imag[..., 1 : n + 1] * (-1.0 / math.sqrt(2 * (n + 1)))
    return out.movedim(-1, dim)


@functools.lru_cache(maxsize=64)
def dst1_matrix(n: int, device, dtype):
    """(n, n) matrix of the orthonormal type-I DST (symmetric, its own inverse): ``S @ x`` is :func:`dst1` along
    the first axis. Its sines are taken of exact arguments (the index product reduced modulo the period)."""
    torch = _torch()
    k = torch.arange(1, n + 1, dtype=torch.int64)
    phase = (k[:, None] * k[None, :]) % (2 * (n + 1))
    s = math.sqrt(2.0 / (n + 1)) * torch.sin(phase.to(torch.float64) * (math.pi / (n + 1)))
    return s.to(device=device, dtype=dtype)


class BoxPoisson:
    """Solver of the 5-point Dirichlet Laplacian (4 x_i - sum of neighbours = f) on an (m, n) box, zero outside.

    ``dense``: the sine transforms as matrix products (:func:`dst1_matrix`) instead of FFTs. On a GPU a box of a
    new size then costs no cuFFT plan: 34 ms the first time a size came on an H200, against 1 ms once planned,
    and a moving contact brings a new box size nearly every frame (benchmarks/RESULTS.md). On a CPU the FFT is
    the faster.
    """

    def __init__(self, m: int, n: int, device, dtype, dense: bool = False):
        self.lam = _torch().as_tensor(box_eigenvalues(m, n), dtype=dtype, device=device)
        self.dense = (dst1_matrix(m, device, dtype), dst1_matrix(n, device, dtype)) if dense else None

    def __call__(self, f):
        """x with L x = f; ``f`` is (..., m, n)."""
        if self.dense is not None:
            s_m, s_n = self.dense
            return s_m @ ((s_m @ f @ s_n) / self.lam) @ s_n
        return dst1(dst1(dst1(dst1(f, -2), -1) / self.lam, -2), -1)


class BoxIntegrator:
    """:mod:`.integrate`'s box solver on a torch device: the changed pixels' box (grown to fast transform sizes,
    :func:`.integrate._box`), its interior solved with the outer ring at the reference, in float32 like the CPU's.

    Parameters
    ----------
    geo : RayGeometry of the sensor
    device : torch device
    """

    def __init__(self, geo: RayGeometry, device):
        torch = _torch()
        self.seen: dict[tuple[int, int], int] = {}
        """How often each box size (h, w) has come (recorded at :data:`RECORD_AFTER`)."""
        self.on_gel = np.isfinite(geo.log_range)
        self.width = geo.log_range.shape[1]
        self.log_range = torch.as_tensor(geo.log_range.astype(np.float32), device=device).flatten()
        self.rays, self.d_u, self.d_v = (
            torch.as_tensor(a, device=device).reshape(-1, 3) for a in (geo.rays32, geo.d_u32, geo.d_v32)
        )
        self.device = device

    def box(self, changed: np.ndarray):
        """The box for ``changed`` ((H, W) bool on the gel), or None when it leaves the gel or touches the border."""
        return _box(changed, self.on_gel)

    def __call__(self, normals, box):
        """(h, w, 3) float32 tensor: the surface points over ``box`` from ``normals`` ((H, W, 3) tensor).

        On a GPU, a box size that keeps coming is recorded as a CUDA graph (the box's place is an input) at its
        :data:`RECORD_AFTER`-th frame; every later frame of that size is one launch. The others are solved
        eagerly, with the same results.
        """
        h, w = box[0].stop - box[0].start, box[1].stop - box[1].start
        offset = box[0].start * self.width + box[1].start
        replay = self._graph(h, w) if self._recorded(h, w) else None
        if replay is None:
            return self._solve(normals, self._index(h, w) + offset)
        frame_normals, place = replay.inputs
        frame_normals.copy_(normals)
        place.fill_(offset)
        return replay()

    def warm_up(self, normals) -> None:
        """Solve one small box in the gel's middle, uncounted: the first box of a stream would otherwise load the
        path's GPU kernels (CUDA loads a kernel on its first use; a stream's first box took 0.36-0.58 s on an
        H200, benchmarks/RESULTS.md). ``normals``: an (H, W, 3) tensor on the device."""
        from scipy.ndimage import distance_transform_edt

        inside = distance_transform_edt(np.pad(self.on_gel, 1))[1:-1, 1:-1]  # the image's border counts as an edge
        middle = np.unravel_index(np.argmax(inside), self.on_gel.shape)
        seed = np.zeros_like(self.on_gel)
        seed[middle[0] - 2 : middle[0] + 3, middle[1] - 2 : middle[1] + 3] = True
        box = self.box(seed & self.on_gel) if (seed & self.on_gel).any() else None
        if box is not None:
            h, w = box[0].stop - box[0].start, box[1].stop - box[1].start
            self._solve(normals, self._index(h, w) + (box[0].start * self.width + box[1].start))

    def _recorded(self, h: int, w: int) -> bool:
        """Whether this frame's (h, w) box runs as a recorded graph (this frame counted)."""
        if self.device.type != "cuda":
            return False
        self.seen[(h, w)] = self.seen.get((h, w), 0) + 1
        return self.seen[(h, w)] >= RECORD_AFTER

    def _solve(self, normals, index):
        """Points over the box whose flat pixel indices are ``index`` ((h, w) long tensor)."""
        torch = _torch()
        rays = self.rays[index]
        x = self.log_range[index]  # a copy: the reference, whose interior is replaced below
        f = box_rhs(normals.reshape(-1, 3)[index], rays, self.d_u[index], self.d_v[index], x)
        x[1:-1, 1:-1] = self._solver(*f.shape)(f)
        return torch.exp(x)[..., None] * rays

    @functools.lru_cache(maxsize=32)  # noqa: B019 -- one per box size; the instance lives as long as the model
    def _solver(self, m: int, n: int) -> BoxPoisson:
        # on a GPU as matrix products: a box of a new size would otherwise wait for its cuFFT plans
        return BoxPoisson(m, n, self.device, _torch().float32, dense=self.device.type == "cuda")

    @functools.lru_cache(maxsize=32)  # noqa: B019
    def _index(self, h: int, w: int):
        """(h, w) flat pixel indices of a box at the image's corner (add its place's flat index)."""
        torch = _torch()
        return torch.arange(h, device=self.device)[:, None] * self.width + torch.arange(w, device=self.device)

    @functools.lru_cache(maxsize=32)  # noqa: B019
    def _graph(self, h: int, w: int):
        """The solve of an (h, w) box recorded as a CUDA graph; inputs: the normal map and the box's flat place."""
        torch = _torch()
        from .cuda_graph import record

        normals = torch.zeros(self.on_gel.shape + (3,), dtype=torch.float32, device=self.device)
        place = torch.zeros((), dtype=torch.long, device=self.device)
        solve = lambda n, o: self._solve(n, self._index(h, w) + o)  # noqa: E731
        return record(solve, (normals, place), self.device, "The changed pixels' box solve")


class DomeIntegrator:
    """Log-range of the whole gel from a normal map, on a torch device (module docstring).

    The box solver works on the bounding box of the inner gel pixels, whose outer frame is ring or off the
    gel; the ring pixels inside the box (where the gel's outline is not that rectangle) are held by the
    capacitance correction. A gel that fills the image needs none: one box solve per frame, no set-up.

    Parameters
    ----------
    geo : RayGeometry of the sensor (rays, their derivatives, the undeformed log-range; NaN off the gel)
    device : torch device
    """

    def __init__(self, geo: RayGeometry, device):
        torch = _torch()
        self.device, dt = device, torch.float64
        on_gel = np.isfinite(geo.log_range)
        inner = _inner(on_gel)
        if not inner.any():
            raise ShapeError("the gel has no pixel whose four neighbours are on the gel: nothing to integrate")
        rows, cols = np.nonzero(inner)
        r0, r1, c0, c1 = int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1
        self.box = (slice(r0, r1), slice(c0, c1))
        # the box and its frame (inner pixels never touch the image border, so the frame is in the image)
        self.framed = (slice(r0 - 1, r1 + 1), slice(c0 - 1, c1 + 1))

        def put(a):
            return torch.as_tensor(np.ascontiguousarray(a), device=device)

        ref = np.where(on_gel, geo.log_range, 0.0)
        self.ref = put(ref[self.box])
        self.inner = put(inner[self.box])
        ring = _dilate4(inner) & ~inner
        self.ring = put(np.flatnonzero(ring[self.box]))  # ring pixels inside the box
        # the framed box's rays and their derivatives, for the log-range gradient of a normal map
        self.rays, self.d_u, self.d_v = (put(a[self.framed]).to(dt) for a in (geo.rays, geo.d_u, geo.d_v))
        self.points_ref = put(np.where(on_gel[..., None], geo.points, np.nan).astype(np.float32))
        self.solve = BoxPoisson(*self.ref.shape, device, dt)
        self.ref_laplacian = _laplacian(put(ref[self.framed]))[1:-1, 1:-1] * self.inner
        self.capacitance_inverse = self._capacitance_inverse() if len(self.ring) else None
        # the inner pixels by index (boolean-mask indexing waits for the device; a CUDA graph cannot)
        self.inner_in_box = put(np.flatnonzero(inner[self.box]))
        self.inner_in_image = put(np.flatnonzero(inner))
        self.inner_rays = put(geo.rays[inner])

    def _capacitance_inverse(self):
        """(b, b) inverse of the box solver's response at the ring to unit sources at the ring."""
        torch = _torch()
        m, n = self.ref.shape
        b = len(self.ring)
        chunk = max(1, min(b, SETUP_BATCH_BYTES // (8 * 4 * (m + 1) * (n + 1))))
        green = torch.empty((b, b), dtype=torch.float64, device=self.device)
        for start in range(0, b, chunk):
            idx = self.ring[start : start + chunk]
            sources = torch.zeros((len(idx), m * n), dtype=torch.float64, device=self.device)
            sources[torch.arange(len(idx), device=self.device), idx] = 1.0
            green[start : start + len(idx)] = self.solve(sources.view(-1, m, n)).view(-1, m * n)[:, self.ring]
        return torch.linalg.inv(green)

    def log_range(self, normals):
        """(m, n) float64 log-range over :attr:`box` from ``normals`` ((H, W, 3) float tensor, unit, camera frame).

        Inner gel pixels are solved, the ring and the rest of the gel keep the reference.
        """
        torch = _torch()
        nb = normals[self.framed].to(torch.float64)
        den = torch.clamp_max((nb * self.rays).sum(-1), -MIN_FACING)
        p = -(nb * self.d_u).sum(-1) / den
        q = -(nb * self.d_v).sum(-1) / den
        # f = (incoming - outgoing edge gradients) at each pixel of the box; the reference to the right-hand side
        gu = 0.5 * (p[1:-1, :-1] + p[1:-1, 1:])  # edge (r, c) -> (r, c + 1)
        gv = 0.5 * (q[:-1, 1:-1] + q[1:, 1:-1])  # edge (r, c) -> (r + 1, c)
        f = gu[:, :-1] - gu[:, 1:] + gv[:-1, :] - gv[1:, :]
        rhs = (f - self.ref_laplacian) * self.inner  # the change from the reference: zero on the ring
        change = self.solve(rhs)
        if self.capacitance_inverse is not None:  # sources on the ring that bring the change there back to zero
            held = -(self.capacitance_inverse @ change.flatten()[self.ring])
            change = self.solve(rhs.flatten().index_add(0, self.ring, held).view_as(rhs))
        return self.ref + change * self.inner

    def __call__(self, normals):
        """(H, W, 3) float32 tensor: the surface points, mm, camera frame (NaN off the gel); depth is their z."""
        torch = _torch()
        points = self.points_ref.clone()
        lr = self.log_range(normals).flatten()[self.inner_in_box]
        points.view(-1, 3)[self.inner_in_image] = (torch.exp(lr)[:, None] * self.inner_rays).to(torch.float32)
        return points


def _inner(on_gel: np.ndarray) -> np.ndarray:
    """Gel pixels whose four neighbours are gel pixels (none on the image border)."""
    inner = on_gel.copy()
    inner[0, :] = inner[-1, :] = inner[:, 0] = inner[:, -1] = False
    inner[1:-1, 1:-1] &= on_gel[:-2, 1:-1] & on_gel[2:, 1:-1] & on_gel[1:-1, :-2] & on_gel[1:-1, 2:]
    return inner


def _dilate4(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out


def _laplacian(x):
    """4 x_i - sum of the four neighbours (zero beyond the array), as :class:`BoxPoisson` defines it."""
    out = 4 * x
    out[1:] -= x[:-1]
    out[:-1] -= x[1:]
    out[:, 1:] -= x[:, :-1]
    out[:, :-1] -= x[:, 1:]
    return out
