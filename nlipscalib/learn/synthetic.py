"""Model-based training samples of steep relief: the tri-colour colour the LED image model predicts for normals that
the calibration presses never reach.

Why: NLiPsNet is an MLP and does not extrapolate. The smooth calibration indenters tilt the gel by at most ~30 deg
(Q2's steepness table), a coin's engraved detail by up to 75 deg, so even a net trained on the twin's true normals
misses the coin (docs/experiments/RESULTS.md, "The coin's ceiling"). The sensor's physics is calibrated already:
the LEDs (core.leds, the one image model), the undeformed surface and its tri-colour frame. A synthetic sample
is a pixel of the undeformed dome whose gel point is pushed a little along the camera ray and turned 30-75 deg:

    S_ref = M^-1 (T_ref - o)
    T_syn = M (S_ref * F(x, n) / F(x0, n0) + a S_ref (1 - cos tilt) / 2) + o

- ``F_g(x, n)``: the LED model's light of tri-colour group g (the sum of its LEDs' :func:`core.leds.led_shading`,
  mean over channels) at point x with normal n; ``x0, n0`` the undeformed surface at that pixel.
- ``T_ref``: the reference tri-colour frame (filtered as the samples' colours are). Dividing by the model's light
  there leaves each pixel's gain of group g (albedo, LED intensity, vignetting, the reference's interreflection):
  nothing is fitted per pixel and no albedo solve is needed.
- ``a S_ref (1 - cos tilt) / 2``: indirect light, when the gel's reflectance ``a`` is given. A facet tilted from
  the surface around it sees that surface over the view factor (1 - cos tilt) / 2 and reflects its radiance (its
  image value, S_ref) times its own reflectance. Why: the direct model alone makes steep facets too dark. On Q2's
  medium twin, at the true geometry of the test presses' contact pixels, it is within 1-4 % of the real colour up
  to 35 deg of tilt but 10-13 % too dark at 35-50 deg and 28-38 % at 50-90 deg (cone, screw, coin), where the
  facets face the gel around them; a = 0.8 leaves -9 to -11 % there. The calibration presses, which stay below 30 deg,
  cannot fit ``a`` (a fit on them gives -0.39; the steep unseen facets would want +1.04): it is the gel's reflectance,
  a property of its coat. Off by default: its 2-4.5 % overshoot at 20-35 deg, where the real samples are, cost Q2's
  seen split 0.15 deg (docs/experiments/RESULTS.md, s33-synth).
- ``M, o``: how the tri-colour channels mix the groups' single-LED images (:func:`fit_mixing`, least squares over
  the pixels of presses that have both). On the twin M is 0.386 I to within 0.003 off the diagonal.

The samples are labelled with the normal they were made with (as NLiPs labels and true normals alike), flagged
``source = SOURCE_SYNTHETIC`` and in contact. Computing only: arrays in, arrays out; :func:`samples_for_dataset`
reads what it needs from a calibration dataset's presses.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.camera import Camera, depth_to_points
from ..core.errors import CaptureError
from ..core.leds import Leds, led_shading, tricolor_groups

if TYPE_CHECKING:  # named in hints only
    from .dataset import CalibrationDataset

SOURCE_SYNTHETIC = 2
"""``source`` of a synthetic sample (0 NLiPs label, 1 reference-surface label: learn.dataset)."""
TILT_DEG = (30.0, 75.0)
"""Range of the synthetic normals' tilt from the undeformed normal: from about where the calibration indenters stop
(99th percentile 22-30 deg) to a coin's steepest engraving (99th percentile 74 deg)."""
BEHIND_MM = (0.0, 2.0)
"""Range of how far behind the undeformed surface, along the camera ray, a synthetic gel point lies (the presses are
0.8-1.5 mm deep)."""
MIN_VIEW_COS = 0.1
"""A synthetic normal must face the camera at least this much (cos of the angle to the reversed ray): the camera
sees no facet turned away from it."""
MIN_LIGHT_RATIO = 0.05
"""A synthetic sample is dropped when its three groups together get less than this share of the light they give the
undeformed surface there: a facet in the shadow of every LED has a colour many normals share."""
GEL_REFLECTANCE = 0.8
"""A white matte silicone coat's diffuse reflectance (the default twin's ``albedo``, scenes/nlipstac.toml): the value
to give the indirect term's ``a`` (module docstring; ``TrainConfig.synthetic_reflectance``, `nlips train
--gel-reflectance`, whose default is 0: direct light only)."""
MIXING_PRESSES = 4
"""Presses (their single-LED and tri-colour images) the mixing fit reads: the fit has 3x4 unknowns and every pixel
of one press is already ~100 000 equations; more presses only cost reading time."""


@dataclasses.dataclass(frozen=True)
class Mixing:
    """How a tri-colour frame is made of the single-LED images: ``T = matrix @ S + offset`` per pixel."""

    matrix: np.ndarray
    """(3, 3) float64: tri-colour channel c from group g's summed single-LED image (mean over its channels)."""
    offset: np.ndarray
    """(3,) float64, linear image units."""
    rms: np.ndarray
    """(3,) float64: the fit's residual RMS per channel over the pixels fitted (noise and what M does not model)."""
    pixels: int
    """How many pixels were fitted."""


def group_sums(led_images: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each tri-colour group's single-LED images summed, each LED's channels averaged.

    Parameters
    ----------
    led_images : (L, ..., 3) float, linear -- one image (or light values) per LED
    groups : (L,) int, 0-2 -- each LED's tri-colour group (:func:`core.leds.tricolor_groups`)

    Returns
    -------
    (..., 3) float64 -- group g's sum in channel g
    """
    grey = np.asarray(led_images, np.float64).mean(-1)
    return np.stack([grey[groups == g].sum(0) for g in range(3)], -1)


def fit_mixing(tricolor: np.ndarray, sums: np.ndarray) -> Mixing:
    """Least-squares ``tricolor = M sums + o`` over corresponding pixels.

    Parameters
    ----------
    tricolor : (N, 3) float -- linear tri-colour values
    sums : (N, 3) float -- the same pixels' :func:`group_sums`

    Returns
    -------
    Mixing
    """
    t, s = np.asarray(tricolor, np.float64), np.asarray(sums, np.float64)
    ok = np.all(np.isfinite(t), -1) & np.all(np.isfinite(s), -1)
    if ok.sum() < 4:
        raise CaptureError(f"the mixing fit needs at least 4 pixels with finite values, got {int(ok.sum())}")
    design = np.concatenate([s[ok], np.ones((int(ok.sum()), 1))], 1)
    coef, *_ = np.linalg.lstsq(design, t[ok], rcond=None)
    rms = np.sqrt(np.mean((t[ok] - design @ coef) ** 2, 0))
    return Mixing(matrix=coef[:3].T.copy(), offset=coef[3].copy(), rms=rms, pixels=int(ok.sum()))


def group_light(points: np.ndarray, normals: np.ndarray, leds: Leds) -> np.ndarray:
    """The LED model's light of each tri-colour group at points with normals (unit albedo).

    Parameters
    ----------
    points : (N, 3) float, mm, camera frame
    normals : (N, 3) float, unit, camera frame, toward the camera
    leds : the sensor's LEDs, in order

    Returns
    -------
    (N, 3) float64 -- :func:`group_sums` of :func:`core.leds.led_shading`
    """
    return group_sums(led_shading(points, normals, leds), tricolor_groups(len(leds)))


def tilted_normals(normals: np.ndarray, tilt_deg: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit normals turned by ``tilt_deg`` from ``normals`` toward the azimuth ``azimuth`` (radians) about them.

    Parameters
    ----------
    normals : (N, 3) float, unit
    tilt_deg, azimuth : (N,) float

    Returns
    -------
    (N, 3) float64, unit
    """
    n = np.asarray(normals, np.float64)
    helper = np.where(np.abs(n[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    e2 = np.cross(n, e1)
    t = np.deg2rad(tilt_deg)[:, None]
    a = np.asarray(azimuth)[:, None]
    return np.cos(t) * n + np.sin(t) * (np.cos(a) * e1 + np.sin(a) * e2)


def synthetic_samples(
    reference: dict,
    tricolor: np.ndarray,
    rays: np.ndarray,
    leds: Leds,
    mixing: Mixing,
    count: int,
    rng: np.random.Generator,
    tilt_deg: Sequence[float] = TILT_DEG,
    behind_mm: Sequence[float] = BEHIND_MM,
    reflectance: float = 0.0,
) -> dict:
    """Synthetic contact samples of steep relief (module docstring), in the shard layout of learn.dataset.

    Parameters
    ----------
    reference : the dataset's reference arrays: depth (H, W) mm (z), normals (H, W, 3), valid (H, W)
    tricolor : (H, W, 3) float -- the reference tri-colour frame, linear, filtered as the samples' colours
    rays : (H, W, 3) float, unit, camera frame -- the pixels' viewing rays
    leds : the sensor's LEDs
    mixing : :func:`fit_mixing` of the sensor
    count : how many samples to draw (fewer come back: those facing away or unlit are dropped)
    rng : numpy Generator
    tilt_deg, behind_mm : (low, high) ranges, uniform
    reflectance : the gel's diffuse reflectance, the indirect term's ``a`` (0: direct light only)

    Returns
    -------
    dict: pixel (K, 2) int16 (u, v); rgb (K, 3) float32; normal and true_normal (K, 3) float32 (the same, unit,
    camera frame); contact (K,) bool (all True); source (K,) uint8 (all SOURCE_SYNTHETIC)
    """
    ok = reference["valid"] & np.all(np.isfinite(tricolor), -1) & np.isfinite(reference["depth"])
    rows, cols = np.nonzero(ok)
    pick = rng.integers(0, len(rows), count)
    rows, cols = rows[pick], cols[pick]
    ray = rays[rows, cols].astype(np.float64)
    x0 = depth_to_points(reference["depth"][rows, cols].astype(np.float64), ray)
    n0 = reference["normals"][rows, cols].astype(np.float64)
    x = x0 + rng.uniform(*behind_mm, count)[:, None] * ray
    tilt = rng.uniform(*tilt_deg, count)
    n = tilted_normals(n0, tilt, rng.uniform(0.0, 2 * np.pi, count))
    light0, light = group_light(x0, n0, leds), group_light(x, n, leds)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = light / light0
        keep = (np.sum(-ray * n, -1) >= MIN_VIEW_COS) & (ratio.sum(-1) >= MIN_LIGHT_RATIO * 3)
    keep &= np.all(np.isfinite(ratio), -1)
    own = (tricolor[rows, cols].astype(np.float64) - mixing.offset) @ np.linalg.inv(mixing.matrix).T
    seen_around = (1.0 - np.cos(np.deg2rad(tilt)))[:, None] / 2  # view factor of the surface around the facet
    rgb = (own * (ratio + reflectance * seen_around)) @ mixing.matrix.T + mixing.offset
    k = int(keep.sum())
    normal = n[keep].astype(np.float32)
    return {
        "pixel": np.stack([cols[keep], rows[keep]], -1).astype(np.int16),
        "rgb": rgb[keep].astype(np.float32),
        "normal": normal,
        "true_normal": normal.copy(),
        "contact": np.ones(k, bool),
        "source": np.full(k, SOURCE_SYNTHETIC, np.uint8),
    }


def dataset_mixing(dataset: CalibrationDataset, names: Sequence[str]) -> Mixing:
    """:func:`fit_mixing` over every pixel of the first :data:`MIXING_PRESSES` of ``names`` (their press folders'
    single-LED and tri-colour images, linear), on the gel."""
    from ..core.capture import load_press

    valid = dataset.reference()["valid"]
    tri, sums = [], []
    for name in list(names)[:MIXING_PRESSES]:
        press = load_press(_folder(dataset, name))
        groups = tricolor_groups(len(press.leds))
        tri.append(press.linear(press.tricolor)[valid])
        sums.append(group_sums(press.linear_led_images[:, valid], groups))
    return fit_mixing(np.concatenate(tri), np.concatenate(sums))


def samples_for_dataset(
    dataset: CalibrationDataset, names: Sequence[str], count: int, seed: int, reflectance: float = 0.0
) -> dict:
    """``count`` synthetic samples (fewer, :func:`synthetic_samples`) of the sensor of ``dataset``, the mixing fitted
    on its presses ``names`` and the LEDs of its reference capture (``index.json``'s ``reference``); ``reflectance``
    the indirect term's (0: none).

    Raises
    ------
    CaptureError : when the reference capture or the presses' folders cannot be read
    """
    from ..core.capture import read_optics

    ref_folder = dataset.index.get("reference")
    if not ref_folder or not Path(ref_folder).is_dir():
        raise CaptureError(
            f"{dataset.folder}: synthetic samples need the reference capture (its LEDs), not found at {ref_folder!r}: "
            "train without --synthetic-share, or where the capture is"
        )
    optics = read_optics(ref_folder)
    camera = Camera.from_dict(dataset.sensor["camera"])
    reference = dataset.reference()
    return synthetic_samples(
        reference,
        dataset.filtered_reference(),
        camera.rays,
        optics.leds,
        dataset_mixing(dataset, names),
        count,
        np.random.default_rng(seed),
        reflectance=reflectance,
    )


def _folder(dataset: CalibrationDataset, name: str) -> Path:
    folder = dataset.entry(name).get("folder")
    if not folder or not Path(folder).is_dir():
        raise CaptureError(f"{dataset.folder}: press {name}'s folder {folder!r} is not there (the mixing fit reads it)")
    return Path(folder)
