"""Interreflection in the image model, on the digital twin (Mitsuba renders, CI-sized: 160x120).

Known answers: the twin's coating reflectance is 0.8 and one bounce adds ~31 % light on the default scene;
a render without bounces has none, whatever its albedo texture. Those answers hold for the exact NLiPs image
model, so these tests render the ideal scene (``nlipstac_ideal``: point LEDs, ideal camera); on the default
scene's extended LEDs the fit sees a 0.85 reflectance and a 1.4 % share in a bounce-0 capture.
"""

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from nlipscalib.core import load_press  # noqa: E402
from nlipscalib.core.metrics import evaluate  # noqa: E402
from nlipscalib.sim.indent import PressConfig  # noqa: E402
from nlipscalib.sim.indenters import IndenterConfig  # noqa: E402
from nlipscalib.sim.press import render_press  # noqa: E402
from nlipscalib.sim.scene import load_scene  # noqa: E402
from nlipscalib.solver import SolverOptions, solve_press  # noqa: E402
from nlipscalib.solver.indirect import fit_indirect  # noqa: E402

from .twin_helpers import contact_box, dimmed_copy, perturbed  # noqa: E402

SPHERE = PressConfig(IndenterConfig(kind="sphere", size=6.0), polar_deg=15, azimuth_deg=30, depth=1.5)


def scene(bounces, spp, noise, variation=0.0):
    return load_scene("nlipstac_ideal").replace(
        noise={"enabled": noise},
        render={"bounces": bounces, "spp": spp},
        camera={"width": 160, "height": 120},
        coating={"variation": variation},
    )


@pytest.fixture(scope="module")
def bounce1(tmp_path_factory):
    """One bounce, 16 spp, sensor noise: the undeformed dome and a sphere press."""
    root = tmp_path_factory.mktemp("ir_b1")
    sc = scene(1, 16, True)
    flat = load_press(render_press(sc, None, root / "flat", seed=3))
    press = load_press(render_press(sc, SPHERE, root / "sphere", seed=4))
    return flat, press


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    """No bounce, a +-5 % albedo texture: the undeformed dome and a sphere press."""
    root = tmp_path_factory.mktemp("ir_tex")
    sc = scene(0, 4, False, variation=0.05)
    flat = load_press(render_press(sc, None, root / "flat", seed=5))
    press = load_press(render_press(sc, SPHERE, root / "sphere", seed=6))
    return flat, press


def test_fit_recovers_the_coating_reflectance_and_the_share(bounce1):
    flat, _ = bounce1
    model = fit_indirect(flat)
    assert model.enabled
    np.testing.assert_allclose(model.reflectance, 0.8, atol=0.03)  # the twin's coating
    assert 0.25 < model.share < 0.37, model.share  # ~31 % measured by bounces-1 over bounces-0 renders


def test_a_warm_refit_lands_where_a_longer_cold_one_does(bounce1):
    """A press's refit without its contact starts from its rough fit (``warm``) and alternates
    ``REFIT_ALTERNATIONS`` times: within 1e-6 of the fixed point, as three alternations from kappa = 0 (the refit
    before), nearer than that many from kappa = 0."""
    from nlipscalib.solver.light_and_contact import REFIT_ALTERNATIONS

    _, press = bounce1
    exclude = np.zeros(press.camera.shape, bool)
    exclude[40:80, 60:110] = True
    cache = {}
    rough = fit_indirect(press, iterations=1, cache=cache)
    warm = fit_indirect(press, exclude=exclude, cache=cache, iterations=REFIT_ALTERNATIONS, warm=True)

    def cold(iterations: int, **kwargs):
        return fit_indirect(press, exclude=exclude, iterations=iterations, **kwargs).kappa

    converged = np.asarray(cold(8))

    def off(kappa) -> float:
        return float(np.abs(np.divide(kappa, converged) - 1).max())

    assert off(warm.kappa) < 1e-6 and off(cold(3)) < 1e-6
    assert off(warm.kappa) < off(cold(REFIT_ALTERNATIONS))
    assert off(rough.kappa) > 10 * off(warm.kappa)  # the premise: the rough fit is off
    assert cold(3, cache={}, warm=True) == cold(3)  # with no earlier fit in its cache a warm fit is the cold one


def test_an_explicit_box_over_most_of_the_gel_is_fitted_as_the_whole_gel(bounce1):
    """Without an undeformed capture the press's own fit leaves an explicit box out; a box over the whole frame
    left nothing to fit on ("no usable pixel to fit the interreflection term on") and one over all but a ring of
    patches fitted the term on that ring alone. Both are now fitted as the whole gel is (away from the contact
    found): the whole-frame box solves to the whole gel's arrays, and the ring box gets the whole gel's term; a box
    around the contact still leaves it out (its own fit, another kappa)."""
    from nlipscalib.core import tolerances
    from nlipscalib.solver.roi import box_mask

    _, press = bounce1
    H, W = press.camera.shape
    fast = SolverOptions(max_iters=5)
    whole = solve_press(press, options=fast)
    boxed = solve_press(press, roi=(0, 0, W, H), options=fast)
    for name, a in whole.arrays().items():
        np.testing.assert_array_equal(getattr(boxed, name), a, err_msg=name)
    ring = (4, 4, W - 8, H - 8)  # leaves one ring of the fit's 4-pixel patches
    from nlipscalib.solver.indirect import fit_patch_share  # after the whole-frame box: what failed before it

    share = fit_patch_share(press, press.leds, box_mask(ring, (H, W)))
    assert 0 < share < tolerances.INDIRECT_FIT_MIN_SHARE, share  # the premise: a few patches left
    kappa = whole.report["interreflection"]["kappa"]
    assert solve_press(press, roi=ring, options=SolverOptions(max_iters=1)).report["interreflection"]["kappa"] == kappa
    around = solve_press(press, roi=contact_box(press.ground_truth.contact), options=SolverOptions(max_iters=1))
    assert around.report["interreflection"]["kappa"] != kappa


def test_fit_patch_share_counts_the_patches_left_to_fit_on(bounce1):
    from nlipscalib.solver.indirect import fit_patch_share

    _, press = bounce1
    H, W = press.camera.shape
    none, every = np.zeros((H, W), bool), np.ones((H, W), bool)
    half = none.copy()
    half[:, : W // 2] = True  # the fit's patches are 4 pixels: half of them, the gel's edge alike on both sides
    assert fit_patch_share(press, press.leds, none) == 1.0
    assert fit_patch_share(press, press.leds, every) == 0.0
    assert fit_patch_share(press, press.leds, half) == pytest.approx(0.5, abs=0.02)


def test_fit_finds_no_interreflection_in_a_textured_bounce0_capture(textured):
    flat, _ = textured
    model = fit_indirect(flat)
    assert not model.enabled, model.reason
    assert model.share < 0.01


def test_interreflection_aware_solve_beats_the_plain_solve_in_the_contact(bounce1):
    flat, press = bounce1
    roi = contact_box(press.ground_truth.contact)
    plain = evaluate(solve_press(press, roi=roi, interreflection="off"), press.ground_truth)["contact"]
    # with the undeformed capture, and from the press alone (the term fitted away from its contact)
    for indirect in (flat, None):
        result = solve_press(press, roi=roi, indirect=indirect)
        aware = evaluate(result, press.ground_truth)["contact"]
        assert result.report["interreflection"]["enabled"]
        assert result.report["outer_passes"] >= 1
        assert aware["aae_deg"] < 0.5 * plain["aae_deg"], (plain, aware)
        assert aware["aae_deg"] < 2.5, aware


def test_a_whole_frame_solves_the_passes_before_the_last_around_the_dent(bounce1):
    """Away from the dent the light changes little between passes: on a whole frame only the last pass
    solves every pixel, and the contact comes out as with an ROI around it."""
    _, press = bounce1
    gt = press.ground_truth
    whole = solve_press(press)
    x0, y0, w, h = whole.report["outer_focus"]
    rows, cols = np.nonzero(gt.contact)
    assert x0 <= cols.min() and cols.max() < x0 + w and y0 <= rows.min() and rows.max() < y0 + h
    assert w * h < 0.5 * whole.mask.sum() and whole.report["outer_passes"] >= 2
    assert whole.reconstructed[whole.mask].all()  # the last pass solved the whole mask
    roi = solve_press(press, roi=contact_box(gt.contact))
    assert roi.report["outer_focus"] is None  # an ROI around the contact is its own focus
    a, b = (evaluate(r, gt)["contact"]["aae_deg"] for r in (whole, roi))
    assert a < 2.5 and abs(a - b) < 0.3, (a, b)
    away = solve_press(press, roi=(0, 0, 60, 38))  # an ROI that misses the contact: nothing to focus on
    assert away.report["outer_focus"] is None and away.reconstructed[away.mask].all()


def test_auto_leaves_a_textured_bounce0_capture_unharmed(textured):
    flat, press = textured
    roi = contact_box(press.ground_truth.contact)
    off = evaluate(solve_press(press, roi=roi, interreflection="off"), press.ground_truth)["contact"]["aae_deg"]
    for indirect in (flat, None):
        result = solve_press(press, roi=roi, indirect=indirect)  # auto by default
        assert not result.report["interreflection"]["enabled"]
        auto = evaluate(result, press.ground_truth)["contact"]["aae_deg"]
        assert abs(auto - off) <= 0.05, (off, auto)


def test_a_coating_albedo_with_the_term_off_is_reported_not_dropped(textured, caplog):
    _, press = textured
    roi = contact_box(press.ground_truth.contact)
    with caplog.at_level("WARNING", logger="nlipscalib"):
        given = solve_press(press, roi=roi, coating_albedo=0.8, options=SolverOptions(max_iters=3))
    assert not given.report["interreflection"]["enabled"]
    assert "--coating-reflectance not used: interreflection off" in caplog.text
    plain = solve_press(press, roi=roi, options=SolverOptions(max_iters=3))
    np.testing.assert_array_equal(given.normals, plain.normals)  # what the warning says: nothing changed


def test_led_calibration_on_an_interreflecting_capture(bounce1):
    """Acceptance: on a bounces-1 + noise capture of the undeformed dome, LED directions within 2 deg,
    positions within 0.3 mm, and NLiPs with the calibrated LEDs within 0.3 deg of NLiPs with the true ones."""
    from nlipscalib.solver import calibrate_leds

    flat, press = bounce1
    true = flat.leds
    # every pixel: at 160x120 the stride-2 sample leaves 2.06 deg on one LED (1.73 with all pixels)
    cal = calibrate_leds(flat, initial=perturbed(true, np.random.default_rng(0)), stride=1)
    assert cal.interreflection and cal.interreflection[0]["enabled"]
    for led, t in zip(cal.leds, true):
        assert np.degrees(np.arccos(min(1.0, np.dot(led.direction, t.direction)))) <= 2.0
        assert np.linalg.norm(np.subtract(led.position, t.position)) <= 0.3
    roi = contact_box(press.ground_truth.contact)
    a = evaluate(solve_press(press, roi=roi, indirect=flat), press.ground_truth)["contact"]["aae_deg"]
    b = evaluate(solve_press(press, roi=roi, indirect=flat, leds=cal.leds), press.ground_truth)["contact"]["aae_deg"]
    assert abs(a - b) <= 0.3, (a, b)


def test_relaxation_is_one_over_one_plus_the_indirect_share():
    from nlipscalib.solver.outer_loop import _relaxation

    direct = np.random.default_rng(0).uniform(0.2, 1.0, (4, 3, 5, 3)).astype(np.float32)
    g = np.linspace(0.0, 1.0, 15).reshape(3, 5)
    light = direct * g[None, ..., None]
    omega = _relaxation((direct + light).sum(axis=(0, 3)), light)
    np.testing.assert_allclose(omega[0, ..., 0], 1.0 / (1.0 + g), rtol=1e-5)


def test_the_outer_loops_normal_change_is_exact_on_float32_normals():
    """A pass's median normal change is compared with OUTER_TOL_DEG (0.05 deg): arccos of a float32 cosine was
    off by up to ~0.02 deg there."""
    from types import SimpleNamespace

    from nlipscalib.solver.outer_loop import _median_change_deg

    rng = np.random.default_rng(4)
    a = rng.normal(size=(40, 50, 3)) * [0.3, 0.3, 1] - [0, 0, 3]
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    turn = np.radians(0.01)  # about y: every normal in the x-z plane turns by 0.01 deg; the others by less
    c, s = np.cos(turn), np.sin(turn)
    b = np.stack([c * a[..., 0] + s * a[..., 2], a[..., 1], -s * a[..., 0] + c * a[..., 2]], -1)
    exact = np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), (a * b).sum(-1)))
    rec = np.ones(a.shape[:2], bool)
    first = SimpleNamespace(normals=a.astype(np.float32), reconstructed=rec)
    second = SimpleNamespace(normals=b.astype(np.float32), reconstructed=rec)
    assert _median_change_deg(first, second, rec) == pytest.approx(np.median(exact), abs=1e-4)


def test_the_relaxed_outer_loop_settles_where_the_plain_one_oscillates(bounce1):
    """The plain iteration alternates around its answer (the subtracted light feeds back through the
    albedo); the per-pixel relaxation lands near the fixed point in two passes."""
    _, press = bounce1
    roi = contact_box(press.ground_truth.contact)
    plain = solve_press(press, roi=roi, max_outer=2, outer_relaxation=1.0)
    relaxed = solve_press(press, roi=roi, max_outer=2)
    fixed = solve_press(press, roi=roi, max_outer=8, outer_relaxation=1.0)
    assert relaxed.report["outer_changes_deg"][-1] < 0.5 * plain.report["outer_changes_deg"][-1]

    def aae(result):
        return evaluate(result, press.ground_truth)["contact"]["aae_deg"]

    assert abs(aae(relaxed) - aae(fixed)) < abs(aae(plain) - aae(fixed)), (aae(plain), aae(relaxed), aae(fixed))


def test_outer_relaxation_out_of_range_is_a_config_error(bounce1):
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError, match="outer_relaxation"):
        solve_press(bounce1[1], outer_relaxation=3.0)


def test_a_whole_frames_gathers_before_the_last_pass_light_the_focus_only(bounce1, monkeypatch):
    """The passes before the last solve the dent's focus alone: their gathers compute the light there only; the
    last gather lights the whole mask (and the surface it reads is the one before, the focus recomputed). The
    first pass subtracts the fit's light of the undeformed dome: no gather before it."""
    from nlipscalib.solver import outer_loop as loop_module  # the gathers' caller

    _, press = bounce1
    receivers = []
    gather = loop_module.surface_indirect

    def spy(*args, **kwargs):
        receivers.append(args[6].copy())
        return gather(*args, **kwargs)

    monkeypatch.setattr(loop_module, "surface_indirect", spy)
    whole = solve_press(press, max_outer=2)
    x0, y0, w, h = whole.report["outer_focus"]
    mask = whole.mask
    focus_gather, last = receivers  # one gather per outer pass
    assert last.sum() == mask.sum()
    assert focus_gather.sum() == mask[y0 : y0 + h, x0 : x0 + w].sum() < 0.5 * mask.sum()


def test_the_outer_loops_first_light_is_the_fits_light_cut_to_the_box(bounce1):
    """The first pass subtracts the fit's undeformed light times the fit's typical albedo: on the mask's box the
    same numbers as the whole frame's upsampled light cut to it, zero off the mask; it agrees with a gather of
    the undeformed surface on the loop's finer patches to a per cent. One LED per pool task: the same bits on one
    thread and on two."""
    from nlipscalib.solver import threads
    from nlipscalib.solver.indirect import surface_indirect
    from nlipscalib.solver.outer_loop import _first_light

    flat, press = bounce1
    model = fit_indirect(flat, mode="on")
    ref = press.reference
    valid = np.isfinite(ref.depth)
    H, W = press.camera.shape
    whole = model.undeformed_light((H, W)) * np.asarray(model.off_view_albedo, np.float32)
    albedo = np.broadcast_to(np.asarray(model.off_view_albedo), (H, W, 3))
    for y0, y1, x0, x1 in ((22, 47, 31, 58), (0, H, 0, W), (50, H, 100, W), (3, 9, 5, 17)):
        box = (slice(y0, y1), slice(x0, x1))
        mask = np.zeros((H, W), bool)
        mask[box] = True
        mask &= valid
        mask[(y0 + y1) // 2, x0:x1] = False  # pixels of the box off the mask: their light is 0
        expected = np.where(mask[box][None, ..., None], whole[:, box[0], box[1]], 0.0)
        before = threads.workers()
        try:
            for count in (1, 2):
                threads.set_workers(count)
                light = _first_light(model, mask, box)
                assert light.dtype == np.float32 and light.shape == (len(press.leds), y1 - y0, x1 - x0, 3)
                np.testing.assert_array_equal(light, expected)
        finally:
            threads.set_workers(before)
    light = _first_light(model, valid, (slice(0, H), slice(0, W)))
    gathered = surface_indirect(model, press.camera, press.leds, ref.depth, ref.normals, albedo, valid)
    np.testing.assert_allclose(light[:, valid], gathered[:, valid], rtol=0.01)


def test_the_light_outside_the_focus_catches_up_on_the_updates_it_missed():
    """At the last gather, the pixels outside the focus take one relaxed update per focus pass they missed,
    with that gather's light; the focus takes one."""
    from nlipscalib.solver.outer_loop import OuterLoop, _relaxation

    rng = np.random.default_rng(2)
    H, W = 6, 8
    loop = object.__new__(OuterLoop)
    loop.box, loop.relaxation = (slice(1, 5), slice(1, 7)), "auto"
    loop.focus = np.zeros((H, W), bool)
    loop.focus[2:4, 3:5] = True
    loop.image_total = rng.uniform(5.0, 9.0, (4, 6))
    light = rng.uniform(0.0, 1.0, (2, 4, 6, 3)).astype(np.float32)
    gathered = rng.uniform(0.0, 1.0, (2, 4, 6, 3)).astype(np.float32)

    def step(values):
        return np.maximum(values + _relaxation(loop.image_total, values) * (gathered - values), 0.0)

    once, twice = step(light), step(step(light))
    out = loop._update(light.copy(), gathered, loop.box, None, missed=1)
    inside = loop.focus[loop.box]
    np.testing.assert_array_equal(out[:, inside], once[:, inside])
    np.testing.assert_array_equal(out[:, ~inside], twice[:, ~inside])


def test_the_outer_loops_update_by_blocks_of_rows_has_the_bits_of_the_whole_window_at_once():
    """:meth:`OuterLoop._update` runs by blocks of rows on the thread pool (per pixel): a focus pass's update and
    the last pass's catching up give the bits of the same updates on the whole arrays, on one thread or several."""
    from nlipscalib.solver import threads
    from nlipscalib.solver.outer_loop import UPDATE_ROWS, OuterLoop, _slices
    from nlipscalib.solver.roi import box_of

    rng = np.random.default_rng(5)
    H, W, L = 7 * UPDATE_ROWS, 50, 3
    loop = object.__new__(OuterLoop)
    loop.box, loop.relaxation = (slice(2, H - 3), slice(1, W - 2)), "auto"
    h, w = H - 5, W - 3
    loop.focus = np.zeros((H, W), bool)
    loop.focus[20:70, 10:30] = True
    loop.focus[40:45, 12:14] = False  # a focus that does not fill its box
    loop.image_total = rng.uniform(0.5, 9.0, (h, w))
    light = rng.uniform(0.0, 3.0, (L, h, w, 3)).astype(np.float32)
    window = _slices(box_of(loop.focus))
    in_focus = rng.uniform(0.0, 3.0, (L, window[0].stop - window[0].start, window[1].stop - window[1].start, 3))
    whole = rng.uniform(0.0, 3.0, (L, h, w, 3)).astype(np.float32)

    def at_once(values, gathered, rows, cols, where):
        new = loop._relaxed(values[:, rows, cols], gathered, loop.image_total[rows, cols])
        np.copyto(values[:, rows, cols], new, where=where)

    expected = light.copy()
    rows, cols = slice(window[0].start - 2, window[0].stop - 2), slice(window[1].start - 1, window[1].stop - 1)
    at_once(expected, in_focus.astype(np.float32), rows, cols, loop.focus[window][None, ..., None])
    focus_pass = expected.copy()
    all_rows, all_cols = slice(0, h), slice(0, w)
    at_once(expected, whole, all_rows, all_cols, True)
    for _ in range(2):
        at_once(expected, whole, all_rows, all_cols, ~loop.focus[loop.box][None, ..., None])
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            got = loop._update(light.copy(), in_focus.astype(np.float32), window, loop.focus, 0)
            np.testing.assert_array_equal(got, focus_pass)
            np.testing.assert_array_equal(loop._update(got, whole, loop.box, None, 2), expected)
    finally:
        threads.set_workers(before)
    assert not np.array_equal(focus_pass, light) and not np.array_equal(expected, focus_pass)


def test_the_box_compensation_is_the_whole_frames_on_one_thread_and_on_two():
    """The outer loop's compensated images: the images minus the light given on the mask's box (zero outside it),
    clipped at 0, as ``compensate`` of the whole frame (held as one box of it, a FrameBox); a focus pass rewrites
    its receivers' box only, and a first call for a focus leaves the images themselves on the rest of the box. One
    LED per pool task: the same bits on one thread and on two."""
    from nlipscalib.solver import threads
    from nlipscalib.solver.interreflection import compensate
    from nlipscalib.solver.outer_loop import BoxCompensation

    rng = np.random.default_rng(3)
    L, H, W = 3, 9, 12
    images = rng.uniform(0.0, 1.0, (L, H, W, 3)).astype(np.float32)
    mask = np.zeros((H, W), bool)
    mask[2:7, 3:10] = True
    light = rng.uniform(0.0, 1.0, (L, 5, 7, 3)).astype(np.float32)  # on the box; above the images in places
    frame_light = np.zeros_like(images)
    frame_light[:, 2:7, 3:10] = light
    receivers = np.zeros((H, W), bool)
    receivers[3:5, 4:6] = True
    focus_light = rng.uniform(0.0, 1.0, light.shape).astype(np.float32)
    expected = compensate(images, frame_light)
    after_focus = expected.copy()
    after_focus[:, 3:5, 4:6] = compensate(images[:, 3:5, 4:6], focus_light[:, 1:3, 1:3])
    assert (expected == 0).any() and not np.array_equal(after_focus, expected)
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            boxed = BoxCompensation(images, mask)
            np.testing.assert_array_equal(boxed(light).whole(), expected)
            np.testing.assert_array_equal(boxed(focus_light, receivers).whole(), after_focus)
            first_a_focus = BoxCompensation(images, mask)(focus_light, receivers)  # the box's rest: the images
            expected_focus = images.copy()
            expected_focus[:, 3:5, 4:6] = after_focus[:, 3:5, 4:6]
            np.testing.assert_array_equal(first_a_focus.whole(), expected_focus)
    finally:
        threads.set_workers(before)


def test_the_gathers_filled_albedo_is_the_whole_frames_on_one_thread_and_on_two():
    """``outer_loop._filled_albedo`` (the solved albedo, its per-channel median where not reconstructed; medians and
    filling on the pool) gives the bits of ``np.where`` with ``np.median(axis=0)``, on one thread and on two, an
    even count of reconstructed pixels (a median between two values) included; nothing reconstructed: the
    fallback."""
    from types import SimpleNamespace

    from nlipscalib.solver import threads
    from nlipscalib.solver.outer_loop import FILL_ROWS, _filled_albedo

    rng = np.random.default_rng(6)
    albedo = rng.lognormal(0.0, 1.0, (2 * FILL_ROWS + 9, 31, 3)).astype(np.float32)
    rec = rng.uniform(size=albedo.shape[:2]) < 0.7
    rec.flat[np.flatnonzero(rec)[0]] ^= bool(rec.sum() % 2)  # an even count
    albedo[~rec] = np.nan
    fallback = np.array([0.1, 0.2, 0.3])
    expected = np.where(rec[..., None], albedo, np.median(albedo[rec], axis=0))
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            got = _filled_albedo(SimpleNamespace(reconstructed=rec, albedo=albedo), fallback)
            assert got.dtype == np.float32 and got.tobytes() == expected.tobytes()
            none = _filled_albedo(SimpleNamespace(reconstructed=np.zeros_like(rec), albedo=albedo), fallback)
            assert np.array_equal(none, np.broadcast_to(fallback, albedo.shape))
    finally:
        threads.set_workers(before)


def test_a_press_with_every_led_dimmer_than_the_undeformed_capture_solves_as_captured(bounce1, tmp_path):
    """Every LED 10 % dimmer than at the undeformed capture (aged LEDs): the albedo takes the scale, but the
    indirect term fitted on that capture kept its brightness. Whole frame, before the gain: gel AAE 0.53 -> 3.1
    deg, contact depth RMSE 0.019 -> 0.21 mm, no warning. Now the term is scaled by the measured gain (in the
    report), the depth is the as-captured press's, and the warning names LED ageing and the remedy."""
    flat, press = bounce1
    as_captured = solve_press(press, indirect=flat)
    dimmed = dimmed_copy(press, tmp_path / "dimmed", 0.9)
    aged = solve_press(dimmed, indirect=flat)
    gain = np.asarray(aged.report["reference_gain"])
    assert np.allclose(gain, 0.9, atol=0.005), gain
    assert np.allclose(as_captured.report["reference_gain"], 1.0, atol=0.005)
    both = aged.reconstructed & as_captured.reconstructed
    assert np.median(np.abs(aged.depth - as_captured.depth)[both]) < 0.005  # before: ~0.2 mm
    assert evaluate(aged, dimmed.ground_truth)["all"]["aae_deg"] < 1.0  # before: 3.1
    said = [note for note in aged.report["warnings"] if "LEDs aged" in note]
    assert len(said) == 1 and "0.90/0.90/0.90 times" in said[0] and "fresh capture of the undeformed dome" in said[0]
    assert not any("LEDs aged" in note for note in as_captured.report.get("warnings", []))
    assert as_captured.report["led_gains"] is None  # within noise: the images as captured


def test_a_press_with_one_led_group_dimmer_than_the_undeformed_capture_solves_as_captured(bounce1, tmp_path):
    """The first LED group (LEDs 1-4) 10 % dimmer than at the undeformed capture, the others not (LEDs aged on their
    own): no global gain, so the model misfit every pixel those LEDs light, only warned about (the twin's 640x480
    sphere press: contact AAE 0.50 -> 4.8 deg, depth 0.49 mm off). The solve now measures each LED's gain on the
    gel, rescales those images (report.json ``led_gains``), and the warning names them and the lasting fix."""
    flat, press = bounce1
    as_captured = solve_press(press, indirect=flat)
    group = np.where(np.arange(len(press.leds)) < 4, 0.9, 1.0)
    red_aged = dimmed_copy(press, tmp_path / "red_aged", group)
    aged = solve_press(red_aged, indirect=flat)
    gains = np.median(aged.report["led_gains"], axis=1)
    assert np.allclose(gains, group, atol=0.01), gains
    assert np.allclose(aged.report["reference_gain"], 1.0, atol=0.01)
    both = aged.reconstructed & as_captured.reconstructed
    # before: 0.38 mm and a gel AAE of 6.5 deg; now 0.005 mm and 0.51 deg (0.51 as captured): the rescaled images
    # weigh those LEDs' residuals by 1 / 0.9, not a bit-identical solve as a global gain's
    assert np.median(np.abs(aged.depth - as_captured.depth)[both]) < 0.02
    assert evaluate(aged, red_aged.ground_truth)["all"]["aae_deg"] < 1.0
    said = [note for note in aged.report["warnings"] if "rescaled these LED images" in note]
    assert len(said) == 1 and "LED 1 (led_01.png) 0.90" in said[0] and "LED 5" not in said[0]
    assert "nlips calibrate-leds" in said[0]
