"""The camera shift measured on every press of a folder against its undeformed capture, in place and moved.

Usage: ``python benchmarks/bench_camera_shift_presses.py REFS PRESSES [--out TABLE.tsv]`` -- each press's undeformed
capture is the folder of REFS whose name its own name holds (q3's: ``cube-p15-a0-d1-28223857c6-a8ee18`` against
``refs/28223857c6``). Each press is measured as it is and with its images rolled 1 and 2 px to the right (the camera
moved: ``np.roll`` along x, as s26-degen2 did); one line per press, then per undeformed capture the largest shift of
the presses in place and the range of the moved ones' dx. Run it with the code to compare on ``PYTHONPATH``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from nlipscalib.core import load_press
from nlipscalib.solver.camera_shift import camera_shift


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("refs", type=Path)
    parser.add_argument("presses", type=Path)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    refs = {folder.name: load_press(folder).linear_led_images for folder in sorted(args.refs.iterdir())}
    rows, seconds = [], []
    for folder in sorted(p for p in args.presses.iterdir() if p.is_dir()):
        ref = next((name for name in refs if name in folder.name), None)
        if ref is None:
            continue
        press = load_press(folder)
        valid = np.isfinite(press.reference.depth)
        images = press.linear_led_images
        shifts = []
        for dx in (0, 1, 2):
            start = time.perf_counter()
            shifts.append(camera_shift(refs[ref], np.roll(images, dx, axis=2), valid))
            seconds.append(time.perf_counter() - start)
        rows.append((ref, folder.name, shifts))
        line = " ".join(f"{x:+.2f},{y:+.2f}" for x, y in shifts)
        print(f"{ref}\t{folder.name}\t{line}", flush=True)
    if args.out:
        args.out.write_text(
            "".join(f"{r}\t{n}\t" + "\t".join(f"{x:.3f},{y:.3f}" for x, y in s) + "\n" for r, n, s in rows),
            encoding="utf-8",
        )
    print(f"camera_shift: median {1000 * np.median(seconds):.1f} ms a call ({len(seconds)} calls)", file=sys.stderr)
    for ref in refs:
        mine = [s for r, _, s in rows if r == ref]
        still = max(np.hypot(*s[0]) for s in mine)
        one, two = [s[1][0] for s in mine], [s[2][0] for s in mine]
        print(
            f"{ref}: {len(mine)} presses, in place up to {still:.2f} px; 1 px: {min(one):.2f}-{max(one):.2f}; "
            f"2 px: {min(two):.2f}-{max(two):.2f}"
        )


if __name__ == "__main__":
    main()
