"""The indirect term by distance from the gel's outline: the solve's fitted term and the twin's filtered bounce light
against the render's raw bounce light (issue 6, s35-wideedge).

Renders SCENE's undeformed dome with one bounce in-process, the bounce light apart from the direct light (raw, and
filtered as the twin's ``render.denoise_indirect`` filters it), at SPP samples and SEED; fits the term on CAPTURE (a
one-bounce ``nlips render --undeformed`` capture of the same scene, ``solver.interreflection.estimate_indirect`` with
its design's LEDs; DIRECT, the same capture in direct light, gives the linear units). Prints per band of distance
from the outline (the outermost gel pixel at 1 px): the share of the light that is indirect, and the fitted term's
and the twin's filtered light's error against the raw light, % of the light (mean over LEDs and pixels; mean and
max over LEDs of each LED's mean). The raw light is taken at full pixel coverage (the pixel's direct light over the
point shading of the ideal twin's point LEDs gives its coverage): use an ideal scene (point LEDs, no defocus).

Usage: python benchmarks/bench_indirect_edge.py SCENE CAPTURE DIRECT [--spp 256] [--seed 6]

Prints only (benchmarks/RESULTS.md, s35-wideedge and s36-twinfilter, have the runs).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

BANDS_PX = (0, 1, 2, 3, 4, 6, 8, 16, np.inf)
"""Bin edges of the distance from the gel's outline, pixels (a bin holds lo < distance <= hi)."""


def split_render(scene_path: str, spp: int, seed: int) -> dict:
    """The undeformed dome rendered with one bounce: direct, raw bounce and filtered bounce light (L, H, W, 3)
    float32, render radiance; the ground truth's depth, normals and valid."""
    from nlipscalib.sim.dome import make_dome
    from nlipscalib.sim.render import surface
    from nlipscalib.sim.scene import load_scene

    scene = load_scene(scene_path).replace(render={"bounces": 1, "spp": spp, "denoise_indirect": True})
    kept = {}
    filtered = surface.denoise_indirect

    def keep_raw(indirect, *guides):  # the twin's filter, its input kept
        kept["raw"] = np.array(indirect)
        kept["filtered"] = filtered(indirect, *guides)
        return kept["filtered"]

    surface.denoise_indirect = keep_raw
    try:
        result = surface.render_surface(scene, make_dome(scene.dome), None, seed=seed)
    finally:
        surface.denoise_indirect = filtered
    gt = result.gt
    return {
        "direct": result.images - kept["filtered"],
        "raw": kept["raw"],
        "filtered": kept["filtered"],
        "depth": gt.depth,
        "normals": gt.normals,
        "valid": gt.valid,
        "albedo": scene.coating.albedo[1],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("capture", type=Path)
    ap.add_argument("direct", type=Path)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--seed", type=int, default=6)
    args = ap.parse_args()
    from scipy import ndimage

    from nlipscalib.core import load_press
    from nlipscalib.solver.indirect import direct_shading
    from nlipscalib.solver.interreflection import estimate_indirect

    r = split_render(args.scene, args.spp, args.seed)
    capture, direct = load_press(args.capture), load_press(args.direct)
    valid = r["valid"]
    green = lambda a: np.asarray(a)[..., 1]  # noqa: E731 -- white LEDs, a grey coat: one channel says it
    shading = green(direct_shading(capture.camera, capture.leds, r["depth"], r["normals"]))
    coverage = np.where(valid, green(r["direct"]).sum(0) / np.maximum((r["albedo"] / np.pi * shading).sum(0), 1e-30), 0)
    per_cover = 1.0 / np.maximum(coverage, 1e-3)
    distance = ndimage.distance_transform_edt(valid)
    inner = distance > 16
    units = green(direct.linear_led_images)[:, inner].sum() / green(r["direct"])[:, inner].sum()  # linear per radiance
    raw = green(r["raw"]) * per_cover
    light = (green(r["direct"]) + green(r["raw"])) * per_cover
    fitted = green(estimate_indirect(capture, capture.leds)) / units
    print(
        "band px | coverage | indirect share | fitted term - raw: mean, LEDs' |mean| mean / max | filtered - raw: same"
    )
    for lo, hi in zip(BANDS_PX[:-1], BANDS_PX[1:]):
        m = valid & (distance > lo) & (distance <= hi)
        cells = [f"{lo:g}-{hi:g}", f"{coverage[m].mean():.2f}", f"{raw[:, m].sum() / light[:, m].sum():.3f}"]
        # the fitted term is at full coverage (the solve's per-pixel albedo takes the pixel's coverage); the filtered
        # light is what the pixel's camera sample holds, against its own raw light and captured light
        captured = light[:, m] * coverage[m]
        for e in (
            (fitted[:, m] - raw[:, m]) / light[:, m],
            (green(r["filtered"])[:, m] - green(r["raw"])[:, m]) / captured,
        ):
            led = 100 * e.mean(axis=1)
            cells.append(f"{100 * e.mean():+.2f} %, {np.abs(led).mean():.2f} / {np.abs(led).max():.2f}")
        print(" | ".join(cells))


if __name__ == "__main__":
    main()
