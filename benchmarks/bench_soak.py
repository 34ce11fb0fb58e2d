"""Soak test of the real-time paths: a long stream (or many emulated captures in one process), with the process's
memory, threads, open files, CPU, frame rate and output size sampled over time.

Run (from the checkout, a model of the emulated sensor first: README, "NLiPsNet"):
  PYTHONPATH=. python benchmarks/bench_soak.py stream --model emu.pt --session emu --frames 200000 --work /tmp/soak
  PYTHONPATH=. python benchmarks/bench_soak.py stream --model emu.pt --emulate nlipstac --command live --frames 20000 \
      --work /tmp/soak-live
  PYTHONPATH=. python benchmarks/bench_soak.py capture --sessions 40 --work /tmp/soak-capture

``stream`` runs the user's command (``nlips infer MODEL 'seq/img_%06d.png'``: an image sequence of ``--frames``
symbolic links, 10 to each tri-colour frame of ``--session``'s folders in turn; or ``--emulate SCENE`` with
``--max-frames``) in its own process under a pseudo-terminal (so it prints its running rate each second), with
``--out`` (``--every``) and ``--log-file``, and samples /proc/PID every ``--sample-s`` seconds: VmRSS, VmHWM,
threads, open file descriptors, CPU (user + system) and the size of the output folder and the log. ``capture``
runs ``nlips capture --emulate`` ``--sessions`` times in this process (``nlipscalib.cli.main``; each session's
folder removed after it) and samples this process after each: what a lab's script looping over sessions keeps.

Prints a markdown table and the drift of each quantity over the run's second half (least-squares slope), for
benchmarks/RESULTS.md. No assertion: tests/device/test_soak.py holds the bounded-growth checks.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's package, not an installed one

PAGE_KB = os.sysconf("SC_PAGE_SIZE") / 1024
TICKS = os.sysconf("SC_CLK_TCK")


def sample(pid: int) -> dict:
    """The process's memory (MB), threads, open files and CPU seconds now, from /proc (Linux)."""
    status = Path(f"/proc/{pid}/status").read_text(encoding="utf-8")
    field = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    field = {k: v.split()[0] for k, v in field.items() if v.split()}  # a zombie's memory lines are gone
    stat = Path(f"/proc/{pid}/stat").read_text(encoding="utf-8").rsplit(")", 1)[1].split()
    return {
        "rss_mb": int(field["VmRSS"]) / 1024,
        "hwm_mb": int(field["VmHWM"]) / 1024,
        "threads": int(field["Threads"]),
        "fds": len(os.listdir(f"/proc/{pid}/fd")),
        "cpu_s": (int(stat[11]) + int(stat[12])) / TICKS,  # utime, stime
    }


def folder_size(folder: Path) -> tuple[int, int]:
    """(files, bytes) under ``folder`` (0, 0 when missing)."""
    files = size = 0
    for dirpath, _, names in os.walk(folder):
        for name in names:
            try:
                size += os.stat(os.path.join(dirpath, name)).st_size
                files += 1
            except FileNotFoundError:  # a temporary renamed while walking
                pass
    return files, size


def make_sequence(session: Path, frames: int, folder: Path) -> str:
    """``frames`` symbolic links ``folder/img_NNNNNN.png``, 10 to each tri-colour frame of the session's folders in
    turn (reference first): a long recording of a few presses on a few kB of disk. Returns the pattern."""
    sources = [p / "tricolor.png" for p in sorted(session.iterdir()) if (p / "tricolor.png").is_file()]
    sources.sort(key=lambda p: p.parent.name != "reference")
    if not sources:
        raise SystemExit(f"{session}: no folder with a tricolor.png")
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(frames):
        link = folder / f"img_{i:06d}.png"
        if not link.is_symlink():
            link.symlink_to(sources[(i // 10) % len(sources)].resolve())
    return str(folder / "img_%06d.png")


def stream(args: argparse.Namespace) -> list[dict]:
    """Run the stream command under a pseudo-terminal and sample it; returns the samples."""
    import pty

    work = Path(args.work)
    out, log_file = work / "out", work / "nlips.log"
    shutil.rmtree(out, ignore_errors=True)
    log_file.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "nlipscalib", args.command]
    if args.command == "live":
        cmd += ["--model", args.model, "--no-window"]
    else:
        cmd += [args.model]
    if args.emulate:
        cmd += ["--emulate", args.emulate, "--max-frames", str(args.frames)]
    else:
        cmd += [make_sequence(Path(args.session), args.frames, work / "seq")]
    cmd += ["--out", str(out), "--every", str(args.every), "--log-file", str(log_file)]
    print("$", " ".join(cmd), file=sys.stderr)
    master, slave = pty.openpty()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=slave, env=env, text=True)
    os.close(slave)
    rates: list[tuple[float, float]] = []  # (time, fps) of each running-rate line
    said: list[str] = []  # the other lines on the terminal: the summary is on stderr, stdout holds the --out folder

    def read_terminal() -> None:
        buffer = b""
        while True:
            try:
                chunk = os.read(master, 4096)
            except OSError:  # the command ended: the terminal closed
                return
            if not chunk:
                return
            buffer += chunk
            *lines, buffer = re.split(rb"[\r\n]+", buffer)
            for line in lines:
                m = re.fullmatch(rb"\s*([0-9.]+) fps\s*", line)
                if m:
                    rates.append((time.monotonic() - t0, float(m.group(1))))
                elif line.strip():
                    said.append(line.decode(errors="replace"))
                    print(said[-1], file=sys.stderr)

    reader = threading.Thread(target=read_terminal, daemon=True)
    reader.start()
    samples = []
    while proc.poll() is None:
        time.sleep(args.sample_s)
        try:
            s = sample(proc.pid)
        except (FileNotFoundError, ProcessLookupError, KeyError):  # ended between poll() and the read
            break
        s["t"] = time.monotonic() - t0
        s["out_files"], out_bytes = folder_size(out)
        s["out_mb"] = out_bytes / 1e6
        s["log_kb"] = log_file.stat().st_size / 1e3 if log_file.exists() else 0.0
        samples.append(s)
    stdout = proc.communicate()[0]
    wall = time.monotonic() - t0
    reader.join(timeout=2)
    os.close(master)
    print(stdout, file=sys.stderr)
    _rates_between(samples, rates)
    result = stdout.strip().splitlines()[:1]
    print(f"exit {proc.returncode}, process wall {wall:.1f} s; result: {result}; summary: {said[-1:]}")
    return samples


def _rates_between(samples: list[dict], rates: list[tuple[float, float]]) -> None:
    """Each sample's fps: the mean of the running-rate lines printed since the sample before."""
    before = 0.0
    for s in samples:
        got = [fps for t, fps in rates if before < t <= s["t"]]
        s["fps"] = sum(got) / len(got) if got else float("nan")
        before = s["t"]


def capture(args: argparse.Namespace) -> list[dict]:
    """``nlips capture --emulate`` ``--sessions`` times in this process; this process sampled after each."""
    from nlipscalib.cli import main

    work = Path(args.work)
    samples = []
    t0 = time.monotonic()
    for i in range(args.sessions):
        folder = work / f"session{i:04d}"
        shutil.rmtree(folder, ignore_errors=True)
        argv = ["capture", "--emulate", args.scene, "--presses", str(args.presses), "--width", str(args.width)]
        argv += ["--height", str(args.height), "--out", str(folder), "--yes", "--no-progress"]
        code = main(argv)
        if code != 0:
            raise SystemExit(f"nlips capture exited {code} in session {i}")
        shutil.rmtree(folder)
        s = sample(os.getpid())
        s.update(t=time.monotonic() - t0, session=i + 1)
        samples.append(s)
    return samples


def slope(samples: list[dict], key: str) -> float:
    """Least-squares slope of ``key`` per minute over the second half of the samples (after the warm-up)."""
    half = [s for s in samples[len(samples) // 2 :] if s.get(key) == s.get(key)]  # NaN-free
    if len(half) < 2:
        return float("nan")
    ts = [s["t"] / 60 for s in half]
    ys = [s[key] for s in half]
    mt, my = sum(ts) / len(ts), sum(ys) / len(ys)
    den = sum((t - mt) ** 2 for t in ts)
    return sum((t - mt) * (y - my) for t, y in zip(ts, ys)) / den if den else float("nan")


def table(samples: list[dict], keys: list[str], rows: int) -> str:
    """A markdown table of about ``rows`` samples, evenly spaced (the first and last included)."""
    step = max(1, len(samples) // rows)
    picked = samples[::step] + ([samples[-1]] if (len(samples) - 1) % step else [])
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    for s in picked:
        cells = [f"{s[k]:.1f}" if isinstance(s[k], float) else str(s[k]) for k in keys]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="what", required=True)
    s = sub.add_parser("stream", help="a long `nlips infer` / `nlips live` stream, sampled from outside")
    s.add_argument("--model", required=True)
    s.add_argument("--session", help="a capture session (its folders' tricolor.png make the frames)")
    s.add_argument("--emulate", metavar="SCENE", help="stream the emulated sensor instead of an image sequence")
    s.add_argument("--command", choices=("infer", "live"), default="infer")
    s.add_argument("--frames", type=int, default=100000)
    s.add_argument("--every", type=int, default=1000, help="--every of the command's --out")
    s.add_argument("--sample-s", type=float, default=5.0)
    c = sub.add_parser("capture", help="`nlips capture --emulate` many times in one process")
    c.add_argument("--sessions", type=int, default=40)
    c.add_argument("--presses", type=int, default=2)
    c.add_argument("--scene", default="nlipstac")
    c.add_argument("--width", type=int, default=160)
    c.add_argument("--height", type=int, default=120)
    for p in (s, c):
        p.add_argument("--work", required=True, help="scratch folder (frames, output, log)")
        p.add_argument("--rows", type=int, default=12, help="rows of the printed table")
        p.add_argument("--json", help="also write every sample to this file")
    args = parser.parse_args()
    if args.what == "stream" and not (args.emulate or args.session):
        parser.error("stream needs --session (an image sequence is made of it) or --emulate SCENE")
    Path(args.work).mkdir(parents=True, exist_ok=True)
    samples = stream(args) if args.what == "stream" else capture(args)
    if not samples:
        raise SystemExit("no samples: the command ended before the first one (see its output above)")
    if args.json:
        Path(args.json).write_text(json.dumps(samples, indent=1), encoding="utf-8")
    if args.what == "stream":
        keys = ["t", "rss_mb", "hwm_mb", "threads", "fds", "cpu_s", "fps", "out_files", "out_mb", "log_kb"]
    else:
        keys = ["session", "t", "rss_mb", "hwm_mb", "threads", "fds", "cpu_s"]
    print(table(samples, keys, args.rows))
    drift = ", ".join(f"{k} {slope(samples, k):+.3f}/min" for k in ("rss_mb", "threads", "fds", "fps") if k in keys)
    print(f"second-half drift: {drift}")


if __name__ == "__main__":
    main()
