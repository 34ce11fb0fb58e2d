"""What the capture checks' lag-band look costs with the LED model (``core.repeated_frames.frame_checks`` as the solve,
``nlips calibrate-leds`` and ``nlips capture`` call it), per capture.

Usage::

    python benchmarks/bench_lag_check.py TAG PRESS [PRESS ...]

Per press, process CPU of ``frame_checks(images, gel, model_light(...))`` with a fresh ``ModelLight`` each call (as
each caller makes its own), median of 15 calls after one: ``cold`` with this process's kept model blocks dropped
before each call (a process's first check of a design; a tree without the store has nothing to drop), ``warm`` with
them kept (its later checks: the solve's undeformed capture, calibrate-leds' second look, a batch's next press), and
``none`` without the model. Prints one line, TAG first: run it on two trees alternately (PYTHONPATH) for an A/B.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from nlipscalib.core import repeated_frames
from nlipscalib.core.capture import load_press

CALLS = 15
"""Calls timed per press and kind (their median is printed)."""


def _median_ms(images: np.ndarray, gel: np.ndarray, before_each, model) -> float:
    """Median process CPU (ms) of ``frame_checks(images, gel, model())`` over :data:`CALLS` calls after one."""
    repeated_frames.frame_checks(images, gel, model())
    times = []
    for _ in range(CALLS):
        before_each()
        expected = model()
        start = time.process_time()
        repeated_frames.frame_checks(images, gel, expected)
        times.append(time.process_time() - start)
    return 1e3 * float(np.median(times))


def _drop_kept() -> None:
    """Forget the LED model's blocks kept in this process (absent before s36-lagcost: nothing to forget)."""
    kept = getattr(repeated_frames, "_MODEL_BLOCKS", None)
    if kept is not None:
        kept.clear()


def main(argv: list[str]) -> None:
    tag, folders = argv[0], argv[1:]
    said = [tag]
    for folder in folders:
        press = load_press(folder)
        images = np.asarray(press.linear_led_images)
        gel = np.isfinite(press.reference.depth)

        def fresh(press=press):
            return repeated_frames.model_light(press.reference.depth, press.reference.normals, press.camera, press.leds)

        cold = _median_ms(images, gel, _drop_kept, fresh)
        warm = _median_ms(images, gel, lambda: None, fresh)
        none = _median_ms(images, gel, lambda: None, lambda: None)
        said.append(f"{Path(folder).name} cold {cold:.2f} warm {warm:.2f} none {none:.2f}")
    print(*said, flush=True)


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tag", help="printed first: which tree this run measures")
    parser.add_argument("presses", nargs="+", help="press folders (their tri-colour, LED and dark images)")
    args = parser.parse_args()
    main([args.tag, *args.presses])
