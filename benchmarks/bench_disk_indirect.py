"""Why ``--led-model disks`` loses on one-bounce presses: the disk solve with the indirect term of the same disks.

An experiment, not a product path (s33-disklose, benchmarks/RESULTS.md): ``solve_press`` with an LED file's
disks, where the interreflection term (the reference surface's direct shading that the term is fitted on, the
off-view dome's light, the outer loop's solved-surface light) is computed from the same disks instead of the
file's point LEDs. The point shading functions that ``solver/indirect.py`` and ``solver/contact.py`` import are
swapped for :func:`nlipscalib.core.leds.disk_shading` of the file's emitters wherever they are called with the
file's point LEDs (monkeypatched; the product code is unchanged). Scores (AAE deg / depth RMSE mm) of the whole
gel, the truth's contact, and rings of image radius (in 320-wide pixels, off the contact).

Usage::

    python benchmarks/bench_disk_indirect.py PRESS LEDS.json MODE [--reference REF] [--out RESULT.npz]

MODE: ``points`` (the file's points), ``disks`` (the file's disks, the term of its points: the product),
``disks-consistent`` (the term of the disks too), or one part of the term of the disks: ``disks-fit-shading``
(the reference surface's shading the term is fitted on and the contact map reads), ``disks-solved-light`` (the
outer loop's solved-surface falloff), ``disks-off-view`` (the off-view dome's light). Without ``--reference``
the press itself is the undeformed capture (as ``nlips solve PRESS``). Give each MODE its own ``NLIPS_CACHE_DIR``:
the cached interreflection fit and reference shading are keyed by the point LEDs, not by what shaded them.

Since s33-diskterm the product does this itself: a disk solve's term is shaded with its disks
(``solver.indirect.term_shading``), so ``disks`` here is what ``disks-consistent`` measured before (the patches
below then find no point-LED shading of the term to swap), and the script reproduces the old numbers only on the
revision before it (``0c950d6f``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import nlipscalib.core.leds as core_leds
import nlipscalib.solver.contact as contact
import nlipscalib.solver.indirect as indirect
from nlipscalib.core.leds import Led, disk_shading
from nlipscalib.solver.press import solve_press

MODES = ("points", "disks", "disks-consistent", "disks-fit-shading", "disks-solved-light", "disks-off-view")
OFF_VIEW_CALLERS = ("_off_view_light", "_gather_at")
FIT_SHADING_CALLER = "rows"  # indirect._shading_on_threads' per-block closure: the reference surface's shading
RINGS = ((0, 40), (40, 70), (70, 100), (100, 120), (120, 400))


def _patch(points: tuple[Led, ...], emitters: tuple[Led, ...], radius: float, mode: str) -> dict:
    """Swap the point shading of ``points`` for the disks' in the interreflection term's callers; call counts."""
    keys = [tuple(p.position) for p in points]
    unit = tuple(Led.from_dict({**e.to_dict(), "intensity": [1.0, 1.0, 1.0]}) for e in emitters)  # falloff: no Psi
    calls: dict = {}
    point_shading, point_falloff = core_leds.led_shading, core_leds.led_falloff

    def which(leds):
        try:
            return [keys.index(tuple(led.position)) for led in leds]
        except ValueError:
            return None

    def wanted(caller: str) -> bool:
        if mode == "disks-off-view":
            return caller in OFF_VIEW_CALLERS
        if mode == "disks-fit-shading":
            return caller == FIT_SHADING_CALLER
        return mode == "disks-consistent"

    def shading(pts, nrm, leds, out=None):
        idx, caller = which(tuple(leds)), sys._getframe(1).f_code.co_name
        if idx is None or not wanted(caller):
            return point_shading(pts, nrm, leds, out=out)
        calls[caller] = calls.get(caller, 0) + 1
        s = disk_shading(pts, nrm, [emitters[i] for i in idx], radius)
        if out is None:
            return s
        out[...] = s
        return out

    def falloff(pts, nrm, leds):
        idx = which(tuple(leds))
        if idx is None or mode not in ("disks-consistent", "disks-solved-light"):
            return point_falloff(pts, nrm, leds)
        calls["falloff"] = calls.get("falloff", 0) + 1
        return disk_shading(pts, nrm, [unit[i] for i in idx], radius)[..., 0]

    indirect.led_shading, indirect.led_falloff, contact.led_shading = shading, falloff, shading
    return calls


def _scores(result, truth: dict) -> dict:
    """AAE deg / depth RMSE mm / mean depth error mm of the whole gel, the contact, and rings off it."""
    m = truth["valid"] & result.reconstructed
    ang = np.degrees(np.arccos(np.clip((result.normals * truth["normals"]).sum(-1), -1, 1)))
    dz = result.depth - truth["depth"]
    h, w = m.shape
    yy, xx = np.mgrid[:h, :w]
    radius = np.hypot(xx - (w - 1) / 2, yy - (h - 1) / 2) * 320 / w

    def of(sel):
        return [
            round(float(ang[sel].mean()), 3),
            round(float(np.sqrt((dz[sel] ** 2).mean())), 4),
            round(float(dz[sel].mean()), 4),
            int(sel.sum()),
        ]

    out = {"whole": of(m), "contact": of(m & truth["contact"])}
    for lo, hi in RINGS:
        out[f"ring{lo}-{hi}"] = of(m & ~truth["contact"] & (radius >= lo) & (radius < hi))
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("press")
    p.add_argument("leds")
    p.add_argument("mode", choices=MODES)
    p.add_argument("--reference", default=None)
    p.add_argument("--out", default=None)
    args = p.parse_args()
    d = json.loads(Path(args.leds).read_text(encoding="utf-8"))
    points = tuple(Led.from_dict(x) for x in d["leds"])
    emitters = tuple(Led.from_dict(x) for x in d["emitters"]["leds"])
    radius = float(d["emitters"]["radius_mm"])
    calls = _patch(points, emitters, radius, args.mode) if args.mode not in ("points", "disks") else {}
    kw: dict = {"leds": points}
    if args.reference is not None:
        kw["indirect"] = args.reference
    if args.mode != "points":
        kw.update(led_radius=radius, emitters=emitters)
    res = solve_press(args.press, **kw)
    if args.out:
        np.savez(args.out, normals=res.normals, depth=res.depth, reconstructed=res.reconstructed)
    truth = dict(np.load(Path(args.press) / "gt.npz"))
    line = {"press": args.press, "mode": args.mode, "disk_calls": calls, **_scores(res, truth)}
    line["coating_reflectance"] = res.report["interreflection"]["coating_reflectance"]
    print(json.dumps(line))


if __name__ == "__main__":
    main()
