"""Pictures people look at (matplotlib, like the paper's figures), used by the CLI.

Computing packages (sim/, solver/, learn/, device/) return arrays; only this package draws them.
One module per subject: ``figures`` holds the shared building blocks (normal-map colouring, panels,
contact sheets).
"""

from .figures import Panel, contact_sheet, display_image, normals_to_rgb

__all__ = ["Panel", "contact_sheet", "display_image", "normals_to_rgb"]
