"""Helpers of the tests and benchmarks on the digital twin's renders (tests/solver/test_twin.py,
test_interreflection.py, benchmarks/bench_accuracy.py): LEDs off as a calibration starts from them, and a box
around the true contact, and a capture whose LEDs aged."""

from __future__ import annotations

import json
import shutil

import numpy as np

from nlipscalib.core import Led, load_press
from nlipscalib.core.imageio import read_png16, write_png16


def perturbed(leds, rng, mm=(0.3, 0.5), deg=5.0):
    """The scene's LEDs off by ``mm`` (0.3-0.5 mm), ``deg`` (5 deg), mu x1.3, Psi x0.8: a calibration's starting
    point."""
    out = []
    for led in leds:
        offset = rng.normal(size=3)
        offset *= rng.uniform(*mm) / np.linalg.norm(offset)
        d = np.asarray(led.direction)
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        tilt = np.radians(deg)
        direction = np.cos(tilt) * d + np.sin(tilt) * axis  # axis is perpendicular to d
        out.append(
            Led(
                tuple(np.add(led.position, offset)),
                tuple(direction),
                led.mu * 1.3,
                tuple(0.8 * np.asarray(led.intensity)),
            )
        )
    return out


def contact_box(contact, margin=8):
    """(x0, y0, w, h) around the true contact: auto ROI is unreliable on noisy one-bounce renders."""
    rows, cols = np.nonzero(contact)
    y0, x0 = max(rows.min() - margin, 0), max(cols.min() - margin, 0)
    y1, x1 = min(rows.max() + 1 + margin, contact.shape[0]), min(cols.max() + 1 + margin, contact.shape[1])
    return int(x0), int(y0), int(x1 - x0), int(y1 - y0)


def dimmed_copy(press, folder, gain):
    """A copy of ``press`` in ``folder`` with every LED image ``gain`` times as bright above the dark frame (LEDs
    aged alike, or a shorter exposure; one gain per LED: LEDs aged each on its own), as a press captured so would
    store it."""
    shutil.copytree(press.folder, folder)
    images = json.loads((folder / "meta.json").read_text(encoding="utf-8"))["images"]
    dark = read_png16(folder / images["dark"]).astype(float)
    for name, led_gain in zip(images["leds"], np.broadcast_to(gain, len(images["leds"])), strict=True):
        lit = read_png16(folder / name).astype(float) - dark
        write_png16(folder / name, np.clip(np.rint(dark + led_gain * lit), 0, 65535).astype(np.uint16))
    recorded_anew(folder)
    return load_press(folder)


def recorded_anew(folder):
    """``folder``'s checksums.json written for its files as they are now: a press edited by a test to stand for one
    captured so (aged LEDs, exchanged images), which its capture would have recorded as such."""
    from nlipscalib.core.press_checksums import write_checksums
    from nlipscalib.core.press_meta import listed_files, read_meta

    write_checksums(folder, listed_files(read_meta(folder)))
