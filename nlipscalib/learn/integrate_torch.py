"""Normal integration on the dome in PyTorch, on any device: the changed pixels' box, or the whole gel.

Both solve the equation of :mod:`.integrate` (5-point Poisson in the log-range along the camera's real
rays, gradients averaged on each pixel pair; :func:`.integrate_box.edge_box_rhs` is shared).

- :class:`BoxIntegrator`: the CPU's box solver (the changed pixels' box, its outer ring at the reference;
  else per region a box, an edge box mirrored across the image border, a box across the image with a cosine
  axis, or a rim box with the CPU's capacitance matrix: the same boxes and equations as
  :func:`.integrate.integrate_on_dome`'s "auto"), its sine (and cosine) transforms by torch's FFT on a CPU and
  by dense matrix products on a GPU (no cuFFT plan per box size). The regions the CPU solves otherwise (its
  sparse path, and its rim boxes at the image border or anchored: rare on a real sensor) are solved by the CPU's
  own code on the host (:meth:`BoxIntegrator.on_host`, :func:`.integrate.solve_region_group`).
- :class:`DomeIntegrator`: every gel pixel whose neighbours in the image are all on the gel. The gel pixels
  next to them that meet the dome's base (an off-gel pixel) are the Dirichlet boundary, held at the undeformed
  reference: the gel is fixed there. The image border is a natural (Neumann) boundary: the surface there is
  free (a contact that reaches the border displaces it; holding it at the reference made such contacts
  1.4-2.6 % too shallow at 640x480) and only the pixel pairs inside the image enter the equation, as on
  the CPU's sparse path. A box whose side is at the image border is solved with the type-II cosine
  transform along that axis, one whose sides are held with the type-I sine transform. Where the domain is
  not that rectangle, the box solver is corrected on the held pixels inside it with a precomputed
  capacitance matrix -- the capacitance-matrix method for the discrete Poisson equation on irregular
  regions (Buzbee, Dorr, George & Golub, SIAM J. Numer. Anal. 8(4), 1971): per frame two box solves and
  one (b, b) matrix-vector product (b: held pixels inside the box), exact up to rounding, no iterations;
  set up once per sensor with b box solves (batched: under a second on a GPU, about a minute on two CPU
  cores at 640x480). A gel that fills the image has no held pixel: one box solve, no set-up, and nothing
  fixes its level but the pixels that did not change, whose mean change is set to zero (the least-squares
  level shift over them).
"""

from __future__ import annotations

import collections
import functools
import math
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..core.errors import ShapeError, require
from ..core.tolerances import INTEGRATION_MIN_FACING
from .integrate import solve_region_group
from .integrate_box import box_eigenvalues, edge_box_parts, edge_box_rhs
from .integrate_geometry import RayGeometry
from .integrate_regions import BOTH_SIDES, Box, Edges, _box, _crop_edges, _regions
from .integrate_rim import _faster_rim_box, _rim_box_anchor, rim_box_capacitance, rim_box_rhs, rim_box_solve

if TYPE_CHECKING:  # torch is optional and imported where it is used (``_torch``): named for the hints only
    import torch

RECORD_AFTER = 3
"""A box size is recorded as a CUDA graph when it comes the third time, solved eagerly before: a contact that
moves or grows brings a new box size nearly every frame, and recording one costs several eager solves (its
warm-up runs and a memory pool of its own; benchmarks/RESULTS.md), while a held contact repeats its size."""
SIZES_COUNTED = 1024
"""Box sizes whose frames :class:`BoxIntegrator` counts toward :data:`RECORD_AFTER`, the most recently come (a size
that drops out counts anew: at most RECORD_AFTER - 1 more eager solves). Why a bound: a contact that moves and grows
through a stream of hours brings thousands of box sizes, and their counts were kept forever."""
SETUP_BATCH_BYTES = 1 << 29
"""Memory of one batch of box solves while the capacitance matrix is set up (float64 boxes)."""


def _torch():
    return require("torch", "torch", "Normal integration in PyTorch")


def dst1(x: torch.Tensor, dim: int) -> torch.Tensor:
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


def dct2(x: torch.Tensor, dim: int) -> torch.Tensor:
    """Orthonormal type-II discrete cosine transform of a torch tensor along ``dim``; :func:`idct2` inverts it.

    Through one complex FFT of length n of the reordered [x0, x2, x4, ..., x5, x3, x1] (Makhoul, IEEE Trans.
    ASSP 28(1), 1980): torch has no DCT; equals ``scipy.fft.dct(x, type=2, norm="ortho", axis=dim)``.
    """
    torch = _torch()
    x = x.movedim(dim, -1)
    n = x.shape[-1]
    v = torch.cat([x[..., 0::2], x[..., 1::2].flip(-1)], dim=-1)
    out = (torch.fft.fft(v, dim=-1) * _twiddle(n, -1.0, x)).real * math.sqrt(2.0 / n)
    out[..., 0] *= math.sqrt(0.5)
    return out.movedim(-1, dim)


def idct2(y: torch.Tensor, dim: int) -> torch.Tensor:
    """Inverse of :func:`dct2` (the orthonormal type-III DCT) along ``dim``, by one complex inverse FFT."""
    torch = _torch()
    y = y.movedim(dim, -1)
    n = y.shape[-1]
    c = torch.cat([y[..., :1] * math.sqrt(n), y[..., 1:] * math.sqrt(n / 2.0)], dim=-1)  # sum x_j cos(...)
    mirrored = torch.cat([torch.zeros_like(c[..., :1]), c[..., 1:].flip(-1)], dim=-1)  # c[n - k], c[n] = 0
    v = torch.fft.ifft(_twiddle(n, 1.0, y) * torch.complex(c, -mirrored), dim=-1).real
    half = (n + 1) // 2
    x = torch.empty_like(v)
    x[..., 0::2] = v[..., :half]
    x[..., 1::2] = v[..., half:].flip(-1)
    return x.movedim(-1, dim)


def _twiddle(n: int, sign: float, like: torch.Tensor):
    """(n,) complex exp(sign i pi k / 2n) of ``like``'s dtype and device."""
    torch = _torch()
    k = torch.arange(n, dtype=like.dtype, device=like.device)
    return torch.polar(torch.ones_like(k), k * (sign * math.pi / (2 * n)))


@functools.lru_cache(maxsize=64)
def dst1_matrix(n: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(n, n) matrix of the orthonormal type-I DST (symmetric, its own inverse): ``S @ x`` is :func:`dst1` along
    the first axis. Its sines are taken of exact arguments (the index product reduced modulo the period)."""
    torch = _torch()
    k = torch.arange(1, n + 1, dtype=torch.int64)
    phase = (k[:, None] * k[None, :]) % (2 * (n + 1))
    s = math.sqrt(2.0 / (n + 1)) * torch.sin(phase.to(torch.float64) * (math.pi / (n + 1)))
    return s.to(device=device, dtype=dtype)


@functools.lru_cache(maxsize=64)
def dct2_matrix(n: int, device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(n, n) matrix of the orthonormal type-II DCT (its transpose inverts it): ``C @ x`` is :func:`dct2` along
    the first axis. Its cosines are taken of exact arguments (the index product reduced modulo the period)."""
    torch = _torch()
    k = torch.arange(n, dtype=torch.int64)
    phase = (k[:, None] * (2 * k[None, :] + 1)) % (4 * n)
    c = math.sqrt(2.0 / n) * torch.cos(phase.to(torch.float64) * (math.pi / (2 * n)))
    c[0] *= math.sqrt(0.5)
    return c.to(device=device, dtype=dtype)


class BoxPoisson:
    """Solver of the 5-point Laplacian (deg x_i - sum of neighbours = f) on an (m, n) box.

    Per axis (rows, columns): zero beyond both ends (Dirichlet: the type-I sine transform, deg 4 in the box's
    interior), or with ``neumann`` no neighbour beyond them (natural boundary: the type-II cosine transform;
    a pixel's degree counts its neighbours in the box). Neumann on both axes leaves the constant free: the
    solve then drops it (the least-norm solution, zero mean; exact where ``f`` sums to zero).

    ``dense``: the transforms as matrix products (:func:`dst1_matrix`, :func:`dct2_matrix`) instead of FFTs.
    On a GPU a box of a new size then costs no cuFFT plan: 34 ms the first time a size came on an H200,
    against 1 ms once planned, and a moving contact brings a new box size nearly every frame
    (benchmarks/RESULTS.md). On a CPU the FFT is the faster.
    """

    def __init__(
        self,
        m: int,
        n: int,
        device: torch.device,
        dtype: torch.dtype,
        dense: bool = False,
        neumann: tuple[bool, bool] = (False, False),
    ):
        lam = box_eigenvalues(m, n, neumann)
        lam[0, 0] = np.inf if all(neumann) else lam[0, 0]  # the constant's eigenvalue 0: its coefficient dropped
        self.lam = _torch().as_tensor(lam, dtype=dtype, device=device)
        self.neumann = neumann
        self.dense = [_axis_matrices(k, neumann[i], device, dtype) for i, k in enumerate((m, n))] if dense else None

    def __call__(self, f: torch.Tensor) -> torch.Tensor:
        """x with L x = f; ``f`` is (..., m, n)."""
        if self.dense is not None:
            (c_m, ct_m), (c_n, ct_n) = self.dense  # C x along the rows; x C^T along the columns
            return ct_m @ ((c_m @ f @ ct_n) / self.lam) @ c_n
        (fwd_m, inv_m), (fwd_n, inv_n) = ((dct2, idct2) if nm else (dst1, dst1) for nm in self.neumann)
        return inv_n(inv_m(fwd_n(fwd_m(f, -2), -1) / self.lam, -2), -1)


def _axis_matrices(n: int, neumann: bool, device: torch.device, dtype: torch.dtype):
    """(C, C^T): one axis's (n, n) orthonormal transform matrix of :class:`BoxPoisson` and its inverse."""
    if not neumann:
        s = dst1_matrix(n, device, dtype)
        return s, s
    c = dct2_matrix(n, device, dtype)
    return c, c.mT.contiguous()


class RecentCounts(collections.OrderedDict):
    """How often each key has come, for the ``size`` keys that came last (least recently come dropped first).

    Parameters
    ----------
    size : most keys kept (>= 1)
    """

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = int(size)

    def add(self, key: object) -> int:
        """Count ``key`` once more; its count (1 when new, or dropped since it last came)."""
        count = self.pop(key, 0) + 1
        self[key] = count  # the most recent, at the end
        if len(self) > self.size:
            self.popitem(last=False)
        return count


class Plan(NamedTuple):
    """How :class:`BoxIntegrator` solves a frame's changed pixels: the CPU's regions (:meth:`BoxIntegrator.plan`)."""

    boxes: list[tuple[Box, Edges]]
    """Boxes and edge boxes, each with its :data:`.integrate_regions.Edges` ((0, 0): a box), solved on the device."""
    rim: list[Box]
    """Rim boxes (holding off-gel pixels; :func:`.integrate_rim._solve_rim_box`'s equation), solved on the device."""
    host: list[tuple[Box, list[Box]]]
    """Region groups solved by the CPU's code on the host (its sparse path, and a rim box at the image border or
    anchored): each group's bounds and the frame's other boxes and groups (which bound a rim box's growth)."""


class BoxIntegrator:
    """:mod:`.integrate`'s box solver on a torch device: the changed pixels' box (grown to fast transform sizes,
    :func:`.integrate_regions._box`), its interior solved with the outer ring at the reference, in float32 like the
    CPU's; where that box does not apply, the CPU's boxes and edge boxes per region (:meth:`boxes`).

    Parameters
    ----------
    geo : RayGeometry of the sensor
    device : torch device
    dense : the sine transforms as matrix products (:class:`BoxPoisson`); None: on a CUDA device
    """

    def __init__(self, geo: RayGeometry, device: torch.device, dense: bool | None = None):
        torch = _torch()
        self.seen = RecentCounts(SIZES_COUNTED)
        """How often each box size (h, w) has come (recorded at :data:`RECORD_AFTER`), of the
        :data:`SIZES_COUNTED` sizes that came last."""
        self.on_gel = np.isfinite(geo.log_range)
        self.width = geo.log_range.shape[1]
        self.log_range = torch.as_tensor(geo.log_range.astype(np.float32), device=device).flatten()
        self.rays, self.d_u, self.d_v = (
            torch.as_tensor(a, device=device).reshape(-1, 3) for a in (geo.rays32, geo.d_u32, geo.d_v32)
        )
        self.device = device
        # on a GPU as matrix products: a box of a new size would otherwise wait for its cuFFT plans
        self.dense = device.type == "cuda" if dense is None else dense
        self.geo = geo

    def box(self, changed: np.ndarray) -> tuple[slice, slice] | None:
        """The box for ``changed`` ((H, W) bool on the gel), or None when it leaves the gel or touches the border."""
        return _box(changed, self.on_gel)

    def plan(self, changed: np.ndarray) -> Plan:
        """The boxes, edge boxes (with their :data:`.integrate_regions.Edges`; a box across the image too: its cosine
        axis), rim boxes and host regions that solve ``changed`` ((H, W) bool on the gel) as
        :func:`.integrate.integrate_on_dome`'s "auto" does: its regions, and its rim box where one applies (the
        same test and the same growth). Decided on the host, like the CPU's."""
        boxes, edge_boxes, sparse = _regions(changed, self.on_gel, "auto")
        rim, host = [], []
        for i, crop in enumerate(sparse):
            others = [box for box, _ in edge_boxes] + boxes + sparse[:i] + sparse[i + 1 :]
            edges = _crop_edges(changed, crop)
            # a plain rim box on the device; one at the image border or anchored (rare) by the CPU's code
            if edges == (0, 0) and _rim_box_anchor(changed, self.on_gel, crop) == 0.0:
                rim.append(_faster_rim_box(changed, self.on_gel, crop, others))
            else:
                host.append((crop, others))
        return Plan([(b, (0, 0)) for b in boxes] + edge_boxes, rim, host)

    def rim_box(self, normals: torch.Tensor, box: Box) -> torch.Tensor:
        """(h, w, 3) float32 tensor: the surface points over a rim box (:attr:`Plan.rim`) from ``normals`` ((H, W, 3)
        tensor): the CPU's equation and arithmetic (:func:`.integrate_rim.rim_box_rhs`,
        :func:`.integrate_rim.rim_box_solve`, float64 like the CPU's), its capacitance matrix made once per box place on
        the host; NaN off the gel."""
        torch = _torch()
        r0, r1, c0, c1 = box[0].start, box[0].stop, box[1].start, box[1].stop
        rim = self._rim_system(r0, r1, c0, c1)
        index = self._index(r1 - r0, c1 - c0) + (r0 * self.width + c0)
        rays, d_u, d_v = (a[index] for a in self._geometry64)
        f = rim_box_rhs(normals.reshape(-1, 3)[index].to(torch.float64), rays, d_u, d_v, rim.known, rim.gel)
        y = rim_box_solve(f, rim.solve, rim.rim, rim.points, rim.v_t, rim.solve_capacitance)
        x = rim.reference.clone()  # NaN off the gel
        x[1:-1, 1:-1] = torch.where(rim.solved, y, x[1:-1, 1:-1])
        return torch.exp(x.to(torch.float32))[..., None] * self.rays[index]

    def on_host(
        self, normals: torch.Tensor, changed: np.ndarray, group: tuple[Box, list[Box]]
    ) -> tuple[Box, np.ndarray, np.ndarray]:
        """A region group of :attr:`Plan.host` solved by the CPU's code (:func:`.integrate.solve_region_group`,
        the frame's normals copied to the host): its box, the (h, w) bool pixels solved there and their (n, 3)
        surface points, mm, camera frame -- as the CPU path solves that group in that frame."""
        crop, others = group
        return solve_region_group(normals.cpu().numpy(), changed & self.on_gel, self.on_gel, self.geo, crop, others)

    def __call__(self, normals: torch.Tensor, box: tuple[slice, slice], edges: Edges = (0, 0)) -> torch.Tensor:
        """(h, w, 3) float32 tensor: the surface points over ``box`` from ``normals`` ((H, W, 3) tensor); an edge
        box (``edges`` of :meth:`boxes`) mirrored across the image border as on the CPU.

        On a GPU, a box size that keeps coming is recorded as a CUDA graph (the box's place is an input) at its
        :data:`RECORD_AFTER`-th frame; every later frame of that size is one launch. The others are solved
        eagerly, with the same results.
        """
        h, w = box[0].stop - box[0].start, box[1].stop - box[1].start
        offset = box[0].start * self.width + box[1].start
        replay = self._graph(h, w, edges) if self._recorded(h, w, edges) else None
        if replay is None:
            return self._solve(normals, self._index(h, w) + offset, edges)
        frame_normals, place = replay.inputs
        frame_normals.copy_(normals)
        place.fill_(offset)
        return replay()

    def warm_up(self, normals: torch.Tensor) -> None:
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

    def _recorded(self, h: int, w: int, edges: Edges = (0, 0)) -> bool:
        """Whether this frame's (h, w) box (an edge box: with its ``edges``) runs as a recorded graph (this frame
        counted)."""
        if self.device.type != "cuda":
            return False
        key = (h, w) if edges == (0, 0) else (h, w, edges)
        return self.seen.add(key) >= RECORD_AFTER

    def _solve(self, normals: torch.Tensor, index: torch.Tensor, edges: Edges = (0, 0)):
        """Points over the box whose flat pixel indices are ``index`` ((h, w) long tensor); an edge box mirrored
        across the image border on its ``edges`` sides (:func:`.integrate_box.edge_box_rhs`, the CPU's arithmetic)."""
        torch = _torch()
        rays = self.rays[index]
        x = self.log_range[index]  # a copy: the reference, whose interior is replaced below
        f = edge_box_rhs(normals.reshape(-1, 3)[index], rays, self.d_u[index], self.d_v[index], x, edges)
        own, interior = edge_box_parts(x.shape, edges)
        # an axis across the image (BOTH_SIDES) has a natural side at both ends: the cosine transform, as on the CPU
        x[interior] = self._solver(*f.shape, tuple(edge == BOTH_SIDES for edge in edges))(f)[own]
        return torch.exp(x)[..., None] * rays

    @functools.lru_cache(maxsize=32)  # noqa: B019 -- one per box size; the instance lives as long as the model
    def _solver(self, m: int, n: int, neumann: tuple[bool, bool] = (False, False)) -> BoxPoisson:
        return BoxPoisson(m, n, self.device, _torch().float32, dense=self.dense, neumann=neumann)

    @functools.lru_cache(maxsize=32)  # noqa: B019
    def _index(self, h: int, w: int):
        """(h, w) flat pixel indices of a box at the image's corner (add its place's flat index)."""
        torch = _torch()
        return torch.arange(h, device=self.device)[:, None] * self.width + torch.arange(w, device=self.device)

    @functools.cached_property
    def _geometry64(self):
        """(H * W, 3) float64 tensors of the rays and their derivatives: a rim box's arithmetic is the CPU's
        float64 (made on the first rim box)."""
        geo = self.geo
        return tuple(_torch().as_tensor(a, device=self.device).reshape(-1, 3) for a in (geo.rays, geo.d_u, geo.d_v))

    @functools.lru_cache(maxsize=8)  # noqa: B019 -- per rim box place: a held contact repeats it
    def _rim_system(self, r0: int, r1: int, c0: int, c1: int) -> _RimSystem:
        return _RimSystem(self.on_gel[r0:r1, c0:c1], self.geo.log_range[r0:r1, c0:c1], self.device, self.dense)

    @functools.lru_cache(maxsize=32)  # noqa: B019
    def _graph(self, h: int, w: int, edges: Edges = (0, 0)):
        """The solve of an (h, w) box (an edge box: with its ``edges``) recorded as a CUDA graph; inputs: the normal
        map and the box's flat place."""
        torch = _torch()
        from .cuda_graph import record

        normals = torch.zeros(self.on_gel.shape + (3,), dtype=torch.float32, device=self.device)
        place = torch.zeros((), dtype=torch.long, device=self.device)
        solve = lambda n, o: self._solve(n, self._index(h, w) + o, edges)  # noqa: E731
        return record(solve, (normals, place), self.device, "The changed pixels' box solve")


class _RimSystem:
    """What a rim box's solve needs besides the frame's normals (:meth:`BoxIntegrator.rim_box`), on the device:
    its gel pixels, the reference, the box's float64 Dirichlet solve and the capacitance matrix's LU factors
    (:func:`.integrate_rim.rim_box_capacitance`, made on the host as the CPU's)."""

    def __init__(self, gel: np.ndarray, log_range: np.ndarray, device: torch.device, dense: bool):
        torch = _torch()

        def put(a: np.ndarray):
            return torch.as_tensor(np.ascontiguousarray(a), device=device)

        self.gel, self.solved = put(gel), put(gel[1:-1, 1:-1])
        self.known = put(np.where(gel, log_range, 0.0))  # the reference log-range, 0 off the gel
        self.reference = put(np.where(gel, log_range, np.nan))
        rim, points, v_t, capacitance = rim_box_capacitance(gel)
        self.rim, self.points, self.v_t = put(rim), put(points), put(v_t)
        self.factors = torch.linalg.lu_factor(put(capacitance)) if len(rim) else None
        self.solve = BoxPoisson(gel.shape[0] - 2, gel.shape[1] - 2, device, torch.float64, dense=dense)

    def solve_capacitance(self, b: torch.Tensor) -> torch.Tensor:
        """s with C s = b ((r,) float64), C the capacitance matrix."""
        return _torch().linalg.lu_solve(*self.factors, b[:, None])[:, 0]


class DomeIntegrator:
    """Log-range of the whole gel from a normal map, on a torch device (module docstring).

    The box solver works on the bounding box of the solved pixels. Along an axis where they stay inside the
    image, the box's frame beyond them is held (the sine transform); along one where they reach the image
    border, the box's sides have no neighbour beyond (the cosine transform) and the box spans the held pixels
    too. The held pixels inside the box (where the gel's outline is not that rectangle) are held by the
    capacitance correction. A gel that fills the image needs none: one box solve per frame, no set-up.

    Parameters
    ----------
    geo : RayGeometry of the sensor (rays, their derivatives, the undeformed log-range; NaN off the gel)
    device : torch device
    """

    def __init__(self, geo: RayGeometry, device: torch.device):
        torch = _torch()
        self.device, dt = device, torch.float64
        on_gel = np.isfinite(geo.log_range)
        solved = _solved(on_gel)
        if not solved.any():
            raise ShapeError("no gel pixel has all its neighbours in the image on the gel: nothing to integrate")
        held = _dilate4(solved) & ~solved  # the gel pixels next to the solved ones that meet the base
        spans = [_span(solved.any(1 - axis), held.any(1 - axis)) for axis in (0, 1)]
        self.box, self.framed, self.in_frame = (tuple(s[i] for s in spans) for i in range(3))
        # natural sides along an axis where the box needs no frame
        self.neumann = tuple(inside == slice(None) for inside in self.in_frame)

        def put(a: np.ndarray):
            return torch.as_tensor(np.ascontiguousarray(a), device=device)

        ref = np.where(on_gel, geo.log_range, 0.0)
        self.ref = put(ref[self.box])
        self.solved = put(solved[self.box])
        self.held = put(np.flatnonzero(held[self.box]))  # held pixels inside the box
        # the framed box's rays and their derivatives, for the log-range gradient of a normal map
        self.rays, self.d_u, self.d_v = (put(a[self.framed]).to(dt) for a in (geo.rays, geo.d_u, geo.d_v))
        self.points_ref = put(np.where(on_gel[..., None], geo.points, np.nan).astype(np.float32))
        self.solve = BoxPoisson(*self.ref.shape, device, dt, neumann=self.neumann)
        framed_ref = put(ref[self.framed])
        ref_div = self._divergence(framed_ref[:, 1:] - framed_ref[:, :-1], framed_ref[1:] - framed_ref[:-1])
        self.ref_divergence = ref_div * self.solved
        self.capacitance_inverse = self._capacitance_inverse() if len(self.held) else None
        # the solved pixels by index (boolean-mask indexing waits for the device; a CUDA graph cannot)
        self.solved_in_box = put(np.flatnonzero(solved[self.box]))
        self.solved_in_image = put(np.flatnonzero(solved))
        self.solved_rays = put(geo.rays[solved])

    def _capacitance_inverse(self):
        """(b, b) inverse of the box solver's response at the held pixels to unit sources there; (b + 1, b + 1)
        with the level as a last unknown where the box solve leaves the constant free (both axes natural)."""
        torch = _torch()
        m, n = self.ref.shape
        b = len(self.held)
        chunk = max(1, min(b, SETUP_BATCH_BYTES // (8 * 4 * (m + 1) * (n + 1))))
        free = all(self.neumann)
        green = torch.zeros((b + free, b + free), dtype=torch.float64, device=self.device)
        for start in range(0, b, chunk):
            idx = self.held[start : start + chunk]
            sources = torch.zeros((len(idx), m * n), dtype=torch.float64, device=self.device)
            sources[torch.arange(len(idx), device=self.device), idx] = 1.0
            green[start : start + len(idx), :b] = self.solve(sources.view(-1, m, n)).view(-1, m * n)[:, self.held]
        if free:  # x = solve(f + sources) + level, held at zero; the sources make f + sources sum to zero
            green[:b, b] = green[b, :b] = 1.0
        return torch.linalg.inv(green)

    def log_range(self, normals: torch.Tensor, unchanged: torch.Tensor | None = None) -> torch.Tensor:
        """(m, n) float64 log-range over :attr:`box` from ``normals`` ((H, W, 3) float tensor, unit, camera frame).

        Solved gel pixels are solved, the held ones and the rest of the gel keep the reference. ``unchanged``
        ((H, W) bool tensor, or None: every pixel) sets the level where nothing holds it (a gel that fills the
        image): the mean change of the unchanged solved pixels is zero (of all of them where none is unchanged).
        """
        torch = _torch()
        nb = normals[self.framed].to(torch.float64)
        den = torch.clamp_max((nb * self.rays).sum(-1), -INTEGRATION_MIN_FACING)
        p = -(nb * self.d_u).sum(-1) / den
        q = -(nb * self.d_v).sum(-1) / den
        # f = (incoming - outgoing edge gradients) at each pixel of the box; the reference to the right-hand side
        f = self._divergence(0.5 * (p[:, :-1] + p[:, 1:]), 0.5 * (q[:-1] + q[1:]))
        rhs = (f - self.ref_divergence) * self.solved  # the change from the reference: zero on the held pixels
        change = self.solve(rhs)
        if self.capacitance_inverse is not None:
            change = self._hold(rhs, change)
        elif all(self.neumann):
            change = change - self._level(change, unchanged)
        return self.ref + change * self.solved

    def __call__(self, normals: torch.Tensor, unchanged: torch.Tensor | None = None) -> torch.Tensor:
        """(H, W, 3) float32 tensor: the surface points, mm, camera frame (NaN off the gel); depth is their z.

        ``unchanged``: (H, W) bool tensor of the pixels that did not change, or None (:meth:`log_range`).
        """
        torch = _torch()
        points = self.points_ref.clone()
        lr = self.log_range(normals, unchanged).flatten()[self.solved_in_box]
        points.view(-1, 3)[self.solved_in_image] = (torch.exp(lr)[:, None] * self.solved_rays).to(torch.float32)
        return points

    def _divergence(self, along_u: torch.Tensor, along_v: torch.Tensor):
        """(m, n): incoming minus outgoing edge values at each pixel of the box, from the framed box's edges
        along u ((mf, nf - 1), pixel (r, c) to (r, c + 1)) and along v ((mf - 1, nf)). On a natural side no
        edge leaves the box (the 5-point Laplacian's row of the pixel counts its neighbours in the image)."""
        torch = _torch()
        rows, cols = self.in_frame
        gu, gv = along_u[rows], along_v[:, cols]
        if self.neumann[1]:
            gu = torch.nn.functional.pad(gu, (1, 1))
        if self.neumann[0]:
            gv = torch.nn.functional.pad(gv, (0, 0, 1, 1))
        return gu[:, :-1] - gu[:, 1:] + gv[:-1, :] - gv[1:, :]

    def _hold(self, rhs: torch.Tensor, change: torch.Tensor):
        """The box solve again, with sources on the held pixels that bring their change (``change``: the solve
        without them) back to zero; where the box leaves the level free, with the level that does too."""
        flat = rhs.flatten()
        held = -change.flatten()[self.held]
        if not all(self.neumann):
            return self.solve(flat.index_add(0, self.held, self.capacitance_inverse @ held).view_as(rhs))
        sources = self.capacitance_inverse @ _torch().cat([held, -flat.sum()[None]])
        return self.solve(flat.index_add(0, self.held, sources[:-1]).view_as(rhs)) + sources[-1]

    def _level(self, change: torch.Tensor, unchanged: torch.Tensor | None):
        """The constant whose removal makes the mean change over the unchanged solved pixels zero (the
        least-squares level shift; over every solved pixel where ``unchanged`` is None or holds none of them)."""
        torch = _torch()
        weight = self.solved if unchanged is None else self.solved & unchanged[self.box]
        # a where, not an if: nothing waits for the device (a CUDA graph records the whole-gel solve)
        weight = torch.where(weight.sum() > 0, weight, self.solved).to(change.dtype)
        return (change * weight).sum() / weight.sum()


def _solved(on_gel: np.ndarray) -> np.ndarray:
    """Gel pixels whose neighbours in the image are all gel pixels (beyond the image border: no neighbour)."""
    padded = np.pad(on_gel, 1, constant_values=True)
    return on_gel & padded[:-2, 1:-1] & padded[2:, 1:-1] & padded[1:-1, :-2] & padded[1:-1, 2:]


def _span(solved: np.ndarray, held: np.ndarray) -> tuple[slice, slice, slice]:
    """(box, framed box, the box within the framed box) along one axis, from where the solved and the held pixels
    are on it ((n,) bool each).

    Solved pixels inside the image: the box is theirs, its frame one pixel beyond each end (held or off the
    gel: Dirichlet). Solved pixels that reach the image border: a natural boundary, no frame; the box spans
    the held pixels too (a box side off the border then has no solved pixel on it).
    """
    lo, hi = _extent(solved)
    if lo > 0 and hi < len(solved):
        return slice(lo, hi), slice(lo - 1, hi + 1), slice(1, -1)
    lo, hi = _extent(solved | held)
    return slice(lo, hi), slice(lo, hi), slice(None)


def _extent(mask: np.ndarray) -> tuple[int, int]:
    """[lo, hi) of the True entries of a 1-D mask."""
    idx = np.flatnonzero(mask)
    return int(idx[0]), int(idx[-1]) + 1


def _dilate4(mask: np.ndarray) -> np.ndarray:
    out = mask.copy()
    out[1:] |= mask[:-1]
    out[:-1] |= mask[1:]
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    return out
