"""A watched folder's frames read ahead on one thread (``device.live.ReadAhead`` over ``WatchedFolder``) against read
on the stream's thread, with a writer that renames a frame into the folder every ``--period`` s: frames/s and each
frame's latency (from its rename to its result), interleaved.

In process (default): ``device.live.stream`` of the same ``WatchedFolder`` with and without the read-ahead, the
predictor ``learn.watch.MismatchWatch`` over the model (as ``nlips live --model`` runs it), no output; a frame's
latency from its rename (``time.perf_counter`` after ``os.replace``) to the end of its predictor call (a sink).
Whole commands (``--before CHECKOUT [--after CHECKOUT]``): ``nlips infer MODEL --watch FOLDER --out OUT --max-frames N``
of a checkout without the read-ahead and of one with it (default: this one), each a user's process (``--live``: this
checkout's ``nlips live --model MODEL --watch FOLDER --no-window --out OUT --max-frames N``, what a lab watching a
folder runs, against its ``nlips infer`` of the same); a frame's latency from its rename to its ``frame_NNNNNN.npz``
(the file's modification time against ``time.time()`` after the rename: the kernel's coarse file clock, a few ms).

Run: .venv/bin/python benchmarks/bench_watch_read_ahead.py --model M.pt --frame PRESS/tricolor.png
     [--frames 40] [--pairs 3] [--periods 0.05,0.25] [--before CHECKOUT [--after CHECKOUT] | --live]
Prints Markdown; the results are in benchmarks/RESULTS.md (s39-livewatch: --before 1f11bc1c, --after 83904661, the
commit that read watched folders ahead; measured no gain, so the product reads them on the stream's thread).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench_infer_watch import STREAM_RATE, run_watched  # noqa: E402  (the process harness: one copy)


def _writer(frame: Path, folder: Path, n: int, period: float, landed: list[float], clock=time.perf_counter):
    """Rename a copy of ``frame`` into ``folder`` every ``period`` s, ``n`` times; ``landed``: each rename's time."""

    def write() -> None:
        next_at = time.perf_counter()
        for i in range(n):
            next_at += period
            time.sleep(max(0.0, next_at - time.perf_counter()))  # a fixed rate, not period + copy time
            tmp = folder / f".f{i:04d}.png.part"
            shutil.copyfile(frame, tmp)
            os.replace(tmp, folder / f"f{i:04d}.png")
            landed.append(clock())

    return write


def in_process(model: Path, frame: Path, n: int, period: float, ahead: bool, work: Path) -> dict:
    """One in-process stream of ``n`` frames written every ``period`` s (see the module's docstring)."""
    from nlipscalib.device.live import ReadAhead, stream
    from nlipscalib.device.watch_folder import WatchedFolder
    from nlipscalib.learn.infer import Predictor
    from nlipscalib.learn.watch import MismatchWatch

    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    predictor = _predictor(model, Predictor)
    watch = MismatchWatch(predictor, str(work), in_light=True)
    landed: list[float] = []
    done: list[float] = []
    stopping = threading.Event()  # ends the read-ahead thread's wait for a file that never comes, so it is joined
    watched = WatchedFolder(work, predictor.shape, tone_curve=predictor.tone_curve, stop=stopping.is_set)
    source = ReadAhead(watched) if ahead else watched
    thread = threading.Thread(target=_writer(frame, work, n, period, landed))
    c0 = time.process_time()
    thread.start()
    try:
        stats = stream(source, watch, [lambda i, f, r: done.append(time.perf_counter())], max_frames=n, report=None)
    finally:
        stopping.set()
        source.close()
        if ahead:
            watched.close()
        thread.join()
    cpu = time.process_time() - c0
    latencies = [1e3 * (d - w) for d, w in zip(done, landed)]
    return {
        "fps": stats.frames / (done[-1] - landed[0]),  # first frame's landing to the last result
        "latency": statistics.median(latencies),
        "p90": statistics.quantiles(latencies, n=10)[-1],
        "cpu": cpu,
    }


_PREDICTORS: dict = {}


def _predictor(model: Path, make):
    if model not in _PREDICTORS:  # loaded once: the stream, not the model's load, is timed
        _PREDICTORS[model] = make(model)
    return _PREDICTORS[model]


def _env(root: Path, tag: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(PYTHONPATH=str(root), PYTHONPYCACHEPREFIX=f"/tmp/bench-{tag}-pyc", NLIPS_CACHE_DIR=f"/tmp/bench-{tag}-c")
    return env


def whole_command(
    root: Path, model: Path, frame: Path, n: int, period: float, work: Path, tag: str, live: bool = False
) -> dict:
    """``nlips infer MODEL --watch`` (``live``: ``nlips live --model MODEL --watch``) of the checkout ``root``, a
    writer renaming a frame in every ``period`` s once it says it is watching."""
    shutil.rmtree(work, ignore_errors=True)
    folder, out = work / "frames", work / "out"
    folder.mkdir(parents=True)
    landed: list[float] = []
    command = ["live", "--model", str(model), "--no-window"] if live else ["infer", str(model)]
    args = [*command, "--watch", str(folder), "--out", str(out), "--max-frames", str(n)]
    result = run_watched(args, _env(root, tag), _writer(frame, folder, n, period, landed, clock=time.time))
    rate = STREAM_RATE.search(result["said"])
    saved = [os.stat(out / f"frame_{i:06d}.npz").st_mtime for i in range(n)]
    latencies = [1e3 * (s - w) for s, w in zip(saved, landed)]
    return {
        "wall": result["wall"],
        "cpu": result["cpu"],
        "fps": float(rate.group(3)),
        "latency": statistics.median(latencies),
        "p90": statistics.quantiles(latencies, n=10)[-1],
    }


def spread(values: list[float], digits: int = 1) -> str:
    return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, required=True)
    ap.add_argument("--frame", type=Path, required=True, help="a 16-bit tri-colour PNG of the model's size")
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--periods", default="0.05,0.25", help="seconds between the writer's frames, comma-separated")
    ap.add_argument("--before", type=Path, help="a checkout without the read-ahead: whole commands, it against --after")
    ap.add_argument("--after", type=Path, default=ROOT, help="a checkout with the read-ahead (default: this one)")
    ap.add_argument("--live", action="store_true", help="whole `nlips live --watch` commands of this checkout alone")
    args = ap.parse_args()
    model, frame = args.model.resolve(), args.frame.resolve()
    periods = [float(p) for p in args.periods.split(",")]
    from common import machine

    print(f"machine: {machine()}; load average at the start {'/'.join(f'{x:.1f}' for x in os.getloadavg())}\n")
    if args.live:
        sides = {"`nlips infer --watch`": False, "`nlips live --model --watch --no-window`": True}
        what = "whole commands of this checkout, --out, `nlips infer` and `nlips live` interleaved"
    elif args.before is None:
        sides, what = {"on the stream's thread": False, "read ahead (one thread)": True}, "in process, no output"
    else:
        sides = {
            f"before ({args.before.name})": args.before.resolve(),
            f"after ({args.after.name})": args.after.resolve(),
        }
        what = "whole `nlips infer --watch --out` commands"
    with tempfile.TemporaryDirectory(prefix="bench-watch-ahead-") as tmp:
        work = Path(tmp) / "w"

        def run(side: str, period: float) -> dict:
            if args.live:
                tag = f"s39-{'live' if sides[side] else 'infer'}"
                return whole_command(ROOT, model, frame, args.frames, period, work, tag, live=sides[side])
            if args.before is not None:
                tag = f"s39-ahead-{side[:5]}"
                return whole_command(sides[side], model, frame, args.frames, period, work, tag)
            return in_process(model, frame, args.frames, period, sides[side], work)

        rows = {(side, p): [] for p in periods for side in sides}
        for side in sides:  # warm-up: the model, bytecode, page caches
            run(side, periods[0])
        for _ in range(args.pairs):
            for period in periods:
                for side in sides:
                    rows[side, period].append(run(side, period))
    load = os.getloadavg()
    print(
        f"{what}: {args.frames} frames of {frame} a run, n = {args.pairs} a row after one warm-up a side, "
        f"interleaved; load average at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}\n"
    )
    whole = args.before is not None or args.live
    extra = " process wall s |" if whole else ""
    print(f"| writer's period s | reading |{extra} frames/s | median latency ms | p90 latency ms | CPU s |")
    print("|---|---|" + "---|" * (5 if whole else 4))
    for (side, period), r in rows.items():
        wall = f" {spread([x['wall'] for x in r], 2)} |" if whole else ""
        print(
            f"| {period} | {side} |{wall} {spread([x['fps'] for x in r])} | {spread([x['latency'] for x in r], 0)} | "
            f"{spread([x['p90'] for x in r], 0)} | {spread([x['cpu'] for x in r], 2)} |"
        )


if __name__ == "__main__":
    main()
