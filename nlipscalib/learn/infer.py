"""Real-time inference: one tri-colour frame -> normal map, depth on the dome, points.

Only the pixels that differ from the undeformed reference frame (:func:`changed_pixels`) go through
the network, with their colours low-pass filtered as the model's training samples were
(:mod:`.prefilter`; for a model of ``colour_input`` "ratio" then divided by its reference's, :mod:`.model`);
the others keep the reference normals and depth. Depth integrates the normals on the dome along the
camera's real rays (:mod:`nlipscalib.learn.integrate`).
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera, depth_to_points
from ..core.config import said
from ..core.errors import PATH, CaptureError, ConfigError, ShapeError, check_flag, check_kind
from ..core.sensor_record import camera_response_of, response_table_of
from ..core.sensor_response import CLIPPED_VALUE, linearise, redo_tone_curve, undo_tone_curve
from ..core.tolerances import (
    FRAME_BLACK_FRACTION,
    FRAME_BRIGHTNESS_OFF,
    FRAME_CHANNEL_DRIFT,
    FRAME_MISMATCH_FRACTION,
    REFRESH_GAIN_LIMIT,
    REFRESH_SMOOTHING_PX,
    SATURATED_SHARE_WARN,
)
from .change import ChangeDetector
from .integrate import integrate_on_dome
from .integrate_geometry import RayGeometry
from .model import load_model
from .prefilter import Prefilter
from .torch_device import torch_threads

if TYPE_CHECKING:  # named in hints only: to_reconstruction imports it where it makes one
    from collections.abc import Sequence

    import torch

    from ..core.reconstruction import Reconstruction
    from .model import LoadedModel

BACKENDS = ("auto", "torch", "onnx", "onnx-int8")
"""Network runtimes: auto (onnx when MODEL.onnx exists and is the model's export, else torch), PyTorch, onnxruntime
float32, and onnxruntime with dynamic int8 quantisation (about 1.5x faster for the paper's net, ~0.05 deg)."""

log = logging.getLogger(__name__)

RESULT_DIR = "nlipsnet"
"""Reconstruction folder name inside a press (core reconstruction format, like PRESS/nlips)."""


@dataclasses.dataclass
class Frame:
    """What one tri-colour frame gives."""

    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame; zero off the gel."""
    depth: np.ndarray
    """(H, W) float32, mm, camera-frame z; NaN off the gel."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame; NaN off the gel."""
    changed: np.ndarray
    """(H, W) bool -- pixels that differed from the reference frame: their normals are the network's, the rest
    keeps the reference's (every gel pixel with ``full_frame``)."""
    seconds: dict
    """Time of each step of the predictor's call, s: linearise (a stored frame's, :meth:`Predictor.predict_stored`),
    change, network, integrate, check (the exposure of a frame unlike the calibration's), and total: the whole call
    (the device path, :mod:`.fullframe`: upload, compute, download, check, total; network first with the
    full-frame graph, onnxruntime's run)."""
    brightness: float = 1.0
    """Median brightness on the gel over the reference frame's, at least 0 (a frame below the calibration's dark frame
    is 0, not negative); measured only for a frame that differs over most of the gel (:func:`mismatch_warning`), else
    1."""
    saturated: float = 0.0
    """Share of the gel's pixels with a channel at the white level (or an 8-bit frame's 255), measured like
    ``brightness``."""
    mismatch: float = 0.0
    """Median difference from the reference frame over the gel, fraction of its brightness (:func:`mismatch_warning`).
    """
    contact: np.ndarray | None = None
    """(H, W) bool -- the change rule's changed pixels where ``changed`` is not them (``full_frame``: every gel pixel
    is the network's), for the small-contact warning (``learn.resolution.frame_warning``); None: ``changed``."""
    channels: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Median red, green and blue on the gel where the frame did not change, over the reference frame's
    (:attr:`.change.ChangeDetector.channel_ratio`; on the device path, :mod:`.fullframe`, the same blocks and
    formula)."""


class Predictor:
    """A loaded model ready for frames.

    Parameters
    ----------
    model_path : the model file (.pt) from ``nlips train``
    backend : one of :data:`BACKENDS` ("onnx" and "onnx-int8" use the .onnx file beside the model, from
        ``nlips train``; with ``full_frame`` on the CPU, "onnx" (and "auto" when it is there) the full-frame graph
        MODEL.frame.onnx, ``nlips export MODEL --full-frame``, for the normals; "auto" skips an export of another
        model, or a ratio model's export of before 2026-12-07, with one warning, :func:`resolved_backend`)
    threads : CPU threads for the network (0: all cores this process may use for onnx, torch's default for torch);
        torch's count is set for each call only (:func:`.torch_device.torch_threads`), the process's kept
    depth : integrate depth (False: normals only; each frame's depth and points are then the undeformed dome's)
    device : "cpu", or a torch GPU ("cuda", "cuda:N"): every step of a frame on that GPU (:mod:`.fullframe`, the
        PyTorch backend; the same change rule, box integration and results as the CPU path)
    full_frame : the network's normals on every gel pixel, not only where the frame changed (the rest keeps
        the reference's otherwise), on ``device`` by :mod:`.fullframe`
    reference : (H, W, 3) float32, linear -- an undeformed frame of the sensor taken now (:meth:`refresh`): its LEDs,
        coating and exposure as they have aged since the calibration; None: the calibration's
    onnx : the ONNX file to run instead of the one beside the model (``nlips export MODEL --out F`` wrote it
        elsewhere): the per-pixel export, or with ``full_frame`` the full-frame graph; "auto" then runs it, checked
        as the one beside the model is (another model's is refused: named, it is not skipped); None: beside the model
    """

    def __init__(
        self,
        model_path: str | Path,
        backend: str = "torch",
        threads: int = 0,
        depth: bool = True,
        device: str = "cpu",
        full_frame: bool = False,
        reference: np.ndarray | None = None,
        onnx: str | Path | None = None,
    ):
        check_kind(model_path, PATH, "model_path", "the model file's path (str or Path)")
        check_kind(backend, str, "backend", "a backend's name ('auto', 'torch', 'onnx' ...)")
        if onnx is not None:
            check_kind(onnx, PATH, "onnx", "an ONNX file's path (str or Path), or None")
        backend = onnx_backend(backend, onnx, device, full_frame)
        self.onnx = None if onnx is None else Path(onnx)
        """The ONNX file named to run (``onnx``), or None: the one beside the model."""
        check_flag(depth, "depth")  # "no" is truthy: it integrated the depth (s38-apikinds)
        check_flag(full_frame, "full_frame")
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
            raise ConfigError(f"threads must be an integer >= 0 (0: all cores), got {threads!r}")
        self.device = predictor_device(device, backend, full_frame)
        self.full_frame = full_frame
        self.model = load_model(model_path)
        if self.model.table is not None and self.device is not None:
            raise ConfigError(
                f"{model_path}: a lookup table runs on the CPU, on the changed pixels (not on a GPU nor the whole "
                "frame): leave the device at cpu, without the whole frame"
            )
        ref = self.model.reference
        self.camera = Camera.from_dict(self.model.sensor["camera"])
        self.valid = ref["valid"].astype(bool)
        self.ref_tricolor = ref["tricolor"].astype(np.float32)
        self.ref_normals = np.where(self.valid[..., None], ref["normals"], 0).astype(np.float32)
        self.ref_depth = ref["depth"].astype(np.float64)
        self.dark = ref["dark"].astype(np.float32)
        sensor = self.model.sensor
        # the response the calibration's captures declared ("linear" in a model from before it was recorded): its
        # captures had their curve undone as they were loaded, the stored frames given here (stills, streams)
        # declare none and are taken as encoded alike
        self.camera_response = camera_response_of(sensor)
        self.tone_curve = response_table_of(sensor)
        self.geo = RayGeometry.from_reference(self.camera.rays, self.ref_depth) if depth else None
        # normals only: every frame's depth and points are the undeformed dome's; made once, not per frame (that
        # cost 2-8 ms a 640x480 frame, more than integrating the changed pixels with depth)
        self._reference_surface = None if depth else self._undeformed_surface()
        self.changed = ChangeDetector(self.ref_tricolor, self.valid)
        self.prefilter = Prefilter(self.valid, self.model.smoothing_px, self.model.smoothing_colour)
        self.backend = backend
        self._run = self._backend(backend, threads)
        self._full = self._frame_graph = None
        if self.device is not None:  # a GPU, or the whole frame on the CPU
            from .fullframe import FullFrame

            self._full = FullFrame(self.model, self.device, self.geo, keep_reference=not full_frame)
        if self.full_frame and self.backend == "onnx":  # the normals by MODEL.frame.onnx, the rest by .fullframe
            from .onnx_fullframe import FrameGraph, frame_graph_path

            graph = self.onnx or frame_graph_path(self.model.path)
            self._frame_graph = FrameGraph(graph, self.model, threads)
        self.gain = None
        """(H, W, 3) float32 or None -- what each frame is multiplied by first (:meth:`refresh`)."""
        if reference is not None:
            self.refresh(reference)
        self._warm_up()

    def refresh(self, reference: np.ndarray) -> None:
        """Bring frames of an aged sensor back to the calibration's light, without training again.

        LEDs dim with age (one colour group more than the others), the coating scuffs darker in places and the
        camera's exposure or gain drifts: each scales the light a gel pixel gets, so each frame is multiplied by the
        calibration's reference frame over ``reference`` (both smoothed on the gel first, so the new frame's
        noise is not copied into every frame). A 10 % dimmer LED group cost 6-7 deg of contact error, 0.0-0.1
        after a refresh (benchmarks/RESULTS.md, s28-ageing). A gel that swelled changes the shading itself, not
        only its scale: 0.15 mm of radius cost 0.35 deg on one twin press, 0.05 after a refresh; more than that
        was not measured, and a new calibration is the sure remedy. A ``reference`` taken while something pressed
        the gel would carry its dent into every frame: ``nlips infer --reference`` refuses one
        (:func:`.reference_press.press_in_frame`, which a caller of this method may use alike).

        Parameters
        ----------
        reference : (H, W, 3) float32, linear -- an undeformed frame of the sensor now (:meth:`linear`)
        """
        if reference.shape != self.shape + (3,):
            raise ShapeError(f"reference frame is {reference.shape}, the model expects {self.shape + (3,)}")
        old, new = (_smooth_on_gel(frame, self.valid) for frame in (self.ref_tricolor, reference))
        with np.errstate(divide="ignore", invalid="ignore"):
            gain = np.where(new > 0, old / new, 1.0)
        gain = np.clip(gain, 1 / REFRESH_GAIN_LIMIT, REFRESH_GAIN_LIMIT)
        self.gain = np.where(self.valid[..., None], gain, 1.0).astype(np.float32)
        if self._full is not None:  # applied on the device, after a stored frame's linearisation there
            self._full.set_gain(self.gain)

    def _undeformed_surface(self) -> tuple[np.ndarray, np.ndarray]:
        """(depth (H, W) float32 mm, points (H, W, 3) float32 mm, camera frame) of the calibration's undeformed dome:
        what every frame gives without depth."""
        depth = self.ref_depth.astype(np.float32)
        return depth, depth_to_points(depth, self.camera.rays).astype(np.float32)

    def _warm_up(self) -> None:
        """First calls import and plan (scipy.fft, the runtime's kernels): not part of any frame's time."""
        if self._frame_graph is not None:  # onnxruntime plans its first run; the rest without PyTorch's network
            empty = np.zeros(self.shape + (3,), np.uint16)
            self._full(empty, stored=True, normals=self._frame_graph(empty))
            return
        if self._full is not None:
            self._full.warm_up()
            return
        self._run(np.zeros((2, 5), np.float32))
        if self.geo is not None:
            unknown = np.zeros(self.valid.shape, bool)
            rows, cols = np.nonzero(self.valid)
            if len(rows):
                unknown[int(np.median(rows)), int(np.median(cols))] = True
                integrate_on_dome(self.ref_normals, unknown, self.geo)

    def _backend(self, backend: str, threads: int):
        """The network on the CPU: (N, 5) float32 pixels and filtered linear colours -> (N, 3) unit normals, for a
        model of colour ratios too (its ONNX graph divides the colours by the reference itself, PyTorch's runner
        here: once, either way); None on a GPU or the whole frame (:mod:`.fullframe`)."""
        on_cpu = self.device is None or (self.full_frame and self.device.type == "cpu")
        asked = backend
        model = self.model
        self.backend = backend = resolved_backend(model.path, backend, on_cpu, self.full_frame, model.digest, self.onnx)
        if asked == "auto" and backend == "torch" and on_cpu:  # an export there that cannot run: skipped, said
            from .exports import beside_export, skipped_warning, why_stale

            why = why_stale(beside_export(model.path, self.full_frame), model.digest, self.full_frame)
            if why is not None:
                log.warning("%s", skipped_warning(model.path, why, self.full_frame))
        if self.device is not None:  # a GPU or the whole frame: run by .fullframe (its normals by the graph: onnx)
            return None
        if backend == "lut":  # a lookup table (learn.lut): NumPy and SciPy, no network runtime
            table = self.model.table
            return lambda x: table.predict(x[:, :2], x[:, 2:])
        if backend in ("onnx", "onnx-int8"):
            from .onnx_export import OnnxNet

            export = self.onnx or Path(self.model.path).with_suffix(".onnx")
            return OnnxNet(export, self.model, threads, int8=backend == "onnx-int8")
        if backend != "torch":
            raise ShapeError(f"backend must be one of {BACKENDS}, got {backend!r}")
        import torch

        from .model import fused_net, model_inputs

        net = fused_net(self.model.net)
        divide = self.model.input_reference  # a model of colour ratios: its filtered reference (model_inputs)

        def run(x: np.ndarray):
            if divide is not None:
                x = model_inputs(x[:, :2], x[:, 2:], divide)
            with torch_threads(threads), torch.inference_mode():
                return net(torch.from_numpy(x)).numpy()

        return run

    @property
    def shape(self) -> tuple[int, int]:
        return self.model.shape

    # ------------------------------------------------------------------ inputs
    def linear(self, image: np.ndarray, where: str | Path = "frame", in_light: bool = False) -> np.ndarray:
        """Linear tri-colour image from stored 16-bit values, with the calibration's camera response, dark frame
        and levels.

        Parameters
        ----------
        image : (H, W, 3) uint16 stored values, encoded as the calibration's captures were (a tri-colour PNG or a
            camera frame of this sensor; not changed)
        where : name used in error messages (the file)
        in_light : ``image`` has the calibration's tone curve undone already (converted with :attr:`tone_curve`:
            ``device.camera.to_stored``, an 8-bit frame's in one 256-entry lookup)
        """
        if getattr(image, "dtype", None) != np.uint16:
            # an 8-bit frame was read as 16-bit values (1/256 of its light), a linear one as stored: no error
            got = getattr(image, "dtype", None) or f"a {type(image).__name__}, not an array"
            raise ShapeError(
                f"{where}: {got} values, not the stored frame's (H, W, 3) uint16 (an 8-bit camera frame: "
                "device.camera.to_stored(frame); a linear float frame: predict(frame))"
            )
        if image.shape != self.shape + (3,):
            h, w = self.shape
            raise CaptureError(
                f"{where}: image is {image.shape[1]}x{image.shape[0]}, the model was calibrated for {w}x{h} images"
            )
        return self._linearise(image if in_light else self.in_light(image))

    def in_light(self, image: np.ndarray) -> np.ndarray:
        """``image``'s stored values with the calibration's tone curve undone (a new array; ``image`` itself for a
        linear camera): what the capture loader makes of a declared camera's images, with the same table.

        Parameters
        ----------
        image : (H, W, 3) uint16 stored values as the camera encoded them

        Returns
        -------
        (H, W, 3) uint16 stored values linear in the light
        """
        if self.tone_curve is None:
            return image
        # a copy: the frame may be a reader's buffer or the caller's array (2.3 ms a 640x480 frame, the copy 0.3)
        return undo_tone_curve(np.array(image, np.uint16), self.tone_curve)

    def _linearise(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) float32 linear frame of stored values already linear in the light (:meth:`in_light`)."""
        s = self.model.sensor
        return linearise(image, self.dark, s["black_level"], s["white_level"])

    # ------------------------------------------------------------------ one frame
    def predict(self, tricolor: np.ndarray) -> Frame:
        """Normals, depth and points of one frame.

        Parameters
        ----------
        tricolor : (H, W, 3) float32, linear (``Press.linear(press.tricolor)`` or :meth:`linear`)

        Raises
        ------
        ShapeError -- another shape, or not a float array: a stored frame (uint16, a camera's or a PNG's) is
            :meth:`predict_stored`'s (it was taken for light 65535x full scale, and gave normals without a word)
        """
        shape = getattr(tricolor, "shape", None)
        if shape != self.shape + (3,):
            got = shape if shape is not None else f"a {type(tricolor).__name__}, not an array"
            raise ShapeError(f"tri-colour frame is {got}, the model expects {self.shape + (3,)}")
        if tricolor.dtype.kind != "f":
            raise ShapeError(
                f"tri-colour frame is {tricolor.dtype}: predict takes the linear frame (float32, 1 = full scale); "
                "give a stored frame (uint16, as a camera or a tri-colour PNG gives it) to predict_stored"
            )
        if self._full is not None:  # the gain (:meth:`refresh`) is applied on the device
            return self._whole_frame(tricolor, stored=False)
        captured = tricolor  # as the camera gave it: what is clipped there (:meth:`_exposure`)
        if self.gain is not None:  # an aged sensor's frame, in the calibration's light (:meth:`refresh`)
            tricolor = tricolor * self.gain
        t0 = time.perf_counter()
        changed = self.changed(tricolor)
        t1 = time.perf_counter()
        normals = self.ref_normals.copy()
        index = np.flatnonzero(changed)  # flat pixel indices: gathers and scatters on them are the cheapest
        if len(index) >= 1:
            x = np.empty((len(index), 5), np.float32)
            row, col = np.divmod(index, self.shape[1])
            x[:, 1], x[:, 0] = row, col  # v = row, u = column
            x[:, 2:] = self._colours(tricolor, row, col)  # a ratio model's runtime divides them (:meth:`_backend`)
            normals.reshape(-1, 3)[index] = self._run(x)
        t2 = time.perf_counter()
        if self.geo is not None:
            depth, points = integrate_on_dome(normals, changed, self.geo)
        else:  # copies: a caller may change its frame's arrays
            depth, points = (surface.copy() for surface in self._reference_surface)
        t3 = time.perf_counter()
        frame = Frame(normals, depth, points, changed, {}, mismatch=self.changed.mismatch)
        frame.channels = tuple(float(r) for r in self.changed.channel_ratio)
        if frame.mismatch > FRAME_MISMATCH_FRACTION:  # only then: what the warning can say about it
            frame.brightness, frame.saturated = self._exposure(captured, self.gain)
        t4 = time.perf_counter()
        # "check": the exposure of a frame unlike the calibration's (~20 ms of a 640x480 frame) is part of the
        # frame's time; outside the stages, a stream's stage line said 155 frames/s for 11.6 (s24 live walk)
        frame.seconds = {"change": t1 - t0, "network": t2 - t1, "integrate": t3 - t2, "check": t4 - t3}
        frame.seconds["total"] = t4 - t0
        return frame

    def _exposure(self, tricolor: np.ndarray, gain: np.ndarray | None = None) -> tuple[float, float]:
        """(brightness, saturated) of a linear frame as captured (:class:`Frame`): its median brightness on the gel
        over the reference frame's (1: as bright; 0 when no brighter than the calibration's dark frame, never
        negative), with ``gain`` ((H, W, 3) float32, :meth:`refresh`'s) in the calibration's light, and the share of
        the gel's pixels with a channel clipped (stored at the white level, or at
        :data:`~nlipscalib.core.sensor_response.CLIPPED_VALUE`) as captured: judged after the gain, a refresh's
        brightening named unclipped pixels "saturated (at the white level)" and its dimming hid clipped ones."""
        gel = tricolor[self.valid]
        level, clipped = self._exposure_levels
        saturated = float((gel >= clipped).any(-1).mean()) if len(gel) else 0.0
        if gain is not None:
            gel = gel * gain[self.valid]
        brightness = max(0.0, float(np.median(gel.sum(-1))) / level) if level > 0 else float("nan")
        return brightness, saturated

    @functools.cached_property
    def _exposure_levels(self) -> tuple[float, np.ndarray]:
        """(the reference frame's median brightness on the gel, (N, 3) float32 the clipping level at each gel pixel):
        :meth:`_exposure`'s constants, made once, at its first call (they were made for every frame unlike the
        calibration's: 11 of the 31 ms that check added to each such 640x480 frame of a stream)."""
        level = float(np.median(self.ref_tricolor[self.valid].sum(-1)))
        s = self.model.sensor
        # the clipping level at each gel pixel, linearised as the frame was (its tone curve undone first: an 8-bit
        # sRGB frame's 255 stays the white level, a 16-bit one's 0xFF00 is darker); half a step below for rounding
        # (a per-channel curve: each channel's own, (3,))
        top = np.float32(min(float(s["white_level"]), CLIPPED_VALUE))
        if self.tone_curve is not None:
            top = self.tone_curve[int(top)].astype(np.float32)
        top = top - np.float32(0.5)
        dark = self.dark[self.valid]
        if top.ndim:  # each channel's: one level per gel pixel and channel, as the dark frame's
            top = np.broadcast_to(top, dark.shape)
        return level, linearise(top, dark, s["black_level"], s["white_level"])

    def _colours(self, tricolor: np.ndarray, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """(N, 3) network input colours at the changed pixels: the model's prefilter, on their bounding box only."""
        rows, cols = slice(int(row[0]), int(row[-1]) + 1), slice(int(col.min()), int(col.max()) + 1)  # row is sorted
        return self.prefilter(tricolor, rows, cols)[row - rows.start, col - cols.start]

    def predict_stored(self, image: np.ndarray, where: str | Path = "frame", in_light: bool = False) -> Frame:
        """:meth:`predict` of a stored frame ((H, W, 3) uint16, as a camera or a tri-colour PNG gives it);
        ``in_light``: its tone curve undone already (:meth:`linear`)."""
        if self._full is not None and image.dtype == np.uint16 and image.shape == self.shape + (3,):
            # the tone curve undone here, the rest converted on the device: half the bytes to move; the frame as
            # stored kept for the full-frame graph, which undoes the curve itself
            light = image if in_light else self.in_light(image)
            return self._whole_frame(light, stored=True, encoded=None if in_light else image)
        t0 = time.perf_counter()
        linear = self.linear(image, where, in_light)
        t1 = time.perf_counter()
        frame = self.predict(linear)
        # the stored values' linearisation is a step of the frame too (a stream's frames are all stored)
        frame.seconds = {"linearise": t1 - t0, **frame.seconds, "total": time.perf_counter() - t0}
        return frame

    def _whole_frame(self, tricolor: np.ndarray, stored: bool, encoded: np.ndarray | None = None) -> Frame:
        """:mod:`.fullframe`'s result as a Frame ("changed": every gel pixel with ``full_frame``); with the full-frame
        graph (``--backend onnx``) its normals, from ``encoded`` (the frame as the camera stored it) or, without it,
        ``tricolor`` stored again (:meth:`_encoded`)."""
        given, network = None, {}
        if self._frame_graph is not None:
            t0 = time.perf_counter()
            if encoded is None or self.gain is not None:
                encoded = self._encoded(tricolor, stored)
            given = self._frame_graph(encoded)
            network = {"network": time.perf_counter() - t0}
        normals, depth, points, changed, seconds, mismatch, channels = self._full(tricolor, stored, given)
        if network:  # before the rest, and part of the frame's total
            seconds = network | seconds
            seconds["total"] += network["network"]
        frame = Frame(normals, depth, points, changed, seconds, mismatch=mismatch, channels=channels)
        if self.full_frame:  # the network's normals on the whole gel; the rule's changed pixels are the contact
            frame.changed, frame.contact = self.valid.copy(), changed
        t0 = time.perf_counter()
        if frame.mismatch > FRAME_MISMATCH_FRACTION:
            linear = self._linearise(tricolor) if stored else tricolor  # stored: its tone curve already undone
            frame.brightness, frame.saturated = self._exposure(linear, self.gain)
        check = time.perf_counter() - t0
        frame.seconds = {**{k: v for k, v in seconds.items() if k != "total"}, "check": check}
        frame.seconds["total"] = seconds["total"] + check
        return frame

    def _encoded(self, tricolor: np.ndarray, stored: bool) -> np.ndarray:
        """(H, W, 3) uint16: ``tricolor`` (linear float32, or stored values with the tone curve undone) as the camera
        would have stored it, the gain of :meth:`refresh` applied: the full-frame graph's input, which undoes the
        calibration's tone curve and subtracts the dark frame itself (a linear camera's frame comes back exactly; a
        tone curve rounds the brightest values by up to a step of 1/65535)."""
        linear = self._linearise(tricolor) if stored else tricolor
        if self.gain is not None:
            linear = linear * self.gain
        s = self.model.sensor
        values = np.clip(np.rint(linear * np.float32(s["white_level"] - s["black_level"]) + self.dark), 0, 65535)
        if self.tone_curve is not None:
            values = np.clip(np.rint(redo_tone_curve(values, self.tone_curve)), 0, 65535)
        return values.astype(np.uint16)


def predictor_device(device: str, backend: str, full_frame: bool, flag: bool = False) -> torch.device | None:
    """The torch device a :class:`Predictor` runs on, or None for the CPU without the whole-frame path (no torch
    needed then); ConfigError for a backend that cannot run there. ``flag``: worded for the command line
    (``--device cuda``, :func:`nlipscalib.core.config.said`); ``nlips infer`` and ``nlips live`` check their options so
    before the Predictor is made."""
    if device == "cpu" and not full_frame:
        return None
    # the whole frame on the CPU may take its normals from the full-frame graph (MODEL.frame.onnx, onnxruntime)
    if full_frame and device == "cpu" and backend == "onnx-int8":
        raise ConfigError(
            f"{said('backend', backend, flag)} quantises the per-pixel network: "
            f"{'--full-frame' if flag else 'full_frame=True'} runs PyTorch ({said('backend', 'torch', flag)}) or the "
            f"full-frame graph, MODEL.frame.onnx ({said('backend', 'onnx', flag)})"
        )
    if backend not in ("auto", "torch") and not (full_frame and device == "cpu" and backend == "onnx"):
        full = f" and {'--full-frame' if flag else 'full_frame=True'} run" if full_frame else " runs"
        raise ConfigError(
            f"{said('backend', backend, flag)} runs on the CPU alone: {said('device', device, flag)}{full} the "
            f"PyTorch backend ({said('backend', 'torch', flag)})"
        )
    from .torch_device import check_device

    return check_device(device, flag)


def _smooth_on_gel(frame: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32: ``frame`` Gaussian-smoothed over the gel only (normalised by the gel's own weight, so the
    dark off-gel pixels do not darken its rim), :data:`~nlipscalib.core.tolerances.REFRESH_SMOOTHING_PX`."""
    from .reference_press import smooth_on_gel

    return smooth_on_gel(frame, valid, REFRESH_SMOOTHING_PX)


def onnx_backend(
    backend: str, onnx: str | Path | None, device: str = "cpu", full_frame: bool = False, flag: bool = False
) -> str:
    """The backend a :class:`Predictor` given ``backend`` and the ONNX file ``onnx`` to run (None: the one beside the
    model, ``backend`` as it is) runs: "onnx" for "auto", onnx and onnx-int8 as they are; ConfigError for "torch",
    or a device where no ONNX file runs (a GPU: PyTorch runs every step there). ``flag``: worded for the command
    line (``--onnx F``)."""
    if onnx is None:
        return backend
    if not Path(onnx).is_file():  # before the model loads: the option's file, named as given
        raise ConfigError(f"{said('onnx', onnx, flag)}: no such file (`nlips export MODEL --out FILE` writes one)")
    if backend == "torch":
        raise ConfigError(
            f"{said('onnx', onnx, flag)} names an ONNX file for onnxruntime, {said('backend', 'torch', flag)} runs "
            f"PyTorch: {'drop one of them' if flag else 'give backend=' + repr('onnx') + ' (the default is torch)'}"
        )
    if device != "cpu":
        raise ConfigError(
            f"{said('onnx', onnx, flag)} runs on the CPU (onnxruntime), {said('device', device, flag)} runs PyTorch "
            "on the GPU: drop one of them"
        )
    return "onnx" if backend == "auto" else backend


def resolved_backend(
    model_path: str | Path,
    backend: str,
    on_cpu: bool = True,
    full_frame: bool = False,
    digest: str | None = None,
    onnx: str | Path | None = None,
) -> str:
    """The runtime a :class:`Predictor` of ``model_path`` with ``backend`` runs (what its results record).

    PyTorch off the CPU (``on_cpu`` False: a GPU, run by :mod:`.fullframe`); "auto" is onnxruntime ("onnx") when the
    model was exported beside it (MODEL.onnx: ``nlips train`` writes one; with ``full_frame``, MODEL.frame.onnx:
    ``nlips export MODEL --full-frame``) and that export records this model's digest, else PyTorch (an export left
    from before the model was trained again, or a ratio model's of before 2026-12-07, is skipped:
    :func:`.exports.why_stale`); with ``onnx`` (an ONNX file named to run) "onnx" (:func:`onnx_backend`); any other
    as given; "lut" for a lookup table's file (``learn.model.model_method``). ``digest``: the model file's
    (``onnx_export.bytes_digest``, of the bytes loaded), read from the file when not given. Found from the file
    names, a table's first pickled strings and the export's recorded metadata alone (a few hundred bytes:
    ``onnx_export.recorded_metadata``), so ``nlips infer`` can tell that a re-run's results are all kept without
    loading the model or importing either runtime.
    """
    from .model import model_method

    if model_method(model_path) == "lut":  # a lookup table runs on its own; what the others run is a network
        if onnx is not None:
            raise ConfigError(
                f"{model_path}: a lookup table (`nlips lut`), run by NumPy and SciPy: the ONNX file {onnx} holds an "
                "NLiPsNet network; leave it out"
            )
        if backend != "auto":
            raise ConfigError(
                f"{model_path}: a lookup table (`nlips lut`), run by NumPy and SciPy: backend {backend!r} runs an "
                "NLiPsNet network; leave the backend at auto"
            )
        return "lut"
    if not on_cpu:
        return "torch"
    backend = onnx_backend(backend, onnx)
    if backend == "auto":
        from .exports import beside_export, why_stale
        from .onnx_export import file_digest

        export = beside_export(model_path, full_frame)
        if not export.is_file():
            return "torch"
        return "torch" if why_stale(export, digest or file_digest(model_path), full_frame) else "onnx"
    return backend


def capture_changes(model: LoadedModel, folder: str | Path) -> list[str]:
    """'key: calibration's -> press's' of every capture setting (``core.sensor_record.capture_settings``) where the
    press folder ``folder`` was taken otherwise than the model's calibration reference; empty when the same, or
    when the model predates the record (2026-12-05) or the press's meta.json cannot be read (its load says why)."""
    from ..core.press_meta import read_meta
    from ..core.sensor_record import capture_settings, setting_differences

    recorded = model.info.get("capture")
    if not isinstance(recorded, dict):
        return []
    try:
        meta = read_meta(Path(folder))
    except (CaptureError, OSError, ValueError):
        return []
    return setting_differences(recorded, capture_settings(meta), recorded_only=True)


def mismatch_warning(frame: Frame, where: str | Path, changes: Sequence[str] = ()) -> str | None:
    """Why ``frame``'s result is not to be trusted when it differs from the reference frame almost everywhere.

    The change rule finds the pixels that differ from the rest of the frame; a frame unlike the calibration's
    reference over the whole gel (another exposure, LEDs off or lit otherwise, red and blue swapped, another
    sensor) leaves it nothing to find, and the result would silently be the undeformed dome. None when the
    frame is like the reference (:data:`nlipscalib.core.tolerances.FRAME_MISMATCH_FRACTION`). ``changes``: the
    capture settings a press was taken with otherwise than the calibration (:func:`capture_changes`), named as the
    cause instead of a guess from the brightness.
    """
    check_kind(frame, Frame, "frame", "a Frame (Predictor.predict's result)")
    check_kind(where, PATH, "where", "what the frame is of, for the message: a press folder's path or a name")
    if not frame.mismatch > FRAME_MISMATCH_FRACTION:
        return drift_warning(frame, where)
    brightness = 0.0 if frame.brightness < 0 else frame.brightness  # never a negative ratio (NaN stays NaN)
    off = abs(brightness - 1) > FRAME_BRIGHTNESS_OFF
    if changes:  # recorded: what differs is known, no guess
        shown = ", ".join(changes[:3]) + (f" and {len(changes) - 3} more" if len(changes) > 3 else "")
        question = (
            f"it was captured with other settings than the calibration's presses ({shown}): infer presses taken "
            "with the calibration's settings, or calibrate on presses taken with these"
        )
    elif brightness <= FRAME_BLACK_FRACTION:
        question = "the frame is black (no light above the black level: LEDs off, lens cap, camera not streaming?)"
    elif frame.saturated >= SATURATED_SHARE_WARN:
        times = f", and it is {brightness:.2g} times as bright" if off else ""
        share = 100 if frame.saturated >= 1 else int(100 * frame.saturated)  # 99.6 % is not all of it
        question = (
            f"{share} % of the gel is saturated (at the white level){times}: was it taken at the calibration's "
            "exposure and LED level?"
        )
    elif off:  # darker or brighter throughout: say by how much
        question = (
            f"it is {brightness:.2g} times as bright: was it taken at the calibration's exposure and LED level, "
            "with its values at the calibration's bit depth (12-bit values in a 16-bit file are 1/16 as bright)? "
            f"{REFRESH_REMEDY}"
        )
    elif _explains(frame.channels, frame.mismatch):  # dimmer (or brighter) colours: light that aged
        question = f"{_channel_words(frame.channels)}: {REFRESH_REMEDY}"
    else:
        question = (
            "was it taken with this sensor, its LEDs lit in the tri-colour pattern, and stored as RGB (not "
            "OpenCV's BGR)?"
        )
    return (
        f"{where}: differs from the calibration's reference frame over most of the gel (median difference "
        f"{100 * frame.mismatch:.0f} % of its brightness; a press changes only part of it, and up to "
        f"{100 * FRAME_MISMATCH_FRACTION:.0f} % is normal), so a contact cannot be told apart and the result is "
        f"unreliable: {question}"
    )


REFRESH_REMEDY = (
    "LEDs dimmed with age, or the exposure or gain drifted since the calibration? Capture an undeformed frame now "
    "and pass it with `nlips infer MODEL ... --reference FRAME` (no training), or calibrate again"
)
"""What to do about a sensor whose light drifted (:func:`drift_warning`)."""


def _drifted(channels: Sequence[float]) -> bool:
    return any(not abs(r - 1) <= FRAME_CHANNEL_DRIFT for r in channels)  # NaN counts as drifted


def _explains(channels: Sequence[float], mismatch: float) -> bool:
    """Whether colours that drifted account for a frame's mismatch: every colour off the same way (LEDs that aged,
    an exposure that drifted; not one up and one down) and by at least half the median difference (a colour 10 %
    dimmer gave 3.5 %; red and blue swapped, BGR stored as RGB, gave 14-28 % with the medians 3 % apart)."""
    off = max(abs(r - 1) for r in channels)
    one_way = all(r <= 1 + FRAME_CHANNEL_DRIFT for r in channels) or all(r >= 1 - FRAME_CHANNEL_DRIFT for r in channels)
    return _drifted(channels) and one_way and off >= mismatch / 2


def _channel_words(channels: Sequence[float]) -> str:
    shown = ", ".join(f"{name} {ratio:.2f}" for name, ratio in zip(("red", "green", "blue"), channels))
    return f"the undeformed gel is {shown} times as bright as in the calibration's reference frame"


def drift_warning(frame: Frame, where: str | Path) -> str | None:
    """Why ``frame``'s result drifted when the frame is otherwise like the reference (:func:`mismatch_warning`
    says why when it is not): a colour's median on the unchanged gel off the reference's by more than
    :data:`~nlipscalib.core.tolerances.FRAME_CHANNEL_DRIFT` (an aged LED group, a drifted exposure or gain);
    None otherwise. The model (a network or a lookup table) reads colours as they were at the calibration: 5 % less
    red cost the network 3 deg."""
    if not _drifted(frame.channels):
        return None
    return (
        f"{where}: {_channel_words(frame.channels)} (more than {100 * FRAME_CHANNEL_DRIFT:.3g} % off), so the "
        f"model reads its colours as other normals and the result drifts by degrees: {REFRESH_REMEDY}"
    )


def to_reconstruction(
    frame: Frame, predictor: Predictor, source: str, provenance: dict | None = None, identity: dict | None = None
) -> Reconstruction:
    """The frame in the core reconstruction format (what ``nlips eval`` scores).

    Parameters
    ----------
    frame : Frame
    predictor : Predictor
    source : str
        The name of the press or image frame it read (report ``source``).
    provenance : dict, optional
        What made it, recorded as the report's ``provenance`` (docs/formats.md; ``nlips infer`` writes ``key``,
        ``software_version``, ``settings`` and ``inputs``). Its ``inputs``, the identity of what it read
        (``{"press": capture identity}`` or ``{"frame": SHA-256 of the image file}``), is what ``nlips eval
        PRESS --result`` compares with PRESS. None: nothing recorded (eval then warns it cannot check).
        A press's identity is also compared with the captures the model learnt from (:func:`.seen.trained_on`):
        the report's ``trained_on`` ("train", "validation" or "unseen"; absent when it cannot tell), by which
        ``nlips eval`` scores seen and unseen presses apart.
    identity : dict, optional
        The input's identity by content (``core.press_identity.press_identity`` of a press folder, ``frame_identity``
        of an image frame), compared first (:func:`.seen.trained_on`); None: the ``inputs`` alone.
    """
    from ..core.reconstruction import Reconstruction
    from .seen import TRAINED_ON_KEY, trained_on

    check_kind(frame, Frame, "frame", "a Frame (Predictor.predict's result)")
    check_kind(predictor, Predictor, "predictor", "the Predictor that made the frame")
    check_kind(source, PATH, "source", "the name of the press or image the frame is of (str)")
    valid = predictor.valid
    H, W = valid.shape
    nan = np.full((H, W), np.nan, np.float32)
    inputs = (provenance or {}).get("inputs")
    return Reconstruction(
        depth=np.where(valid, frame.depth, np.nan).astype(np.float32),
        points=np.where(valid[..., None], frame.points, np.nan).astype(np.float32),
        normals=np.where(valid[..., None], frame.normals, np.nan).astype(np.float32),
        albedo=np.full((H, W, 3), np.nan, np.float32),
        residual=nan,
        confidence=valid.astype(np.float32),
        usable_leds=np.zeros((H, W), np.int16),
        mask=valid.copy(),
        reconstructed=valid.copy(),
        report={
            "method": predictor.model.method,
            "model": str(predictor.model.path.resolve()),  # absolute: a later command may run elsewhere
            "backend": predictor.backend,
            "device": str(predictor.device or "cpu"),
            "full_frame": predictor.full_frame,
        }
        | model_shape(predictor.model)
        | {
            "labels": predictor.model.info.get("labels"),
            "source": source,
            "changed_pixels": int(frame.changed.sum()),
            "seconds": frame.seconds,
        }
        | ({TRAINED_ON_KEY: seen} if (seen := trained_on(predictor.model.info, inputs, identity)) else {})
        | ({"provenance": dict(provenance)} if provenance else {}),
    )


def model_shape(model: LoadedModel) -> dict:
    """A result's (report.json) and a stream's (stream.json) record of what the model is: an NLiPsNet's ``hidden``
    layer widths, a lookup table's ``table`` (``bins`` levels per channel, ``cells`` regions per side)."""
    if model.table is not None:
        return {"table": {"bins": model.table.bins, "cells": model.table.cells}}
    return {"hidden": list(model.hidden)}


def load_tricolor(folder: str | Path) -> tuple[np.ndarray, dict]:
    """The linear tri-colour frame and sensor description of a press folder, without its LED images.

    Returns
    -------
    frame : (H, W, 3) float32, linear (dark-subtracted, 1 = full scale)
    sensor : dict (:func:`nlipscalib.core.sensor_record.sensor_of` layout)
    """
    from ..core.imageio import capture_shape_problem, read_png16
    from ..core.press_meta import META_FILE, parse_optics, read_meta
    from ..core.sensor_record import describe_sensor
    from ..core.sensor_response import undo_tone_curve

    check_kind(folder, PATH, "folder", "a press folder's path (str or Path)")
    folder = Path(folder)
    meta = read_meta(folder)
    camera, leds, response = parse_optics(meta, folder / META_FILE)  # each bad key named, as load_press does
    sensor = describe_sensor(camera, leds, response)
    images = []
    for name in (meta["images"]["tricolor"], meta["images"]["dark"]):
        img = read_png16(folder / name)
        if problem := capture_shape_problem(img.shape, camera.shape):
            raise CaptureError(f"{folder / name}: {problem}")
        images.append(undo_tone_curve(img, response.tone_curve()))  # a declared sRGB camera, as load_press does
    return linearise(images[0], images[1], response.black_level, response.white_level), sensor
