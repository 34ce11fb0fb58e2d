"""NLiPs solver: near-light photometric stereo on the capture's real (distorted) camera.

Never imports nlipscalib.sim or nlipscalib.device: it works from captures (``Press``) or plain arrays.

Importing it imports no SciPy: its modules import ``scipy.sparse`` (~0.1 s of CPU, most of it SciPy 1.17's array-API
layer importing ``numpy.f2py``, ``numpy.testing`` and ``numpy.ma``) and ``scipy.sparse.linalg`` (~35 ms) in the
functions that use them, so a command that imports the solver without solving (``nlips solve`` reusing a result:
0.27 -> 0.16 s) does not wait for them. ``nlips solve`` imports both beside the press's PNG decoding (cli/solve.py),
pyamg's background import the rest (:func:`.krylov.import_amg_in_background`).
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
