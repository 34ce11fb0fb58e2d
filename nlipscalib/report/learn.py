"""Figures of the NLiPsNet calibration: coverage of the dome and of normal directions, training curves."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from .figures import axis_from_zero, new_figure, save_png, wrap_text

if TYPE_CHECKING:  # named in hints only: matplotlib is imported where a figure is drawn
    from matplotlib.figure import Figure
    from matplotlib.projections.polar import PolarAxes

DPI = 110
"""Resolution of the coverage and training figures (their smallest text, 6 pt, is 9.2 px tall)."""


def _save(fig: Figure, path: str | Path) -> Path:
    return save_png(fig, path, DPI)


THETA_SUBSTEPS = 8
"""Angular steps drawn per azimuth sector, so the rings are round (with one step per sector, octagons)."""
RING_TICKS_DEG = (10.0, 25.0, 45.0)
"""Tilt rings labelled in the coverage figure (the inner 2-deg ring is too small to label)."""


def coverage_figure(cov: dict, path: str | Path) -> Path:
    """One polar histogram of tilt directions per image region, laid out like the image, next press marked.

    Each plot is oriented like the image: a tilt toward the image's right is drawn right, toward its bottom
    drawn at the bottom (:func:`image_polar_axes`); its radius is the tilt from the undeformed normal.

    Parameters
    ----------
    cov : the dict of ``nlipscalib.learn.coverage.coverage``
    path : output .png
    """
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    cells, counts, gel = cov["cells"], np.asarray(cov["counts"]), np.asarray(cov["gel"])
    rings = np.array(cov["tilt_edges_deg"][:-1] + [60.0])  # outer ring drawn to 60 deg
    sectors = cov["azimuth_sectors"]
    # learn.coverage's sector k spans atan2(d_y, d_x) from -pi + k * 2 pi / sectors
    theta = np.linspace(-np.pi, np.pi, sectors * THETA_SUBSTEPS + 1)
    nxt = tuple(cov["next_press"]["region"])
    norm = Normalize(0, np.log1p(max(int(counts.max()), 1)))
    header = _coverage_header(cov, width_in=2.2 * cells + 1.0 - COLOUR_BAR_IN)
    header_in = (header.count("\n") + 1) * HEADER_PT * HEADER_LINE_SPACING / 72 + HEADER_PAD_IN
    fig = new_figure(figsize=(2.2 * cells + 1.0, 2.2 * cells + header_in))
    keyed = False
    for r in range(cells):
        for c in range(cells):
            ax = fig.add_subplot(cells, cells, r * cells + c + 1, projection="polar")
            image_polar_axes(ax)
            ax.set_xticks([])
            ax.set_yticks(RING_TICKS_DEG, [] if keyed or not gel[r, c] else [f"{t:.0f}°" for t in RING_TICKS_DEG])
            ax.tick_params(labelsize=6, colors="white")
            ax.grid(color="white", alpha=0.3, lw=0.5)
            if not gel[r, c]:
                ax.set_facecolor("0.9")
                continue
            keyed = True  # ring labels on the first gel plot only
            grid = np.repeat(counts[r, c].reshape(-1, sectors), THETA_SUBSTEPS, axis=1)
            ax.pcolormesh(theta, rings, np.log1p(grid), cmap="viridis", norm=norm)
            ax.set_ylim(0, rings[-1])
            covered = (counts[r, c] >= cov["min_samples"]).mean()
            ax.set_title(f"{covered * 100:.0f}%", fontsize=8, color="red" if (r, c) == nxt else "black")
            if (r, c) == nxt:
                ax.spines["polar"].set_color("red")
                ax.spines["polar"].set_linewidth(2)
    fig.suptitle(header, fontsize=HEADER_PT)
    fig.tight_layout(rect=(0, 0, 1 - COLOUR_BAR_IN / fig.get_figwidth(), 1))
    # beside the plots, not the header: a 1 x 1 figure's header fills a third of its height
    plots = [ax.get_position() for ax in fig.axes]
    low, high = min(b.y0 for b in plots), max(b.y1 for b in plots)
    left = 1 - 0.75 / fig.get_figwidth()
    bar_box = (left, low + 0.15 * (high - low), 0.015, 0.7 * (high - low))
    bar = fig.colorbar(ScalarMappable(norm, "viridis"), cax=fig.add_axes(bar_box))
    ticks = [n for n in (0, 1, 10, 100, 1000, 10000, 100000) if np.log1p(n) <= norm.vmax]
    bar.set_ticks(np.log1p(ticks), labels=[str(n) for n in ticks])
    bar.ax.tick_params(labelsize=7)
    bar.set_label("samples per bin (log scale)", fontsize=8)
    return _save(fig, path)


HEADER_PT = 8
"""Font size of the coverage figure's header, points (12.2 px tall at :data:`DPI`)."""
HEADER_LINE_SPACING = 1.2
"""Height of a header line as a share of its font size (matplotlib's default ``linespacing``)."""
HEADER_PAD_IN = 0.5
"""Room around the header, inches: above it and between it and the first row's titles."""
COLOUR_BAR_IN = 0.9
"""Width right of the plots kept for the colour bar and its label, inches."""


def _coverage_header(cov: dict, width_in: float) -> str:
    """The coverage figure's header (coverage, where to press next, how to read a plot), each line wrapped to
    ``width_in`` inches: a 2 x 2 grid's 5.4-in figure cut its three long lines at both edges.

    Parameters
    ----------
    cov : the dict of ``nlipscalib.learn.coverage.coverage``
    width_in : the room, inches
    """
    nxt = cov["next_press"]
    lines = [
        f"normal-direction coverage per image region ({cov['covered_fraction'] * 100:.0f}% of bins)",
        f"press next (red): {nxt['indenter']} at u~{nxt['centre_uv'][0]:.0f}, v~{nxt['centre_uv'][1]:.0f}"
        + _press_direction(nxt),
        *_steep_line(cov.get("steep")).splitlines()[1:],
        "each plot: tilt direction as in the image (right = +u, down = +v), radius = tilt from the undeformed normal",
        f"(rings {'/'.join(f'{t:g}' for t in cov['tilt_edges_deg'])}°, outer ring drawn to 60°); "
        f"title = share of its direction bins with ≥ {cov['min_samples']} samples",
    ]
    return "\n".join(wrap_text(line, HEADER_PT, width_in) for line in lines)


def image_polar_axes(ax: PolarAxes) -> None:
    """Orient polar axes like the image (x right, y down): angle ``atan2(d_y, d_x)`` of a camera-frame direction
    is drawn where that direction points in the image. Matplotlib's default (counter-clockwise, y up) drew a
    tilt toward the image's bottom at the top."""
    ax.set_theta_zero_location("E")
    ax.set_theta_direction(-1)


def _press_direction(next_press: dict) -> str:
    """The next press's direction (polar, azimuth) for the title, "" when the coverage report has none."""
    if next_press.get("polar_deg") is None:
        return ""
    return f" (polar {next_press['polar_deg']:.0f}°, azimuth {next_press['azimuth_deg']:.0f}°)"


def _steep_line(steep: dict | None) -> str:
    """The coverage figure's line on how steep the taught normals are ("" for reports without it)."""
    if not steep or steep.get("taught_tilt_deg") is None:
        return ""
    line = f"\n99% of taught normals within {steep['taught_tilt_deg']:.0f}° of the undeformed"
    if steep.get("untaught_from_deg") is not None:
        line += f"; none beyond {steep['untaught_from_deg']:.0f}°: press an object with steep relief"
    return line


def training_curve(
    history: list[dict], path: str | Path, title: str = "NLiPsNet", val_presses: Sequence[str] = ()
) -> Path:
    """Training loss and validation AAE per epoch, best epoch marked; epochs numbered from 1, as `nlips train` says.

    Parameters
    ----------
    history : list of dicts with epoch (0-based, as stored), train_loss, val_aae_deg, val_contact_aae_deg
    path : output .png
    title : the net (e.g. "NLiPsNet 64,64,64")
    val_presses : the validation presses' names, named in the title (:func:`validation_line`)
    """
    from matplotlib.ticker import MaxNLocator

    ep = [h["epoch"] + 1 for h in history]
    fig = new_figure(figsize=(9, 3.2))
    a1, a2 = fig.subplots(1, 2)
    a1.semilogy(ep, [h["train_loss"] for h in history])
    a1.set_xlabel("epoch")
    a1.set_ylabel(r"training loss, mean $1 - \hat{n} \cdot n$")
    a2.plot(ep, [h["val_aae_deg"] for h in history], label="validation, all samples")
    a2.plot(ep, [h["val_contact_aae_deg"] for h in history], label="validation, contact")
    # from 0 as every AAE axis of report/: from the curve's own low the late epochs' 0.1 deg filled the axis
    axis_from_zero(a2)
    best = min(history, key=lambda h: h["val_aae_deg"])
    a2.axvline(best["epoch"] + 1, color="0.5", ls="--", lw=1)
    a2.set_xlabel("epoch")
    a2.set_ylabel("AAE, deg")
    a2.legend(fontsize=8)
    a2.set_title(best_epoch_title(best), fontsize=9)
    for ax in (a1, a2):  # epochs are whole numbers (matplotlib would tick 2.5, 7.5, ...)
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    fig.suptitle(title + validation_line(val_presses), fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


VALIDATION_NAMES_CHARS = 60
"""Longest list of validation press names the training curve's title gives; a longer one is counted (the paper's
10 presses, or an experiment's "sphere-p12.1-a15.2-d1.05-86cb5640ea-584aae", would run off the 9-in figure)."""


def validation_line(names: Sequence[str]) -> str:
    """The training curve's title's end: on which presses the validation AAE was measured, as `nlips train` prints
    them ("" when not given): ", validation press sphere", ", validation presses a, b", ", 10 validation presses".

    Parameters
    ----------
    names : the validation presses' names
    """
    if not names:
        return ""
    listed = ", ".join(names)
    if len(listed) > VALIDATION_NAMES_CHARS:
        return f", {len(names)} validation press{'es' if len(names) > 1 else ''}"
    return f", validation press{'es' if len(names) > 1 else ''} {listed}"


def best_epoch_title(best: dict) -> str:
    """The curve's title: the best epoch (from 1) and its validation AAE, all samples and contact, as `nlips train`
    prints them ("best epoch 2: 1.72 deg (contact 1.68 deg)"); the contact figure was missing, though it is the
    number reports quote. Validation presses without contact samples (contact AAE NaN or None) say so.

    Parameters
    ----------
    best : one entry of the training history: epoch (0-based), val_aae_deg, val_contact_aae_deg (degrees)
    """
    contact = best.get("val_contact_aae_deg")
    contact_text = (
        f"contact {contact:.2f} deg" if contact is not None and np.isfinite(contact) else "no contact samples"
    )
    return f"best epoch {best['epoch'] + 1}: {best['val_aae_deg']:.2f} deg ({contact_text})"
