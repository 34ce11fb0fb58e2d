"""The LED fits' Jacobian: the image model's analytic derivatives (core/leds_jacobian.py) against scipy's finite
differences (``jac="2-point"``: 9 model evaluations a trf step), on one reference's samples.

Fits each LED of a reference (its true LEDs moved 0.3 mm and a few deg, as a converged point fit leaves a disk's start)
as a disk of the given radius and as a point, on at most ``calibration_term.DISK_FIT_SAMPLES`` samples as the disk
fits of ``nlips calibrate-leds`` are, both ways in turn; prints process CPU a fit round (12 LEDs), the trf steps,
and the largest difference of the fitted LEDs. One BLAS thread, as ``fit_leds`` runs.
Usage: python benchmarks/bench_led_jacobian.py REFERENCE [--rounds 3] [--radius 1.8]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import scipy.optimize  # noqa: E402

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.leds import Led  # noqa: E402
from nlipscalib.solver.calibration_term import DISK_FIT_SAMPLES  # noqa: E402
from nlipscalib.solver.led_fit import capture_samples, disk_model, fit_leds, point_model  # noqa: E402

_least_squares = scipy.optimize.least_squares


def _counting(finite_differences: bool, steps: list[int]):
    """scipy's least_squares, counting its Jacobians, with scipy's own finite differences when asked."""

    def least_squares(*args, **kwargs):
        if finite_differences:
            kwargs.pop("jac", None)
        res = _least_squares(*args, **kwargs)
        steps.append(res.njev)
        return res

    return least_squares


def moved(leds, rng) -> list[Led]:
    out = []
    for led in leds:
        offset = rng.normal(size=3)
        axis = np.asarray(led.direction) + np.radians(3.0) * np.cross(led.direction, rng.normal(size=3))
        out.append(Led(tuple(np.add(led.position, 0.3 * offset / np.linalg.norm(offset))), tuple(axis), led.mu))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("reference", type=Path)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--radius", type=float, default=1.8)
    args = parser.parse_args()
    press = load_press(args.reference)
    x, n, img, ok, _ = capture_samples(press, press, len(press.leds), 2)
    every = slice(None, None, -(-len(x) // DISK_FIT_SAMPLES))
    x, n, img, ok = x[every], n[every], img[:, every], ok[:, every]
    start = moved(press.leds, np.random.default_rng(0))
    print(f"{args.reference}: {len(x)} samples, {len(start)} LEDs")
    for name, model in (("disk", disk_model(args.radius)), ("point", point_model)):
        cpu: dict[str, list[float]] = {"analytic": [], "finite differences": []}
        fits, steps = {}, {}
        for _ in range(args.rounds):
            for way in cpu:
                steps[way] = []
                scipy.optimize.least_squares = _counting(way != "analytic", steps[way])
                t = time.process_time()
                fits[way] = fit_leds(start, x, n, img, ok, "cauchy", model)
                cpu[way].append(time.process_time() - t)
        scipy.optimize.least_squares = _least_squares
        a, f = (np.array([p for p, _, _ in fits[w]]) for w in cpu)
        for way, times in cpu.items():
            print(
                f"{name} {way}: CPU {np.median(times):.2f} s [{min(times):.2f}-{max(times):.2f}] a round, "
                f"{sum(steps[way])} Jacobians"
            )
        gap = np.abs(a - f)
        print(f"{name}: largest parameter difference {gap.max():.1e} (position {gap[:, 6:].max():.1e} mm)")


if __name__ == "__main__":
    main()
