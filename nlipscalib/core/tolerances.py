"""Numerical tolerances used across the workbench, in one place (as trimesh does)."""

CONTACT_MM = 1e-3
"""A gel vertex displaced by more than this (mm) is in contact / deformed."""
MIN_LEDS_PER_PIXEL = 3
"""A pixel needs at least this many usable (lit, unsaturated) LEDs to be reconstructed."""
NORMAL_EPS = 1e-9
"""Norms below this are treated as zero when normalising."""
EXPERIMENT_CHECK_ABS = {"aae_deg": 0.5, "mabse": 0.005, "depth_rmse_mm": 0.05}
"""``nlips experiment --check``: an accuracy figure is worse when it exceeds the baseline by more than
max(this absolute amount, EXPERIMENT_CHECK_REL x baseline) (units: degrees, unitless, mm)."""
EXPERIMENT_CHECK_REL = 0.10
"""Relative part of the ``--check`` tolerance (fraction of the baseline value)."""
