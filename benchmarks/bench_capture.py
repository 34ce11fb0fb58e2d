"""Capture time per press on the emulated sensor, and the expected time on a 30 fps camera.

Run:  PYTHONPATH=. python benchmarks/bench_capture.py [--width 640 --height 480 --presses 5]

Measures, with every scripted surface rendered beforehand (so the numbers are the hardware path, not the
renderer): the time of one press (LED commands through the real host driver to the virtual board,
frames from the emulated camera, the movement check, the atomic press write), split into its parts;
then the whole-process wall time of the user's command ``nlips capture --emulate`` (rendering included).
The 30 fps estimate counts the frames a real camera needs per press with the session's flushing.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout's package, not an installed one

import nlipscalib.device.session as session_module  # noqa: E402
from nlipscalib.device.session import Operator, SessionConfig, capture_press, frame_sequence  # noqa: E402
from nlipscalib.emulator import default_script, open_emulated_sensor  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402


class Timed:
    """Proxy adding the time spent in some methods of an object to a shared tally."""

    def __init__(self, obj, tally: dict, methods: dict):
        self._obj, self._tally, self._methods = obj, tally, methods

    def __getattr__(self, name):
        attr = getattr(self._obj, name)
        if name not in self._methods:
            return attr

        def timed(*a, **k):
            t0 = time.perf_counter()
            try:
                return attr(*a, **k)
            finally:
                key = self._methods[name]
                self._tally[key] = self._tally.get(key, 0.0) + time.perf_counter() - t0

        return timed


def expected_camera_seconds(n_leds: int, fps: float, flush_frames: int, average: int, latch_s: float) -> float:
    """Seconds per press on a camera at ``fps``: every image waits for its flushed frames, then averages."""
    images = len(frame_sequence(n_leds, SessionConfig()))
    return images * ((flush_frames + average) / fps + latch_s)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--presses", type=int, default=5)
    args = ap.parse_args()
    print(f"load average: {os.getloadavg()}")

    scene = load_scene().replace(camera={"width": args.width, "height": args.height})
    script = default_script(args.presses)
    sensor = open_emulated_sensor(scene, script, echo=lambda s: None)
    t0 = time.perf_counter()
    sensor.prerender()
    print(f"pre-rendering {len(script) + 1} surfaces: {time.perf_counter() - t0:.1f} s")
    tally: dict = {}
    rig = sensor.rig
    rig.controller = Timed(rig.controller, tally, {"set_all": "leds", "off": "leds"})
    rig.source = Timed(rig.source, tally, {"capture": "camera"})
    session_module.write_press = Timed(session_module, tally, {"write_press": "write"}).write_press
    cfg = SessionConfig(presses=args.presses, tricolor_level=sensor.tricolor_level)
    op = Operator(echo=lambda s: None)
    per_press, parts = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k, step in enumerate(script, 1):
            sensor.camera.show(step.press)
            tally.clear()
            t0 = time.perf_counter()
            capture_press(rig, Path(tmp) / f"press_{k:04d}", cfg, op, index=k)
            per_press.append(time.perf_counter() - t0)
            parts.append(dict(tally))
    n_images = len(frame_sequence(len(rig.leds), cfg))
    leds = statistics.median(p["leds"] for p in parts)
    camera = statistics.median(p["camera"] for p in parts)
    write = statistics.median(p["write"] for p in parts)
    total = statistics.median(per_press)
    print(f"emulator {args.width}x{args.height}, {len(rig.leds)} LEDs, {n_images} images per press:")
    print(f"  per press median {total:.3f} s (LED commands {leds:.3f} s = {1e3 * leds / (n_images + 1):.1f} ms each,")
    print(f"  emulated camera {camera:.3f} s, atomic press write {write:.3f} s, movement check and rest ", end="")
    print(f"{total - leds - camera - write:.3f} s)")
    latch = leds / (n_images + 1)
    for flush in (1, 2):
        est = expected_camera_seconds(len(rig.leds), 30.0, flush, 1, latch)
        print(f"  expected on a 30 fps camera, {flush} flushed + 1 used frame per image: {est:.2f} s + write")
    sensor.close()

    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-c", "import sys; from nlipscalib.cli import command; sys.exit(command())"]
        cmd += ["capture", "--emulate", "nlipstac", "--presses", "3", "--out", str(Path(tmp) / "s")]
        cmd += ["--width", str(args.width), "--height", str(args.height)]
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, capture_output=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
        print(
            f"whole command `nlips capture --emulate nlipstac --presses 3` ({args.width}x{args.height}): "
            f"{time.perf_counter() - t0:.1f} s wall (renders included)"
        )
    print(f"load average: {os.getloadavg()}")


if __name__ == "__main__":
    main()
