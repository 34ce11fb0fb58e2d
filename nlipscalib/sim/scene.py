"""Scene configs of the digital twin: one sensor = dome + camera + LEDs + coating + noise + render.

The sensor design (dome, camera, LEDs) is defined in :mod:`nlipscalib.core.sensor` and shared with
device/; this module adds what only the twin needs (coating, noise model, renderer settings).

Frames (docs/conventions.md): the **dome frame** has its origin at the centre of the dome's base
and +z along the dome's axis toward the apex; millimetres. The camera sits on the axis at
``camera.position`` looking along +z with its axes parallel to the dome's (OpenCV camera:
x right, y down, z forward), so ``p_camera = p_dome - camera.position``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from ..config import check_count, check_range, from_mapping, read_config_file, to_mapping
from ..core.camera import Camera
from ..core.capture import SensorResponse
from ..core.leds import Led
from ..core.sensor import CameraConfig, DomeConfig, LedConfig, SensorDesign
from ..errors import ConfigError
from .render.variant import VARIANTS

SCENES_DIR = Path(__file__).resolve().parents[1] / "scenes"
"""The shipped scenes (nlipscalib/scenes links to the repository's scenes/; installs carry a copy)."""
DEFAULT_SCENE = SCENES_DIR / "nlipstac.toml"


@dataclasses.dataclass(frozen=True)
class CoatingConfig:
    """The Lambertian reflective coating on the gel."""

    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    """Diffuse reflectance per channel (0..1)."""
    variation: float = 0.0
    """Relative amplitude of smooth spatial albedo variation (0 = uniform)."""
    variation_scale: float = 4.0
    """Spatial scale of the variation, mm."""

    def __post_init__(self):
        for i, a in enumerate(self.albedo):
            check_range(f"albedo[{i}]", a, 0.0, 1.0)
        check_range("variation", self.variation, 0.0, 1.0)
        check_range("variation_scale", self.variation_scale, 0.0, open_lo=True)


@dataclasses.dataclass(frozen=True)
class NoiseConfig:
    """Image sensor model applied to the rendered radiance."""

    enabled: bool = True
    """False gives ideal, noise-free images (still quantised)."""
    full_well: float = 10000.0
    """Electrons at full scale: sets the shot noise."""
    read_noise: float = 2.0
    """Read noise, standard deviation in DN of the sensor's bit depth."""
    bit_depth: int = 12
    """ADC bits (8, 10, 12 or 16)."""
    black_level: float = 64.0
    """Black level in DN of the sensor's bit depth."""
    exposure: float = 1.0
    """Scale from rendered radiance to full scale (1.0 = the scene's calibrated exposure)."""

    def __post_init__(self):
        check_count("bit_depth", self.bit_depth, minimum=1)
        check_range("bit_depth", self.bit_depth, 8, 16)
        check_range("full_well", self.full_well, 0.0, open_lo=True)
        check_range("read_noise", self.read_noise, 0.0)
        check_range("black_level", self.black_level, 0.0, (1 << self.bit_depth) - 2)
        check_range("exposure", self.exposure, 0.0, open_lo=True)

    def response(self) -> SensorResponse:
        shift = 16 - self.bit_depth
        white = float(((1 << self.bit_depth) - 1) << shift)
        return SensorResponse(bit_depth=self.bit_depth, black_level=self.black_level * (1 << shift), white_level=white)


@dataclasses.dataclass(frozen=True)
class RenderConfig:
    """Mitsuba settings."""

    spp: int = 4
    """Samples per pixel."""
    bounces: int = 0
    """Interreflection bounces inside the dome (0 = direct light only)."""
    variant: str = "auto"
    """Mitsuba variant: auto, llvm_ad_rgb, scalar_rgb or cuda_ad_rgb."""
    threads: int = 0
    """Render threads (0 = all cores)."""
    seed: int = 0
    """Seed of the sampler and the noise: same seed, same images."""

    def __post_init__(self):
        check_count("spp", self.spp, minimum=1)
        check_count("bounces", self.bounces, minimum=0)
        check_count("threads", self.threads, minimum=0)
        check_count("seed", self.seed, minimum=0)
        if self.variant not in VARIANTS:
            raise ConfigError(f"variant must be one of {list(VARIANTS)}, got {self.variant!r}")


@dataclasses.dataclass(frozen=True)
class SceneConfig:
    """One sensor of the digital twin."""

    name: str = "nlipstac"
    """Scene name, stored with every capture."""
    dome: DomeConfig = DomeConfig()
    camera: CameraConfig = CameraConfig()
    leds: LedConfig = LedConfig()
    coating: CoatingConfig = CoatingConfig()
    noise: NoiseConfig = NoiseConfig()
    render: RenderConfig = RenderConfig()

    @property
    def design(self) -> SensorDesign:
        """The sensor's design (dome, camera, LEDs): what device/ and solver/ may know of it too."""
        return SensorDesign(dome=self.dome, camera=self.camera, leds=self.leds)

    def camera_model(self) -> Camera:
        return self.design.camera_model()

    def led_models(self) -> tuple[Led, ...]:
        return self.design.led_models()

    def to_dict(self) -> dict:
        return to_mapping(self)

    def replace(self, **sections) -> SceneConfig:
        """Copy with some sections' fields changed: ``scene.replace(render={"spp": 16})``."""
        data = self.to_dict()
        for section, changes in sections.items():
            if section not in data:
                raise ConfigError(f"scene has no section '{section}'")
            data[section] = data[section] | changes if isinstance(changes, dict) else changes
        return from_mapping(SceneConfig, data, "scene")


def load_scene(path: str | Path | None = None) -> SceneConfig:
    """Load a scene file (TOML/YAML), or the built-in default NLiPsTac scene when ``path`` is None.

    A bare name such as ``"fingertip"`` is looked up in the shipped ``scenes/`` folder.
    """
    if path is None:
        path = DEFAULT_SCENE
    path = Path(path)
    if not path.exists() and not path.suffix and (SCENES_DIR / f"{path}.toml").exists():
        path = SCENES_DIR / f"{path}.toml"
    data = read_config_file(path)
    return from_mapping(SceneConfig, data, str(path))
