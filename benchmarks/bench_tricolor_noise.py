"""The tri-colour check's misfit against the camera's noise (s40-trinoise): clean presses, two LED images of different
groups exchanged (led_04 / led_05, the shipped ring's weakest cross-group pair, and led_01 / led_09), another press's
tri-colour frame (the same noise, another azimuth), the frame as BGR, and all 32 cross-group pairs, per noise level of
the presses' scene (meta.json ``provenance.scene.noise``), each with the misfit its own noise leaves (measured
between pairs of blocks since s43-bayer, each block's halves before) and what is told above the fixed 3 % (until s41)
and above the misfit allowed now (``tricolor_check.allowed_misfit``), and the check's cost per press.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_tricolor_noise.py PRESSES_ROOT [--side 8] [--cost PRESS]
        [--extra-noise 400,800]

``PRESSES_ROOT``: folders ``sphere-p<polar>-a<azimuth>-d<depth>-<spec>-*`` (``nlips experiment studies``' presses).
``--side``: the blocks' side in px (default: the check's own, :func:`~nlipscalib.core.tricolor_check.tricolor_block`;
1 is single pixels). ``--extra-noise``: Gaussian noise (16-bit codes) added in memory to the noisiest level's presses,
each a level of its own, beyond the studies' noisiest."""

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

ORDER = ("off", "40000/1", "10000/2", "2500/4", "625/8")


def _noise(folder: Path) -> str:
    noise = json.loads((folder / "meta.json").read_text(encoding="utf-8"))["provenance"]["scene"]["noise"]
    return "off" if not noise["enabled"] else f"{noise['full_well']:.0f}/{noise['read_noise']:.0f}"


def _swapped(count: int, i: int, j: int) -> list[int]:
    order = list(range(count))
    order[i], order[j] = j, i
    return order


def _faulty(samples: tc.BlockSamples, order: list[int]) -> tc.BlockSamples:
    """``samples`` with the LED images in ``order`` (two exchanged)."""
    pairs = None if samples.images_pairs is None else samples.images_pairs[order]
    return samples._replace(images=samples.images[order], images_pairs=pairs)


def _bgr(samples: tc.BlockSamples) -> tc.BlockSamples:
    pairs = None if samples.tricolor_pairs is None else samples.tricolor_pairs[:, ::-1]
    return samples._replace(tricolor=samples.tricolor[:, ::-1], tricolor_pairs=pairs)


def _noisier(press, sigma: float, seed: int):  # noqa: ANN001, ANN202
    """``press`` with Gaussian noise of ``sigma`` 16-bit codes added to every stored frame (dark too), in memory."""
    rng = np.random.default_rng(seed)

    def noisy(frames: np.ndarray) -> np.ndarray:
        return np.clip(frames + rng.normal(0.0, sigma, frames.shape), 0, 65535).astype(frames.dtype)

    return dataclasses.replace(
        press, dark=noisy(press.dark), led_images=noisy(press.led_images), tricolor=noisy(press.tricolor)
    )


def _judge(samples: tc.BlockSamples, groups: np.ndarray) -> tuple[tc.TricolorFit, float]:
    """The fit within the misfit allowed for ``samples``' own noise, and that noise (worst channel)."""
    noise = tc.noise_misfits(samples, groups)
    fit = tc.tricolor_fit(samples.tricolor, samples.images, groups, tc.allowed_misfit(noise))
    return fit, float(np.nanmax(noise)) if np.isfinite(noise).any() else float("nan")


def measure(root: Path, side: int | None, extra: list[float]) -> dict:
    """Per (noise, kind): the worst channel's misfit of each press, its measured noise misfit, and what is told
    (above the fixed 3 %, as until s41, and above the misfit allowed for the capture's noise); ``extra``: 16-bit
    codes of Gaussian noise added to the noisiest level's presses, each a level of its own."""
    if side is not None:
        tc.tricolor_block = lambda shape: side  # the check's blocks, of this side
    presses = {f: (_noise(f), load_press(f)) for f in sorted(root.glob("sphere-*"))}
    noisiest = [n for n in ORDER if any(level == n for level, _ in presses.values())][-1]
    for sigma in extra:
        for k, (f, (n, p)) in enumerate(list(presses.items())):
            if n == noisiest:
                presses[f.with_name(f"{f.name}+{sigma:g}")] = (f"{noisiest} +{sigma:g}", _noisier(p, sigma, k))
    groups = tricolor_groups(12)
    pairs = [(i, j) for i in range(12) for j in range(i + 1, 12) if groups[i] != groups[j]]
    rows: dict = defaultdict(lambda: defaultdict(list))
    for folder, (noise, press) in presses.items():
        pixels = tc.gel_samples(press.reference, press.camera.shape)
        samples = tc.block_samples(press, pixels)
        polar = folder.name.split("-a")[0]
        other = next(
            g for g, (n, _) in presses.items() if n == noise and g != folder and g.name.startswith(polar + "-")
        )
        mixed = tc.block_samples(dataclasses.replace(press, tricolor=presses[other][1].tricolor), pixels)
        row = rows[noise]
        clean, row_noise = _judge(samples, groups)
        row["clean"].append(np.max(clean.misfit))
        row["noise"].append(row_noise)
        row["allowed"].append(clean.allowed)
        row["clean warned 3 %"].append(np.max(clean.misfit) > 0.03)
        row["clean warned"].append(np.max(clean.misfit) > clean.allowed)
        fit, _ = _judge(_faulty(samples, _swapped(12, 3, 4)), groups)
        row["led_04/05"].append(np.max(fit.misfit))
        row["04/05 told"].append(np.max(fit.misfit) > fit.allowed)
        row["named"].append(fit.exchanged == (3, 4))
        fit, _ = _judge(_faulty(samples, _swapped(12, 0, 8)), groups)
        row["led_01/09"].append(np.max(fit.misfit))
        row["01/09 told"].append(np.max(fit.misfit) > fit.allowed)
        fit, _ = _judge(mixed, groups)
        row["other frame"].append(np.max(fit.misfit))
        row["other told 3 %"].append(np.max(fit.misfit) > 0.03)
        row["other told"].append(np.max(fit.misfit) > fit.allowed)
        row["bgr said"].append(_judge(_bgr(samples), groups)[0].sources == (2, 1, 0))
        told = []
        for i, j in pairs:
            fit, _ = _judge(_faulty(samples, _swapped(12, i, j)), groups)
            told.append(np.max(fit.misfit) > fit.allowed)
        row["pairs told"].append(np.mean(told))
    return rows


def cost(folder: Path, runs: int = 7) -> tuple[float, float]:
    """Median CPU seconds of the verdict on a press freshly loaded (its frames decoded first), without and with the
    whole frames linearised before (a capture / a solve)."""
    times: dict = {False: [], True: []}
    for linear in (False, True):
        for _ in range(runs):
            press = load_press(folder)
            decoded = [press.led_images, press.tricolor, press.dark]  # as a solve holds them
            if linear:
                decoded.append(press.linear_led_images)
            start = time.process_time()
            tc.press_tricolor_verdict(press)
            times[linear].append(time.process_time() - start)
    return float(np.median(times[False])), float(np.median(times[True]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path)
    parser.add_argument("--side", type=int, default=None)
    parser.add_argument("--cost", type=Path, default=None, help="a press to time the check on")
    parser.add_argument(
        "--extra-noise",
        default="",
        help="comma-separated 16-bit codes of Gaussian noise added to the noisiest level's presses (e.g. 400,800)",
    )
    args = parser.parse_args()
    extra = [float(v) for v in args.extra_noise.split(",") if v]
    rows = measure(args.root, args.side, extra)
    print(
        "| noise | presses | clean | noise measured | allowed | clean warned (3 % / now) | led_04/05 | told, named "
        "| led_01/09 told | another press's frame | told (3 % / now) | BGR said | pairs told |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    span = lambda v: f"{100 * min(v):.2f}-{100 * max(v):.2f} %"  # noqa: E731
    levels = [n for n in ORDER if n in rows] + sorted(set(rows) - set(ORDER), key=lambda n: float(n.split("+")[-1]))
    for noise in levels:
        r = rows[noise]
        print(
            f"| {noise} | {len(r['clean'])} | {span(r['clean'])} | {span(r['noise'])} | {span(r['allowed'])} "
            f"| {sum(r['clean warned 3 %'])} / {sum(r['clean warned'])} | {span(r['led_04/05'])} "
            f"| {sum(r['04/05 told'])}, {sum(r['named'])} | {sum(r['01/09 told'])} | {span(r['other frame'])} "
            f"| {sum(r['other told 3 %'])} / {sum(r['other told'])} | {sum(r['bgr said'])} "
            f"| {100 * np.mean(r['pairs told']):.0f} % |"
        )
    if args.cost:
        cold, linear = cost(args.cost)
        print(f"cost per press: {1e3 * cold:.1f} ms CPU (frames decoded), {1e3 * linear:.1f} ms (linearised already)")


if __name__ == "__main__":
    main()
