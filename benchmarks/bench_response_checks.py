"""What the camera-response bracket's checks measure (s31-respcam): on the emulated sensor, the channels' difference,
the exposure-ratio error and the dark frame's median code of brackets that are right (the margins under
``tolerances.RESPONSE_CHANNEL_SPREAD``, ``RESPONSE_RATIO_ERROR`` and ``RESPONSE_BLACK_CODES``); on the stand-in
webcams of ``tests/device/test_response_bracket.py``, what ``nlips calibrate-camera-response`` does with a camera
that takes an exposure at a time of its own or adds a black level (exit code, the refusal, or the written curve's
error against the true gamma 2.2). The stand-ins are this file's repository's; the package is PYTHONPATH's, so
``PYTHONPATH=OLD_TREE python benchmarks/bench_response_checks.py --no-emulated`` shows what an older one did::

    PYTHONPATH=. python benchmarks/bench_response_checks.py [--no-emulated] [--no-stand-in]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import tempfile
from pathlib import Path

import numpy as np

FULL_STOPS = (0.25, 0.5, 1, 2, 4, 8, 16, 32, 64)
FROM_DARK = tuple(round(0.125 * 2 ** (k / 2), 3) for k in range(19))
SHUTTER_MS = tuple(1000 / n for n in (4000, 2000, 1000, 500, 250, 125, 60, 30, 15))
"""A camera's table of 1/n s exposures: asked a power of two ms, it takes the nearest."""


def emulated() -> None:
    """The checks' measures on right brackets of the emulated sensor."""
    from nlipscalib.cli import camera_response as cr
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.device.response_fit import check_black, fit_response

    for size in ((64, 48, 1), (160, 120, 4)):
        for curve in (None, "gamma2.2", "s-curve", "srgb", "rgb-gammas"):
            for name, exposures in (("half", cr.DEFAULT_EXPOSURES_MS), ("full", FULL_STOPS), ("from 0.125", FROM_DARK)):
                if size[0] == 160 and name != "half":
                    continue
                args = argparse.Namespace(
                    emulate="nlipstac", width=size[0], height=size[1], spp=size[2], led=1, level=255, seed=0
                )
                args.emulate_tone_curve = curve
                codes, source, _, black, dark, _ = cr._emulated_bracket(args, exposures)
                median = check_black(dark[0], dark[1], source, black, dark[2])
                try:
                    fit = fit_response(codes, exposures, source)
                except CaptureError as exc:
                    print(f"{size} {curve} {name}: refused: {exc}")
                    continue
                print(
                    f"{size} {curve} {name}: channel spread {fit.channel_spread:.4f}, difference "
                    f"{fit.channel_difference:.4f}, per channel {fit.kept.ndim == 2}, exposure ratio error "
                    f"{fit.ratio_error:.4f}, dark median {median:g} codes",
                    flush=True,
                )


def stand_in() -> None:
    """The stand-in webcams through the command."""
    import importlib.util

    import cv2

    from nlipscalib.cli import main
    from nlipscalib.device.virtual_board import VirtualBoard

    path = Path(__file__).resolve().parents[1] / "tests" / "device" / "test_response_bracket.py"
    spec = importlib.util.spec_from_file_location("stand_in_webcams", path)
    bracket = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bracket)

    def nearest(table):
        return lambda ms: min(table, key=lambda t: abs(math.log(t / ms)))

    cases = {
        "takes the times asked": ({}, None),
        "4 ms taken 4.12 (3 %)": ({"taken": lambda ms: 4.12 if ms == 4 else ms}, None),
        "4 ms taken 4.2 (5 %)": ({"taken": lambda ms: 4.2 if ms == 4 else ms}, None),
        "4 ms taken 4.3 (7.5 %)": ({"taken": lambda ms: 4.3 if ms == 4 else ms}, None),
        "2.83 ms taken 3.0 (6 %)": ({"taken": lambda ms: 3.0 if abs(ms - 2.83) < 0.05 else ms}, None),
        "16 ms taken 1/60 s (4.2 %)": ({"taken": lambda ms: 16.67 if ms == 16 else ms}, None),
        "full stops, right": ({}, FULL_STOPS),
        "full stops, 1/n s table": ({"taken": nearest(SHUTTER_MS)}, FULL_STOPS),
        "full stops 0.5-64, 1/n s table read back": (
            {"taken": nearest(SHUTTER_MS), "reports": "taken"},
            FULL_STOPS[1:],
        ),
        "full stops 0.5-64, 1/n s table, reads back the time asked": (
            {"taken": nearest(SHUTTER_MS), "reports": "asked"},
            FULL_STOPS[1:],
        ),
        "a 1 ms minimum, read back": ({"min_ms": 1.0}, None),
        "times 0.5 * (t / 0.5) ** 0.9": ({"taken": lambda ms: 0.5 * (ms / 0.5) ** 0.9}, None),
        "black level +3 codes": ({"black": 3}, None),
        "black level +8 codes": ({"black": 8}, None),
    }
    truth = (np.arange(256) / 255) ** bracket.GAMMA
    for name, (behaviour, exposures) in cases.items():
        cv2.VideoCapture = lambda *a, _b=behaviour, **k: bracket.Webcam(**_b)
        board = VirtualBoard(12)
        bracket.BOARDS.append(board)  # the stand-in sees the gel dark while every LED is off
        out = Path(tempfile.mkdtemp()) / "r.json"
        more = ["--exposures-ms", ",".join(f"{t:g}" for t in exposures)] if exposures else []
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(["calibrate-camera-response", "--port", board.url, "--camera", "0", "--out", str(out), *more])
        bracket.BOARDS.remove(board)
        board.close()
        said = err.getvalue().strip().splitlines()
        if out.exists():
            doc = json.loads(out.read_text(encoding="utf-8"))
            error = np.abs(np.asarray(doc["response_curve"]) - truth)[10:251].max()
            ratio = doc["provenance"].get("exposure_ratio_error")
            print(f"{name}: exit {code}, curve {error:.4f} off the camera's, exposure ratio error {ratio}")
        else:
            print(f"{name}: exit {code}: {said[-1] if said else ''}")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--no-emulated", action="store_true")
    p.add_argument("--no-stand-in", action="store_true")
    args = p.parse_args()
    if not args.no_emulated:
        emulated()
    if not args.no_stand_in:
        stand_in()


if __name__ == "__main__":
    main()
