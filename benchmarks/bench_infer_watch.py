"""``nlips infer MODEL --watch FOLDER`` against the same frames streamed from a folder (``--camera FOLDER``), whole
commands, interleaved.

Watch: the command started on an empty folder; once it says it is watching, a writer drops ``--frames`` copies of one
tri-colour PNG into the folder, each written under a hidden temporary name and renamed into place, as camera
programs do, either as fast as it can (throughput) or every ``--period`` s (latency: from each rename to its
``frame_NNNNNN.npz`` being written, from the files' modification times); ``--max-frames`` ends the command.
Folder: ``nlips infer MODEL --camera FOLDER`` on a folder already holding the same frames (decoded ahead on several
threads). Both with ``--out`` (normal-map PNG and npz a frame: the stream's outputs). Each process runs as a user's
does (``common.nlips_process``' environment: bytecode written under a prefix of its own, its own disk cache).

Reading alone (``--read-only``, in process, no model): the CPU time and wall a frame of ``WatchedFolder.read`` (its
observer thread's events, the settle check, the decoding) for frames renamed into the folder all at once, against
``FolderSource.frame_at`` (the decoding alone) of the same files; and, with frames renamed in one every ``--period``
s, the time from each rename to ``read`` returning its frame.

Run: .venv/bin/python benchmarks/bench_infer_watch.py --model M.pt --frame PRESS/tricolor.png
     [--frames 30] [--pairs 3] [--period 0.2]
     .venv/bin/python benchmarks/bench_infer_watch.py --read-only --frame PRESS/tricolor.png [--frames 30] [--pairs 5]
Prints Markdown; the results are in benchmarks/RESULTS.md (s38-inferwatch).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
STREAM_RATE = re.compile(r"(\d+) frames in ([0-9.]+) s: ([0-9.]+) fps")
PREDICTOR = re.compile(r"= ([0-9.]+) frames/s for the predictor alone")


def _env(tag: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    path = os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")]))
    env.update(PYTHONPATH=path, PYTHONPYCACHEPREFIX=f"/tmp/bench-{tag}-pyc", NLIPS_CACHE_DIR=f"/tmp/bench-{tag}-cache")
    return env


def _run(args: list[str], tag: str, writer=None) -> dict:
    """:func:`run_watched` of this checkout."""
    return run_watched(args, _env(tag), writer)


def run_watched(args: list[str], env: dict, writer=None) -> dict:
    """One ``nlips`` process: wall s, user+sys s, its stderr; ``writer()`` runs beside it on a thread once the
    command says it is watching (``--watch``). Shared with bench_watch_read_ahead.py."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", "nlipscalib", "--no-progress", *args],
        cwd=tempfile.gettempdir(),
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    lines, thread = [], None
    for line in proc.stderr:
        lines.append(line)
        if writer is not None and thread is None and line.startswith("watching "):
            thread = threading.Thread(target=writer)
            thread.start()
    proc.wait()
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if thread is not None:
        thread.join()
    if proc.returncode != 0:
        raise SystemExit(f"nlips {' '.join(args)}: exit {proc.returncode}\n{''.join(lines)}")
    cpu = after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime
    return {"wall": wall, "cpu": cpu, "said": "".join(lines)}


def _writer(frame: Path, folder: Path, n: int, period: float, landed: list[float]):
    def write() -> None:
        for i in range(n):
            if period:
                time.sleep(period)
            tmp = folder / f".f{i:04d}.png.part"
            shutil.copyfile(frame, tmp)
            os.replace(tmp, folder / f"f{i:04d}.png")
            landed.append(os.stat(folder / f"f{i:04d}.png").st_mtime)

    return write


def one(side: str, model: Path, frame: Path, n: int, period: float, work: Path) -> dict:
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    frames, out = work / "frames", work / "out"
    frames.mkdir()
    if side == "folder":
        for i in range(n):
            shutil.copyfile(frame, frames / f"f{i:04d}.png")
        result = _run(["infer", str(model), "--camera", str(frames), "--out", str(out)], "s38-inferwatch-folder")
        landed = []
    else:
        landed: list[float] = []
        writer = _writer(frame, frames, n, period if side == "watch paced" else 0.0, landed)
        args = ["infer", str(model), "--watch", str(frames), "--out", str(out), "--max-frames", str(n)]
        result = _run(args, "s38-inferwatch-watch", writer)
    rate = STREAM_RATE.search(result["said"])
    predictor = PREDICTOR.search(result["said"])
    result |= {"frames": int(rate.group(1)), "stream_fps": float(rate.group(3))}
    result["predictor_fps"] = float(predictor.group(1)) if predictor else float("nan")
    if landed:  # each frame's arrays written, against its file's landing (both the file system's clock)
        from nlipscalib.cli._watch import WATCHED_FILES

        named = (out / WATCHED_FILES).read_text(encoding="utf-8").splitlines()[1:]
        if [line.split("\t")[1] for line in named] != [f"f{i:04d}.png" for i in range(n)]:
            raise SystemExit(f"{out / WATCHED_FILES}: not the frames in the order written")
        saved = [os.stat(out / f"frame_{i:06d}.npz").st_mtime for i in range(n)]
        result["latency_ms"] = statistics.median(1e3 * (s - w) for s, w in zip(saved, landed))
    return result


def read_only(frame: Path, n: int, rounds: int, period: float) -> None:
    """Reading alone: ``WatchedFolder.read`` against ``FolderSource.frame_at`` (see the module's docstring)."""
    from nlipscalib.device.camera import FolderSource
    from nlipscalib.device.watch_folder import WatchedFolder

    rows = {"folder (decode)": [], "watch (events + decode)": []}
    delays = []
    with tempfile.TemporaryDirectory(prefix="bench-inferwatch-read-") as tmp:
        staged, watched = Path(tmp) / "staged", Path(tmp) / "watched"
        for r in range(rounds + 1):  # round 0: warm-up
            for folder in (staged, watched):
                shutil.rmtree(folder, ignore_errors=True)
                folder.mkdir()
            for i in range(n):
                shutil.copyfile(frame, staged / f"f{i:04d}.png")
            source = FolderSource(staged)
            c0, t0 = time.process_time(), time.perf_counter()
            for i in range(n):
                source.frame_at(i)
            folder_times = ((time.process_time() - c0) / n, (time.perf_counter() - t0) / n)
            with WatchedFolder(watched, source.shape) as watch:
                c0, t0 = time.process_time(), time.perf_counter()
                for i in range(n):
                    os.replace(staged / f"f{i:04d}.png", watched / f"f{i:04d}.png")
                for _ in range(n):
                    watch.read()
                watch_times = ((time.process_time() - c0) / n, (time.perf_counter() - t0) / n)
                if period:  # one frame at a time: from its rename to read() returning it
                    for i in range(n):
                        tmp_file = watched / f".p{i:04d}.part"
                        shutil.copyfile(frame, tmp_file)
                        time.sleep(period)
                        t0 = time.perf_counter()
                        os.replace(tmp_file, watched / f"p{i:04d}.png")
                        watch.read()
                        if r:
                            delays.append(time.perf_counter() - t0)
            if r:
                rows["folder (decode)"].append(folder_times)
                rows["watch (events + decode)"].append(watch_times)

    def spread(values: list[float]) -> str:
        ms = [1e3 * v for v in values]
        return f"{statistics.median(ms):.2f} [{min(ms):.2f}-{max(ms):.2f}]"

    load = os.getloadavg()
    print(
        f"{n} frames of {frame} a round, {rounds} rounds after a warm-up; load average at the end "
        f"{load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}\n"
    )
    print("| reading | CPU ms a frame | wall ms a frame |\n|---|---|---|")
    for side, times in rows.items():
        print(f"| {side} | {spread([c for c, _ in times])} | {spread([w for _, w in times])} |")
    if delays:
        print(f"\nOne frame every {period} s: rename to read() returning it, ms: {spread(delays)} (n = {len(delays)})")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, help="model file (not with --read-only)")
    ap.add_argument("--read-only", action="store_true", help="reading alone, in process, no model")
    ap.add_argument("--frame", type=Path, required=True, help="a 16-bit tri-colour PNG of the model's size")
    ap.add_argument("--frames", type=int, default=30)
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--period", type=float, default=0.2, help="seconds between frames of the paced writer")
    args = ap.parse_args()
    if args.read_only:
        read_only(args.frame.resolve(), args.frames, args.pairs, args.period)
        return
    if args.model is None:
        ap.error("--model is required (or --read-only)")
    sides = ("folder", "watch", "watch paced")
    runs = {side: [] for side in sides}
    with tempfile.TemporaryDirectory(prefix="bench-inferwatch-") as tmp:
        for side in sides:  # warm-up: bytecode, page and disk caches
            one(side, args.model.resolve(), args.frame.resolve(), args.frames, args.period, Path(tmp) / "w")
        for _ in range(args.pairs):
            for side in sides:
                runs[side].append(
                    one(side, args.model.resolve(), args.frame.resolve(), args.frames, args.period, Path(tmp) / "w")
                )
    load = os.getloadavg()
    from common import machine

    print(f"machine: {machine()}")

    def spread(values: list[float], digits: int = 2) -> str:
        return f"{statistics.median(values):.{digits}f} [{min(values):.{digits}f}-{max(values):.{digits}f}]"

    print(
        f"{args.frames} frames of {args.frame} a run, n = {args.pairs} a side after one warm-up each, interleaved; "
        f"load average at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f}\n"
    )
    print("| mode | process wall s | user+sys s | stream frames/s | predictor frames/s | median latency ms |")
    print("|---|---|---|---|---|---|")
    for side in sides:
        r = runs[side]
        latency = spread([x["latency_ms"] for x in r], 0) if "latency_ms" in r[0] else "-"
        print(
            f"| {side} | {spread([x['wall'] for x in r])} | {spread([x['cpu'] for x in r])} | "
            f"{spread([x['stream_fps'] for x in r], 1)} | {spread([x['predictor_fps'] for x in r], 1)} | {latency} |"
        )


if __name__ == "__main__":
    main()
