"""NLiPsNet inference in PyTorch with every step on one device (a GPU's way to real time), depth over the whole gel.

The CPU path (:mod:`.infer`) gathers the pixels that changed, sends only them through the network
and integrates their bounding box: shapes that change every frame. On a GPU fixed shapes are
cheaper, and they let the whole frame's work be recorded once as a CUDA graph and replayed, so this
path runs every step on the device with the shapes of the sensor: the tri-colour frame's
linearisation, the model's Gaussian prefilter (:mod:`.prefilter`'s normalised filter, OpenCV's
kernel), the network on every gel pixel, the change rule of :mod:`.change` (the same operations),
the reference normals kept where nothing changed (as on the CPU path; ``keep_reference=False``
keeps the network's everywhere), and the integration of the normals over the whole gel.

The integration solves the same equation as :mod:`.integrate` (5-point Poisson in the log-range
along the camera's real rays, gradients averaged on each pixel pair) on every gel pixel whose four
neighbours are on the gel; the gel's outermost pixel ring is the Dirichlet boundary, held at the
undeformed reference (the gel is fixed where it meets the dome's base; where the gel fills the
image, the ring is the image border). Where the domain is not a rectangle, the fast sine-transform
solver of its bounding box is corrected on the boundary ring with a precomputed capacitance
matrix -- the capacitance-matrix method for the discrete Poisson equation on irregular regions
(Buzbee, Dorr, George & Golub, SIAM J. Numer. Anal. 8(4), 1971): per frame two box solves and one
(b, b) matrix-vector product (b: ring pixels inside the box), exact up to rounding, no iterations;
set up once per sensor with b box solves (batched: under a second on a GPU, about a minute on two CPU
cores at 640x480). A gel that fills the image needs one box solve and no set-up.
"""

from __future__ import annotations

import functools
import math
import time

import numpy as np

from ..errors import ConfigError, ShapeError, require
from .integrate import MIN_FACING, RayGeometry, _box, box_eigenvalues, box_rhs
from .prefilter import kernel_radius

SETUP_BATCH_BYTES = 1 << 29
"""Memory of one batch of box solves while the capacitance matrix is set up (float64 boxes)."""


def _torch():
    return require("torch", "torch", "Whole-frame inference")


def check_device(device: str):
    """The torch device ``device`` names ("cpu", "cuda", "cuda:1"), or ConfigError naming what is missing."""
    torch = _torch()
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(f"--device {device!r}: not a torch device ({exc}); use cpu, cuda or cuda:N") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(
                f"--device {device}: torch {torch.__version__} sees no CUDA device (a CPU build, or no GPU here); "
                "use --device cpu"
            )
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"--device {device}: there are {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise ConfigError(f"--device {device}: only cpu and cuda devices are supported")
    return dev


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


class BoxPoisson:
    """Solver of the 5-point Dirichlet Laplacian (4 x_i - sum of neighbours = f) on an (m, n) box, zero outside."""

    def __init__(self, m: int, n: int, device, dtype):
        self.lam = _torch().as_tensor(box_eigenvalues(m, n), dtype=dtype, device=device)

    def __call__(self, f):
        """x with L x = f; ``f`` is (..., m, n)."""
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
        self.on_gel = np.isfinite(geo.log_range)
        self.log_range = torch.as_tensor(geo.log_range.astype(np.float32), device=device)
        self.rays, self.d_u, self.d_v = (torch.as_tensor(a, device=device) for a in (geo.rays32, geo.d_u32, geo.d_v32))
        self.device = device

    def box(self, changed: np.ndarray):
        """The box for ``changed`` ((H, W) bool on the gel), or None when it leaves the gel or touches the border."""
        return _box(changed, self.on_gel)

    def __call__(self, normals, box):
        """(h, w, 3) float32 tensor: the surface points over ``box`` from ``normals`` ((H, W, 3) tensor)."""
        torch = _torch()
        x = self.log_range[box].clone()
        f = box_rhs(normals[box], self.rays[box], self.d_u[box], self.d_v[box], x)
        x[1:-1, 1:-1] = self._solver(*f.shape)(f)
        return torch.exp(x)[..., None] * self.rays[box]

    @functools.lru_cache(maxsize=32)  # noqa: B019 -- one per box size; the instance lives as long as the model
    def _solver(self, m: int, n: int) -> BoxPoisson:
        return BoxPoisson(m, n, self.device, _torch().float32)


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


class FullFrame:
    """Every step of NLiPsNet inference on a torch device (module docstring).

    Parameters
    ----------
    model : LoadedModel (``learn.model.load_model``)
    device : torch device
    geo : RayGeometry of the sensor, or None for normals only (the reference depth and points)
    keep_reference : pixels the change rule finds unchanged keep the reference normals, as on the CPU path;
        False: the network's normals on every gel pixel
    """

    def __init__(self, model, device, geo: RayGeometry | None, keep_reference: bool = True):
        from ..core.camera import Camera, depth_to_points
        from .model import fused_net

        torch = _torch()
        self.torch, self.device = torch, device
        ref = model.reference
        camera = Camera.from_dict(model.sensor["camera"])
        valid = ref["valid"].astype(bool)
        self.shape = valid.shape
        s = model.sensor
        self.scale = float(s["white_level"] - s["black_level"])
        self.dark = torch.as_tensor(ref["dark"].astype(np.float32), device=device)
        self.flat = torch.as_tensor(np.flatnonzero(valid), device=device)
        row, col = np.divmod(np.flatnonzero(valid), self.shape[1])
        self.x = torch.as_tensor(np.stack([col, row], 1).astype(np.float32), device=device)  # u = column, v = row
        self.net = fused_net(model.net).to(device)
        self.filter = _GelFilter(valid, model.smoothing_px, device)
        # the whole gel (every pixel's normal from the network, or a change that reaches the image border) and the
        # changed pixels' box (the reference elsewhere, as on the CPU path)
        self.integrator = DomeIntegrator(geo, device) if geo is not None else None
        self.box_integrator = BoxIntegrator(geo, device) if geo is not None and keep_reference else None
        self.ref_points_host = depth_to_points(ref["depth"].astype(np.float32), camera.rays).astype(np.float32)
        self.ref_points = torch.as_tensor(self.ref_points_host, device=device)
        self.change = _ChangeRule(ref["tricolor"].astype(np.float32), valid, device)
        self.keep_reference = keep_reference
        ref_normals = np.where(valid[..., None], ref["normals"], 0).astype(np.float32)
        self.ref_normals = torch.as_tensor(ref_normals, device=device)
        self._graphs: dict = {}

    def warm_up(self) -> None:
        """Plan and record what the first frames of either kind (linear, stored) would: not part of a frame's time."""
        linear = np.zeros(self.shape + (3,), np.float32)
        self(linear)
        if self.device.type == "cuda":
            self(linear.astype(np.uint16), stored=True)

    def __call__(self, tricolor: np.ndarray, stored: bool = False):
        """normals, depth, points, changed (numpy, as :class:`.infer.Frame` holds them), stage seconds, mismatch.

        ``tricolor`` is (H, W, 3): linear float32, or the stored uint16 values when ``stored`` (converted on the
        device: half the bytes to move). Stage seconds: upload, compute (everything on the device), download.

        On a CUDA device the work up to the normals (the whole integration with ``keep_reference=False``) is a
        recorded graph; the changed pixels' box is solved after it (its shape changes from frame to frame).
        """
        torch = self.torch
        t0 = time.perf_counter()
        with torch.no_grad():
            host = torch.from_numpy(np.ascontiguousarray(tricolor))
            replay = self._graph(host, stored) if self.device.type == "cuda" else None
            if replay is not None:
                replay.input.copy_(host)
                t1 = self._sync()
                replay.graph.replay()
                out = replay.outputs
            else:
                frame = host.to(self.device)
                t1 = self._sync()
                out = self._compute(frame, stored)
            normals, changed, mismatch, points = out
            changed = changed.cpu().numpy()
            points = self._box_points(normals, changed) if self.box_integrator is not None else points
            t2 = self._sync()
            normals, mismatch = normals.cpu().numpy(), float(mismatch)
            points = points if isinstance(points, np.ndarray) else points.cpu().numpy()
        t3 = time.perf_counter()
        seconds = {"upload": t1 - t0, "compute": t2 - t1, "download": t3 - t2, "total": t3 - t0}
        return normals, points[..., 2], points, changed, seconds, mismatch  # depth: the points' z, not downloaded

    def _box_points(self, normals, changed: np.ndarray):
        """Points of the frame whose changed pixels are ``changed``: the reference, with the changed pixels' box
        solved (:class:`BoxIntegrator`; only the box comes back from the device), or the whole gel solved where
        that box would leave the gel or touch the image border."""
        if not changed.any():
            return self.ref_points_host.copy()
        box = self.box_integrator.box(changed)
        if box is None:
            return self.integrator(normals)
        points = self.ref_points_host.copy()
        points[box] = self.box_integrator(normals, box).cpu().numpy()
        return points

    def _compute(self, frame, stored: bool):
        """(normals (H, W, 3), changed (H, W), mismatch (), points (H, W, 3)) tensors of one frame on the device;
        with ``keep_reference`` the points are the reference's (the box is integrated after, not recorded)."""
        torch = self.torch
        if stored:
            frame = (frame.to(torch.float32) - self.dark) / self.scale
        filtered = self.filter(frame)
        # every gel pixel through the network: on a GPU cheaper than gathering the changed ones (a shape per frame)
        x = torch.cat([self.x, filtered.reshape(-1, 3)[self.flat]], 1)
        normals = torch.zeros(self.shape + (3,), dtype=torch.float32, device=self.device)
        normals.view(-1, 3)[self.flat] = self.net(x)
        changed, mismatch = self.change(frame)
        if not self.keep_reference:  # the network's normals everywhere, integrated over the whole gel
            whole = self.integrator(normals) if self.integrator is not None else self.ref_points
            return normals, self.change.valid, mismatch, whole
        # the reference normals where nothing changed; the box is integrated after (its shape changes per frame)
        return torch.where(changed[..., None], normals, self.ref_normals), changed, mismatch, self.ref_points

    def _graph(self, host, stored: bool):
        """The frame's work recorded once as a CUDA graph and replayed per frame (one launch instead of ~100 small
        kernels: a frame's Python and launch overhead was as long as its arithmetic). None where recording
        fails (the eager path then runs, identical in results)."""
        key = (host.dtype, stored)
        if key not in self._graphs:
            self._graphs[key] = _record(self._compute, host.to(self.device), stored, self.device)
        return self._graphs[key]

    def _sync(self) -> float:
        if self.device.type == "cuda":  # stage times of queued GPU work: wait for it
            self.torch.cuda.synchronize(self.device)
        return time.perf_counter()


class _Replay:
    """A recorded CUDA graph with its static input and output tensors."""

    def __init__(self, graph, input, outputs):
        self.graph, self.input, self.outputs = graph, input, outputs


def _record(compute, static_input, stored: bool, device):
    """``compute(static_input, stored)`` recorded as a CUDA graph after warm-up runs on a side stream (cuFFT plans,
    allocator pools), as torch.cuda.graphs requires; None, with a warning, when the runtime refuses."""
    import logging

    torch = _torch()
    try:
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):
            for _ in range(3):
                compute(static_input, stored)
        torch.cuda.current_stream(device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            outputs = compute(static_input, stored)
    except RuntimeError as exc:  # an op this torch build cannot record: run eagerly
        logging.getLogger(__name__).warning("whole-frame inference runs without a CUDA graph (slower): %s", exc)
        return None
    return _Replay(graph, static_input, outputs)


class _GelFilter:
    """:class:`.prefilter.Prefilter` on a torch device: blur(image * valid) / blur(valid), OpenCV's Gaussian
    kernel, reflected borders (torch's "reflect" is OpenCV's BORDER_REFLECT_101)."""

    def __init__(self, valid: np.ndarray, sigma_px: float, device):
        torch = _torch()
        self.radius = kernel_radius(sigma_px)
        self.valid = torch.as_tensor(valid, device=device)
        if self.radius:
            cv2 = require("cv2", "opencv-python-headless", "Filtering the tri-colour image")
            self.kernel = [float(w) for w in cv2.getGaussianKernel(2 * self.radius + 1, sigma_px, cv2.CV_32F).ravel()]
            self.weight = self._blur(self.valid.to(torch.float32)[None]).clamp_min(1e-6)

    def _blur(self, a):
        """(C, H, W) -> (C, H, W), separable Gaussian per channel.

        Weighted sums of shifted copies rather than a convolution: cuDNN convolves in TF32 by default (1e-3
        relative, 0.04 deg in the normals), these stay in float32 like OpenCV's filter.
        """
        F = _torch().nn.functional
        r = self.radius
        a = F.pad(a[None], (r, r, r, r), mode="reflect")[0]
        H, W = a.shape[1] - 2 * r, a.shape[2] - 2 * r
        rows = sum(w * a[:, i : i + H, :] for i, w in enumerate(self.kernel))
        return sum(w * rows[:, :, i : i + W] for i, w in enumerate(self.kernel))

    def __call__(self, frame):
        """(H, W, 3) -> (H, W, 3) float32 filtered; NaN-safe off the gel."""
        torch = _torch()
        if not self.radius:
            return frame
        inside = torch.where(self.valid[..., None], frame, 0.0).permute(2, 0, 1)
        return (self._blur(inside) / self.weight).permute(1, 2, 0)


class _ChangeRule:
    """:class:`.change.ChangeDetector` on a torch device, operation for operation: 2x2-block means, the signed
    difference from the reference box-averaged (replicated border), summed over colours, compared with the
    median and the median absolute deviation over the gel's sampled blocks and with the reference's level, an
    opening and growth with the 3x3 cross (zeros outside), back to full resolution. Also its whole-frame figure
    (:attr:`.change.ChangeDetector.mismatch`)."""

    def __init__(self, reference: np.ndarray, valid: np.ndarray, device):
        from .change import MIN_REL_CHANGE, NOISE_SIGMAS, NOISE_STRIDE, SMOOTH_BLOCKS

        torch = _torch()
        self.smooth, self.sigmas = SMOOTH_BLOCKS, NOISE_SIGMAS
        self.valid = torch.as_tensor(valid, device=device)
        h2, w2 = valid.shape[0] // 2, valid.shape[1] // 2
        self.crop = (slice(0, 2 * h2), slice(0, 2 * w2))
        ref = torch.as_tensor(np.where(valid[..., None], reference, 0).astype(np.float32), device=device)
        self.ref_blocks = self._blocks(ref)
        self.on = self._blocks(torch.as_tensor(valid.astype(np.float32), device=device)[..., None])[..., 0] == 1
        self.floor = MIN_REL_CHANGE * self.ref_blocks.sum(-1)
        self.sample = torch.nonzero(self.on.flatten()).flatten()[::NOISE_STRIDE]
        level = self.ref_blocks.sum(-1).flatten()[self.sample]
        self.level = float(_median(level)) if len(level) else 0.0

    def _blocks(self, image):
        F = _torch().nn.functional
        return F.avg_pool2d(image[self.crop].permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0)

    def __call__(self, frame):
        """(changed (H, W) bool, mismatch 0-d) tensors for ``frame`` ((H, W, 3) linear)."""
        from .change import DILATE_BLOCKS

        torch = _torch()
        F = torch.nn.functional
        if not len(self.sample) or self.level <= 0:
            return torch.zeros_like(self.valid), torch.zeros((), device=frame.device)
        signed = torch.where(self.on[..., None], self._blocks(frame) - self.ref_blocks, 0.0)
        r = self.smooth // 2
        padded = F.pad(signed.permute(2, 0, 1)[None], (r, r, r, r), mode="replicate")
        diff = F.avg_pool2d(padded, self.smooth, stride=1)[0].abs().sum(0)
        sample = diff.flatten()[self.sample]
        median = _median(sample)
        sigma = 1.4826 * _median((sample - median).abs()) + 1e-6
        hit = self.on & (diff > median + self.sigmas * sigma) & (diff > self.floor)
        hit = _cross(_cross(hit, torch.amin), torch.amax)  # opening: isolated blocks are noise
        for _ in range(DILATE_BLOCKS):
            hit = _cross(hit, torch.amax)
        changed = torch.zeros_like(self.valid)
        changed[self.crop] = hit.repeat_interleave(2, 0).repeat_interleave(2, 1)
        return changed & self.valid, median / self.level


def _median(x):
    """numpy's median of a 1-d tensor (the mean of the middle two of an even count), without leaving the device."""
    torch = _torch()
    n = len(x)
    return torch.sort(x).values[(n - 1) // 2 : n // 2 + 1].mean()


def _cross(mask, reduce):
    """Erosion (``torch.amin``) or dilation (``torch.amax``) of a bool mask by the 3x3 cross, zeros outside."""
    F = _torch().nn.functional
    m = F.pad(mask[None, None].to(_torch().uint8), (1, 1, 1, 1))[0, 0]
    H, W = mask.shape
    shifts = [m[1 : H + 1, 1 : W + 1], m[:H, 1 : W + 1], m[2:, 1 : W + 1], m[1 : H + 1, :W], m[1 : H + 1, 2:]]
    return reduce(_torch().stack(shifts), 0).bool()


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
