"""LED self-calibration of a sensor not built as designed: how far from the design can its LEDs sit?

Renders, per perturbation size, the undeformed dome of a copy of the default twin (scenes/nlipstac.toml) whose LEDs
are moved from the design by known amounts (each LED: its position by ``pos`` mm in a random 3-D direction, its axis
tilted by ``dir`` deg about a random axis, every LED's mu set to ``mu``), calibrates the LEDs from the **design's**
LEDs (as ``nlips calibrate-leds`` does on a real sensor, whose capture records the design) and reports the recovered
LEDs' errors against the rendered truth.

Usage: python benchmarks/bench_led_starts.py OUT [--levels 0,1,2,3,4] [--width 160 --height 120] [--led-diameter 3.6]
[--bounces 1]

With ``--led-diameter`` the calibration also fits the LEDs as disks of that diameter (``LedCalibration.emitters``,
what ``nlips calibrate-leds --led-diameter`` writes as 'emitters'); each row then scores them too ("disks"). With
``--bounces 1`` the captures show the dome's interreflection (a real sensor's; issue 6 point 2's setting), their
folders and files tagged ``_b1``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from nlipscalib.core.sensor import SCENES_DIR  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402

LEVELS = [  # (position mm, direction deg, mu of every LED)
    (0.0, 0.0, 1.0),
    (0.5, 5.0, 1.2),
    (1.0, 10.0, 1.4),
    (2.0, 15.0, 1.6),
    (3.0, 25.0, 2.0),
    (4.0, 35.0, 2.5),
    (6.0, 45.0, 3.0),
]


def perturbed_leds_toml(pos_mm: float, dir_deg: float, mu: float, seed: int = 0) -> str:
    """The ``[leds]`` table of the design's ring with every LED moved by ``pos_mm`` and tilted by ``dir_deg``."""
    scene = load_scene("nlipstac")
    rng = np.random.default_rng(seed)
    cam = np.asarray(scene.camera.position)
    positions, directions = [], []
    for led in scene.led_models():
        p = np.asarray(led.position) + cam  # dome frame
        d = np.asarray(led.direction)
        u = rng.normal(size=3)
        positions.append(p + pos_mm * u / np.linalg.norm(u))
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        t = np.radians(dir_deg)  # Rodrigues, axis perpendicular to d
        directions.append(d * np.cos(t) + np.cross(axis, d) * np.sin(t))
    rows = lambda a: "[" + ", ".join("[" + ", ".join(f"{v:.6f}" for v in r) + "]" for r in a) + "]"  # noqa: E731
    return f"[leds]\nmu = {mu}\npositions = {rows(positions)}\ndirections = {rows(directions)}\n"


def scene_file(out: Path, level: int, seed: int) -> Path:
    text = (SCENES_DIR / "nlipstac.toml").read_text(encoding="utf-8")
    head, rest = text.split("[leds]", 1)
    tail = rest[rest.index("\n[led_package]") + 1 :]  # the section, not a comment naming it
    path = out / f"scene_l{level}_s{seed}.toml"
    body = head.replace('name = "nlipstac"', f'name = "nlipstac_l{level}"')
    path.write_text(body + perturbed_leds_toml(*LEVELS[level], seed=seed) + "\n" + tail, encoding="utf-8")
    return path


def render(scene: Path, out: Path, args, extra: list[str]) -> None:
    cmd = [sys.executable, "-m", "nlipscalib", "--no-progress", "render", "--scene", str(scene), "--out", str(out)]
    cmd += ["--width", str(args.width), "--height", str(args.height), "--spp", str(args.spp)]
    cmd += ["--bounces", str(args.bounces)] + extra
    subprocess.run(cmd, check=True, capture_output=True)


def led_errors(fitted, truth) -> dict:
    pos = [np.linalg.norm(np.subtract(a.position, b.position)) for a, b in zip(fitted, truth)]
    ang = [np.degrees(np.arccos(np.clip(np.dot(a.direction, b.direction), -1, 1))) for a, b in zip(fitted, truth)]
    psi_t = np.array([b.intensity for b in truth]).mean(1)
    psi_t /= psi_t.mean()
    psi = np.array([a.intensity for a in fitted]).mean(1)
    return {
        "pos_mm": [float(np.median(pos)), float(np.max(pos))],
        "dir_deg": [float(np.median(ang)), float(np.max(ang))],
        "psi_pct": float(100 * np.max(np.abs(psi / psi_t - 1))),
        "mu_err": float(np.max(np.abs([a.mu - b.mu for a, b in zip(fitted, truth)]))),
    }


def nlips(*argv: str) -> str:
    cmd = [sys.executable, "-m", "nlipscalib", "--no-progress", *argv]
    return subprocess.run(cmd, check=True, capture_output=True, text=True).stdout


def press_aae(args, scene: Path, ref: Path, level: int, cal) -> dict:
    """Per press: NLiPs contact AAE, deg, with the true LEDs (the capture's) and with the calibrated ones."""
    from nlipscalib.core.ledfile import save_leds

    led_file = save_leds(args.out / f"leds_l{level}_s{args.seed}_cal.json", cal.leds)
    out = {}
    for kind in args.presses.split(","):
        folder = args.out / f"{kind}_l{level}_s{args.seed}{f'_b{args.bounces}' if args.bounces else ''}"
        if not folder.exists():
            render(scene, folder, args, ["--indenter", kind])
        aae = []
        for leds in ([], ["--leds", str(led_file)]):
            result = folder.with_name(folder.name + ("_cal" if leds else "_true"))
            nlips("solve", str(folder), "--reference", str(ref), "--out", str(result), "--overwrite", *leds)
            text = nlips("eval", str(folder), "--result", str(result), "--region", "contact")
            aae.append(float(text.strip().splitlines()[-1].split()[2]))
        out[kind] = aae
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--levels", default="0,1,2,3,4")
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--height", type=int, default=120)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--bounces", type=int, default=0, help="interreflection bounces of the renders (default 0)")
    ap.add_argument("--presses", default="", help="indenters to render and solve with both LED sets, e.g. sphere,cube")
    ap.add_argument("--seed", type=int, default=0, help="the perturbations' random directions")
    ap.add_argument(
        "--led-diameter", type=float, default=0.0, help="also fit the LEDs as disks of this diameter, mm (scored too)"
    )
    args = ap.parse_args()
    from nlipscalib.core.capture import as_press
    from nlipscalib.solver.calibrate import calibrate_leds

    args.out.mkdir(parents=True, exist_ok=True)
    design = load_scene("nlipstac").led_models()
    for level in map(int, args.levels.split(",")):
        scene = scene_file(args.out, level, args.seed)
        bounce_tag = f"_b{args.bounces}" if args.bounces else ""
        ref = args.out / f"ref_l{level}_s{args.seed}{bounce_tag}"
        if not ref.exists():
            render(scene, ref, args, ["--undeformed"])
        press = as_press(ref, "reference")
        t0 = time.perf_counter()
        cal = calibrate_leds(press, initial=design, allow_contact=True, led_radius=args.led_diameter / 2)
        seconds = time.perf_counter() - t0
        row = {"level": level, "perturbation": LEVELS[level], "seconds": round(seconds, 1)}
        row |= {"start": led_errors(design, press.leds), "fitted": led_errors(cal.leds, press.leds)}
        if cal.emitters:  # the disks: the physical LEDs, scored against the render's disk centres
            row |= {"disks": led_errors(cal.emitters, press.leds)}
        row |= {"quality": cal.quality.get("median_ratio"), "reliable": cal.quality.get("reliable")}
        row |= {"warnings": list(cal.warnings), "contact_pixels": list(cal.contact_pixels)}
        if args.presses:
            row |= {"contact_aae_deg": press_aae(args, scene, ref, level, cal)}
        print(json.dumps(row), flush=True)
        tag = bounce_tag + (f"_d{args.led_diameter:g}" if args.led_diameter else "")
        (args.out / f"leds_l{level}_s{args.seed}{tag}.json").write_text(json.dumps(row), encoding="utf-8")


if __name__ == "__main__":
    main()
