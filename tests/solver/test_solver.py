import json
import re
import shutil

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError, ShapeError
from nlipscalib.core.metrics import evaluate
from nlipscalib.solver import SolverOptions, solve, solve_press

from . import synth

OPTS = SolverOptions(max_iters=20)


def _solve(press, **kw):
    return solve_press(press, options=kw.pop("options", OPTS), **kw)


@pytest.mark.parametrize("kind", ["sphere", "cube"])
def test_exact_data(presses, kind):
    press = load_press(presses[kind])
    res = _solve(press)
    gt = press.ground_truth
    scores = evaluate(res, gt)
    assert scores["all"]["aae_deg"] < 0.5
    assert scores["contact"]["aae_deg"] < 1.5
    m = res.reconstructed & gt.valid
    assert np.mean(np.abs(res.depth[m] - gt.depth[m]) / gt.depth[m]) < 0.01
    assert res.report["pixels_too_few_leds"] == 0 and res.reconstructed.all()
    assert all(np.all(np.diff(lv["energy"]) <= 1e-12 * lv["energy"][0]) for lv in res.report["levels"])
    # smooth indenters' Gauss-Newton models predict their steps' decrease well: no doubled step (the expanding
    # line search is for relief, whose IRLS model is too stiff), so they keep the plain backtracking's bits
    assert all(lv["expanded_steps"] == 0 for lv in res.report["levels"])
    # the prior alone is far off in the contact: the solver did the work
    assert evaluate(_prior_result(press, res), gt)["contact"]["aae_deg"] > 5


def test_same_inputs_give_the_same_bits_whatever_numpys_global_generator_holds(sphere_press):
    """pyamg can draw from NumPy's global generator while building a hierarchy (its spectral radius estimate):
    the solve must not depend on it, and must leave the caller's generator as it found it."""
    opts = SolverOptions(max_iters=20, cg_jacobi_iters=0)  # AMG from the first Gauss-Newton step
    np.random.seed(1)
    a = _solve(sphere_press, options=opts)
    after = np.random.random()
    np.random.seed(2)
    b = _solve(sphere_press, options=opts)
    assert sum(level["amg_setups"] for level in a.report["levels"]) >= 1
    np.testing.assert_array_equal(a.depth, b.depth)
    np.testing.assert_array_equal(a.normals, b.normals)
    np.random.seed(1)
    assert np.random.random() == after  # the solve drew nothing from the caller's generator


def _prior_result(press, res):
    import dataclasses

    return dataclasses.replace(res, normals=press.reference.normals)


def test_roi_and_led_subset(presses):
    press = load_press(presses["sphere"], led_subset=[0, 2, 4, 6, 8, 10])
    gt = press.ground_truth
    rows, cols = np.nonzero(gt.contact)
    roi = (cols.min() - 4, rows.min() - 4, np.ptp(cols) + 9, np.ptp(rows) + 9)
    res = _solve(press, roi=roi)
    assert res.mask.sum() == roi[2] * roi[3]
    assert not res.reconstructed[0, 0] and np.isnan(res.normals[0, 0]).all()
    assert evaluate(res, gt)["contact"]["aae_deg"] < 1.0
    assert res.report["leds_used"] == list(range(6))


@pytest.mark.parametrize("dtype, depth_rtol, normal_atol", [("float64", 1e-6, 1e-5), ("float32", 1e-5, 1e-4)])
def test_torch_backend_matches_numpy(sphere_press, dtype, depth_rtol, normal_atol):
    pytest.importorskip("torch")
    opts = SolverOptions(max_iters=3, dtype=dtype)
    a = _solve(sphere_press, options=opts)
    b = _solve(sphere_press, options=opts, backend="torch")
    np.testing.assert_allclose(a.depth, b.depth, rtol=depth_rtol)
    assert np.nanmax(np.abs(a.normals - b.normals)) < normal_atol


def test_float32_matches_float64(sphere_press):
    a = _solve(sphere_press, options=SolverOptions(max_iters=20, dtype="float64"))
    b = _solve(sphere_press, options=SolverOptions(max_iters=20, dtype="float32"))
    m = a.reconstructed & b.reconstructed
    assert np.max(np.abs(a.depth[m] - b.depth[m]) / a.depth[m]) < 1e-4
    ang = _angles_deg(a.normals[m], b.normals[m])  # float32 output normals resolve ~0.02 deg near 0
    assert ang.mean() < 0.005 and ang.max() < 0.05


def _angles_deg(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(a * b, -1), -1, 1)))


@pytest.mark.parametrize("roi", ["contact", (30, 20, 40, 40)])
def test_roi_agrees_with_whole_image(sphere_press, roi):
    """A region of interest is the same problem on fewer pixels: on exact data its depth and normals
    must be the whole image's. (Alternating albedo and depth updates once left small ROIs hundreds of
    iterations from convergence along the depth scale the albedo absorbs: 0.8 deg, 3 % depth here.)"""
    press = sphere_press
    if roi == "contact":
        rows, cols = np.nonzero(press.ground_truth.contact)
        roi = (cols.min() - 4, rows.min() - 4, np.ptp(cols) + 9, np.ptp(rows) + 9)
    full = _solve(press)
    part = _solve(press, roi=roi)
    m = part.reconstructed
    assert m.sum() == roi[2] * roi[3]
    ang = _angles_deg(part.normals[m], full.normals[m])
    rel = np.abs(part.depth[m] - full.depth[m]) / full.depth[m]
    # what remains is the discretisation at the ROI's edge (one-sided differences there, central
    # ones in the whole image) on this coarse 96x72 image
    assert ang.mean() < 0.1 and np.percentile(ang, 95) < 0.3
    assert np.median(rel) < 1.5e-3 and rel.max() < 3e-3
    assert evaluate(part, press.ground_truth)["all"]["depth_rmse_mm"] < 0.03


def test_robustness_noise_shadow_saturation_dead_led(tmp_path):
    rng = np.random.default_rng(0)

    def corrupt(lin):
        lin = lin * (1 + 0.01 * rng.standard_normal(lin.shape)) + 0.002 * rng.standard_normal(lin.shape)
        lin[3] = 0.0  # dead LED
        lin[0, 10:25, 5:20] *= 0.001  # a cast shadow in LED 1
        lin[5, 40:44, 60:64] = 2.0  # saturated spot in LED 6
        lin[:, 30:32, 70:72] = 0.0  # dead pixels
        return np.maximum(lin, 0)

    folder = synth.make_press(tmp_path / "p", "sphere", lin_hook=corrupt, exposure=None)
    press = load_press(folder)
    res = _solve(press)
    rep = res.report
    assert rep["dead_leds"] == [3]
    assert rep["saturated_samples"] >= 16 * 3
    assert rep["shadow_samples"] > 0
    assert rep["dead_pixels"] == 4
    assert not res.reconstructed[30:32, 70:72].any() and rep["pixels_too_few_leds"] >= 4
    assert evaluate(res, press.ground_truth)["all"]["aae_deg"] < 2.0
    assert res.usable_leds[40, 60] <= 10 and res.usable_leds[50, 50] == 11


def test_too_few_leds_reported_not_filled(tmp_path):
    def darken(lin):
        lin[2:, 20:30, 20:30] = 0.0  # only LEDs 1-2 light this block
        return lin

    press = load_press(synth.make_press(tmp_path / "p", "none", lin_hook=darken))
    res = _solve(press, options=SolverOptions(max_iters=3))
    block = np.zeros(press.camera.shape, bool)
    block[20:30, 20:30] = True
    assert res.report["pixels_too_few_leds"] == 100
    assert np.isnan(res.depth[block]).all() and not res.reconstructed[block].any()
    assert (res.confidence[block] == 0).all() and (res.confidence[~block] > 0).all()


def test_bad_inputs(presses, sphere_press, tmp_path):
    p = sphere_press
    imgs = p.linear(p.led_images)
    with pytest.raises(ShapeError, match="NaN"):
        bad = imgs.copy()
        bad[0, 0, 0, 0] = np.nan
        solve(bad, p.camera, p.leds)
    with pytest.raises(ShapeError, match="LED images but"):
        solve(imgs[:5], p.camera, p.leds)
    with pytest.raises(ShapeError, match="must be"):
        solve(imgs[:, :10], p.camera, p.leds)
    with pytest.raises(ShapeError, match="prior_depth"):
        solve(imgs, p.camera, p.leds, prior_depth=np.ones((3, 3)))
    with pytest.raises(ShapeError, match="roi"):
        solve_press(p, roi=(90, 0, 20, 20))
    # missing LED image and wrong metadata: the capture loader names the file
    broken = tmp_path / "broken"
    shutil.copytree(presses["sphere"], broken)
    (broken / "led_03.png").unlink()
    with pytest.raises(CaptureError, match="led_03.png"):
        load_press(broken)
    meta = json.loads((presses["sphere"] / "meta.json").read_text(encoding="utf-8"))
    meta["camera"]["width"] = 100
    wrong = tmp_path / "wrong"
    shutil.copytree(presses["sphere"], wrong)
    (wrong / "meta.json").write_text(json.dumps(meta), encoding="utf-8")
    with pytest.raises(CaptureError, match="camera"):
        load_press(wrong)


def test_an_undeformed_capture_of_another_sensor_is_refused(tmp_path):
    """The same camera and LED count are not enough: LEDs 1.5 mm / 10 deg elsewhere (another dome's ring) or
    another undeformed surface make it another sensor, named in one line; the same sensor passes."""
    import dataclasses

    from nlipscalib.core.leds import led_geometry_mismatch

    press = load_press(synth.make_press(tmp_path / "press", "sphere"))
    same = load_press(synth.make_press(tmp_path / "same", "none"))
    moved = tuple(dataclasses.replace(led, position=(led.position[0] * 1.17, *led.position[1:])) for led in press.leds)
    other = load_press(synth.make_press(tmp_path / "other", "none", leds=moved))
    solve_press(press, roi=(20, 15, 24, 24), indirect=same, max_outer=0)  # the same sensor: accepted
    with pytest.raises(CaptureError, match=r"other: not a capture of the sensor of .*press \(LED 1 is 1\.53 mm"):
        solve_press(press, roi=(20, 15, 24, 24), indirect=other)
    assert led_geometry_mismatch([[0, 0, 0]], [[0, 0, 1]], [[0.4, 0, 0]], [[0, 0.05, 0.9987]]) is None  # within
    turned = led_geometry_mismatch([[0, 0, 0]], [[0, 0, 1]], [[0, 0, 0]], [[0, 0.0872, 0.9962]])  # 5 deg
    assert turned == "LED 1 is 0.00 mm and 5.0 deg from its counterpart"


@pytest.mark.parametrize("workers", [1, 2])
def test_the_entry_check_finds_a_non_finite_value_in_any_leds_image_on_one_or_two_threads(workers):
    """check_inputs checks the LEDs' images on the thread pool (one task per LED): a NaN or inf in the last LED's
    image, or in the first's, is found on one thread and on two, and the message counts every one of them."""
    from nlipscalib.solver import threads
    from nlipscalib.solver.inputs import check_inputs

    cam = synth.camera(12, 10)
    leds = synth.ring_leds()
    images = np.full((len(leds), 10, 12, 3), 0.5, np.float32)
    before = threads.workers()
    threads.set_workers(workers)
    try:
        assert check_inputs(images, cam, leds, None, None, None, SolverOptions())[0] is images
        for where in [(-1, 9, 11, 2), (0, 0, 0, 0)]:
            bad = images.copy()
            bad[where] = np.inf
            bad[1, 3, 4, 1] = np.nan
            with pytest.raises(ShapeError, match="images contain 2 NaN/inf values"):
                check_inputs(bad, cam, leds, None, None, None, SolverOptions())
    finally:
        threads.set_workers(before)


def test_normals_of_a_shaded_depth_reuse_its_gradient_to_the_bit(sphere_press, monkeypatch):
    """A level's normals at its start and at each accepted step come from the gradient its shading took (two sparse
    products fewer per step): the same bits as the normals computed from the depth again."""
    from nlipscalib.solver import gauss_newton, operators

    calls = []
    gradient = operators.log_depth_gradient

    def counted(ops, t):
        calls.append(1)
        return gradient(ops, t)

    # the level's shading takes it (gauss_newton), and so do normals from a depth (operators.depth_normals)
    monkeypatch.setattr(gauss_newton, "log_depth_gradient", counted)
    monkeypatch.setattr(operators, "log_depth_gradient", counted)
    reused = _solve(sphere_press)
    reused_calls = len(calls)
    calls.clear()
    normals = operators.depth_normals
    monkeypatch.setattr(gauss_newton._Level, "normals", lambda self, tt: normals(self.ops, tt, self.A, self.B, self.C))
    again = _solve(sphere_press)
    steps = sum(len(level["normal_change_deg"]) + 1 for level in again.report["levels"])  # the start and each step
    assert len(calls) - reused_calls == steps
    np.testing.assert_array_equal(reused.depth, again.depth)
    np.testing.assert_array_equal(reused.normals, again.normals)


def test_the_too_few_leds_warning_names_the_press_and_counts_in_words(tmp_path, caplog):
    """In a batch the warning "1 pixels have fewer than 3 usable LEDs" named no press, and one pixel was plural."""
    import logging

    def saturate_one_pixel(lin):
        lin = lin.copy()
        lin[:10, 20, 30, :] = 5.0  # saturated in 10 of the 12 LED images: 2 usable LEDs there
        return lin

    folder = synth.make_press(tmp_path / "p", "sphere", size=(64, 48), lin_hook=saturate_one_pixel)
    caplog.set_level(logging.WARNING)
    res = _solve(load_press(folder), options=SolverOptions(max_iters=3))
    assert res.report["pixels_too_few_leds"] == 1
    warned = [r.getMessage() for r in caplog.records if "usable LEDs" in r.getMessage()]
    assert warned == [f"{folder}: 1 pixel has fewer than 3 usable LEDs: not reconstructed (NaN)"]
    caplog.clear()  # the outer interreflection loop's passes: once, of the result (it was once per pass)
    res = _solve(load_press(folder), options=SolverOptions(max_iters=3), interreflection="on")
    assert res.report["pixels_too_few_leds"] == 1 and res.report["outer_passes"] > 0, res.report.get("outer_passes")
    assert sum("usable LEDs" in r.getMessage() for r in caplog.records) == 1


def test_the_progress_line_names_the_level_and_counts_iterations_without_a_false_eta(sphere_press, as_terminal):
    """The bar ran to levels x max_iters; levels stop on convergence long before, so it ended at 3-10 % with an
    ETA of tens of seconds (a 1280x960 whole frame showed "1/30 [00:01<00:36]" and finished in 19 s). On a terminal:
    elsewhere no bar is drawn (tests/solver/test_press.py)."""
    terminal = as_terminal()
    res = _solve(sphere_press, progress=True)
    shown = terminal.getvalue().replace("\r", "\n")
    last = [
        line for line in shown.splitlines() if re.match(r"NLiPs level (\d+) of \1 \(\d+x\d+\): \d+ iterations", line)
    ]
    assert last, shown
    assert int(last[-1].split(": ")[1].split()[0]) > 0 and res.report["levels"][-1]["iterations"] > 0
    assert "%" not in shown and "<" not in shown and "it/s" not in shown, shown


def test_a_warm_started_finest_level_takes_its_first_step_tighter_by_amg(sphere_press, monkeypatch):
    """The outer loop's last pass starts the finest level from a solved depth: its first linear solve is to
    krylov.WARM_FIRST_RTOL by AMG (not the forcing term's cap by Jacobi), except on a level of WARM_FIRST_MAX_ROWS
    rows or more; a solve from the prior keeps the forcing term's first step."""
    from nlipscalib.solver import krylov

    p = sphere_press
    images = p.led_images
    prior = p.reference.depth
    cold = solve(images, p.camera, p.leds, prior_depth=prior, options=OPTS)
    first = cold.report["levels"][0]
    assert first["cg_rtol"][0] == OPTS.cg_rtol_max
    start = np.where(cold.reconstructed, prior + 0.5 * (cold.depth - prior), np.nan)  # half-way: steps to take
    warm = solve(images, p.camera, p.leds, prior_depth=prior, options=OPTS, init_depth=start)
    (level,) = warm.report["levels"]
    assert level["cg_rtol"][0] == krylov.WARM_FIRST_RTOL
    assert level["amg_setups"] >= 1 and len(level["cg_rtol"]) >= 2
    assert evaluate(warm, p.ground_truth)["contact"]["aae_deg"] < 1.5
    monkeypatch.setattr(krylov, "WARM_FIRST_MAX_ROWS", level["pixels"])  # as a whole 640x480 frame's level
    large = solve(images, p.camera, p.leds, prior_depth=prior, options=OPTS, init_depth=start)
    assert large.report["levels"][0]["cg_rtol"][0] == OPTS.cg_rtol_max
