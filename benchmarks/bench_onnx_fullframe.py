"""What a frame costs through the full-frame ONNX graph (``nlips export MODEL --full-frame``, s39-onnxfull) on the CPU,
against the two PyTorch-and-NumPy paths of ``nlips infer`` on the CPU: the PyTorch full-frame path
(``learn.fullframe.FullFrame``, ``keep_reference=False``, normals only) and the changed-pixels path
(``Predictor(..., backend="onnx", depth=False).predict_stored``: the change rule, the prefilter of the changed pixels'
box, the per-pixel ONNX file on them).

Model: ``--model`` (a trained 640x480 model: Q2's 256-256-128 ratio model with the default bilateral prefilter, copied
into ``--out``) and its Gaussian-only variant (the same file with ``smoothing_colour`` 0, made in ``--out``). Frame:
``--press``'s tri-colour PNG as stored (uint16). Each path is timed ``--repeats`` times in rounds that alternate
the paths (one process; a warm-up call each first): wall and this process's CPU a frame. onnxruntime runs with its
default threads (the usable cores) and with one.

Also the graph's size (nodes, bytes) and the whole process of ``nlips export MODEL --full-frame`` (wall, user+sys)
once per variant.

Run: .venv/bin/python benchmarks/bench_onnx_fullframe.py --model /tmp/s38/q2f/q2-full/learned/nlipsnet-2bf3....pt
     --press /tmp/s38/q2f/q2-full/presses/coin-... --out /tmp/s39/onnxfull-bench [--repeats 10]
Prints Markdown tables; the results are in benchmarks/RESULTS.md (s39-onnxfull).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def spread(values: list[float], digits: int = 1) -> str:
    return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"


def variants(model: Path, out: Path) -> dict[str, Path]:
    """The model as it is ("bilateral") and its Gaussian-only copy, in ``out``."""
    import torch

    out.mkdir(parents=True, exist_ok=True)
    paths = {"bilateral": out / "bilateral.pt", "gaussian": out / "gaussian.pt"}
    if not paths["bilateral"].is_file():
        shutil.copy(model, paths["bilateral"])
    if not paths["gaussian"].is_file():
        payload = torch.load(model, weights_only=False)
        payload["smoothing_colour"] = 0.0
        torch.save(payload, paths["gaussian"])
    return paths


def export(model: Path) -> tuple[float, float]:
    """(wall s, user+sys s of the children) of ``nlips export MODEL --full-frame`` and of the per-pixel export."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"} | {"PYTHONPATH": str(ROOT)}
    env["PYTHONPYCACHEPREFIX"] = "/tmp/bench-onnxfull-pyc"
    if not model.with_suffix(".onnx").is_file():  # the changed-pixels path's file
        subprocess.run([sys.executable, "-m", "nlipscalib", "export", str(model)], env=env, check=True)
    before = os.times()
    t0 = time.perf_counter()
    command = [sys.executable, "-m", "nlipscalib", "export", str(model), "--full-frame"]
    subprocess.run(command, env=env, check=True, capture_output=True, cwd="/tmp")
    wall = time.perf_counter() - t0
    after = os.times()
    return wall, (after.children_user - before.children_user) + (after.children_system - before.children_system)


def session(path: Path, threads: int):
    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads
    return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])


def paths_of(model_path: Path, frame):
    """name -> a call running one frame."""
    import torch

    from nlipscalib.learn.fullframe import FullFrame
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.model import load_model

    model = load_model(model_path)
    onnx_file = model_path.with_suffix(".frame.onnx")
    runs = {}
    for threads in (0, 1):
        s = session(onnx_file, threads)
        runs[f"ONNX full frame ({threads or 'default'} threads)"] = lambda s=s: s.run(None, {"tricolor": frame})
    full = FullFrame(model, torch.device("cpu"), None, keep_reference=False)
    runs["PyTorch full frame (learn.fullframe, CPU)"] = lambda: full(frame, stored=True)
    predictor = Predictor(model_path, backend="onnx", depth=False)
    runs["changed pixels (Predictor onnx, depth off)"] = lambda: predictor.predict_stored(frame)
    return runs, predictor.predict_stored(frame).changed.sum()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", type=Path, required=True, help="a trained 640x480 model (.pt), copied")
    p.add_argument("--press", type=Path, required=True, help="a press folder of its sensor (tricolor.png)")
    p.add_argument("--out", type=Path, required=True, help="folder for the copies and exports (kept)")
    p.add_argument("--repeats", type=int, default=10, help="frames a path (default 10)")
    args = p.parse_args()
    import onnx

    from nlipscalib.core.imageio import read_png16

    print(f"load average at the start: {os.getloadavg()}")
    frame = read_png16(args.press / "tricolor.png")
    models = variants(args.model, args.out)
    print("\n| prefilter | graph nodes | .frame.onnx bytes | `nlips export --full-frame` wall s | user+sys s |")
    print("|---|---|---|---|---|")
    for name, path in models.items():
        wall, cpu = export(path)
        graph = onnx.load(str(path.with_suffix(".frame.onnx"))).graph
        size = path.with_suffix(".frame.onnx").stat().st_size
        print(f"| {name} | {len(graph.node)} | {size} | {wall:.1f} | {cpu:.1f} |")
    for name, path in models.items():
        runs, changed = paths_of(path, frame)
        times = {key: ([], []) for key in runs}
        for fn in runs.values():
            fn()  # warm-up
        for _ in range(args.repeats):
            for key, fn in runs.items():
                w, c = time.perf_counter(), time.process_time()
                fn()
                times[key][0].append((time.perf_counter() - w) * 1e3)
                times[key][1].append((time.process_time() - c) * 1e3)
        print(f"\n{name} prefilter, {frame.shape[1]}x{frame.shape[0]}, {changed} changed pixels, n={args.repeats}\n")
        print("| path | wall ms/frame | CPU ms/frame |\n|---|---|---|")
        for key, (walls, cpus) in times.items():
            print(f"| {key} | {spread(walls)} | {spread(cpus)} |")
    print(f"\nload average at the end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
