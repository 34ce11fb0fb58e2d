"""LED ablation: the same presses on sensors with 3 to 24 LEDs (scene ``leds.count``)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..report import experiments as fig
from .common import CUBE, FULL_TWIN, MEDIUM_TWIN, QUICK_TWIN, SPHERE
from .framework import Experiment, Table
from .plan import PressGrid, TwinConfig, solve_dict
from .summary import aggregate

PAPER_AAE = {3: 9.86, 12: 7.28, 24: 7.46}
"""The paper's AAE (degrees, real sensor) by number of LEDs."""


@dataclasses.dataclass(frozen=True)
class AblationConfig:
    """LED ablation: AAE and MabsE against the number of LEDs in the ring."""

    twin: TwinConfig = TwinConfig(**FULL_TWIN)
    """The twin; its LED ring gets ``counts`` LEDs in turn (same ring radius, height and tilt)."""
    counts: tuple[int, ...] = (3, 6, 9, 12, 15, 18, 21, 24)
    """LED counts."""
    presses: PressGrid = PressGrid(
        indenters=(SPHERE, CUBE), polar_deg=(5.0, 15.0, 25.0), azimuth_deg=(0.0, 90.0, 180.0, 270.0)
    )
    """Presses on every sensor."""
    interreflection: str = "dent"
    """Interreflection correction of the solver."""
    roi: str = "truth"
    """Solved region: truth, auto or full."""


class Ablation(Experiment):
    name = "ablation"
    title = "LED ablation: 3 to 24 LEDs"
    description = (
        "The same presses on twins whose LED ring has 3 to 24 LEDs (true LEDs, interreflection-corrected "
        "NLiPs). The paper's real-sensor AAE: 9.86° with 3 LEDs, 7.28° with 12, 7.46° with 24."
    )
    config_cls = AblationConfig
    sizes = {
        "quick": AblationConfig(twin=TwinConfig(**QUICK_TWIN), counts=(3, 12, 24), presses=PressGrid()),
        "medium": AblationConfig(
            twin=TwinConfig(**MEDIUM_TWIN), presses=PressGrid(polar_deg=(10.0, 20.0), azimuth_deg=(30.0, 210.0))
        ),
        "full": AblationConfig(),
    }
    paper = {"aae_deg_by_leds": PAPER_AAE, "source": "paper, real NLiPsTac sensor, LED subsets"}
    check_table = "ablation"

    def evaluations(self, cfg: AblationConfig) -> list[tuple[dict, dict, dict, dict]]:
        out = []
        for n in cfg.counts:
            scene = cfg.twin.scene_dict(leds={"count": n})
            solve = solve_dict(leds="true", interreflection=cfg.interreflection, roi=cfg.roi)
            out += [(scene, p, {"leds": n, "indenter": p["indenter"]["kind"]}, solve) for p in cfg.presses.presses()]
        return out

    def tables(self, cfg: AblationConfig, rows: list[dict], learned: dict | None = None) -> list[Table]:
        main = aggregate(rows, ("leds",))
        for r in main:
            r["paper_aae_deg"] = PAPER_AAE.get(r["leds"])
        per = aggregate(rows, ("leds", "indenter"))
        return [
            Table(
                "ablation",
                "AAE and MabsE by number of LEDs (all presses)",
                ("leds",),
                main,
                {"paper_aae_deg": "paper AAE (°)"},
            ),
            Table("ablation_by_indenter", "By number of LEDs and indenter", ("leds", "indenter"), per),
        ]

    def figures(
        self, cfg: AblationConfig, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        main = tables[0].rows
        x = [r["leds"] for r in main]
        paper = {"paper (real sensor)": (list(PAPER_AAE), list(PAPER_AAE.values()))}
        figs = [
            ("AAE against the number of LEDs, with the paper's", "ablation_aae.png"),
            ("MabsE against the number of LEDs", "ablation_mabse.png"),
        ]
        fig.sweep(
            {"twin": (x, [r["aae_deg"] for r in main], [r["aae_deg_std"] for r in main])},
            "number of LEDs",
            "AAE in the contact (°)",
            folder / figs[0][1],
            paper,
            title=figs[0][0],
        )
        fig.sweep(
            {"twin": (x, [r["mabse"] for r in main], [r["mabse_std"] for r in main])},
            "number of LEDs",
            fig.MABSE_LABEL,
            folder / figs[1][1],
            title=figs[1][0],
        )
        return figs
