"""What the LED board's ``STATE`` after every frame costs ``nlips calibrate-camera-response --port`` (s40-respwatch):
the command run whole (a process each) against the firmware in simavr paced at 115200 baud, a stand-in webcam
that sleeps one frame time per read (30 fps: a UVC webcam's), each checkout given (``--trees A,B``) run in turn, so
that a machine's load falls on both alike. Inner timer: the seconds spent in ``LedController.state``.
Needs gcc-avr, avr-libc and simavr (setup.sh). Usage::

    python benchmarks/bench_response_watch.py --trees /path/before,/path/after [--repeats 5] [--fps 30]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve()


def child(url: str, out: str, fps: float) -> None:
    """One run of the command in this process (its tree on PYTHONPATH); prints the seconds spent in STATE."""
    sys.path.insert(0, os.environ["PYTHONPATH"].split(os.pathsep)[0])
    import cv2
    import numpy as np

    from nlipscalib.cli import main
    from nlipscalib.device.controller import LedController
    from tests.device.test_response_bracket import BOARDS, Webcam

    class Paced(Webcam):
        def read(self):
            time.sleep(1 / fps)
            return super().read()

    spent = [0.0, 0]
    state = LedController.state

    def timed(self):
        t0 = time.perf_counter()
        try:
            return state(self)
        finally:
            spent[0] += time.perf_counter() - t0
            spent[1] += 1

    class Shown:  # the colours the board acknowledged: what the webcam sees lit (the harness's stdin is ours)
        latched = np.zeros((12, 3), np.uint8)  # the firmware build's 12 LEDs, dark as it boots

    set_all = LedController.set_all

    def seen(self, colours):
        set_all(self, colours)
        Shown.latched = self._shown.copy()

    LedController.state, LedController.set_all = timed, seen
    off = LedController.off
    LedController.off = lambda self: (off(self), setattr(Shown, "latched", self._shown.copy()))
    BOARDS.append(Shown)
    cv2.VideoCapture = lambda *a, **k: Paced()
    code = main(["calibrate-camera-response", "--port", url, "--camera", "0", "--out", out, "-q"])
    print(json.dumps({"code": code, "state_s": spent[0], "states": spent[1]}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trees", required=True, help="comma-separated checkouts to run in turn")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--fps", type=float, default=30.0)
    parser.add_argument("--child", nargs=2, metavar=("URL", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(*args.child, args.fps)
        return
    sys.path.insert(0, str(HERE.parents[1]))
    from tests.device.ledboards import SimavrUnderTest, build_firmware

    trees = args.trees.split(",")
    walls: dict[str, list[float]] = {t: [] for t in trees}
    inner: dict[str, list[dict]] = {t: [] for t in trees}
    with tempfile.TemporaryDirectory(prefix="nlips-bench-") as tmp:
        elf, harness = build_firmware(Path(tmp))
        board = SimavrUnderTest(elf, harness, Path(tmp) / "tty")
        board.pace(115200)
        try:
            for _ in range(args.repeats):
                for tree in trees:
                    env = {**os.environ, "PYTHONPATH": tree}
                    command = [sys.executable, str(HERE), "--trees", tree, "--fps", str(args.fps)]
                    command += ["--child", board.url, str(Path(tmp) / "r.json")]
                    t0 = time.perf_counter()
                    done = subprocess.run(command, env=env, capture_output=True, text=True, cwd=tmp)
                    walls[tree].append(time.perf_counter() - t0)
                    assert done.stdout.strip(), done.stderr
                    record = json.loads(done.stdout.strip().splitlines()[-1])
                    assert record["code"] == 0, done.stderr
                    inner[tree].append(record)
        finally:
            board.close()
    for tree in trees:
        states = inner[tree][0]["states"]
        state_s = statistics.median(r["state_s"] for r in inner[tree])
        print(
            f"{tree}: whole process median {statistics.median(walls[tree]):.2f} s "
            f"(runs {', '.join(f'{w:.2f}' for w in walls[tree])}); STATE {states} calls, {state_s:.3f} s in all"
        )


if __name__ == "__main__":
    main()
