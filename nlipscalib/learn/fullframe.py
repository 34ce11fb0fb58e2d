"""NLiPsNet inference in PyTorch with every step on one device: a GPU's way to real time (``--device cuda``).

The CPU path (:mod:`.infer`) gathers the pixels that changed, sends only them through the network
and integrates their bounding box: shapes that change every frame. On a GPU fixed shapes are
cheaper, and they let the whole frame's work be recorded once as a CUDA graph and replayed, so this
path runs every step on the device with the shapes of the sensor: the tri-colour frame's
linearisation, the model's prefilter (:mod:`.prefilter`'s normalised Gaussian, OpenCV's kernel, or its
bilateral filter with the model's ``smoothing_colour``; for a model of ``colour_input`` "ratio" then divided by its
filtered reference frame), the network on every gel pixel, the change rule of
:mod:`.change` (the same operations), the reference normals kept where nothing changed (as on the CPU path;
``keep_reference=False`` keeps the network's everywhere: ``--full-frame``). Then :mod:`.integrate_torch` integrates the
changed pixels' boxes as the CPU does (per region where their common box does not apply, an edge box
where one reaches the image border, a cosine box across the image, a rim box near the gel's outline; a region
the CPU solves on its sparse path by the CPU's code on the host), after the graph (the box's shape changes per
frame), or the whole gel inside it (``--full-frame``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import require
from .change import channel_ratio
from .cuda_graph import record
from .integrate_geometry import RayGeometry
from .integrate_torch import BoxIntegrator, DomeIntegrator
from .prefilter import bilateral_offsets, gaussian_kernel, kernel_radius

if TYPE_CHECKING:  # torch is optional and imported where it is used (``_torch``): named for the hints only
    import torch

    from .model import LoadedModel


def _torch():
    return require("torch", "torch", "Inference with --device or --full-frame")


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

    def __init__(self, model: LoadedModel, device: torch.device, geo: RayGeometry | None, keep_reference: bool = True):
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
        self.filter = _GelFilter(valid, model.smoothing_px, device, model.smoothing_colour)
        divide = model.input_reference  # a model of colour ratios: its filtered reference (learn.model.model_inputs)
        self.input_reference = None if divide is None else torch.as_tensor(divide, device=device)
        # the whole gel (every pixel's normal from the network, or a region the boxes cannot solve) and the
        # changed pixels' boxes (the reference elsewhere, as on the CPU path)
        # the whole gel's set-up (a minute on two CPU cores for a gel that does not fill the image) only for it
        self.integrator = DomeIntegrator(geo, device) if geo is not None and not keep_reference else None
        self.has_geometry = geo is not None
        self.box_integrator = BoxIntegrator(geo, device) if geo is not None and keep_reference else None
        self.ref_points_host = depth_to_points(ref["depth"].astype(np.float32), camera.rays).astype(np.float32)
        self.ref_points = torch.as_tensor(self.ref_points_host, device=device)
        self.change = _ChangeRule(ref["tricolor"].astype(np.float32), valid, device)
        self.keep_reference = keep_reference
        self.gain = None
        """(H, W, 3) float32 tensor or None: what each linear frame is multiplied by first (:meth:`set_gain`)."""
        ref_normals = np.where(valid[..., None], ref["normals"], 0).astype(np.float32)
        self.ref_normals = torch.as_tensor(ref_normals, device=device)
        self._graphs: dict = {}

    def set_gain(self, gain: np.ndarray | None) -> None:
        """Multiply each linear frame by ``gain`` ((H, W, 3) float32, or None for none) before the change rule and
        the network: an aged sensor's frames in the calibration's light (``learn.infer.Predictor.refresh``).

        On the device, after a stored frame's linearisation (a stored frame is converted there); the recorded
        graphs are dropped, so the next frames record them with the gain.
        """
        torch = self.torch
        self.gain = None if gain is None else torch.as_tensor(np.asarray(gain, np.float32), device=self.device)
        self._graphs.clear()

    def warm_up(self) -> None:
        """Plan and record what the first frames of either kind (linear, stored) would: not part of a frame's time."""
        linear = np.zeros(self.shape + (3,), np.float32)
        self(linear)
        if self.device.type == "cuda":
            self(linear.astype(np.uint16), stored=True)
        if self.box_integrator is not None:  # and the changed pixels' box, which an empty frame never reaches
            self.box_integrator.warm_up(self.ref_normals)

    def __call__(self, tricolor: np.ndarray, stored: bool = False, normals: np.ndarray | None = None):
        """normals, depth, points, changed (numpy, as :class:`.infer.Frame` holds them; the change rule's pixels also
        with ``keep_reference=False``, where the network's normals are every gel pixel's), stage seconds, mismatch,
        channels (each colour's median over the reference's on the unchanged gel, :func:`.change.channel_ratio`).

        ``tricolor`` is (H, W, 3): linear float32, or the stored uint16 values when ``stored`` (converted on the
        device: half the bytes to move). Stage seconds: upload, compute (everything on the device), download.
        ``normals``: (H, W, 3) float32 unit, 0 off the gel, made elsewhere (the full-frame ONNX graph,
        :class:`.onnx_fullframe.FrameGraph`): the prefilter and the network are skipped, the change rule and the
        integration run on them as on the network's (not recorded as a CUDA graph).

        On a CUDA device the work up to the normals (the whole integration with ``keep_reference=False``) is a
        recorded graph; the changed pixels' box is solved after it (its shape changes from frame to frame).
        """
        torch = self.torch
        t0 = time.perf_counter()
        with torch.no_grad():
            host = torch.from_numpy(np.ascontiguousarray(tricolor))
            given = None if normals is None else torch.from_numpy(np.ascontiguousarray(normals, np.float32))
            replay = self._graph(host, stored) if self.device.type == "cuda" and given is None else None
            if replay is not None:
                replay.inputs[0].copy_(host)
                t1 = self._sync()
                out = replay()
            else:
                frame = host.to(self.device)
                given = None if given is None else given.to(self.device)
                t1 = self._sync()
                out = self._compute(frame, stored, given)
            normals, changed, mismatch, points, sampled = out
            changed = changed.cpu().numpy()
            channels = self.change.channels(sampled.cpu().numpy())
            if not self.has_geometry:  # normals only: the reference surface, nothing to bring back
                points = self.ref_points_host.copy()
            elif self.box_integrator is not None:
                points = self._box_points(normals, changed)
            t2 = self._sync()
            normals, mismatch = normals.cpu().numpy(), float(mismatch)
            points = points if isinstance(points, np.ndarray) else points.cpu().numpy()
        t3 = time.perf_counter()
        seconds = {"upload": t1 - t0, "compute": t2 - t1, "download": t3 - t2, "total": t3 - t0}
        # depth: the points' z, not downloaded
        return normals, points[..., 2], points, changed, seconds, mismatch, channels

    def _box_points(self, normals: torch.Tensor, changed: np.ndarray):
        """Points of the frame whose changed pixels are ``changed``: the reference, with the changed pixels solved
        as on the CPU path (:meth:`BoxIntegrator.plan`): their box, else per region a box, an edge box at the image
        border, a cosine box across the image or a rim box on the device (only the boxes come back, in one copy),
        and a region the CPU solves on its sparse path by the CPU's code on the host."""
        if not changed.any():
            return self.ref_points_host.copy()
        integrator = self.box_integrator
        plan = integrator.plan(changed)
        points = self.ref_points_host.copy()
        # queued on the device
        solved = [integrator(normals, box, edges) for box, edges in plan.boxes]
        solved += [integrator.rim_box(normals, box) for box in plan.rim]
        if solved:
            flat = self.torch.cat([s.flatten() for s in solved]).cpu().numpy()  # the one wait for the device
            start = 0
            for box, s in zip([box for box, _ in plan.boxes] + plan.rim, solved):
                points[box] = flat[start : start + s.numel()].reshape(s.shape)
                start += s.numel()
        for group in plan.host:
            box, solved, solved_points = integrator.on_host(normals, changed, group)
            points[box][solved] = solved_points
        return points

    def _compute(self, frame: torch.Tensor, stored: bool, given: torch.Tensor | None = None):
        """(normals (H, W, 3), changed (H, W), mismatch (), points (H, W, 3), sampled (N, 4)) tensors of one frame
        on the device (sampled: :meth:`_ChangeRule.__call__`'s); with ``keep_reference`` the points are the
        reference's (the box is integrated after, not recorded). ``given``: the normals, made elsewhere
        (:meth:`__call__`)."""
        torch = self.torch
        if stored:
            frame = (frame.to(torch.float32) - self.dark) / self.scale
        if self.gain is not None:  # an aged sensor's frame, in the calibration's light (set_gain)
            frame = frame * self.gain
        normals = self._network(frame) if given is None else given
        changed, mismatch, sampled = self.change(frame)
        if not self.keep_reference:  # the network's normals everywhere, integrated over the whole gel
            whole = self.integrator(normals, ~changed) if self.integrator is not None else self.ref_points
            # the rule's changed pixels all the same (the contact the small-contact warning measures): the same
            # download as the gel's mask it replaced
            return normals, changed, mismatch, whole, sampled
        # the reference normals where nothing changed; the box is integrated after (its shape changes per frame)
        kept = torch.where(changed[..., None], normals, self.ref_normals)
        return kept, changed, mismatch, self.ref_points, sampled

    def _network(self, frame: torch.Tensor):
        """(H, W, 3) normals of the linear ``frame``: the model's prefilter, a ratio model's division, the network on
        every gel pixel (0 off the gel)."""
        torch = self.torch
        filtered = self.filter(frame)
        if self.input_reference is not None:  # the colours over the reference's (1 off the gel: no division by 0)
            filtered = filtered / self.input_reference
        # every gel pixel through the network: on a GPU cheaper than gathering the changed ones (a shape per frame)
        x = torch.cat([self.x, filtered.reshape(-1, 3)[self.flat]], 1)
        normals = torch.zeros(self.shape + (3,), dtype=torch.float32, device=self.device)
        normals.view(-1, 3)[self.flat] = self.net(x)
        return normals

    def _graph(self, host: torch.Tensor, stored: bool):
        """The frame's work recorded once as a CUDA graph and replayed per frame (one launch instead of ~100 small
        kernels: a frame's Python and launch overhead was as long as its arithmetic). None where recording
        fails (the eager path then runs, identical in results)."""
        key = (host.dtype, stored)
        if key not in self._graphs:
            inputs = (host.to(self.device), stored)
            self._graphs[key] = record(self._compute, inputs, self.device, "NLiPsNet inference on the GPU")
        return self._graphs[key]

    def _sync(self) -> float:
        if self.device.type == "cuda":  # stage times of queued GPU work: wait for it
            self.torch.cuda.synchronize(self.device)
        return time.perf_counter()


class _GelFilter:
    """:class:`.prefilter.Prefilter` on a torch device: blur(image * valid) / blur(valid), OpenCV's Gaussian
    kernel, reflected borders (torch's "reflect" is OpenCV's BORDER_REFLECT_101); with a colour sigma OpenCV's
    bilateral filter instead (:meth:`_edge_stopping`)."""

    def __init__(self, valid: np.ndarray, sigma_px: float, device: torch.device, colour_sigma: float = 0.0):
        torch = _torch()
        self.radius = kernel_radius(sigma_px)
        self.valid = torch.as_tensor(valid, device=device)
        self.colour = float(colour_sigma)
        # OpenCV's bilateral window: the offsets within the radius (a disc), each with its spatial Gaussian weight
        # (none without a radius: a model trained unfiltered, smoothing_px 0, has no window and no sigma to divide by)
        self.offsets = bilateral_offsets(sigma_px)
        if self.radius and not self.colour:
            self.kernel = [float(w) for w in gaussian_kernel(sigma_px)]
            self.weight = self._blur(self.valid.to(torch.float32)[None]).clamp_min(1e-6)

    def _blur(self, a: torch.Tensor):
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

    def _edge_stopping(self, a: torch.Tensor):
        """(C, H, W) -> (C, H, W): OpenCV's bilateral filter (:mod:`.prefilter`), each offset of the disc weighted by
        its spatial Gaussian times exp(-d^2 / (2 colour^2)), d the L1 colour distance; the weighted sums of shifted
        copies, as :meth:`_blur`'s (float32). Off the gel black, which the colour weight leaves out."""
        F = _torch().nn.functional
        r = self.radius
        padded = F.pad(a[None], (r, r, r, r), mode="reflect")[0]
        H, W = a.shape[1], a.shape[2]
        total, weight = 0.0, 0.0
        scale = -0.5 / self.colour**2
        for dy, dx, near in self.offsets:
            shifted = padded[:, r + dy : r + dy + H, r + dx : r + dx + W]
            apart = (shifted - a).abs().sum(0, keepdim=True)
            w = near * (apart * apart * scale).exp()
            total, weight = total + w * shifted, weight + w
        return total / weight

    def __call__(self, frame: torch.Tensor):
        """(H, W, 3) -> (H, W, 3) float32 filtered; NaN-safe off the gel."""
        torch = _torch()
        if not self.radius:
            return frame
        inside = torch.where(self.valid[..., None], frame, 0.0).permute(2, 0, 1)
        if self.colour:
            return self._edge_stopping(inside).permute(1, 2, 0)
        return (self._blur(inside) / self.weight).permute(1, 2, 0)


class _ChangeRule:
    """:class:`.change.ChangeDetector` on a torch device, operation for operation: 2x2-block means, the signed
    difference from the reference box-averaged (replicated border), summed over colours, compared with the
    median and the median absolute deviation over the gel's sampled blocks and with the reference's level, an
    opening and growth with the 3x3 cross (zeros outside); twice, the second time with the first pass's per-colour
    gain taken out (:func:`.change.rule_gain`, here on the device: the same picks, the same bound), back to full
    resolution. Also its whole-frame figure
    (:attr:`.change.ChangeDetector.mismatch`) and the sampled blocks its per-colour ratio is taken from
    (:func:`.change.channel_ratio`, on the host, the first pass's: the frame's own)."""

    def __init__(self, reference: np.ndarray, valid: np.ndarray, device: torch.device):
        from ..core.robust_scale import MAD_TO_SIGMA
        from ..core.tolerances import CHANGE_GAIN_TRIM_SIGMAS, CHANGE_MIN_REL, CHANGE_NOISE_SIGMAS, FRAME_CHANNEL_DRIFT
        from .change import NOISE_STRIDE, SMOOTH_BLOCKS

        torch = _torch()
        self.smooth, self.sigmas, self.drift = SMOOTH_BLOCKS, CHANGE_NOISE_SIGMAS, FRAME_CHANNEL_DRIFT
        self.trim = float(np.float32(CHANGE_GAIN_TRIM_SIGMAS * MAD_TO_SIGMA))  # as learn.change's float32 product
        self.valid = torch.as_tensor(valid, device=device)
        h2, w2 = valid.shape[0] // 2, valid.shape[1] // 2
        self.crop = (slice(0, 2 * h2), slice(0, 2 * w2))
        ref = torch.as_tensor(np.where(valid[..., None], reference, 0).astype(np.float32), device=device)
        self.ref_blocks = self._blocks(ref)
        self.on = self._blocks(torch.as_tensor(valid.astype(np.float32), device=device)[..., None])[..., 0] == 1
        self.floor = CHANGE_MIN_REL * self.ref_blocks.sum(-1)
        self.sample = torch.nonzero(self.on.flatten()).flatten()[::NOISE_STRIDE]
        level = self.ref_blocks.sum(-1).flatten()[self.sample]
        self.level = float(_median(level)) if len(level) else 0.0
        self.ref_sample_device = self.ref_blocks.reshape(-1, 3)[self.sample]
        self.ref_sample = self.ref_sample_device.cpu().numpy()

    def _blocks(self, image: torch.Tensor):
        F = _torch().nn.functional
        return F.avg_pool2d(image[self.crop].permute(2, 0, 1)[None], 2)[0].permute(1, 2, 0)

    def __call__(self, frame: torch.Tensor):
        """(changed (H, W) bool, mismatch 0-d, sampled (N, 4)) tensors for ``frame`` ((H, W, 3) linear); sampled:
        the frame's block means minus the reference's at the sampled gel blocks, then 1 where the rule found a change
        (one small download for :meth:`channels`, which takes the ratio by the CPU path's own code)."""
        torch = _torch()
        if not len(self.sample) or self.level <= 0:
            nothing = torch.zeros((0, 4), device=frame.device)
            return torch.zeros_like(self.valid), torch.zeros((), device=frame.device), nothing
        blocks = self._blocks(frame)
        signed = torch.where(self.on[..., None], blocks - self.ref_blocks, 0.0)
        hit, median = self._hits(signed)
        samples = signed.reshape(-1, 3)[self.sample]
        rest = ~hit.flatten()[self.sample]
        # the second pass: the frame's colours in the reference's gain (learn.change's module docstring)
        inverse = (1 / self._gain(samples, rest)).to(torch.float32)
        second, _ = self._hits(torch.where(self.on[..., None], blocks * inverse - self.ref_blocks, 0.0))
        changed = torch.zeros_like(self.valid)
        changed[self.crop] = second.repeat_interleave(2, 0).repeat_interleave(2, 1)
        sampled = torch.cat([samples, (~rest)[:, None].to(samples.dtype)], 1)
        return changed & self.valid, median / self.level, sampled

    def _hits(self, signed: torch.Tensor):
        """(changed blocks (H/2, W/2) bool, median 0-d) of a frame whose block means differ from the reference's by
        ``signed`` (0 off the gel): :meth:`.change.ChangeDetector._hits`."""
        from .change import DILATE_BLOCKS

        torch = _torch()
        F = torch.nn.functional
        r = self.smooth // 2
        padded = F.pad(signed.permute(2, 0, 1)[None], (r, r, r, r), mode="replicate")
        diff = F.avg_pool2d(padded, self.smooth, stride=1)[0].abs().sum(0)
        sample = diff.flatten()[self.sample]
        median = _median(sample)
        # core.robust_scale.mad_scale on the GPU (the CPU rule, learn.change, calls it; parity-tested)
        sigma = 1.4826 * _median((sample - median).abs()) + 1e-6
        hit = self.on & (diff > median + self.sigmas * sigma) & (diff > self.floor)
        hit = _cross(_cross(hit, torch.amin), torch.amax)  # opening: isolated blocks are noise
        for _ in range(DILATE_BLOCKS):
            hit = _cross(hit, torch.amax)
        return hit, median

    def _gain(self, samples: torch.Tensor, rest: torch.Tensor):
        """(3,) float64 -- :func:`.change.rule_gain` on the device: each colour's middle ratio of the frame's block
        means over the reference's on the unchanged blocks, again on those within the trim of it in every colour, 1 +
        that held within 1 +- FRAME_CHANNEL_DRIFT; 1s when every sampled block changed. The same element picks
        (index n // 2 of the n counted, np.partition's) in the same float32 arithmetic; fixed shapes (the blocks not
        counted sorted last as +inf), so a CUDA graph records it."""
        torch = _torch()
        ratio = samples / self.ref_sample_device.clamp_min(1e-12)
        centre = _middle_of(ratio, rest)
        off = (ratio - centre).abs()
        inside = rest & (off <= _middle_of(off, rest) * self.trim).all(1)
        again = torch.where(inside.any(), _middle_of(ratio, inside), centre)  # none inside: the first median
        gain = 1.0 + again.to(torch.float64)
        gain = torch.where(torch.isfinite(gain) & (rest.sum() > 0), gain, 1.0)
        return gain.clamp(1 - self.drift, 1 + self.drift)

    def channels(self, sampled: np.ndarray) -> tuple[float, float, float]:
        """Each colour's median over the reference's on the unchanged gel (:func:`.change.channel_ratio`) from
        :meth:`__call__`'s downloaded ``sampled`` ((N, 4) float32)."""
        if not len(sampled):
            return (1.0, 1.0, 1.0)
        ratio = channel_ratio(sampled[:, :3], self.ref_sample, sampled[:, 3] == 0)
        return tuple(float(r) for r in ratio)


def _median(x: torch.Tensor):
    """numpy's median of a 1-d tensor (the mean of the middle two of an even count), without leaving the device."""
    torch = _torch()
    n = len(x)
    return torch.sort(x).values[(n - 1) // 2 : n // 2 + 1].mean()


def _middle_of(values: torch.Tensor, counted: torch.Tensor):
    """(3,) -- each column of ``values`` ((N, 3)) at index n // 2 of its ``counted`` ((N,) bool) rows sorted, n their
    count (:func:`.change._middle`'s pick; the last row's when none is counted)."""
    torch = _torch()
    ordered = torch.where(counted[:, None], values, torch.inf).sort(0).values
    pick = (counted.sum() // 2).clamp_max(len(counted) - 1)
    return ordered.gather(0, pick.expand(1, values.shape[1]))[0]


def _cross(mask: torch.Tensor, reduce: Callable[..., torch.Tensor]):
    """Erosion (``torch.amin``) or dilation (``torch.amax``) of a bool mask by the 3x3 cross, zeros outside."""
    F = _torch().nn.functional
    m = F.pad(mask[None, None].to(_torch().uint8), (1, 1, 1, 1))[0, 0]
    H, W = mask.shape
    shifts = [m[1 : H + 1, 1 : W + 1], m[:H, 1 : W + 1], m[2:, 1 : W + 1], m[1 : H + 1, :W], m[1 : H + 1, 2:]]
    return reduce(_torch().stack(shifts), 0).bool()
