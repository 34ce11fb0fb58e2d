"""Pictures people look at, used by the CLI.

Computing packages (sim/, solver/, learn/, device/) return arrays; only this package draws them.
One module per subject: ``figures`` holds the matplotlib building blocks (normal-map colouring,
panels, contact sheets), ``maps`` the cheap OpenCV maps (normal, scalar with colour bar),
``reconstruction`` the figures of one reconstruction, and ``live`` the pictures of a live stream (its window, its
saved normal maps; imported from there).
"""

from .figures import Panel, contact_sheet, display_image, normals_to_rgb
from .maps import normal_map_png, scalar_map_png
from .reconstruction import (
    FIGURE_LEVELS,
    error_map,
    figure_level,
    figures_missing,
    figures_problem,
    write_reconstruction_figures,
)

__all__ = [
    "FIGURE_LEVELS",
    "Panel",
    "contact_sheet",
    "display_image",
    "error_map",
    "figure_level",
    "figures_missing",
    "figures_problem",
    "normal_map_png",
    "normals_to_rgb",
    "scalar_map_png",
    "write_reconstruction_figures",
]
