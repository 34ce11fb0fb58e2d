"""How much of a press's ground-truth contact ``--roi auto`` boxes, how much those left out matter, and the box margin.

For each press folder (rendered by the twin: it needs gt.npz): the auto box of ``solve_press(press, roi="auto")``,
the share of the truth's contact it holds -- all of it, and only the pixels whose normal the press tilts by more than
1 and 2 deg from the undeformed surface's (``reference.npz``) -- and the contact AAE over the boxed truth. With
``--whole`` the press is also solved on the whole gel, and the truth left out of the box is scored twice: the whole
solve's normals there, and the undeformed surface's (what the box leaves the user). ``--margins`` solves at other
margins of the box around the contact's misfit (``contact_roi.contact_box``'s ``margin``, 8 px; not a user option:
the script sets its default for the experiment) and reports the in-process solve time of each.

Usage: python benchmarks/bench_auto_roi.py PRESS [PRESS ...] [--reference REF] [--whole] [--margins 8,16]

One JSON line per (press, margin); prints only (benchmarks/RESULTS.md, s31-autobox, has the runs).
"""

from __future__ import annotations

import argparse
import functools
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import twin_presses  # noqa: E402

TILTS_DEG = (1.0, 2.0)
"""Truth pixels tilted by more than these (deg) from the undeformed surface are counted apart: the solve's contact AAE
is 0.4-0.7 deg, so a pixel tilted less is as well described by the undeformed surface as by a solve."""


def _solve(press, reference, roi, margin: int):
    """(SolveResult, seconds of CPU, seconds of wall) of ``press`` with ``--roi auto``'s margin ``margin``."""
    from nlipscalib.solver import press as press_solve
    from nlipscalib.solver.contact_roi import contact_box

    default = press_solve.contact_box
    press_solve.contact_box = functools.partial(contact_box, margin=margin)
    try:
        cpu, wall = time.process_time(), time.perf_counter()
        result = press_solve.solve_press(press, roi=roi, indirect=reference)
        return result, time.process_time() - cpu, time.perf_counter() - wall
    finally:
        press_solve.contact_box = default


def _row(press, reference, margin: int, whole) -> dict:
    """The box, the truth it holds and the contact AAE of ``press`` at ``margin``; ``whole``: its whole-gel solve."""
    from nlipscalib.core.metrics import aae, angle_deg, evaluate

    result, cpu, wall = _solve(press, reference, "auto", margin)
    truth = press.ground_truth
    contact = truth.contact & truth.valid
    boxed = contact & result.mask
    tilt = angle_deg(truth.normals, press.reference.normals)
    row = {
        "press": press.folder.name,
        "margin": margin,
        "roi": result.report["roi"],
        "truth_px": int(contact.sum()),
        "boxed": round(float(boxed.sum() / max(contact.sum(), 1)), 4),
        "contact_aae_deg": round(evaluate(result, truth)["contact"]["aae_deg"], 4),
        "solve_cpu_s": round(cpu, 2),
        "solve_wall_s": round(wall, 2),
    }
    for deg in TILTS_DEG:
        tilted = contact & (tilt > deg)
        row[f"boxed_tilted_over_{deg:g}deg"] = round(float((tilted & result.mask).sum() / max(tilted.sum(), 1)), 4)
    left = contact & ~result.mask
    if left.any():
        row["left_out_tilt_deg_p50_p90_max"] = [round(float(v), 2) for v in np.percentile(tilt[left], [50, 90, 100])]
        row["left_out_aae_undeformed_deg"] = round(aae(press.reference.normals, truth.normals, left), 3)
        if whole is not None:
            row["left_out_aae_whole_solve_deg"] = round(aae(whole.normals, truth.normals, left), 3)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("presses", nargs="+", type=Path, help="press folders rendered by the twin (with gt.npz)")
    ap.add_argument("--reference", type=Path, help="the undeformed dome's capture (as nlips solve --reference)")
    ap.add_argument("--whole", action="store_true", help="also solve the whole gel: the left-out truth's AAE there")
    ap.add_argument("--margins", default="8", help="comma-separated box margins, px (the default's: 8)")
    args = ap.parse_args()
    reference, presses = twin_presses(args.presses, args.reference)
    for _, press in presses:
        whole = _solve(press, reference, None, 8)[0] if args.whole else None
        for margin in (int(m) for m in args.margins.split(",")):
            print(json.dumps(_row(press, reference, margin, whole)), flush=True)


if __name__ == "__main__":
    main()
