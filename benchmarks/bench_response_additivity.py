"""What the camera-response calibration's additivity frames say (s31-additive): LEDs lit apart and together at one
exposure, the fitted curve undone (``device.additivity``). On the emulated sensor: every tone curve's right bracket
(the misfit as fitted, the two bins' gap: the margins under ``tolerances.RESPONSE_ADDITIVITY_ERROR`` and
``RESPONSE_ADDITIVITY_GAP``), and the emulated camera made to take ``0.5 (t / 0.5) ** a`` ms when asked ``t`` (the
power its curve is then off by, pinned back). On the stand-in webcams of ``tests/device/test_response_bracket.py``:
times a power of the asked ones, and LED pairs that dim (or brighten) as a whole; exit code, power, misfit before
and after, the written curve's error against the true gamma 2.2 and the fitted one's (the written curve to the
power 1 / ``power``)::

    PYTHONPATH=. python benchmarks/bench_response_additivity.py [--sizes 64x48x1,160x120x4] [--no-stand-in]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
from pathlib import Path

import numpy as np


def _record(path: Path) -> tuple[dict, np.ndarray]:
    doc = json.loads(path.read_text(encoding="utf-8"))
    return doc["provenance"]["additivity"], np.asarray(doc["response_curve"], dtype=np.float64)


def _line(name: str, code: int, err: str, out: Path, true: np.ndarray | None) -> str:
    if code != 0:
        return f"{name}: exit {code}: {err.strip()[-260:]}"
    rec, curve = _record(out)
    text = (
        f"{name}: exit 0, power {rec['power']:.4f}, misfit {rec['error']:.4f} -> {rec['error_after']:.4f} "
        f"(pairs {rec['pairs']}, {rec['exposure_ms']:g} ms)"
    )
    if true is not None:
        lit = slice(10, 251)
        fitted = curve ** (1 / rec["power"])
        text += (
            f"; curve off the true by {np.abs(curve - true)[..., lit].max():.4f} (as fitted "
            f"{np.abs(fitted - true)[..., lit].max():.4f})"
        )
    return text


def _run(args: list[str]) -> tuple[int, str]:
    from nlipscalib.cli import main

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(args)
    return code, err.getvalue()


def _power_camera(a: float):
    """The emulated camera taking 0.5 (t / 0.5) ** a ms when asked t (its exposure_scale is t / 10 ms)."""
    from nlipscalib import emulator

    class PowerCamera(emulator.EmulatedCamera):
        @property
        def exposure_scale(self) -> float:
            return self._scale

        @exposure_scale.setter
        def exposure_scale(self, value: float) -> None:
            self._scale = 0.05 * (value / 0.05) ** a

    return PowerCamera


def emulated(sizes: list[tuple[int, int, int]]) -> None:
    from nlipscalib import emulator
    from nlipscalib.emulator import EMULATED_TONE_CURVES

    grid = np.linspace(0, 1, 400001, dtype=np.float32)
    real = emulator.EmulatedCamera
    for w, h, spp in sizes:
        size = ["--width", str(w), "--height", str(h), "--spp", str(spp)]
        for curve in (None, "gamma2.2", "s-curve", "srgb", "rgb-gammas"):
            if curve is None:
                true = np.arange(256) / 255
            else:
                encoded = EMULATED_TONE_CURVES[curve](np.stack([grid] * 3, -1)).astype(np.float64)
                true = np.stack([np.interp(np.arange(256) / 255, encoded[:, c], grid) for c in range(3)])
                true = true if curve == "rgb-gammas" else true[1]
            for a in (1.0, 0.9, 1.1) if curve in (None, "gamma2.2") else (1.0,):
                emulator.EmulatedCamera = real if a == 1.0 else _power_camera(a)
                with tempfile.TemporaryDirectory() as tmp:
                    out = Path(tmp) / "r.json"
                    more = ["--emulate-tone-curve", curve] if curve else []
                    code, err = _run(
                        ["calibrate-camera-response", "--emulate", "nlipstac", *more, *size, "--out", str(out)]
                    )
                    print(
                        _line(f"emulated {w}x{h}x{spp} {curve or 'linear'} times^{a}", code, err, out, true), flush=True
                    )
    emulator.EmulatedCamera = real


def _power_times(a: float):
    """The stand-in's real time when asked ``ms``: 0.5 (ms / 0.5) ** a."""
    return lambda ms: 0.5 * (ms / 0.5) ** a


def stand_in() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "device"))
    import cv2
    import test_response_bracket as t

    cases = [("right", {})]
    cases += [(f"times^{a}", {"taken": _power_times(a)}) for a in (0.8, 0.9, 0.97, 1.1)]
    cases += [(f"droop {k}", {"droop": k}) for k in (0.95, 0.97, 0.98, 1.05)]
    for name, behaviour in cases:
        cv2.VideoCapture = (lambda b: lambda *x, **k: t.Webcam(**b))(behaviour)
        with tempfile.TemporaryDirectory() as tmp:
            board = t.VirtualBoard(12)
            t.BOARDS.append(board)
            out = Path(tmp) / "r.json"
            try:
                code, err = _run(["calibrate-camera-response", "--port", board.url, "--camera", "0", "--out", str(out)])
            finally:
                t.BOARDS.remove(board)
                board.close()
            print(_line(f"stand-in {name}", code, err, out, t._true_curve()), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="64x48x1", help="emulated WxHxSPP, comma-separated")
    parser.add_argument("--no-stand-in", action="store_true")
    parser.add_argument("--no-emulated", action="store_true")
    args = parser.parse_args()
    if not args.no_emulated:
        emulated([tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")])
    if not args.no_stand_in:
        stand_in()


if __name__ == "__main__":
    main()
