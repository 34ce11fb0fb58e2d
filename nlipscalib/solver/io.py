"""Saving solver results next to a press (npz + PNG figures) and LED parameter files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_dir
from ..core.imageio import save_npz
from ..core.leds import Led
from ..errors import CaptureError
from .nlips import SolveResult

RESULT_DIR = "nlips"
RESULT_FILE = "result.npz"
REPORT_FILE = "report.json"


def result_dir(press_folder, out: str | Path | None = None) -> Path:
    return Path(out) if out is not None else Path(press_folder) / RESULT_DIR


def save_result(result: SolveResult, folder: str | Path, ground_truth=None, overwrite: bool = False) -> Path:
    """Write result.npz, report.json and PNGs (normals, depth, residual[, error]) atomically into ``folder``."""
    folder = Path(folder)
    with atomic_dir(folder, overwrite=overwrite) as tmp:
        save_npz(tmp / RESULT_FILE, result.arrays())
        (tmp / REPORT_FILE).write_text(json.dumps(_jsonable(result.report), indent=2) + "\n")
        _figures(result, tmp, ground_truth)
    return folder


def load_result(folder: str | Path) -> SolveResult:
    folder = Path(folder)
    path = folder / RESULT_FILE
    if not path.is_file():
        raise CaptureError(f"{path}: no solver result (run `nlips solve` first)")
    with np.load(path) as data:
        arrays = {k: data[k] for k in data.files}
    report = json.loads((folder / REPORT_FILE).read_text()) if (folder / REPORT_FILE).is_file() else {}
    return SolveResult(**arrays, report=report)


def save_leds(path: str | Path, leds, extra: dict | None = None) -> Path:
    """Write an LED file: {"leds": [Led.to_dict() ...], ...extra} (``nlips solve --leds FILE``)."""
    from ..core.atomic import write_json

    return write_json(path, {"leds": [led.to_dict() for led in leds]} | (extra or {}))


def load_leds(path: str | Path) -> tuple[Led, ...]:
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        return tuple(Led.from_dict(d) for d in data["leds"])
    except FileNotFoundError:
        raise CaptureError(f"{path}: no such LED file") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise CaptureError(f"{path}: not a valid LED file ({exc})") from None


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    return obj


def _figures(result: SolveResult, folder: Path, ground_truth) -> None:
    from ..viz import Panel, contact_sheet, normals_to_rgb
    from .metrics import aae, angular_error_map

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
