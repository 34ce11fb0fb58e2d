"""The tri-colour check on frames of a Bayer camera (s43-bayer): each press as rendered (three colours per pixel) and
as a Bayer camera delivers it, with and without the filters' colour crosstalk, per demosaicing: the clean frame's
misfit, the misfit its own noise leaves (:func:`~nlipscalib.core.tricolor_check.noise_misfits`), the misfit allowed,
false alarms, and what is told of two LED images of different groups exchanged (led_04 / led_05, the shipped ring's
weakest cross-group pair: told and named; led_01 / led_09; all 32 pairs), of another press's frame and of a BGR frame.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_bayer_tricolor.py PRESS... [--pattern RGGB] [--extra-noise 1500]
    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_bayer_tricolor.py PRESS --cost

``--cost``: the CPU time of the tri-colour verdict and of the solver's ``image_noise`` on each press as stored
(median of 7, its frames decoded first), for the before / after of s43-bayer (run it against each checkout).

The Bayer camera is made in memory from each press's stored frames (:func:`nlipscalib.sim.bayer.bayer_camera`: each
pixel's own channel of frames noised per pixel and channel is the noisy raw frame, so this is the twin's Bayer render
of the same light and noise); the crosstalk (:data:`~nlipscalib.sim.bayer.TYPICAL_CROSSTALK`) mixes the stored values
above the black level, their noise with them (the twin's ``camera_effects.crosstalk`` mixes the light before the
noise: the same light, noise ~1-2 % larger here). ``--extra-noise``: Gaussian noise (16-bit codes) added to every
stored frame before the camera (the raw frame's noise: a noisier camera). A press whose meta.json already records a
Bayer camera is read as it is, a camera of its own (``rendered bayer``)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from nlipscalib.core import load_press
from nlipscalib.core import tricolor_check as tc
from nlipscalib.core.leds import tricolor_groups
from nlipscalib.sim.bayer import TYPICAL_CROSSTALK, bayer_camera

CAMERAS = ("rgb", "bilinear", "edge_aware", "edge_aware + crosstalk")


def _camera(press, camera: str, pattern: str):  # noqa: ANN001, ANN202
    """``press`` with its stored frames as ``camera`` delivers them, in memory."""
    if camera == "rgb":
        return press
    method = camera.split(" ")[0]
    black = float(press.response.black_level)
    mix = np.asarray(TYPICAL_CROSSTALK)

    def seen(frames: np.ndarray) -> np.ndarray:
        if camera.endswith("crosstalk"):
            mixed = (frames.astype(np.float64) - black) @ mix.T + black
            frames = np.clip(np.rint(mixed), 0, 65535).astype(np.uint16)
        return bayer_camera(frames, pattern, method)

    return dataclasses.replace(
        press, dark=seen(press.dark), led_images=seen(press.led_images), tricolor=seen(press.tricolor)
    )


def _noise_fields(samples: tc.BlockSamples) -> tuple[str, str]:
    """The tri-colour frame's and the LED images' noise fields of ``samples``: ``*_pairs`` (s43-bayer on), or the
    blocks' ``*_halves`` of the code before (this file run against an older checkout, for the before side)."""
    return (
        ("tricolor_pairs", "images_pairs")
        if "images_pairs" in samples._fields
        else ("tricolor_halves", "images_halves")
    )


def _swapped(samples: tc.BlockSamples, i: int, j: int) -> tc.BlockSamples:
    order = list(range(samples.images.shape[0]))
    order[i], order[j] = j, i
    field = _noise_fields(samples)[1]
    noise = getattr(samples, field)
    return samples._replace(images=samples.images[order], **{field: None if noise is None else noise[order]})


def _bgr(samples: tc.BlockSamples) -> tc.BlockSamples:
    field = _noise_fields(samples)[0]
    noise = getattr(samples, field)
    return samples._replace(tricolor=samples.tricolor[:, ::-1], **{field: None if noise is None else noise[:, ::-1]})


def _judge(samples: tc.BlockSamples, groups: np.ndarray) -> tuple[tc.TricolorFit, float]:
    noise = tc.noise_misfits(samples, groups)
    fit = tc.tricolor_fit(samples.tricolor, samples.images, groups, tc.allowed_misfit(noise))
    return fit, float(np.nanmax(noise)) if np.isfinite(noise).any() else float("nan")


def _recorded_bayer(folder: Path) -> bool:
    meta = json.loads((folder / "meta.json").read_text(encoding="utf-8"))
    return (meta.get("provenance", {}).get("scene", {}).get("camera_effects", {}).get("bayer", "none")) != "none"


def _noisier(press, sigma: float, seed: int):  # noqa: ANN001, ANN202
    """``press`` with Gaussian noise of ``sigma`` 16-bit codes added to every stored frame (dark too), in memory."""
    if not sigma:
        return press
    rng = np.random.default_rng(seed)

    def noisy(frames: np.ndarray) -> np.ndarray:
        return np.clip(frames + rng.normal(0.0, sigma, frames.shape), 0, 65535).astype(frames.dtype)

    return dataclasses.replace(
        press, dark=noisy(press.dark), led_images=noisy(press.led_images), tricolor=noisy(press.tricolor)
    )


def measure(folders: list[Path], pattern: str, sigma: float = 0.0) -> dict:
    groups = tricolor_groups(12)
    pairs = [(i, j) for i in range(12) for j in range(i + 1, 12) if groups[i] != groups[j]]
    loaded = {f: _noisier(load_press(f), sigma, k) for k, f in enumerate(folders)}
    rows: dict = defaultdict(lambda: defaultdict(list))
    for folder, stored in loaded.items():
        cameras = ("rendered bayer",) if _recorded_bayer(folder) else CAMERAS
        other = next((g for g in folders if g != folder and loaded[g].camera.shape == stored.camera.shape), None)
        for camera in cameras:
            press = stored if camera == "rendered bayer" else _camera(stored, camera, pattern)
            key = (f"{stored.camera.shape[1]}x{stored.camera.shape[0]}", camera)
            pixels = tc.gel_samples(press.reference, press.camera.shape)
            samples = tc.block_samples(press, pixels)
            row = rows[key]
            clean, noise = _judge(samples, groups)
            row["clean"].append(np.max(clean.misfit))
            row["noise"].append(noise)
            row["allowed"].append(clean.allowed)
            row["warned"].append(np.max(clean.misfit) > clean.allowed or clean.sources != (0, 1, 2))
            fit, _ = _judge(_swapped(samples, 3, 4), groups)
            row["04/05"].append(np.max(fit.misfit))
            row["04/05 told"].append(np.max(fit.misfit) > fit.allowed)
            row["named"].append(fit.exchanged == (3, 4))
            fit, _ = _judge(_swapped(samples, 0, 8), groups)
            row["01/09 told"].append(np.max(fit.misfit) > fit.allowed)
            if other is not None:
                mixed = dataclasses.replace(press, tricolor=_camera(loaded[other], camera, pattern).tricolor)
                if camera == "rendered bayer":
                    mixed = dataclasses.replace(press, tricolor=loaded[other].tricolor)
                fit, _ = _judge(tc.block_samples(mixed, pixels), groups)
                row["other told"].append(np.max(fit.misfit) > fit.allowed)
            row["bgr said"].append(_judge(_bgr(samples), groups)[0].sources == (2, 1, 0))
            told = [np.max((f := _judge(_swapped(samples, i, j), groups)[0]).misfit) > f.allowed for i, j in pairs]
            row["pairs told"].append(np.mean(told))
    return rows


def cost(folder: Path, runs: int = 7) -> tuple[float, float]:
    """Median CPU seconds of the tri-colour verdict and of ``image_noise`` of the press's linear LED images."""
    from nlipscalib.solver.image_stats import image_noise

    verdict, noise = [], []
    for _ in range(runs):
        press = load_press(folder)
        _ = [press.led_images, press.tricolor, press.dark]  # decoded, as a solve holds them
        start = time.process_time()
        tc.press_tricolor_verdict(press)
        verdict.append(time.process_time() - start)
        linear, valid = press.linear_led_images, np.isfinite(press.reference.depth)
        start = time.process_time()
        image_noise(linear, valid)
        noise.append(time.process_time() - start)
    return float(np.median(verdict)), float(np.median(noise))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("presses", type=Path, nargs="+")
    parser.add_argument("--pattern", default="RGGB")
    parser.add_argument("--extra-noise", type=float, default=0.0, help="16-bit codes of Gaussian noise, raw")
    parser.add_argument("--cost", action="store_true", help="time the verdict and image_noise instead")
    args = parser.parse_args()
    if args.cost:
        for folder in args.presses:
            verdict, noise = cost(folder)
            print(f"{folder}: verdict {1e3 * verdict:.1f} ms CPU, image_noise {1e3 * noise:.1f} ms CPU")
        return
    rows = measure(args.presses, args.pattern, args.extra_noise)
    print(
        "| frame | camera | presses | clean misfit | noise measured | allowed | clean warned | led_04/05 | told, named "
        "| led_01/09 told | another press's frame told | BGR said | pairs told |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    span = lambda v: f"{100 * np.nanmin(v):.2f}-{100 * np.nanmax(v):.2f} %"  # noqa: E731
    for (size, camera), r in sorted(rows.items(), key=lambda kv: (kv[0][0], kv[0][1])):
        other = f"{sum(r['other told'])} of {len(r['other told'])}" if r["other told"] else "-"
        print(
            f"| {size} | {camera} | {len(r['clean'])} | {span(r['clean'])} | {span(r['noise'])} | {span(r['allowed'])} "
            f"| {sum(r['warned'])} | {span(r['04/05'])} | {sum(r['04/05 told'])}, {sum(r['named'])} "
            f"| {sum(r['01/09 told'])} | {other} | {sum(r['bgr said'])} | {100 * np.mean(r['pairs told']):.0f} % |"
        )


if __name__ == "__main__":
    main()
