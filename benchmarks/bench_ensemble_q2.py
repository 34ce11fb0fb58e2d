"""Q2's scores of two trained NLiPsNets and of their ensemble (the normalised mean of their normals per sample).

Why: issue 8 asks whether averaging models of two training seeds brings the unseen split toward the goal. Each
model and the ensemble are scored by Q2's own code (:func:`nlipscalib.experiments.learning.score`, per split and per
test indenter as the report's tables), on the test presses a Q2 report names, so each model alone reproduces its
report's numbers (s35-ensemble, docs/experiments/RESULTS.md). Also how far apart the two models' normals are on the
contact samples: what averaging can remove at most.

Usage::

    PYTHONPATH=. python benchmarks/bench_ensemble_q2.py WORK/learned/nlipsnet-A.json WORK/learned/nlipsnet-B.json \
        --report REPORT/results.json [--out scores.json]

WORK is the Q2 work folder (its ``calibration/`` dataset and ``learned/`` models, as the records name them).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nlipscalib.core.metrics import aae
from nlipscalib.experiments import learning
from nlipscalib.experiments.q2 import _by_indenter
from nlipscalib.learn.dataset import CalibrationDataset


def ensemble(first: learning.Predictor, second: learning.Predictor) -> learning.Predictor:
    """(pixel, rgb) -> the normalised mean of the two predictors' unit normals."""

    def predict(pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        n = first(pixel, rgb) + second(pixel, rgb)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    return predict


def memo(predict: learning.Predictor) -> learning.Predictor:
    """``predict`` that runs once per input arrays (the ensemble and the model alone ask for the same samples)."""
    seen: dict[tuple, np.ndarray] = {}

    def cached(pixel: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        key = (pixel.shape, pixel.tobytes().__hash__(), rgb.tobytes().__hash__())
        if key not in seen:
            seen[key] = predict(pixel, rgb)
        return seen[key]

    return cached


def disagreement(data: CalibrationDataset, first, second, groups: dict[str, list[str]]) -> list[dict]:
    """Per group: AAE between the two models and of each against the true normals, on the true contact samples."""
    rows = []
    for key, names in groups.items():
        s = data.arrays(names)
        keep = s["contact"] & np.all(np.isfinite(s["true_normal"]), -1)
        a, b, t = (
            first(s["pixel"][keep], s["rgb"][keep]),
            second(s["pixel"][keep], s["rgb"][keep]),
            s["true_normal"][keep],
        )
        rows.append(
            {"group": key, "between_deg": aae(a, b), "first_vs_true_deg": aae(a, t), "second_vs_true_deg": aae(b, t)}
        )
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", nargs=2, type=Path, help="the two models' records (learned/nlipsnet-KEY.json)")
    ap.add_argument("--report", type=Path, required=True, help="a Q2 report's results.json (its test presses)")
    ap.add_argument("--out", type=Path, help="write the rows as JSON here")
    args = ap.parse_args()
    work = args.records[0].resolve().parent.parent
    names = json.loads(args.report.read_text(encoding="utf-8"))["learned"]["names"]
    data = CalibrationDataset(work / learning.DATASET_DIR)
    first, second = (
        memo(learning.net_predictor(work, json.loads(r.read_text(encoding="utf-8")), 1)) for r in args.records
    )
    labels = [r.stem.removeprefix("nlipsnet-") for r in args.records]
    predictors = {labels[0]: first, labels[1]: second, "ensemble": ensemble(first, second)}
    tests = {"seen": names["seen"], "unseen": names["unseen"]}
    groups = _by_indenter(data, tests)
    rows = learning.score(data, predictors, tests) + learning.score(data, predictors, groups)
    apart = disagreement(data, first, second, tests | groups)
    for r in rows:
        print(
            f"{r['split']:16s} {r['method']:36s} {r['contact_samples']:7d} "
            f"{r['aae_vs_nlips_deg']:.3f} / {r['aae_vs_true_deg']:.3f}"
        )
    for r in apart:
        print(
            f"{r['group']:16s} between {r['between_deg']:.2f}  vs truth "
            f"{r['first_vs_true_deg']:.2f} / {r['second_vs_true_deg']:.2f}"
        )
    if args.out:
        args.out.write_text(json.dumps({"scores": rows, "between": apart}, indent=1), encoding="utf-8")


if __name__ == "__main__":
    main()
