"""Per-pixel normal refinement (solver/refine.py, ``SolverOptions.normals = "refined"``)."""

import json
import shutil

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import load_press
from nlipscalib.core.errors import ConfigError
from nlipscalib.core.leds import disk_shading
from nlipscalib.core.metrics import angle_deg, evaluate
from nlipscalib.solver import SolverOptions, refine, solve_press
from nlipscalib.solver.refine import RefitInputs, refine_normals

from . import synth

ALBEDO = np.array([0.8, 0.7, 0.6])


def _tilted(normals: np.ndarray, deg: float) -> np.ndarray:
    """``normals`` (N, 3) turned by ``deg`` about an axis perpendicular to each (toward +x where possible)."""
    axis = np.cross(normals, [0.0, 1.0, 0.0])
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    t = np.radians(deg)
    return normals * np.cos(t) + np.cross(axis, normals) * np.sin(t)


def _surface(kind: str):
    """Exact linear images (L, N, 3), points (N, 3), true normals (N, 3) of the gel pixels, and the LEDs."""
    cam, leds = synth.camera(64, 48), synth.ring_leds()
    _, pts, nrm, valid = synth.surface(cam, kind, 1.5)
    lin = synth.render(cam, leds, pts, nrm, ALBEDO, exposure=1.0)
    return lin[:, valid], pts[valid], nrm[valid], leds


def _refined(images, points, normals, start, leds, sigma=0.0, led_radius=0.0):
    lit = images > 0  # exact data: the solve's shadow exclusion is the model's max(0, .)
    scale = max(3 * sigma, 0.02 * float(np.median(images[lit])))  # the solve's lambda: 3 sigma, its floor
    albedo = np.broadcast_to(ALBEDO * 1.1, normals.shape)  # its ratios right, its level not
    fit = RefitInputs(images, lit, points, start, albedo, leds, scale, brightest=8, led_radius=led_radius)
    return refine_normals(fit)


def test_exact_images_give_the_true_normals_and_albedo():
    images, points, truth, leds = _surface("cube")
    n, rho, changed = _refined(images, points, truth, _tilted(truth, 8.0), leds)
    assert changed.all()
    assert np.nanmax(angle_deg(n, truth)) < 1e-4
    np.testing.assert_allclose(rho, np.broadcast_to(ALBEDO, rho.shape), rtol=1e-5)


DISK_RADIUS = 1.8
"""mm: the default twin's LED light cups (``[led_package] size = 3.6``)."""


def test_disk_leds_are_refitted_with_the_disk_model_the_solve_used():
    # images of LEDs that emit from disks: refined with the disks (a --led-model disks solve) the normals are the
    # truth; with points (before s32-diskmodel, whatever the solve's LEDs) they are off by the disks' missed light
    _, points, truth, leds = _surface("cube")
    images = disk_shading(points, truth, leds, DISK_RADIUS) * ALBEDO  # (L, N, 3)
    start = _tilted(truth, 8.0)
    n, rho, changed = _refined(images, points, truth, start, leds, led_radius=DISK_RADIUS)
    assert changed.mean() > 0.99
    assert np.nanmax(angle_deg(n[changed], truth[changed])) < 1e-4
    np.testing.assert_allclose(rho[changed], np.broadcast_to(ALBEDO, rho[changed].shape), rtol=1e-5)
    as_points = _refined(images, points, truth, start, leds)[0]
    assert np.nanmax(angle_deg(as_points, truth)) > 100 * np.nanmax(angle_deg(n[changed], truth[changed]))


def _noisy_sphere():
    """The sphere's exact images with the twin's noise; one pixel in 7 starts 12 deg off (a wall's depth normal)."""
    images, points, truth, leds = _surface("sphere")
    rng = np.random.default_rng(1)
    sigma = 0.02 * float(np.median(images[images > 0]))  # the twin's noise: 2 % of the median level
    noisy = images + rng.normal(0.0, sigma, images.shape)
    start = truth.copy()
    off = np.arange(len(truth)) % 7 == 0
    start[off] = _tilted(truth[off], 12.0)
    return noisy, points, truth, start, off, leds, sigma


def test_a_smooth_surface_keeps_its_normals_where_they_fit_and_is_corrected_where_not():
    noisy, points, truth, start, off, leds, sigma = _noisy_sphere()
    n, _, changed = _refined(noisy, points, truth, start, leds, sigma)
    kept = ~off & ~changed
    assert kept.sum() >= 0.999 * (~off).sum()  # the right normals stay (the gate)
    np.testing.assert_array_equal(n[kept], start[kept].astype(np.float32))
    assert changed[off].mean() > 0.99 and np.mean(angle_deg(n[off], truth[off])) < 1.0


def test_pixels_whose_images_cannot_reject_their_normal_are_not_fitted_and_the_numbers_are_those_of_fitting_all(
    monkeypatch,
):
    noisy, points, truth, start, off, leds, sigma = _noisy_sphere()
    fitted = []
    light_vectors = refine._light_vectors

    def counted(pts, leds_, *radius):
        fitted.append(len(pts))
        return light_vectors(pts, leds_, *radius)

    monkeypatch.setattr(refine, "_light_vectors", counted)
    skipping = _refined(noisy, points, truth, start, leds, sigma)
    assert off.sum() <= sum(fitted) < 0.9 * len(points)  # the 12-deg-off pixels fitted, many others not
    monkeypatch.setattr(refine, "_may_pass_gate", lambda images, *_: np.ones(images.shape[-1], bool))
    every = _refined(noisy, points, truth, start, leds, sigma)
    assert sum(fitted) > len(points)  # ... this time all of them
    for a, b in zip(skipping, every):
        np.testing.assert_array_equal(a, b)


def test_solve_with_refined_normals_keeps_the_depth_and_does_no_harm(presses):
    press = load_press(presses["sphere"])
    plain = solve_press(press, options=SolverOptions(max_iters=20))
    refined = solve_press(press, options=SolverOptions(max_iters=20, normals="refined"))
    assert plain.report["normals"] == "depth" and refined.report["normals"] == "refined"
    np.testing.assert_array_equal(refined.depth, plain.depth)
    gt = press.ground_truth
    a, b = evaluate(plain, gt)["contact"]["aae_deg"], evaluate(refined, gt)["contact"]["aae_deg"]
    assert b <= a + 0.01, (a, b)
    assert refined.report["refined_pixels"] >= 0 and refined.report["refine_seconds"] >= 0


def test_the_option_is_checked():
    with pytest.raises(ConfigError, match="solver.normals"):
        SolverOptions(normals="gradient")


def test_solve_command_writes_which_normals_it_holds(presses, tmp_path):
    press = tmp_path / "sphere"
    shutil.copytree(presses["sphere"], press)
    cfg = tmp_path / "solver.toml"
    cfg.write_text("max_iters = 5\n", encoding="utf-8")
    assert main(["solve", str(press), "--config", str(cfg), "--normals", "refined", "--no-figures"]) == 0
    report = json.loads((press / "nlips" / "report.json").read_text(encoding="utf-8"))
    assert report["normals"] == "refined"
    assert report["provenance"]["settings"]["options"]["normals"] == "refined"
    assert report["provenance"]["settings"]["options"]["max_iters"] == 5  # the config's values kept
