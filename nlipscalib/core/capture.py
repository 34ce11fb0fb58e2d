"""The press capture format shared by the digital twin (sim/) and the real sensor (device/).

A press folder (see docs/formats.md)::

    press_0007/
      meta.json        camera, LEDs, sensor response, provenance
      dark.png         all LEDs off, 16-bit RGB, linear (or sRGB-encoded: meta.json sensor.camera_response)
      led_01.png ...   one image per LED lit alone in white
      tricolor.png     LED groups lit in red, green, blue at once
      reference.npz    optional: undeformed-dome depth and normals (sensor design / CAD)
      gt.npz           optional (synthetic presses): per-pixel ground truth

Writers build the folder under a temporary name and rename it when complete
(:func:`nlipscalib.core.atomic.atomic_dir`), so a press folder that exists is whole.

This module holds the press itself (:class:`Press`) and the reading and writing of its folder
(:func:`load_press`, :func:`read_optics`, :func:`write_press`). The format's other parts live beside it and every
public name of them is importable from here too: the file names and meta.json (:mod:`.press_meta`), the sensor
response (:mod:`.sensor_response`), the images decoded at their first read (:mod:`.stored_images`), the ground
truth and reference arrays (:mod:`.surface_files`) and the press folders found in a tree (:mod:`.press_folders`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import reprlib
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from .. import __version__
from .atomic import atomic_dir, write_json
from .camera import Camera
from .errors import PATH, CaptureError, ConfigError, ShapeError, check_kind
from .imageio import png_size, read_png_bytes, write_png16
from .leds import Led, Leds
from .prefetch import prefetch_images
from .press_checksums import write_checksums
from .press_folders import (
    find_presses,
    is_incomplete_press,
    is_press_folder,
    missing_capture_files,
    no_presses_error,
    split_reference,
)
from .press_meta import (
    FORMAT_NAME,
    FORMAT_VERSION,
    GT_FILE,
    META_FILE,
    REFERENCE_FILE,
    REFERENCE_FOLDER,
    existing_file,
    image_size,
    led_frame_name,
    led_image_name,
    listed_files,
    parse_optics,
    read_meta,
)
from .response_curve import per_channel
from .sensor_response import CLIPPED_VALUE, LEAST_BIT_DEPTH, SensorResponse, linearise, white_level_of
from .stored_images import (
    FileLoader,
    LoadedOnRead,
    Loader,
    StoredImages,
    decode_in_background,
    decode_together,
    file_stamp,
    in_threads,
    load_image,
)
from .surface_files import GT_KEYS, GroundTruth, Reference, ground_truth_loader, read_reference

# every public name of the format, the re-exported ones with those defined here
__all__ = [
    "as_press",
    "CLIPPED_VALUE",
    "CaptureOptics",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "FileLoader",
    "GT_FILE",
    "GT_KEYS",
    "GroundTruth",
    "LEAST_BIT_DEPTH",
    "Loader",
    "META_FILE",
    "Press",
    "REFERENCE_FILE",
    "REFERENCE_FOLDER",
    "Reference",
    "SensorResponse",
    "StoredImages",
    "decode_in_background",
    "decode_together",
    "file_stamp",
    "find_presses",
    "image_size",
    "is_incomplete_press",
    "is_press_folder",
    "led_frame_name",
    "led_image_name",
    "linearise",
    "listed_files",
    "load_press",
    "missing_capture_files",
    "no_presses_error",
    "parse_optics",
    "prefetch_press",
    "read_meta",
    "read_optics",
    "select_leds",
    "with_led_gains",
    "with_unusable_samples",
    "unusable_digest",
    "split_reference",
    "white_level_of",
    "write_press",
]


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
    """How the stored values relate to light: bit depth, black and white levels, tone curve (meta.json
    ``sensor``)."""
    dark: np.ndarray = LoadedOnRead()
    """(H, W, 3) uint16, stored values, RGB, linear in the light (a camera's tone curve undone by :func:`load_press`;
    may be given as a :class:`Loader`: loaded at the first read)."""
    led_images: np.ndarray = LoadedOnRead()
    """(L, H, W, 3) uint16, stored values, RGB, one per LED lit alone in white (may be given deferred)."""
    tricolor: np.ndarray = LoadedOnRead()
    """(H, W, 3) uint16, stored values, RGB (may be given deferred: a solve does not read it)."""
    meta: dict
    """The whole meta.json (provenance: scene, indenter, press pose, seed, software version)."""
    reference: Reference | None = None
    """The undeformed surface (reference.npz), or None when the folder has none; its arrays are read-only (one
    load per process is shared by every press loaded from the file)."""
    ground_truth: GroundTruth | None = LoadedOnRead(None)
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
        check_kind(image, (np.ndarray, list, tuple), "image", "an (..., H, W, 3) array of stored values")
        return linearise(image, self.dark[tuple(window)], self.response.black_level, self.response.white_level)

    @functools.cached_property
    def linear_led_images(self) -> np.ndarray:
        """(L, H, W, 3) float32, read-only -- :meth:`linear` of ``led_images``, computed once per press
        (a solve reads it in the contact classification, the indirect fit and the solve itself).

        One LED per thread (:func:`in_threads`; each element's own arithmetic, so the same numbers): at 640x480
        with 12 LEDs the conversion, most of it the first touch of the 44 MB result's pages, took ~17-30 ms of one
        core at the start of every solve while the other waited."""
        images = self.led_images
        lin = np.empty(images.shape, np.float32)
        black, white = self.response.black_level, self.response.white_level
        in_threads([(linearise, images[i], self.dark, black, white, lin[i]) for i in range(len(images))])
        lin.setflags(write=False)
        return lin

    @functools.cached_property
    def saturated_led_images(self) -> np.ndarray:
        """(L, H, W, 3) bool, read-only -- :meth:`saturated` of ``led_images``, computed once per press (a solve
        reads it in the contact classification, the indirect fit of a press on itself and the solve itself:
        ~4 ms each at 640x480 with 12 LEDs, two of them on two threads at once). The samples a solve leaves out
        per LED: :func:`with_unusable_samples` adds others (an LED image's rows read while its LED was off)."""
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


def _format_version(response: SensorResponse) -> int:
    """meta.json's format_version: the oldest that holds the response, so every reader that can read a capture
    reads it and one that cannot refuses it rather than read encoded values as light: 1 for a linear camera (as
    before the tone curves), 2 for one curve for all channels, 3 for a measured curve per channel."""
    if response.camera_response == "linear":
        return 1
    return FORMAT_VERSION if response.response_curve is not None and per_channel(response.response_curve) else 2


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
    sensor = dataclasses.asdict(response)
    if response.camera_response == "linear":  # written as before it existed: every reader reads it alike
        del sensor["camera_response"]
    if response.response_curve is None:  # a measured curve's table only: "srgb" captures written as before
        del sensor["response_curve"]
    meta = {
        "format": FORMAT_NAME,
        "format_version": _format_version(response),
        "software_version": __version__,
        "units": "mm",
        "frame": "camera (OpenCV: x right, y down, z forward)",
        "camera": camera.to_dict(),
        "leds": [led.to_dict() for led in leds],
        "sensor": sensor,
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
        in_threads(jobs)
        # before meta.json, inside the folder's atomic write: a published press always has its record
        write_checksums(tmp, listed_files(meta))
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
    reference = read_reference(folder, meta, camera, leds)
    return CaptureOptics(folder=folder, camera=camera, leds=tuple(leds), reference=reference)


def as_press(press: Press | str | os.PathLike, name: str = "press") -> Press:
    """``press`` itself, or the press folder it names loaded with :func:`load_press` (all its LEDs).

    Why: the library's functions that take a capture take its folder's path too (str or Path), as a script or
    notebook has it; anything else is one ShapeError naming the argument (``name``), not an AttributeError deep in
    the computation."""
    if isinstance(press, Press):
        return press
    if isinstance(press, (str, os.PathLike)):
        return load_press(press)
    raise ShapeError(
        f"{name} must be a Press (load_press(folder)) or a press folder's path, got {type(press).__name__}"
    )


def select_leds(press: Press, keep: Sequence[int]) -> Press:
    """``press`` with only the LEDs ``keep`` (0-based, in order), as ``load_press(folder, led_subset=keep)`` would
    load it, without reading anything again: the kept LED images are a copy, the other fields ``press``'s own (a
    field not read yet stays deferred). Why: a solve leaves out an LED whose image does not fit its model (a weak
    LED, :mod:`nlipscalib.solver.led_checks`) after the capture is loaded."""
    keep = [int(i) for i in keep]
    fields = {field.name: press.__dict__[field.name] for field in dataclasses.fields(press)}
    fields.update(leds=tuple(press.leds[i] for i in keep), led_images=press.led_images[keep])
    return Press(**fields)


UNUSABLE_DIGEST = "unusable_samples_digest"
"""Where :func:`with_unusable_samples` leaves a digest of its copy's unusable samples (the instance's ``__dict__``;
:func:`unusable_digest` reads it)."""


def unusable_digest(press: Press) -> str | None:
    """The digest of the samples :func:`with_unusable_samples` marked in ``press`` (with the saturated ones), or None
    for a press as loaded: a key of what is computed from those samples adds it (an undeformed capture's indirect
    fit, kept under its images' digest, must not serve the copy)."""
    return press.__dict__.get(UNUSABLE_DIGEST)


def with_unusable_samples(press: Press, unusable: np.ndarray) -> Press:
    """``press`` whose :attr:`Press.saturated_led_images` also marks the samples ``unusable``: what a solve leaves
    out per LED, pixel and channel (its data term, its contact map, the interreflection term fitted on it) is
    what that mask says, whatever the cause.

    Why: an LED image with a band of rows read while its LED was off (:mod:`nlipscalib.core.repeated_frames`)
    holds no light of that LED there, and its light everywhere else; the solve's own exclusion of saturated
    samples leaves out just those samples, with no new path through the solver.

    Parameters
    ----------
    press : Press
    unusable : (L, H, W) bool -- per LED image and pixel (every channel).

    Returns
    -------
    Press -- a copy, its other fields ``press``'s own; its saturated samples (``saturated_led_images``) are
    ``press``'s or ``unusable``.
    """
    fields = {field.name: press.__dict__[field.name] for field in dataclasses.fields(press)}
    masked = Press(**fields)
    samples = press.saturated_led_images | np.asarray(unusable, bool)[..., None]
    samples.setflags(write=False)
    masked.__dict__["saturated_led_images"] = samples  # the cached property's slot: read as computed
    from .diskcache import digest

    # what names the copy apart from ``press`` where a result computed from its samples is kept (an indirect fit)
    masked.__dict__[UNUSABLE_DIGEST] = digest(np.packbits(samples))
    if "linear_led_images" in press.__dict__:  # computed already: the same images
        masked.__dict__["linear_led_images"] = press.__dict__["linear_led_images"]
    return masked


def with_led_gains(press: Press, gains: np.ndarray) -> Press:
    """``press`` as captured with each LED at its modelled power: LED ``k``'s image divided by ``gains[k]`` above
    the dark frame, per channel (stored values rounded; a saturated value kept, so it stays saturated).

    Why: an LED at a fraction g of the power it had at the undeformed capture scales its image by g; dividing the
    image by g is the model with that LED's Psi and its fitted indirect light times g (the solve's least squares
    then weigh that LED's residual by 1 / g, a few per cent), without fitting the undeformed capture's indirect
    term or its shading again (:func:`nlipscalib.solver.led_checks.led_gains`).

    Parameters
    ----------
    press : Press
    gains : (L, 3) float -- each LED's brightness over its modelled one, per channel (R, G, B), > 0.

    Returns
    -------
    Press -- a copy whose ``led_images`` (new uint16 array) are rescaled; the other fields ``press``'s own.
    """
    gains = np.asarray(gains, np.float64)
    dark = press.dark.astype(np.float32)
    stored = press.led_images
    images = np.empty_like(stored)
    for k in range(len(stored)):
        lit = stored[k].astype(np.float32) - dark
        scaled = np.clip(np.rint(dark + lit / gains[k].astype(np.float32)), 0, 65535)
        images[k] = np.where(press.response.saturated(stored[k]), stored[k], scaled.astype(np.uint16))
    fields = {field.name: press.__dict__[field.name] for field in dataclasses.fields(press)}
    fields.update(led_images=images)
    return Press(**fields)


def read_ground_truth(folder: str | Path) -> GroundTruth | None:
    """A press folder's ground truth (gt.npz, checked as :func:`load_press` checks it), or None when it has none,
    without reading its images: what a figure of another method's result (``nlips infer``'s) scores it against."""
    folder = Path(folder)
    meta = read_meta(folder)
    camera, leds, _ = parse_optics(meta, folder / META_FILE)
    return ground_truth_loader(folder, meta, camera, leds).load()


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
    check_kind(folder, PATH, "folder", "a press folder's path (str or Path)")
    if not any(decode is mode for mode in (True, False)) and decode != "background":
        raise ConfigError(f"decode must be True, False or 'background', got {decode!r}")
    subset = None if led_subset is None else _subset_indices(led_subset)  # its kind before any file is read
    folder = Path(folder)
    meta = read_meta(folder)
    camera, leds, response = parse_optics(meta, folder / META_FILE)
    images = meta["images"]
    names = images["leds"]
    if len(names) != len(leds):
        raise CaptureError(f"{folder / META_FILE}: {len(leds)} LEDs but {len(names)} LED images listed")
    keep = range(len(leds)) if subset is None else _check_subset(subset, len(leds), folder)
    stored = _read_stored(folder, [images["dark"]] + [names[i] for i in keep], camera)
    curve = response.tone_curve()  # undone at decoding, before anything subtracts the dark frame
    dark = StoredImages(*stored[0], camera, stacked=False, named=decode is False, tone_curve=curve)
    led_images = StoredImages(*stored[1], camera, stacked=True, named=decode is False, tone_curve=curve)
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
            folder / images["tricolor"], functools.partial(load_image, folder, images["tricolor"], camera, curve)
        ),
        meta=meta,
        reference=read_reference(folder, meta, camera, leds),
        ground_truth=ground_truth_loader(folder, meta, camera, leds),
    )


def prefetch_press(folder: str | Path) -> None:
    """Start decoding the dark, LED and tri-colour images of the press at ``folder`` on a thread of their own, in
    that order, for a :func:`load_press` of it to come (:mod:`.prefetch`: it takes them when their bytes are the ones
    it reads), and reading its reference.npz on another (:func:`_reference_ahead`). Nothing happens, and nothing is
    raised, when ``folder``'s meta.json does not list its images: the load reports what is wrong.

    The tri-colour image last: a solve reads it for its check against the LED images (:mod:`.tricolor_check`) after
    the LED images' wait, and decoded there it took ~5-8 ms of the main thread while the other core idled
    (benchmarks/RESULTS.md, s42-speed)."""
    try:
        meta = read_meta(folder)
        images = meta["images"]
        names = [images["dark"], *images["leds"], images["tricolor"]]
    except (CaptureError, KeyError, TypeError):
        return
    if all(isinstance(name, str) for name in names):
        prefetch_images([Path(folder) / name for name in names])
        _reference_ahead(Path(folder), meta)


def _reference_ahead(folder: Path, meta: dict) -> None:
    """Read and check the press's reference.npz (:func:`read_reference`, kept per file) on a daemon thread; a
    problem is left to :func:`load_press`, which reads it again and names it.

    Why: ``nlips solve`` read it on the main thread just after the solver's import, while the second core had
    nothing left to do: its content hash, the disk cache's mapping and the surface check, ~25-30 ms idle on the
    2-core VM (benchmarks/RESULTS.md, s31-cube). Here it runs beside the import (GIL-bound) and the decoding;
    hashing and NumPy's loops release the GIL."""

    def run() -> None:
        with contextlib.suppress(Exception):  # the load reads it again and reports what is wrong, naming the file
            camera, leds, _ = parse_optics(meta, folder / META_FILE)
            read_reference(folder, meta, camera, leds)

    threading.Thread(target=run, name="prefetch-reference", daemon=True).start()


def _read_stored(folder: Path, names: list[str], camera: Camera) -> tuple[tuple[list, list], tuple[list, list]]:
    """((paths, bytes) of the first image, (paths, bytes) of the others) of ``names`` in ``folder``, each checked to
    be a whole PNG of the camera's size (:func:`load_image`'s errors, before decoding)."""
    paths = [existing_file(folder, name) for name in names]
    data = [read_png_bytes(path) for path in paths]
    for path, d in zip(paths, data):
        if png_size(d) != camera.shape:
            (h, w), (H, W) = png_size(d), camera.shape
            raise CaptureError(f"{path}: image is {w}x{h} pixels, but the camera in {META_FILE} is {W}x{H}")
    return (paths[:1], data[:1]), (paths[1:], data[1:])


def _check_image(img: np.ndarray, shape: tuple[int, int], name: str) -> None:
    if img.dtype != np.uint16 or img.shape != tuple(shape) + (3,):
        raise CaptureError(f"{name}: expected ({shape[0]}, {shape[1]}, 3) uint16, got {img.shape} {img.dtype}")


def _subset_indices(led_subset: object) -> list[int]:
    """``load_press``'s ``led_subset`` as a list of ints; ShapeError naming the argument, as the API's kind checks
    (``core.errors.check_kind``) do, unless it is a sequence of whole numbers (a string gave "invalid literal for
    int()", and 1.5 was taken for LED index 1 without a word)."""
    given = list(led_subset) if not isinstance(led_subset, (str, bytes)) and np.iterable(led_subset) else None
    if given is None or not all(isinstance(i, (int, np.integer)) and not isinstance(i, bool) for i in given):
        raise ShapeError(
            f"led_subset must be a sequence of LED indices (0-based integers), got {type(led_subset).__name__} "
            f"{reprlib.repr(led_subset)}"
        )
    return [int(i) for i in given]


def subset_problem(subset: Sequence[int], n: int) -> str | None:
    """What is wrong with the 0-based LED indices ``subset`` of a capture of ``n`` LEDs, in words counting the LEDs
    from 1 as the user typed them ("LED 13 out of range 1..12", "LED 1 named twice", "no LED"); None when nothing.
    Why: "indices must be unique" named no LED (s34-walk)."""
    bad = [i for i in subset if not 0 <= i < n]
    twice = sorted({i + 1 for i in subset if list(subset).count(i) > 1})
    if not subset:
        return "no LED"
    if bad:
        return f"LED {', '.join(str(i + 1) for i in bad)} out of range 1..{n}"
    return f"LED {', '.join(map(str, twice))} named twice" if twice else None


def _check_subset(subset: list[int], n: int, folder: Path) -> list[int]:
    """``subset`` unless :func:`subset_problem` finds one: CaptureError naming the folder and the argument."""
    if why := subset_problem(subset, n):
        raise CaptureError(
            f"{folder}: led_subset={subset} (0-based; LEDs {[i + 1 for i in subset]} counting from 1) "
            f"is invalid for its {n} LEDs: {why}"
        )
    return subset
