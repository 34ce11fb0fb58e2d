"""Scene configs of the digital twin: one sensor = dome + camera + LEDs + coating + noise + render.

The sensor design (dome, camera, LEDs) is defined in :mod:`nlipscalib.core.sensor` and shared with
device/; this module adds what only the twin needs (coating, noise model, renderer settings).

Defaults are the paper's NLiPsTac as built: extended (WS2812B) LEDs, a fixed-focus lens's slight defocus
and a black-level error that the dark frame absorbs are on; the glossy lobe, vignetting, a response curve
and the refracting gel are off (docs/twin.md says why for each). :meth:`SceneConfig.ideal` turns every
departure from the NLiPs image model off, for checks that need the model exactly.

Frames (docs/conventions.md): the **dome frame** has its origin at the centre of the dome's base
and +z along the dome's axis toward the apex; millimetres. The camera sits on the axis at
``camera.position`` looking along +z with its axes parallel to the dome's (OpenCV camera:
x right, y down, z forward), so ``p_camera = p_dome - camera.position``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Literal

from ..core.camera import Camera
from ..core.config import (
    OMIT_AT_DEFAULT,
    check_count,
    check_range,
    check_size_pair,
    from_mapping,
    read_config_file,
    to_mapping,
)
from ..core.errors import PATH, ConfigError, check_kind
from ..core.leds import Led
from ..core.sensor import MAX_EMITTER_DIAMETER_MM, SCENES_DIR, CameraConfig, DomeConfig, LedConfig, SensorDesign
from ..core.sensor_response import SensorResponse
from .render.denoise import DenoiseConfig
from .render.variant import VARIANTS

DEFAULT_SCENE = SCENES_DIR / "nlipstac.toml"
DATASETS_DIR = SCENES_DIR / "datasets"
"""The shipped dataset specs (``nlips dataset train50`` names one)."""


@dataclasses.dataclass(frozen=True)
class CoatingConfig:
    """The Lambertian reflective coating on the gel."""

    albedo: tuple[float, float, float] = (0.8, 0.8, 0.8)
    """Diffuse reflectance per channel (0..1)."""
    variation: float = 0.0
    """Relative amplitude of smooth spatial albedo variation (0 = uniform)."""
    variation_scale: float = 4.0
    """Spatial scale of the variation, mm."""
    specular: float = 0.0
    """Weight of a rough specular lobe on top of the diffuse coat (0 = perfectly Lambertian, the NLiPs
    model; a sprayed matte coat is about 0.02-0.05, a satin one 0.1-0.3): ``(1 - specular) * Lambert(albedo) +
    specular * GGX(roughness)``, a Mitsuba ``blendbsdf`` of ``diffuse`` and a reflectance-1 ``roughconductor``
    (:func:`nlipscalib.sim.render.scene.coating_bsdf`)."""
    roughness: float = 0.3
    """GGX roughness alpha of that lobe (0.01 = nearly mirror-like, 1 = very rough)."""

    def __post_init__(self):
        check_range("specular", self.specular, 0.0, 1.0)
        check_range("roughness", self.roughness, 0.01, 1.0)
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
class LedPackageConfig:
    """Extended LEDs: each LED emits from a flat disk or square instead of a point.

    Every area element emits with the LED's own law, intensity (Psi / area) (n_s . d)^mu, so the
    LED's total light is unchanged and a point LED is the limit ``size -> 0``. On by default: the
    paper's NLiPsTac has WS2812B LEDs about 10 mm from the gel, where their 3.6 mm light cup is no point;
    the NLiPs model (and the solver) assume point LEDs, the limit case (``enabled = false``).
    """

    enabled: bool = True
    """True: LEDs are disks/squares of ``size``; False: point LEDs (the NLiPs model)."""
    shape: Literal["disk", "square"] = "disk"
    """Emitting area's shape, in the plane perpendicular to the LED's principal direction."""
    size: float = 3.6
    """Disk diameter or square side, mm. Default: the round light cup of a WS2812B (5050 package,
    5.0 x 5.0 mm outline; the emitting window is about 3.6 mm across)."""

    def __post_init__(self):
        check_range("size", self.size, 0.0, MAX_EMITTER_DIAMETER_MM)


@dataclasses.dataclass(frozen=True)
class CameraEffectsConfig:
    """Departures of the camera from the ideal linear pinhole the solver assumes (applied in that order).

    The NLiPs model is a linear camera without falloff; each effect is a separate switch. Defaults: the
    paper's NLiPsTac, a fixed-focus lens (0.7 px defocus) and a stated black level 3 DN off (the dark
    frame carries the true one); vignetting and the response curve off (docs/twin.md says why).
    """

    defocus_px: float = 0.7
    """Defocus blur: radius of a uniform disk point-spread function, pixels (0 = sharp)."""
    vignetting: Literal["none", "cos4", "polynomial"] = "none"
    """Radial falloff of the image: ``cos4`` = cos^4 of each pixel's ray angle to the optical axis (a thin
    rectilinear lens); ``polynomial`` = 1 + c1 r^2 + c2 r^4 + c3 r^6 with r the distance to the principal
    point over half the image diagonal."""
    vignetting_coeffs: tuple[float, float, float] = (-0.3, 0.0, 0.0)
    """c1, c2, c3 of the ``polynomial`` falloff (default: 30 % darker in the image corners)."""
    response_gamma: float = 1.0
    """Response curve: the sensor records x^gamma of the fraction of full scale x (1 = linear)."""
    black_level_error: float = 3.0
    """The true black level differs from the one stated in the capture's response by this much, DN
    (the dark frame carries the true one)."""
    bayer: Literal["none", "RGGB", "BGGR", "GRBG", "GBRG"] = dataclasses.field(
        default="none", metadata={OMIT_AT_DEFAULT: True}
    )
    """A Bayer sensor's 2x2 colour filter pattern, from the frame's top-left pixel (``none``: three colours per pixel,
    as rendered). Every stored frame (dark, LED images, tri-colour) keeps each pixel's own channel and is demosaiced
    again by OpenCV (:mod:`nlipscalib.sim.bayer`), as a webcam delivers it."""
    demosaic: Literal["edge_aware", "bilinear"] = dataclasses.field(
        default="edge_aware", metadata={OMIT_AT_DEFAULT: True}
    )
    """How a ``bayer`` camera interpolates the missing colours (:data:`nlipscalib.sim.bayer.DEMOSAIC_METHODS`):
    OpenCV's edge-aware demosaicing, like a webcam's image signal processor, or bilinear."""
    crosstalk: tuple[tuple[float, float, float], tuple[float, float, float], tuple[float, float, float]] = (
        dataclasses.field(default=((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), metadata={OMIT_AT_DEFAULT: True})
    )
    """The camera's colour crosstalk, ``[channel][light colour]``: the share of each colour's light each channel
    records, applied to the linear light before the sensor's noise (identity: none;
    :data:`nlipscalib.sim.bayer.TYPICAL_CROSSTALK`, a typical webcam sensor's, ``nlips render --crosstalk typical``)."""

    def __post_init__(self):
        check_range("defocus_px", self.defocus_px, 0.0, 50.0)
        for c, row in enumerate(self.crosstalk):
            for s, share in enumerate(row):
                check_range(f"crosstalk[{c}][{s}]", share, 0.0, 1.0)
        if not all(self.crosstalk[c][c] > 0 for c in range(3)):
            raise ConfigError(f"camera_effects.crosstalk {self.crosstalk}: a channel records none of its own colour")
        check_range("response_gamma", self.response_gamma, 0.2, 5.0)
        check_range("black_level_error", self.black_level_error, -1000.0, 1000.0)
        if self.vignetting == "polynomial":
            c1, c2, c3 = self.vignetting_coeffs
            if 1 + min(0.0, c1) + min(0.0, c2) + min(0.0, c3) <= 0:
                raise ConfigError(f"camera_effects.vignetting_coeffs {self.vignetting_coeffs} reach zero in the image")

    @property
    def enabled(self) -> bool:
        """Whether any effect departs from the ideal camera."""
        return self != IDEAL_CAMERA


IDEAL_CAMERA = CameraEffectsConfig(defocus_px=0.0, vignetting="none", response_gamma=1.0, black_level_error=0.0)
"""The camera of the NLiPs model: sharp, no falloff, linear, black level as stated."""


@dataclasses.dataclass(frozen=True)
class GelOpticsConfig:
    """Refraction at the gel's inner surface: the gel's index differs from the housing's inside it.

    The camera and the LEDs sit in the housing (index ``housing_ior``); the gel (``gel_ior``) fills the
    dome from its inner surface (the undeformed dome moved inward by ``dome.thickness``) to the coated
    outer surface. Off by default: the twin treats the gel as index-matched, as the NLiPs model does.
    Needs ``led_package.enabled`` (a point light cannot be reached through a refracting surface) and
    many samples per pixel: light reaches the coat only by paths that happen to hit an LED.
    """

    enabled: bool = False
    """True: trace refraction at the gel's inner surface."""
    gel_ior: float = 1.41
    """Refractive index of the gel (silicone elastomers: 1.40-1.43)."""
    housing_ior: float = 1.0
    """Refractive index inside the housing, where camera and LEDs sit (air: 1.0)."""

    def __post_init__(self):
        check_range("gel_ior", self.gel_ior, 1.0, 3.0)
        check_range("housing_ior", self.housing_ior, 1.0, 3.0)


MAX_BOUNCES = 8
"""Most interreflection bounces a render follows: a bounce adds ~0.31 of the previous one's light on the default
dome (one bounce: 31 % brighter, measured), so the ninth would add < 1e-4; ``--bounces 1000`` rendered for
over ten minutes without ending (a native call that SIGTERM cannot cut short)."""


MAX_SPP = 4096
"""Most samples per pixel a render takes (``--spp 1000000000`` ended in drjit's own traceback)."""


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
    denoise_indirect: bool = True
    """With bounces: filter the path tracer's Monte Carlo noise out of the bounce light before the camera
    (edge-avoiding a-trous filter on the true normals and depth, :mod:`nlipscalib.sim.render.denoise`; on the gel's
    outline in a view past it, per unit of each pixel's coverage, the render's alpha). At 16 spp that noise is
    about 27 % of the bounce light per pixel (RMS, against 256 spp), more than the sensor noise in all; it is the
    renderer's, not a sensor's. The direct light is never filtered."""
    denoise: DenoiseConfig = DenoiseConfig()
    """The filter's settings."""

    def __post_init__(self):
        check_count("spp", self.spp, minimum=1)
        if self.spp > MAX_SPP:
            raise ConfigError(f"spp: must be at most {MAX_SPP}, got {self.spp} (the twin's presses use 4-64)")
        check_count("bounces", self.bounces, minimum=0)
        if self.bounces > MAX_BOUNCES:
            raise ConfigError(
                f"bounces: must be at most {MAX_BOUNCES}, got {self.bounces} (each bounce adds about a third of the "
                f"last on the default dome: {MAX_BOUNCES} leave less than 1e-4 of the light; more only cost time)"
            )
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
    """The gel's shape and thickness (scene file ``[dome]``); part of the sensor's :attr:`design`."""
    camera: CameraConfig = CameraConfig()
    """The camera inside the dome: image size, field of view, lens, position (``[camera]``); part of the design."""
    leds: LedConfig = LedConfig()
    """The LED ring or explicit LEDs, in the dome frame (``[leds]``); part of the design."""
    coating: CoatingConfig = CoatingConfig()
    """The gel's reflective coat: albedo, its variation, a specular lobe (``[coating]``)."""
    noise: NoiseConfig = NoiseConfig()
    """The image sensor: shot and read noise, bit depth, black level, exposure (``[noise]``)."""
    render: RenderConfig = RenderConfig()
    """Mitsuba's settings: samples per pixel, interreflection bounces, variant, seed (``[render]``)."""
    led_package: LedPackageConfig = LedPackageConfig()
    """Extended LEDs (off: point LEDs, the NLiPs model)."""
    camera_effects: CameraEffectsConfig = CameraEffectsConfig()
    """Vignetting, response curve, black-level error, defocus (``IDEAL_CAMERA``: the NLiPs model's camera)."""
    gel_optics: GelOpticsConfig = GelOpticsConfig()
    """Refraction at the gel's inner surface (off: index-matched gel)."""

    def __post_init__(self):
        if self.gel_optics.enabled and not self.led_package.enabled:
            raise ConfigError(
                "gel_optics.enabled needs led_package.enabled: point LEDs cannot light through a refracting surface"
            )

    @property
    def design(self) -> SensorDesign:
        """The sensor's design (dome, camera, LEDs): what device/ and solver/ may know of it too."""
        return SensorDesign(dome=self.dome, camera=self.camera, leds=self.leds)

    def camera_model(self) -> Camera:
        return self.design.camera_model()

    def led_models(self) -> tuple[Led, ...]:
        return self.design.led_models()

    def ideal(self) -> SceneConfig:
        """Copy that renders exactly the NLiPs image model (``core.leds.led_shading``): point LEDs, Lambertian
        coat, ideal linear camera, index-matched gel. Noise, interreflection and spp are kept. Its design declares
        point LEDs too (``leds.emitter_diameter`` 0): ``nlips calibrate-leds`` then fits its captures' LEDs as the
        points they are."""
        return dataclasses.replace(
            self,
            leds=dataclasses.replace(self.leds, emitter_diameter=0.0),
            led_package=dataclasses.replace(self.led_package, enabled=False),
            coating=dataclasses.replace(self.coating, specular=0.0),
            camera_effects=IDEAL_CAMERA,
            gel_optics=dataclasses.replace(self.gel_optics, enabled=False),
        )

    def to_dict(self) -> dict:
        return to_mapping(self)

    def replace(self, **sections) -> SceneConfig:
        """Copy with some sections' fields changed: ``scene.replace(render={"spp": 16})``."""
        data = self.to_dict()
        for section, changes in sections.items():
            if section not in data:
                raise ConfigError(f"scene has no section '{section}'")
            # a table over a section's fields; anything else replaces it and is checked as the field's kind ("name":
            # a table for it was Python's "unsupported operand type(s) for |", s38-apikinds)
            merge = isinstance(changes, dict) and isinstance(data[section], dict)
            data[section] = data[section] | changes if merge else changes
        return from_mapping(SceneConfig, data, "scene")


def dataset_spec_path(spec: str | Path) -> Path:
    """The dataset spec file ``spec`` names: a path as given, or a bare name such as ``"train50"`` looked up
    in the shipped ``scenes/datasets/`` folder (an installed package has no checkout to name it by path).

    Raises
    ------
    ConfigError
        A bare name that is no file here nor a shipped spec (the line lists the shipped ones).
    """
    path = Path(spec)
    if path.is_file() or path.suffix:  # a path (load_dataset_spec says what is wrong with it); a folder
        # named like a shipped spec is not one: `nlips dataset train50 --out train50` resumes
        return path
    if not (DATASETS_DIR / f"{path}.toml").is_file():
        if path.is_dir():  # a dataset's folder given for its spec: "no such file" was untrue; the reader says so
            return path
        shipped = ", ".join(sorted(p.stem for p in DATASETS_DIR.glob("*.toml")))
        raise ConfigError(f"dataset spec {str(path)!r}: no such file, nor a shipped dataset spec ({shipped})")
    return DATASETS_DIR / f"{path}.toml"


def load_scene(path: str | Path | None = None) -> SceneConfig:
    """Load a scene file (TOML/YAML), or the built-in default NLiPsTac scene when ``path`` is None.

    A bare name such as ``"fingertip"`` is looked up in the shipped ``scenes/`` folder.
    """
    if path is None:
        path = DEFAULT_SCENE
    check_kind(path, PATH, "path", "a scene file's path (str or Path) or a shipped scene's name ('nlipstac')")
    path = Path(path)
    if not path.exists() and not path.suffix:
        if not (SCENES_DIR / f"{path}.toml").exists():  # a typo'd name, not a missing "config file"
            shipped = ", ".join(sorted(p.stem for p in SCENES_DIR.glob("*.toml")))
            # a design of one's own named as the shipped ones are (`--scene mine` beside mine.toml): name the file
            own = [str(path.with_suffix(s)) for s in (".toml", ".yaml", ".yml") if path.with_suffix(s).is_file()]
            hint = f"; a scene file of one's own is named with its suffix: {own[0]}" if own else ""
            raise ConfigError(f"scene {str(path)!r}: no such scene file, nor a shipped scene ({shipped}){hint}")
        path = SCENES_DIR / f"{path}.toml"
    data = read_config_file(path)
    camera = data.get("camera")
    if isinstance(camera, dict):  # one side alone kept the default other: `width = 1280` made 1280x480 images
        size = (CameraConfig.width, CameraConfig.height)
        check_size_pair(camera.get("width"), camera.get("height"), size, "{}", " = ", ", ", f"{path}: [camera] ")
    return from_mapping(SceneConfig, data, str(path))
