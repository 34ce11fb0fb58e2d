"""What `--backend auto`'s check for an export of another model costs (s40-companions): reading the `model_digest` an
ONNX file records (``learn.onnx_export.recorded_digest``: its top-level protobuf fields walked, the graph skipped)
against protobuf's parser, and a `nlips infer` re-run that keeps every result (it reads the digest to choose its
runtime before anything loads) before and after the change.

1. In process, this checkout: ``recorded_digest`` and protobuf's ``ModelProto.FromString`` of each ONNX file beside
   ``--model`` (MODEL.onnx, MODEL.frame.onnx), CPU ms median [range] over ``--repeats`` calls; protobuf's first call
   (importing its messages) apart.
2. ``nlips infer MODEL PRESS --out OUT --figures none`` (auto), the checkouts interleaved (``common.interleaved``:
   one warm-up run each infers the press, then ``--pairs`` rounds, each a re-run that keeps its result): process wall
   and user+sys.

Run: .venv/bin/python benchmarks/bench_stale_export.py --before /tmp/s40/companions-before \\
     --model /tmp/s40/companions-scratch/m/net.pt --press /tmp/keep/sphere1 --out /tmp/s40/companions-bench [--pairs 10]
Prints Markdown; the results are in benchmarks/RESULTS.md (s40-companions).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def spread(values: list[float], digits: int = 2) -> str:
    return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"


def cpu_ms(fn, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.process_time()
        fn()
        times.append((time.process_time() - t0) * 1e3)
    return times


def in_process(model: Path, repeats: int) -> None:
    from nlipscalib.learn.onnx_export import onnx_messages, recorded_digest

    files = [p for p in (model.with_suffix(".onnx"), model.with_suffix(".frame.onnx")) if p.is_file()]
    t0 = time.process_time()
    messages = onnx_messages()
    imported = (time.process_time() - t0) * 1e3
    print(f"\nIn process, CPU ms a call (n={repeats}); importing protobuf's messages once: {imported:.1f} ms\n")
    print("| file | bytes | recorded_digest | protobuf's FromString |\n|---|---|---|---|")
    for path in files:
        walk = cpu_ms(lambda path=path: recorded_digest(path), repeats)
        parse = cpu_ms(lambda path=path: messages.ModelProto.FromString(path.read_bytes()), repeats)
        print(f"| {path.name} | {path.stat().st_size} | {spread(walk, 3)} | {spread(parse, 2)} |")


def kept_reruns(before: Path, model: Path, press: Path, out: Path, pairs: int) -> None:
    from common import interleaved, nlips_process, timing_rows

    trees = {"before": before.resolve(), "after": ROOT}
    out.mkdir(parents=True, exist_ok=True)
    for side in trees:
        (out / side).mkdir(exist_ok=True)
        for path in (model, model.with_suffix(".onnx")):
            shutil.copy(path, out / side / path.name)

    def run(side: str) -> tuple[float, float, int]:
        args = ["infer", str(out / side / model.name), str(press), "--out", str(out / side / "results")]
        return nlips_process(trees[side], [*args, "--figures", "none"], f"stale-{side}")

    print(f"\n`nlips infer MODEL PRESS --out OUT` re-run, its result kept (n={pairs}, interleaved)\n")
    print("| checkout | wall s | user+sys s |\n|---|---|---|")
    print(timing_rows(interleaved(list(trees), run, pairs, "nlips infer"), digits=2))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, required=True, help="the checkout before the change (a git worktree)")
    p.add_argument("--model", type=Path, required=True, help="a model file with its MODEL.onnx beside it")
    p.add_argument("--press", type=Path, required=True, help="a press folder of the model's sensor")
    p.add_argument("--out", type=Path, required=True, help="folder for the copies and results (kept)")
    p.add_argument("--pairs", type=int, default=10, help="interleaved rounds of kept re-runs (default 10)")
    p.add_argument("--repeats", type=int, default=30, help="in-process calls a file (default 30)")
    args = p.parse_args()
    if not args.model.with_suffix(".onnx").is_file():
        sys.exit(f"{args.model.with_suffix('.onnx')}: missing: `nlips export {args.model}` writes it")
    print(f"load average at the start: {os.getloadavg()}")
    in_process(args.model, args.repeats)
    kept_reruns(args.before, args.model, args.press, args.out, args.pairs)
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
