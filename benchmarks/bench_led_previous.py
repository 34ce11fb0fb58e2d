"""``nlips calibrate-leds --previous``: how well two calibrations of one unchanged sensor repeat, and what an aged one
reads (the tolerances ``LED_GROUP_CHANGE``, ``LED_BRIGHTNESS_CHANGE``, ``LED_MOVED_MM``, ``LED_TURNED_DEG``).

Renders the twin's undeformed dome (default scene, one bounce, sensor noise) under several noise seeds, calibrates
each with `nlips calibrate-leds`, and compares every ordered pair (``core.led_change.compare_calibrations``): the
spread of the tri-colour groups' median brightness, of each LED's own over its group's, of the positions and axes, and
the changes warned (0 expected). Then the first seed's capture with LEDs aged (``--aged 1-4:0.9``: LEDs 1-4 at 0.9
above the dark frame, ``tests/solver/twin_helpers.dimmed_copy``) is calibrated and compared with every clean file.

Usage: python benchmarks/bench_led_previous.py OUT [--seeds 7,8,9,10,11,12,13] [--size 160x120] [--spp 16]
       [--aged 1-4:0.9,1-4:0.95,6:0.9]

Prints one line per statistic and per aged case; renders and LED files are made once under OUT and reused.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def calibrated(capture: Path) -> Path:
    """The LED file of ``capture`` (``capture``.json), calibrated with the command's defaults unless already there."""
    from nlipscalib.cli import main

    out = capture.parent / f"{capture.name}.json"  # not with_suffix: "..._0.95" has one
    if not out.exists() and main(["-q", "--no-progress", "calibrate-leds", str(capture), "--out", str(out)]) != 0:
        raise SystemExit(f"{capture}: calibrate-leds failed")
    return out


def spread(name: str, values: list[float]) -> None:
    v = np.asarray(values)
    print(
        f"{name}: n={v.size} median {np.median(v):.4f}, 95th percentile {np.percentile(v, 95):.4f}, max {v.max():.4f}"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path, help="folder for the renders and LED files (reused when there)")
    ap.add_argument("--seeds", default="7,8,9,10,11,12,13", help="render and noise seeds")
    ap.add_argument("--size", default="160x120", help="image size WxH")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel")
    ap.add_argument("--aged", default="1-4:0.9,1-4:0.95,6:0.9", help="LEDS:GAIN cases, LEDs from 1 (a-b or one)")
    args = ap.parse_args()
    from nlipscalib.core import load_press
    from nlipscalib.core.led_change import compare_calibrations, led_brightness_ratios
    from nlipscalib.core.ledfile import read_led_file
    from nlipscalib.core.leds import led_arrays, led_offsets, tricolor_groups
    from nlipscalib.sim.press import render_press
    from nlipscalib.sim.scene import load_scene
    from tests.solver.twin_helpers import dimmed_copy

    width, height = (int(v) for v in args.size.split("x"))
    scene = load_scene("nlipstac").replace(
        render={"bounces": 1, "spp": args.spp}, camera={"width": width, "height": height}
    )
    seeds = [int(s) for s in args.seeds.split(",")]
    files = {}
    for seed in seeds:
        folder = args.out / f"seed{seed}"
        if not (folder / "meta.json").exists():
            render_press(scene, None, folder, seed=seed)
        files[seed] = read_led_file(calibrated(folder))
    groups = tricolor_groups(len(files[seeds[0]].leds))
    group, own, moved, turned, alarms = [], [], [], [], []
    for a, b in itertools.permutations(seeds, 2):
        ratio = led_brightness_ratios(files[a].leds, files[b].leds)
        medians = np.array([np.median(ratio[groups == g]) for g in np.unique(groups)])
        group += list(np.abs(np.log(medians)))
        own += list(np.abs(np.log(ratio / medians[groups])))
        (pa, da, _, _), (pb, db, _, _) = led_arrays(files[a].leds), led_arrays(files[b].leds)
        gap, turn = led_offsets(pa, da, pb, db)
        moved += list(gap)
        turned += list(turn)
        alarms += compare_calibrations(files[a], f"seed{a}", files[b].leds)["changes"]
    spread("group median |log ratio|", group)
    spread("LED over its group |log ratio|", own)
    spread("moved mm", moved)
    spread("turned deg", turned)
    print(f"changes warned over {len(seeds) * (len(seeds) - 1)} ordered clean pairs: {len(alarms)}", alarms[:3])
    for case in args.aged.split(","):
        which, gain = case.split(":")
        first, _, last = which.partition("-")
        leds = np.arange(int(first) - 1, int(last or first))
        gains = np.ones(len(groups))
        gains[leds] = float(gain)
        folder = args.out / f"seed{seeds[0]}_aged_{which}_{gain}"
        if not (folder / "meta.json").exists():
            dimmed_copy(load_press(args.out / f"seed{seeds[0]}"), folder, gains)
        aged = read_led_file(calibrated(folder))
        read, said = [], []
        for seed in seeds:
            compared = compare_calibrations(files[seed], f"seed{seed}", aged.leds)
            read.append(float(np.median(np.asarray(compared["brightness"])[leds])))
            said.append(len(compared["changes"]))
        print(f"LEDs {which} at {gain}: read {min(read):.3f}-{max(read):.3f}; changes per earlier file {said}")


if __name__ == "__main__":
    main()
