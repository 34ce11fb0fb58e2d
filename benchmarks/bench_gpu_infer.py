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

3. the stream alone, on the GPU machine::

       python benchmarks/bench_gpu_infer.py stream --model A.pt [--model B.pt] --frames frames.npz --out OUT

   the frames as a 16-bit PNG sequence, streamed in this process as ``nlips infer`` streams them (its source,
   read-ahead and mismatch watch) with 1, 2 and 4 decoding threads, then the whole command (process wall) with
   its default and with ``--full-frame``. Results: OUT/gpu_stream.json, stdout.
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
    """Degrees between the vectors of ``a`` and ``b`` ((H, W, 3)) on ``where`` ((H, W) bool), (N,) float64."""
    from nlipscalib.core.metrics import angle_deg

    return angle_deg(a[where], b[where])


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
    (Path(args.out) / "gpu_infer.json").write_text(json.dumps(report, indent=2), encoding="utf-8")


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
    # TF32 for every float32 matrix product: the network's, and the changed pixels' box solve's (dense sine
    # transforms on a GPU), whose depth then loses precision too
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
        predictor._full.box_integrator._graph = lambda *size: None


def _png_sequence(stored, args) -> str:
    """``args.command_frames`` 16-bit PNG frames cycling through ``stored``; returns their pattern."""
    import cv2

    seq = Path(args.scratch) / "frames"
    seq.mkdir(parents=True, exist_ok=True)
    for i in range(args.command_frames):  # RGB frames stored as PNG (OpenCV writes BGR)
        path = seq / f"img_{i:04d}.png"
        if not path.exists():
            cv2.imwrite(str(path), stored[i % len(stored)][..., ::-1])
    return str(seq / "img_%04d.png")


def _command(model, stored, args) -> dict:
    """The whole `nlips infer MODEL SEQUENCE --device cuda` on PNG frames, timed from outside."""
    return run_command(model, _png_sequence(stored, args), args, [])


def run_command(model, pattern: str, args, extra: list) -> dict:
    """``python -m nlipscalib infer MODEL PATTERN --device DEVICE [extra]``: its process wall and printout."""
    cmd = [sys.executable, "-m", "nlipscalib", "infer", model, pattern, "--device", args.device, *extra]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    wall = time.perf_counter() - t0
    return {"frames": args.command_frames, "process_wall_s": wall, "rc": done.returncode, "stdout": done.stdout[-800:]}


def stream_step(args) -> None:
    """Step 3: the streaming command's frames/s with 1, 2, 4 decoding threads, and the whole command."""
    import torch

    from nlipscalib.device.camera import SequenceSource
    from nlipscalib.device.live import ReadAhead, decoding_workers, stream
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.watch import MismatchWatch

    _, presses = _frames(args.frames)
    stored = [p["tricolor"] for p in presses.values()]
    pattern = _png_sequence(stored, args)
    gpu = torch.cuda.get_device_name(0) if torch.cuda.is_available() else "none"
    report = {"gpu": gpu, "cpu_count": os.cpu_count(), "default_workers": decoding_workers()}
    print(json.dumps(report), flush=True)
    for model in args.model:
        entry = report.setdefault(Path(model).stem, {})
        for full in (False, True) if not args.no_sweep else ():
            predictor = Predictor(model, device=args.device, full_frame=full)
            watch = MismatchWatch(predictor, "bench")
            for f in stored:  # warm-up: records the CUDA graphs
                watch(f)
            for workers in (1, 2, 4):
                with ReadAhead(SequenceSource(pattern), workers=workers) as source:
                    stats = stream(source, watch, [], report=None)
                key = f"{'full_frame' if full else 'changed'}_workers_{workers}"
                entry[key] = {"frames": stats.frames, "fps": stats.fps, "summary": stats.summary()}
                print(f"{Path(model).stem} {key}: {stats.summary()}", flush=True)
        for extra in ([], ["--full-frame"]):
            entry["command" + "".join(extra)] = run_command(model, pattern, args, extra)
            print(f"{Path(model).stem} command {extra}: {json.dumps(entry['command' + ''.join(extra)])}", flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "gpu_stream.json").write_text(json.dumps(report, indent=2), encoding="utf-8")


def boxes_step(args) -> None:
    """Step 4: what a new size of the changed pixels' box costs on the GPU (a moving contact brings new sizes):
    per size, its first eager solve (with FFTs: its cuFFT plans made), a later eager solve, its graph recording and
    a replay."""
    import torch

    from nlipscalib.learn import integrate_torch
    from nlipscalib.learn.fullframe import FullFrame
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.integrate_regions import _fast_span
    from nlipscalib.learn.torch_device import check_device

    integrate_torch.RECORD_AFTER = 1  # a size's first call through the integrator records it, the next replays
    pred = Predictor(args.model[0])
    full = FullFrame(pred.model, check_device(args.device, flag=True), pred.geo, keep_reference=True)
    integ = full.box_integrator
    H, W = integ.on_gel.shape
    normals = full.ref_normals
    rng = np.random.default_rng(0)
    rows = []

    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)

    def timed(f):
        sync()
        t0 = time.perf_counter()
        f()
        sync()
        return 1e3 * (time.perf_counter() - t0)

    for _ in range(args.sizes):
        r0, c0 = int(rng.integers(2, H // 3)), int(rng.integers(2, W // 3))
        r0, r1 = _fast_span(r0, r0 + int(rng.integers(20, H // 2)), H)
        c0, c1 = _fast_span(c0, c0 + int(rng.integers(20, W // 2)), W)
        box = (slice(r0, r1), slice(c0, c1))
        h, w = r1 - r0, c1 - c0
        index = integ._index(h, w) + (r0 * integ.width + c0)
        rows.append(
            {
                "h": h,
                "w": w,
                "eager_first_ms": timed(lambda i=index: integ._solve(normals, i)),
                "eager_ms": timed(lambda i=index: integ._solve(normals, i)),
                "record_ms": timed(lambda b=box: integ(normals, b)),
                "replay_ms": timed(lambda b=box: integ(normals, b)),
            }
        )
    med = {k: float(np.median([r[k] for r in rows])) for k in rows[0] if k.endswith("_ms")}
    print(json.dumps({"sizes": len(rows), "median": med}), flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    (Path(args.out) / "gpu_boxes.json").write_text(
        json.dumps({"median": med, "rows": rows}, indent=2), encoding="utf-8"
    )


def moving_step(args) -> None:
    """Step 5: a contact that grows and shrinks (a new box size nearly every frame): frames/s and the slowest
    frames, the box solved by dense sine transforms (the default on a GPU) or, with ``--fft``, by FFTs (a cuFFT
    plan per new box size). One model per process: the plans a process made would serve the next model."""
    import torch

    from nlipscalib.learn import integrate_torch
    from nlipscalib.learn.infer import Predictor

    integrate_torch.RECORD_AFTER = args.record_after or integrate_torch.RECORD_AFTER
    if args.fft:
        integrate_torch.BoxIntegrator._solver = lambda self, m, n: integrate_torch.BoxPoisson(
            m, n, self.device, torch.float32
        )
    _, presses = _frames(args.frames)
    press = next(iter(presses.values()))
    pred = Predictor(args.model[0], device=args.device)
    frames = _growing_contact(pred, press, args.moving_frames)
    sizes, walls = set(), []
    t_all = time.perf_counter()
    for f in frames:
        t0 = time.perf_counter()
        res = pred.predict(f)
        walls.append(time.perf_counter() - t0)
        rows, cols = np.flatnonzero(res.changed.any(1)), np.flatnonzero(res.changed.any(0))
        sizes.add((len(rows), len(cols)))
    entry = {
        "model": Path(args.model[0]).stem,
        "box_solve": "fft" if args.fft else "dense",
        "record_after": integrate_torch.RECORD_AFTER,
        "slowest_frame": int(np.argmax(walls)),
        "frames": len(frames),
        "frames_per_s": len(frames) / (time.perf_counter() - t_all),
        "call_ms_median": 1e3 * float(np.median(walls)),
        "call_ms_p95": 1e3 * float(np.percentile(walls, 95)),
        "call_ms_max": 1e3 * float(np.max(walls)),
        "changed_extents": len(sizes),
    }
    print(json.dumps(entry), flush=True)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    with open(Path(args.out) / "gpu_moving.jsonl", "a", encoding="utf-8") as fh:
        fh.write(json.dumps(entry) + "\n")


def parity_step(args) -> None:
    """Step 6: the GPU's result against the CPU's (the torch backend) on every packed frame and on frames of a
    growing contact: changed masks, normals, depth."""
    from nlipscalib.learn.infer import Predictor

    _, presses = _frames(args.frames)
    for model in args.model:
        gpu, cpu = Predictor(model, device=args.device), Predictor(model, backend="torch")
        frames = [gpu.linear(p["tricolor"]) for p in presses.values()]
        frames += _growing_contact(gpu, next(iter(presses.values())), 12)
        worst = {"changed_masks_differ_px": 0, "max_normal_diff": 0.0, "max_depth_diff_mm": 0.0}
        for f in frames:
            a, b = gpu.predict(f), cpu.predict(f)
            differ = int((a.changed != b.changed).sum())
            worst["changed_masks_differ_px"] = max(worst["changed_masks_differ_px"], differ)
            worst["max_normal_diff"] = max(worst["max_normal_diff"], float(np.abs(a.normals - b.normals).max()))
            worst["max_depth_diff_mm"] = max(worst["max_depth_diff_mm"], float(np.nanmax(np.abs(a.depth - b.depth))))
        print(json.dumps({"model": Path(model).stem, "frames": len(frames), **worst}), flush=True)


def _growing_contact(pred, press: dict, n: int) -> list:
    """``n`` linear frames: the press's frame inside a disc about its contact that grows to the whole contact and
    shrinks back, the reference frame outside (a press going in and out)."""
    linear = pred.linear(press["tricolor"])
    diff = np.abs(linear - pred.ref_tricolor).sum(-1)
    cy, cx = np.unravel_index(np.argmax(diff), diff.shape)
    yy, xx = np.indices(diff.shape)
    dist = np.hypot(yy - cy, xx - cx)
    reach = float(dist[diff > 0.2 * diff.max()].max())
    radii = reach * np.sin(np.linspace(0.05, np.pi - 0.05, n))
    return [np.where((dist <= r)[..., None], linear, pred.ref_tricolor).astype(np.float32) for r in radii]


STEPS = {"run": run, "stream": stream_step, "boxes": boxes_step, "moving": moving_step, "parity": parity_step}
"""The steps on the GPU machine; each takes --model (repeatable) and --device, and those of NEEDS their own."""
NEEDS = {
    "run": ("--frames", "--out", "--repeats", "--command-frames", "--scratch"),
    "stream": ("--frames", "--out", "--command-frames", "--scratch", "--no-sweep"),
    "boxes": ("--out", "--sizes"),
    "moving": ("--frames", "--out", "--moving-frames", "--fft", "--record-after"),
    "parity": ("--frames",),
}
OPTIONS = {
    "--frames": {"required": True, "help": "frames.npz from the pack step"},
    "--out": {"required": True, "help": "folder for the step's JSON"},
    "--repeats": {"type": int, "default": 300},
    "--command-frames": {"type": int, "default": 300},
    "--scratch": {"default": "/tmp/bench_gpu_infer"},
    "--no-sweep": {"action": "store_true", "help": "only the whole commands"},
    "--sizes": {"type": int, "default": 40},
    "--moving-frames": {"type": int, "default": 200},
    "--fft": {"action": "store_true", "help": "the box solved by FFTs (a cuFFT plan per new box size)"},
    "--record-after": {"type": int, "help": "record a box size at its N-th frame (default: the module's)"},
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="step", required=True)
    p = sub.add_parser("pack")
    p.add_argument("presses", nargs="+")
    p.add_argument("--reference", required=True)
    p.add_argument("--out", required=True)
    for name, needs in NEEDS.items():
        step = sub.add_parser(name)
        step.add_argument("--model", action="append", required=True)
        step.add_argument("--device", default="cuda")
        for option in needs:
            step.add_argument(option, **OPTIONS[option])
    args = ap.parse_args()
    if args.step != "pack":
        _check_device(args.step, args.device)
    (STEPS | {"pack": pack})[args.step](args)


def _check_device(step: str, device: str) -> None:
    """Exit with one line, before any work, when ``device`` is not here (no GPU, or a CPU build of torch)."""
    from nlipscalib.core.errors import NlipsError
    from nlipscalib.learn.torch_device import check_device

    try:
        check_device(device, flag=True)  # worded for this script's --device
    except (NlipsError, ImportError) as exc:  # ImportError: torch missing (MissingDependencyError)
        raise SystemExit(f"bench_gpu_infer.py {step}: {exc}") from None


if __name__ == "__main__":
    main()
