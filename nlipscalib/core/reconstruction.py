"""The reconstruction format: what NLiPs (and later NLiPsNet) writes and what training and scoring read.

A reconstruction folder (``PRESS/nlips/`` from NLiPs, ``PRESS/nlipsnet/`` from NLiPsNet; see
docs/formats.md)::

    nlips/
      result.npz     the maps below, over the full image grid
      report.json    format, format_version, software_version, method, and what made it
                     (provenance: settings and input identities, their hash; timings; exclusions)
      *.png          optional figures (nlipscalib.report), never read back

Written atomically (the folder appears complete or not at all); :func:`load_reconstruction`
validates format, version, keys, shapes and dtypes and names the file and the problem.
"""

from __future__ import annotations

import dataclasses
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import __version__
from .atomic import atomic_dir, write_json
from .errors import CaptureError
from .formatfile import read_arrays, read_format_json
from .imageio import save_npz
from .surface_checks import non_unit_count

FORMAT_NAME = "nlipscalib.reconstruction"
FORMAT_VERSION = 1
RESULT_DIR = "nlips"
METHODS = ("nlips", "nlipsnet")
"""Reconstruction methods; each writes PRESS/<method>/ in this format."""
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


def provenance_key(settings: dict, inputs: dict) -> str:
    """The key of a result's provenance (its report's ``provenance.key``): SHA-256 (hex) of the settings that decide
    it, the identities of its inputs and the software version, as sorted JSON. A kept result whose key equals a new
    request's is reused (``nlips solve``, ``nlips infer``); one formula for both, so their records read alike."""
    import hashlib
    import json

    source = {"settings": settings, "inputs": inputs, "software_version": __version__}
    return hashlib.sha256(json.dumps(source, sort_keys=True).encode()).hexdigest()


def reconstruction_dir(press_folder: str | Path, out: str | Path | None = None, method: str = RESULT_DIR) -> Path:
    """Where the reconstruction of ``press_folder`` lives (``out`` when given, else PRESS/<method>)."""
    if method not in METHODS:
        raise CaptureError(f"unknown reconstruction method {method!r}; expected one of {METHODS}")
    return Path(out) if out is not None else Path(press_folder) / method


def has_reconstruction(folder: str | Path) -> bool:
    """True when ``folder`` holds a (complete, atomically written) reconstruction."""
    return (Path(folder) / RESULT_FILE).is_file()


def is_reconstruction_dir(folder: str | Path) -> bool:
    """True when ``folder`` itself looks like a reconstruction folder (result.npz and report.json)."""
    folder = Path(folder)
    return (folder / RESULT_FILE).is_file() and (folder / REPORT_FILE).is_file()


def replace_problem(folder: str | Path) -> str | None:
    """Why writing a reconstruction into ``folder`` would destroy something else, or None when it may.

    A reconstruction is published by replacing the whole folder (core.atomic), so ``folder`` must be
    absent, an empty folder, or a reconstruction folder -- even a damaged one: result.npz or report.json
    among files alone. A file, a press folder, a folder of presses or any other folder is not one
    (``nlips solve PRESS --out DATASET`` would otherwise replace the dataset with one result).
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
    return None


def check_replaceable(folder: str | Path, remedy: str = "move it away or choose another --out") -> None:
    """Raise CaptureError (:func:`replace_problem`, with ``remedy``) unless a reconstruction may be written
    into ``folder``."""
    problem = replace_problem(folder)
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
        read_report(folder)
        with zipfile.ZipFile(path) as zf:
            names = {n.removesuffix(".npy") for n in zf.namelist()}
            bad = _damaged_member(zf) if verify else None
    except CaptureError as exc:
        return str(exc)
    except (OSError, zipfile.BadZipFile, EOFError, ValueError, zlib.error) as exc:
        return f"{path}: damaged or truncated reconstruction ({exc})"
    if bad is not None:
        return f"{path}: damaged reconstruction (array {bad[0].removesuffix('.npy')!r}: {bad[1]})"
    missing = sorted(set(ARRAYS) - names)
    if missing:
        return f"{path}: missing arrays {missing}"
    return _verified_content(path) if verify else None


def _verified_content(path: Path) -> str | None:
    """:func:`content_problem` of the result.npz at ``path`` (its members already checked to inflate)."""
    try:
        with np.load(path) as npz:
            arrays = {name: npz[name] for name in ("depth", "normals", "reconstructed")}
    except (ValueError, OSError, KeyError) as exc:  # object arrays (pickled), a hand-made file
        return f"{path}: damaged or foreign reconstruction ({exc})"
    if (
        arrays["normals"].shape != arrays["depth"].shape + (3,)
        or arrays["reconstructed"].shape != arrays["depth"].shape
    ):
        return f"{path}: arrays 'depth', 'normals' and 'reconstructed' differ in shape"
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
    """
    from concurrent.futures import ThreadPoolExecutor

    folder = Path(folder).absolute()  # "." has no name to write beside
    check_replaceable(folder)
    # the pool is left (its thread joined) before the folder is published or, on an error, removed
    with atomic_dir(folder, overwrite=overwrite) as tmp, ThreadPoolExecutor(1, "save-extra") as pool:
        # beside the arrays' deflating: both it and the figures' PNG encoding (and the ground truth's inflating
        # for error.png) release the GIL, so the two take one wall instead of two (an auto-ROI 640x480 result:
        # ~0.06 s of deflating, ~0.05 s of figures and ground truth)
        extra = pool.submit(extra_files, tmp) if extra_files is not None else None
        save_npz(tmp / RESULT_FILE, rec.arrays(), compress="auto")  # dense float maps stored: 10x faster
        head = {"format": FORMAT_NAME, "format_version": FORMAT_VERSION, "software_version": __version__}
        write_json(tmp / REPORT_FILE, head | jsonable(rec.report))
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
    folder = Path(folder)
    path, rpath = folder / RESULT_FILE, folder / REPORT_FILE
    if not path.is_file():
        raise CaptureError(f"{path}: no reconstruction there (run `nlips solve` first)")
    report = _read_report(rpath)
    arrays = read_arrays(path, ARRAYS, unreadable="damaged or truncated reconstruction")
    grid = tuple(arrays["depth"].shape) if shape is None else tuple(shape)
    for name, (ndim, kind) in ARRAYS.items():
        a = arrays[name]
        want = grid + ((3,) if ndim == 3 else ())
        if a.shape != want or a.dtype.kind != kind:
            raise CaptureError(f"{path}: array '{name}' is {a.shape} {a.dtype}, expected {want} of kind '{kind}'")
    if problem := content_problem(arrays):
        raise CaptureError(f"{path}: {problem}")
    return Reconstruction(**{k: arrays[k] for k in ARRAYS}, report=report)


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
    return read_format_json(path, FORMAT_NAME, FORMAT_VERSION, missing_hint="an incomplete reconstruction folder")


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
