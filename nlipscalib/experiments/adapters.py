"""The only seams between experiments and the rest of the workbench: render, calibrate, solve, score.

Every experiment goes through these few functions, so when the twin, the solver or the pipeline gain
a better API, only this file changes. Presses are solved by ``nlipscalib.pipeline`` (the path every
command takes: recorded provenance, skip-if-solved, claims). This is wiring (like cli/): it may import
sim/, solver/ and learn/ together.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.config import from_mapping
from ..core.errors import CaptureError, ConfigError
from ..core.leds import Led, Leds

if TYPE_CHECKING:  # named in hints only: each function imports what it uses
    from ..core.capture import Press
    from ..core.reconstruction import Reconstruction
    from ..core.surface_files import GroundTruth
    from ..sim.scene import SceneConfig
    from ..solver import SolverOptions

ROI_MARGIN_PX = 8
"""Margin around the true contact's bounding box for ``roi = "truth"``, pixels."""


def build_scene(scene: dict, reference: bool = False) -> SceneConfig:
    """SceneConfig from a full scene mapping (as stored in a task); ``reference``: the one its undeformed
    reference is rendered with (``plan.REFERENCE_RENDER`` applied)."""
    from ..sim.scene import SceneConfig
    from .plan import REFERENCE_RENDER

    scene = dict(scene)
    overrides = scene.pop(REFERENCE_RENDER, None)
    cfg = from_mapping(SceneConfig, scene, "experiment scene")
    return cfg.replace(render=overrides) if reference and overrides else cfg


def render(scene: dict, press: dict | None, folder: Path, threads: int = 0) -> Path:
    """Render one press (None: the undeformed dome) of the twin into a press folder (atomic).

    The render and noise seed derive from the scene's seed and the press description
    (``sim.press.press_seed``), so the same task renders the same images on any worker.
    """
    from ..sim.indent import PressConfig
    from ..sim.press import render_press

    cfg = build_scene(scene, reference=press is None).replace(render={"threads": int(threads)})
    press_cfg = None if press is None else from_mapping(PressConfig, press, "experiment press")
    return render_press(cfg, press_cfg, folder, overwrite=True)


def load(folder: Path) -> Press:
    from ..core.capture import load_press

    return load_press(folder)


def perturb_leds(leds: Leds, position_mm: float = 0.0, direction_deg: float = 0.0, seed: int = 0) -> tuple[Led, ...]:
    """LEDs as a CAD with errors would give them: each moved by exactly ``position_mm`` in a random
    direction and its axis tilted by exactly ``direction_deg`` about a random perpendicular axis.

    Parameters
    ----------
    leds : sequence of Led, camera frame, mm
    position_mm, direction_deg : size of the error (fixed magnitude, random direction per LED)
    seed : the random directions' seed

    Returns
    -------
    tuple of Led
    """
    if position_mm == 0 and direction_deg == 0:
        return tuple(leds)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 7919]))
    out = []
    for led in leds:
        shift = rng.normal(size=3)
        shift *= position_mm / np.linalg.norm(shift)
        d = np.asarray(led.direction)
        axis = np.cross(d, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        a = np.radians(direction_deg)  # Rodrigues, axis perpendicular to d
        new_d = d * np.cos(a) + np.cross(axis, d) * np.sin(a)
        out.append(
            Led(
                position=tuple(np.asarray(led.position) + shift),
                direction=tuple(new_d),
                mu=led.mu,
                intensity=led.intensity,
            )
        )
    return tuple(out)


def auto_led_diameter(folder: Path) -> float:
    """The diameter (mm) of disks ``--led-model auto`` solves ``folder``'s LEDs as, 0 for points: its design's
    declared ``leds.emitter_diameter`` where point LEDs miss those disks' light unevenly over its gel (the flat pad,
    oblate and capsule), 0 elsewhere (:func:`nlipscalib.pipeline.led_choice.auto_led_diameter`, the one rule of
    ``nlips solve``: the design and calibrated rows take the model the true row's plain solve takes)."""
    from ..pipeline.led_choice import auto_led_diameter as choose

    return choose(folder)


def calibrate(
    reference_folder: Path, initial: Leds, led_diameter: float = 0.0
) -> tuple[tuple[Led, ...], tuple[Led, ...], dict]:
    """LED self-calibration from the undeformed dome's capture, starting from ``initial`` LEDs, as ``nlips
    calibrate-leds``: with ``led_diameter`` (mm) > 0 the LEDs also fitted as disks of that size.

    Returns the calibrated point LEDs (camera frame), their disks (empty for ``led_diameter`` 0) and a JSON-able
    summary (RMS residual per LED, the fit's ``quality``: its residual over the images' noise, ``reliable``).
    """
    from ..solver import calibrate_leds

    cal = calibrate_leds(load(reference_folder), initial=initial, led_radius=led_diameter / 2)
    quality = {k: cal.quality[k] for k in ("median_ratio", "threshold", "reliable")}
    info = {"rms": [float(r) for r in cal.rms], "albedo": list(cal.albedo), "quality": quality}
    return cal.leds, tuple(cal.emitters or ()), info


def solver_options(overrides: dict) -> SolverOptions:
    from ..solver import SolverOptions

    return from_mapping(SolverOptions, dict(overrides), "solver options")


def truth_roi(press: Press, margin: int = ROI_MARGIN_PX) -> tuple[int, int, int, int]:
    """(x0, y0, w, h) around the true contact: solver accuracy without the contact detector's errors."""
    contact = press.ground_truth.contact & press.ground_truth.valid
    if not contact.any():
        raise CaptureError(f"{press.folder}: the press has no visible contact")
    rows, cols = np.nonzero(contact)
    H, W = press.camera.shape
    y0, y1 = max(rows.min() - margin, 0), min(rows.max() + 1 + margin, H)
    x0, x1 = max(cols.min() - margin, 0), min(cols.max() + 1 + margin, W)
    return int(x0), int(y0), int(max(x1 - x0, 4)), int(max(y1 - y0, 4))


def solve(
    press: Press,
    *,
    out: Path,
    leds: Leds | None = None,
    interreflection: str,
    reference: Path | None = None,
    roi: str = "truth",
    options: SolverOptions | None = None,
    albedo: float | tuple[float, float, float] | None = None,
    disks: tuple[Leds | None, float] | None = None,
) -> Reconstruction:
    """NLiPs on one press through the one solving path (``pipeline.solve_folder``) into ``out``.

    The pipeline records what made the result (settings, input hashes) and reuses an identical one:
    a press folder that survived an interruption is not solved again. The result is read back from
    ``out`` either way (lossless), so a fresh and a reused solve give the same numbers.

    Parameters
    ----------
    press : Press (with ground truth when ``roi = "truth"``), loaded from its folder
    out : reconstruction folder to write (e.g. PRESS/solves/<variant>)
    leds : sequence of Led given to the solver (CAD-with-error or self-calibrated), None: the capture's
    interreflection : "off" (direct model only), "reference" (the interreflection term fitted on the
        undeformed capture, the undeformed surface's indirect light subtracted) or "dent" (also the outer
        loop on the solved surface: the solver's default)
    reference : press folder of the undeformed dome, needed unless ``interreflection == "off"``
    roi : "truth" (true contact box), "auto" (the solver's contact detector) or "full"
    options : SolverOptions or None
    albedo : coating reflectance to impose on the interreflection term, or None (fitted from the data)
    disks : ``leds``' disks, (emitters or None for ``leds`` themselves, radius mm), which the pipeline's
        ``--led-model auto`` solves with where it takes disks for the press's design, as an LED file's fitted disks
        (``nlips solve --leds FILE``); None: points

    Returns
    -------
    core.Reconstruction over the full image
    """
    from ..core.reconstruction import load_reconstruction
    from ..pipeline import solve_folder

    if interreflection not in ("off", "reference", "dent"):
        raise ConfigError(f"interreflection must be off, reference or dent, got {interreflection!r}")
    if interreflection != "off" and reference is None:
        raise ConfigError(f"interreflection {interreflection!r} needs the undeformed reference capture")
    box = {"truth": lambda: truth_roi(press), "auto": lambda: "auto", "full": lambda: None}[roi]()
    result, status = solve_folder(
        press.folder,
        reference=None if interreflection == "off" else reference,
        roi=box,
        leds=leds,
        options=options,
        out=out,
        progress=False,
        figures=False,
        solver_keywords={
            "dent_interreflection": interreflection == "dent",
            "coating_albedo": albedo,
            "interreflection": "off" if interreflection == "off" else "on",
        },
        led_disks=disks,  # solved as disks where --led-model auto takes disks for the press (pipeline.for_press)
    )
    return load_reconstruction(out, press.camera.shape)


def score(result: Reconstruction, ground_truth: GroundTruth) -> dict:
    """AAE / MabsE / depth RMSE over the solved region ("all") and its true contact ("contact")."""
    from ..core.metrics import evaluate

    return evaluate(result, ground_truth)


def error_crop(result: Reconstruction, ground_truth: GroundTruth) -> dict[str, np.ndarray]:
    """Arrays for the error-map figures, cut to the solved region's bounding box.

    Returns
    -------
    dict with "true" and "estimate" (h, w, 3) float32 normals (NaN outside), "error" (h, w) float32 degrees
    """
    from ..core.metrics import angular_error_map

    shown = result.reconstructed & ground_truth.valid
    if not shown.any():
        return {}
    rows, cols = np.nonzero(shown)
    win = (slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1))
    est = np.where(shown[..., None], result.normals, np.nan)[win]
    gt = np.where(shown[..., None], ground_truth.normals, np.nan)[win]
    err = angular_error_map(est, gt)
    return {"true": gt.astype(np.float32), "estimate": est.astype(np.float32), "error": err.astype(np.float32)}


def calibration_samples(press: Press, rec: Reconstruction, reference: Path, sampling: dict) -> dict[str, np.ndarray]:
    """NLiPsNet calibration samples of one solved press, as ``nlips calibrate`` makes them.

    Parameters
    ----------
    press : Press ; rec : its NLiPs Reconstruction (full image) ; reference : press folder of the
    undeformed dome ; sampling : learn.dataset.SamplingConfig mapping

    Returns
    -------
    dict of the shard arrays (learn.dataset: pixel, rgb, normal, true_normal, contact, source)
    """
    from ..learn.dataset import SamplingConfig, press_samples, reference_arrays

    cfg = from_mapping(SamplingConfig, dict(sampling), "experiment sampling")
    return press_samples(press, rec, reference_arrays(load(reference)), cfg)


def write_samples(path: Path, arrays: dict, entry: dict) -> None:
    """Write a calibration shard atomically, carrying its index ``entry`` (learn.dataset's writer)."""
    from ..learn.dataset import write_shard

    write_shard(Path(path), arrays, entry)


def samples_entry(path: Path) -> tuple[dict | None, int]:
    """The index entry a calibration shard carries (None: written before shards carried one) and its sample count.

    Raises
    ------
    CaptureError -- naming the file: missing, damaged, truncated or inconsistent.
    """
    from ..learn.dataset import shard_entry

    return shard_entry(Path(path))


def figure_view(press: Press, reference: Path, sampling: dict, margin: int = ROI_MARGIN_PX) -> dict[str, np.ndarray]:
    """A crop around the true contact for the NLiPsNet figure (objects / true / predicted / error).

    Parameters
    ----------
    press : Press ; reference : press folder of the undeformed dome (its gel mask) ; sampling :
    learn.dataset.SamplingConfig mapping (the prefilter of the network's input colours)

    Returns
    -------
    dict: "rgb" (h, w, 3) float32 linear tri-colour image; "input" (h, w, 3) float32 the same filtered as
    the samples' colours (learn.prefilter, over the whole frame); "true" (h, w, 3) float32 true normals
    (NaN off the gel); "origin" (2,) int (x0, y0) of the crop in the image; {} when there is no contact
    """
    from ..learn.dataset import SamplingConfig, reference_arrays
    from ..learn.prefilter import Prefilter

    if press.ground_truth is None or not (press.ground_truth.contact & press.ground_truth.valid).any():
        return {}
    x0, y0, w, h = truth_roi(press, margin)
    win = (slice(y0, y0 + h), slice(x0, x0 + w))
    gt = press.ground_truth
    true = np.where(gt.valid[win][..., None], gt.normals[win], np.nan)
    tri = press.linear(press.tricolor)
    cfg = from_mapping(SamplingConfig, dict(sampling), "experiment sampling")
    prefilter = Prefilter(reference_arrays(load(reference))["valid"], cfg.smoothing_px, cfg.smoothing_colour)
    return {
        "rgb": tri[win].astype(np.float32),
        "input": prefilter(tri, *win),
        "true": true.astype(np.float32),
        "origin": np.array([x0, y0], np.int64),
    }
