"""NLiPs solver: near-light photometric stereo on the capture's real (distorted) camera.

Never imports nlipscalib.sim or nlipscalib.device: it works from captures (``Press``) or plain arrays.
"""

from .calibrate import LedCalibration, calibrate_leds
from .contact import ContactMap, classify_contact
from .indirect import IndirectModel, fit_indirect
from .nlips import SolveResult, exclusions, solve
from .options import SolverOptions
from .press import solve_press

__all__ = [
    "ContactMap",
    "IndirectModel",
    "classify_contact",
    "fit_indirect",
    "LedCalibration",
    "SolveResult",
    "SolverOptions",
    "calibrate_leds",
    "exclusions",
    "solve",
    "solve_press",
]
