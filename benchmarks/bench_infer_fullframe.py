"""``nlips infer MODEL FRAMES --full-frame`` on the CPU: PyTorch's full-frame path (``--backend torch``) against the
full-frame ONNX graph (``--backend onnx``: MODEL.frame.onnx's normals, the same change rule and whole-gel
integration), whole commands alternating on the same stored frames, so both see the same load.

Per run: the process wall and user + system CPU as a user measures them (the command from a folder outside the
checkout, bytecode written), and stream.json's CPU per frame, median frame time and load average. The model needs
its graph beside it (``nlips export MODEL --full-frame``). Prints one line per run and the medians.

Run: .venv/bin/python benchmarks/bench_infer_fullframe.py --model M.pt --frames 'frames/img_%04d.png'
     [--max-frames 6] [--rounds 3] [--work DIR]
Results: benchmarks/RESULTS.md, s39-onnxinfer.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nlipscalib.learn.onnx_fullframe import frame_graph_path  # noqa: E402

BACKENDS = ("torch", "onnx")


def run_once(args: argparse.Namespace, backend: str, out: Path) -> dict:
    """One whole ``nlips infer`` command: its wall, its CPU (the child's rusage) and stream.json's figures."""
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    env.pop("PYTHONDONTWRITEBYTECODE", None)  # as a user runs it: bytecode written
    command = [str(Path(sys.executable).parent / "nlips"), "infer", args.model, args.frames, "--full-frame"]
    command += ["--backend", backend, "--max-frames", str(args.max_frames), "--out", str(out)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(command, cwd=args.work, env=env, check=True, capture_output=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    stream = json.loads((out / "stream.json").read_text(encoding="utf-8"))
    assert stream["backend"] == backend, stream["backend"]
    return {
        "wall_s": wall,
        "cpu_s": after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime,
        "cpu_s_per_frame": stream["cpu_s_per_frame"],
        "median_frame_s": stream["median_stage_s"]["total"],
        "load": stream["load_average"],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="model file (.pt) with MODEL.frame.onnx beside it")
    parser.add_argument("--frames", required=True, help="image sequence pattern or video of stored frames")
    parser.add_argument("--max-frames", type=int, default=6)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--work", default=".", help="folder the commands run in (outside the checkout)")
    args = parser.parse_args()
    args.model, args.work = str(Path(args.model).resolve()), str(Path(args.work).resolve())
    graph = frame_graph_path(args.model)
    if not graph.is_file():  # said once here, not by every onnx run's failing command
        raise SystemExit(f"{graph}: missing (`nlips export {args.model} --full-frame` writes it)")
    runs: dict[str, list[dict]] = {b: [] for b in BACKENDS}
    for round_ in range(args.rounds):
        for backend in BACKENDS:
            r = run_once(args, backend, Path(args.work) / f"bench-{backend}-{round_}")
            runs[backend].append(r)
            print(backend, round_, json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items()}))
    for backend, rs in runs.items():
        medians = {k: round(statistics.median(r[k] for r in rs), 3) for k in rs[0] if k != "load"}
        print(backend, "median", medians)


if __name__ == "__main__":
    main()
