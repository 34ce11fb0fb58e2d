"""What the standalone ONNX file of a ratio model costs (s38-onnxratio: the colours divided by the reference inside the
graph, a 640x480x3 float32 map stored in the file) against the export before it (the division made by `nlips infer`
in NumPy, the map read from the .pt), for a linear and a ratio model of the paper's architecture, two checkouts.

Models: made here once (``--out DIR``, kept), the paper's 256-256-128 net with seeded weights and BatchNorm statistics
(timings depend on the architecture and the pixels that change, not on trained values), the reference arrays and sensor
of ``--reference`` (a 640x480 undeformed capture with reference.npz), the default prefilter (1 px, colour 0.08). Each
checkout exports its own copy (``nlips export``), so the before side runs the old graph.

Measured, the two checkouts interleaved (``--pairs`` rounds after one warm-up each):

1. ``nlips export MODEL`` whole process (wall, user+sys) and the .onnx's size.
2. ``nlips infer MODEL FRAMES --backend onnx --no-progress`` on ``--frames`` copies of ``--press``'s tri-colour frame:
   wall, user+sys, and the command's own median ms/frame.
3. In process (a worker process per checkout and round): ``Predictor(MODEL, backend)`` load, then ``predict`` of the
   frame ``--repeats`` times: the frame's total and its network stage (which, after, holds the division), for onnx and
   onnx-int8.

Run: .venv/bin/python benchmarks/bench_onnx_ratio.py --before /tmp/s38/onnxratio-before --reference /tmp/keep/reference
     --press /tmp/keep/sphere1 --out /tmp/s38/onnxratio-bench [--pairs 5] [--command-pairs 5] [--export-runs 3]
     [--frames 10] [--repeats 5]
     --network-only | --graphs-alone (the exports already in --out: the network stage, or the ratio graphs alone)
Prints Markdown tables; the results are in benchmarks/RESULTS.md (s38-onnxratio; the ratio int8 rows s40-companions).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if "--worker" not in sys.argv:  # a worker imports the checkout of its PYTHONPATH, not this one
    sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

MODELS = ("linear", "ratio")
FRAME_TIME = re.compile(r"median ([0-9.]+) ms/frame")


def spread(values: list[float], digits: int = 1) -> str:
    return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"


def make_models(reference: Path, out: Path) -> dict[str, Path]:
    """The two model files (made once, kept in ``out``): the paper's net, seeded weights, ``reference``'s arrays."""
    import numpy as np
    import torch

    from nlipscalib.core import load_press
    from nlipscalib.core.sensor_record import sensor_of
    from nlipscalib.learn.dataset import reference_arrays
    from nlipscalib.learn.model import PAPER_HIDDEN, build_net, save_model

    paths = {name: out / f"{name}.pt" for name in MODELS}
    if all(p.is_file() for p in paths.values()):
        return paths
    press = load_press(reference)
    arrays = reference_arrays(press)
    height, width = arrays["valid"].shape
    for name, path in paths.items():
        torch.manual_seed(0)
        net = build_net(PAPER_HIDDEN, 0.2, width, height)
        with torch.no_grad():
            for m in net.mlp:
                if isinstance(m, torch.nn.BatchNorm1d):
                    m.running_mean.uniform_(-1, 1)
                    m.running_var.uniform_(0.5, 2)
            gel = arrays["tricolor"][arrays["valid"]]
            net.in_offset[2:] = torch.tensor([1.0] * 3 if name == "ratio" else gel.mean(0).tolist())
            net.in_scale[2:] = torch.tensor([0.1] * 3 if name == "ratio" else (gel.std(0) + 1e-6).tolist())
        save_model(
            path,
            net.eval(),
            hidden=PAPER_HIDDEN,
            dropout=0.2,
            sensor=sensor_of(press),
            reference={k: np.asarray(v) for k, v in arrays.items()},
            info={"benchmark": "bench_onnx_ratio (seeded weights, not trained)"},
            smoothing_px=1.0,
            smoothing_colour=0.08,
            colour_input=name,
        )
    return paths


def run_nlips(tree: Path, args: list[str], tag: str) -> tuple[float, float, int, str]:
    """(wall s, user+sys s, exit status, stderr) of ``python -m nlipscalib ARGS`` from ``tree``
    (``common.nlips_process``)."""
    from common import nlips_process

    said: list[str] = []
    wall, cpu, rc = nlips_process(tree, args, tag, said)
    return wall, cpu, rc, said[0]


def worker(model: Path, press: Path, repeats: int) -> None:
    """In-process timings of this checkout (``PYTHONPATH``), one JSON line on stdout."""
    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor

    loaded = load_press(press)
    frame = loaded.linear(loaded.tricolor)
    result = {}
    for backend in ("onnx", "onnx-int8"):
        t0 = time.perf_counter()
        predictor = Predictor(model, backend=backend, threads=1)
        load = time.perf_counter() - t0
        runs = [predictor.predict(frame).seconds for _ in range(repeats)]
        result[backend] = {
            "load_ms": load * 1e3,
            "total_ms": [r["total"] * 1e3 for r in runs],
            "network_ms": [r["network"] * 1e3 for r in runs],
            "changed": int(predictor.predict(frame).changed.sum()),
        }
    print(json.dumps(result))


def in_process(trees: dict[str, Path], models: dict[str, dict[str, Path]], args) -> None:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    got: dict = {}
    for round_ in range(args.pairs + 1):  # the first round warms up
        for name in MODELS:
            for side, tree in trees.items():
                cmd = [sys.executable, __file__, "--worker", str(models[side][name]), "--press", str(args.press)]
                cmd += ["--repeats", str(args.repeats)]
                env.update(PYTHONPATH=str(tree), PYTHONPYCACHEPREFIX=f"/tmp/bench-onnxratio-{side}-pyc")
                done = subprocess.run(
                    cmd, env=env, capture_output=True, text=True, check=True, cwd=tempfile.gettempdir()
                )
                if round_:
                    got.setdefault((name, side), []).append(json.loads(done.stdout.strip().splitlines()[-1]))
    print(f"\nIn process, 1 thread (n={args.pairs} loads, {args.pairs * args.repeats} frames a side, interleaved)\n")
    print("| model | backend | checkout | load ms | predict ms/frame (total) | network stage ms | changed px |")
    print("|---|---|---|---|---|---|---|")
    for name in MODELS:
        for backend in ("onnx", "onnx-int8"):
            for side in trees:
                runs = [r[backend] for r in got[(name, side)]]
                load = [r["load_ms"] for r in runs]
                total = [t for r in runs for t in r["total_ms"]]
                network = [t for r in runs for t in r["network_ms"]]
                print(
                    f"| {name} | {backend} | {side} | {spread(load)} | {spread(total)} | {spread(network)} | "
                    f"{runs[0]['changed']} |"
                )


def network_only(folder: Path, press: Path, repeats: int) -> None:
    """The network stage alone, one process (this checkout's OnnxNet, 1 thread), the two exports of the ratio model
    alternating ``repeats`` times: before, the NumPy division of the changed pixels' colours (what `nlips infer`
    did) and the old graph; after, the standalone graph on the linear colours. Wall and process CPU a call: on a
    loaded machine the CPU is the steadier figure. The linear model's two exports likewise (the same graph)."""
    import numpy as np

    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import OnnxNet, max_angle_deg

    loaded = load_press(press)
    frame = loaded.linear(loaded.tricolor)
    inputs = []
    predictor = Predictor(folder / "after" / "ratio.pt", backend="torch", threads=1, depth=False)
    run = predictor._run
    predictor._run = lambda x: inputs.append(x.copy()) or run(x)
    predictor.predict(frame)
    x = np.concatenate(inputs[-1:])  # the frame's changed pixels: (u, v, filtered linear r, g, b)
    divide = load_model(folder / "after" / "ratio.pt").input_reference
    row, col = x[:, 1].astype(np.intp), x[:, 0].astype(np.intp)
    print(f"\nThe network stage alone ({len(x)} changed pixels, 1 thread, {repeats} calls a side, alternating)\n")
    print("| model | export | wall ms | CPU ms | max angle to the other export, deg |\n|---|---|---|---|---|")
    for name in MODELS:
        for int8 in (False, True):
            nets = {side: OnnxNet(folder / side / f"{name}.onnx", threads=1, int8=int8) for side in ("before", "after")}

            def before(buf: np.ndarray, nets=nets, name=name) -> np.ndarray:
                if name == "ratio":  # Predictor.predict's line before s38-onnxratio, on its own copy of the inputs
                    buf[:, 2:] /= divide[row, col]
                return nets["before"](buf)

            calls = {"before": before, "after": lambda buf, nets=nets: nets["after"](buf)}
            times = {side: ([], []) for side in calls}
            out = {side: fn(x.copy()) for side, fn in calls.items()}  # warm-up
            for _ in range(repeats):
                for side, fn in calls.items():
                    buf = x.copy()  # infer builds its input array a frame: not timed on either side
                    w, c = time.perf_counter(), time.process_time()
                    fn(buf)
                    times[side][0].append((time.perf_counter() - w) * 1e3)
                    times[side][1].append((time.process_time() - c) * 1e3)
            angle = max_angle_deg(out["before"], out["after"])  # accurate for tiny angles (arccos is not)
            for side, (walls, cpus) in times.items():
                kind = "int8" if int8 else "float32"
                print(f"| {name} | {side} ({kind}) | {spread(walls, 2)} | {spread(cpus, 2)} | {angle:.2g} |")


def graphs_alone(folder: Path, press: Path, repeats: int) -> None:
    """The ratio model's two graphs alone, float32 and int8 (``OnnxNet``, 1 thread), in one process, the 4 sessions
    alternating ``repeats`` times: before is given the ratios already divided, so neither side holds NumPy's division
    (s40-companions: the network stage's int8 medians swung by 20 ms between runs on a loaded machine)."""
    import numpy as np

    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model
    from nlipscalib.learn.onnx_export import OnnxNet

    loaded = load_press(press)
    inputs = []
    predictor = Predictor(folder / "after" / "ratio.pt", backend="torch", threads=1, depth=False)
    run = predictor._run
    predictor._run = lambda x: inputs.append(x.copy()) or run(x)
    predictor.predict(loaded.linear(loaded.tricolor))
    x = inputs[-1]
    divided = x.copy()
    divided[:, 2:] /= load_model(folder / "after" / "ratio.pt").input_reference[
        x[:, 1].astype(np.intp), x[:, 0].astype(np.intp)
    ]
    sessions = {
        f"ratio {side}, {'int8' if int8 else 'float32'}": (
            OnnxNet(folder / side / "ratio.onnx", threads=1, int8=int8),
            divided if side == "before" else x,
        )
        for int8 in (True, False)
        for side in ("before", "after")
    }
    times = {name: [] for name in sessions}
    for net, given in sessions.values():
        net(given)  # warm-up
    for _ in range(repeats):
        for name, (net, given) in sessions.items():
            t0 = time.process_time()
            net(given)
            times[name].append((time.process_time() - t0) * 1e3)
    print(f"\nThe ratio graphs alone ({len(x)} pixels, 1 thread, {repeats} calls each, alternating), CPU ms\n")
    print("| graph | CPU ms |\n|---|---|")
    for name, values in times.items():
        print(f"| {name} | {spread(values)} |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--before", type=Path, help="the checkout before the change (a git worktree)")
    p.add_argument("--reference", type=Path, help="a 640x480 undeformed capture with reference.npz")
    p.add_argument("--press", type=Path, required=True, help="a 640x480 press folder (a contact on the gel)")
    p.add_argument("--out", type=Path, help="folder for the models and exports (kept)")
    p.add_argument("--frames", type=int, default=10, help="copies of its frame each command infers (default 10)")
    p.add_argument("--pairs", type=int, default=5, help="alternating rounds in process (default 5)")
    p.add_argument("--command-pairs", type=int, default=5, help="alternating rounds of nlips infer (default 5)")
    p.add_argument("--export-runs", type=int, default=3, help="alternating rounds of nlips export (default 3)")
    p.add_argument("--repeats", type=int, default=5, help="frames a round in process (default 5)")
    p.add_argument("--worker", type=Path, help=argparse.SUPPRESS)
    p.add_argument("--network-only", action="store_true", help="the network stage alone, of the exports in --out")
    p.add_argument("--graphs-alone", action="store_true", help="the ratio graphs alone, of the exports in --out")
    args = p.parse_args()
    if args.worker:
        return worker(args.worker, args.press, args.repeats)
    if args.network_only:
        return network_only(args.out, args.press, args.repeats)
    if args.graphs_alone:
        return graphs_alone(args.out, args.press, args.repeats)
    trees = {"before": args.before.resolve(), "after": ROOT}
    args.out.mkdir(parents=True, exist_ok=True)
    made = make_models(args.reference, args.out)
    models = {side: {} for side in trees}
    for side in trees:
        (args.out / side).mkdir(exist_ok=True)
        for name, path in made.items():
            models[side][name] = shutil.copy(path, args.out / side / path.name)
    print(f"load average at the start: {os.getloadavg()}")
    # 1. nlips export
    export = {(name, side): [] for name in MODELS for side in trees}
    for _ in range(args.export_runs):  # no warm-up: each checkout's bytecode is made by its first export
        for name in MODELS:
            for side, tree in trees.items():
                wall, cpu, rc, err = run_nlips(tree, ["export", str(models[side][name])], f"onnxratio-{side}")
                if rc:
                    raise SystemExit(f"{side}: nlips export {name}: exit {rc}: {err.strip()}")
                export[(name, side)].append((wall, cpu))
    print(f"\n`nlips export MODEL` (whole process, n={args.export_runs}, interleaved)\n")
    print("| model | checkout | .onnx bytes | wall s | user+sys s |\n|---|---|---|---|---|")
    for (name, side), runs in export.items():
        size = Path(models[side][name]).with_suffix(".onnx").stat().st_size
        walls, cpus = [w for w, _ in runs], [c for _, c in runs]
        print(f"| {name} | {side} | {size} | {spread(walls, 2)} | {spread(cpus, 2)} |")
    # 2. nlips infer on frames
    with tempfile.TemporaryDirectory(prefix="bench-onnxratio-") as tmp:
        frames = Path(tmp) / "frames"
        frames.mkdir()
        for i in range(args.frames):
            shutil.copy(args.press / "tricolor.png", frames / f"frame_{i:03d}.png")
        infer = {(name, side): [] for name in MODELS for side in trees}
        said = {(name, side): [] for name in MODELS for side in trees}
        for round_ in range(args.command_pairs + 1):
            for name in MODELS:
                for side, tree in trees.items():
                    command = ["infer", str(models[side][name]), str(frames), "--backend", "onnx", "--no-progress"]
                    wall, cpu, rc, err = run_nlips(tree, command, f"onnxratio-{side}")
                    if rc:
                        raise SystemExit(f"{side}: nlips infer {name}: exit {rc}: {err.strip()}")
                    if round_:
                        infer[(name, side)].append((wall, cpu))
                        said[(name, side)].append(err)
    print(f"\n`nlips infer MODEL FRAMES --backend onnx` ({args.frames} frames, n={args.command_pairs}, interleaved)\n")
    print("| model | checkout | wall s | user+sys s | the command's median ms/frame |\n|---|---|---|---|---|")
    for key, runs in infer.items():
        ms = [float(m.group(1)) for text in said[key] if (m := FRAME_TIME.search(text))]
        walls, cpus = [w for w, _ in runs], [c for _, c in runs]
        print(f"| {key[0]} | {key[1]} | {spread(walls, 2)} | {spread(cpus, 2)} | {spread(ms) if ms else 'n/a'} |")
    # 3. in process
    in_process(trees, models, args)
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
