"""``nlips infer --reference FRAME``: which frames the pressed-reference check (``learn.reference_press``) refuses,
and what it costs (the tolerances ``REFERENCE_PRESS_SHARE``, ``REFERENCE_COLOUR_*``).

Each press folder given is checked against the calibration's reference frame (CALIBRATION: the undeformed capture a
model was calibrated on, or a model file, whose stored reference frame is taken), as it is and aged: one LED's light
times g (its own LED image scaled onto its colour group's share of the tri-colour frame by least squares), each colour
group and all LEDs times g, noise of a fraction of the gel's median, and a scuff (all three colours darker over a
Gaussian patch at the gel's centre); a twin press (contact in its gt.npz) only as it is, red 90 % and all 80 %, a
capture without ground truth (a sensor's or the emulator's) every variant. Undeformed frames should show no press;
presses should.

Usage: python benchmarks/bench_reference_press.py CALIBRATION FOLDER... [--leds 0.99,0.95,0.8] [--repeats 9]
       [--no-leds]

Prints one line per frame (the patch's share of the gel and box, or "-") and the check's median wall and CPU time,
the LEDs' shares (``LedShares.shares``) made in each call, as in the one check of an ``nlips infer`` run.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def calibration_frame(path: Path, leds: bool = True):
    """(the calibration's linear tri-colour frame, the gel mask, its LEDs' shares or None) of a press folder or a
    model file (``leds`` False: None, the smooth colour field alone)."""
    from nlipscalib.core.capture import load_press
    from nlipscalib.core.leds import tricolor_groups
    from nlipscalib.learn.infer import load_tricolor
    from nlipscalib.learn.reference_press import LedShares

    if path.is_file():
        from nlipscalib.learn.model import load_model

        model = load_model(path)
        ref = model.reference
        shares = LedShares.of_model(model.sensor, ref) if leds else None
        return ref["tricolor"].astype(np.float32), ref["valid"].astype(bool), shares
    press = load_press(path)
    depth, normals = press.reference.depth, press.reference.normals
    groups = np.asarray(tricolor_groups(len(press.leds)))
    shares = LedShares(press.camera, depth, normals, tuple(press.leds), groups) if leds else None
    return load_tricolor(path)[0], np.isfinite(depth), shares


def one_led_dimmed(folder: Path, frame: np.ndarray, led: int, gain: float) -> np.ndarray:
    """``frame`` (``folder``'s linear tri-colour frame) with LED ``led``'s light times ``gain``."""
    from nlipscalib.core.capture import load_press
    from nlipscalib.core.leds import tricolor_colors

    press = load_press(folder)
    colours = tricolor_colors(len(press.leds))
    colour = int(np.argmax(colours[led]))
    lit = press.linear(press.led_images).astype(np.float64)
    single = lit[..., colour] if lit.ndim == 4 else lit
    total = single[colours[:, colour] > 0].sum(0)
    out = frame.astype(np.float64)
    scale = float((out[..., colour] * total).sum() / (total * total).sum())
    out[..., colour] -= (1 - gain) * scale * single[led]
    return out.astype(np.float32)


def variants(folder: Path, frame: np.ndarray, valid: np.ndarray, led_gains: list[float]):
    """(name, frame) of ``frame`` as it is and aged."""
    yield "as captured", frame
    if not (folder / "gt.npz").is_file() or not np.load(folder / "gt.npz")["contact"].any():
        n_leds = len(json.loads((folder / "meta.json").read_text(encoding="utf-8"))["leds"])
        for led in range(n_leds):
            for gain in led_gains:
                yield f"LED {led + 1} x{gain}", one_led_dimmed(folder, frame, led, gain)
        for name, gains in (("red x0.9", [0.9, 1, 1]), ("blue x0.95", [1, 1, 0.95]), ("all x0.8", [0.8] * 3)):
            yield name, frame * np.float32(gains)
        rng = np.random.default_rng(0)
        for sigma in (0.01, 0.02, 0.05):
            noise = rng.normal(0, sigma * np.median(frame[valid]), frame.shape).astype(np.float32)
            yield f"noise {sigma:.0%}", frame + noise
        rows, cols = np.mgrid[0 : valid.shape[0], 0 : valid.shape[1]]
        cy, cx = (float(np.median(a[valid])) for a in (rows, cols))
        for depth, size in ((0.1, 0.04), (0.25, 0.06)):
            s = size * valid.shape[1]
            patch = 1 - depth * np.exp(-((cols - cx) ** 2 + (rows - cy) ** 2) / (2 * s * s))
            yield f"scuff {depth:.0%}", frame * patch[..., None].astype(np.float32)
    else:
        yield "red x0.9", frame * np.float32([0.9, 1, 1])
        yield "all x0.8", frame * np.float32(0.8)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("calibration", type=Path, help="the calibration's undeformed capture, or a model file")
    ap.add_argument("folders", type=Path, nargs="+", help="press folders to check (undeformed captures and presses)")
    ap.add_argument("--leds", default="0.99,0.95,0.8", help="gains of one LED at a time (undeformed frames only)")
    ap.add_argument("--repeats", type=int, default=9, help="timed calls of the check on the first frame")
    ap.add_argument("--no-leds", action="store_true", help="the smooth colour field alone, without the LEDs' shares")
    args = ap.parse_args()
    from nlipscalib.learn.infer import load_tricolor
    from nlipscalib.learn.reference_press import press_in_frame

    calibration, valid, leds = calibration_frame(args.calibration, leds=not args.no_leds)
    gains = [float(g) for g in args.leds.split(",") if g]
    for folder in args.folders:
        frame = load_tricolor(folder)[0]
        for name, candidate in variants(folder, frame, valid, gains):
            found = press_in_frame(calibration, candidate, valid, leds)
            said = "-" if found is None else f"press {found.share:.2%} of the gel, box {found.box}"
            print(f"{folder.name} {name}: {said}", flush=True)
    first = load_tricolor(args.folders[0])[0]
    walls, cpus = [], []
    for _ in range(max(args.repeats, 1)):
        t, c = time.perf_counter(), time.process_time()
        press_in_frame(calibration, first, valid, leds)
        walls.append(time.perf_counter() - t)
        cpus.append(time.process_time() - c)
    print(
        f"check of {first.shape[1]}x{first.shape[0]}: median {1e3 * np.median(walls):.1f} ms wall "
        f"[{1e3 * min(walls):.1f}-{1e3 * max(walls):.1f}], {1e3 * np.median(cpus):.1f} ms CPU, n={len(walls)}"
    )


if __name__ == "__main__":
    main()
