"""A kept `nlips train` re-run, now that it makes the ONNX files beside the reused model current (s41-exports2):
the same training run again reuses its finished model, and now reads the model file's digest and each export's
recorded metadata (``cli.train._companions_made_current``) to find a stale MODEL.frame.onnx (or, with --no-onnx, a
stale MODEL.onnx) and make it again or remove it.

1. In process, this checkout: ``_companions_made_current`` on the model with both exports current (what every kept
   re-run now does, given the digest of the model it loads anyway), and that load (``load_model``, one a re-run
   before the change too), CPU ms median [range] over ``--repeats`` calls.
2. ``nlips train DATASET --out MODEL TRAIN_ARGS`` whole process, the checkouts interleaved (``common.interleaved``),
   each side on its own copy of the model, its checkpoint, MODEL.onnx and MODEL.frame.onnx: a re-run that reuses
   the model (checked: each side's stderr says "reused"). Process wall and user+sys.
3. Once, this checkout: the same re-run with MODEL.frame.onnx of another model beside the model (its weights 1 %
   larger), which it makes again.

Run: .venv/bin/python benchmarks/bench_reused_train.py --before /tmp/s41/exports2-before \\
     --dataset /tmp/s41/exports2-bench/calib --model /tmp/s41/exports2-bench/m/net.pt \\
     --out /tmp/s41/exports2-bench/runs --train-args "--epochs 2 --no-progress" [--pairs 10]
Prints Markdown; the results are in benchmarks/RESULTS.md (s41-exports2; s41-trainreuse: ``--reruns-only``, both
orders, the re-run deciding to reuse before it builds the net and optimiser). A checkout whose ``core/`` or ``learn/``
differs from the model's trains its copy once first (said: "trained once, then reused").
"""

from __future__ import annotations

import argparse
import os
import shlex
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


def companion_files(model: Path) -> list[Path]:
    from nlipscalib.learn.checkpoint import checkpoint_path

    return [model, checkpoint_path(model), model.with_suffix(".onnx"), model.with_suffix(".frame.onnx")]


def in_process(model: Path, repeats: int) -> None:
    from nlipscalib.cli.train import _companions_made_current
    from nlipscalib.learn.model import load_model

    digest = load_model(model).digest  # what the reuse loads anyway (it did before the change too)
    rows = {
        "`_companions_made_current` (both exports current)": lambda: _companions_made_current(model, False, digest),
        "`load_model` (the reused model's one load, as before)": lambda: load_model(model),
    }
    print(f"\nIn process, CPU ms a call (n={repeats}), {model.stat().st_size} bytes of model\n")
    print("| call | CPU ms |\n|---|---|")
    for name, fn in rows.items():
        fn()
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            fn()
            times.append((time.process_time() - t0) * 1e3)
        print(f"| {name} | {spread(times, 3)} |")


def kept_reruns(
    before: Path, dataset: Path, model: Path, out: Path, train_args: list[str], pairs: int, after_first: bool = False
) -> None:
    from common import interleaved, nlips_process, timing_rows

    trees = {"before": before.resolve(), "after": ROOT}
    if after_first:  # each round's order swapped: a bias of the second run of a pair falls on the other side
        trees = dict(reversed(trees.items()))
    for side in trees:
        (out / side).mkdir(parents=True, exist_ok=True)
        if not (out / side / model.name).is_file():  # kept between runs: a side's own training is reused
            for path in companion_files(model):
                shutil.copy2(path, out / side / path.name)

    def args(side: str) -> list[str]:
        return ["train", str(dataset), "--out", str(out / side / model.name), *train_args]

    # each side must reuse its model (else the times are a training's): a checkout whose training code (core/, learn/:
    # learn.checkpoint.training_code) differs from the model's trains it again once, then reuses its own
    for side, tree in trees.items():
        said: list[str] = []
        for _ in range(2):
            nlips_process(tree, args(side), f"reused-{side}", said)
            if ": reused, trained before" in said[-1]:
                break
        else:
            raise SystemExit(f"{side}: the re-run did not reuse the model:\n{said[-1]}")
        print(f"\n{side}: {'trained once, then ' if len(said) > 1 else ''}reused")

    def run(side: str) -> tuple[float, float, int]:
        return nlips_process(trees[side], args(side), f"reused-{side}")

    print(
        f"\n`nlips train DATASET --out MODEL {shlex.join(train_args)}` re-run that reuses the model (n={pairs}, "
        "interleaved)\n"
    )
    print("| checkout | wall s | user+sys s |\n|---|---|---|")
    print(timing_rows(interleaved(list(trees), run, pairs, "nlips train"), digits=2))


def stale_frame_graph(dataset: Path, model: Path, out: Path, train_args: list[str]) -> None:
    import torch
    from common import nlips_process

    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_fullframe import export_full_frame

    folder = out / "stale"
    folder.mkdir(parents=True, exist_ok=True)
    for path in companion_files(model):
        shutil.copy2(path, folder / path.name)
    other = out / "other" / model.name
    other.parent.mkdir(exist_ok=True)
    payload = torch.load(model, weights_only=True)
    payload["state_dict"] = {k: v * 1.01 if v.is_floating_point() else v for k, v in payload["state_dict"].items()}
    torch.save(payload, other)
    export_full_frame(load_model(other), (folder / model.name).with_suffix(".frame.onnx"), check=False)
    said: list[str] = []
    wall, cpu, rc = nlips_process(
        ROOT, ["train", str(dataset), "--out", str(folder / model.name), *train_args], "reused-after", said
    )
    made = [line for line in said[0].splitlines() if "made again" in line]
    print(
        f"\nStale MODEL.frame.onnx made again by the re-run (this checkout, once): wall {wall:.1f} s, user+sys "
        f"{cpu:.1f} s, exit {rc}; said: {made[0] if made else 'nothing'}"
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, required=True, help="the checkout before the change (a git worktree)")
    p.add_argument("--dataset", type=Path, required=True, help="the calibration dataset the model was trained on")
    p.add_argument("--model", type=Path, required=True, help="its model, with checkpoint, MODEL.onnx, MODEL.frame.onnx")
    p.add_argument("--out", type=Path, required=True, help="folder for the copies (kept)")
    p.add_argument("--train-args", default="--no-progress", help="the options the model was trained with")
    p.add_argument("--pairs", type=int, default=10, help="interleaved rounds of kept re-runs (default 10)")
    p.add_argument("--repeats", type=int, default=30, help="in-process calls (default 30)")
    p.add_argument("--after-first", action="store_true", help="run this checkout first in each round")
    p.add_argument("--reruns-only", action="store_true", help="the interleaved re-runs alone (no stale case)")
    args = p.parse_args()
    missing = [path for path in companion_files(args.model) if not path.is_file()]
    if missing:
        sys.exit(f"{missing[0]}: missing (train the model, then `nlips export MODEL --full-frame`)")
    train_args = shlex.split(args.train_args)
    print(f"load average at the start: {os.getloadavg()}")
    if not args.reruns_only:
        in_process(args.model, args.repeats)
    kept_reruns(args.before, args.dataset, args.model, args.out, train_args, args.pairs, args.after_first)
    if not args.reruns_only:
        stale_frame_graph(args.dataset, args.model, args.out, train_args)
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
