"""A press's identity by what was captured: the content of its images and its sensor record, not its meta.json's
bytes (times, software versions, paths), so the same images are the same press wherever the folder lies.

What tells whether a model learnt from a capture (``learn.seen``, report.json ``trained_on``): a calibration
dataset records each press's identity (index.json ``press_identity``), a model keeps those of its training and
validation presses, and ``nlips infer`` compares the press or image frame it reads with them.

The record (:func:`press_identity`), rule :data:`IDENTITY_RULE`:

- ``tricolor``: :func:`pixels_digest` of the tri-colour frame as stored 16-bit RGB values (decoded, before any tone
  curve is undone): the network's only input, and what an image frame of the same pixels (a press's tri-colour image
  copied, or written again losslessly in another format) is compared on (:func:`frame_identity`);
- ``press``: SHA-256 over the rule, meta.json's ``sensor`` record (how the stored values read as light: bit depth,
  black and white levels, exposure, gain, tone curve), ``tricolor``, and the SHA-256 of the dark image's and each LED
  image's file bytes, in meta.json's LED order.

Left out on purpose: meta.json's ``provenance`` (render or capture times, software and library versions, the code's
fingerprint), its ``format_version`` and ``software_version``, file names, and the camera, LED and design records
(a geometry that a later calibration may rewrite without another capture), reference.npz and gt.npz (computed from
the design, not captured). Why file bytes for the dark and LED images but pixels for the tri-colour one: decoding
the twelve LED images costs ~0.2 s of CPU a 640x480 press, hashing their bytes ~13 ms, and a copied or re-rendered
press has the same bytes (the PNG writer is deterministic); only the tri-colour frame has a counterpart outside a
press folder (an image frame given to ``nlips infer``).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .errors import CaptureError

IDENTITY_RULE = 1
"""The version of the rule above, recorded with every identity: identities of another rule are never compared."""
IDENTITY_KEY = "press_identity"
"""index.json entry key holding a press's :func:`press_identity` record."""


def pixels_digest(image: np.ndarray) -> str:
    """SHA-256 (hex) of an image's stored values: dtype, shape and bytes (C order).

    Parameters
    ----------
    image : (H, W, 3) uint16, stored values, RGB (a tri-colour frame as decoded, no tone curve undone)
    """
    a = np.ascontiguousarray(image)
    digest = hashlib.sha256(f"{a.dtype.str}:{a.shape}:".encode())
    digest.update(memoryview(a).cast("B"))
    return digest.hexdigest()


def frame_identity(image: np.ndarray) -> dict:
    """The identity record of an image frame ((H, W, 3) uint16 stored RGB values, decoded from its file): its
    ``tricolor`` digest alone, which equals a press's when the pixels are that press's tri-colour frame."""
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be (H, W, 3) stored values, got shape {image.shape}")
    return {"rule": IDENTITY_RULE, "tricolor": pixels_digest(image)}


def press_identity(folder: str | Path) -> dict:
    """The identity record of the press folder ``folder``: ``{"rule", "press", "tricolor"}`` (module docstring).

    Cached per process while meta.json and every image keep their stamps (``stored_images.file_stamp``): a warm call
    costs a stat per file. CaptureError naming the file when meta.json or an image it lists is missing or is no
    16-bit PNG."""
    from .press_meta import META_FILE, read_meta
    from .stored_images import file_stamp

    where = str(Path(folder).resolve())
    try:
        meta_stamp = file_stamp(os.path.join(where, META_FILE))
    except FileNotFoundError:
        raise CaptureError(f"{Path(folder) / META_FILE}: missing; {folder} is not a complete press folder") from None
    meta = read_meta(folder)
    images = meta["images"]
    names = (images["tricolor"], images["dark"], *images["leds"])
    stamps = []
    for name in names:
        try:
            stamps.append(file_stamp(os.path.join(where, name)))
        except FileNotFoundError:
            raise CaptureError(f"{Path(folder) / name}: listed in {META_FILE} but missing") from None
    sensor = json.dumps(meta["sensor"], sort_keys=True, separators=(",", ":"))
    return dict(_identity(where, sensor, names, (meta_stamp, *stamps)))


@functools.lru_cache(maxsize=64)
def _identity(folder: str, sensor: str, names: tuple[str, ...], stamps: tuple) -> tuple[tuple[str, object], ...]:
    """:func:`press_identity` of ``folder`` (its images ``names``: tri-colour, dark, LEDs), per the files' ``stamps``
    (the cache's key), as items (hashable, copied into a fresh dict by the caller)."""
    from .imageio import decode_png16, read_png_bytes

    path = Path(folder) / names[0]
    tricolor = pixels_digest(decode_png16(read_png_bytes(path), path))
    press = hashlib.sha256(f"nlipscalib press identity {IDENTITY_RULE}\nsensor {sensor}\n".encode())
    press.update(f"tricolor {tricolor}\n".encode())
    for role, name in zip(["dark", *(f"led {i + 1}" for i in range(len(names) - 2))], names[1:]):
        try:
            with open(Path(folder) / name, "rb") as f:
                press.update(f"{role} {hashlib.file_digest(f, 'sha256').hexdigest()}\n".encode())
        except FileNotFoundError:  # removed since its stat
            raise CaptureError(f"{Path(folder) / name}: listed in meta.json but missing") from None
    return (("rule", IDENTITY_RULE), ("press", press.hexdigest()), ("tricolor", tricolor))


def is_identity(record: object, kind: str = "press") -> bool:
    """Whether ``record`` is an identity record of this rule holding a ``kind`` digest (``"press"`` or
    ``"tricolor"``); a hand-edited file may hold anything."""
    if not isinstance(record, dict) or record.get("rule") != IDENTITY_RULE:
        return False
    value = record.get(kind)
    return isinstance(value, str) and len(value) == 64
