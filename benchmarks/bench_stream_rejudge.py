"""How stale a stream's verdict on a held press gets, and what telling it costs (s34-live): the small/steep-contact
check of ``nlips infer`` / ``nlips live`` streams (``learn.resolution.StreamSteepness``).

Each press's stored tri-colour frame is predicted once; then:

- ``stale``: its normals' tilt from the undeformed ones ramped ``--rates`` a frame over 60 frames (slerp past the
  frame's own normals, the changed pixels kept: a press steepening in place); per ramp, the frames whose streamed
  verdict (warned or not) differs from the still-frame check's, the longest such run, how far the tilt of the verdict
  in use lies from the frame's own (75th percentile, ``core.steepness``), its age in frames, the contacts measured;
- ``noise``: the press held with fresh noise each frame (the frame's own noise level added again, 6 draws cycled over
  60 frames): the contacts measured, the check's process CPU per frame (median of 9 streams) and how far
  ``contact_bend`` wanders;
- ``cost``: process CPU per call (median of 200) of ``contact_extent``, ``contact_bend`` at steps 1, 2, 4 and
  ``bend_step``'s, and the measure (``judge_steepness``).

The package is PYTHONPATH's, so an older tree's ``stale`` and ``noise`` run too (``cost`` needs ``contact_bend``)::

    PYTHONPATH=. python benchmarks/bench_stream_rejudge.py MODEL.pt PRESS [PRESS ...] [--steps stale,noise,cost]
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np


def _steepened(frame, reference: np.ndarray, scale: float) -> np.ndarray:
    """(H, W, 3) float32: ``frame``'s normals on its changed pixels turned to ``scale`` times their tilt."""
    n, r = frame.normals.astype(np.float64), reference.astype(np.float64)
    theta = np.arccos(np.clip((n * r).sum(-1), -1, 1))
    sin = np.sin(theta)
    ok = frame.changed & (sin > 1e-9)
    safe = np.where(ok, sin, 1.0)
    w_ref = np.where(ok, np.sin((1 - scale) * theta) / safe, 1.0)
    w_own = np.where(ok, np.sin(scale * theta) / safe, 0.0)
    out = w_ref[..., None] * r + w_own[..., None] * n
    out /= np.linalg.norm(out, axis=-1, keepdims=True).clip(1e-12)
    return np.where(frame.changed[..., None], out, frame.normals).astype(np.float32)


def stale(predictor, name: str, frame, rates: list[float]) -> None:
    from nlipscalib.core import masks
    from nlipscalib.core.steepness import patch_steepness
    from nlipscalib.learn import resolution

    ref = predictor.ref_normals
    calibrated = resolution.recorded_steepness(predictor.model.info)
    for rate in rates:
        frames = [dataclasses.replace(frame, normals=_steepened(frame, ref, 1.0 + rate * k)) for k in range(60)]
        check = resolution.StreamSteepness(predictor)
        own = [resolution.judge_steepness(f.changed, f.normals, ref, calibrated) for f in frames]
        tilts = [patch_steepness(masks.erode(f.changed, resolution.RIM_PX), f.normals, ref)[1] for f in frames]
        wrong = run = longest = oldest = 0
        worst, last = 0.0, 0
        for k, f in enumerate(frames):
            judged = check.judged
            streamed = check(f, "f")
            last = k if check.judged > judged else last
            worst, oldest = max(worst, abs(tilts[last] - tilts[k]) / tilts[k]), max(oldest, k - last)
            run = run + 1 if bool(streamed) != bool(own[k]) else 0
            wrong, longest = wrong + (run > 0), max(longest, run)
        flips = sum(bool(own[k]) != bool(own[k - 1]) for k in range(1, 60))
        print(
            f"{name} steepening {100 * rate:.2f} %/frame (x{1 + 59 * rate:.2f}): {wrong} of 60 frames' verdict not the "
            f"still-frame check's (longest run {longest}; the check flips {flips} times); the verdict's tilt up to "
            f"{100 * worst:.1f} % off the frame's own, up to {oldest} frames old; measured {check.judged} of 60",
            flush=True,
        )


def noise(predictor, name: str, image: np.ndarray, reference_image: np.ndarray) -> None:
    from nlipscalib.learn import resolution

    clean = predictor.predict_stored(image.astype(np.uint16), name)
    far = predictor.valid & ~clean.changed
    sigma = float(np.std((image - reference_image)[far])) / np.sqrt(2)  # two frames' independent noise
    rng = np.random.default_rng(0)
    draws = []
    for _ in range(6):
        noisy = np.clip(image + rng.normal(0, sigma, image.shape), 0, 65535).astype(np.uint16)
        draws.append(predictor.predict_stored(noisy, name))
    spent = []
    for _ in range(9):  # the whole check of a frame (StreamSteepness), its CPU per frame
        check = resolution.StreamSteepness(predictor)
        start = time.process_time()
        for k in range(60):
            check(draws[k % 6], "f")
        spent.append(1e3 * (time.process_time() - start) / 60)
    line = f"{name} held, noise {sigma:.0f} added: measured {check.judged} of 60, {np.median(spent):.3f} ms CPU/frame"
    if hasattr(resolution, "contact_bend"):
        ref = predictor.ref_normals
        extents = [resolution.contact_extent(d.changed) for d in draws]
        step = resolution.bend_step(extents[0])
        bends = [resolution.contact_bend(d.changed, d.normals, ref, e, step) for d, e in zip(draws, extents)]
        spread = 100 * np.ptp(bends) / np.median(bends)
        line += f"; contact_bend at step {step} {min(bends):.1f}-{max(bends):.1f} ({spread:.2f} %)"
    print(line, flush=True)


def _cpu_ms(call, n: int = 200) -> float:
    spent = []
    for _ in range(n):
        start = time.process_time()
        call()
        spent.append(time.process_time() - start)
    return 1e3 * float(np.median(spent))


def cost(predictor, name: str, frame) -> None:
    from nlipscalib.learn import resolution

    ref, extent = predictor.ref_normals, resolution.contact_extent(frame.changed)
    row = [f"contact_extent {_cpu_ms(lambda: resolution.contact_extent(frame.changed)):.3f}"]
    for step in sorted({1, 2, 4, resolution.bend_step(extent)}):
        spent = _cpu_ms(lambda step=step: resolution.contact_bend(frame.changed, frame.normals, ref, extent, step))
        row.append(f"bend step {step}{' (bend_step)' if step == resolution.bend_step(extent) else ''} {spent:.3f}")
    measure = _cpu_ms(lambda: resolution.judge_steepness(frame.changed, frame.normals, ref, 0.1, extent), 50)
    print(f"{name} ms of CPU a call: {'; '.join(row)}; measure {measure:.3f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("model", help="NLiPsNet model file (.pt) of the presses' sensor")
    parser.add_argument("presses", nargs="+", help="press folders (tricolor.png); their parent's reference/ too")
    parser.add_argument("--steps", default="stale,noise,cost", help="comma-separated: stale, noise, cost")
    parser.add_argument("--rates", default="0.005,0.02", help="tilt ramps of 'stale', a fraction a frame")
    args = parser.parse_args()
    from nlipscalib.core.imageio import read_png16
    from nlipscalib.learn.infer import Predictor

    predictor = Predictor(args.model, threads=1)
    steps = args.steps.split(",")
    for press in map(Path, args.presses):
        image = read_png16(press / "tricolor.png")
        frame = predictor.predict_stored(image, press.name)
        if "stale" in steps:
            stale(predictor, press.name, frame, [float(r) for r in args.rates.split(",")])
        if "noise" in steps:
            reference = read_png16(press.parent / "reference" / "tricolor.png").astype(np.float64)
            noise(predictor, press.name, image.astype(np.float64), reference)
        if "cost" in steps:
            cost(predictor, press.name, frame)


if __name__ == "__main__":
    main()
