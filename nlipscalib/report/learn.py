"""Figures of the NLiPsNet calibration: coverage of the dome and of normal directions, training curves."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from ..core.atomic import write_bytes


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path, dpi=110) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    _plt().close(fig)
    return write_bytes(path, buf.getvalue())


def coverage_figure(cov: dict, path) -> Path:
    """One polar histogram of tilt directions per image region, laid out like the image, next press marked.

    Parameters
    ----------
    cov : the dict of ``nlipscalib.learn.coverage.coverage``
    path : output .png
    """
    plt = _plt()
    cells, counts, gel = cov["cells"], np.asarray(cov["counts"]), np.asarray(cov["gel"])
    edges = np.radians(cov["tilt_edges_deg"][:-1] + [60.0])  # outer ring drawn to 60 deg
    sectors = cov["azimuth_sectors"]
    theta = np.linspace(-np.pi, np.pi, sectors + 1)
    nxt = tuple(cov["next_press"]["region"])
    vmax = max(int(counts.max()), 1)
    fig = plt.figure(figsize=(2.2 * cells, 2.2 * cells + 0.8))
    for r in range(cells):
        for c in range(cells):
            ax = fig.add_subplot(cells, cells, r * cells + c + 1, projection="polar")
            ax.set_xticks([])
            ax.set_yticks([])
            if not gel[r, c]:
                ax.set_facecolor("0.9")
                continue
            grid = counts[r, c].reshape(-1, sectors)
            ax.pcolormesh(theta, np.degrees(edges), np.log1p(grid), cmap="viridis", vmin=0, vmax=np.log1p(vmax))
            covered = (grid >= cov["min_samples"]).mean()
            ax.set_title(f"{covered * 100:.0f}%", fontsize=8, color="red" if (r, c) == nxt else "black")
            if (r, c) == nxt:
                ax.spines["polar"].set_color("red")
                ax.spines["polar"].set_linewidth(2)
    fig.suptitle(
        f"normal-direction coverage per image region ({cov['covered_fraction'] * 100:.0f}% of bins)\n"
        f"press next (red): {cov['next_press']['indenter']} at u~{cov['next_press']['centre_uv'][0]:.0f}, "
        f"v~{cov['next_press']['centre_uv'][1]:.0f}" + _steep_line(cov.get("steep")),
        fontsize=9,
    )
    fig.tight_layout()
    return _save(fig, path)


def _steep_line(steep: dict | None) -> str:
    """The coverage figure's line on how steep the taught normals are ("" for reports without it)."""
    if not steep or steep.get("taught_tilt_deg") is None:
        return ""
    line = f"\n99% of taught normals within {steep['taught_tilt_deg']:.0f}° of the undeformed"
    if steep.get("untaught_from_deg") is not None:
        line += f"; none beyond {steep['untaught_from_deg']:.0f}°: press an object with steep relief"
    return line


def training_curve(history: list[dict], path, title: str = "NLiPsNet") -> Path:
    """Training loss and validation AAE per epoch, best epoch marked; epochs numbered from 1, as `nlips train` says.

    Parameters
    ----------
    history : list of dicts with epoch (0-based, as stored), train_loss, val_aae_deg, val_contact_aae_deg
    path : output .png
    """
    plt = _plt()
    ep = [h["epoch"] + 1 for h in history]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.2))
    a1.semilogy(ep, [h["train_loss"] for h in history])
    a1.set_xlabel("epoch")
    a1.set_ylabel("training loss 1 - n.n")
    a2.plot(ep, [h["val_aae_deg"] for h in history], label="validation, all samples")
    a2.plot(ep, [h["val_contact_aae_deg"] for h in history], label="validation, contact")
    best = min(history, key=lambda h: h["val_aae_deg"])
    a2.axvline(best["epoch"] + 1, color="0.5", ls="--", lw=1)
    a2.set_xlabel("epoch")
    a2.set_ylabel("AAE, deg")
    a2.legend(fontsize=8)
    a2.set_title(f"best epoch {best['epoch'] + 1}: {best['val_aae_deg']:.2f} deg", fontsize=9)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    return _save(fig, path)
