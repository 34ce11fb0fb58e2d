"""The twin's ``cuda_ad_rgb`` variant on a GPU: render time of the bench press and agreement with ``llvm_ad_rgb``.

Two steps, because the GPU machine has neither pymeshlab (the indentation) nor the internet:

1. here (the CPU machine with the whole ``sim`` extra)::

       python benchmarks/bench_gpu_render.py pack --out .gpu/gel.npz
       benchmarks/gpu_bundle.sh .gpu/mitsuba-cp312.tar.xz WHEELS   # Mitsuba, drjit, trimesh for Python 3.12

   ``pack`` deforms the gel under bench_render.py's press (its mesh, vertex normals and contact go in the file)
   and renders it with ``llvm_ad_rgb`` in bench_render.py's two cases, (bounces 0, 4 spp) and (bounces 1,
   16 spp), at 640x480; it keeps 8x8-block means of every LED's image, every LED's mean over the gel, the
   ground truth on every 4th pixel, and the noise floor: the same statistics between two seeds of llvm;
2. on the GPU machine (bundle unpacked into SITE)::

       PYTHONPATH=SITE:. python3 benchmarks/bench_gpu_render.py run --gel .gpu/gel.npz --out OUT

   sets the variant through the scene's render config (the product's path), renders once (kernel compile,
   OptiX), then times ``render_surface`` (all 12 LED images + ground truth) ``--repeats`` times per case and
   compares with the packed llvm statistics; then times the whole ``python3 -m nlipscalib render --undeformed``
   command from outside (process wall) twice in a fresh $HOME (drjit's kernel cache lives there: first cold,
   then warm), and once with ``--variant auto`` (which variant it picked). A step that fails prints one line
   and the next one runs. Results: one JSON line per result on stdout, all in OUT/gpu_render.json.

``run --variant llvm_ad_rgb`` runs the same steps on a CPU (the check of this script, and the llvm numbers).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(ROOT))  # this checkout's package, not an installed one

BLOCK = 8
"""Side of the pixel blocks whose means are compared (a 16-spp render's noise averages out over 64 pixels)."""
GT_STRIDE = 4
"""The ground truth is kept on every GT_STRIDE-th pixel of each row and column."""
SIZE = (640, 480)
"""Width, height of every render here (bench_render.py's)."""
COMMAND_TIMEOUT_S = 150
"""Longest a whole ``nlips render`` may run before it counts as failed."""


def _cases():
    from bench_render import CASES

    return [(bounces, spp) for bounces, spp, _goal in CASES]


def _scene(variant: str, bounces: int, spp: int):
    from nlipscalib.sim.scene import load_scene

    scene = load_scene()
    require_size = (scene.camera.width, scene.camera.height)
    if require_size != SIZE:
        raise SystemExit(f"bench_gpu_render.py: the default scene is {require_size}, this benchmark expects {SIZE}")
    return scene.replace(render={"spp": spp, "bounces": bounces, "variant": variant})


def _stats(result) -> dict:
    """8x8-block means (L, H/8, W/8, 3) and per-LED means over the gel (L, 3) of one render, float64."""
    images = result.images.astype(np.float64)
    n, h, w, c = images.shape
    blocks = images.reshape(n, h // BLOCK, BLOCK, w // BLOCK, BLOCK, c).mean(axis=(2, 4))
    valid = result.gt.valid
    return {"blocks": blocks, "led_means": images[:, valid].mean(axis=1)}


def _full_blocks(valid: np.ndarray) -> np.ndarray:
    """(H/8, W/8) bool: blocks whose every pixel sees the gel (the rim's partial blocks move with the edge)."""
    h, w = valid.shape
    return valid.reshape(h // BLOCK, BLOCK, w // BLOCK, BLOCK).all(axis=(1, 3))


def _relative(a: dict, b: dict, full: np.ndarray) -> dict:
    """Relative differences of ``a``'s statistics from ``b``'s: blocks (median, p99, max) and LED means (max)."""
    ref = b["blocks"][:, full]
    rel = np.abs(a["blocks"][:, full] - ref) / np.maximum(np.abs(ref), 1e-12)
    leds = np.abs(a["led_means"] - b["led_means"]) / np.maximum(np.abs(b["led_means"]), 1e-12)
    return {
        "block_rel_median": float(np.median(rel)),
        "block_rel_p99": float(np.percentile(rel, 99)),
        "block_rel_max": float(rel.max()),
        "led_mean_rel_max": float(leds.max()),
    }


def pack(args) -> None:
    from bench_render import bench_press

    from nlipscalib.sim.indent import apply_press
    from nlipscalib.sim.render import render_surface

    gel = apply_press(_scene("llvm_ad_rgb", 0, 1).dome, bench_press())
    arrays = {
        "vertices": np.asarray(gel.mesh.vertices, np.float64),
        "faces": np.asarray(gel.mesh.faces, np.int32),
        "normals": np.asarray(gel.mesh.vertex_normals, np.float64),
        "contact": np.asarray(gel.contact, bool),
    }
    mesh = _mesh(arrays)
    for bounces, spp in _cases():
        scene = _scene("llvm_ad_rgb", bounces, spp)
        first = render_surface(scene, mesh, arrays["contact"])
        other = render_surface(scene, mesh, arrays["contact"], seed=first.seed + 1)
        stats, full = _stats(first), _full_blocks(first.gt.valid)
        floor = _relative(_stats(other), stats, full)
        key = f"b{bounces}s{spp}"
        arrays |= {f"{key}/{k}": v.astype(np.float32) for k, v in stats.items()}
        arrays[f"{key}/noise_floor"] = np.array([floor[k] for k in sorted(floor)])
        arrays[f"{key}/llvm_seconds"] = np.array(first.seconds)
        print(f"{key}: llvm {first.seconds:.1f} s; seed vs seed+1: {json.dumps(floor)}", flush=True)
    gt = first.gt
    sub = np.s_[::GT_STRIDE, ::GT_STRIDE]
    arrays |= {"gt/depth": gt.depth[sub], "gt/normals": gt.normals[sub], "gt/valid": gt.valid[sub]}
    arrays["gt/full_blocks"] = full
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(args.out).with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(args.out)
    print(f"{args.out}: {len(arrays['vertices'])} vertices, {os.path.getsize(args.out) / 1e6:.1f} MB")


def _mesh(arrays):
    import trimesh

    return trimesh.Trimesh(
        arrays["vertices"], arrays["faces"], vertex_normals=arrays["normals"], process=False, validate=False
    )


class Report:
    """Results as they come: one JSON line each on stdout, all rewritten into OUT/gpu_render.json each time
    (so a run cut off by its time limit still leaves what it measured)."""

    def __init__(self, out: Path, budget_s: float):
        self.path = out / "gpu_render.json"
        self.results: list[dict] = []
        self.deadline = time.monotonic() + budget_s
        out.mkdir(parents=True, exist_ok=True)

    def left_s(self) -> float:
        return self.deadline - time.monotonic()

    def add(self, step: str, **fields) -> None:
        entry = {"step": step, **fields}
        self.results.append(entry)
        print(json.dumps(entry), flush=True)
        tmp = self.path.with_suffix(".tmp")
        tmp.write_text(json.dumps(self.results, indent=1) + "\n", encoding="utf-8")
        tmp.replace(self.path)

    def attempt(self, step: str, work, need_s: float = 10.0) -> None:
        """``work()`` (which adds its results), or one line saying why it did not run or failed."""
        if self.left_s() < need_s:
            self.add(step, skipped=f"time budget: {self.left_s():.0f} s left, the step needs about {need_s:.0f} s")
            return
        try:
            work()
        except Exception as exc:  # any failure (no OptiX, no CUDA, an import) is a result: the next step goes on
            line = (str(exc).strip().splitlines() or [""])[0][:300]
            print(f"bench_gpu_render.py run: {step}: {type(exc).__name__}: {line}", file=sys.stderr, flush=True)
            self.add(step, error=f"{type(exc).__name__}: {line}")


def _environment(report: Report) -> None:
    fields = {"python": platform.python_version(), "machine": platform.machine(), "cores": os.cpu_count()}
    try:
        smi = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version,memory.total", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=20,
        )
        fields["gpu"] = smi.stdout.strip() or smi.stderr.strip()[:200]
    except (OSError, subprocess.TimeoutExpired) as exc:
        fields["gpu"] = f"nvidia-smi: {exc}"
    import drjit
    import mitsuba

    fields |= {
        "mitsuba": f"{mitsuba.__version__} {Path(mitsuba.__file__).parent}",
        "drjit": f"{drjit.__version__} {Path(drjit.__file__).parent}",
        "variants": mitsuba.variants(),
    }
    report.add("environment", **fields)


def _render_case(report: Report, ref, mesh, contact, variant: str, bounces: int, spp: int, repeats: int) -> None:
    from nlipscalib.sim.render import render_surface

    scene = _scene(variant, bounces, spp)
    t0 = time.perf_counter()
    first = render_surface(scene, mesh, contact)  # kernel compile (and OptiX pipeline) on the first call
    first_s = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        render_surface(scene, mesh, contact)
        times.append(time.perf_counter() - t0)
    key = f"b{bounces}s{spp}"
    full = ref["gt/full_blocks"]
    ours = _stats(first)
    packed = {"blocks": ref[f"{key}/blocks"].astype(np.float64), "led_means": ref[f"{key}/led_means"]}
    floor_keys = sorted(_relative(packed, packed, full))
    report.add(
        f"render_surface bounces {bounces} spp {spp}",
        variant=first.variant,
        first_s=round(first_s, 3),
        median_s=round(statistics.median(times), 3),
        min_s=round(min(times), 3),
        max_s=round(max(times), 3),
        repeats=repeats,
        llvm_packed_s=round(float(ref[f"{key}/llvm_seconds"]), 3),
        vs_llvm=_relative(ours, packed, full),
        llvm_noise_floor=dict(zip(floor_keys, map(float, ref[f"{key}/noise_floor"]), strict=True)),
        ground_truth=_gt_agreement(first.gt, ref),
    )


def _gt_agreement(gt, ref) -> dict:
    """Ground truth against llvm's on the packed pixels: depth (mm), normals (deg), coverage."""
    from nlipscalib.core.metrics import angle_deg

    sub = np.s_[::GT_STRIDE, ::GT_STRIDE]
    both = gt.valid[sub] & ref["gt/valid"]
    angle = angle_deg(gt.normals[sub][both], ref["gt/normals"][both])
    return {
        "depth_max_abs_mm": float(np.max(np.abs(gt.depth[sub][both] - ref["gt/depth"][both]))),
        "normal_max_deg": float(angle.max()),
        "valid_mismatch_px": int(np.count_nonzero(gt.valid[sub] != ref["gt/valid"])),
        "compared_px": int(both.sum()),
    }


def _command(report: Report, variant: str, home: str, label: str) -> None:
    """The whole ``nlips render --undeformed`` (bounces 1, 16 spp, 640x480), process wall from outside."""
    out = Path(home) / f"render-{label}"
    cmd = [sys.executable, "-m", "nlipscalib", "--no-progress", "render", "--undeformed", "--variant", variant]
    cmd += ["--bounces", "1", "--spp", "16", "--width", str(SIZE[0]), "--height", str(SIZE[1]), "--out", str(out)]
    path = os.pathsep.join(filter(None, [os.environ.get("PYTHONPATH"), str(ROOT)]))
    env = dict(os.environ, HOME=home, PYTHONPATH=path)
    env.pop("XDG_CACHE_HOME", None)
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=COMMAND_TIMEOUT_S)
    wall = time.perf_counter() - t0
    fields = {"wall_s": round(wall, 2), "returncode": done.returncode}
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()
        fields["error"] = tail[-1][:300] if tail else "no message"
    else:
        provenance = json.loads((out / "meta.json").read_text(encoding="utf-8"))["provenance"]
        fields |= {"variant_used": provenance["variant"], "render_s": round(provenance["render_seconds"], 2)}
    report.add(f"command render --undeformed --variant {variant} ({label})", **fields)


def run(args) -> None:
    report = Report(Path(args.out), args.budget)
    ref = np.load(args.gel)
    report.attempt("environment", lambda: _environment(report), need_s=5)
    mesh = _mesh(ref)
    for bounces, spp in _cases():
        report.attempt(
            f"render_surface bounces {bounces} spp {spp}",
            lambda b=bounces, s=spp: _render_case(report, ref, mesh, ref["contact"], args.variant, b, s, args.repeats),
            need_s=20,
        )
    with tempfile.TemporaryDirectory(prefix="nlips-gpu-render-") as home:  # a fresh $HOME: drjit's cache is cold
        for label in ("cold kernel cache", "warm kernel cache"):
            report.attempt(f"command ({label})", lambda lb=label: _command(report, args.variant, home, lb), 30)
        report.attempt("command (auto)", lambda: _command(report, "auto", home, "auto"), need_s=30)
    print(f"{report.path}: {len(report.results)} results", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="step", required=True)
    p = sub.add_parser("pack", help="here: the bench press's gel and llvm_ad_rgb's reference statistics")
    p.add_argument("--out", required=True, help="the .npz to write")
    p = sub.add_parser("run", help="on the GPU machine: time the variant, compare with llvm, time the command")
    p.add_argument("--gel", required=True, help="the .npz written by pack")
    p.add_argument("--out", required=True, help="folder for gpu_render.json")
    p.add_argument("--variant", default="cuda_ad_rgb", help="Mitsuba variant to time (llvm_ad_rgb: check on a CPU)")
    p.add_argument("--repeats", type=int, default=3, help="timed render_surface calls per case, after one warm-up")
    p.add_argument("--budget", type=float, default=170.0, help="seconds; a step that would run past it is skipped")
    args = ap.parse_args()
    if args.step == "run" and not Path(args.gel).is_file():
        raise SystemExit(f"bench_gpu_render.py run: {args.gel}: no such file (make it with the pack step)")
    (pack if args.step == "pack" else run)(args)


if __name__ == "__main__":
    main()
