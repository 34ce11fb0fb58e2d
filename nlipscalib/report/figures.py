"""Pictures people look at: normal maps, error maps with colour bars, contact sheets (matplotlib)."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

import numpy as np

from ..core.atomic import write_bytes


def normals_to_rgb(normals: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Normal map as an image, in the usual normal-map colours: a surface facing the camera is blue.

    Parameters
    ----------
    normals : (H, W, 3) float, unit, camera frame (toward the camera, docs/conventions.md)
    mask : (H, W) bool, optional -- pixels outside are shown black

    Returns
    -------
    rgb : (H, W, 3) float in [0, 1], RGB = ((n_x, -n_y, -n_z) + 1) / 2 -- x right, y up, z toward the viewer
    """
    n = np.nan_to_num(normals)
    rgb = np.clip((np.stack([n[..., 0], -n[..., 1], -n[..., 2]], axis=-1) + 1.0) / 2.0, 0.0, 1.0)
    if mask is not None:
        rgb[~mask] = 0.0
    return rgb


def display_image(linear: np.ndarray, percentile: float = 99.5) -> np.ndarray:
    """Linear (H, W, 3) image scaled to [0, 1] with a mild gamma, for viewing only."""
    img = np.clip(np.nan_to_num(linear), 0.0, None)
    top = np.percentile(img, percentile) or 1.0
    return np.clip(img / top, 0.0, 1.0) ** (1 / 2.2)


@dataclasses.dataclass
class Panel:
    """One picture of a contact sheet."""

    title: str
    image: np.ndarray
    """(H, W, 3) RGB in [0, 1], or (H, W) scalar shown with ``cmap`` and a colour bar."""
    cmap: str = "viridis"
    label: str = ""
    """Colour bar label (scalar panels)."""
    vmin: float | None = None
    vmax: float | None = None


def contact_sheet(rows: list[tuple[str, list[Panel]]], path: str | Path, dpi: int = 110) -> Path:
    """Save a grid of panels (one row per press) as a PNG, atomically.

    Parameters
    ----------
    rows : list of (row title, panels)
    path : output .png
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ncols = max(len(p) for _, p in rows)
    fig, axes = plt.subplots(len(rows), ncols, figsize=(3.2 * ncols, 2.7 * len(rows)), squeeze=False)
    for r, (row_title, panels) in enumerate(rows):
        for c in range(ncols):
            ax = axes[r, c]
            ax.set_axis_off()
            if c >= len(panels):
                continue
            _draw(fig, ax, panels[c])
        axes[r, 0].text(-0.08, 0.5, row_title, transform=axes[r, 0].transAxes, rotation=90, va="center", ha="right")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return write_bytes(path, buf.getvalue())


def _draw(fig, ax, panel: Panel) -> None:
    ax.set_title(panel.title, fontsize=9)
    if panel.image.ndim == 3:
        ax.imshow(panel.image)
        return
    import matplotlib

    # pixels without a value (NaN) in light grey, not the colour of zero
    cmap = matplotlib.colormaps[panel.cmap].with_extremes(bad="0.85")
    im = ax.imshow(panel.image, cmap=cmap, vmin=panel.vmin, vmax=panel.vmax)
    bar = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
    bar.ax.tick_params(labelsize=7)
    if panel.label:
        bar.set_label(panel.label, fontsize=8)
