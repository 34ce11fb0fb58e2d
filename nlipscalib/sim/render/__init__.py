"""Mitsuba rendering of the digital twin: LED emitter, distorted camera, multi-LED integrator, GT.

Importing this package does not import mitsuba; :func:`load_mitsuba` does, on first use.
"""

from .surface import RenderResult, render_surface
from .variant import load_mitsuba, pick_variant

__all__ = ["RenderResult", "load_mitsuba", "pick_variant", "render_surface"]
