"""The reconstruction format: what NLiPs (and later NLiPsNet) writes and what training and scoring read.

A reconstruction folder (``PRESS/nlips/`` from NLiPs, ``PRESS/nlipsnet/`` from NLiPsNet; see
docs/formats.md)::

    nlips/
      result.npz     the maps below, on the result's box (format_version 2; version 1: the full image grid)
      report.json    format, format_version, software_version, method, and what made it
                     (provenance: settings and input identities, their hash; timings; exclusions)
      *.png          optional figures (nlipscalib.report), never read back

Written atomically (the folder appears complete or not at all); :func:`load_reconstruction`
validates format, version, keys, box, shapes and dtypes, names the file and the problem, and pastes the box
back into full-frame maps, so every reader sees what a version 1 file (full-frame maps) gave it.
"""

from __future__ import annotations

import dataclasses
import json
import numbers
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import __version__
from .atomic import atomic_dir, write_json
from .errors import PATH, CaptureError, check_kind
from .formatfile import read_arrays, read_format_json
from .imageio import save_npz
from .surface_checks import non_unit_count

FORMAT_NAME = "nlipscalib.reconstruction"
FORMAT_VERSION = 2
"""Version 2 stores the maps on the result's box (:func:`result_box`); version 1 over the full image."""
READ_VERSIONS = (1, FORMAT_VERSION)
"""The versions :func:`load_reconstruction` reads (version 1 files are pasted as they are: full-frame maps)."""
RESULT_DIR = "nlips"
METHODS = ("nlips", "nlipsnet", "lut")
"""Reconstruction methods; each writes PRESS/<method>/ in this format (``lut``: `nlips infer` of a lookup table's
model file, ``nlips lut``)."""
METHOD_NAMES = {"nlips": "NLiPs", "nlipsnet": "NLiPsNet", "lut": "lookup-table"}
"""Each method as a user reads it."""
MADE_BY = {"nlips": "nlips solve", "nlipsnet": "nlips infer", "lut": "nlips infer"}
"""The command that makes each method's results."""
RESULT_FILE = "result.npz"
REPORT_FILE = "report.json"

# name: (number of dims, trailing 3?, dtype kind)
ARRAYS = {
    "depth": (2, "f"),
    "points": (3, "f"),
    "normals": (3, "f"),
    "albedo": (3, "f"),
    "residual": (2, "f"),
    "confidence": (2, "f"),
    "usable_leds": (2, "i"),
    "mask": (2, "b"),
    "reconstructed": (2, "b"),
}
FILL = {"confidence": 0.0, "usable_leds": 0, "mask": False, "reconstructed": False}
"""What a map holds outside the solved pixels, and so outside a version 2 file's box; NaN for the maps not listed."""
BOX_ARRAYS = ("box", "frame")
"""Version 2's extra arrays: ``box`` (4,) int64 [x0, y0, w, h] pixels, ``frame`` (2,) int64 [H, W] of the image."""


@dataclasses.dataclass(frozen=True)
class Reconstruction:
    """Depth and normals of one press; every map is (H, W[, 3]) over the full image, NaN where not reconstructed."""

    depth: np.ndarray
    """(H, W) float32, mm -- z in the camera frame."""
    points: np.ndarray
    """(H, W, 3) float32, mm, camera frame."""
    normals: np.ndarray
    """(H, W, 3) float32, unit, camera frame, toward the camera."""
    albedo: np.ndarray
    """(H, W, 3) float32 -- rho_c in linear image units per unit Psi (relative)."""
    residual: np.ndarray
    """(H, W) float32 -- RMS of the model-minus-image residual over usable LEDs/channels, linear units."""
    confidence: np.ndarray
    """(H, W) float32 in [0, 1] -- usable fraction of LED images times mean robust weight; 0 if not solved."""
    usable_leds: np.ndarray
    """(H, W) int16 -- LEDs with at least one usable (lit, unsaturated, alive) channel at the pixel."""
    mask: np.ndarray
    """(H, W) bool -- pixels that were unknowns of the solve."""
    reconstructed: np.ndarray
    """(H, W) bool -- mask and enough usable LEDs and a valid gradient: the maps are defined here."""
    report: dict
    """What made it and what happened: exclusions (dead LEDs, dead/saturated/shadowed/too-few pixels),
    per-level iterations, energy, times, options and inputs."""

    def arrays(self) -> dict:
        """The maps by name (everything but the report)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "report"}

    @property
    def shape(self) -> tuple[int, int]:
        return tuple(self.depth.shape)


def provenance_key(settings: dict, inputs: dict, libraries: dict) -> str:
    """The key of a result's provenance (its report's ``provenance.key``): SHA-256 (hex) of the settings that decide
    it, the identities of its inputs, the software version, the code's fingerprint
    (:func:`~nlipscalib.core.code_version.code_fingerprint`: the version is the same in every commit) and the
    versions of the ``libraries`` that shape it (:func:`~nlipscalib.core.libraries.library_versions`: a release
    moves numbers), as sorted JSON. A kept result whose key equals a new request's is reused (``nlips solve``,
    ``nlips infer``); one formula for both, so their records read alike."""
    import hashlib
    import json

    from .code_version import code_fingerprint

    source = {
        "settings": settings,
        "inputs": inputs,
        "software_version": __version__,
        "code": code_fingerprint(),
        "libraries": libraries,
    }
    return hashlib.sha256(json.dumps(source, sort_keys=True).encode()).hexdigest()


def reconstruction_dir(press_folder: str | Path, out: str | Path | None = None, method: str = RESULT_DIR) -> Path:
    """Where the reconstruction of ``press_folder`` lives (``out`` when given, else PRESS/<method>).

    CaptureError when PRESS/<method> (not given by the user) is a symbolic link to a place outside the press folder.
    Why: a press folder from elsewhere (an archive, a colleague's disk) may carry such a link, and a solve, written
    where the link points, replaced the reconstruction of another press there (docs/formats.md, "Files from
    others"); a folder the user names (``out``) is written where it points, as the user asked."""
    if method not in METHODS:
        raise CaptureError(f"unknown reconstruction method {method!r}; expected one of {METHODS}")
    if out is not None:
        return Path(out)
    folder = Path(press_folder) / method
    if folder.is_symlink() and not folder.resolve().is_relative_to(Path(press_folder).resolve()):
        raise CaptureError(
            f"{folder}: a symbolic link to {folder.resolve()}, outside the press folder (a press folder from elsewhere "
            "may carry one); remove the link, or name the reconstruction's folder on the command line (--out)"
        )
    return folder


def has_reconstruction(folder: str | Path) -> bool:
    """True when ``folder`` holds a (complete, atomically written) reconstruction."""
    return (Path(folder) / RESULT_FILE).is_file()


def is_reconstruction_dir(folder: str | Path) -> bool:
    """True when ``folder`` itself looks like a reconstruction folder (result.npz and report.json)."""
    folder = Path(folder)
    return (folder / RESULT_FILE).is_file() and (folder / REPORT_FILE).is_file()


def replace_problem(folder: str | Path, method: str | None = None) -> str | None:
    """Why writing a reconstruction into ``folder`` would destroy something else, or None when it may.

    A reconstruction is published by replacing the whole folder (core.atomic), so ``folder`` must be
    absent, an empty folder, or a reconstruction folder -- even a damaged one: result.npz or report.json
    among files alone. A file, a press folder, a folder of presses or any other folder is not one
    (``nlips solve PRESS --out DATASET`` would otherwise replace the dataset with one result). With ``method``
    (:data:`METHODS`: what is to be written), a result its report.json records as another method's is not one
    either (``nlips solve PRESS --out PRESS/nlipsnet`` replaced the press's NLiPsNet result, exit 0).
    """
    folder = Path(folder)
    if not folder.exists() and not folder.is_symlink():
        return None
    if not folder.is_dir():
        return f"{folder}: exists and is not a folder (a file or a broken link), not a reconstruction folder"
    entries = sorted(folder.iterdir())
    if not entries:
        return None
    names = {e.name for e in entries}
    listed = ", ".join(e.name for e in entries[:3]) + (f" and {len(entries) - 3} more" if len(entries) > 3 else "")
    if "meta.json" in names:
        return f"{folder}: is a press folder, not a reconstruction folder"
    if not names & {RESULT_FILE, REPORT_FILE} or any(e.is_dir() for e in entries):
        return f"{folder}: exists and holds other things than a reconstruction ({listed})"
    other = _recorded_method(folder / REPORT_FILE) if method is not None else None
    if other is not None and other != method:
        made = f"{'a' if other == 'lut' else 'an'} {METHOD_NAMES[other]} result (`{MADE_BY[other]}`)"
        return f"{folder}: holds {made}, which this {METHOD_NAMES[method]} result would replace"
    return None


def _recorded_method(report: Path) -> str | None:
    """The method (:data:`METHODS`) a report.json records; None when it cannot be read or names none."""
    try:
        method = json.loads(report.read_text(encoding="utf-8")).get("method")
    except (OSError, ValueError, AttributeError):
        return None
    return method if method in METHODS else None


def check_replaceable(
    folder: str | Path, remedy: str = "move it away or choose another --out", method: str | None = None
) -> None:
    """Raise CaptureError (:func:`replace_problem`, with ``remedy``) unless a reconstruction (of ``method``, when
    given) may be written into ``folder``."""
    problem = replace_problem(folder, method)
    if problem is not None:
        raise CaptureError(f"{problem}; {remedy}")


def read_report(folder: str | Path) -> dict:
    """The validated report.json of a reconstruction folder (format and version checked), without the maps."""
    return _read_report(Path(folder) / REPORT_FILE)


def reconstruction_problem(folder: str | Path, verify: bool = False) -> str | None:
    """Why the reconstruction in ``folder`` cannot be used, or None when it looks whole.

    Cheap (no array is decompressed): report.json is validated, and result.npz's zip directory -- the
    last bytes of the file, so a truncated file loses it -- must list every array. ``verify`` also
    reads every array and checks it against its checksum (~25 ms for a whole 640x480 frame): damage
    inside the file (a bad disk block, a partial overwrite) then shows too, for a caller that reuses a
    result without loading it (:func:`load_reconstruction` checks the same when it reads the arrays).
    """
    import zlib

    folder = Path(folder)
    path = folder / RESULT_FILE
    if not path.is_file():
        return f"{path}: missing"
    try:
        version = read_report(folder)["format_version"]
        with zipfile.ZipFile(path) as zf:
            names = {n.removesuffix(".npy") for n in zf.namelist()}
            bad = _damaged_member(zf) if verify else None
    except CaptureError as exc:
        return str(exc)
    except (OSError, zipfile.BadZipFile, EOFError, ValueError, zlib.error) as exc:
        return f"{path}: damaged or truncated reconstruction ({exc})"
    if bad is not None:
        return f"{path}: damaged reconstruction (array {bad[0].removesuffix('.npy')!r}: {bad[1]})"
    missing = sorted(set(_stored_arrays(version)) - names)
    if missing:
        return f"{path}: missing arrays {missing}"
    return _verified_content(path, version) if verify else None


def _stored_arrays(version: int) -> tuple[str, ...]:
    """The arrays a result.npz of format ``version`` holds."""
    return tuple(ARRAYS) + (BOX_ARRAYS if version >= 2 else ())


def _verified_content(path: Path, version: int) -> str | None:
    """Box, shapes and :func:`content_problem` of the result.npz at ``path`` (its members already checked to
    inflate), reading only the arrays they need."""
    names = ("depth", "normals", "reconstructed") + (BOX_ARRAYS if version >= 2 else ())
    try:
        with open(path, "rb") as f, np.load(f) as npz:  # not np.load(path): see core.imageio._open_npz
            arrays = {name: npz[name] for name in names}
        _box_checked(path, arrays, version)
    except CaptureError as exc:
        return str(exc)
    except (ValueError, OSError, KeyError) as exc:  # object arrays (pickled), a hand-made file
        return f"{path}: damaged or foreign reconstruction ({exc})"
    problem = content_problem(arrays)
    return f"{path}: {problem}" if problem else None


def _damaged_member(zf: zipfile.ZipFile) -> tuple[str, str] | None:
    """(name, problem) of the first member whose data does not inflate or match its CRC, or None."""
    import zlib

    for info in zf.infolist():
        try:
            with zf.open(info) as f:
                while f.read(1 << 20):
                    pass
        except zipfile.BadZipFile as exc:
            return info.filename, str(exc)
        except zlib.error as exc:
            return info.filename, f"compressed data damaged: {exc}"
    return None


def save_reconstruction(
    rec: Reconstruction,
    folder: str | Path,
    overwrite: bool = False,
    extra_files: Callable[[Path], object] | None = None,
) -> Path:
    """Write ``rec`` atomically into ``folder``.

    Parameters
    ----------
    rec : Reconstruction
    folder : output folder (created; replaced when ``overwrite``). CaptureError when something else than
        a reconstruction is there (:func:`replace_problem`): it is never replaced.
    extra_files : optional callable ``f(tmp_folder)`` that adds files (figures) before the folder is
        moved into place, so they appear together with the result or not at all. It runs on a thread of its
        own while the arrays are written (it must not write result.npz or report.json).

    Returns the folder; raises FileExistsError (an OSError naming it) when it is there and not ``overwrite``.
    """
    from concurrent.futures import ThreadPoolExecutor

    check_kind(rec, Reconstruction, "rec", "a Reconstruction (a solve's result, load_reconstruction)")
    check_kind(folder, PATH, "folder", "the output folder's path (str or Path)")
    check_kind(overwrite, bool, "overwrite", "True or False")  # "no" would have been taken as True
    folder = Path(folder)
    # "." has no name to write beside; any other folder stays as given, so that an error names it as the user did
    # (an absolute path named `--out bad/../ro/inf` "/home/.../bad/../ro/inf")
    folder = folder if folder.name else folder.absolute()
    check_replaceable(folder)
    # the pool is left (its thread joined) before the folder is published or, on an error, removed
    with atomic_dir(folder, overwrite=overwrite) as tmp, ThreadPoolExecutor(1, "save-extra") as pool:
        # beside the arrays' writing: both it and the figures' PNG encoding (and the ground truth's inflating
        # for error.png) release the GIL, so the two take one wall instead of two (an auto-ROI 640x480 result:
        # ~0.01 s of writing its box, ~0.1 s of figures and ground truth)
        extra = pool.submit(extra_files, tmp) if extra_files is not None else None
        # on the box, not the frame: an ROI's maps are then dense, stored (10x faster than deflated), not deflated
        # NaN around them (cube1's auto ROI: 0.13 s -> 0.01 s of the main thread, benchmarks/RESULTS.md s20-crop)
        save_npz(tmp / RESULT_FILE, boxed_arrays(rec), compress="auto")
        head = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "software_version": __version__}
        # the header last too: a loaded result's report carries the version of the file it was read from
        write_json(tmp / REPORT_FILE, head | jsonable(rec.report) | head)
        if extra is not None:
            extra.result()  # its error, if any, is the save's
    return folder


def load_reconstruction(folder: str | Path, shape: tuple[int, int] | None = None) -> Reconstruction:
    """Load and validate a reconstruction folder.

    Parameters
    ----------
    folder : the reconstruction folder (e.g. PRESS/nlips)
    shape : (H, W) the image it must match (the press's camera), or None

    Raises
    ------
    CaptureError naming the file: missing, unreadable or truncated, wrong format or version, missing
    arrays, wrong shapes or dtypes.
    """
    check_kind(folder, PATH, "folder", "a reconstruction folder's path (str or Path)")
    pair = isinstance(shape, (tuple, list)) and len(shape) == 2
    if shape is not None and not (
        pair and all(isinstance(n, numbers.Integral) and not isinstance(n, bool) for n in shape)
    ):
        # "64x48" was compared with the arrays' shape and reported as a damaged result (s38-apikinds)
        check_kind(shape, (), "shape", "(H, W) pixels (press.camera.shape), or None")
    folder = Path(folder)
    path, rpath = folder / RESULT_FILE, folder / REPORT_FILE
    if not path.is_file():
        raise CaptureError(f"{path}: no reconstruction there (run `nlips solve` first)")
    report = _read_report(rpath)
    version = report["format_version"]
    # the format's arrays only: another member (a gigabyte of zeros in a result from elsewhere) is never inflated
    stored = _stored_arrays(version)
    arrays = read_arrays(path, stored, unreadable="damaged or truncated reconstruction", only=stored)
    box, frame = _box_checked(path, arrays, version, shape)
    if problem := content_problem(arrays):  # on the box: nothing outside it is reconstructed
        raise CaptureError(f"{path}: {problem}")
    if version >= 2 and box != (0, 0, frame[1], frame[0]):  # a whole-frame box is read as it is: no copy
        arrays = {name: pasted(arrays[name], box, frame, FILL.get(name, np.nan)) for name in ARRAYS}
    return Reconstruction(**{k: arrays[k] for k in ARRAYS}, report=report)


def result_box(arrays: dict) -> tuple[int, int, int, int]:
    """Where a result says anything: what a version 2 result.npz stores.

    Parameters
    ----------
    arrays : the full-frame maps by name (:meth:`Reconstruction.arrays`), each (H, W[, 3])

    Returns
    -------
    (x0, y0, w, h) pixels, image frame: the bounding box of ``mask`` (the ROI on the gel, or the whole gel),
    widened over any pixel where another map is not its fill (:data:`FILL`), compared bit for bit -- so that pasting
    the box back into filled maps gives the same bytes, even for a NaN of another sign; (0, 0, 0, 0) when
    nothing is.
    """
    H, W = np.shape(arrays["mask"])
    rows, cols = np.zeros(H, bool), np.zeros(W, bool)
    for name, a in arrays.items():
        # each map's rows and columns, not a union of maps: ~10x faster (no (H, W, 3) reduction over channels)
        said = _not_fill(a, FILL.get(name, np.nan))
        rows |= said.reshape(H, -1).any(axis=1)
        in_cols = said.any(axis=0)
        cols |= in_cols.any(axis=1) if in_cols.ndim == 2 else in_cols
    rows, cols = np.flatnonzero(rows), np.flatnonzero(cols)
    if rows.size == 0:
        return (0, 0, 0, 0)
    return (int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1))


def _not_fill(a: np.ndarray, fill: float) -> np.ndarray:
    """(H, W[, 3]) bool: where ``a`` ((H, W[, 3])) differs from ``fill`` in its bits (a NaN of another sign
    or payload differs from NaN; a mask's True from False)."""
    a = np.asarray(a)
    bits = np.dtype(f"u{a.dtype.itemsize}")
    return a.view(bits) != np.array(fill, a.dtype).view(bits)


def boxed_arrays(rec: Reconstruction) -> dict:
    """What a version 2 result.npz holds: every map cut to :func:`result_box` (views, no copy), with ``box``
    ((4,) int64 [x0, y0, w, h]) and ``frame`` ((2,) int64 [H, W], the full image)."""
    arrays = rec.arrays()
    x0, y0, w, h = box = result_box(arrays)
    cut = {name: a[y0 : y0 + h, x0 : x0 + w] for name, a in arrays.items()}
    return cut | {"box": np.array(box, np.int64), "frame": np.array(rec.shape, np.int64)}


def pasted(a: np.ndarray, box: tuple[int, int, int, int], frame: tuple[int, int], fill: float) -> np.ndarray:
    """``a`` ((h, w[, 3]), a map on ``box`` [x0, y0, w, h]) in a (H, W[, 3]) ``frame`` of ``fill``, same dtype."""
    x0, y0, w, h = box
    full = np.full(tuple(frame) + a.shape[2:], fill, a.dtype)
    full[y0 : y0 + h, x0 : x0 + w] = a
    return full


MAX_FRAME_SIDE = 1 << 16
"""The largest image side a result may claim: more is a damaged ``frame``, not a camera (pasting would exhaust
memory)."""


def _box_checked(
    path: Path, arrays: dict, version: int, shape: tuple[int, int] | None = None
) -> tuple[tuple[int, int, int, int], tuple[int, int]]:
    """(box, frame) of a result.npz's ``arrays`` (those of :data:`ARRAYS` among them checked), or CaptureError
    naming ``path``: a box not inside its frame, a frame other than ``shape``, a map of another shape than its
    box or of another dtype kind. Version 1 files hold full-frame maps: their box is the whole frame."""
    if version < 2:
        frame = tuple(arrays["depth"].shape) if shape is None else tuple(shape)
        box = (0, 0, frame[1], frame[0]) if len(frame) == 2 else (0, 0, 0, 0)
        grid = frame
    else:
        box, frame = _stored_box(path, arrays)
        if shape is not None and frame != tuple(shape):
            raise CaptureError(f"{path}: a result of a {frame} image (H, W), expected {tuple(shape)}")
        grid = (box[3], box[2])
    for name, (ndim, kind) in ARRAYS.items():
        if name not in arrays:
            continue
        a = arrays[name]
        want = grid + ((3,) if ndim == 3 else ())
        if a.shape != want or a.dtype.kind != kind:
            on = f" (its box [x0, y0, w, h] is {list(box)})" if version >= 2 else ""
            raise CaptureError(f"{path}: array '{name}' is {a.shape} {a.dtype}, expected {want} of kind '{kind}'{on}")
    return box, frame


def _stored_box(path: Path, arrays: dict) -> tuple[tuple[int, int, int, int], tuple[int, int]]:
    """The (box, frame) a version 2 result.npz records, checked to be integers and the box inside the frame."""
    box, frame = arrays["box"], arrays["frame"]
    if box.shape != (4,) or frame.shape != (2,) or box.dtype.kind not in "iu" or frame.dtype.kind not in "iu":
        raise CaptureError(
            f"{path}: damaged reconstruction (box {box.shape} {box.dtype} and frame {frame.shape} {frame.dtype}; "
            "expected 4 and 2 integers)"
        )
    (x0, y0, w, h), (H, W) = (int(v) for v in box), (int(v) for v in frame)
    if not (0 < H <= MAX_FRAME_SIDE and 0 < W <= MAX_FRAME_SIDE):
        raise CaptureError(f"{path}: damaged reconstruction (frame [H, W] = {[H, W]} is not an image size)")
    if min(x0, y0, w, h) < 0 or x0 + w > W or y0 + h > H:
        raise CaptureError(
            f"{path}: damaged reconstruction (box [x0, y0, w, h] = {[x0, y0, w, h]} is not inside its {H}x{W} frame)"
        )
    return (x0, y0, w, h), (H, W)


def content_problem(arrays: dict) -> str | None:
    """Why a reconstruction's maps break its own promise, or None: on every reconstructed pixel the depth is
    finite and the normal a finite unit vector (a result of NaN -- a diverged solve, a network with NaN weights,
    a hand-made file -- would otherwise be reused, and scored on the pixels where it is not NaN)."""
    done = np.asarray(arrays["reconstructed"], bool)
    n = int(done.sum())
    bad = int(np.count_nonzero(done & ~np.isfinite(arrays["depth"])))
    if bad:
        return f"array 'depth' is not finite on {bad} of its {n} reconstructed pixels"
    bad = non_unit_count(arrays["normals"], done)
    if bad:
        return f"array 'normals' is not a finite unit vector on {bad} of its {n} reconstructed pixels"
    return None


def _read_report(path: Path) -> dict:
    return read_format_json(path, FORMAT_NAME, READ_VERSIONS, missing_hint="an incomplete reconstruction folder")


def jsonable(obj: object) -> object:
    """A copy of ``obj`` that json can write (numpy scalars and arrays become Python numbers and lists)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return obj
