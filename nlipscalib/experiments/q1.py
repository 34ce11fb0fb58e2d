"""Q1, calibration fidelity: sphere and cube presses solved with the true and the self-calibrated LEDs."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..report import experiments as fig
from .common import CUBE, FULL_TWIN, MAPS_NEED, MEDIUM_TWIN, QUICK_TWIN, SPHERE, draw_error_maps, series_by
from .framework import Experiment, Table, WorkFigure
from .plan import PressGrid, TwinConfig, solve_dict
from .summary import aggregate

ERROR_MAPS = WorkFigure(
    "q1_error_maps.png", "True normals, NLiPs normals and angular error (first press of each kind)", MAPS_NEED
)


@dataclasses.dataclass(frozen=True)
class Q1Config:
    """Q1: NLiPs accuracy against the twin's true normals."""

    twin: TwinConfig = TwinConfig(**FULL_TWIN)
    """The twin (default NLiPsTac sensor with noise and one interreflection bounce)."""
    presses: PressGrid = PressGrid(
        indenters=(SPHERE, CUBE),
        polar_deg=(5.0, 15.0, 25.0),
        azimuth_deg=(0.0, 90.0, 180.0, 270.0),
        depth=(0.5, 1.0, 1.5),
    )
    """Presses of each indenter."""
    leds: tuple[str, ...] = ("true", "calibrated")
    """LEDs given to the solver: true (the twin's) and calibrated (self-calibrated on the undeformed dome)."""
    interreflection: str = "dent"
    """Interreflection correction of the solver: off, reference or dent."""
    roi: str = "truth"
    """Solved region: truth (true contact box), auto or full."""


class Q1(Experiment):
    name = "q1"
    title = "Q1: calibration fidelity (sphere and cube indenters)"
    description = (
        "NLiPs normals and depth of sphere and cube presses on the default NLiPsTac twin, scored against the "
        "twin's true normals, once with the true LEDs and once with LEDs self-calibrated from a capture of the "
        "undeformed dome (design LEDs as the starting point). The paper measured its real sensor against a "
        "reference scan: AAE 7.04°, MabsE 0.0588."
    )
    config_cls = Q1Config
    sizes = {
        "quick": Q1Config(twin=TwinConfig(**QUICK_TWIN), presses=PressGrid(indenters=(SPHERE, CUBE))),
        "medium": Q1Config(
            twin=TwinConfig(**MEDIUM_TWIN),
            presses=PressGrid(indenters=(SPHERE, CUBE), polar_deg=(10.0, 20.0), azimuth_deg=(30.0, 210.0)),
        ),
        "full": Q1Config(),
    }
    paper = {"source": "Quéau-style NLiPs on the real NLiPsTac sensor (paper, Q1)", "aae_deg": 7.04, "mabse": 0.0588}
    check_table = "q1"
    work_figures = (ERROR_MAPS,)

    def evaluations(self, cfg: Q1Config) -> list[tuple[dict, dict, dict, dict]]:
        scene = cfg.twin.scene_dict()
        return [
            (
                scene,
                press,
                {"indenter": press["indenter"]["kind"], "leds": leds},
                solve_dict(leds=leds, interreflection=cfg.interreflection, roi=cfg.roi),
            )
            for press in cfg.presses.presses()
            for leds in cfg.leds
        ]

    def tables(self, cfg: Q1Config, rows: list[dict], learned: dict | None = None) -> list[Table]:
        main = aggregate(rows, ("indenter", "leds"))
        for r in main:
            r["paper_aae_deg"], r["paper_mabse"] = self.paper["aae_deg"], self.paper["mabse"]
        paper_cols = {"paper_aae_deg": "paper AAE (°, real sensor)", "paper_mabse": "paper MabsE"}
        return [Table("q1", "NLiPs on the twin vs the paper's real sensor", ("indenter", "leds"), main, paper_cols)]

    def figures(
        self, cfg: Q1Config, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        figs = [
            ("AAE per indenter and LED source", "q1_aae.png"),
            ("MabsE per indenter and LED source", "q1_mabse.png"),
        ]
        cats, aae = series_by(rows, "indenter", "leds", "aae_deg")
        paper = {"paper, real sensor": 7.04}
        fig.grouped_bars(cats, aae, "AAE in the contact (°)", folder / figs[0][1], paper, title=figs[0][0])
        cats, mab = series_by(rows, "indenter", "leds", "mabse")
        paper = {"paper, real sensor": 0.0588}
        fig.grouped_bars(cats, mab, fig.MABSE_LABEL, folder / figs[1][1], paper, title=figs[1][0])
        return figs

    def draw_work_figures(
        self, cfg: Q1Config, rows: list[dict], out: Path, folder: Path, learned: dict | None = None
    ) -> list[WorkFigure]:
        return draw_error_maps(rows, out, ("indenter", "leds"), ERROR_MAPS, folder)
