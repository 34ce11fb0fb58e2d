"""Saving solver results next to a press (npz + PNG figures) and LED parameter files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.leds import Led
from ..core.reconstruction import (
    Reconstruction,
    load_reconstruction,
    save_reconstruction,
)
from ..errors import CaptureError


def save_result(result: Reconstruction, folder: str | Path, ground_truth=None, overwrite: bool = False) -> Path:
    """Write the reconstruction and its PNG figures (normals, depth, residual[, error]) atomically into ``folder``."""
    return save_reconstruction(result, folder, overwrite, lambda tmp: _figures(result, tmp, ground_truth))


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


def _figures(result: Reconstruction, folder: Path, ground_truth) -> None:
    from ..core.metrics import aae, angular_error_map
    from ..report import Panel, contact_sheet, normals_to_rgb

    shown = result.reconstructed
    figures = {
        "normals.png": Panel("normals", normals_to_rgb(result.normals, shown)),
        "depth.png": Panel("depth", result.depth, "viridis", "mm"),
        "residual.png": Panel("RMS residual", result.residual, "magma", "linear intensity"),
    }
    if ground_truth is not None:
        m = shown & ground_truth.valid
        err = np.where(m, angular_error_map(result.normals, ground_truth.normals), np.nan)
        title = f"angular error, AAE {aae(result.normals, ground_truth.normals, m):.2f} deg"
        figures["error.png"] = Panel(title, err, "jet", "deg", 0, 10)
    for name, panel in figures.items():
        contact_sheet([("", [panel])], folder / name, dpi=200)
