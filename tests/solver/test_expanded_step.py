"""The expanding line search (:func:`nlipscalib.solver.gauss_newton.expanded_step`): a doubled Gauss-Newton step
where the step's actual energy decrease beat its model's prediction by a wide margin."""

import pytest

from nlipscalib.solver import SolverOptions
from nlipscalib.solver.gauss_newton import expanded_step


def _newton(energy, x0: float, g: float, h_model: float):
    """The Gauss-Newton step of a 1-D model with gradient g and curvature h_model at x0: (trial, full trial,
    start energy, predicted decrease); a trial is (x, energy)."""
    delta = -g / h_model
    predicted = -g * delta - 0.5 * h_model * delta**2
    calls = []

    def trial(alpha: float) -> tuple:
        calls.append(alpha)
        x = x0 + alpha * delta
        return x, energy(x)

    full = (x0 + delta, energy(x0 + delta))
    return trial, full, energy(x0), predicted, calls


def _quadratic(x: float) -> float:
    return (x - 3.0) ** 2


@pytest.mark.parametrize("ratio", [1.01, 1.5, 4.0])
def test_never_tried_where_the_model_is_exact(ratio):
    """A quadratic with its own curvature: the actual decrease equals the prediction, nothing to expand."""
    trial, full, e0, predicted, calls = _newton(_quadratic, 0.0, g=-6.0, h_model=2.0)
    assert e0 - full[1] == pytest.approx(predicted)
    assert expanded_step(trial, full, e0, predicted, ratio) is full
    assert calls == []


def test_the_doubled_step_is_taken_where_the_model_is_too_stiff_and_it_is_better():
    """The model's curvature 4x the energy's (as IRLS weights overestimate a robust loss's): the step is a quarter
    of the way, the decrease 1.75x the prediction; the doubled step lands lower."""
    trial, full, e0, predicted, calls = _newton(_quadratic, 0.0, g=-6.0, h_model=8.0)
    assert (e0 - full[1]) / predicted == pytest.approx(1.75)
    x, e = expanded_step(trial, full, e0, predicted, 1.5)
    assert calls == [2.0] and x == pytest.approx(1.5) and e < full[1]
    # the same step below the ratio: not tried
    assert expanded_step(trial, full, e0, predicted, 2.0) is full and calls == [2.0]


def test_the_full_step_is_kept_where_the_doubled_one_is_worse():
    """One Cauchy residual far out: the IRLS step lands on its minimum with 4.7x the predicted decrease (above the
    default ratio); doubling overshoots back to the start's energy and is refused."""
    import math

    def cauchy(x: float) -> float:
        return 0.5 * math.log1p((x - 10.0) ** 2)

    weight = 1.0 / (1.0 + 10.0**2)
    trial, full, e0, predicted, calls = _newton(cauchy, 0.0, g=weight * -10.0, h_model=weight)
    ratio = SolverOptions().line_search_expand
    assert (e0 - full[1]) / predicted > ratio
    assert expanded_step(trial, full, e0, predicted, ratio) is full
    assert calls == [2.0]


def test_off_at_zero():
    trial, full, e0, predicted, calls = _newton(_quadratic, 0.0, g=-6.0, h_model=8.0)
    assert expanded_step(trial, full, e0, predicted, 0.0) is full and calls == []
