import json
import shutil

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.errors import CaptureError, ShapeError
from nlipscalib.solver import SolverOptions, evaluate, solve, solve_press

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
    # the prior alone is far off in the contact: the solver did the work
    assert evaluate(_prior_result(press, res), gt)["contact"]["aae_deg"] > 5


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


def test_torch_backend_matches_numpy(sphere_press):
    pytest.importorskip("torch")
    opts = SolverOptions(max_iters=3)
    a = _solve(sphere_press, options=opts)
    b = _solve(sphere_press, options=opts, backend="torch")
    np.testing.assert_allclose(a.depth, b.depth, rtol=1e-6)
    assert np.nanmax(np.abs(a.normals - b.normals)) < 1e-5


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
    meta = json.loads((presses["sphere"] / "meta.json").read_text())
    meta["camera"]["width"] = 100
    wrong = tmp_path / "wrong"
    shutil.copytree(presses["sphere"], wrong)
    (wrong / "meta.json").write_text(json.dumps(meta))
    with pytest.raises(CaptureError, match="camera"):
        load_press(wrong)
