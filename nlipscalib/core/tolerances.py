"""Numerical tolerances used across the workbench, in one place (as trimesh does)."""

CONTACT_MM = 1e-3
"""A gel vertex displaced by more than this (mm) is in contact / deformed."""
MIN_LEDS_PER_PIXEL = 3
"""A pixel needs at least this many usable (lit, unsaturated) LEDs to be reconstructed."""
NORMAL_EPS = 1e-9
"""Norms below this are treated as zero when normalising."""
