"""CPU cost of one 640x480 frame through two NLiPsNets averaged, against one (the Predictor, torch backend).

Why: issue 8's ensemble of two training seeds would run the network twice per frame. The frame's change rule,
prefilter and depth integration are the same for both nets and done once; only the network runs twice, on the same
changed pixels' inputs. One net: ``Predictor.predict`` as ``nlips infer`` runs it; two: the same stages with both
nets (the first Predictor's steps, the second's network), alternating with the one-net frame (``--rounds`` pairs).
Wall and process CPU per frame (ms), median [range]; the network stage of the one-net frame too.

Usage::

    PYTHONPATH=. python benchmarks/bench_ensemble_infer.py A.pt B.pt PRESS [PRESS ...] [--rounds 9] [--threads 1]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from nlipscalib.core.capture import load_press
from nlipscalib.learn.infer import Predictor
from nlipscalib.learn.integrate import integrate_on_dome


def two_nets(a: Predictor, b: Predictor, tricolor: np.ndarray) -> int:
    """One frame with the normalised mean of both nets' normals on the changed pixels; returns their count."""
    changed = a.changed(tricolor)
    normals = a.ref_normals.copy()
    index = np.flatnonzero(changed)
    x = np.empty((len(index), 5), np.float32)
    row, col = np.divmod(index, a.shape[1])
    x[:, 1], x[:, 0] = row, col
    x[:, 2:] = a._colours(tricolor, row, col)  # the prefiltered colours, as Predictor.predict makes them
    if a.model.input_reference is not None:  # over the reference's, as Predictor.predict gives a ratio model them
        x[:, 2:] /= a.model.input_reference[row, col]
    mean = a._run(x) + b._run(x)
    normals.reshape(-1, 3)[index] = mean / np.linalg.norm(mean, axis=-1, keepdims=True)
    integrate_on_dome(normals, changed, a.geo)
    return len(index)


def timed(fn) -> tuple[float, float, object]:
    """(wall s, process CPU s, result) of ``fn()``."""
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - w, time.process_time() - c, out


def spread(values: list[float]) -> str:
    ms = 1e3 * np.asarray(values)
    return f"{np.median(ms):.1f} [{ms.min():.1f}-{ms.max():.1f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("models", nargs=2, type=Path)
    ap.add_argument("presses", nargs="+", type=Path, help="press folders whose tri-colour frame is inferred")
    ap.add_argument("--rounds", type=int, default=9)
    ap.add_argument("--threads", type=int, default=1, help="torch threads (Predictor's threads)")
    args = ap.parse_args()
    a, b = (Predictor(m, threads=args.threads) for m in args.models)
    for folder in args.presses:
        press = load_press(folder)
        frame = press.linear(press.tricolor)
        rows: dict[str, list[float]] = {"one": [], "one_cpu": [], "net": [], "two": [], "two_cpu": []}
        for _ in range(args.rounds):
            wall, cpu, res = timed(lambda f=frame: a.predict(f))
            rows["one"].append(wall), rows["one_cpu"].append(cpu), rows["net"].append(res.seconds["network"])
            wall, cpu, pixels = timed(lambda f=frame: two_nets(a, b, f))
            rows["two"].append(wall), rows["two_cpu"].append(cpu)
        print(
            f"{folder.name}: {pixels} changed px; wall one {spread(rows['one'])} (network {spread(rows['net'])}), "
            f"two {spread(rows['two'])}; CPU one {spread(rows['one_cpu'])}, two {spread(rows['two_cpu'])} ms; "
            f"n={args.rounds}"
        )


if __name__ == "__main__":
    main()
