"""The tri-colour check's misfit against the camera's noise (s40-trinoise): clean presses, two LED images of different
groups exchanged (led_04 / led_05, the shipped ring's weakest cross-group pair, and led_01 / led_09), another press's
tri-colour frame (the same noise, another azimuth), the frame as BGR, and all 32 cross-group pairs, per noise level of
the presses' scene (meta.json ``provenance.scene.noise``), and the check's cost per press.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_tricolor_noise.py PRESSES_ROOT [--side 8] [--cost PRESS]

``PRESSES_ROOT``: folders ``sphere-p<polar>-a<azimuth>-d<depth>-<spec>-*`` (``nlips experiment studies``' presses).
``--side``: the blocks' side in px (default: the check's own, :func:`~nlipscalib.core.tricolor_check.tricolor_block`;
1 is single pixels)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from nlipscalib.core import load_press
from nlipscalib.core import tricolor_check as tc
from nlipscalib.core.leds import tricolor_groups

ORDER = ("off", "40000/1", "10000/2", "2500/4", "625/8")


def _noise(folder: Path) -> str:
    noise = json.loads((folder / "meta.json").read_text(encoding="utf-8"))["provenance"]["scene"]["noise"]
    return "off" if not noise["enabled"] else f"{noise['full_well']:.0f}/{noise['read_noise']:.0f}"


def _swapped(count: int, i: int, j: int) -> list[int]:
    order = list(range(count))
    order[i], order[j] = j, i
    return order


def measure(root: Path, side: int | None) -> dict:
    """Per (noise, kind): the worst channel's misfit of each press."""
    if side is not None:
        tc.tricolor_block = lambda shape: side  # the check's blocks, of this side
    presses = {f: (_noise(f), load_press(f)) for f in sorted(root.glob("sphere-*"))}
    groups = tricolor_groups(12)
    rows: dict = defaultdict(lambda: defaultdict(list))
    for folder, (noise, press) in presses.items():
        pixels = tc.gel_samples(press.reference, press.camera.shape)
        tri, images = tc.tricolor_samples(press, pixels)
        polar = folder.name.split("-a")[0]
        other = next(
            g for g, (n, _) in presses.items() if n == noise and g != folder and g.name.startswith(polar + "-")
        )
        mixed = dataclasses.replace(press, tricolor=presses[other][1].tricolor)
        row = rows[noise]
        row["clean"].append(np.max(tc.channel_misfits(tri, images, groups)))
        fit = tc.tricolor_fit(tri, images[_swapped(12, 3, 4)], groups)
        row["led_04/05"].append(np.max(fit.misfit))
        row["named"].append(fit.exchanged == (3, 4))
        row["led_01/09"].append(np.max(tc.channel_misfits(tri, images[_swapped(12, 0, 8)], groups)))
        row["other frame"].append(np.max(tc.channel_misfits(*tc.tricolor_samples(mixed, pixels), groups)))
        row["bgr said"].append(tc.tricolor_fit(tri[:, ::-1], images, groups).sources == (2, 1, 0))
        pairs = [(i, j) for i in range(12) for j in range(i + 1, 12) if groups[i] != groups[j]]
        worst = [np.max(tc.channel_misfits(tri, images[_swapped(12, i, j)], groups)) for i, j in pairs]
        row["pairs told"].append(np.mean(np.array(worst) > 0.03))
    return rows


def cost(folder: Path, runs: int = 7) -> tuple[float, float]:
    """Median CPU seconds of the verdict on a press freshly loaded (its frames decoded first), without and with the
    whole frames linearised before (a capture / a solve)."""
    times: dict = {False: [], True: []}
    for linear in (False, True):
        for _ in range(runs):
            press = load_press(folder)
            decoded = [press.led_images, press.tricolor, press.dark]  # as a solve holds them
            if linear:
                decoded.append(press.linear_led_images)
            start = time.process_time()
            tc.press_tricolor_verdict(press)
            times[linear].append(time.process_time() - start)
    return float(np.median(times[False])), float(np.median(times[True]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("--side", type=int, default=None)
    parser.add_argument("--cost", type=Path, default=None, help="a press to time the check on")
    args = parser.parse_args()
    rows = measure(args.root, args.side)
    print("| noise | presses | clean | led_04/05 | named | led_01/09 | another press's frame | BGR said | pairs told |")
    print("|---|---|---|---|---|---|---|---|---|")
    span = lambda v: f"{100 * min(v):.2f}-{100 * max(v):.2f} %"  # noqa: E731
    for noise in [n for n in ORDER if n in rows] + sorted(set(rows) - set(ORDER)):
        r = rows[noise]
        print(
            f"| {noise} | {len(r['clean'])} | {span(r['clean'])} | {span(r['led_04/05'])} | {sum(r['named'])} "
            f"| {span(r['led_01/09'])} | {span(r['other frame'])} | {sum(r['bgr said'])} "
            f"| {100 * np.mean(r['pairs told']):.0f} % |"
        )
    if args.cost:
        cold, linear = cost(args.cost)
        print(f"cost per press: {1e3 * cold:.1f} ms CPU (frames decoded), {1e3 * linear:.1f} ms (linearised already)")


if __name__ == "__main__":
    main()
