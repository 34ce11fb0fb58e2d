"""Normal error by distance from the gel's edge: how a whole-frame solve of a view that sees past the gel fares there.

For each (press folder rendered by the twin, with gt.npz; result folder of ``nlips solve``): the mean normal error
(deg) off the contact in bins of distance from the gel's outline (``gt.npz`` ``valid``; the outermost gel pixel is at
distance 1), the contact AAE, the whole gel's AAE, the mean confidence in the outer 2 px against the rest, and the
depth RMSE off the contact (mm).

Usage: python benchmarks/bench_rim_edge.py PRESS RESULT [PRESS RESULT ...]

One JSON line per pair; prints only (benchmarks/RESULTS.md, s33-rimedge, has the runs).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

EDGE_BINS_PX = (0, 1, 2, 3, 4, 6, 8, 16, np.inf)
"""Bin edges of the distance from the gel's outline, pixels (a bin holds lo < distance <= hi)."""


def _row(press_folder: Path, result_folder: Path) -> dict:
    """The scores of one result against its press's ground truth."""
    from scipy import ndimage

    from nlipscalib.core import load_press
    from nlipscalib.core.metrics import angle_deg
    from nlipscalib.core.reconstruction import load_reconstruction

    truth = load_press(press_folder).ground_truth
    result = load_reconstruction(result_folder, truth.valid.shape)
    scored = truth.valid & result.reconstructed
    error = np.full(truth.valid.shape, np.nan)
    error[scored] = angle_deg(result.normals[scored], truth.normals[scored])
    distance = ndimage.distance_transform_edt(truth.valid)
    off = scored & ~truth.contact
    bins = {}
    for lo, hi in zip(EDGE_BINS_PX[:-1], EDGE_BINS_PX[1:]):
        inside = off & (distance > lo) & (distance <= hi)
        bins[f"{lo:g}-{hi:g}"] = round(float(error[inside].mean()), 3) if inside.any() else None
    depth_error = (result.depth - truth.depth)[off]
    outer = scored & (distance <= 2)
    return {
        "press": press_folder.name,
        "result": str(result_folder),
        "off_contact_aae_by_edge_px": bins,
        "contact_aae_deg": round(float(error[scored & truth.contact].mean()), 4),
        "gel_aae_deg": round(float(error[scored].mean()), 4),
        "off_contact_depth_rmse_mm": round(float(np.sqrt(np.mean(depth_error**2))), 4),
        "confidence_outer_2px": round(float(result.confidence[outer].mean()), 3),
        "confidence_rest": round(float(result.confidence[scored & ~outer].mean()), 3),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("pairs", nargs="+", type=Path, help="PRESS RESULT pairs (a twin press folder, an nlips solve out)")
    args = ap.parse_args()
    if len(args.pairs) % 2:
        ap.error("give PRESS RESULT pairs")
    for press, result in zip(args.pairs[::2], args.pairs[1::2]):
        print(json.dumps(_row(press, result)), flush=True)


if __name__ == "__main__":
    main()
