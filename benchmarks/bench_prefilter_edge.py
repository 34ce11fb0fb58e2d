"""What the edge-stopping prefilter (``SamplingConfig.smoothing_colour``, learn.prefilter) costs against the Gaussian.

Usage::

    python benchmarks/bench_prefilter_edge.py --press PRESS --reference REF [--pairs 7] \
        [--model-gauss M1.pt --model-edge M2.pt --frames PRESS ...]

1. The whole frame of PRESS's tri-colour image through ``Prefilter(valid, 1.0)`` and ``Prefilter(valid, 1.0, 0.08)``,
   interleaved pairs: median [range] of wall and of process CPU (user + sys) per call.
2. The same on the window inference filters: the bounding box of the pixels the change rule finds changed against
   REF (as ``learn.infer.Predictor`` does).
3. With two models of the same architecture (one trained with each prefilter, same sensor): ``Predictor.predict``
   (CPU path, normals and depth) per frame on the --frames presses' tri-colour images, interleaved.
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.learn.change import ChangeDetector  # noqa: E402
from nlipscalib.learn.prefilter import Prefilter  # noqa: E402

COLOUR_SIGMA = 0.08


def _timed(fn) -> tuple[float, float]:
    c0, t0 = time.process_time(), time.perf_counter()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def _pairs(a, b, pairs: int, inner: int) -> dict[str, list[tuple[float, float]]]:
    """``pairs`` interleaved runs of ``inner`` calls each of a and b (after one warm-up each): per-call times."""
    a(), b()
    out = {"gauss": [], "edge": []}
    for _ in range(pairs):
        for name, fn in (("gauss", a), ("edge", b)):
            wall, cpu = _timed(lambda fn=fn: [fn() for _ in range(inner)])
            out[name].append((wall / inner, cpu / inner))
    return out


def _row(what: str, name: str, times: list[tuple[float, float]]) -> str:
    wall, cpu = [1e3 * t[0] for t in times], [1e3 * t[1] for t in times]
    return (
        f"| {what} | {name} | {statistics.median(wall):.2f} [{min(wall):.2f}-{max(wall):.2f}] | "
        f"{statistics.median(cpu):.2f} [{min(cpu):.2f}-{max(cpu):.2f}] | {len(times)} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--press", type=Path, required=True)
    ap.add_argument("--reference", type=Path, required=True)
    ap.add_argument("--pairs", type=int, default=7)
    ap.add_argument("--model-gauss", type=Path)
    ap.add_argument("--model-edge", type=Path)
    ap.add_argument("--frames", type=Path, nargs="*", default=[])
    args = ap.parse_args()
    press, ref = load_press(args.press), load_press(args.reference)
    valid = np.isfinite(ref.reference.depth)
    tri = press.linear(press.tricolor)
    gauss, edge = Prefilter(valid, 1.0), Prefilter(valid, 1.0, COLOUR_SIGMA)
    rows = ["| what | prefilter | wall ms per call, median [range] | CPU ms per call | pairs |"]
    rows.append("|---|---|---|---|---|")
    h, w = valid.shape
    full = _pairs(lambda: gauss(tri), lambda: edge(tri), args.pairs, 10)
    rows += [_row(f"whole frame {w}x{h}", k, v) for k, v in full.items()]
    changed = ChangeDetector(ref.linear(ref.tricolor), valid)(tri)
    r, c = np.nonzero(changed)
    win = (slice(r.min(), r.max() + 1), slice(c.min(), c.max() + 1))
    size = f"{c.max() - c.min() + 1}x{r.max() - r.min() + 1}"
    part = _pairs(lambda: gauss(tri, *win), lambda: edge(tri, *win), args.pairs, 20)
    rows += [_row(f"changed pixels' window {size} ({changed.sum()} px changed)", k, v) for k, v in part.items()]
    if args.model_gauss and args.model_edge and args.frames:
        from nlipscalib.learn.infer import Predictor

        frames = [load_press(f) for f in args.frames]
        frames = [f.linear(f.tricolor) for f in frames]
        pg, pe = Predictor(args.model_gauss, threads=1), Predictor(args.model_edge, threads=1)
        assert pe.model.smoothing_colour > 0 and not pg.model.smoothing_colour
        both = _pairs(lambda: [pg.predict(f) for f in frames], lambda: [pe.predict(f) for f in frames], args.pairs, 1)
        n = len(frames)
        both = {k: [(t[0] / n, t[1] / n) for t in v] for k, v in both.items()}
        rows += [_row(f"Predictor.predict per frame ({n} frames, 1 thread)", k, v) for k, v in both.items()]
    with open("/proc/loadavg", encoding="ascii") as f:
        load = f.read().split()[:3]
    print("\n".join(rows))
    print(f"\nload average {' '.join(load)}")


if __name__ == "__main__":
    main()
