"""Why an 8-bit lossy video of calibration presses was warned "contact too small or steep" where their 16-bit PNGs
are not: each press's contact measured (``learn.resolution.measure_contact``, as ``nlips infer`` judges it) on its
16-bit tri-colour PNG, the same PNG cut to 8 bits (lossless), the video's frame, the video's frame with its
per-colour gain over the reference taken out first (``ChangeDetector.channel_ratio``) for the network too, and the
video's normals on the PNG's region (whether the normals or the region differ); each cell ends with the change
rule's region in pixels. Also the change rule's noise figures (median and MAD of the smoothed difference, over the
reference's level). Since the change rule 3 (s43-mjpg) the rule itself takes the gain out before it thresholds: the
"video" column is then what ``nlips infer`` sees, and runs of the checkout before it (rule 2) give the old figures.

Usage: python benchmarks/bench_lossy_steepness.py MODEL.pt VIDEO DATASET [COUNT] (--help: what each is).
"""

from __future__ import annotations

import argparse

import cv2
import numpy as np

from nlipscalib.core.robust_scale import mad_scale
from nlipscalib.core.tolerances import CHANGE_NOISE_SIGMAS
from nlipscalib.device.camera import to_stored
from nlipscalib.learn import change
from nlipscalib.learn.infer import Predictor
from nlipscalib.learn.resolution import measure_contact


def video_frames(path: str, count: int) -> list[np.ndarray]:
    """The first ``count`` frames of ``path`` as stored values ((H, W, 3) uint16), as ``nlips infer`` reads them."""
    capture, frames = cv2.VideoCapture(path), []
    while len(frames) < count:
        ok, frame = capture.read()
        if not ok:
            break
        frames.append(to_stored(frame)[0])
    return frames


def noise(predictor: Predictor, linear: np.ndarray) -> tuple[float, float]:
    """(median, MAD scale) of the change rule's smoothed difference over the gel's sampled blocks, over the
    reference's level (``learn.change.ChangeDetector``'s figures)."""
    rule = predictor.changed
    signed = change._blocks(linear, rule._crop) - rule._ref_blocks
    signed[~rule._valid_blocks] = 0
    smooth = cv2.blur(signed, (change.SMOOTH_BLOCKS,) * 2, borderType=cv2.BORDER_REPLICATE)
    sample = np.abs(smooth).sum(-1).ravel()[rule._sample]
    level = float(np.median(rule._level.ravel()[rule._sample]))
    median = float(np.median(sample))
    return median / level, mad_scale(sample, center=median) / level


def measured(predictor: Predictor, region: np.ndarray, normals: np.ndarray) -> str:
    found = measure_contact(region, normals, predictor.ref_normals)
    figure = "-" if found is None else f"{found[0]:.1f} px {found[1]:.1f} deg {found[1] / found[0]:.3f}"
    return f"{figure} ({int(region.sum())})"


def main(model: str, video: str, dataset: str, count: int = 10) -> None:
    predictor = Predictor(model)
    frames = video_frames(video, count)
    print(f"change rule: threshold median + {CHANGE_NOISE_SIGMAS} MAD")
    print("press | PNG 16-bit | PNG as 8-bit | video | video, gain taken out | video normals on PNG region")
    print("(each: diameter, 75th-percentile tilt, deg/px of the contact; in brackets the change rule's pixels)")
    for i, stored in enumerate(frames, start=1):
        png = cv2.imread(f"{dataset}/press_{i:04d}/tricolor.png", cv2.IMREAD_UNCHANGED)
        lossless = predictor.linear(to_stored(png)[0])
        eight = predictor.linear(to_stored((png >> 8).astype(np.uint8))[0])
        lossy = predictor.linear(stored)
        predictor.changed(lossy)
        gain_out = lossy / predictor.changed.channel_ratio.astype(np.float32)
        results = [predictor.predict(frame) for frame in (lossless, eight, lossy, gain_out)]
        cells = [measured(predictor, r.changed, r.normals) for r in results]
        cells.append(measured(predictor, results[0].changed, results[2].normals))
        print(f"press_{i:04d} | " + " | ".join(cells))
        if i == 1:
            for name, frame in (("PNG", lossless), ("video", lossy), ("video, gain out", gain_out)):
                median, sigma = noise(predictor, frame)
                predictor.changed(frame)
                ratio = ", ".join(f"{r:.4f}" for r in predictor.changed.channel_ratio)
                print(
                    f"  {name}: median {median:.4f} MAD {sigma:.4f} threshold "
                    f"{median + CHANGE_NOISE_SIGMAS * sigma:.4f} of the level; colours over the reference {ratio}"
                )


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="the model file (.pt) from nlips train")
    parser.add_argument("video", help="the presses' tri-colour frames in order, press_0001 first (an MJPG .avi)")
    parser.add_argument("dataset", help="the folder of press_0001 ... whose tricolor.png the video was made from")
    parser.add_argument("count", type=int, nargs="?", default=10, help="presses (default 10)")
    args = parser.parse_args()
    main(args.model, args.video, args.dataset, args.count)
