"""What the API's entry checks cost (s38-apikinds): one ``SolverOptions()`` (its fields checked by their annotated
kinds, ``core.config.check_field_kinds``; a solve makes ~7) and ``solver.press_checks.check_keywords`` of every
``solve_press`` keyword. Prints the median wall per call of 5 repeats, microseconds.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_api_entry_checks.py`` (on a tree before s38-apikinds only the first
line is printed: it had no keyword check).
"""

from __future__ import annotations

import argparse
import statistics
import timeit

from nlipscalib.solver import SolverOptions

CALLS = 2000


def _median_us(call) -> float:
    return statistics.median(timeit.repeat(call, number=CALLS, repeat=5)) / CALLS * 1e6


def main() -> None:
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0]).parse_args()
    print(f"SolverOptions(): {_median_us(SolverOptions):.1f} us")
    try:
        from nlipscalib.solver.press import KEYWORDS
        from nlipscalib.solver.press_checks import check_keywords
    except ImportError:  # a tree before s38-apikinds
        return
    every = {
        "roi": "auto", "progress": False, "dent_interreflection": True, "coating_albedo": (0.8, 0.8, 0.8),
        "interreflection": "auto", "bounces": 1, "max_outer": 2, "outer_relaxation": "auto", "check_sensor": True,
        "reorder_leds": True, "light_gain": (1.0, 1.0, 1.0), "led_radius": 1.8,
    }  # fmt: skip
    print(f"check_keywords(every keyword): {_median_us(lambda: check_keywords(every, KEYWORDS)):.1f} us")


if __name__ == "__main__":
    main()
