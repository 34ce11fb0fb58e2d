"""Benchmark: one full press (12 LED images + tri-colour + dark + GT + noise + PNG write) at 640x480.

Run: ``.venv/bin/python benchmarks/bench_render.py [--repeats 5] [--threads 0]``. Updates its section
of benchmarks/RESULTS.md. Goals on the 2-core CPU: bounces 0 @ 4 spp <= 2 s, bounces 1 @ 16 spp <= 8 s.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import re
import statistics
import sys
import tempfile
import time
from pathlib import Path

RESULTS = Path(__file__).with_name("RESULTS.md")
SECTION = "## bench_render"
CASES = ((0, 4, 2.0), (1, 16, 8.0))  # (bounces, spp, goal seconds)


def _press():
    try:
        from nlipscalib.sim.indent import PressConfig

        from nlipscalib.cli.render import DEFAULT_PRESS
        from nlipscalib.config import from_mapping
    except ModuleNotFoundError:
        return None  # indentation not available yet: the undeformed dome costs the same to render
    return from_mapping(PressConfig, DEFAULT_PRESS | {"indenter": {"kind": "sphere"}}, "press")


def bench(repeats: int, threads: int) -> list[dict]:
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene

    press = _press()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for bounces, spp, goal in CASES:
            scene = load_scene().replace(render={"spp": spp, "bounces": bounces, "threads": threads})
            render_press(scene, press, Path(tmp) / "warm", seed=0, overwrite=True)  # kernel compile, caches
            full, render = [], []
            for i in range(repeats):
                t = time.perf_counter()
                _, res = render_press(scene, press, Path(tmp) / "p", seed=i, overwrite=True, return_result=True)
                full.append(time.perf_counter() - t)
                render.append(res.seconds)
            rows.append(
                {
                    "bounces": bounces,
                    "spp": spp,
                    "goal": goal,
                    "full": statistics.median(full),
                    "render": statistics.median(render),
                    "variant": res.variant,
                    "press": press is not None,
                }
            )
    return rows


def write_results(rows: list[dict], repeats: int, threads: int, load: str) -> str:
    lines = [
        SECTION,
        "",
        f"- date: {datetime.date.today().isoformat()}",
        f"- machine: {platform.node()} {platform.processor() or platform.machine()}, {os.cpu_count()} cores; {load}",
        f"- command: `.venv/bin/python benchmarks/bench_render.py --repeats {repeats} --threads {threads}`",
        f"- 640x480, 12 LEDs, variant {rows[0]['variant']}, "
        + ("sphere press" if rows[0]["press"] else "undeformed dome"),
        "",
        "| bounces | spp | median full press (s) | median render+GT (s) | goal (s) |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {r['bounces']} | {r['spp']} | {r['full']:.2f} | {r['render']:.2f} | {r['goal']:.0f} |" for r in rows]
    text = "\n".join(lines) + "\n"
    old = RESULTS.read_text() if RESULTS.exists() else "# Benchmark results\n"
    pattern = re.compile(re.escape(SECTION) + r"\n.*?(?=\n## |\Z)", re.S)
    new = pattern.sub(text.rstrip("\n"), old) if pattern.search(old) else old.rstrip("\n") + "\n\n" + text
    RESULTS.write_text(new if new.endswith("\n") else new + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="render threads (0 = all cores)")
    args = ap.parse_args(argv)
    load = "load average before: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    rows = bench(args.repeats, args.threads)
    load += ", after: {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())
    print(write_results(rows, args.repeats, args.threads, load))
    return 0


if __name__ == "__main__":
    sys.exit(main())
