"""NLiPsNet benchmark: accuracy on seen indenters at new places and on unseen indenters, and frames/s.

Usage (datasets rendered with `nlips dataset`, e.g. the reduced specs in benchmarks/learn_*.toml)::

    nlips dataset benchmarks/learn_train.toml --out DATA/train
    nlips dataset benchmarks/learn_unseen.toml --out DATA/unseen
    python benchmarks/bench_learn.py --train DATA/train --unseen DATA/unseen --out OUT [--test-count 6]

1. `nlips calibrate` both folders (NLiPs solve + samples), timed.
2. The last ``--test-count`` presses of --train are held out (seen indenters, new places); --unseen
   holds other indenters. Trained on the rest (``VARIANTS``): the paper's NLiPsNet with and without
   dropout, 64-64-64 and 32-32-32 variants without dropout on NLiPs labels, the paper's net on the
   twin's true normals (upper bound), and the GelSight-style lookup table.
3. Contact-sample AAE of each against the NLiPs normals and against the true normals.
4. The same held-out samples through onnxruntime float32 and int8 (``--backend onnx-int8``).
5. Frames/s of the predictor at 640x480 on a rendered press whose contact covers ~10 % of the image
   (normals + depth on the dome): per stage (change detection, network, integration), wall and process
   CPU per frame, onnxruntime float32 and int8, 1 and 2 threads, with the load average; and the whole
   `nlips infer MODEL VIDEO` command on a lossless video of that press.
Prints a markdown table and writes OUT/bench_learn.json.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from nlipscalib.cli import main as nlips  # noqa: E402
from nlipscalib.core.metrics import aae  # noqa: E402
from nlipscalib.learn.dataset import CalibrationDataset  # noqa: E402
from nlipscalib.learn.evaluate import net_predict, sample_scores  # noqa: E402
from nlipscalib.learn.lut import LookupTable  # noqa: E402
from nlipscalib.learn.model import load_model  # noqa: E402
from nlipscalib.learn.train import TrainConfig, train  # noqa: E402
from nlipscalib.report.learn import training_curve  # noqa: E402

PAPER = (256, 256, 128)
FAST = (64, 64, 64)
TINY = (32, 32, 32)
VARIANTS = (
    # key, hidden, dropout, labels: the paper's net as the paper trains it, the same without dropout (which
    # underfits), the real-time variants without dropout, and the true-normal upper bound
    ("paper", PAPER, 0.2, "nlips"),
    ("paper_d0", PAPER, 0.0, "nlips"),
    ("fast", FAST, 0.0, "nlips"),
    ("tiny", TINY, 0.0, "nlips"),
    ("upper", PAPER, 0.2, "true"),
)


def calibrate(folder: Path, solve: bool = True) -> tuple[CalibrationDataset, float]:
    t0 = time.perf_counter()
    if not solve:  # presses solved before: only (re)build the samples
        from nlipscalib.core import find_presses
        from nlipscalib.learn.dataset import build_dataset

        presses = [p for p in find_presses(folder) if (p / "nlips" / "result.npz").is_file() and p.name != "reference"]
        build_dataset(presses, folder / "reference", folder / "calibration", progress=False)
        return CalibrationDataset(folder / "calibration"), time.perf_counter() - t0
    rc = nlips(["calibrate", str(folder), "--no-progress"])
    if rc not in (0, 1):
        raise SystemExit(f"nlips calibrate {folder} failed ({rc})")
    return CalibrationDataset(folder / "calibration"), time.perf_counter() - t0


def accuracy(args) -> dict:
    train_data, t_train = calibrate(Path(args.train), not args.no_solve)
    unseen_data, t_unseen = calibrate(Path(args.unseen), not args.no_solve)
    test_seen = train_data.names[-args.test_count :]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    models, times = {}, {}
    for key, hidden, dropout, labels in VARIANTS:
        t0 = time.perf_counter()
        cfg = TrainConfig(
            hidden=hidden,
            dropout=dropout,
            seed=args.seed,
            labels=labels,
            max_epochs=args.epochs,
            patience=args.patience,
            max_seconds=args.max_minutes * 60,
        )
        res = train(train_data, cfg, out / f"{key}.pt", exclude=test_seen, progress=False)
        times[key] = time.perf_counter() - t0
        models[key] = load_model(res.model_path)
        training_curve(res.history, out / f"{key}_curve.png", f"NLiPsNet {key} {'-'.join(map(str, hidden))}")
        print(f"trained {key}: {len(res.history)} epochs, {times[key]:.0f} s", flush=True)
    tr = train_data.arrays(models["paper"].info["train_presses"] + models["paper"].info["val_presses"])
    lut = LookupTable.fit(tr["pixel"], tr["rgb"], tr["normal"], train_data.reference()["tricolor"])
    rows = {}
    for split, data, names in (("seen", train_data, test_seen), ("unseen", unseen_data, unseen_data.names)):
        s = data.arrays(names)
        rows[split] = {k: sample_scores(net_predict(m, s["pixel"], s["rgb"]), s) for k, m in models.items()}
        rows[split]["lut"] = sample_scores(lut.predict(s["pixel"], s["rgb"]), s)
        m = s["contact"] & (s["source"] == 0) & np.all(np.isfinite(s["true_normal"]), -1)
        rows[split]["nlips"] = {"aae_vs_true_deg": aae(s["normal"][m], s["true_normal"][m]), "aae_vs_nlips_deg": 0.0}
    return {
        "train_presses": len(train_data.names) - len(test_seen),
        "test_seen": test_seen,
        "unseen": unseen_data.names,
        "calibrate_seconds": {"train": t_train, "unseen": t_unseen},
        "train_seconds": times,
        "scores": rows,
        "models": {k: str(out / f"{k}.pt") for k in models},
    }


def fps_sensor(out: Path):
    """A 640x480 reference and press (rendered once), contact ~10 % of the image."""
    from nlipscalib.sim.indent import PressConfig
    from nlipscalib.sim.indenters import IndenterConfig
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    scene = load_scene().replace(render={"spp": 1, "bounces": 0})
    folder = out / "fps640"
    if not (folder / "press" / "meta.json").is_file():
        render_press(scene, None, folder / "reference", seed=1, overwrite=True)
        cfg = PressConfig(IndenterConfig(kind="sphere", size=8.0), polar_deg=10, azimuth_deg=30, depth=1.6)
        render_press(scene, cfg, folder / "press", seed=2, overwrite=True)
    return folder


def fps_model(key: str, trained_path: Path, folder: Path, out: Path) -> Path:
    """The trained weights re-targeted to the 640x480 sensor (weights' values do not change the speed)."""
    from nlipscalib.core import load_press
    from nlipscalib.core.sensor_record import sensor_of
    from nlipscalib.learn.dataset import reference_arrays
    from nlipscalib.learn.model import build_net, save_model

    src = load_model(trained_path)
    ref = load_press(folder / "reference")
    sensor = sensor_of(ref)
    net = build_net(src.hidden, 0.2, ref.camera.width, ref.camera.height)
    state = {k: v for k, v in src.net.state_dict().items() if k not in ("in_offset", "in_scale")}
    net.load_state_dict(state, strict=False)
    path = out / f"{key}_640.pt"
    save_model(path, net, hidden=src.hidden, dropout=0.2, sensor=sensor, reference=reference_arrays(ref), info=src.info)
    return path


BACKENDS = ("onnx", "onnx-int8")
COMMAND_FRAMES = 100
"""Frames of the video the whole `nlips infer` command is timed on (start-up and warm-up amortised)."""


def frames_per_second(model_paths: dict, folder: Path, out: Path, repeats: int) -> dict:
    """Per stage (change detection, network, integration) wall and process CPU per frame, for each net,
    onnxruntime float32 and int8, 1 and 2 threads, with the load average at the time."""
    from nlipscalib.core import load_press
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.onnx_export import export_onnx

    press = load_press(folder / "press")
    frame = press.linear(press.tricolor)
    result = {}
    for key, trained in model_paths.items():
        path = fps_model(key, Path(trained), folder, out)
        export_onnx(load_model(path), path.with_suffix(".onnx"))
        for backend in BACKENDS:
            for threads in (1, 2):
                pred = Predictor(path, backend=backend, threads=threads)
                pred.predict(frame)  # warm-up
                cpu0, wall0 = time.process_time(), time.perf_counter()
                runs = [pred.predict(frame).seconds for _ in range(repeats)]
                cpu = (time.process_time() - cpu0) / repeats
                wall = (time.perf_counter() - wall0) / repeats
                med = {k: float(np.median([r[k] for r in runs])) for k in runs[0]}
                fraction = int(pred.predict(frame).changed.sum()) / frame[..., 0].size
                # on a shared machine the wall clock counts other jobs' time; the process CPU time per
                # frame is what the cores this process used actually spent on it
                result[f"{key}/{backend}/{threads}t"] = med | {
                    "wall_fps_median": 1 / med["total"],
                    "wall_fps_mean": 1 / wall,
                    "cpu_s_per_frame": cpu,
                    "changed_fraction": fraction,
                    "load_average": os.getloadavg(),
                }
                print(
                    f"{key}/{backend}/{threads} threads: change {1e3 * med['change']:.1f} ms, network "
                    f"{1e3 * med['network']:.1f} ms, integrate {1e3 * med['integrate']:.1f} ms; wall "
                    f"{1 / med['total']:.1f} frames/s (median), CPU {cpu * 1000:.1f} ms/frame, changed {fraction:.3f}, "
                    f"load {os.getloadavg()[0]:.2f}",
                    flush=True,
                )
    result |= stream_command(model_paths, folder, out, repeats)
    return result


def stream_command(model_paths: dict, folder: Path, out: Path, repeats: int) -> dict:
    """The whole `nlips infer MODEL VIDEO` command on a lossless 8-bit video of the 640x480 press, timed
    from outside (process wall and CPU of the child)."""
    import resource

    import cv2

    from nlipscalib.core.imageio import read_png16

    video = out / "fps640.avi"
    if not video.is_file():
        rgb8 = (read_png16(folder / "press" / "tricolor.png") >> 8).astype(np.uint8)
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 30, rgb8.shape[1::-1])
        for _ in range(COMMAND_FRAMES):
            writer.write(np.ascontiguousarray(rgb8[..., ::-1]))
        writer.release()
    result = {}
    for key in model_paths:
        for backend in BACKENDS:
            cmd = [
                sys.executable,
                "-c",
                "import sys; from nlipscalib.cli import command; sys.exit(command())",
                "infer",
                str(out / f"{key}_640.pt"),
                str(video),
                "--backend",
                backend,
                "--threads",
                "2",
            ]
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            done = subprocess.run(cmd, capture_output=True, text=True, env=os.environ | {"PYTHONPATH": str(ROOT)})
            wall = time.perf_counter() - t0
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            result[f"{key}/{backend}/command"] = {
                "wall_s": wall,
                "cpu_s": cpu,
                "frames": COMMAND_FRAMES,
                "output": done.stdout.strip(),
                "load_average": os.getloadavg(),
            }
            print(f"{key}/{backend} command: {wall:.1f} s wall, {cpu:.1f} s CPU; {done.stdout.strip()}", flush=True)
    return result


def int8_accuracy(model_paths: dict, args) -> dict:
    """AAE of each net through onnxruntime float32 and int8 on the held-out presses (same samples as `accuracy`)."""
    from nlipscalib.learn.model import model_inputs
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx

    train_data = CalibrationDataset(Path(args.train) / "calibration")
    unseen_data = CalibrationDataset(Path(args.unseen) / "calibration")
    test_seen = train_data.names[-args.test_count :]
    splits = {"seen": train_data.arrays(test_seen), "unseen": unseen_data.arrays(unseen_data.names)}
    result = {}
    for key, path in model_paths.items():
        model = load_model(path)
        onnx_path = export_onnx(model, Path(args.out) / f"{key}_eval.onnx")
        for backend, int8 in (("onnx", False), ("onnx-int8", True)):
            net = OnnxNet(onnx_path, int8=int8)
            for split, s in splits.items():
                scores = sample_scores(net(model_inputs(s["pixel"], s["rgb"])), s)  # a ratio model's graph divides
                result[f"{key}/{backend}/{split}"] = scores
                print(f"{key} {backend} {split}: {scores}", flush=True)
    return result


def table(acc: dict) -> str:
    names = {
        "paper": "NLiPsNet 256-256-128 (NLiPs labels, dropout 0.2)",
        "paper_d0": "NLiPsNet 256-256-128 (NLiPs labels, no dropout)",
        "fast": "NLiPsNet 64-64-64 (NLiPs labels, no dropout)",
        "tiny": "NLiPsNet 32-32-32 (NLiPs labels, no dropout)",
        "upper": "NLiPsNet 256-256-128 (true normals, upper bound)",
        "lut": "lookup table (Yuan 2017)",
        "nlips": "NLiPs itself (the labels)",
    }
    lines = [
        "| method | seen: vs NLiPs | seen: vs true | unseen: vs NLiPs | unseen: vs true |",
        "|---|---|---|---|---|",
    ]
    for k, label in names.items():
        if k not in acc["scores"]["seen"]:  # a run before this variant existed
            continue
        s, u = acc["scores"]["seen"][k], acc["scores"]["unseen"][k]
        lines.append(
            f"| {label} | {s['aae_vs_nlips_deg']:.2f} | {s['aae_vs_true_deg']:.2f} | "
            f"{u['aae_vs_nlips_deg']:.2f} | {u['aae_vs_true_deg']:.2f} |"
        )
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--train", required=True)
    ap.add_argument("--unseen", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--test-count", type=int, default=6)
    ap.add_argument("--epochs", type=int, default=120)
    ap.add_argument("--patience", type=int, default=12)
    ap.add_argument("--seed", type=int, default=0, help="training seed (also picks the validation presses)")
    ap.add_argument("--max-minutes", type=float, default=0.0, help="training time limit per model")
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--no-solve", action="store_true", help="presses already solved: only rebuild the samples")
    ap.add_argument("--skip-accuracy", action="store_true", help="frames/s only (models from a previous run)")
    ap.add_argument(
        "--fps-model",
        action="append",
        default=[],
        metavar="KEY=MODEL",
        help="a trained model (of --train's sensor) timed and scored too, or instead of the run's model KEY",
    )
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    report = {"uptime_before": os.getloadavg()}
    if args.skip_accuracy:
        report["accuracy"] = json.loads((out / "bench_learn.json").read_text(encoding="utf-8"))["accuracy"]
    else:
        report["accuracy"] = accuracy(args)
    if report["accuracy"].get("scores"):
        print(table(report["accuracy"]), flush=True)
    folder = fps_sensor(out)
    models = {k: v for k, v in report["accuracy"]["models"].items() if k in ("paper", "fast", "tiny")}
    models |= dict(item.split("=", 1) for item in args.fps_model)
    report["int8_accuracy"] = int8_accuracy(models, args)
    report["fps"] = frames_per_second(models, folder, out, args.repeats)
    report["uptime_after"] = os.getloadavg()
    (out / "bench_learn.json").write_text(json.dumps(report, indent=2, default=float), encoding="utf-8")
    print(json.dumps(report["fps"], indent=1, default=float))


if __name__ == "__main__":
    main()
