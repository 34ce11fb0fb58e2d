"""Contact classification, anchoring, calibrated LEDs, dead LEDs and unreconstructable captures
(exact-data presses from tests/solver/synth.py)."""

import numpy as np
import pytest

from nlipscalib.cli import main
from nlipscalib.core import Led, load_press
from nlipscalib.errors import CaptureError
from nlipscalib.solver import SolverOptions, evaluate, solve_press
from nlipscalib.solver.contact import classify_contact

from . import synth


@pytest.fixture(scope="module")
def mostly_dent(tmp_path_factory):
    """A 64x64 crop of a 480x360 view centred on a large sphere dent: most of the view is deformed."""
    cam = synth.crop_camera((480, 360), (64, 64), synth.dent_centre())
    folder = synth.make_press(tmp_path_factory.mktemp("crop") / "p", "sphere", depth=2.5, cam=cam)
    return load_press(folder)


def test_a_capture_that_is_mostly_dent_matches_anchoring_off(mostly_dent):
    press = mostly_dent
    gt = press.ground_truth
    assert gt.contact[gt.valid].mean() > 0.8  # the premise: mostly dent
    default = solve_press(press)
    off = solve_press(press, options=SolverOptions(anchor_weight=0.0))
    a, b = evaluate(default, gt)["all"], evaluate(off, gt)["all"]
    # pinned pixels may only be ones the data show undeformed
    assert default.report["anchored_pixels"] <= (gt.valid & ~gt.contact).sum()
    assert a["aae_deg"] <= b["aae_deg"] + 0.05, (a, b)
    assert a["depth_rmse_mm"] <= b["depth_rmse_mm"] + 0.01, (a, b)
    assert "anchor" in default.report["anchoring"]


def test_weak_evidence_means_no_anchoring(presses):
    """LEDs 2 mm off: nothing fits the undeformed model at noise level, so nothing is pinned, and the
    report says why."""
    press = load_press(presses["sphere"])
    wrong = [Led(tuple(np.add(led.position, (2.0, 0, 0))), led.direction, led.mu, led.intensity) for led in press.leds]
    result = solve_press(press, leds=wrong, options=SolverOptions(max_iters=5))
    assert result.report["anchored_pixels"] == 0
    assert result.report["anchoring"].startswith("anchoring off: weak evidence")


def test_calibrated_leds_reach_the_contact_classification(presses):
    """The classification shades with the LEDs the solve uses: with the true LEDs the undeformed gel fits
    at noise level, with 'calibrated' (here: different) LEDs it does not."""
    press = load_press(presses["sphere"])
    gel = np.isfinite(press.reference.depth) & ~press.ground_truth.contact
    true = classify_contact(press)
    moved = [Led(tuple(np.add(led.position, (0.5, 0, 0))), led.direction, led.mu, led.intensity) for led in press.leds]
    other = classify_contact(press, moved)
    assert np.nanmedian(other.misfit[gel]) > 10 * np.nanmedian(true.misfit[gel])
    # and solve_press passes them on: the anchoring decision changes with the LEDs
    r_true = solve_press(press, roi="auto", options=SolverOptions(max_iters=3))
    r_moved = solve_press(press, roi="auto", leds=moved, options=SolverOptions(max_iters=3))
    assert r_true.report["anchored_pixels"] != r_moved.report["anchored_pixels"]


def test_dead_led_with_auto_roi(tmp_path):
    def kill(lin):
        lin = lin.copy()
        lin[4] = 0.0
        return lin

    press = load_press(synth.make_press(tmp_path / "dead", "sphere", lin_hook=kill))
    result = solve_press(press, roi="auto", options=SolverOptions(max_iters=10))
    assert result.report["dead_leds_contact"] == [4] and 4 in result.report["dead_leds"]
    roi = result.report["roi"]
    rows, cols = np.nonzero(press.ground_truth.contact)
    assert roi[0] <= cols.min() and roi[0] + roi[2] > cols.max() and roi[1] <= rows.min()
    assert evaluate(result, press.ground_truth)["contact"]["aae_deg"] < 2.0


def test_nothing_reconstructable_is_an_error_with_the_reason(tmp_path, capsys):
    folder = synth.make_press(tmp_path / "dark", "sphere", lin_hook=lambda lin: np.zeros_like(lin))
    with pytest.raises(CaptureError, match="lit|reconstruct"):
        solve_press(load_press(folder), roi="auto")
    with pytest.raises(CaptureError, match="reconstruct"):
        solve_press(load_press(folder))
    code = main(["solve", str(folder), "--out", str(tmp_path / "out")])
    assert code != 0
    assert "reconstruct" in capsys.readouterr().err


def _direct_shading(press):
    from nlipscalib.core.camera import depth_to_points
    from nlipscalib.core.leds import led_shading

    ref = press.reference
    valid = np.isfinite(ref.depth)
    pts = depth_to_points(np.where(valid, ref.depth, 0.0), press.camera.rays)
    return led_shading(pts, np.where(valid[..., None], ref.normals, 0.0), press.leds).astype(np.float32)


def test_undeformed_light_kept_apart_gives_the_classification_of_the_sum(sphere_press):
    """``undeformed_light`` (smooth at the blur's scale) is added to the smoothed shading, and the read-only
    shading's smoothed copy is reused: both give the misfit of classifying against ``shading + light``."""
    shading = _direct_shading(sphere_press)
    # a positive extra light unlike the shading's shape, smooth (constant per LED and channel: the blur keeps it)
    light = np.broadcast_to(0.2 * shading.mean(axis=(1, 2), keepdims=True), shading.shape).copy()
    summed = classify_contact(sphere_press, undeformed_images=shading + light)
    shading.flags.writeable = False
    first = classify_contact(sphere_press, undeformed_images=shading, undeformed_light=light)
    again = classify_contact(sphere_press, undeformed_images=shading, undeformed_light=light)  # the kept copy
    gel = np.isfinite(summed.misfit)
    np.testing.assert_array_equal(gel, np.isfinite(first.misfit))
    np.testing.assert_allclose(first.misfit[gel], summed.misfit[gel], rtol=1e-4, atol=1e-7)
    np.testing.assert_array_equal(first.misfit, again.misfit)
    # without the light the misfit is another one: the light was not dropped
    plain = classify_contact(sphere_press, undeformed_images=shading)
    assert np.nanmedian(np.abs(plain.misfit - first.misfit)) > 1e-4


def test_misfit_leaves_out_saturated_samples_like_the_plain_sums():
    """The einsum form against the textbook one: per-pixel albedo fitted on usable samples only."""
    from nlipscalib.solver.contact import _misfit

    rng = np.random.default_rng(3)
    S = rng.uniform(0.1, 1.0, (5, 4, 6, 3)).astype(np.float32)
    img = (S * rng.uniform(0.5, 0.9, (1, 4, 6, 3)) + rng.normal(0, 0.01, S.shape)).astype(np.float32)
    ok = rng.random(S.shape) > 0.3
    count = np.maximum(ok.sum((0, 3)), 1)
    alb = (S * img * ok).sum(0) / (S * S * ok).sum(0)
    want = np.sqrt((((alb * S - img) * ok) ** 2).sum((0, 3)) / count)
    np.testing.assert_allclose(_misfit(S, img, ok, count), want, rtol=1e-5)
    full = np.full((4, 6), 15)
    want_all = np.sqrt((((img * S).sum(0) / (S * S).sum(0) * S - img) ** 2).sum((0, 3)) / 15)
    np.testing.assert_allclose(_misfit(S, img, None, full), want_all, rtol=1e-5)
