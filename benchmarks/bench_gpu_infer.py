"""NLiPsNet on a GPU: frames/s and accuracy of the whole-frame path (``nlips infer --device cuda --full-frame``).

Two steps, because the GPU machine has no renderer:

1. here (any machine with the twin's presses)::

       python benchmarks/bench_gpu_infer.py pack PRESS [PRESS ...] --reference REF --out frames.npz

   packs each press's stored tri-colour frame and ground truth (normals, depth) and the reference depth into one
   file (a few MB per press);
2. on the GPU machine::

       python benchmarks/bench_gpu_infer.py run --model A.pt [--model B.pt] --frames frames.npz --out OUT

   times, per model, stored uint16 frames in and numpy results out (uploads and downloads count): the GPU path
   (``--device cuda``: the change rule, the network, the changed pixels' box integrated), normals only, without
   its CUDA graph, with TF32 matrix products, the whole-frame variant (``--full-frame``: the network's normals on
   every gel pixel, depth over the whole gel), and the CPU path on the same machine; checks the GPU against
   the CPU and the graph against eager execution; scores each against the truth (AAE in the contact and over the
   gel, depth error); then the whole ``python -m nlipscalib infer MODEL 'frames/img_%04d.png' --device cuda``
   command on a sequence of PNG frames (process wall, decoding included). Results: OUT/gpu_infer.json, stdout.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

CONTACT_MM = 0.02
"""Pixels whose true depth differs from the reference by more than this are the contact."""


def pack(args) -> None:
    from nlipscalib.core import load_press

    arrays = {"reference_depth": load_press(args.reference).ground_truth.depth.astype(np.float32)}
    for folder in args.presses:
        press = load_press(folder)
        name = Path(folder).name
        arrays[f"{name}/tricolor"] = press.tricolor
        arrays[f"{name}/normals"] = press.ground_truth.normals.astype(np.float32)
        arrays[f"{name}/depth"] = press.ground_truth.depth.astype(np.float32)
    np.savez_compressed(args.out, **arrays)
    print(f"{args.out}: {len(args.presses)} presses, {os.path.getsize(args.out) / 1e6:.1f} MB")


def _frames(path):
    data = np.load(path)
    names = sorted({k.split("/")[0] for k in data.files if "/" in k})
    return data["reference_depth"], {n: {k: data[f"{n}/{k}"] for k in ("tricolor", "normals", "depth")} for n in names}


def _angles(a, b, where):
    """Degrees between unit vectors (atan2 of sine and cosine: exact near 0, where arccos of a cosine is not)."""
    a, b = a[where].astype(np.float64), b[where].astype(np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1)))


def _timed(predictor, frames: list, repeats: int) -> dict:
    """Median stage times and whole-call wall per frame (stored uint16 in, numpy out), after a warm-up."""
    for f in frames:
        predictor.predict_stored(f)
    walls, stages = [], []
    t_all = time.perf_counter()
    for i in range(repeats):
        t0 = time.perf_counter()
        res = predictor.predict_stored(frames[i % len(frames)])
        walls.append(time.perf_counter() - t0)
        stages.append(res.seconds)
    elapsed = time.perf_counter() - t_all
    med = {f"{k}_ms": 1e3 * float(np.median([s[k] for s in stages])) for k in stages[0]}
    return med | {
        "call_ms_median": 1e3 * float(np.median(walls)),
        "frames_per_s": repeats / elapsed,
        "frames_per_s_median": 1 / float(np.median(walls)),
    }


def _scores(predictor, press: dict, ref_depth) -> dict:
    res = predictor.predict_stored(press["tricolor"])
    valid = predictor.valid
    contact = valid & (np.abs(press["depth"] - ref_depth) > CONTACT_MM)
    out = {
        "aae_contact_deg": float(_angles(res.normals, press["normals"], contact).mean()),
        "aae_gel_deg": float(_angles(res.normals, press["normals"], valid).mean()),
        "contact_fraction": float(contact.sum() / contact.size),
    }
    if predictor.geo is not None:
        err = np.abs(res.depth - press["depth"])
        out |= {
            "depth_mae_contact_mm": float(np.nanmean(err[contact])),
            "depth_rmse_gel_mm": float(np.sqrt(np.nanmean(err[valid] ** 2))),
        }
    return out


def run(args) -> None:
    import torch

    ref_depth, presses = _frames(args.frames)
    stored = [p["tricolor"] for p in presses.values()]
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"
    report = {"gpu": gpu, "torch": torch.__version__, "cpu_count": os.cpu_count(), "models": {}}
    print(f"GPU {gpu}, torch {torch.__version__}, {os.cpu_count()} CPUs; {len(stored)} frames", flush=True)
    for model in args.model:
        key = Path(model).stem
        entry = report["models"].setdefault(key, {})
        try:
            _bench_model(model, key, entry, stored, presses, ref_depth, args)
        except Exception as exc:  # one model's failure leaves the others measured (a GPU lease is short)
            import traceback

            traceback.print_exc()
            entry["error"] = repr(exc)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "gpu_infer.json").write_text(json.dumps(report, indent=2))


def _bench_model(model, key, entry, stored, presses, ref_depth, args) -> None:
    import torch

    from nlipscalib.learn.infer import Predictor

    configs = {
        "gpu": dict(device=args.device),
        "gpu_normals_only": dict(device=args.device, depth=False),
        "gpu_no_cuda_graph": dict(device=args.device),
        "gpu_full_frame": dict(device=args.device, full_frame=True),
        "gpu_full_frame_no_cuda_graph": dict(device=args.device, full_frame=True),
        "cpu_changed_pixels": dict(backend="torch"),
    }
    for name, kw in configs.items():
        pred = Predictor(model, **kw)
        if name.endswith("no_cuda_graph") and pred._full is not None:  # eager: per-frame launches from Python
            _eager(pred)
        repeats = args.repeats if name != "cpu_changed_pixels" else max(args.repeats // 10, 5)
        entry[name] = _timed(pred, stored, repeats) | {
            "scores": {n: _scores(pred, p, ref_depth) for n, p in presses.items()}
        }
        print(f"{key} {name}: {json.dumps(entry[name])}", flush=True)
    torch.backends.cuda.matmul.allow_tf32 = True
    for name, kw in (("gpu_tf32", {}), ("gpu_full_frame_tf32", {"full_frame": True})):
        pred = Predictor(model, device=args.device, **kw)
        scores = {n: _scores(pred, p, ref_depth) for n, p in presses.items()}
        entry[name] = _timed(pred, stored, args.repeats) | {"scores": scores}
        print(f"{key} {name}: {json.dumps(entry[name])}", flush=True)
    torch.backends.cuda.matmul.allow_tf32 = False
    entry["gpu_vs_cpu"] = {}
    for name, kw in (("changed", {}), ("full_frame", {"full_frame": True})):
        gpu = Predictor(model, device=args.device, **kw).predict_stored(stored[0])
        eager_pred = Predictor(model, device=args.device, **kw)
        if eager_pred._full is not None:
            _eager(eager_pred)
        eager = eager_pred.predict_stored(stored[0])
        cpu = Predictor(model, backend="torch", **kw).predict_stored(stored[0])
        entry["gpu_vs_cpu"][name] = {
            "changed_masks_differ_px": int((gpu.changed != cpu.changed).sum()),
            "max_normal_diff": float(np.abs(gpu.normals - cpu.normals).max()),
            "max_depth_diff_mm": float(np.nanmax(np.abs(gpu.depth - cpu.depth))),
            "graph_vs_eager_max_normal_diff": float(np.abs(gpu.normals - eager.normals).max()),
            "graph_vs_eager_max_depth_diff_mm": float(np.nanmax(np.abs(gpu.depth - eager.depth))),
        }
    print(f"{key} gpu vs cpu: {json.dumps(entry['gpu_vs_cpu'])}", flush=True)
    entry["command"] = _command(model, stored, args)
    print(f"{key} command: {json.dumps(entry['command'])}", flush=True)


def _eager(predictor) -> None:
    """No CUDA graphs in ``predictor``: the frame's and the box's work launched from Python, kernel by kernel."""
    import torch

    predictor._full._graphs = {(torch.uint16, True): None, (torch.float32, False): None}
    if predictor._full.box_integrator is not None:
        predictor._full.box_integrator._graph = lambda h, w: None


def _command(model, stored, args) -> dict:
    """The whole `nlips infer MODEL SEQUENCE --device cuda` on PNG frames, timed from outside."""
    import cv2

    seq = Path(args.scratch) / "frames"
    seq.mkdir(parents=True, exist_ok=True)
    for i in range(args.command_frames):  # RGB frames stored as PNG (OpenCV writes BGR)
        path = seq / f"img_{i:04d}.png"
        if not path.exists():
            cv2.imwrite(str(path), stored[i % len(stored)][..., ::-1])
    cmd = [sys.executable, "-m", "nlipscalib", "infer", model, str(seq / "img_%04d.png"), "--device", args.device]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    wall = time.perf_counter() - t0
    return {"frames": args.command_frames, "process_wall_s": wall, "rc": done.returncode, "stdout": done.stdout[-800:]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="step", required=True)
    p = sub.add_parser("pack")
    p.add_argument("presses", nargs="+")
    p.add_argument("--reference", required=True)
    p.add_argument("--out", required=True)
    r = sub.add_parser("run")
    r.add_argument("--model", action="append", required=True)
    r.add_argument("--frames", required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--device", default="cuda")
    r.add_argument("--repeats", type=int, default=300)
    r.add_argument("--command-frames", type=int, default=300)
    r.add_argument("--scratch", default="/tmp/bench_gpu_infer")
    args = ap.parse_args()
    pack(args) if args.step == "pack" else run(args)


if __name__ == "__main__":
    main()
