"""An exposure bracket a lab took itself (``nlips calibrate-camera-response --bracket FOLDER``): for a camera OpenCV
cannot set the exposure of, whose vendor's tool can. One image per exposure, the exposure, ms, in its name
(``gel_2.5ms.png``, ``0.707 ms.tif``), or in ``exposures.csv`` beside them (``file,exposure_ms`` rows), which then
rules. An image whose name starts with ``dark`` (``dark.png``, ``dark_0.5ms.png``) is a frame with every LED off,
not one of the bracket: what the camera reads for no light (``device.response_fit.check_black``). Optionally, a
subfolder ``additivity/`` of LEDs lit apart and together at one exposure (:func:`read_pair_frames`): what checks the
curve's power (``device.additivity``), which no bracket can."""

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
PAIRS_FOLDER = "additivity"
"""The bracket folder's optional subfolder of LEDs lit apart and together (:func:`read_pair_frames`)."""
LED_NAME = re.compile(r"^led[ _-]?(\d+)(?:\+(\d+))?(?![\d+])", re.IGNORECASE)
"""A pair frame's name: ``led_3`` (LED 3 lit alone) or ``led_3+9`` (LEDs 3 and 9 lit together), 1-based, then
anything (``led_3+9_8ms.png``)."""


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


def read_pair_frames(folder: str | Path) -> tuple[dict, float | None] | None:
    """The frames of LEDs lit apart and together in a bracket folder's :data:`PAIRS_FOLDER` subfolder, None when it
    has none: ``dark.png`` (every LED off), ``led_A.png`` and ``led_B.png`` (each LED alone), ``led_A+B.png`` (the
    two together), for one or more pairs, all at one exposure and LED level (an exposure in the names, ``_8ms``,
    must be one for all; none is needed).

    Parameters
    ----------
    folder : the bracket folder

    Returns
    -------
    frames : "dark" -> (H, W, 3) uint16 stored values, as :func:`read_bracket_folder`'s; LED number -> its frame
        lit alone; (A, B) with A < B -> the frame of the two lit together
    exposure : ms, from the names, or None when they give none

    Raises
    ------
    CaptureError -- one line naming the subfolder or file: no dark frame, no pair, a pair without a frame of each
        of its LEDs alone, a name that is none of these, two frames of one key, exposures that differ, an image
        OpenCV cannot read.
    """
    sub = Path(folder) / PAIRS_FOLDER
    if not sub.is_dir():
        return None
    example = "dark.png, led_1.png, led_2.png, led_1+2.png"
    frames: dict = {}
    times: dict[float, Path] = {}
    for path in sorted(p for p in sub.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES):
        key = _pair_key(path, example)
        if key in frames:
            raise CaptureError(f"{path}: a second frame of {_pair_name(key)} in {sub}: one each")
        image = read_image(path)
        if image is None:
            raise CaptureError(f"{path}: OpenCV cannot read it as an image")
        frames[key] = to_stored(image, str(path))[0]
        for ms in MS_IN_NAME.findall(path.stem)[-1:]:
            times.setdefault(float(ms), path)
    pairs = [k for k in frames if isinstance(k, tuple)]
    if "dark" not in frames or not pairs:
        missing = "no dark.png (every LED off)" if "dark" not in frames else "no pair lit together (led_A+B.png)"
        raise CaptureError(f"{sub}: {missing}: the LEDs lit apart and together need {example} (more pairs alike)")
    for a, b in pairs:
        for led in (a, b):
            if led not in frames:
                raise CaptureError(f"{sub}: led_{a}+{b} without led_{led} (LED {led} lit alone at that exposure)")
    shapes = {f.shape for f in frames.values()}
    if len(shapes) > 1:
        raise CaptureError(f"{sub}: images of {len(shapes)} sizes: one camera setting for all")
    if len(times) > 1:
        (t0, p0), (t1, p1) = list(times.items())[:2]
        raise CaptureError(f"{sub}: {p0.name} at {t0:g} ms, {p1.name} at {t1:g} ms: one exposure for all")
    return frames, next(iter(times), None)


def _pair_key(path: Path, example: str) -> str | int | tuple[int, int]:
    """A pair frame's key from its name (:data:`LED_NAME`): "dark", an LED's number or a pair (A, B), A < B."""
    if path.name.lower().startswith(DARK_PREFIX):
        return "dark"
    found = LED_NAME.match(path.stem)
    if found is None or int(found[1]) < 1 or (found[2] is not None and int(found[2]) < 1):
        raise CaptureError(
            f"{path}: not a name the LEDs' frames take ({example}: every LED off, each LED alone, two together)"
        )
    if found[2] is None:
        return int(found[1])
    a, b = sorted((int(found[1]), int(found[2])))
    if a == b:
        raise CaptureError(f"{path}: LED {a} with itself: a pair is two LEDs (led_1+2.png)")
    return a, b


def _pair_name(key: str | int | tuple[int, int]) -> str:
    return key if isinstance(key, str) else f"led_{key}" if isinstance(key, int) else f"led_{key[0]}+{key[1]}"
