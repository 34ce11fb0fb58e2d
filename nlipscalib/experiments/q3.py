"""Q3, dome shapes: every shipped sensor (scenes/*.toml) with sphere, cube and screw presses."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..report import experiments as fig
from ..sim.scene import SCENES_DIR
from .common import CUBE, FULL_TWIN, MAPS_NEED, MEDIUM_TWIN, QUICK_TWIN, SCREW, SPHERE, draw_error_maps, series_by
from .framework import Experiment, Table, WorkFigure
from .plan import PressGrid, TwinConfig, solve_dict
from .summary import aggregate

PAPER_BOUND_DEG = 10.0
"""The paper: AAE below 10° on each of its three dome shapes."""
SCREW_MAPS = WorkFigure(
    "q3_screw_maps.png", "A screw pressed into each dome shape: true normals, NLiPs, angular error", MAPS_NEED
)


def shipped_shapes() -> tuple[str, ...]:
    """One shipped sensor scene (scenes/*.toml) per dome shape, the default first.

    Variants of a shape (``nlipstac_realistic``: the default dome with the twin's non-ideal effects)
    are not another shape; the first scene of each shape in that order stands for it.
    """
    from ..sim.scene import load_scene

    names = sorted((p.stem for p in SCENES_DIR.glob("*.toml")), key=lambda n: (n != "nlipstac", n))
    shapes: dict[str, str] = {}
    for name in names:
        shapes.setdefault(load_scene(name).dome.shape, name)
    return tuple(shapes.values())


@dataclasses.dataclass(frozen=True)
class Q3Config:
    """Q3: NLiPs on every dome shape."""

    twin: TwinConfig = TwinConfig(**FULL_TWIN)
    """Render settings (its ``scene`` is replaced by each shape)."""
    shapes: tuple[str, ...] = shipped_shapes()
    """Scene names or files, one per dome shape."""
    presses: PressGrid = PressGrid(
        indenters=(SPHERE, CUBE, SCREW), polar_deg=(5.0, 15.0, 25.0), azimuth_deg=(0.0, 120.0, 240.0)
    )
    """Presses on every shape (a screw is always among them)."""
    leds: tuple[str, ...] = ("true", "calibrated")
    """LEDs given to the solver (each shape is self-calibrated on its own undeformed capture)."""
    interreflection: str = "dent"
    """Interreflection correction of the solver."""
    roi: str = "truth"
    """Solved region: truth, auto or full."""


class Q3(Experiment):
    name = "q3"
    title = "Q3: dome shapes"
    description = (
        "Every shipped sensor shape (hemisphere, fingertip, oblate, capsule, flat pad), pressed with a sphere, a "
        "cube and a screw (side on), solved with the true LEDs and with LEDs self-calibrated on the shape's own "
        "undeformed capture (quick size: the screw and the true LEDs only). "
        "The paper reports AAE below 10° on its three dome shapes."
    )
    config_cls = Q3Config
    sizes = {
        "quick": Q3Config(twin=TwinConfig(**QUICK_TWIN), presses=PressGrid(indenters=(SCREW,)), leds=("true",)),
        "medium": Q3Config(
            twin=TwinConfig(**MEDIUM_TWIN),
            presses=PressGrid(indenters=(SPHERE, SCREW), polar_deg=(15.0,), azimuth_deg=(30.0,)),
        ),
        "full": Q3Config(),
    }
    paper = {"aae_deg_below": PAPER_BOUND_DEG, "shapes": 3, "source": "paper, three real dome shapes"}
    check_table = "q3"
    work_figures = (SCREW_MAPS,)

    def evaluations(self, cfg: Q3Config) -> list[tuple[dict, dict, dict, dict]]:
        out = []
        for shape in cfg.shapes:
            scene = cfg.twin.scene_dict(scene=shape)
            for p in cfg.presses.presses():
                for leds in cfg.leds:
                    labels = {"shape": scene["name"], "indenter": p["indenter"]["kind"], "leds": leds}
                    out.append(
                        (scene, p, labels, solve_dict(leds=leds, interreflection=cfg.interreflection, roi=cfg.roi))
                    )
        return out

    def tables(self, cfg: Q3Config, rows: list[dict], learned: dict | None = None) -> list[Table]:
        by_shape = aggregate(rows, ("shape", "leds"))
        for r in by_shape:
            r["paper_below"] = f"< {PAPER_BOUND_DEG:g}"
        return [
            Table(
                "q3",
                "AAE per dome shape (all indenters)",
                ("shape", "leds"),
                by_shape,
                {"paper_below": "paper AAE (°)"},
            ),
            Table(
                "q3_by_indenter",
                "Per dome shape and indenter",
                ("shape", "indenter", "leds"),
                aggregate(rows, ("shape", "indenter", "leds")),
            ),
        ]

    def figures(
        self, cfg: Q3Config, rows: list[dict], tables: list[Table], folder: Path, learned: dict | None = None
    ) -> list[tuple[str, str]]:
        true_rows = [r for r in rows if r["leds"] == cfg.leds[0]]
        cats, aae = series_by(true_rows, "shape", "indenter", "aae_deg")
        caption, name = "AAE per dome shape and indenter", "q3_aae.png"
        fig.grouped_bars(
            cats,
            aae,
            f"AAE in the contact (°), {cfg.leds[0]} LEDs",
            folder / name,
            {"paper bound": PAPER_BOUND_DEG},
            title=caption,
        )
        return [(caption, name)]

    def draw_work_figures(
        self, cfg: Q3Config, rows: list[dict], out: Path, folder: Path, learned: dict | None = None
    ) -> list[WorkFigure]:
        screws = [r for r in rows if r["leds"] == cfg.leds[0] and r["indenter"] == "screw"]
        return draw_error_maps(screws, out, ("shape", "indenter"), SCREW_MAPS, folder, limit=len(cfg.shapes))
