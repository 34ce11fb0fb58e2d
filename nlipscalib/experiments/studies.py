"""Studies the paper could not run: they need the true normals only a twin has.

- noise: sensor noise scaled by k (shot noise via full well / k^2, read noise x k; k = 0: noise off)
- interreflection: direct light only vs one bounce, the bounce uncorrected, corrected with the
  undeformed reference, and also for the dent's own bounce
- LED position / direction error: how precise must the CAD be, and how much does self-calibration recover
- press depth and coating albedo
The number of calibration presses (how many are enough?) trains NLiPsNet on Q2's presses: its own
experiment, ``nlips experiment presses``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..report import experiments as fig
from .common import FULL_TWIN, MEDIUM_TWIN, QUICK_TWIN, SPHERE
from .framework import Experiment, Table
from .plan import PressGrid, TwinConfig, solve_dict
from .summary import aggregate

INTERREFLECTION_CASES = (
    (0, "off", "no bounce, uncorrected"),
    (1, "off", "1 bounce, uncorrected"),
    (1, "reference", "1 bounce, reference-corrected"),
    (1, "dent", "1 bounce, reference + dent corrected"),
)
"""(render bounces, solver correction, label) of the interreflection study."""

XLABELS = {
    "noise": "noise scale k (0 = off)",
    "interreflection": "",
    "led_position": "LED position error (mm)",
    "led_direction": "LED axis error (°)",
    "depth": "press depth (mm)",
    "albedo": "coating albedo",
}


@dataclasses.dataclass(frozen=True)
class StudiesConfig:
    """Sweeps of one factor at a time around the default twin."""

    twin: TwinConfig = TwinConfig(**FULL_TWIN)
    """The default twin every sweep starts from."""
    presses: PressGrid = PressGrid(indenters=(SPHERE,), polar_deg=(5.0, 15.0, 25.0), azimuth_deg=(0.0, 90.0, 180.0))
    """Presses of every sweep point."""
    noise: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0)
    """Noise scales k."""
    interreflection: bool = True
    """Run the interreflection study."""
    led_position_mm: tuple[float, ...] = (0.0, 0.1, 0.25, 0.5, 1.0)
    """LED position errors, mm."""
    led_direction_deg: tuple[float, ...] = (0.0, 2.0, 5.0, 10.0)
    """LED axis errors, degrees."""
    depth: tuple[float, ...] = (0.25, 0.5, 1.0, 1.5, 2.0, 2.5)
    """Press depths, mm."""
    albedo: tuple[float, ...] = (0.5, 0.65, 0.8, 0.95)
    """Coating albedos (grey)."""
    correction: str = "dent"
    """Interreflection correction of the solver outside the interreflection study."""
    roi: str = "truth"
    """Solved region: truth, auto or full."""


class Studies(Experiment):
    name = "studies"
    title = "Studies only a twin can run: noise, interreflection, LED errors, depth, albedo"
    description = __doc__.split("\n\n", 1)[1].strip()
    config_cls = StudiesConfig
    sizes = {
        "quick": StudiesConfig(
            twin=TwinConfig(**QUICK_TWIN),
            presses=PressGrid(),
            noise=(0.0, 1.0),
            led_position_mm=(0.0, 0.5),
            led_direction_deg=(0.0, 5.0),
            depth=(0.5,),
            albedo=(0.5,),
        ),
        "medium": StudiesConfig(
            twin=TwinConfig(**MEDIUM_TWIN),
            presses=PressGrid(),
            noise=(0.0, 1.0, 2.0, 4.0),
            led_position_mm=(0.0, 0.25, 0.5, 1.0),
            depth=(0.5, 1.0, 1.5, 2.0),
            albedo=(0.5, 0.8, 0.95),
        ),
        "full": StudiesConfig(),
    }
    paper = {"note": "the paper has no ground-truth normals for these factors"}
    check_table = "noise"

    def evaluations(self, cfg: StudiesConfig) -> list[tuple[dict, dict, dict, dict]]:
        twin, presses = cfg.twin, cfg.presses.presses()
        base_solve = {"interreflection": cfg.correction, "roi": cfg.roi}
        out = []

        def add(
            study: str, value: float | str, scene: dict, solve: dict, plist: list[dict] = presses, **extra: str
        ) -> None:
            out.extend((scene, p, {"study": study, "value": value} | extra, solve) for p in plist)

        base = twin.scene_dict()
        for k in cfg.noise:
            noise = {"enabled": k > 0} | ({"full_well": 10000.0 / k**2, "read_noise": 2.0 * k} if k > 0 else {})
            add("noise", k, twin.scene_dict(noise=noise), solve_dict(leds="true", **base_solve))
        if cfg.interreflection:
            for bounces, corr, label in INTERREFLECTION_CASES:
                scene = twin.scene_dict(render={"bounces": bounces})
                add("interreflection", label, scene, solve_dict(leds="true", interreflection=corr, roi=cfg.roi))
        for err in cfg.led_position_mm:
            for leds in ("design", "calibrated"):
                add("led_position", err, base, solve_dict(leds=leds, position_error_mm=err, **base_solve), leds=leds)
        for err in cfg.led_direction_deg:
            for leds in ("design", "calibrated"):
                add("led_direction", err, base, solve_dict(leds=leds, direction_error_deg=err, **base_solve), leds=leds)
        for d in cfg.depth:
            add("depth", d, base, solve_dict(leds="true", **base_solve), plist=cfg.presses.presses(depth=(d,)))
        for a in cfg.albedo:
            add("albedo", a, twin.scene_dict(coating={"albedo": [a, a, a]}), solve_dict(leds="true", **base_solve))
        return out

    def tables(self, cfg: StudiesConfig, rows: list[dict], learned: dict | None = None) -> list[Table]:
        tables = []
        for study in XLABELS:
            mine = [r for r in rows if r["study"] == study]
            if not mine:
                continue
            by = ("value", "leds") if study.startswith("led_") else ("value",)
            caption = f"{study.replace('_', ' ')}: {XLABELS[study] or 'render and correction'}"
            order = self._order(cfg, study)
            rows_sorted = sorted(
                aggregate(mine, by), key=lambda r: (order.index(r["value"]), r.get("leds") != "design")
            )
            tables.append(Table(study, caption, by, rows_sorted))
        return tables

    @staticmethod
    def _order(cfg: StudiesConfig, study: str) -> list:
        """Sweep values in the order the config lists them."""
        if study == "interreflection":
            return [label for _, _, label in INTERREFLECTION_CASES]
        return list(
            getattr(cfg, {"led_position": "led_position_mm", "led_direction": "led_direction_deg"}.get(study, study))
        )

    def figures(
        self, cfg: StudiesConfig, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        figs = []
        for t in tables:
            if t.name.startswith("led_"):
                series = {}
                for leds in ("design", "calibrated"):
                    mine = [r for r in t.rows if r["leds"] == leds]
                    series[f"{leds} LEDs"] = (
                        [r["value"] for r in mine],
                        [r["aae_deg"] for r in mine],
                        [r["aae_deg_std"] for r in mine],
                    )
            else:
                series = {
                    "AAE": (
                        [r["value"] for r in t.rows],
                        [r["aae_deg"] for r in t.rows],
                        [r["aae_deg_std"] for r in t.rows],
                    )
                }
            name = f"study_{t.name}.png"
            fig.sweep(
                series,
                XLABELS[t.name] or "render / correction",
                "AAE in the contact (°)",
                folder / name,
                categorical=t.name == "interreflection",
                title=t.caption,
            )
            figs.append((t.caption, name))
        return figs
