"""The press capture format shared by the digital twin (sim/) and the real sensor (device/).

A press folder (see docs/formats.md)::

    press_0007/
      meta.json        camera, LEDs, sensor response, provenance
      dark.png         all LEDs off, 16-bit RGB, linear
      led_01.png ...   one image per LED lit alone in white
      tricolor.png     LED groups lit in red, green, blue at once
      reference.npz    optional: undeformed-dome depth and normals (sensor design / CAD)
      gt.npz           optional (synthetic presses): per-pixel ground truth

Writers build the folder under a temporary name and rename it when complete
(:func:`nlipscalib.core.atomic.atomic_dir`), so a press folder that exists is whole.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import logging
import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from .. import __version__
from .atomic import TMP_PREFIX, atomic_dir, write_json
from .camera import Camera
from .cpus import usable_cores
from .errors import CaptureError, ShapeError
from .formatfile import read_arrays, read_format_json
from .imageio import decode_png16, png_size, read_png_bytes, save_npz, write_png16
from .leds import Led, Leds
from .prefetch import prefetch_images
from .prefetch import stop as stop_prefetching
from .prefetch import take as take_prefetched
from .surface_checks import surface_problem

FORMAT_NAME = "nlipscalib.press"
FORMAT_VERSION = 1
META_FILE = "meta.json"
GT_FILE = "gt.npz"
REFERENCE_FILE = "reference.npz"
REFERENCE_FOLDER = "reference"
"""A folder of presses (a twin dataset, a capture session) keeps the capture of its undeformed dome here."""
log = logging.getLogger(__name__)
GT_KEYS = {"depth": 2, "points": 3, "normals": 3, "valid": 2, "contact": 2}
"""Ground-truth arrays and their number of dimensions; all (H, W[, 3]) in the camera frame."""


def led_frame_name(index: int) -> str:
    """Name of LED ``index``'s (0-based) frame: led_01 for the first LED (a capture's frame, its image's stem)."""
    return f"led_{index + 1:02d}"


def led_image_name(index: int) -> str:
    """File name of LED ``index`` (0-based) image: led_01.png for the first LED."""
    return f"{led_frame_name(index)}.png"


def white_level_of(bit_depth: int) -> int:
    """The stored white level of a ``bit_depth``-bit sensor: its largest value shifted up to 16 bits, as stored
    values are (``DN << (16 - bit_depth)``, docs/formats.md; ``device.camera.to_stored``): 0xFF00 at 8 bits."""
    return ((1 << bit_depth) - 1) << (16 - bit_depth)


LEAST_BIT_DEPTH = 8
"""Fewest bits a sensor's values have (:attr:`SensorResponse.bit_depth`): an 8-bit camera, video or image file."""
CLIPPED_VALUE = white_level_of(LEAST_BIT_DEPTH)
"""Stored values from here up count as clipped in a frame from any source (``nlips infer``'s images and streams),
even below the sensor's white level: the white level of the fewest bits a frame has, an 8-bit frame's 255 shifted
up to 16 bits (0xFF00)."""


def linearise(
    image: np.ndarray, dark: np.ndarray, black_level: float, white_level: float, out: np.ndarray | None = None
) -> np.ndarray:
    """Dark-subtracted linear intensity, scaled so the sensor's full range is 1: the one conversion of stored
    values to light (:meth:`Press.linear`, NLiPsNet's frames, the capture's exposure check).

    Parameters
    ----------
    image : (..., H, W, 3) stored values (uint16), or a scalar (one stored level, e.g. the clipping value)
    dark : (H, W, 3) the dark frame's stored values (uint16, or float32 already); any shape that ``image``
        ends with (e.g. (N, 3), the gel's pixels)
    black_level, white_level : the sensor's levels (:class:`SensorResponse`), 16-bit units
    out : (..., H, W, 3) float32 or None -- written and returned when given (an array image only)

    Returns
    -------
    (..., H, W, 3) float32, 0 = dark frame, 1 = full scale: ``(image - dark) / (white_level - black_level)``
    """
    image, dark = np.asarray(image), np.asarray(dark)
    if image.ndim and image.shape[image.ndim - dark.ndim :] != dark.shape:  # (H, W, 3) - (1, W, 3) broadcast silently
        raise ShapeError(f"image {image.shape} must end with the dark frame's shape {dark.shape}")
    scale = np.float32(white_level - black_level)
    # one float32 array, cast while subtracting and divided in place: the same numbers as casting both first, without
    # two more arrays of the result's size (12 LED images at 640x480: 44 MB each, most of their cost page faults)
    diff = np.subtract(image, dark, dtype=np.float32, out=out)
    return np.divide(diff, scale, out=diff) if diff.ndim else diff / scale


@dataclasses.dataclass(frozen=True)
class SensorResponse:
    """How stored 16-bit values relate to light."""

    bit_depth: int = 12
    """Bits of the sensor ADC; stored values are DN << (16 - bit_depth)."""
    black_level: float = 256.0
    """Stored value of zero light (16-bit units), before read noise."""
    white_level: float = 65520.0
    """Largest stored value; pixels at or above it are saturated (16-bit units)."""
    exposure_ms: float = 10.0
    """Exposure time, ms (informational; images are not normalised by it); > 0."""
    gain: float = 1.0
    """Analogue gain (informational); >= 0."""

    def __post_init__(self):
        from .config import is_finite_number, is_whole_number

        # types first: a string compared below would fail as "'<=' not supported ...", naming no key
        if not is_whole_number(self.bit_depth):
            raise CaptureError(f"sensor.bit_depth must be a whole number of bits, got {self.bit_depth!r}")
        for key in ("black_level", "white_level", "exposure_ms", "gain"):
            if not is_finite_number(getattr(self, key)):
                raise CaptureError(f"sensor.{key} must be a finite number, got {getattr(self, key)!r}")
        if not self.exposure_ms > 0 or self.gain < 0:
            raise CaptureError(
                f"sensor.exposure_ms must be > 0 and sensor.gain >= 0, got {self.exposure_ms}, {self.gain}"
            )
        if not LEAST_BIT_DEPTH <= self.bit_depth <= 16:
            raise CaptureError(f"sensor.bit_depth must be {LEAST_BIT_DEPTH}..16, got {self.bit_depth}")
        if not 0 <= self.black_level < self.white_level <= 65535:
            raise CaptureError(
                f"sensor levels must satisfy 0 <= black_level < white_level <= 65535, "
                f"got {self.black_level}, {self.white_level}"
            )

    def saturated(self, image: np.ndarray) -> np.ndarray:
        """Which stored values are at or above the white level (clipped).

        Parameters
        ----------
        image : (..., H, W, 3) uint16 (or float) -- stored 16-bit values, not linearised.

        Returns
        -------
        (..., H, W, 3) bool, per channel.
        """
        return image >= self.white_level


@dataclasses.dataclass(frozen=True)
class GroundTruth:
    """Per-pixel truth of a synthetic press, camera frame, millimetres."""

    depth: np.ndarray
    """(H, W) float32, mm -- z coordinate of the surface point; NaN where the ray misses the gel."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, pointing toward the camera (shading normals)."""
    valid: np.ndarray
    """(H, W) bool -- the pixel sees the gel surface."""
    contact: np.ndarray
    """(H, W) bool -- the gel under this pixel is displaced by the press."""

    def save(self, path: Path) -> None:
        save_npz(path, {k: getattr(self, k) for k in GT_KEYS})

    @classmethod
    def load(cls, path: Path, shape: tuple[int, int]) -> GroundTruth:
        arrays = _load_npz(path, GT_KEYS)
        for key, ndim in GT_KEYS.items():
            a = arrays[key]
            want = shape + ((3,) if ndim == 3 else ())
            if a.shape != want:
                raise CaptureError(f"{path}: ground truth '{key}' has shape {a.shape}, expected {want}")
        return cls(**{k: arrays[k] for k in GT_KEYS})


@dataclasses.dataclass(frozen=True)
class Reference:
    """The undeformed sensor surface as seen by the camera (from the design or a calibration)."""

    depth: np.ndarray
    """(H, W) float32, mm -- z of the undeformed gel surface; NaN where the ray misses the gel."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, toward the camera."""

    def save(self, path: Path) -> None:
        save_npz(path, {"depth": self.depth, "normals": self.normals})

    @classmethod
    def load(cls, path: Path, shape: tuple[int, int]) -> Reference:
        arrays = _load_npz_kept(path, {"depth": 2, "normals": 3})
        if arrays["depth"].shape != shape or arrays["normals"].shape != shape + (3,):
            raise CaptureError(f"{path}: reference arrays do not match the camera size {shape}")
        return cls(depth=arrays["depth"], normals=arrays["normals"])


class Loader:
    """A value of a :class:`Press` field given before it is loaded: ``load()`` makes it at the first read of the
    field (:class:`_LoadedOnRead`), and any error it raises (a CaptureError naming the file) comes out there."""

    def __init__(self, load: Callable[[], object]):
        self._load = load

    def load(self) -> object:
        return self._load()


class FileLoader(Loader):
    """A :class:`Loader` of one file of the capture, which must still be the file that was there when the press
    was loaded: a press is what its folder held then, and a file replaced since (the folder rendered or captured
    again) would mix two presses in one object. Such a read is refused, naming the file."""

    def __init__(self, path: Path, load: Callable[[], object]):
        super().__init__(load)
        self.path = path
        self.stamp = _stamp_or_none(path)

    def load(self) -> object:
        if _stamp_or_none(self.path) != self.stamp:
            raise CaptureError(f"{self.path}: changed since the press was loaded; load the press again")
        return self._load()


def _stamp_or_none(path: Path) -> tuple[int, ...] | None:
    try:
        return file_stamp(path)
    except OSError:  # missing: the loader names it at the read, as it would have at the load
        return None


class StoredImages(Loader):
    """Stored images of a capture read from their PNG files now, decoded at the first read.

    The files' bytes are read once and kept until decoded, so the decoded images and :attr:`digest` always
    name the same content, whatever happens to the files later.
    """

    def __init__(
        self, paths: Sequence[Path], data: Sequence[np.ndarray], camera: Camera, stacked: bool, named: bool = True
    ):
        self._paths, self._data, self._camera, self._stacked = list(paths), list(data), camera, stacked
        self._images, self._lock = None, threading.Lock()
        self.digest = _bytes_digest(self._data) if named else None
        """Digest of the files' raw bytes, in order; None when not ``named`` (images decoded at once: ~25 ms
        of hashing at 640x480 that nothing reads)."""

    def load(self) -> np.ndarray:
        return decode_together(self)[0]

    def __getstate__(self) -> dict:  # a Press sent to another process (a worker): the lock is this process's
        return {k: v for k, v in self.__dict__.items() if k != "_lock"}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, _lock=threading.Lock())


def _bytes_digest(data: Sequence[np.ndarray]) -> str:
    h = hashlib.blake2b(digest_size=16)
    for d in data:  # lengths too: the same bytes cut between two files otherwise would not differ
        h.update(len(d).to_bytes(8, "little"))
        h.update(memoryview(d))
    return f"png:{h.hexdigest()}"


def decode_together(*sources: StoredImages) -> list[np.ndarray]:
    """The images of ``sources``, each (H, W, 3) or stacked (N, H, W, 3) uint16, decoded on one thread pool
    (libpng and zlib release the GIL) once for all reads of them; a problem names its file (:func:`_load_image`'s
    errors)."""
    for src in sources:  # in order, always: two threads reading two fields at once wait for each other
        src._lock.acquire()
    try:
        todo = [src for src in sources if src._images is None]
        # each image decoded straight into its place in the result: no per-image copies, no np.stack
        images = [np.empty((len(src._paths),) + src._camera.shape + (3,), np.uint16) for src in todo]
        jobs = [
            (_decode_image, p, d, src._camera, out[i])
            for src, out in zip(todo, images)
            for i, (p, d) in enumerate(zip(src._paths, src._data))
        ]
        if jobs:
            stop_prefetching()  # what the prefetch has not begun is decoded here, on two threads
            _in_threads(jobs)
        for src, out in zip(todo, images):  # only now: a failed decode leaves the source undecoded
            src._images = out if src._stacked else out[0]
            src._data = []  # the bytes are no longer needed
        return [src._images for src in sources]
    finally:
        for src in sources:
            src._lock.release()


def decode_in_background(*sources: StoredImages) -> threading.Thread:
    """Start :func:`decode_together` of ``sources`` on a thread of its own and return it; the first read of them
    waits for it (the sources' locks), or decodes them itself when it comes before the thread took them.

    Why: cv2's PNG decoding releases the GIL, so the decoding runs on the second core while the caller goes on
    (``nlips solve`` reads and checks reference.npz meanwhile; the decoding is ~0.14 s on two threads at 640x480
    with 12 LEDs).

    A problem is not raised on the thread: a failed decode leaves its source undecoded, and the first read decodes
    it again and raises the error there, naming the file (:func:`_load_image`'s errors)."""

    def decode() -> None:
        with contextlib.suppress(Exception):  # raised again, at the first read, to whoever reads the images
            decode_together(*sources)

    thread = threading.Thread(target=decode, name="decode-capture", daemon=True)
    thread.start()
    return thread


class _LoadedOnRead:
    """A :class:`Press` field that takes its value or a :class:`Loader` of it: the value is loaded at the
    first read and kept. Why: a solve reads neither the tri-colour image nor the ground truth, and a solve that
    reuses the undeformed capture's results never reads its images (decoding them is most of a warm process's
    loading)."""

    def __init__(self, default: object = dataclasses.MISSING):
        self.default = default

    def __set_name__(self, owner: type, name: str):
        self.name = name

    def __get__(self, obj: object, owner: type | None = None) -> object:
        if obj is None:  # the dataclass asks for the field's default
            if self.default is dataclasses.MISSING:
                raise AttributeError(self.name)
            return self.default
        value = obj.__dict__[self.name]
        if isinstance(value, Loader):
            value = value.load()
            obj.__dict__[self.name] = value  # the Loader stays in the source: what the value was read from
        return value

    def __set__(self, obj: object, value: object) -> None:  # __init__ only: the frozen Press refuses others
        obj.__dict__[self.name] = value
        obj.__dict__[f"{self.name}_source"] = value if isinstance(value, Loader) else None


@dataclasses.dataclass(frozen=True)
class Press:
    """One press: everything the solver and the network need, loaded and validated."""

    folder: Path
    """Where it was loaded from."""
    camera: Camera
    """Intrinsics and lens of the camera that took the images (meta.json ``camera``); ``camera.shape`` = (H, W)."""
    leds: tuple[Led, ...]
    """The L LEDs, camera frame, mm, in the order of ``led_images`` (meta.json ``leds``)."""
    response: SensorResponse
    """How the stored values relate to light: bit depth, black and white levels (meta.json ``sensor``)."""
    dark: np.ndarray = _LoadedOnRead()
    """(H, W, 3) uint16, stored values, RGB (may be given as a :class:`Loader`: loaded at the first read)."""
    led_images: np.ndarray = _LoadedOnRead()
    """(L, H, W, 3) uint16, stored values, RGB, one per LED lit alone in white (may be given deferred)."""
    tricolor: np.ndarray = _LoadedOnRead()
    """(H, W, 3) uint16, stored values, RGB (may be given deferred: a solve does not read it)."""
    meta: dict
    """The whole meta.json (provenance: scene, indenter, press pose, seed, software version)."""
    reference: Reference | None = None
    """The undeformed surface (reference.npz), or None when the folder has none; its arrays are read-only (one
    load per process is shared by every press loaded from the file)."""
    ground_truth: GroundTruth | None = _LoadedOnRead(None)
    """Per-pixel truth (gt.npz, synthetic presses only), or None (may be given deferred)."""

    def images_digest(self) -> str:
        """A digest naming the stored dark and LED images: of the raw bytes of the files they are decoded from
        when :func:`load_press` deferred them (:class:`StoredImages`: nothing decoded to name them), else of the
        arrays (:func:`nlipscalib.core.diskcache.digest`)."""
        sources = self.__dict__["dark_source"], self.__dict__["led_images_source"]
        if all(isinstance(src, StoredImages) and src.digest for src in sources):
            return "+".join(src.digest for src in sources)
        from .diskcache import digest

        return digest(self.led_images, self.dark)

    def linear(self, image: np.ndarray, window: tuple[slice, slice] = (slice(None), slice(None))) -> np.ndarray:
        """Dark-subtracted linear intensity, scaled so the sensor's full range is 1.

        Parameters
        ----------
        image : (..., H, W, 3) uint16, stored values (or (..., h, w, 3) cut out with ``window``)
        window : (rows, cols) slices that cut ``image`` out of the full frame; the dark frame is cut alike

        Returns
        -------
        (..., H, W, 3) float32, linear, 0 = dark frame, 1 = full scale
        """
        return linearise(image, self.dark[tuple(window)], self.response.black_level, self.response.white_level)

    @functools.cached_property
    def linear_led_images(self) -> np.ndarray:
        """(L, H, W, 3) float32, read-only -- :meth:`linear` of ``led_images``, computed once per press
        (a solve reads it in the contact classification, the indirect fit and the solve itself).

        One LED per thread (:func:`_in_threads`; each element's own arithmetic, so the same numbers): at 640x480
        with 12 LEDs the conversion, most of it the first touch of the 44 MB result's pages, took ~17-30 ms of one
        core at the start of every solve while the other waited."""
        images = self.led_images
        lin = np.empty(images.shape, np.float32)
        black, white = self.response.black_level, self.response.white_level
        _in_threads([(linearise, images[i], self.dark, black, white, lin[i]) for i in range(len(images))])
        lin.setflags(write=False)
        return lin

    @functools.cached_property
    def saturated_led_images(self) -> np.ndarray:
        """(L, H, W, 3) bool, read-only -- :meth:`saturated` of ``led_images``, computed once per press (a solve
        reads it in the contact classification, the indirect fit of a press on itself and the solve itself:
        ~4 ms each at 640x480 with 12 LEDs, two of them on two threads at once)."""
        saturated = self.saturated(self.led_images)
        saturated.setflags(write=False)
        return saturated

    def saturated(self, image: np.ndarray) -> np.ndarray:
        """Which stored values are at or above the white level (:meth:`SensorResponse.saturated`).

        Parameters
        ----------
        image : (..., H, W, 3) uint16 -- stored 16-bit values of this press (e.g. ``led_images``), not linearised.

        Returns
        -------
        (..., H, W, 3) bool, per channel.
        """
        return self.response.saturated(image)


def write_press(
    folder: str | Path,
    camera: Camera,
    leds: Leds,
    response: SensorResponse,
    dark: np.ndarray,
    led_images: np.ndarray,
    tricolor: np.ndarray,
    provenance: dict | None = None,
    reference: Reference | None = None,
    ground_truth: GroundTruth | None = None,
    overwrite: bool = False,
    design: dict | None = None,
) -> Path:
    """Write a press folder atomically and return its path.

    Parameters
    ----------
    folder : path of the press folder to create
    camera, leds, response : the capture's optics and sensor response
    dark : (H, W, 3) uint16 -- stored values (``DN << (16 - bit_depth)``) with all LEDs off
    led_images : (L, H, W, 3) uint16 -- stored values, one image per LED lit alone in white, in the order of ``leds``
    tricolor : (H, W, 3) uint16 -- stored values with the LED groups (:func:`~nlipscalib.core.leds.tricolor_groups`)
        lit in red, green and blue at once
    provenance : extra JSON-able metadata (source, scene, indenter, press, seed ...)
    design : the sensor design (``dome``, ``camera``, ``leds`` as in a scene file) that ``reference`` was computed
        from, written as meta.json's ``design``: the solver models the dome beyond the view from it
    """
    leds = tuple(leds)
    shape = camera.shape
    _check_image(dark, shape, "dark")
    _check_image(tricolor, shape, "tricolor")
    if led_images.ndim != 4 or led_images.shape[0] != len(leds):
        raise CaptureError(f"led_images must be (L={len(leds)}, H, W, 3), got {led_images.shape}")
    for i, img in enumerate(led_images):
        _check_image(img, shape, led_image_name(i))
    meta = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "software_version": __version__,
        "units": "mm",
        "frame": "camera (OpenCV: x right, y down, z forward)",
        "camera": camera.to_dict(),
        "leds": [led.to_dict() for led in leds],
        "sensor": dataclasses.asdict(response),
        "images": {
            "dark": "dark.png",
            "leds": [led_image_name(i) for i in range(len(leds))],
            "tricolor": "tricolor.png",
        },
        "reference": REFERENCE_FILE if reference is not None else None,
        "ground_truth": GT_FILE if ground_truth is not None else None,
        "provenance": provenance or {},
    }
    if design is not None:
        meta["design"] = design
    with atomic_dir(folder, overwrite=overwrite) as tmp:
        jobs = [(write_png16, tmp / "dark.png", dark), (write_png16, tmp / "tricolor.png", tricolor)]
        jobs += [(write_png16, tmp / led_image_name(i), img) for i, img in enumerate(led_images)]
        jobs += [(obj.save, tmp / name) for obj, name in ((reference, REFERENCE_FILE), (ground_truth, GT_FILE)) if obj]
        _in_threads(jobs)
        write_json(tmp / META_FILE, meta)  # last: its presence marks a complete folder
    return Path(folder)


@dataclasses.dataclass(frozen=True)
class CaptureOptics:
    """What a capture says about its sensor, read without decoding its images: enough to tell two sensors apart."""

    folder: Path
    camera: Camera
    leds: tuple[Led, ...]
    reference: Reference | None
    """The undeformed surface (reference.npz), when the capture has one (read-only arrays, as in :class:`Press`)."""


def read_optics(folder: str | Path) -> CaptureOptics:
    """The camera, LEDs and undeformed surface of a press folder (meta.json and reference.npz only).

    Why: checks that two captures come from one sensor run before a solve says anything, and decoding every
    image for them would cost as much as the solve's own loading.
    """
    folder = Path(folder)
    meta = read_meta(folder)
    camera, leds, _ = parse_optics(meta, folder / META_FILE)
    reference = _reference(folder, meta, camera, leds)
    return CaptureOptics(folder=folder, camera=camera, leds=tuple(leds), reference=reference)


def load_press(folder: str | Path, led_subset: Sequence[int] | None = None, decode: bool | str = True) -> Press:
    """Load and validate a press folder; every problem is reported naming the file.

    The tri-colour image and the ground truth (gt.npz) are loaded at their first read (a solve reads neither):
    a problem with them is reported then, naming the file.

    Parameters
    ----------
    folder : path of the press folder
    led_subset : optional sequence of 0-based LED indices to keep (for ablations)
    decode : False: the dark and LED images are read and checked to be whole PNGs of the camera's size now,
        and decoded at their first read (:class:`StoredImages`; a capture whose results may be reused under
        :meth:`Press.images_digest`, such as the undeformed dome's, is then never decoded); "background": read
        and checked now, decoded on a thread started now (:func:`decode_in_background`), so that the caller's
        next work runs beside the decoding; the first read of the images waits for it
    """
    if decode not in (True, False, "background"):
        raise ValueError(f"decode must be True, False or 'background', got {decode!r}")
    folder = Path(folder)
    meta = read_meta(folder)
    camera, leds, response = parse_optics(meta, folder / META_FILE)
    images = meta["images"]
    names = images["leds"]
    if len(names) != len(leds):
        raise CaptureError(f"{folder / META_FILE}: {len(leds)} LEDs but {len(names)} LED images listed")
    keep = range(len(leds)) if led_subset is None else _check_subset(led_subset, len(leds), folder)
    stored = _read_stored(folder, [images["dark"]] + [names[i] for i in keep], camera)
    dark = StoredImages(*stored[0], camera, stacked=False, named=decode is False)
    led_images = StoredImages(*stored[1], camera, stacked=True, named=decode is False)
    if decode == "background":
        decode_in_background(dark, led_images)
    elif decode:
        dark, led_images = decode_together(dark, led_images)
    return Press(
        folder=folder,
        camera=camera,
        leds=tuple(leds[i] for i in keep),
        response=response,
        dark=dark,
        led_images=led_images,
        tricolor=FileLoader(
            folder / images["tricolor"], functools.partial(_load_image, folder, images["tricolor"], camera)
        ),
        meta=meta,
        reference=_reference(folder, meta, camera, leds),
        ground_truth=_ground_truth_loader(folder, meta, camera, leds),
    )


def prefetch_press(folder: str | Path) -> None:
    """Start decoding the dark and LED images of the press at ``folder`` on a thread of their own, for a
    :func:`load_press` of it to come (:mod:`.prefetch`: it takes them when their bytes are the ones it reads).
    Nothing happens, and nothing is raised, when ``folder``'s meta.json does not list its images: the load reports
    what is wrong."""
    try:
        images = read_meta(folder)["images"]
        names = [images["dark"], *images["leds"]]
    except (CaptureError, KeyError, TypeError):
        return
    if all(isinstance(name, str) for name in names):
        prefetch_images([Path(folder) / name for name in names])


def _read_stored(folder: Path, names: list[str], camera: Camera) -> tuple[tuple[list, list], tuple[list, list]]:
    """((paths, bytes) of the first image, (paths, bytes) of the others) of ``names`` in ``folder``, each checked to
    be a whole PNG of the camera's size (:func:`_load_image`'s errors, before decoding)."""
    paths = [_existing(folder, name) for name in names]
    data = [read_png_bytes(path) for path in paths]
    for path, d in zip(paths, data):
        if png_size(d) != camera.shape:
            (h, w), (H, W) = png_size(d), camera.shape
            raise CaptureError(f"{path}: image is {w}x{h} pixels, but the camera in {META_FILE} is {W}x{H}")
    return (paths[:1], data[:1]), (paths[1:], data[1:])


def _ground_truth_loader(folder: Path, meta: dict, camera: Camera, leds: Leds) -> Loader:
    """The press's ground truth, loaded at its first read (:func:`_ground_truth`)."""
    load = functools.partial(_ground_truth, folder, meta, camera, leds)
    name = meta.get("ground_truth")
    return FileLoader(folder / name, load) if name and isinstance(name, str) else Loader(load)


def _ground_truth(folder: Path, meta: dict, camera: Camera, leds: Leds) -> GroundTruth | None:
    """The capture's gt.npz, checked against the format's promise; None when it has none."""
    if not meta.get("ground_truth"):
        return None
    path = _existing(folder, meta["ground_truth"])
    gt = GroundTruth.load(path, camera.shape)
    _check_surface(path, surface_problem(gt.depth, gt.normals, gt.valid.astype(bool), camera, leds))
    return gt


def _reference(folder: Path, meta: dict, camera: Camera, leds: Leds) -> Reference | None:
    """The capture's reference.npz, checked against the format's promise; None when it has none."""
    if not meta.get("reference"):
        return None
    path = _existing(folder, meta["reference"])
    return _checked_reference(path, file_stamp(path), camera, tuple(leds))


@functools.lru_cache(maxsize=4)
def _checked_reference(path: Path, stamp: tuple, camera: Camera, leds: tuple[Led, ...]) -> Reference:
    """The reference.npz at ``path``, checked, its arrays read-only: loaded once per process while the file is the
    same file, size and times (``stamp``, :func:`file_stamp`). Why: a solve with a reference reads each capture's
    file twice (the settings check's :func:`read_optics`, then :func:`load_press`), ~35 ms each at 640x480."""
    ref = Reference.load(path, camera.shape)
    _check_surface(path, surface_problem(ref.depth, ref.normals, np.isfinite(ref.depth), camera, leds))
    for array in (ref.depth, ref.normals):  # shared by every Press loaded from the file
        array.setflags(write=False)
    return ref


def file_stamp(path: str | os.PathLike) -> tuple[int, ...]:
    """What tells that a file's content may have changed without reading it, for caches of what a process read
    from a capture: device and inode (replaced by a rename), size, and modification and change times in ns
    (written in place; the change time too, as a copy that keeps the old modification time still sets it).
    FileNotFoundError when there is none. A stat: microseconds (os.stat of a str: half pathlib's cost)."""
    st = os.stat(path)
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns


def _check_surface(path: Path, problem: str | None) -> None:
    """CaptureError naming the file when ``problem`` (:func:`nlipscalib.core.surface_checks.surface_problem` of
    its depth and normals) says what is wrong with the surface it holds; nothing when ``problem`` is None."""
    if problem:
        raise CaptureError(f"{path}: {problem}")


def read_meta(folder: str | Path) -> dict:
    """Read and check the top level of a press folder's meta.json."""
    folder = Path(folder)
    path = folder / META_FILE
    if folder.exists() and not folder.is_dir():
        raise CaptureError(f"{folder}: a file, not a press folder")
    if not folder.is_dir():
        raise CaptureError(f"{folder}: not a press folder (no such directory)")
    meta = read_format_json(
        path,
        FORMAT_NAME,
        FORMAT_VERSION,
        required=("camera", "leds", "sensor", "images"),
        missing_hint=f"{folder} is not a complete press folder",
    )
    _check_file_names(meta, path)
    _check_units(meta, path)
    return meta


def image_size(folder: str | Path) -> tuple[int, int]:
    """(width, height) in pixels of a press folder's images, from its meta.json (:func:`read_meta`'s errors)."""
    camera = Camera.from_dict(read_meta(folder)["camera"])
    return camera.width, camera.height


def _check_units(meta: dict, path: Path) -> None:
    """CaptureError when meta.json declares units or a frame other than the format's (millimetres, the camera
    frame): its numbers would be read as such and solve to a wrong result without a word. Both keys are optional."""
    units = meta.get("units", "mm")
    if units != "mm":
        raise CaptureError(f"{path}: 'units' is {units!r}; captures are in millimetres ('mm'): convert the file")
    frame = meta.get("frame", "camera")
    if not (isinstance(frame, str) and frame.startswith("camera")):
        raise CaptureError(f"{path}: 'frame' is {frame!r}; captures are in the camera frame ('camera')")


def _check_file_names(meta: dict, path: Path) -> None:
    """CaptureError naming the key of meta.json whose file name is not a string (every reader joins them to the
    folder, and the capture's identity hashes them before the press is loaded: else a TypeError traceback)."""
    images = meta["images"]
    if not isinstance(images, dict):
        raise CaptureError(f"{path}: 'images' must be a mapping of image names, got {type(images).__name__}")
    for key in ("dark", "leds", "tricolor"):
        if key not in images:
            raise CaptureError(f"{path}: missing key 'images.{key}'")
    for key in ("dark", "tricolor"):
        _check_name(images[key], f"images.{key}", path)
    if not isinstance(images["leds"], list):
        raise CaptureError(f"{path}: 'images.leds' must be a list of file names, got {images['leds']!r}")
    for i, name in enumerate(images["leds"]):
        _check_name(name, f"images.leds[{i}]", path)
    for key in ("reference", "ground_truth"):  # optional files: null or absent when there is none
        if meta.get(key) is not None:
            _check_name(meta[key], key, path)


def _check_name(name: object, key: str, path: Path) -> None:
    if not isinstance(name, str) or not name:
        raise CaptureError(f"{path}: '{key}' must be a file name, got {name!r}")


def is_press_folder(folder: str | Path) -> bool:
    """True when ``folder`` holds a meta.json (complete press folders are written atomically)."""
    return (Path(folder) / META_FILE).is_file()


def find_presses(root: str | Path) -> list[Path]:
    """Press folders at ``root`` (itself a press) or directly below it, sorted by name.

    Folders below ``root`` that hold press images but no meta.json (an interrupted or partial write)
    are skipped with a warning naming each, never silently.
    """
    root = Path(root)
    if is_press_folder(root):
        return [root]
    if root.exists() and not root.is_dir():
        raise CaptureError(f"{root}: a file, not a press folder nor a folder of presses")
    if not root.is_dir():
        raise CaptureError(f"{root}: no such folder")
    presses = []
    for p in sorted(root.iterdir()):
        if not p.is_dir() or p.name.startswith(TMP_PREFIX):  # a write in progress or interrupted
            continue
        if is_press_folder(p):
            presses.append(p)
        elif is_incomplete_press(p):
            log.warning("%s: incomplete press folder (no %s; an interrupted write): skipped", p, META_FILE)
    return presses


def missing_capture_files(folder: str | Path) -> list[str]:
    """Files a press folder's meta.json lists (images, reference, ground truth) that are not there; [] for a
    whole press.

    CaptureError (naming meta.json) when meta.json itself is missing or malformed."""
    folder = Path(folder)
    return [name for name in listed_files(read_meta(folder)) if not (folder / name).is_file()]


def listed_files(meta: dict) -> list[str]:
    """The files a press folder's meta.json lists: its images (dark, tri-colour, one per LED) and, when it
    records them, its reference and ground-truth arrays (KeyError/TypeError when ``images`` is malformed)."""
    images = meta["images"]
    names = [images["dark"], images["tricolor"], *images["leds"]]
    names += [meta[key] for key in ("reference", "ground_truth") if meta.get(key)]
    return [str(name) for name in names]


def no_presses_error(root: str | Path) -> CaptureError:
    """The error for a ``root`` in which :func:`find_presses` found no press: a press folder that lacks its
    meta.json says so (not "no press folders found", which sends the user looking for the wrong thing), and so
    does a reconstruction folder."""
    if is_incomplete_press(root):
        return CaptureError(
            f"{Path(root) / META_FILE}: missing; {root} holds press images but no {META_FILE} (an interrupted "
            "write or a deleted file): capture or render it again"
        )
    from .reconstruction import RESULT_FILE

    if (Path(root) / RESULT_FILE).is_file():  # PRESS/nlips given for PRESS: "no press folders found" said no more
        return CaptureError(f"{root}: a reconstruction folder ({RESULT_FILE}), not a press: give the press folder")
    return CaptureError(f"{root}: no press folders found")


def is_incomplete_press(folder: str | Path) -> bool:
    """True when ``folder`` holds press images (dark, tri-colour or LED frames) but no meta.json."""
    folder = Path(folder)
    if is_press_folder(folder) or not folder.is_dir():
        return False
    return any((folder / name).is_file() for name in ("dark.png", "tricolor.png")) or any(folder.glob("led_*.png"))


def split_reference(root: str | Path, reference: str | Path | None = None) -> tuple[list[Path], Path | None]:
    """The presses at ``root`` (:func:`find_presses`) and the undeformed dome's capture, kept apart.

    ``reference``: the capture named by the user; None: ``root/reference`` (:data:`REFERENCE_FOLDER`) when
    ``root`` is a folder of presses that holds one. The reference is never among the presses returned, nor is
    ``root/reference`` when another ``reference`` is named: a folder's own undeformed capture is not a press.
    """
    presses = find_presses(root)
    default = Path(root) / REFERENCE_FOLDER
    if not is_press_folder(root):
        presses = [p for p in presses if p != default]
    if reference is None:
        reference = default if not is_press_folder(root) and is_press_folder(default) else None
    if reference is None:
        return presses, None
    reference = Path(reference)
    return [p for p in presses if p.resolve() != reference.resolve()], reference


# ---------------------------------------------------------------------- helpers
def _in_threads(jobs: list[tuple]) -> list:
    """Run (func, *args) jobs on a thread pool: PNG and zlib coding release the GIL, so this scales."""
    with ThreadPoolExecutor(max_workers=min(len(jobs), usable_cores()) or 1) as pool:
        return list(pool.map(lambda job: job[0](*job[1:]), jobs))


def parse_optics(meta: dict, path: Path) -> tuple[Camera, list[Led], SensorResponse]:
    """(camera, LEDs, sensor response) of a press's meta.json (``read_meta``); CaptureError naming ``path``."""
    try:
        camera = Camera.from_dict(meta["camera"])
        if not isinstance(meta["leds"], list):
            raise ValueError(f"'leds' must be a list of LEDs, got {meta['leds']!r}")
        leds = [_led(d, i) for i, d in enumerate(meta["leds"])]
        if not isinstance(meta["sensor"], dict):
            raise ValueError(f"'sensor' must be a mapping of sensor levels, got {meta['sensor']!r}")
        response = SensorResponse(**meta["sensor"])
    except (TypeError, ValueError) as exc:
        raise CaptureError(f"{path}: {exc}") from None
    if not leds:
        raise CaptureError(f"{path}: 'leds' is empty")
    return camera, leds, response


def _led(entry: object, index: int) -> Led:
    """LED ``index`` of meta.json's ``leds``; a bad value names its place (``leds[3]``) as well as its key."""
    try:
        return Led.from_dict(entry)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"leds[{index}]: {exc}") from None


def _existing(folder: Path, name: str) -> Path:
    path = folder / name
    if not path.is_file():
        raise CaptureError(f"{path}: listed in {META_FILE} but missing")
    return path


def _load_image(folder: Path, name: str, camera: Camera) -> np.ndarray:
    path = _existing(folder, name)
    return _decode_image(path, read_png_bytes(path), camera)


def _decode_image(path: Path, data: np.ndarray, camera: Camera, out: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint16 of a capture's PNG read from ``path`` (``data``: its bytes), checked against the camera;
    written into ``out`` ((H, W, 3) uint16) when given. An image decoded ahead from these same bytes
    (:mod:`.prefetch`) is taken rather than decoded again."""
    img = take_prefetched(path, data)
    if img is None:
        img = decode_png16(data, path, out=out)
    elif out is not None and out.shape == img.shape:
        out[...] = img
        img = out
    if img.shape != camera.shape + (3,):
        raise CaptureError(f"{path}: image is {img.shape}, but the camera in {META_FILE} is {camera.shape + (3,)}")
    return img


def _check_image(img: np.ndarray, shape: tuple[int, int], name: str) -> None:
    if img.dtype != np.uint16 or img.shape != tuple(shape) + (3,):
        raise CaptureError(f"{name}: expected ({shape[0]}, {shape[1]}, 3) uint16, got {img.shape} {img.dtype}")


def _check_subset(subset: Sequence[int], n: int, folder: Path) -> list[int]:
    subset = [int(i) for i in subset]
    bad = [i for i in subset if not 0 <= i < n]
    if bad or len(set(subset)) != len(subset) or not subset:
        raise CaptureError(
            f"{folder}: LED subset {subset} (0-based; LEDs {[i + 1 for i in subset]} counting from 1) "
            f"is invalid for {n} LEDs: indices must be unique, in range and at least one"
        )
    return subset


def _load_npz_kept(path: Path, keys: dict) -> dict:
    """:func:`_load_npz`, its arrays kept in the disk tier (:mod:`nlipscalib.core.diskcache`) under a digest of the
    file's bytes: the next process reading the same bytes maps them instead of inflating them.

    Why: a sensor's presses carry the same reference.npz (the undeformed surface, the same bytes in every press
    folder), and inflating its 4.3 MB took ~27 ms of one core at the start of every ``nlips solve`` (~0.16 s of the
    main thread under load, beside the press's PNG decoding on the other core); reading and hashing the file
    takes ~5 ms. The same arrays: those :func:`_load_npz` read and checked, stored as they are."""
    from . import diskcache

    entry = None
    with contextlib.suppress(OSError):  # missing or unreadable: _load_npz names the file and the problem
        content = hashlib.blake2b(path.read_bytes(), digest_size=16).hexdigest()
        entry = diskcache.entry("npz arrays", (content, sorted(keys.items())))
    if entry is not None:
        with contextlib.suppress(KeyError):  # not kept yet, or unreadable: read again and kept
            return diskcache.load(entry)
    arrays = _load_npz(path, keys)
    if entry is not None:
        diskcache.store_later(entry, arrays)
    return arrays


def _load_npz(path: Path, keys: dict) -> dict:
    arrays = read_arrays(path, keys, unreadable="not a readable .npz file")
    for k in keys:
        if arrays[k].dtype.kind not in "biuf":  # strings, objects: else numpy's "ufunc 'isfinite' not supported"
            raise CaptureError(f"{path}: array '{k}' holds {arrays[k].dtype} values, expected numbers")
        if arrays[k].dtype.kind == "f" and k != "depth" and k != "points" and not np.all(np.isfinite(arrays[k])):
            # normals are finite everywhere by convention (zero where invalid); depth/points use NaN
            raise CaptureError(f"{path}: array '{k}' contains NaN or infinity")
    return arrays
