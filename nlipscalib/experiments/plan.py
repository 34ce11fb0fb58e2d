"""From an experiment's list of wanted evaluations to the fewest tasks: one render per distinct press.

An experiment asks for evaluations = (scene, press, labels, solve). Evaluations of the same press on
the same scene share one render (an LED-error sweep solves one press many ways); every scene gets one
reference task, every (scene, LED error) that a calibrated solve needs one calibration task.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..core.config import check_count, to_mapping
from ..core.errors import ConfigError
from ..sim.indent import PressConfig, check_polar
from ..sim.indenters import IndenterConfig
from .tasks import SolveSpec, Task, calibration_id, digest, scene_key

REFERENCE_RENDER = "reference_render"
"""Key of an experiment's scene mapping (not a scene section): render overrides of its undeformed reference."""


@dataclasses.dataclass(frozen=True)
class TwinConfig:
    """The digital twin an experiment renders with (overrides of a shipped or given scene)."""

    scene: str = "nlipstac"
    """Scene file or shipped scene name."""
    width: int = 320
    """Image width, pixels (the camera's field of view is kept)."""
    height: int = 240
    """Image height, pixels."""
    spp: int = 16
    """Samples per pixel."""
    bounces: int = 1
    """Interreflection bounces (0 = direct light only)."""
    noise: bool = True
    """Sensor noise on."""
    seed: int = 0
    """Render and noise seed of the scene (each press mixes in its own description)."""
    reference_spp: int = 0
    """Samples per pixel of the undeformed reference render, when more than ``spp`` (0: ``spp``). LED
    self-calibration and the reference's interreflection fit read that one image: with interreflection at few spp
    it carries Monte Carlo noise of the bounce light that the LED model cannot explain (96x72, one bounce: the
    calibration's residual 1.40x the images' noise at 8 spp, 1.11-1.12x at 32, 1.02 at 64), and one render per
    scene costs little."""

    def scene_dict(self, scene: str | None = None, **sections) -> dict:
        """Full scene mapping with this twin's settings and extra section overrides.

        With ``reference_spp`` above the scene's spp the mapping carries :data:`REFERENCE_RENDER` (the
        reference's render overrides, which ``adapters.render`` applies to the undeformed dome only), so the
        scene's reference, calibration and press tasks are told apart from those of a plain scene.
        """
        from ..sim.scene import load_scene

        cfg = load_scene(scene or self.scene)
        base = {
            "camera": {"width": self.width, "height": self.height},
            "render": {"spp": self.spp, "bounces": self.bounces, "seed": self.seed, "threads": 0},
            "noise": {"enabled": self.noise},
        }
        for name, changes in sections.items():
            base[name] = base.get(name, {}) | changes
        out = cfg.replace(**base).to_dict()
        if self.reference_spp > out["render"]["spp"]:
            out[REFERENCE_RENDER] = {"spp": self.reference_spp}
        return out


@dataclasses.dataclass(frozen=True)
class PressGrid:
    """Presses: every combination of indenters, locations and depths."""

    indenters: tuple[IndenterConfig, ...] = (IndenterConfig(kind="sphere", size=6.0),)
    """Indenters."""
    polar_deg: tuple[float, ...] = (15.0,)
    """Polar angles of the press locations, degrees."""
    azimuth_deg: tuple[float, ...] = (30.0,)
    """Azimuths of the press locations, degrees."""
    depth: tuple[float, ...] = (1.0,)
    """Indentation depths, mm."""

    def presses(
        self, indenters: tuple[IndenterConfig, ...] | None = None, depth: tuple[float, ...] | None = None
    ) -> list[dict]:
        out = []
        for ind in indenters or self.indenters:
            for polar in self.polar_deg:
                check_polar("presses.polar_deg", polar)  # named by the config's section, not PressConfig's field
                for az in self.azimuth_deg:
                    for d in depth or self.depth:
                        p = PressConfig(indenter=ind, polar_deg=polar, azimuth_deg=az, depth=d)
                        out.append(to_mapping(p))
        return out


@dataclasses.dataclass(frozen=True)
class PressSet:
    """Presses at seeded random places: ``count`` presses, the indenters taking turns (round robin).

    Places are uniform over the dome's cap up to ``polar_max_deg`` (uniform in cos(polar)), the spin
    and depth uniform; values are rounded (0.1 degree, 0.01 mm) so press names stay readable. Two sets
    with different seeds press the same indenters at other places (a test set of "seen indenters at
    unseen places"). The first k presses of a set are balanced over its indenters.
    """

    indenters: tuple[IndenterConfig, ...] = (IndenterConfig(kind="sphere", size=6.0),)
    """Indenters, taking turns."""
    count: int = 3
    """Number of presses."""
    polar_max_deg: float = 25.0
    """Largest polar angle of a press location, degrees."""
    depth_mm: tuple[float, float] = (0.8, 1.6)
    """Range of indentation depths, mm."""
    seed: int = 0
    """Seed of the places, spins and depths."""

    def __post_init__(self):
        check_count("count", self.count)
        # named by this field: each press's PressConfig would refuse its own polar_deg, a field the user never wrote
        check_polar("polar_max_deg", self.polar_max_deg)
        if self.count and not self.indenters:
            raise ConfigError(f"indenters: {self.count} presses need at least one indenter, got none")

    def presses(self) -> list[dict]:
        rng = np.random.default_rng(np.random.SeedSequence([int(self.seed), 4242]))
        cos_lo = np.cos(np.radians(self.polar_max_deg))
        out = []
        for i in range(int(self.count)):
            polar = np.degrees(np.arccos(rng.uniform(cos_lo, 1.0)))
            azimuth, spin = rng.uniform(0.0, 360.0, size=2)
            depth = rng.uniform(*self.depth_mm)
            p = PressConfig(
                indenter=self.indenters[i % len(self.indenters)],
                polar_deg=round(float(polar), 1),
                azimuth_deg=round(float(azimuth), 1),
                spin_deg=round(float(spin), 1),
                depth=round(float(depth), 2),
            )
            out.append(to_mapping(p))
        return out


def press_name(press: dict) -> str:
    ind = press["indenter"]
    return f"{ind['kind']}-p{press['polar_deg']:g}-a{press['azimuth_deg']:g}-d{press['depth']:g}"


def solve_dict(**fields) -> dict:
    """SolveSpec as a mapping; ``options`` may be given as a dict."""
    opts = fields.pop("options", {}) or {}
    return SolveSpec(options=tuple(sorted(dict(opts).items())), **fields).to_dict()


def _check_press(scene: dict, press: dict) -> None:
    """ConfigError now, while planning, for a press its render would refuse after the reference was rendered
    (a place off the dome, a depth beyond the gel): the caller names the config file."""
    check_polar("presses.polar_deg", press["polar_deg"])
    thickness = scene["dome"]["thickness"]
    if press["depth"] > thickness:
        raise ConfigError(f"presses.depth: {press['depth']} mm exceeds the gel thickness {thickness} mm")


def build_tasks(evaluations: list[tuple[dict, dict, dict, dict]], samples: dict | None = None) -> list[Task]:
    """Tasks for (scene, press, labels, solve) evaluations, in a fixed order.

    ``samples`` (a learn.dataset.SamplingConfig mapping): every press task also writes the NLiPsNet
    calibration samples of its first solve (the NLiPs labels).

    Returns reference tasks, then calibration tasks, then press tasks (ids are readable and unique).
    """
    presses: dict[str, dict] = {}
    refs: dict[str, Task] = {}
    cals: dict[str, Task] = {}
    for scene, press, labels, solve in evaluations:
        skey = scene_key(scene)
        refs.setdefault(skey, Task(kind="reference", id=f"ref-{skey}", scene=scene))
        if solve["leds"] == "calibrated":
            err = {
                "position_mm": solve["position_error_mm"],
                "direction_deg": solve["direction_error_deg"],
                "seed": solve["error_seed"],
            }
            cid = calibration_id(scene, err)
            cals.setdefault(cid, Task(kind="calibration", id=cid, scene=scene, led_error=err))
        pid = f"{press_name(press)}-{skey}-{digest(press, 6)}"
        if pid not in presses:
            _check_press(scene, press)
        entry = presses.setdefault(pid, {"scene": scene, "press": press, "evaluations": []})
        entry["evaluations"].append({"labels": labels, "solve": solve})
    press_tasks = [
        Task(
            kind="press",
            id=pid,
            scene=e["scene"],
            press=e["press"],
            evaluations=tuple(e["evaluations"]),
            samples=samples,
        )
        for pid, e in presses.items()
    ]
    return list(refs.values()) + list(cals.values()) + press_tasks
