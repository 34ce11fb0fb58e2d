"""An exposure bracket a lab took itself (``nlips calibrate-camera-response --bracket FOLDER``): for a camera OpenCV
cannot set the exposure of, whose vendor's tool can. One image per exposure, the exposure, ms, in its name
(``gel_2.5ms.png``, ``0.707 ms.tif``), or in ``exposures.csv`` beside them (``file,exposure_ms`` rows), which then
rules. An image whose name starts with ``dark`` (``dark.png``, ``dark_0.5ms.png``) is a frame with every LED off,
not one of the bracket: what the camera reads for no light (``device.response_fit.check_black``)."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np

from ..core.errors import CaptureError
from ..core.imageio import read_image
from .camera import IMAGE_SUFFIXES, to_stored

EXPOSURES_CSV = "exposures.csv"
"""The folder's optional table of ``file,exposure_ms`` rows (a header row of those names)."""
MS_IN_NAME = re.compile(r"(\d+(?:\.\d+)?)\s*ms", re.IGNORECASE)
"""An exposure in a file's name: a number followed by ``ms`` (the last such in the name)."""


DARK_PREFIX = "dark"
"""The start of a dark frame's name (any case)."""


def read_bracket_folder(
    folder: str | Path,
) -> tuple[list[np.ndarray], list[float], int, tuple[np.ndarray, float | None] | None]:
    """The images of a bracket folder and their exposures, in the order of their names.

    Parameters
    ----------
    folder : the folder of images (``IMAGE_SUFFIXES``), and optionally ``exposures.csv``

    Returns
    -------
    frames : list of (H, W, 3) uint16, RGB, stored values ``DN << (16 - bit_depth)``
    exposures : ms, one per frame
    bit_depth : of the images (8 or 16; all must share it)
    dark : (the dark frame, (H, W, 3) uint16 as the frames; its exposure, ms, or None when its name and the CSV
        give none), or None when the folder has none

    Raises
    ------
    CaptureError -- one line naming the folder or file: no folder, no images, an image without an exposure, one
        OpenCV cannot read, two images at one exposure, images of different sizes or bit depths.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise CaptureError(f"--bracket {folder}: no such folder")
    images = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    darks = [p for p in images if p.name.lower().startswith(DARK_PREFIX)]
    files = [p for p in images if p not in darks]
    if not files:
        raise CaptureError(f"--bracket {folder}: no images ({', '.join(IMAGE_SUFFIXES)}) in the folder")
    if len(darks) > 1:
        raise CaptureError(f"--bracket {folder}: {len(darks)} dark frames ({darks[0].name}, {darks[1].name}): one")
    table = _exposure_table(folder / EXPOSURES_CSV)
    exposures = [_exposure_of(path, table) for path in files]
    seen: dict[float, Path] = {}
    for path, ms in zip(files, exposures, strict=True):
        if ms in seen:
            raise CaptureError(f"{path}: exposure {ms:g} ms, as {seen[ms].name}: one image per exposure")
        seen[ms] = path
    frames, depths = [], set()
    for path in files + darks:
        image = read_image(path)
        if image is None:
            raise CaptureError(f"{path}: OpenCV cannot read it as an image")
        stored, bits = to_stored(image, str(path))
        if frames and stored.shape != frames[0].shape:
            raise CaptureError(
                f"{path}: {stored.shape[1]}x{stored.shape[0]}, the bracket's first image is "
                f"{frames[0].shape[1]}x{frames[0].shape[0]}: one camera setting for all"
            )
        frames.append(stored)
        depths.add(bits)
    if len(depths) > 1:
        raise CaptureError(f"--bracket {folder}: images of {sorted(depths)} bits: one camera setting for all")
    dark = (frames.pop(), _dark_exposure(darks[0], table)) if darks else None
    return frames, exposures, depths.pop(), dark


def _dark_exposure(path: Path, table: dict[str, float] | None) -> float | None:
    """The dark frame's exposure, ms, from the CSV or its name; None when neither gives one (it is optional)."""
    if table is not None and path.name in table:
        return table[path.name]
    found = MS_IN_NAME.findall(path.stem)
    return float(found[-1]) if found else None


def _exposure_table(path: Path) -> dict[str, float] | None:
    """``exposures.csv``'s file name -> ms, None when the folder has none."""
    if not path.exists():
        return None
    table = {}
    with path.open(newline="", encoding="utf-8") as f:
        rows = csv.DictReader(f)
        for row in rows:
            try:
                table[row["file"].strip()] = float(row["exposure_ms"])
            except (KeyError, TypeError, ValueError, AttributeError):
                raise CaptureError(
                    f"{path}: line {rows.line_num}: needs file,exposure_ms columns (a header row of those names, "
                    "then rows such as gel_1.png,2.5)"
                ) from None
    return table


def _exposure_of(path: Path, table: dict[str, float] | None) -> float:
    if table is not None:
        if path.name not in table:
            raise CaptureError(f"{path}: not in {EXPOSURES_CSV} (give each image's exposure_ms there)")
        ms = table[path.name]
    else:
        found = MS_IN_NAME.findall(path.stem)
        if not found:
            raise CaptureError(
                f"{path}: no exposure in its name: name each image with its exposure (gel_2.5ms.png) or list them "
                f"in {path.parent / EXPOSURES_CSV} (file,exposure_ms)"
            )
        ms = float(found[-1])
    if not ms > 0 or ms == float("inf"):
        raise CaptureError(f"{path}: exposure {ms:g} ms: must be > 0")
    return ms
