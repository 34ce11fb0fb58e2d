"""The camera shift measured on every press of a folder against its undeformed capture, in place and moved.

Usage: ``python benchmarks/bench_camera_shift_presses.py REFS PRESSES [--out TABLE.tsv]`` -- each press's undeformed
capture is the folder of REFS whose name its own name holds (q3's: ``cube-p15-a0-d1-28223857c6-a8ee18`` against
``refs/28223857c6``). Each press is measured as it is and moved by the sub-pixel shifts of :data:`SHIFTS` (the camera
moved: ``cv2.warpAffine``, bilinear, its border reflected); one line per press (the measured shifts), then per
undeformed capture and indenter (the press name's first word) the largest reading error per true shift, the presses in
place at or above ``tolerances.CAMERA_SHIFT_PX`` (false warnings) and the moved ones of 1 px or more below it (missed).
Run it with the code to compare on ``PYTHONPATH``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from nlipscalib.core import load_press, tolerances
from nlipscalib.solver.camera_shift import camera_shift, log_blocks

SHIFTS = [(0.0, 0.0), (0.5, 0.0), (1.0, 0.0), (2.0, 0.0), (3.0, 0.0), (0.0, 0.5), (0.0, 1.0), (0.0, -2.0)]
"""True shifts (dx, dy), pixels, x right and y down."""


def moved(images: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    """(L, H, W, 3) -- ``images`` moved by ``shift``: ``out(x) = images(x - shift)``."""
    if shift == (0.0, 0.0):
        return images
    H, W = images.shape[1:3]
    matrix = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    return np.stack(
        [cv2.warpAffine(np.asarray(im, np.float32), matrix, (W, H), borderMode=cv2.BORDER_REFLECT) for im in images]
    )


def kept_blocks(images: np.ndarray):
    """``(step, block) ->`` :func:`log_blocks` of ``images``, made once: a solve keeps its undeformed capture's too."""
    made = {}

    def blocks(step: int, block: int) -> np.ndarray:
        if (step, block) not in made:
            made[step, block] = log_blocks(images[::step], block)
        return made[step, block]

    return blocks


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("refs", type=Path)
    parser.add_argument("presses", type=Path)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    refs = {folder.name: kept_blocks(load_press(folder).linear_led_images) for folder in sorted(args.refs.iterdir())}
    rows, seconds = [], []
    for folder in sorted(p for p in args.presses.iterdir() if p.is_dir()):
        ref = next((name for name in refs if name in folder.name), None)
        if ref is None:
            continue
        press = load_press(folder)
        valid = np.isfinite(press.reference.depth)
        images = press.linear_led_images
        shifts = []
        for true in SHIFTS:
            image = moved(images, true)
            start = time.process_time()
            shifts.append(camera_shift(refs[ref], image, valid))
            seconds.append(time.process_time() - start)
        rows.append((ref, folder.name, shifts))
        line = " ".join(f"{x:+.2f},{y:+.2f}" for x, y in shifts)
        print(f"{ref}\t{folder.name}\t{line}", flush=True)
    if args.out:
        args.out.write_text(
            "".join(f"{r}\t{n}\t" + "\t".join(f"{x:.3f},{y:.3f}" for x, y in s) + "\n" for r, n, s in rows),
            encoding="utf-8",
        )
    print(f"camera_shift: median {1000 * np.median(seconds):.1f} ms CPU a call ({len(seconds)} calls)", file=sys.stderr)
    print("capture\tindenter\tpresses\t" + "\t".join(f"{x:+g},{y:+g}" for x, y in SHIFTS) + "\tfalse\tmissed")
    for ref, kind in sorted({(r, n.split("-")[0]) for r, n, _ in rows}):
        mine = np.array([s for r, n, s in rows if r == ref and n.split("-")[0] == kind])  # (presses, shifts, 2)
        error = np.hypot(*(mine - np.array(SHIFTS)).transpose(2, 0, 1)).max(axis=0)
        reads = np.hypot(mine[..., 0], mine[..., 1])
        false = int((reads[:, 0] >= tolerances.CAMERA_SHIFT_PX).sum())
        big = [i for i, s in enumerate(SHIFTS) if np.hypot(*s) >= 1]
        missed = int((reads[:, big] < tolerances.CAMERA_SHIFT_PX).sum())
        print(f"{ref}\t{kind}\t{len(mine)}\t" + "\t".join(f"{e:.2f}" for e in error) + f"\t{false}\t{missed}")


if __name__ == "__main__":
    main()
