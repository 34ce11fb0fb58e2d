"""Where a box's (``--roi``) depth error lies, and what the anchors' weight and the rescale onto the reference do to it.

For each press folder (rendered by the twin: it needs gt.npz) and each anchor weight (``SolverOptions.anchor_weight``,
which ``tolerances.ROI_ANCHOR_GAIN`` multiplies in a box): ``solve_press(press, roi=ROI)``, its contact AAE
and depth RMSE, the solved-minus-true depth over the contact and over the box's outer 4-px ring, the depth scale
``anchoring.rescale_to_anchors`` applied (``report["anchor_scale"]``), and the depth RMSE without that rescale.

Usage: python benchmarks/bench_rim_depth.py PRESS [PRESS ...] [--reference REF] [--anchor-weights 1000,3000]
       [--roi X0 Y0 W H] (default: auto)

One JSON line per (press, weight); prints only (benchmarks/RESULTS.md, s31-rimdepth and s31-roiscale, has the runs).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import twin_presses  # noqa: E402

RING_PX = 4
"""Width of the box's outer ring whose depth offset is reported, pixels."""


def _row(press, reference, weight: float, roi: str | tuple[int, int, int, int] = "auto") -> dict:
    """The accuracy and depth offsets of ``press`` solved in the box ``roi`` at anchor weight ``weight``."""
    from nlipscalib.core import masks
    from nlipscalib.core.metrics import depth_rmse, evaluate
    from nlipscalib.solver import SolverOptions, solve_press

    cpu = time.process_time()
    result = solve_press(press, roi=roi, indirect=reference, options=SolverOptions(anchor_weight=weight))
    cpu = time.process_time() - cpu
    truth = press.ground_truth
    scored = result.reconstructed & truth.valid
    contact = scored & truth.contact
    ring = scored & ~masks.erode(result.mask, iterations=RING_PX)
    error = result.depth - truth.depth
    scale = result.report.get("anchor_scale")
    figures = evaluate(result, truth)["contact"]
    return {
        "press": press.folder.name,
        "anchor_weight": weight,
        "roi": result.report["roi"],
        "contact_aae_deg": round(figures["aae_deg"], 4),
        "contact_depth_rmse_mm": round(figures["depth_rmse_mm"], 4),
        "contact_offset_mm": round(float(np.mean(error[contact])), 4),
        "ring_offset_mm": round(float(np.mean(error[ring])), 4),
        "anchor_scale": scale,
        "depth_rmse_unscaled_mm": round(depth_rmse(result.depth / (scale or 1.0), truth.depth, contact), 4),
        "solve_cpu_s": round(cpu, 2),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presses", nargs="+", type=Path, help="press folders rendered by the twin (with gt.npz)")
    ap.add_argument("--reference", type=Path, help="the undeformed dome's capture (as nlips solve --reference)")
    ap.add_argument("--anchor-weights", default="1000", help="comma-separated SolverOptions.anchor_weight values")
    ap.add_argument("--roi", nargs=4, type=int, metavar=("X0", "Y0", "W", "H"), help="an explicit box (default: auto)")
    args = ap.parse_args()
    roi = tuple(args.roi) if args.roi else "auto"
    reference, presses = twin_presses(args.presses, args.reference)
    for _, press in presses:
        for weight in (float(w) for w in args.anchor_weights.split(",")):
            print(json.dumps(_row(press, reference, weight, roi)), flush=True)


if __name__ == "__main__":
    main()
