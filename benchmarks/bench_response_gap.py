"""The LED pairs' check of a camera-response curve over noise seeds (s32-devleft): on the emulated sensor, right
cameras, cameras whose times are a power of the asked ones (``0.5 (t / 0.5) ** a`` ms when asked t) and LED pairs
lit together at ``droop`` times their light apart (a shared supply that sags). One JSON line a run: the misfit as
fitted (``before``), the median of every pair's and mix's signed error (``common``: a pair that dims as a whole
moves it, s33-bracket), the two mixes' gap as fitted and once the best power is pinned (``best_gap``: what
``tolerances.RESPONSE_ADDITIVITY_GAP`` judges), the best power, and what ``device.additivity.pin_power`` does
(kept, pinned, refused)::

    PYTHONPATH=. python benchmarks/bench_response_gap.py --seeds 10 --size 64x48x1 \\
        --curves none,gamma2.2,s-curve,srgb,rgb-gammas \\
        --cases "1,1;0.9,1;0.95,1;1.05,1;1.1,1;1,0.98;1,0.985;1,0.99;1,1.02" > gap.jsonl
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests.device.fakes: the skewed emulated camera


def _run(size: tuple[int, int, int], curve: str, seed: int) -> dict:
    from scipy.optimize import minimize_scalar

    from nlipscalib.cli import camera_response as cr
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.device.additivity import _gap, pair_bins, pair_errors, pin_power
    from nlipscalib.device.response_fit import fit_response

    w, h, spp = size
    args = argparse.Namespace(
        emulate="nlipstac", width=w, height=h, spp=spp, led=1, level=255, seed=seed,
        emulate_tone_curve=None if curve == "none" else curve,
    )  # fmt: skip
    codes, source, _, _, _, shots = cr._emulated_bracket(args, cr.DEFAULT_EXPOSURES_MS)
    fit = fit_response(codes, cr.DEFAULT_EXPOSURES_MS, source)
    curves = np.broadcast_to(fit.kept, (3, 256))
    bins = pair_bins(curves, shots)
    errors = pair_errors(curves, shots, bins)
    finite = [e for pair in errors for e in pair[2:] if np.isfinite(e)]
    rec = {"before": max(abs(e) for e in finite), "gap_as_fitted": _gap(errors), "common": float(np.median(finite))}
    try:
        _, check = pin_power(curves, shots, source)
        rec.update(outcome="kept" if check.power == 1.0 else "pinned", power=check.power, gap=check.gap)
    except CaptureError:
        rec["outcome"] = "refused"

    def misfit(power: float) -> float:
        return float(np.nansum(np.square([e for q in pair_errors(curves**power, shots, bins) for e in q[2:]])))

    best = float(minimize_scalar(misfit, bounds=(0.5, 2), method="bounded", options={"xatol": 1e-4}).x)
    rec.update(best_power=best, best_gap=_gap(pair_errors(curves**best, shots, bins)))
    return rec


def main() -> None:
    from nlipscalib import emulator
    from tests.device.fakes import skewed_emulated_camera

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=5)
    p.add_argument("--size", default="64x48x1", help="emulated WxHxSPP")
    p.add_argument("--curves", default="none,gamma2.2,s-curve,srgb,rgb-gammas")
    p.add_argument("--cases", default="1,1;0.95,1;1,0.98", help="POWER,DROOP;...")
    args = p.parse_args()
    size = tuple(int(v) for v in args.size.split("x"))
    real = emulator.EmulatedCamera
    for case in args.cases.split(";"):
        power, droop = (float(v) for v in case.split(","))
        emulator.EmulatedCamera = real  # the fake subclasses the class installed: one case's faults, not all so far
        emulator.EmulatedCamera = skewed_emulated_camera(power, droop)
        for curve in args.curves.split(","):
            for seed in range(args.seeds):
                rec = {"power_of_times": power, "droop": droop, "curve": curve, "seed": seed, **_run(size, curve, seed)}
                print(json.dumps({k: round(v, 5) if isinstance(v, float) else v for k, v in rec.items()}), flush=True)
    emulator.EmulatedCamera = real


if __name__ == "__main__":
    main()
