"""NLiPs solver options: a frozen dataclass that :func:`nlipscalib.core.config.from_mapping` fills from TOML/YAML."""

from __future__ import annotations

import dataclasses
from typing import Literal

from ..core import tolerances
from ..core.config import check_field_kinds
from ..core.errors import ConfigError

Estimator = Literal["cauchy", "ls", "huber", "tukey"]
Normals = Literal["depth", "refined"]
SmoothDeformation = Literal["auto", "on", "off"]


@dataclasses.dataclass(frozen=True)
class SolverOptions:
    """Numerical settings of :func:`nlipscalib.solver.solve`."""

    estimator: Estimator = "cauchy"
    """Robust estimator of the data term: cauchy (default), ls (least squares), huber or tukey."""
    robust_scale: float = 3.0
    """Estimator scale lambda = robust_scale * 1.4826 * MAD(residuals), set at the start of each pyramid level."""
    robust_floor: float = 0.02
    """Lower bound of lambda relative to the median usable intensity, so exact data is not over-trimmed."""
    prior_weight: float = 1e-3
    """zeta: weight of the depth prior sum (log z - log z0)^2, with images normalised to a 99th percentile of 1."""
    anchor_weight: float = 1000.0
    """Multiplier of zeta on pixels that the capture shows undeformed (:func:`solve_press` with a
    reference): near light fixes absolute depth only weakly, and in a small ROI the depth scale drifts
    (a coin press came out 5 % too close); the undeformed gel around the contact pins it. 0 = off."""
    anchor_threshold: float = 1.5
    """A pixel counts as undeformed when its contact misfit is at most this times the median misfit."""
    smoothness: float = 1e-3
    """gamma: weight of squared second differences of log-depth, relative to the data term's gradient
    curvature; tiny, it only ties together the pixel sub-lattices that central differences decouple."""
    noise_smoothness: float = 25.0
    """Smoothness added per squared relative image noise: gamma = max(smoothness, noise_smoothness *
    (sigma / median image level)^2), sigma estimated from the images (Immerkaer 1996), so noisy data
    (one-bounce twin renders: ~6 % per pixel -> gamma ~0.1) are regularised and exact data are not.
    Applied by :func:`solve_press`; 0 = off."""
    smoothness_edge: float = 0.15
    """Edge-preserving smoothness: a second difference of log-depth is penalised quadratically while the
    surface's slope (tan of its tilt from the ray) changes by up to about this much per pixel, and only
    logarithmically beyond (a Cauchy penalty of that scale, :mod:`nlipscalib.solver.smoothness`). Why: the
    squared penalty flattened the walls of a relief a pixel or two wide (a coin's rim and strokes, steps of
    0.3-0.5 mm) and left the demo's coin face 0.18 mm too shallow; noise and smooth indenters (a few hundredths
    per pixel) stay in its quadratic part. 0 = squared everywhere (the solver before s32)."""
    smooth_deformation: SmoothDeformation = "auto"
    """What the smoothness penalises the second differences of: "on", the deformation, log-depth minus the prior's
    (:class:`nlipscalib.solver.smoothness.Smoothness`' ``about``), where the prior is a surface (a reference's depth;
    the ``nominal_distance`` guess is not one: there, of log-depth); "off", of log-depth itself (the solver before
    s33); "auto" (default), "on" where the camera sees past the gel (the prior's gel covers less than
    ``tolerances.GEL_FRAME_SHARE_PAST_GEL`` of the frame), else "off". Why: the dome's own curvature in log-depth was
    pulled straight where the light holds the depth weakly: a view that sees the dome down to its base (lit at 0.15 of
    the gel's median there) solved its outer 2-4 px 5-10 deg off, exact data included; on the gel-filling view "on"
    moved the contact AAE by -0.005 to +0.006 deg, so that view keeps its bits (benchmarks/RESULTS.md, s33-rimedge)."""
    nominal_distance: float = 15.0
    """Camera-to-surface distance along each ray, mm, used as prior when the capture has no reference."""
    pyramid_levels: int = 0
    """Number of pyramid levels (0 = automatic: halve until the short side is below 2 * min_level_size)."""
    min_level_size: int = 24
    """Smallest short side of the coarsest level, pixels (automatic pyramid)."""
    max_iters: int = 30
    """Iteration cap per pyramid level (one iteration = albedo update + Gauss-Newton step on log-depth)."""
    energy_rtol: float = 1e-3
    """Stop a level when the relative energy decrease, or the decrease its Gauss-Newton model predicts for
    the next step, falls below this. 1e-3: on the default twin's 640x480 presses the step that 1e-4 adds
    on the finest level moved the normals by 0.013 deg (median) at ~1.5 s, and the contact AAE stayed
    within 0.01 deg (benchmarks/RESULTS.md)."""
    seed_energy_rtol: float = 1e-2
    """``energy_rtol`` of a solve from the prior that leaves its finest levels unrefined
    (:func:`nlipscalib.solver.solve` with ``unrefined`` > 0 and no ``init_depth``: the outer interreflection loop's
    first pass, which only seeds its first gather and the passes after it). 1e-2: on the default twin's 640x480
    one-bounce presses it saves a Gauss-Newton step on most of that pass's levels (two on the coin's and the screw's)
    that moved the median normal by 0.001-0.01 deg; contact AAE, MabsE and depth RMSE of six presses in three modes
    stayed within noise of 1e-3. Not the warm-started passes after it: there the screw's whole-frame contact AAE rose
    0.03-0.05 deg (benchmarks/RESULTS.md, s20-passes)."""
    normal_tol_deg: float = 1e-3
    """Stop a level when the median normal change of an iteration falls below this, degrees."""
    cg_rtol: float = 1e-4
    """Relative residual tolerance of the preconditioned conjugate gradient."""
    cg_rtol_max: float = 0.1
    """Loosest CG tolerance (inexact Newton forcing term): early Gauss-Newton steps, whose linear model
    is itself inaccurate, are solved to this; the tolerance tightens toward ``cg_rtol`` with the gradient."""
    cg_jacobi_iters: int = 30
    """CG iterations tried with a Jacobi preconditioner before building an AMG hierarchy (0: AMG only)."""
    cg_maxiter: int = 200
    """Iteration cap of the conjugate gradient."""
    line_search_steps: int = 8
    """Step halvings tried before a Gauss-Newton step is rejected (energy must not increase)."""
    line_search_expand: float = 4.0
    """When a full Gauss-Newton step lowers the energy by more than this times the decrease its model predicted, the
    doubled step is tried too and kept if it lowers the energy further (0 = off). "Predicted" as the solver computes it:
    half the quadratic model's decrease of the energy, whose gradient and normal matrix the solver holds halved (so 4
    asks for twice the model's own decrease; the ratios below are in the same units). The robust loss's IRLS model
    overestimates the curvature where residuals sit in the loss's bend: on relief (the default twin's coin presses) the
    actual decrease ran 4.6-7.7x the prediction in the finest level's linearly converging tail, and the doubled step
    saved a Gauss-Newton step there (benchmarks/RESULTS.md, s23-gn). 4: the smooth and flat-faced presses' steps stay
    below it (2.3-2.9x), so they never try it; a doubled step won on every large level where it was tried but one."""
    shadow_level: float = 0.01
    """Observed intensity below this fraction of the LED image's 99th percentile is shadow: excluded."""
    dead_led_level: float = tolerances.LIT_LEVEL
    """An LED whose image's 99th percentile (linear, full scale 1) is below this is dead: excluded from the
    Gauss-Newton fit and from :func:`nlipscalib.solver.solve_press`'s contact classification (auto ROI,
    anchoring)."""
    dead_pixel_level: float = 1e-4
    """A pixel at or below this in every LED image and channel is dead: excluded."""
    min_leds: int = tolerances.MIN_LEDS_PER_PIXEL
    """A pixel needs this many usable LEDs to be reconstructed; others are reported, not filled."""
    dtype: Literal["float32", "float64"] = "float32"
    """Floating point type of the per-pixel shading, residual and Jacobian computations (the sparse
    system is always assembled and solved in float64; energies are summed in float64). float32 halves
    the memory traffic of these (L, 3, N) arrays and gives the same depth and normals to well below
    the noise of a 16-bit image."""
    normals: Normals = "depth"
    """Which normals the result holds: "depth" (the gradient of the solved depth) or "refined" (each pixel's
    normal refitted to its own images at the solved point where they reject the depth's,
    :mod:`nlipscalib.solver.refine`; the depth kept). "refined" is for steep relief with walls a pixel or two
    wide: the default twin's 640x480 coin presses 4.7 -> 3.8-4.0 deg contact AAE, smooth indenters unchanged
    (benchmarks/RESULTS.md)."""

    def __post_init__(self):
        check_field_kinds(self, "solver")  # a number's kind before its range: "2" failed in Python's "<" below
        self._check_finite()
        positive = (
            "robust_scale",
            "nominal_distance",
            "energy_rtol",
            "seed_energy_rtol",
            "normal_tol_deg",
            "cg_rtol",
            "cg_rtol_max",
        )
        for name in positive:
            if not getattr(self, name) > 0:
                raise ConfigError(f"solver.{name} must be > 0, got {getattr(self, name)}")
        weights = (self.prior_weight, self.robust_floor, self.smoothness, self.anchor_weight, self.noise_smoothness)
        if min(*weights, self.smoothness_edge) < 0:
            raise ConfigError(
                "solver.prior_weight, solver.smoothness, solver.noise_smoothness, solver.smoothness_edge, "
                "solver.robust_floor and solver.anchor_weight must be >= 0"
            )
        if self.max_iters < 1 or self.cg_maxiter < 1 or self.line_search_steps < 0 or self.cg_jacobi_iters < 0:
            raise ConfigError(
                "solver.max_iters and solver.cg_maxiter must be >= 1, line_search_steps and cg_jacobi_iters >= 0"
            )
        if not (self.line_search_expand == 0 or self.line_search_expand >= 1):
            raise ConfigError(f"solver.line_search_expand must be 0 (off) or >= 1, got {self.line_search_expand}")
        if self.pyramid_levels < 0 or self.min_level_size < 4:
            raise ConfigError("solver.pyramid_levels must be >= 0 and solver.min_level_size >= 4")
        if self.min_leds < 1:
            raise ConfigError(f"solver.min_leds must be >= 1, got {self.min_leds}")
        if self.estimator not in ("cauchy", "ls", "huber", "tukey"):
            raise ConfigError(f"solver.estimator must be cauchy, ls, huber or tukey, got {self.estimator!r}")
        # image levels are linear with full scale 1: an LED whose images stay below 1 everywhere is no
        # evidence of a dead LED, and a threshold of 1 or more marks every LED dead (nothing left to solve)
        if not 0 <= self.dead_led_level < 1:
            raise ConfigError(f"solver.dead_led_level must be in [0, 1) of full scale, got {self.dead_led_level}")
        if self.normals not in ("depth", "refined"):
            raise ConfigError(f"solver.normals must be depth or refined, got {self.normals!r}")
        if self.smooth_deformation not in ("auto", "on", "off"):
            raise ConfigError(f"solver.smooth_deformation must be auto, on or off, got {self.smooth_deformation!r}")
        if self.anchor_threshold < 0:
            raise ConfigError(f"solver.anchor_threshold must be >= 0, got {self.anchor_threshold}")

    def _check_finite(self) -> None:
        """Every float option finite: an infinite weight passed the ">= 0" checks and filled the solve with
        NaN (numpy's "invalid value encountered in multiply"), and NaN fails no comparison at all."""
        import math

        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            if isinstance(value, float) and not math.isfinite(value):
                raise ConfigError(f"solver.{field.name} must be a finite number, got {value}")
