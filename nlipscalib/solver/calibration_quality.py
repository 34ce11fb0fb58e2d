"""The LED calibration's quality: how much of the images the fitted LEDs leave unexplained, in units of the images'
own noise and the LED model's error (:func:`fit_quality`), and the warning for an unreliable fit."""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence

import numpy as np

from ..core import tolerances
from ..core.capture import Press
from ..core.leds import Led
from ..core.robust_scale import mad_scale
from .calibration_term import no_interreflection
from .led_fit import fit_samples, point_model


def _led_noise(presses: Sequence[Press]) -> np.ndarray:
    """(L,) float -- the white noise of each LED's images, linear units: Immerkaer's estimate
    (:func:`nlipscalib.solver.image_stats.image_noise`) on the gel, median over the captures, at least one ADC step
    (a noise-free capture holds only quantisation, where the estimate says nothing). An LED image's band left out of
    its fit (:mod:`.calibration_bands`: read while its LED was off, or before it switched) is left out here too: a
    quarter of LED 5's image at the dark frame's level (twin, 320x240) lowered its noise and called its fit 1.58x it
    (1.03x the others)."""
    from ..core.capture import unusable_digest
    from .image_stats import image_noise

    per = []
    for p in presses:
        valid = np.isfinite(p.reference.depth)
        lin = p.linear_led_images
        # only a capture with bands marked (its saturated samples counted as before: the estimates of every capture)
        banded = p.saturated_led_images.any(axis=-1) if unusable_digest(p) is not None else None
        per.append(
            [image_noise(lin[i : i + 1], valid & ~banded[i] if banded is not None else valid) for i in range(len(lin))]
        )
        if banded is not None:  # an image left out whole (a stale frame, calibration_bands): no estimate of it here
            per[-1] = [np.nan if (valid & ~banded[i]).sum() == 0 else v for i, v in enumerate(per[-1])]
    step = adc_step(presses[0])
    with warnings.catch_warnings():  # an LED left out of every capture (not fitted): NaN, no estimate
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.maximum(np.nanmedian(np.asarray(per, float), axis=0), step)


def adc_step(press: Press) -> float:
    """One ADC step of ``press``'s camera in linear units (full scale 1): the least noise an image is said to hold (a
    noise-free capture holds only quantisation)."""
    r = press.response
    return 2.0 ** (16 - r.bit_depth) / (r.white_level - r.black_level)


def fit_quality(
    presses: Sequence[Press],
    fitted: Sequence[tuple[np.ndarray, np.ndarray, float]],
    x: np.ndarray,
    n: np.ndarray,
    img: np.ndarray,
    ok: np.ndarray,
    model: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] = point_model,
) -> dict:
    """How much of the images the fitted LEDs leave unexplained, in units of the images' own noise.

    Each LED's residual scale (1.4826 x the median absolute deviation of model minus image over its fitted
    samples: robust, so a few bad pixels do not count) over the white noise of its images (Immerkaer's
    estimate, which a Laplacian mask makes blind to smooth shading) and the LED model's own error
    (:data:`tolerances.CALIBRATION_MODEL_ERROR` of its median fitted sample), in quadrature. A model that
    explains the images leaves the noise alone: a ratio near 1. The model's error matters without noise only:
    a noise-free render's Immerkaer estimate is its quantisation (the ADC step, the floor), while the smooth
    error of sampling a pixel's footprint at its centre is not noise, 0.24-0.28 % of the level on the twin.
    Light the model does not explain is mostly smooth (measured below: the Monte Carlo error of a low-spp
    render, which the bounce light's denoiser turns into blotches; an interreflection term left out; the
    realistic twin's optics), so it raises the residual and not the noise estimate, and it biases the LEDs far
    beyond their Jacobian ``std``: at 160x120, 4 spp the worst LED's axis is 2-4 deg off while its ``std`` says
    0.15 deg.

    Measured (``nlips render --undeformed``, then ``calibrate_leds`` from the capture's own LEDs; median ratio
    over the LEDs, worst LED against the truth, points, or with ``led_radius`` 1.8 the disks; 2026-12-03, the
    noise alone; the model's error moves these by at most 0.01, below):

    ==================================================  ==============  ==========================
    capture                                             median ratio    worst LED
    ==================================================  ==============  ==========================
    nlipstac, bounces 0, 160x120, 4 spp / 1 spp         1.01 / 1.04     0.51-0.80 deg, 0.24-0.29 mm
    nlipstac, one bounce, 16 spp, 160x120 (3 seeds)     1.06-1.07       disks 0.87-1.43 deg, 0.13-0.30 mm
    ... 320x240 / 640x480                               1.04 / 1.03     1.33 / 1.31 deg (points)
    nlipstac_ideal / fingertip, one bounce, 16 spp      1.08 / 1.11     disks 0.87 / 1.45 deg
    nlipstac, one bounce, 8 spp, 320x240                1.15            1.58 deg, 0.25 mm (points)
    nlipstac, one bounce, 4 spp, 640x480                1.19            3.33 deg, 0.69 mm (points)
    nlipstac, one bounce, 8 spp, 160x120 (3 seeds)      1.20-1.22       disks 2.91-4.58 deg, 0.29-0.55 mm
    oblate, one bounce, 16 spp (term not used: share    1.23            disks 16.2 deg
    0.09 with the starting LEDs; forced on, as
    auto now does: 1.06, points 2.8 deg)
    nlipstac, one bounce, 4 spp, 160x120 (3 seeds)      1.34-1.36       disks 1.81-3.57 deg, 0.43-0.80 mm
    nlipstac_realistic, one bounce, 16 spp              1.52            disks 13.0 deg, 4.9 mm
    nlipstac, one bounce, 2 spp, 160x120 (3 seeds)      1.63-1.64       disks 2.44-5.89 deg, 0.42-0.56 mm
    ==================================================  ==============  ==========================

    Without noise (2026-12-05: the noise-free ``twin()`` of tests/solver/test_twin.py, stride 2, from the true
    LEDs and ones 0.3-0.5 mm / 5 deg off; ratio without / with the model's error; residual: % of the median
    fitted sample):

    ==============================================  ============  =========  ============================
    capture                                         ratio         residual   worst LED
    ==============================================  ============  =========  ============================
    nlipstac, bounces 0, 4 spp, 80x60               1.52-1.56 /   0.26-0.28  0.49-0.61 deg (disks 0.16)
                                                    0.75-0.80
    ... 160x120                                     1.54 / 0.71   0.24       0.43-0.45 deg (disks 0.07)
    nlipstac, one bounce, 16 spp, 160x120           8.6 / 2.9     0.93       1.73-3.12 deg, 0.31-0.36 mm
    ==============================================  ============  =========  ============================

    With the sensor's noise (2.2-3.8 % of the median fitted sample) the model's error moves the median ratio by
    at most 0.01 (the quality tests' captures, stride 4: bounces 0 1.006 -> 0.997, one bounce 16 spp 1.068 ->
    1.061, 2 spp 1.689 -> 1.678, the oblate dome 1.095 -> 1.092).

    Good captures stay at or below 1.11; the poor ones (worst LED beyond the README's 2 deg or 0.3 mm) start at
    1.19, so :data:`tolerances.FIT_NOISE_RATIO` = 1.15 sits between them (the ratio's own scatter at 160x120: about 0.01
    between seeds, up to 0.03 between strides 2, 3 and 4). The worst single LED of a good capture reached 1.13: the
    verdict is the median's, so one LED's chance excess does not raise it. Blind spot: light the LEDs can absorb
    by tilting (the indirect term forced on a bounce-free capture: worst LED 16 deg off at 1.04).

    Parameters
    ----------
    presses : sequence of Press -- the captures (their LED images give the noise).
    fitted : list of (params, std, rms) -- per LED, as :func:`.led_fit.fit_leds` returns them.
    x, n : (N, 3) float -- the samples' points (mm) and normals (unit), camera frame.
    img : (L, N, 3) float -- the images the LEDs were fitted to (minus the indirect light), linear.
    ok : (L, N, 3) bool -- usable samples.
    model : the LED model the parameters are of (default the point LED).

    Returns
    -------
    dict -- ``noise`` (L,), ``model_error`` (L,) and ``residual`` (L,), linear image units; ``ratio`` (L,)
    residual over noise and model error in quadrature;
    ``median_ratio``; ``threshold`` (:data:`tolerances.FIT_NOISE_RATIO`); ``reliable`` (median_ratio <= threshold).
    """
    noise = _led_noise(presses)
    residual, level = [], []
    for i, (params, _, _) in enumerate(fitted):
        use = fit_samples(img[i], ok[i])
        r = (model(params, x, n) - img[i])[use]
        residual.append(mad_scale(r) if r.size else float("nan"))
        level.append(float(np.median(img[i][use])) if r.size else float("nan"))
    model_error = tolerances.CALIBRATION_MODEL_ERROR * np.asarray(level)
    ratio = np.asarray(residual) / np.hypot(noise, model_error)  # independent errors: their variances add
    median = float(np.nanmedian(ratio))
    return {
        "noise": [float(v) for v in noise],
        "model_error": [float(v) for v in model_error],
        "residual": residual,
        "ratio": [round(float(v), 4) for v in ratio],
        "median_ratio": round(median, 4),
        "threshold": tolerances.FIT_NOISE_RATIO,
        "reliable": bool(median <= tolerances.FIT_NOISE_RATIO),
    }


def quality_warning(quality: dict, models: list[dict], interreflection: str) -> list[str]:
    """The warning for an unreliable fit (:func:`fit_quality`), with what to do; [] when reliable."""
    if quality["reliable"]:
        return []
    ratio = np.asarray(quality["ratio"])
    worst = int(np.nanargmax(ratio))
    hint = ""
    if interreflection == "auto" and no_interreflection(models, interreflection) is not None:
        hint = "; the interreflection term was not used: if the gel interreflects, try --interreflection on"
    return [
        f"LED calibration unreliable: its residual is {quality['median_ratio']:.2f}x the images' noise (median "
        f"over the LEDs, reliable up to {quality['threshold']}; LED {worst + 1} {ratio[worst]:.2f}x): the images hold "
        "light the LED model does not explain. Capture again with more samples per pixel (a render) or more frames "
        "averaged, and check the capture (nothing moved, no stray light, the undeformed dome)" + hint
    ]


def single_led_warnings(quality: dict, leds: Sequence[Led]) -> list[str]:
    """Warnings for single LEDs not to be trusted in a calibration the median LED calls reliable (the verdict of
    :func:`quality_warning`, which one LED does not move): an LED whose residual is above
    :data:`tolerances.LED_FIT_OUTLIER_RATIO` times the noise, or whose mu ended at its bound 0. Why: from LEDs far off
    their design (2 mm / 80 deg on synthetic captures) one LED stopped 6.9 mm / 65 deg off at 92x the noise while the
    others sat at 0.03x, and was called reliable (benchmarks/RESULTS.md, s27-ledstarts)."""
    if not quality["reliable"]:  # said already, for all the LEDs
        return []
    notes = []
    for i, (ratio, led) in enumerate(zip(quality["ratio"], leds)):
        why = []
        if ratio > tolerances.LED_FIT_OUTLIER_RATIO:
            median = quality["median_ratio"]
            why.append(f"its residual is {ratio:.2f}x the images' noise (the LEDs' median {median:.2f}x)")
        if led.mu <= 0:
            why.append("its mu ended at its bound 0")
        if why:
            notes.append(
                f"LED {i + 1} not to be trusted: {' and '.join(why)}: its fit may have stopped in a wrong minimum, or "
                "the LED is not as the model has it (blocked, dim, far from its design place): check it, then capture "
                "the undeformed dome again"
            )
    return notes
