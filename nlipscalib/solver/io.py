"""Saving solver results next to a press (npz + PNG figures) and LED parameter files."""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from ..core.atomic import atomic_dir
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
        buf = io.BytesIO()
        np.savez_compressed(buf, **result.arrays())
        (tmp / RESULT_FILE).write_bytes(buf.getvalue())
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
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .metrics import aae, angular_error_map

    def save(name, image, title, cmap=None, label=None, vmin=None, vmax=None):
        fig, ax = plt.subplots(figsize=(6, 4.5), dpi=100)
        im = ax.imshow(image, cmap=cmap, vmin=vmin, vmax=vmax)
        ax.set_title(title)
        ax.axis("off")
        if label:
            fig.colorbar(im, ax=ax, label=label)
        fig.savefig(folder / name, bbox_inches="tight")
        plt.close(fig)

    n = result.normals
    # Paper-style normal map: RGB = ((n_x, -n_y, -n_z) + 1) / 2 with the camera looking at the surface.
    rgb = np.clip((np.stack([n[..., 0], -n[..., 1], -n[..., 2]], -1) + 1) / 2, 0, 1)
    save("normals.png", np.nan_to_num(rgb, nan=0.0), "normals")
    save("depth.png", result.depth, "depth (mm)", "viridis", "mm")
    save("residual.png", result.residual, "RMS residual (linear)", "magma", "linear intensity")
    if ground_truth is not None:
        err = angular_error_map(result.normals, ground_truth.normals)
        err = np.where(result.reconstructed & ground_truth.valid, err, np.nan)
        m = result.reconstructed & ground_truth.valid
        save("error.png", err, f"angular error, AAE {aae(n, ground_truth.normals, m):.2f} deg", "jet", "deg", 0, 10)
