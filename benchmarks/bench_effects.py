"""What each non-ideal effect of the twin costs the solver: AAE on the sphere and cube presses.

Every row renders the same two presses (sphere 6 mm 1.5 mm deep, cube 5 mm 1.0 mm deep, polar 15 deg,
azimuth 30 deg) of the ideal NLiPsTac (``nlipstac_ideal.toml``) with one effect switched on at its
realistic strength (the values of ``scenes/nlipstac_realistic.toml``), direct light only (interreflection
has its own benchmark) and sensor noise on, and solves them with NLiPs on the ROI that ``roi="auto"``
picks on the ideal noise-free render (so every row is scored on the same pixels). Writes its section of
RESULTS.md. ``--defaults`` runs only the ideal scene and the default one (``nlipstac.toml``: extended
LEDs, defocus, black-level error) at several spp, into a section of its own: what the default costs.

    .venv/bin/python benchmarks/bench_effects.py [--width 320 --height 240] [--spp 4] [--gel-spp 64] [--defaults]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # this checkout's package, not an installed one
from common import write_section  # noqa: E402

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.metrics import evaluate  # noqa: E402
from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import solve_press  # noqa: E402

PRESSES = {
    "sphere": PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5),
    "cube": PressConfig(IndenterConfig(kind="cube", size=5.0), polar_deg=15, azimuth_deg=30, depth=1.0),
}
REALISTIC = load_scene("nlipstac_realistic")
IDEAL = load_scene("nlipstac_ideal")
EXTENDED = {"led_package": {"enabled": True, "shape": "disk", "size": REALISTIC.led_package.size}}
EFFECTS = {
    "none (NLiPs model + noise)": {},
    f"extended LEDs (disk {REALISTIC.led_package.size} mm)": EXTENDED,
    f"glossy coat (specular {REALISTIC.coating.specular}, roughness {REALISTIC.coating.roughness})": {
        "coating": {"specular": REALISTIC.coating.specular, "roughness": REALISTIC.coating.roughness}
    },
    "vignetting (polynomial, -30 % in the corners)": {
        "camera_effects": {
            "vignetting": "polynomial",
            "vignetting_coeffs": list(REALISTIC.camera_effects.vignetting_coeffs),
        }
    },
    f"response gamma {REALISTIC.camera_effects.response_gamma}": {
        "camera_effects": {"response_gamma": REALISTIC.camera_effects.response_gamma}
    },
    f"black level off by {REALISTIC.camera_effects.black_level_error:g} DN": {
        "camera_effects": {"black_level_error": REALISTIC.camera_effects.black_level_error}
    },
    f"defocus (disk PSF, {REALISTIC.camera_effects.defocus_px} px)": {
        "camera_effects": {"defocus_px": REALISTIC.camera_effects.defocus_px}
    },
    f"refracting gel (n {REALISTIC.gel_optics.gel_ior} / {REALISTIC.gel_optics.housing_ior}) + extended LEDs": EXTENDED
    | {"gel_optics": dataclasses.asdict(REALISTIC.gel_optics)},
    "all of the above (nlipstac_realistic)": "realistic",
}
DEFAULTS = {"ideal (nlipstac_ideal: NLiPs model + noise)": "ideal", "default (nlipstac)": "default"}
DEFAULTS_SPP = (4, 16)


def scene_for(effect, width: int, height: int, spp: int, gel_spp: int):
    size = {"camera": {"width": width, "height": height}}
    if effect == "realistic":
        scene = REALISTIC.replace(**size)
    elif effect == "default":
        scene = load_scene().replace(**size)
    elif effect == "ideal":
        scene = IDEAL.replace(**size)
    else:
        scene = IDEAL.replace(**size, **effect)
    return scene.replace(render={"spp": gel_spp if scene.gel_optics.enabled else spp, "bounces": 0})


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=240)
    ap.add_argument("--spp", type=int, default=4, help="samples per pixel without gel optics")
    ap.add_argument("--gel-spp", type=int, default=64, help="samples per pixel through the refracting gel")
    ap.add_argument("--no-write", action="store_true", help="print only, leave RESULTS.md alone")
    ap.add_argument("--defaults", action="store_true", help="only the ideal and the default scene, at 4 and 16 spp")
    args = ap.parse_args(argv)
    load_before = os.getloadavg()[0]
    root = Path(tempfile.mkdtemp(prefix="bench_effects_"))
    ideal = IDEAL.replace(
        camera={"width": args.width, "height": args.height}, noise={"enabled": False}, render={"spp": 4}
    )
    rois = {}
    for kind, press in PRESSES.items():
        p = load_press(render_press(ideal, press, root / f"ideal_{kind}", seed=2))
        rois[kind] = tuple(solve_press(p, roi="auto").report["roi"])
    rows = []
    cases = [(label, effect, args.spp) for label, effect in EFFECTS.items()]
    if args.defaults:
        cases = [(label, effect, spp) for spp in DEFAULTS_SPP for label, effect in DEFAULTS.items()]
    for label, effect, spp in cases:
        scene = scene_for(effect, args.width, args.height, spp, args.gel_spp)
        cells, seconds = [], 0.0
        for kind, press in PRESSES.items():
            t0 = time.perf_counter()
            p = load_press(render_press(scene, press, root / f"{len(rows)}_{kind}", seed=2))
            seconds += time.perf_counter() - t0
            e = evaluate(solve_press(p, roi=rois[kind]), p.ground_truth)
            cells += [f"{e['contact']['aae_deg']:.2f}", f"{e['all']['aae_deg']:.2f}"]
        rows.append(f"| {label} | {scene.render.spp} | {' | '.join(cells)} | {seconds:.0f} |")
        print(rows[-1], flush=True)
    which = "ideal and default" if args.defaults else "ideal"
    body = "\n".join(
        [
            f"{args.width}x{args.height}, {which} scene (12 LEDs), direct light (bounces 0), sensor noise on, "
            f"presses at polar 15 deg: sphere 6 mm 1.5 mm deep, cube 5 mm 1.0 mm deep; ROIs {rois} (auto on the "
            "ideal render). AAE in degrees, in the contact and over the ROI. "
            f"Load average before: {load_before:.2f}, after: {os.getloadavg()[0]:.2f} (2 cores shared with other "
            "jobs: render times are contended).",
            "",
            "| effect on | spp | sphere AAE contact | sphere AAE ROI | cube AAE contact | cube AAE ROI | "
            "render both presses (s) |",
            "|---|---|---|---|---|---|---|",
            *rows,
        ]
    )
    if not args.no_write:
        title = "Cost of the default scene's effects (bench_effects.py --defaults)" if args.defaults else None
        write_section(title or "Cost of the twin's non-ideal effects (bench_effects.py)", body)
    print(body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
