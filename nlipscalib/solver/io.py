"""Saving solver results next to a press (the core reconstruction format) and LED parameter files.

No figures here: nlipscalib.report draws them (the CLI passes them in as ``extra_files``)."""

from __future__ import annotations

import json
from pathlib import Path

from ..core.leds import Led
from ..core.reconstruction import (
    Reconstruction,
    load_reconstruction,
    save_reconstruction,
)
from ..errors import CaptureError


def save_result(result: Reconstruction, folder: str | Path, *, overwrite: bool = False, extra_files=None) -> Path:
    """Write the reconstruction atomically into ``folder`` (core.reconstruction.save_reconstruction).

    ``extra_files(tmp_folder)`` may add files (figures) that appear together with the result.
    """
    return save_reconstruction(result, folder, overwrite, extra_files)


def load_result(folder: str | Path) -> Reconstruction:
    return load_reconstruction(folder)


def save_leds(path: str | Path, leds, extra: dict | None = None) -> Path:
    """Write an LED file: {"leds": [Led.to_dict() ...], ...extra} (``nlips solve --leds FILE``)."""
    from ..core.atomic import write_json

    return write_json(path, {"leds": [led.to_dict() for led in leds]} | (extra or {}))


def load_leds(path: str | Path) -> tuple[Led, ...]:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        if not isinstance(data.get("leds"), list):
            raise ValueError(f"'leds' must be a list of LEDs, got {data.get('leds')!r}")
        return tuple(Led.from_dict(d) for d in data["leds"])
    except FileNotFoundError:
        raise CaptureError(f"{path}: no such LED file") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise CaptureError(f"{path}: not a valid LED file ({exc})") from None
