"""Capture files: 16-bit linear PNG (OpenCV does 16-bit 3-channel PNG fast; Pillow cannot) and npz."""

from __future__ import annotations

import contextlib
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path

import numpy as np

from .atomic import write_bytes
from .errors import CaptureError, ShapeError, require
from .tolerances import MAX_IMAGE_PIXELS


def _cv2():
    return require("cv2", "opencv-python-headless", "Reading and writing capture images")


def write_png16(path: str | Path, image: np.ndarray) -> Path:
    """Write a 16-bit PNG, atomically (ShapeError for any other shape or dtype).

    Parameters
    ----------
    path : the PNG file to write (replaced whole if it exists)
    image : (H, W) or (H, W, 3) uint16 -- stored values; channels in RGB order (written as PNG's RGB)

    Returns
    -------
    Path of the written file.
    """
    image = np.asarray(image)
    if image.dtype != np.uint16 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise ShapeError(f"write_png16 needs (H, W) or (H, W, 3) uint16, got {image.shape} {image.dtype}")
    cv2 = _cv2()
    bgr = image[..., ::-1] if image.ndim == 3 else image
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(bgr), png_params())
    if not ok:  # pragma: no cover - OpenCV failure
        raise CaptureError(f"{path}: OpenCV could not encode the image")
    return write_bytes(path, buf.tobytes())


def png_params() -> list[int]:
    """OpenCV's PNG settings for captures and figure maps: every row SUB-filtered, deflated at level 1 with
    run-length matches only.

    A capture's 16-bit values carry sensor noise, which defeats deflate's search for repeated strings and makes
    libpng's per-row choice among its five filters (what a compression level alone asks for) pay for nothing:
    on the twin's noisy 640x480 images this writes a third of the CPU time of ``IMWRITE_PNG_COMPRESSION 1`` alone,
    10 % smaller files, decoded ~1.5x as fast (benchmarks/RESULTS.md, s18-j). Images without noise (a render with
    ``[noise] enabled = false``) come out ~1.7x as large as that setting's. Lossless either way. OpenCV reads the
    strategy after the level (the level resets it); an older OpenCV without the filter setting keeps libpng's choice.
    A solve's figure maps (:mod:`nlipscalib.report.maps`: noisy residual and error maps, smooth normals and depth)
    encode in ~0.4x the CPU of level 1 alone at about the same total size (cube1's auto ROI: 25 -> 10 ms, 798 ->
    792 KiB; benchmarks/RESULTS.md, s37-cubefast).
    """
    cv2 = _cv2()
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_RLE]
    if hasattr(cv2, "IMWRITE_PNG_FILTER"):
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    return params


def opencv_path(path: str | Path) -> str:
    """``path`` as OpenCV takes it; CaptureError for a name that is not valid UTF-8 (a byte sequence the file
    system allows but Python keeps as surrogates): OpenCV crashes the process on it (segfault, measured)."""
    name = str(path)
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        raise CaptureError(f"{name!r}: OpenCV cannot open a path that is not valid UTF-8; rename it") from None
    return name


def read_image(path: str | Path) -> np.ndarray | None:
    """OpenCV's ``imread(path, IMREAD_UNCHANGED)`` (BGR, bit depth kept), or None when OpenCV cannot decode it;
    CaptureError for a PNG cut short.

    The file is read by Python and decoded from memory (``cv2.imdecode``: the same decoders), so any path the
    file system allows works, where ``imread`` crashes on one that is not UTF-8.
    """
    cv2 = _cv2()
    data = np.fromfile(path, np.uint8)
    if data[: len(PNG_SIGNATURE)].tobytes() == PNG_SIGNATURE and (problem := png_problem(data)):
        # libpng would print "libpng error: Read Error" on stderr before the caller's one line
        raise CaptureError(f"{path}: {problem}")
    try:
        image = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    except cv2.error as exc:  # another format above OpenCV's own pixel limit: an assertion, not None
        raise CaptureError(f"{path}: OpenCV cannot decode it ({str(exc).strip().splitlines()[-1]})") from None
    if image is None and data[: len(PNG_SIGNATURE)].tobytes() == PNG_SIGNATURE:
        _raise_if_damaged_inside(data, path)
    return image


def read_png16(path: str | Path) -> np.ndarray:
    """Read a 16-bit PNG written by :func:`write_png16`; returns (H, W[, 3]) uint16, RGB."""
    return decode_png16(read_png_bytes(path), path)


def read_png_bytes(path: str | Path) -> np.ndarray:
    """The bytes of a PNG file ((n,) uint8), checked to be a whole PNG (:func:`png_problem`) but not decoded:
    CaptureError naming the file when it is missing, not a PNG or cut short."""
    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: image file is missing")
    data = np.fromfile(path, np.uint8)
    if problem := png_problem(data):
        raise CaptureError(f"{path}: {problem}")
    return data


def capture_shape_problem(shape: tuple[int, ...], camera_shape: tuple[int, int], meta: str = "meta.json") -> str:
    """Why a capture's decoded image of ``shape`` does not fit its camera's (H, W) ``camera_shape``, in the file's
    terms ("a grey (single-channel) PNG, ...", "image is 80x60 pixels, ..."); "" when it fits. Why: a grey image
    was "image is (120, 160), but the camera in meta.json is (120, 160, 3)", two NumPy shapes to compare."""
    (height, width) = camera_shape
    if len(shape) == 2:
        return f"a grey (single-channel) PNG, where a capture's images are RGB ({width}x{height}, 3 channels)"
    if tuple(shape[:2]) != (height, width):
        return f"image is {shape[1]}x{shape[0]} pixels, but the camera in {meta} is {width}x{height}"
    return "" if shape[2:] == (3,) else f"expected 3 colour channels, found {shape[2]}"


def decode_png16(data: np.ndarray, path: str | Path, out: np.ndarray | None = None) -> np.ndarray:
    """Decode a 16-bit PNG's bytes (:func:`read_png_bytes`) read from ``path`` (named in errors).

    Parameters
    ----------
    data : (n,) uint8, the file's bytes
    path : the file they were read from, named in errors
    out : optional (H, W, 3) uint16 (e.g. one image of a stack) that a colour image of its shape is written into
        and returned as; an image of another shape is returned as decoded (the caller's shape check names it)

    Returns
    -------
    (H, W[, 3]) uint16, stored values, RGB.
    """
    cv2 = _cv2()
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if img is None:
        _raise_if_damaged_inside(data, path)
        raise CaptureError(f"{path}: not a readable PNG image")
    if img.dtype != np.uint16:  # "found uint8" named NumPy's type, not the file's bit depth
        raise CaptureError(f"{path}: an {8 * img.dtype.itemsize}-bit PNG, where a 16-bit PNG is expected")
    if img.ndim == 2:
        return img
    if img.shape[2] != 3:
        raise CaptureError(f"{path}: expected 3 colour channels, found {img.shape[2]}")
    if out is not None and out.shape != img.shape:
        out = None
    # OpenCV's channel swap, not a copy of the view img[..., ::-1]: NumPy copies that 3-wide reversed axis element
    # by element, ~8x slower (12 LED images at 640x480: ~40 ms of one core)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB, dst=out)


def _raise_if_damaged_inside(data: np.ndarray, path: str | Path) -> None:
    """CaptureError naming the chunk of a PNG that OpenCV could not decode whose CRC-32 fails (a bad copy or disk
    block inside a file of whole length), rather than "not a readable PNG image". Checked only once decoding
    failed: on every read it would cost a few % of the decoding (~1 ms of ~20 ms at 640x480, 16-bit)."""
    from .file_checks import png_checksum_problem

    if problem := png_checksum_problem(data.data if data.flags.c_contiguous else data.tobytes()):
        raise CaptureError(f"{path}: {problem}: copy or capture it again")


def png_size(data: np.ndarray) -> tuple[int, int]:
    """(H, W) pixels of a PNG from its header (the IHDR chunk, bytes 16-23), without decoding it: ``data``
    (n,) uint8 as :func:`read_png_bytes` returns (a whole PNG)."""
    head = data[16:24].tobytes()
    return int.from_bytes(head[4:8], "big"), int.from_bytes(head[0:4], "big")


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_problem(data: np.ndarray) -> str | None:
    """What is wrong with ``data`` ((n,) uint8, a file's bytes) as a PNG, from its first and last bytes: no PNG
    signature, or cut short (no IEND chunk at its end: an interrupted copy or write); None for a whole PNG.
    libpng would print its own error line on stderr before the caller's one line. A header of more than
    :data:`~nlipscalib.core.tolerances.MAX_IMAGE_PIXELS` pixels is a problem too, found before anything is inflated
    (a file from elsewhere: a few hundred kilobytes of zeros decode to gigabytes)."""
    if data[: len(PNG_SIGNATURE)].tobytes() != PNG_SIGNATURE:
        return "not a readable PNG image (no PNG signature)"
    if b"IEND" not in data[-64:].tobytes():
        return "truncated PNG image (cut short: copy or capture it again)"
    height, width = png_size(data)
    if height * width > MAX_IMAGE_PIXELS:
        return f"image is {width}x{height} pixels, more than the {MAX_IMAGE_PIXELS} nlipscalib reads"
    return None


def _check_png_ends(path: Path) -> None:
    """CaptureError for a file that is not a PNG or is cut short (:func:`png_problem`), found from its first and
    last bytes only."""
    with open(path, "rb") as f:
        head = f.read(len(PNG_SIGNATURE))
        f.seek(max(f.seek(0, 2) - 64, 0))
        tail = f.read()
    if head != PNG_SIGNATURE:
        raise CaptureError(f"{path}: not a readable PNG image (no PNG signature)")
    if b"IEND" not in tail:
        raise CaptureError(f"{path}: truncated PNG image (cut short: copy or capture it again)")


def read_npz(
    path: str | Path,
    keys: Iterable[str] = (),
    unreadable: str = "damaged or truncated .npz",
    only: Iterable[str] | None = None,
) -> dict[str, np.ndarray]:
    """Every array of a .npz file (or those named in ``only``), checked to be readable and to hold ``keys``.

    ``unreadable`` words the problem when numpy cannot read the file (what the file was meant to be).
    ``only``: the arrays to read; the others are not inflated (np.load reads an archive's members at their access).

    Raises
    ------
    CaptureError naming the file: missing, damaged or truncated, or lacking one of ``keys``.
    """
    with _open_npz(path, keys, unreadable) as data:
        return {k: data[k] for k in (data.files if only is None else only)}


def npz_headers(
    path: str | Path, keys: Iterable[str] = (), unreadable: str = "damaged or truncated .npz"
) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """(shape, dtype) of every array of a .npz file, read from the arrays' headers: the arrays are not inflated.

    Why: a file's shapes and types can be checked when it is opened and each array read at its first use only
    (a 640x480 gt.npz holds 7.6 MB of deflated arrays; an error map needs three of its five).

    Raises
    ------
    CaptureError naming the file: missing, damaged or truncated, or lacking one of ``keys``.
    """
    import struct
    import zlib

    headers = {}
    with _open_npz(path, keys, unreadable) as data:
        for name in data.files:
            try:
                headers[name] = _npy_header(data, name)
            except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, struct.error) as exc:
                what = f"compressed data damaged: {exc}" if isinstance(exc, zlib.error) else str(exc)
                raise CaptureError(f"{path}: array '{name}' is not readable ({what})") from None
    return headers


def _npy_header(data: np.lib.npyio.NpzFile, name: str) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) of the array ``name`` of an open .npz, from its header (the member's first bytes)."""
    with data.zip.open(f"{name}.npy") as f:
        readers = {(1, 0): np.lib.format.read_array_header_1_0, (2, 0): np.lib.format.read_array_header_2_0}
        reader = readers.get(np.lib.format.read_magic(f))
        if reader is None:  # a header format numpy has no public reader for: the array itself tells
            array = data[name]
            return array.shape, array.dtype
        shape, _, dtype = reader(f)
        return shape, dtype


@contextlib.contextmanager
def _open_npz(path: str | Path, keys: Iterable[str], unreadable: str) -> Iterator[np.lib.npyio.NpzFile]:
    """The open .npz archive at ``path`` (its zip directory read, no array inflated), checked to hold ``keys``;
    a problem met opening it or reading from it is one CaptureError naming the file (:func:`read_npz`)."""
    import zlib

    path = Path(path)
    if not path.is_file():
        raise CaptureError(f"{path}: missing")
    # The file is opened here, not by np.load(path): numpy 2.4 hands its own file to the NpzFile before the zip
    # directory is read, so a damaged archive raised BadZipFile and left that file open (a ResourceWarning).
    with open(path, "rb") as f:
        if f.read(2) != b"PK":  # a .npz is a zip archive; numpy would take other bytes for a pickle
            raise CaptureError(f"{path}: {unreadable} (not a .npz archive)")
        f.seek(0)
        try:
            with np.load(f) as data:
                missing = sorted(set(keys) - set(data.files))
                if missing:
                    raise CaptureError(f"{path}: missing arrays {missing}")
                yield data
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            if isinstance(exc, CaptureError):
                raise
            raise CaptureError(f"{path}: {unreadable} ({exc})") from None
        except zlib.error as exc:
            # A flipped byte inside a deflated array fails in zlib's decompressor before the zip layer can
            # compare the CRC, and zlib.error is not an OSError: without this the reader gets a traceback.
            raise CaptureError(f"{path}: {unreadable} (compressed data damaged: {exc})") from None


def save_npz(path: str | Path, arrays: dict[str, np.ndarray], compress: bool | str = True) -> Path:
    """Save arrays as a .npz that ``np.load`` reads.

    ``compress``: True deflates every array at zlib level 1 (``np.savez_compressed`` uses level 6,
    several times slower for float maps that barely compress further); False stores them; "auto"
    deflates only arrays that are mostly NaN or zero (outside a region of interest) and integer /
    boolean masks, and stores dense float maps, which deflate to ~85 % of their size at ~0.1 s per
    megabyte. The file is written in place (callers write inside an atomic folder).

    A failed write (a full disk) raises OSError naming ``path``: the error of a write into the open file names
    none, and the command's line named only the folder ("OUT/press: No space left on device").
    """
    try:
        with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
            for name, arr in arrays.items():
                arr = np.asanyarray(arr)
                member = f"{name}.npy"
                if not _deflate(arr, compress):
                    member = zipfile.ZipInfo(member, date_time=(1980, 1, 1, 0, 0, 0))
                    member.compress_type = zipfile.ZIP_STORED
                with zf.open(member, "w", force_zip64=True) as f:
                    np.lib.format.write_array(f, arr, allow_pickle=False)
    except OSError as exc:
        if exc.filename is None and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror, str(path)) from exc
        raise
    return Path(path)


def _deflate(arr: np.ndarray, compress: bool | str) -> bool:
    if compress != "auto":
        return bool(compress)
    if arr.dtype.kind != "f" or arr.size == 0:
        return True
    informative = np.isfinite(arr) & (arr != 0)  # NaN or zero outside a region of interest deflates well
    return bool(np.count_nonzero(informative) < 0.5 * arr.size)
