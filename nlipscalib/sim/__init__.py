"""The digital twin: parametric domes, indenters, elastomer indentation, Mitsuba 3 rendering.

Produces captures in the core format (nlipscalib.core.capture) with per-pixel ground truth.
Mitsuba is imported only when something renders.
"""
