"""The figure of a measured camera response (``nlips calibrate-camera-response``): the curve per channel, the
measured points behind it, and the straight line of a linear camera to compare."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .figures import new_figure, save_png

CHANNEL_COLOURS = ("tab:red", "tab:green", "tab:blue")
DPI = 110
"""Resolution of the response figure (its 7-pt note line is 10.7 px tall)."""
POINTS_SHOWN = 4000
"""Measured points drawn at most (an evenly spaced subset): more only darkens the cloud."""


def response_figure(
    curve: np.ndarray,
    channels: np.ndarray,
    points: tuple[np.ndarray, np.ndarray],
    path: str | Path,
    title: str,
    note: str = "",
) -> Path:
    """Write the response figure to ``path`` (PNG, atomic).

    Parameters
    ----------
    curve : (N,) float, linear light (fraction of full scale) of each encoded value, N = 256: the curve kept; or
        (3, N), a curve kept per channel (R, G, B)
    channels : (N, 3) float, each channel's fitted curve (R, G, B), NaN where the channel saw no code
    points : (codes (M,), linear (M,)): measured samples, the bracket's estimate of their light
    path : the PNG to write
    title : the figure's title (the camera, the date)
    note : a line under the plot (fit residual, channel spread)
    """
    fig = new_figure(figsize=(6.4, 5.0))
    ax = fig.add_subplot(1, 1, 1)
    encoded = np.arange(np.shape(curve)[-1]) / (np.shape(curve)[-1] - 1)
    codes, linear = points
    step = max(1, len(codes) // POINTS_SHOWN)
    ax.scatter(
        codes[::step] / (len(encoded) - 1), linear[::step], s=2, c="0.6", alpha=0.5, label="measured (green)", lw=0
    )
    for c, colour in enumerate(CHANNEL_COLOURS):
        ax.plot(encoded, channels[:, c], color=colour, lw=0.8, alpha=0.8, label="RGB"[c])
    if np.ndim(curve) == 2:  # each channel keeps its own: drawn thick in its colour, the fits under them thin
        for c, colour in enumerate(CHANNEL_COLOURS):
            ax.plot(encoded, curve[c], color=colour, lw=1.6, label=f"kept ({'RGB'[c]})")
    else:
        ax.plot(encoded, curve, color="k", lw=1.6, label="kept (mean)")
    ax.plot([0, 1], [0, 1], color="0.4", lw=0.8, ls="--", label="linear camera")
    ax.set(xlim=(0, 1), ylim=(0, 1.02), xlabel="encoded value (fraction, black to white)")
    ax.set_ylabel("linear light (fraction of full scale)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper left", fontsize=8, markerscale=4)  # the cloud's 2-pt dots: too small to see in the key
    ax.grid(alpha=0.3)
    if note:
        fig.text(0.5, 0.01, note, ha="center", va="bottom", fontsize=7)
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    return save_png(fig, path, DPI)
