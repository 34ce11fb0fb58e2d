"""A bracket's exposure times estimated from its frames (s33-bracket, ``device.bracket_times``): how close the
estimated steps come to the camera's real ones, on right brackets and on a camera that rounds the times asked to a
1/n s shutter table without a word (16, 32, 64 ms taken as 1/60, 1/30, 1/15 s), and what ``nlips
calibrate-camera-response --bracket FOLDER`` (no ``additivity/`` frames) writes from such folders::

    PYTHONPATH=. python benchmarks/bench_response_times.py estimate [--sizes 64x48x1,160x120x4] [--seeds 3]
    PYTHONPATH=. python benchmarks/bench_response_times.py folders [--emulated]

``estimate`` needs this package's ``device.bracket_times``; ``folders`` runs the command of the package on
PYTHONPATH (``PYTHONPATH=OLD_TREE`` shows what an older one wrote from the same folders: the stand-in gamma 2.2
webcam's of ``tests/device/test_response_bracket.py``, and with ``--emulated`` the emulated sensor's brackets saved
as PNGs). Curve error: max |curve - true| over codes 10-250.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import io
import json
import math
import tempfile
import time
from pathlib import Path

import numpy as np

FULL = (0.5, 1, 2, 4, 8, 16, 32, 64)
FROM_QUARTER = (0.25, *FULL)
SHUTTER_MS = tuple(1000 / n for n in (8000, 4000, 2000, 1000, 500, 250, 125, 60, 30, 15))
LIT = slice(10, 251)


def on_the_table(ms: float) -> float:
    """The 1/n s time a shutter-table camera takes when asked ``ms``."""
    return min(SHUTTER_MS, key=lambda t: abs(math.log(t / ms)))


def _stand_ins():
    path = Path(__file__).resolve().parents[1] / "tests" / "device" / "test_response_bracket.py"
    spec = importlib.util.spec_from_file_location("stand_in_webcams", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def emulated_bracket(size: tuple[int, int, int], curve: str | None, exposures, shutter: bool, seed: int):
    """The emulated sensor's bracket codes (one LED, as the command takes it), through a shutter-table camera when
    ``shutter``; and the true curve (green channel) of ``curve``."""
    from nlipscalib import emulator
    from nlipscalib.cli import camera_response as cr
    from nlipscalib.emulator import EMULATED_TONE_CURVES

    real = emulator.EmulatedCamera

    class ShutterCamera(real):
        @property
        def exposure_scale(self):
            return self._scale

        @exposure_scale.setter
        def exposure_scale(self, value):
            self._scale = on_the_table(value * cr.EMULATED_EXPOSURE_MS) / cr.EMULATED_EXPOSURE_MS

    emulator.EmulatedCamera = ShutterCamera if shutter else real
    try:
        args = argparse.Namespace(
            emulate="nlipstac", width=size[0], height=size[1], spp=size[2], led=1, level=255, seed=seed
        )
        args.emulate_tone_curve = curve
        codes = cr._emulated_bracket(args, exposures)[0]
    finally:
        emulator.EmulatedCamera = real
    grid = np.linspace(0, 1, 400001, dtype=np.float32)
    if curve is None:
        true = np.arange(256) / 255
    else:
        encoded = EMULATED_TONE_CURVES[curve](np.stack([grid] * 3, -1)).astype(np.float64)
        true = np.interp(np.arange(256) / 255, encoded[:, 1], grid)
    return codes, true


def _judge(name: str, frames, named, real, true) -> None:
    from nlipscalib.device.bracket_times import estimate_times
    from nlipscalib.device.response_fit import fit_response

    named = np.asarray(named, dtype=np.float64)
    start = time.process_time()
    estimate = estimate_times(frames, named, name)
    cpu = time.process_time() - start
    if estimate is None:
        print(f"{name}: too few steps judged", flush=True)
        return
    found = np.diff(np.log(estimate.estimated_ms))
    judged = np.array([e is not None for e in estimate.step_errors])
    off = np.abs(np.expm1(found - np.diff(np.log(real))))[judged].max()
    as_named = _curve_error(fit_response, frames, named, true)
    written = _curve_error(fit_response, frames, estimate.estimated_ms, true) if estimate.used else as_named
    print(
        f"{name}: used {estimate.used}, largest step off the named {estimate.largest:.4f}, judged steps off the "
        f"camera's by {off:.4f} at most ({judged.sum()} of {len(judged)}), {estimate.rounds} rounds, {cpu:.2f} s CPU; "
        f"curve at the named times {as_named}, written {written}",
        flush=True,
    )


def _curve_error(fit_response, frames, times, true) -> str:
    from nlipscalib.core.errors import CaptureError

    try:
        return f"{np.abs(fit_response(frames, times, 'x').curve - true)[LIT].max():.4f}"
    except CaptureError as exc:
        return f"refused ({str(exc)[3:60]}...)"


def estimate(sizes, seeds: int) -> None:
    from nlipscalib.cli.camera_response import DEFAULT_EXPOSURES_MS

    for size in sizes:
        for seed in range(seeds if size[0] <= 64 else 1):
            for curve in (None, "gamma2.2", "s-curve", "srgb"):
                for exposures, shutter in (
                    (FULL, False),
                    (FULL, True),
                    (FROM_QUARTER, True),
                    (DEFAULT_EXPOSURES_MS, False),
                ):
                    codes, true = emulated_bracket(size, curve, exposures, shutter, seed)
                    real = [on_the_table(ms) if shutter else ms for ms in exposures]
                    kind = "shutter table" if shutter else "right"
                    size_name = "x".join(map(str, size))
                    span = f"{exposures[0]:g}-64 ms x{len(exposures)}"
                    name = f"emulated {size_name} seed {seed} {curve or 'linear'} {span} {kind}"
                    _judge(name, codes, exposures, real, true)
    # a noisier bracket: a gradient through gamma 2.2 with light noise 0.002 of full scale (s31-respcam's)
    bracket = _stand_ins()
    for named in ((0.125, *FROM_QUARTER), FULL):
        for shutter in (False, True):
            for seed in range(5):
                rng = np.random.default_rng(seed)
                real = [on_the_table(ms) if shutter else ms for ms in named]
                frames = []
                for ms in real:
                    light = np.clip(bracket.LIGHT * ms / 8 + rng.normal(0, 0.002, bracket.LIGHT.shape), 0, 1)
                    frames.append(np.rint(255 * light ** (1 / 2.2)).astype(np.uint8))
                kind = "shutter table" if shutter else "right"
                _judge(
                    f"noisy synthetic {named[0]:g}-64 ms {kind} seed {seed}", frames, named, real, bracket._true_curve()
                )


def _command(folder: Path) -> tuple[int, str, dict | None, np.ndarray | None]:
    from nlipscalib.cli import main

    out = folder.parent / "r.json"
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["calibrate-camera-response", "--bracket", str(folder), "--out", str(out)])
    if code != 0:
        return code, err.getvalue().strip().splitlines()[-1], None, None
    doc = json.loads(out.read_text(encoding="utf-8"))
    return code, err.getvalue(), doc["provenance"], np.asarray(doc["response_curve"])


def folders(with_emulated: bool) -> None:
    import cv2

    bracket = _stand_ins()
    half = bracket.EXPOSURES
    cases = {
        "full stops 0.5-64, 1/n s table": (FULL, on_the_table),
        "full stops 0.25-64, 1/n s table": (FROM_QUARTER, on_the_table),
        "full stops 0.5-64, right": (FULL, None),
        "half stops, right": (half, None),
        "half stops, 16 ms taken 1/60 s": (half, lambda ms: 1000 / 60 if ms == 16 else ms),
        "half stops, 4 ms taken 4.3": (half, lambda ms: 4.3 if ms == 4 else ms),
        "half stops, 2.83 ms taken 3.0": (half, lambda ms: 3.0 if abs(ms - 2.828) < 0.01 else ms),
        "half stops, times 0.5 (t / 0.5) ** 0.9": (half, lambda ms: 0.5 * (ms / 0.5) ** 0.9),
    }
    for name, (named, taken) in cases.items():
        with tempfile.TemporaryDirectory() as tmp:
            real = [taken(ms) for ms in named] if taken else None
            folder = bracket._write_bracket(Path(tmp) / "b", list(named), frame_ms=real)
            _report(f"stand-in: {name}", *_command(folder), bracket._true_curve())
    if not with_emulated:
        return
    for curve in (None, "gamma2.2"):
        for exposures, shutter in ((FULL, True), (FULL, False)):
            codes, true = emulated_bracket((64, 48, 1), curve, exposures, shutter, 0)
            with tempfile.TemporaryDirectory() as tmp:
                folder = Path(tmp) / "b"
                folder.mkdir()
                for ms, frame in zip(exposures, codes, strict=True):
                    cv2.imwrite(str(folder / f"gel_{ms:g}ms.png"), frame[..., ::-1])
                kind = "1/n s table" if shutter else "right"
                _report(f"emulated 64x48x1 {curve or 'linear'} full stops, {kind}", *_command(folder), true)


def _report(name: str, code: int, said: str, provenance: dict | None, curve: np.ndarray | None, true) -> None:
    if code != 0:
        print(f"{name}: exit {code}: {said[:200]}", flush=True)
        return
    record = provenance.get("exposures_estimated")
    used = (
        "no estimate recorded"
        if record is None
        else f"estimate used {record['used']} (largest step {record['largest_step_error']:.4f})"
    )
    print(f"{name}: exit 0, curve {np.abs(curve - true)[LIT].max():.4f} off the camera's; {used}", flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("what", choices=("estimate", "folders"))
    p.add_argument("--sizes", default="64x48x1", help="emulated WxHxSPP, comma-separated")
    p.add_argument("--seeds", type=int, default=3, help="noise seeds of the 64x48 emulated brackets")
    p.add_argument("--emulated", action="store_true", help="folders: the emulated sensor's brackets too")
    args = p.parse_args()
    if args.what == "estimate":
        estimate([tuple(int(v) for v in s.split("x")) for s in args.sizes.split(",")], args.seeds)
    else:
        folders(args.emulated)


if __name__ == "__main__":
    main()
