"""Whole-command speed of ``nlips solve``: process wall time as a user measures it, next to the solver's timer.

Each case runs ``nlips solve PRESS ...`` as a fresh Python process (imports, loading, solving, saving,
figures: everything the user waits for) on an exact-data 640x480 sphere press (12 LEDs) and, when the
twin (Mitsuba) is installed, on rendered 640x480 sphere presses of the default scene with noise: one
bounce at 16 spp (the interreflection term and its outer loop run) and direct light at 4 spp; with
``--overwrite`` so every run solves. Reported per case: median process wall, the solver's own timer
(report.json ``seconds``), the pipeline's load and solve timers (``command_seconds``), and the rest
(imports, ROI/anchor work outside the solver's timer, saving, figures). Also the start-up floor
(``nlips --help`` and importing the solver) and a skipped re-run (identical result).

Each case runs twice over: with a **cold** disk cache (every run gets an empty ``NLIPS_CACHE_DIR``: the first
command on a sensor) and a **warm** one (filled by the case's warm-up run: every later command on that sensor;
``nlipscalib.core.diskcache``). A checkout without the disk cache ignores the variable.

The machine's 2 cores are shared with other work: the load average before and after is recorded.

With ``--against DIR`` (another checkout, e.g. ``git worktree add /tmp/before REV``) every run of each case
alternates between this checkout and that one on the same presses, so both see the same load; the table
gets the other checkout's medians next to this one's. Every process runs from a temporary folder with
``PYTHONPATH`` set: run from a checkout, Python's ``''`` path entry would import that checkout's package.

Run: .venv/bin/python benchmarks/bench_command.py [--repeats 3] [--no-twin] [--against DIR]
Writes the "bench_command" section of benchmarks/RESULTS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(ROOT))
from common import write_section  # noqa: E402

CLI = "import sys; from nlipscalib.cli import command; sys.exit(command())"
GOALS = {"full": 4.0, "auto ROI": 1.5}


def run_process(args: list[str], cpu: list | None = None, root: Path = ROOT, cache: str | None = None) -> float:
    """Wall seconds of ``python -c CLI args`` with ``root``'s package (fails loudly on a non-zero exit); appends
    its CPU seconds to ``cpu``. ``cache``: the disk cache folder (``NLIPS_CACHE_DIR``) it runs with.

    CPU time (user + system of the child) is the steadier number on a shared machine: it does not
    count the time the process waited for a core.
    """
    env = dict(os.environ, PYTHONPATH=str(root))
    if cache is not None:
        env["NLIPS_CACHE_DIR"] = cache
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", CLI, *args], env=env, capture_output=True, text=True, cwd=tempfile.gettempdir()
    )
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"nlips {' '.join(args)} failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    if cpu is not None:
        cpu.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)
    return wall


def run_python(code: str) -> float:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True, cwd=tempfile.gettempdir())
    return time.perf_counter() - t0


def time_case(
    press: Path, extra: list[str], repeats: int, roots: tuple[Path, ...] = (ROOT,), warm: bool = True
) -> list[dict]:
    """Median process wall and the inner timers of ``nlips solve press --overwrite extra``, per checkout in
    ``roots`` (their runs alternate); ``warm``: one disk cache per checkout, filled by the warm-up run, else an
    empty one for every run."""
    series = [{"wall": [], "cpu": [], "solver": [], "load": [], "solve": []} for _ in roots]
    with tempfile.TemporaryDirectory() as caches:
        for i in range(repeats + 1):  # the first run warms the page cache (and a warm case's disk cache)
            for k, (root, s) in enumerate(zip(roots, series)):
                cache = Path(caches) / (f"{k}" if warm else f"{k}-{i}")
                args = ["solve", str(press), "--overwrite", "--no-progress", *extra]
                s["wall"].append(run_process(args, s["cpu"], root, cache=str(cache)))
                _record(s, press)
    return [{k: statistics.median(v[1:]) for k, v in s.items()} for s in series]


def _record(s: dict, press: Path) -> None:
    """Append the run's inner timers (report.json) to the series ``s``."""
    report = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))
    s["solver"].append(report["seconds"])
    s["load"].append(report["command_seconds"]["load"])
    s["solve"].append(report["command_seconds"]["solve"])


BREAKDOWN = """
import json, sys, time
marks = []
def mark(name):
    marks.append((name, time.process_time(), time.perf_counter()))
mark("start")
import nlipscalib.cli
mark("import nlipscalib.cli (parser modules)")
import nlipscalib.solver
mark("import nlipscalib.solver (numpy, scipy.sparse[.linalg])")
from nlipscalib.core.capture import load_press
from nlipscalib.pipeline import make_provenance, make_settings
from nlipscalib.report import write_reconstruction_figures
from nlipscalib.core.reconstruction import save_reconstruction
from nlipscalib.solver import solve_press
mark("import pipeline, report")
folder, roi = sys.argv[1], (None if sys.argv[2] == "full" else "auto")
prov = make_provenance(folder, make_settings(roi=roi))
mark("settings + input hashes (provenance)")
press = load_press(folder)
mark("load_press (14 PNG + 2 npz)")
res = solve_press(press, roi=roi)
mark("solve_press: solver timer %.2f s wall" % res.report["seconds"])
save_reconstruction(res, sys.argv[3], overwrite=True)
mark("save result.npz + report.json")
write_reconstruction_figures(sys.argv[4], res, press.ground_truth)
mark("figure maps (OpenCV)")
print(json.dumps([(n, c - marks[i][1], w - marks[i][2]) for i, (n, c, w) in enumerate(marks[1:])]))
"""


def breakdown(press: Path, case: str, tmp: Path) -> list:
    """CPU and wall seconds of each stage of one solve, in one fresh process, with a warm disk cache (an
    earlier process of the same stages filled it)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT), NLIPS_CACHE_DIR=str(tmp / f"bd-cache-{case}"))
    args = [sys.executable, "-c", BREAKDOWN, str(press), case, str(tmp / "bd"), str(tmp / "bdf")]
    for _ in range(2):
        out = subprocess.run(args, env=env, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def twin_presses(tmp: Path) -> tuple[list[tuple[str, Path]], Path | None]:
    """((label, folder) of the rendered presses, the undeformed dome's capture); ([], None) without Mitsuba."""
    try:
        from nlipscalib.sim.indent import PressConfig
        from nlipscalib.sim.indenters import IndenterConfig
        from nlipscalib.sim.press import render_press
        from nlipscalib.sim.scene import load_scene
    except ImportError as exc:
        print(f"twin presses skipped: {exc}", flush=True)
        return [], None
    press = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5)
    base = load_scene().replace(camera={"width": 640, "height": 480}, noise={"enabled": True})
    out = []
    for label, render in (
        ("twin, bounces 1, 16 spp", {"bounces": 1, "spp": 16}),
        ("twin, bounces 0, 4 spp", {"bounces": 0, "spp": 4}),
    ):
        folder = tmp / label.replace(",", "").replace(" ", "_")
        render_press(base.replace(render=render), press, folder, seed=2)
        out.append((label, folder))
    undeformed = tmp / "undeformed_bounces_1"
    render_press(base.replace(render={"bounces": 1, "spp": 16}), None, undeformed, seed=1)
    return out, undeformed


def load_average() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-twin", action="store_true", help="exact-data press only (no Mitsuba renders)")
    parser.add_argument("--against", type=Path, help="another checkout to time alternately (its medians as 'before')")
    args = parser.parse_args()
    roots = (ROOT,) if args.against is None else (ROOT, args.against.resolve())
    if args.against is not None and not (args.against / "nlipscalib" / "cli").is_dir():
        raise SystemExit(f"--against {args.against}: not a checkout of nlipscalib (no nlipscalib/cli)")
    from tests.solver import synth

    before = load_average()
    with tempfile.TemporaryDirectory() as tmp:
        press = synth.make_press(Path(tmp) / "sphere", "sphere", size=(640, 480))
        floor = {
            "`nlips --help`": statistics.median(run_process(["--help"]) for _ in range(args.repeats)),
            "`import nlipscalib.core`": statistics.median(
                run_python("import nlipscalib.core") for _ in range(args.repeats)
            ),
            "`import nlipscalib.solver`": statistics.median(
                run_python("import nlipscalib.solver") for _ in range(args.repeats)
            ),
        }
        cases = [
            ("exact sphere", press, "full", "maps (default)", []),
            ("exact sphere", press, "full", "none", ["--no-figures"]),
            ("exact sphere", press, "auto ROI", "maps (default)", ["--roi", "auto"]),
            ("exact sphere", press, "auto ROI", "none", ["--roi", "auto", "--no-figures"]),
        ]
        twins, undeformed = ([], None) if args.no_twin else twin_presses(Path(tmp))
        for label, folder in twins:
            cases.append((label, folder, "auto ROI", "maps (default)", ["--roi", "auto"]))
            if "bounces 1" in label:  # the real-sensor workflow: the term fitted on the undeformed capture
                reference = ["--roi", "auto", "--reference", str(undeformed)]
                cases.append((label + ", `--reference`", folder, "auto ROI", "maps (default)", reference))
            if "bounces 0" in label:  # whole frames on the direct-light press only: a one-bounce whole frame is
                # timed by hand (benchmarks/RESULTS.md, the sessions' whole-command sections)
                cases.append((label, folder, "full", "maps (default)", []))
        rows = []
        for label, folder, name, figs, extra in cases:
            for warm in (False, True):
                measured = time_case(folder, extra, args.repeats, roots, warm=warm)
                rows.append((label, name, figs, "warm" if warm else "cold", *measured))
                print(rows[-1], flush=True)
        stages = {case: breakdown(press, case, Path(tmp)) for case in ("full", "auto")}
        rerun = ["solve", str(press), "--roi", "auto", "--no-progress"]
        run_process(rerun)  # the last case ran without figures: this first re-run adds them, later ones skip
        skip = statistics.median(run_process(rerun) for _ in range(args.repeats))
    after = load_average()
    lines = [
        f"`nlips solve` on 640x480 sphere presses (12 LEDs, default options): exact data, and twin renders "
        "(default scene, noise on); each run a fresh "
        f"process with `--overwrite`; median of {args.repeats} after a warm-up. Load average (1/5/15 min) "
        f"before: {before}, after: {after} (2 cores shared with other helpers' work: expect several-fold "
        "inflation of every number when the load is above 2).",
        "",
        "| press | case | figures | disk cache | process wall s | process CPU s | solver timer s | load s "
        "| solve_press s | rest s (imports, save, figures) | goal s |"
        + (" before: wall s / solver s |" if args.against else ""),
        "|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if args.against else ""),
    ]
    for label, name, figs, cache, m, *other in rows:
        rest = m["wall"] - m["load"] - m["solve"]
        lines.append(
            f"| {label} | {name} | {figs} | {cache} | {m['wall']:.2f} | {m['cpu']:.2f} | {m['solver']:.2f} "
            f"| {m['load']:.2f} "
            f"| {m['solve']:.2f} | {rest:.2f} | {GOALS[name]:.1f} |"
            + "".join(f" {o['wall']:.2f} / {o['solver']:.2f} |" for o in other)
        )
    if args.against:
        lines += ["", f"`before`: the checkout {args.against} (its runs alternate with this one's, same presses)."]
    lines += [
        "",
        "`disk cache`: cold = every run starts from an empty `NLIPS_CACHE_DIR` (the first command on a sensor; it "
        "writes the sensor's entries), warm = the entries the warm-up run wrote (every later command on that "
        "sensor). The `--reference` rows fit the interreflection term on a capture of the undeformed dome "
        "(one bounce, 16 spp, another noise seed).",
    ]
    lines += [
        "",
        "`solver timer s` is the NLiPs solver's own timer summed over the outer interreflection passes; "
        "`solve_press s` adds the contact classification (auto ROI, anchoring) and the interreflection term's "
        "fit and gathers (solver/press.py). "
        "Process CPU s (user + system) does not count waiting for a core; PNG decoding and map writing use "
        "threads, so it can exceed wall time on an idle machine.",
        "",
        "| start-up and re-run | process wall s |",
        "|---|---|",
        *(f"| {k} | {v:.2f} |" for k, v in floor.items()),
        f"| identical re-run (`--roi auto`, skipped) | {skip:.2f} |",
        "",
        "Where one solve's time goes (one fresh process per case after one that filled its disk cache, stages "
        "in order; CPU s does not count waiting for a core):",
        "",
        "| stage | full: CPU s | full: wall s | auto ROI: CPU s | auto ROI: wall s |",
        "|---|---|---|---|---|",
    ]
    for (name, cf, wf), (_, ca, wa) in zip(stages["full"], stages["auto"]):
        label = name.split(":")[0] if name.startswith("solve_press") else name
        lines.append(f"| {label} | {cf:.2f} | {wf:.2f} | {ca:.2f} | {wa:.2f} |")
    write_section("bench_command", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
