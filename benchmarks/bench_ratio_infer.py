"""What the colour-ratio input (``TrainConfig.colour_input`` "ratio", the default since the thirty-seventh session)
costs at inference against the paper's linear colours: a linear and a ratio model of one architecture on the same
frames, PyTorch and ONNX, on the CPU.

Whole command: ``nlips infer MODEL FRAMES --backend B`` on a folder of ``--frames`` copies of one press's 640x480
tri-colour frame (results not written: the network, depth and the command around them), the two models alternating,
``--pairs`` times after one warm-up each; process wall, user+sys CPU and the command's own median ms/frame. Every
process runs with its own bytecode cache and ``NLIPS_CACHE_DIR`` (``common.nlips_process``).

In process (``--pairs`` alternating rounds): the Predictor's load (a ratio model filters its reference frame once,
``learn.model.input_reference``) and ``Predictor.predict`` of the frame (``--repeats`` times a round: its total and
network stages; the ratio divides the changed pixels' colours by the reference's there).

Run: .venv/bin/python benchmarks/bench_ratio_infer.py --linear L.pt --ratio R.pt --press PRESS
     [--frames 10] [--pairs 5] [--repeats 5]
Each model needs MODEL.onnx beside it (`nlips export MODEL.pt`). Prints Markdown tables; the results are in
benchmarks/RESULTS.md (s37-ratiodef).
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from common import interleaved, nlips_process, timing_rows  # noqa: E402

SIDES = ("linear", "ratio")
FRAME_TIME = re.compile(r"median ([0-9.]+) ms/frame")


def spread(values: list[float], digits: int = 1) -> str:
    return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"


def whole_commands(models: dict[str, Path], frames: Path, pairs: int) -> None:
    for backend in ("torch", "onnx"):
        said: dict[str, list[str]] = {side: [] for side in SIDES}

        def run(side: str, backend: str = backend, said: dict = said) -> tuple[float, float, int]:
            args = ["infer", str(models[side]), str(frames), "--backend", backend, "--no-progress"]
            return nlips_process(ROOT, args, f"s37-ratiodef-{side}", said[side])

        times = interleaved(list(SIDES), run, pairs, f"nlips infer --backend {backend}")
        print(f"\n`nlips infer MODEL FRAMES --backend {backend}` (n={pairs}, interleaved after one warm-up each)\n")
        print("| model | wall s | user+sys s | the command's median ms/frame |\n|---|---|---|---|")
        for row, side in zip(timing_rows(times, 2).splitlines(), SIDES):
            ms = [float(m.group(1)) for text in said[side][1:] if (m := FRAME_TIME.search(text))]
            print(f"{row} {spread(ms) if ms else 'n/a'} |")


def in_process(models: dict[str, Path], press: Path, pairs: int, repeats: int) -> None:
    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor

    loaded = load_press(press)
    frame = loaded.linear(loaded.tricolor)
    for backend in ("torch", "onnx"):
        load = {side: [] for side in SIDES}
        total = {side: [] for side in SIDES}
        network = {side: [] for side in SIDES}
        changed = {}
        for round_ in range(pairs + 1):  # the first round warms up
            for side in SIDES:
                t0 = time.perf_counter()
                predictor = Predictor(models[side], backend=backend)
                seconds = time.perf_counter() - t0
                runs = [predictor.predict(frame) for _ in range(repeats)]
                changed[side] = int(runs[0].changed.sum()) / int(predictor.valid.sum())
                if round_:
                    load[side].append(seconds * 1e3)
                    total[side] += [r.seconds["total"] * 1e3 for r in runs]
                    network[side] += [r.seconds["network"] * 1e3 for r in runs]
        print(f"\nIn process, `Predictor(MODEL, backend={backend!r})` (n={pairs} loads, {pairs * repeats} frames)\n")
        print("| model | load ms | predict ms/frame (total) | of it the network stage ms | changed share of the gel |")
        print("|---|---|---|---|---|")
        for side in SIDES:
            print(
                f"| {side} | {spread(load[side])} | {spread(total[side])} | {spread(network[side])} | "
                f"{changed[side]:.3f} |"
            )


def ratio_work(models: dict[str, Path], press: Path, repeats: int) -> None:
    """The ratio's own work, alone (wall, and CPU of this process: OpenCV may filter on several threads): the
    filtered reference a ratio model's load makes (``input_reference``) and the division of a frame's changed colours
    by it (``Predictor.predict``'s one line until s38-onnxratio; since then the PyTorch runner's, and the ONNX graph's
    own nodes: benchmarks/bench_onnx_ratio.py)."""
    import numpy as np

    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import input_reference

    predictor = Predictor(models["ratio"], backend="torch")
    model = predictor.model
    loaded = load_press(press)
    changed = predictor.changed(loaded.linear(loaded.tricolor))
    row, col = np.divmod(np.flatnonzero(changed), predictor.shape[1])
    x = np.ones((len(row), 5), np.float32)

    def reference() -> None:
        input_reference(model.reference, model.smoothing_px, model.smoothing_colour, "ratio")

    def divide() -> None:
        x[:, 2:] /= model.input_reference[row, col]

    print(f"\nThe ratio's own work ({repeats} runs after one warm-up; {len(row)} changed pixels)\n")
    print("| step | wall ms | CPU ms (this process) |\n|---|---|---|")
    for name, fn in (("input_reference (once a load)", reference), ("the division (once a frame)", divide)):
        fn()
        wall, cpu = [], []
        for _ in range(repeats):
            w, c = time.perf_counter(), time.process_time()
            fn()
            wall.append((time.perf_counter() - w) * 1e3)
            cpu.append((time.process_time() - c) * 1e3)
        print(f"| {name} | {spread(wall, 2)} | {spread(cpu, 2)} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--linear", type=Path, required=True, help="a model of linear colours (.pt, .onnx beside it)")
    p.add_argument("--ratio", type=Path, required=True, help="a model of colour ratios, the same architecture")
    p.add_argument("--press", type=Path, required=True, help="a 640x480 press folder (~10 %% of the gel changed)")
    p.add_argument("--frames", type=int, default=10, help="copies of its frame each command infers (default 10)")
    p.add_argument("--pairs", type=int, default=5, help="alternating rounds (default 5)")
    p.add_argument("--repeats", type=int, default=5, help="frames a round in process (default 5)")
    p.add_argument("--no-commands", action="store_true", help="in process only")
    p.add_argument("--work-only", action="store_true", help="only the ratio's own work (input_reference, division)")
    args = p.parse_args()
    models = {"linear": args.linear.resolve(), "ratio": args.ratio.resolve()}
    for side, path in models.items():
        if not path.with_suffix(".onnx").is_file():
            raise SystemExit(f"--{side} {path}: no {path.with_suffix('.onnx').name} beside it (`nlips export {path}`)")
    ratio_work(models, args.press, max(args.repeats, 9))
    if args.work_only:
        return
    in_process(models, args.press, args.pairs, args.repeats)
    if not args.no_commands:
        with tempfile.TemporaryDirectory(prefix="bench-ratio-") as tmp:
            frames = Path(tmp) / "frames"
            frames.mkdir()
            for i in range(args.frames):
                shutil.copy(args.press / "tricolor.png", frames / f"frame_{i:03d}.png")
            whole_commands(models, frames, args.pairs)


if __name__ == "__main__":
    main()
