"""Benchmark: one full press of the twin at 640x480 with 12 LEDs, and where its time goes.

Run: ``.venv/bin/python benchmarks/bench_render.py [--repeats 5] [--threads 0]``; rewrites its
section of benchmarks/RESULTS.md. Goals on the 2-core CPU: bounces 0 @ 4 spp <= 2 s and
bounces 1 @ 16 spp <= 8 s for all images + ground truth. Each case runs on the default scene
(``nlipstac.toml``: extended LEDs, defocus, black-level error) and on the ideal one (``nlipstac_ideal.toml``:
point LEDs, ideal camera), so what the default's effects cost is measured next to it.

Stages timed separately: indentation (``apply_press``), render (all LED images in one pass + the
ground-truth pass, ``render_surface``), and the full ``render_press`` (indentation + render + noise
+ writing the press folder).
"""

from __future__ import annotations

import argparse
import itertools
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one
from common import median_time, write_section  # noqa: E402

CASES = ((0, 4, 2.0), (1, 16, 8.0))  # (bounces, spp, goal seconds)


def bench_press():
    """The bench press: sphere 6 mm, polar 15 deg, azimuth 30 deg, 1 mm deep (also bench_gpu_render.py's)."""
    from nlipscalib.sim.indent import IndenterConfig, PressConfig

    return PressConfig(IndenterConfig("sphere", 6.0), polar_deg=15.0, azimuth_deg=30.0, depth=1.0)


def bench(repeats: int, threads: int) -> list[str]:
    from nlipscalib.sim.indent import apply_press
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.render import render_surface
    from nlipscalib.sim.scene import load_scene

    press = bench_press()
    scenes = {"default": load_scene(), "ideal": load_scene("nlipstac_ideal")}
    t_indent, _ = median_time(lambda: apply_press(scenes["default"].dome, press), repeats)
    gel = apply_press(scenes["default"].dome, press)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for (bounces, spp, goal), (name, base) in itertools.product(CASES, scenes.items()):
            scene = base.replace(render={"spp": spp, "bounces": bounces, "threads": threads})
            t_render, _ = median_time(lambda s=scene: render_surface(s, gel.mesh, gel.contact), repeats)
            t_full, _ = median_time(
                lambda s=scene: render_press(s, press, Path(tmp) / "p", seed=1, overwrite=True), repeats
            )
            rows.append(
                f"| {name} | {bounces} | {spp} | {t_indent:.2f} | {t_render:.2f} | {t_full:.2f} | {goal:.0f} | "
                f"{'met' if t_render <= goal else 'missed'} |"
            )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=0, help="render threads (0 = all cores)")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()[0]
    rows = bench(args.repeats, args.threads)
    body = "\n".join(
        [
            "Default scene (extended LEDs, defocus, black-level error) and ideal scene (point LEDs, ideal camera), "
            f"640x480, 12 LEDs, llvm_ad_rgb, sphere press; median of {args.repeats} after a warm-up. "
            f"Load average before: {load_before:.2f}, after: {os.getloadavg()[0]:.2f}.",
            "",
            "| scene | bounces | spp | indentation (s) | render: all images + GT (s) "
            "| full press incl. noise + write (s) "
            "| goal (s) | goal |",
            "|---|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    write_section("Rendering one press (bench_render.py)", body)
    print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
