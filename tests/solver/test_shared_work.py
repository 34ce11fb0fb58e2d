"""Work shared or skipped for speed gives the same numbers as the plain computation (known answers:
each shortcut against the computation it replaces, on exact-data presses from tests/solver/synth.py)."""

import numpy as np
import pytest

from nlipscalib.core import load_press, masks
from nlipscalib.core.errors import ConfigError
from nlipscalib.core.metrics import evaluate
from nlipscalib.solver import SolverOptions, reuse, solve, threads
from nlipscalib.solver.contact import classify_contact
from nlipscalib.solver.image_stats import led_levels
from nlipscalib.solver.indirect import Surface, direct_shading, fit_indirect, surface_digest
from nlipscalib.solver.samples import exclusions

from . import synth


@pytest.fixture(scope="module")
def press(tmp_path_factory):
    return load_press(synth.make_press(tmp_path_factory.mktemp("shared") / "p", "sphere", size=(96, 72)))


def test_a_replaced_surface_equals_a_new_surface_of_the_changed_geometry(press):
    ref = press.reference
    gt = press.ground_truth
    changed = np.zeros(press.camera.shape, bool)
    changed[20:45, 30:61] = True
    changed &= gt.valid
    depth = np.where(changed, gt.depth, ref.depth)
    normals = np.where(changed[..., None], gt.normals, ref.normals)
    base = Surface(press.camera, press.leds, ref.depth, ref.normals, size=4)
    fast = base.replaced(depth, normals, changed)
    fresh = Surface(press.camera, press.leds, depth, normals, size=4)
    for key in ("points", "normals", "area", "pixel_area"):
        np.testing.assert_allclose(fast.patches[key], fresh.patches[key], rtol=1e-12, atol=1e-12, err_msg=key)
    np.testing.assert_allclose(fast.shading, fresh.shading, rtol=1e-12, atol=1e-15)
    assert np.array_equal(fast.keep, fresh.keep)
    assert not np.allclose(base.shading, fresh.shading)  # the premise: the change shows in the patches


@pytest.mark.parametrize("size", [4, 5])
def test_a_replaced_surface_by_bands_is_the_one_bands_bit_for_bit(press, monkeypatch, size):
    """``Surface.replaced`` works by bands of patch rows on the pool (:data:`indirect.REPLACED_PATCH_ROWS`): every
    array of the new surface is the same, bit for bit, as with one band over the whole box; 5 px patches do not
    tile the 96x72 frame (a short last band), and the box leaves the frame's first rows and columns as they were."""
    from nlipscalib.solver import indirect

    ref, gt = press.reference, press.ground_truth
    changed = np.zeros(press.camera.shape, bool)
    changed[13:, 22:70] = True
    changed &= gt.valid
    base = Surface(press.camera, press.leds, ref.depth, ref.normals, size=size)

    def arrays(rows: int) -> list[bytes]:
        monkeypatch.setattr(indirect, "REPLACED_PATCH_ROWS", rows)
        new = base.replaced(gt.depth, gt.normals, changed)
        parts = [new.valid, new.depth, new.normals, new.shading, new.keep]
        return [
            np.ascontiguousarray(a).tobytes()
            for a in parts + [new.patches[k] for k in sorted(new.patches) if k != "size"]
        ]

    one = arrays(1000)
    assert arrays(1) == one and arrays(3) == one
    assert one[3] != base.shading.tobytes()  # the premise: the shading changed


@pytest.mark.parametrize("size", [4, 5])
def test_the_gels_albedo_and_its_patch_means_by_bands_are_the_whole_frames(press, size):
    """``indirect._gel_albedo`` (the outer loop's albedo and its patch means, by bands of patch rows on the pool)
    gives the whole frame's numbers bit for bit, NaN read as 0 and 0 off the gel; 5 px patches do not tile the
    96x72 frame (padded last band)."""
    from nlipscalib.solver import radiosity
    from nlipscalib.solver.indirect import _gel_albedo

    ref = press.reference
    depth = ref.depth.copy()
    depth[:, :7] = np.nan  # off the gel
    surface = Surface(press.camera, press.leds, depth, ref.normals, size=size)
    albedo = np.random.default_rng(1).uniform(0.2, 1.0, press.camera.shape + (3,))
    albedo[10:14, 20:30] = np.nan
    clean, means = _gel_albedo(surface, albedo)
    whole = np.where(surface.valid[..., None], np.nan_to_num(albedo), 0.0)
    assert clean.tobytes() == whole.tobytes() and (~surface.valid).any() and not np.isnan(clean).any()
    assert means.tobytes() == radiosity.patch_mean(surface.patches, whole).tobytes()


def test_direct_shading_is_the_led_image_model(press):
    from nlipscalib.core.camera import depth_to_points
    from nlipscalib.core.leds import led_shading

    ref = press.reference
    valid = np.isfinite(ref.depth)
    expected = led_shading(depth_to_points(np.where(valid, ref.depth, 0.0), press.camera.rays), ref.normals, press.leds)
    expected[:, ~valid] = 0.0
    np.testing.assert_allclose(direct_shading(press.camera, press.leds, ref.depth, ref.normals), expected, rtol=1e-12)


def test_a_refit_with_a_shared_cache_equals_a_fresh_fit(press):
    exclude = np.zeros(press.camera.shape, bool)
    exclude[25:40, 35:55] = True
    cache = {}
    fit_indirect(press, mode="on", iterations=1, cache=cache)  # the rough fit fills the cache
    shared = fit_indirect(press, mode="on", exclude=exclude, cache=cache)
    fresh = fit_indirect(press, mode="on", exclude=exclude)
    np.testing.assert_allclose(shared.kappa, fresh.kappa, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(shared.fitted_light[0], fresh.fitted_light[0], rtol=1e-6, atol=1e-12)


def test_a_second_classification_with_a_cache_equals_a_fresh_one(press):
    cache = {}
    classify_contact(press, cache=cache)
    moved = [
        type(led)(tuple(np.add(led.position, (0.3, 0, 0))), led.direction, led.mu, led.intensity) for led in press.leds
    ]
    shared = classify_contact(press, moved, cache=cache)
    fresh = classify_contact(press, moved)
    np.testing.assert_allclose(shared.misfit, fresh.misfit, rtol=1e-12, equal_nan=True)
    assert shared.noise == fresh.noise and shared.live_leds == fresh.live_leds


def test_led_levels_find_a_dead_led(press):
    lin = press.linear(press.led_images).copy()
    lin[3] = 0.0
    levels = led_levels(lin, np.isfinite(press.reference.depth))
    assert levels[3] < 1e-3 and (np.delete(levels, 3) > 0.1).all()


def test_led_levels_of_read_only_images_are_kept_per_mask(press):
    """The levels of a press's read-only linear images are worked out once per mask (the indirect fit and the
    contact classification both ask): a second mask gets its own, writable images are read anew."""
    lin = press.linear(press.led_images).copy()
    lin.flags.writeable = False
    gel = np.isfinite(press.reference.depth)
    half = gel.copy()
    half[:, : gel.shape[1] // 2] = False
    first = led_levels(lin, gel)
    assert led_levels(lin, gel) is first  # kept
    np.testing.assert_array_equal(led_levels(lin, half), led_levels(lin.copy(), half))
    assert not np.array_equal(led_levels(lin, half), first)  # the premise: the mask matters
    writable = lin.copy()
    before = led_levels(writable, gel)
    writable[3] = 0.0
    assert led_levels(writable, gel)[3] < before[3]


def test_surface_digest_is_the_digest_and_follows_writable_arrays(press):
    ref = press.reference
    assert not ref.depth.flags.writeable and not ref.normals.flags.writeable  # a loaded reference is read-only
    assert surface_digest(ref.depth, ref.normals) == reuse.digest(ref.depth, ref.normals)
    assert surface_digest(ref.depth, ref.normals) == reuse.digest(ref.depth, ref.normals)  # kept
    normals = np.array(ref.normals)
    first = surface_digest(ref.depth, normals)
    normals[10, 10] = (0.0, 0.0, 1.0)
    assert surface_digest(ref.depth, normals) == reuse.digest(ref.depth, normals) != first


def test_exclusions_on_a_crop_equal_the_whole_images_cropped(press):
    lin = press.linear(press.led_images).astype(np.float32)
    sat = press.saturated(press.led_images)
    crop = (slice(10, 50), slice(20, 70))
    whole, _ = exclusions(lin, sat, SolverOptions())
    part, _ = exclusions(lin[:, crop[0], crop[1]], sat[:, crop[0], crop[1]], SolverOptions(), whole=lin)
    assert np.array_equal(part, whole[:, crop[0], crop[1]])


def test_exclusions_by_row_blocks_are_the_whole_arrays_rule(press):
    """Usable samples and counts, computed by row blocks on the pool: the rule on the whole arrays."""
    lin = press.linear(press.led_images).astype(np.float32)
    lin[:, 5, 7] = 0.0  # a dead pixel
    sat = press.saturated(press.led_images)
    sat[2, 30:33, 40:44, 1] = True
    opts = SolverOptions()
    before = threads.workers()
    for count in (1, 2):
        threads.set_workers(count)
        try:
            for saturated in (sat, None):
                usable, report = exclusions(lin, saturated, opts)
                marked = np.zeros(lin.shape, bool) if saturated is None else saturated
                index = np.flatnonzero(masks.sample_grid(np.ones(lin.shape[1:3], bool)))
                shadow_level = opts.shadow_level * np.percentile(lin.reshape(len(lin), -1, 3)[:, index], 99, axis=1)
                dead = lin.max(axis=(0, 3)) <= opts.dead_pixel_level
                shadow = lin < shadow_level[:, None, None, :]
                assert report["dead_pixels"] == int(dead.sum()) >= 1
                assert report["saturated_samples"] == int(marked.sum())
                assert report["shadow_samples"] == int((shadow & ~marked).sum())
                expected = ~marked & ~shadow & ~dead[None, :, :, None]
                expected[report["dead_leds"]] = False
                assert np.array_equal(usable, expected)
        finally:
            threads.set_workers(before)


def test_the_exclusions_bright_ends_per_led_on_the_pool_are_the_stacks_percentiles(press):
    """exclusions' thresholds, the 99th percentiles of each LED image (over pixels and channels, and per channel)
    taken one LED per pool task: the bits of the percentiles along the axes of the whole sampled stack, on one
    thread and on two, in float32 and in float64."""
    from nlipscalib.solver.samples import _bright_ends

    lin = press.linear(press.led_images).astype(np.float32)
    lin[3] *= 0.25  # LEDs of different brightness: a swapped result would show
    index = np.flatnonzero(masks.sample_grid(np.ones(lin.shape[1:3], bool)))
    before = threads.workers()
    try:
        for dtype in (np.float32, np.float64):
            sample = lin.reshape(len(lin), -1, 3)[:, index].astype(dtype)
            # NumPy < 2 takes float32 percentiles in float64: the function returns them rounded to ``dtype``
            per_led = np.percentile(sample.reshape(len(lin), -1), 99, axis=1).astype(dtype)
            per_channel = np.percentile(sample, 99, axis=1).astype(dtype)
            for count in (1, 2):
                threads.set_workers(count)
                got_led, got_channel = _bright_ends(lin, dtype)
                assert got_led.dtype == got_channel.dtype == dtype
                np.testing.assert_array_equal(got_led, per_led)
                np.testing.assert_array_equal(got_channel, per_channel)
    finally:
        threads.set_workers(before)
    assert per_led[3] < 0.5 * per_led[2]


def test_the_kappa_search_per_channel_on_the_pool_has_the_same_bits_on_one_thread_and_on_two():
    """_profile_kappa searches its three channels one per pool task: the same bits on one thread and on two; each
    channel finds the kappa its data were made with (img = rho (S + kappa G) exactly), and a channel with no
    usable patch gets 0."""
    from nlipscalib.solver.indirect import _profile_kappa

    rng = np.random.default_rng(7)
    L, K = 12, 300
    S = rng.uniform(0.5, 1.5, (L, K, 3))
    G = rng.uniform(0.1, 0.4, (L, K, 3))
    rho = rng.uniform(0.6, 0.9, (1, K, 3))
    truth = np.array([0.3, 0.5, 0.7])
    img = rho * (S + truth * G)
    ok = np.ones((L, K, 3), bool)
    ok[:, :, 2] = False  # no data in the last channel
    before = threads.workers()
    try:
        got = []
        for count in (1, 2):
            threads.set_workers(count)
            got.append(_profile_kappa(img, S, G, ok, kappa_max=2.0))
    finally:
        threads.set_workers(before)
    np.testing.assert_array_equal(got[0], got[1])
    np.testing.assert_allclose(got[0][:2], truth[:2], rtol=1e-3)
    assert got[0][2] == 0.0


def test_the_kappa_search_ends_at_the_gains_maximum_and_at_zero_without_indirect_light():
    """_profile_kappa's Newton finish: on noisy data the kappa it returns is where the profiled gain is largest (no
    kappa 1e-4 either side gains more, and Newton's next step from it is below 1e-9 of it; the grid
    search it replaced stopped 0.2-3e-6 away on the twin's presses); with images whose best kappa would be negative
    the gain falls from kappa = 0 on and the search returns 0 exactly."""
    from nlipscalib.solver.indirect import _profile_gain, _profile_kappa, _profile_slopes

    rng = np.random.default_rng(11)
    L, K = 12, 400
    S = rng.uniform(0.5, 1.5, (L, K, 3))
    G = rng.uniform(0.1, 0.4, (L, K, 3))
    rho = rng.uniform(0.6, 0.9, (1, K, 3))
    img = rho * (S + np.array([0.02, 0.3, 0.6]) * G) * rng.normal(1.0, 0.01, (L, K, 3))
    ok = rng.uniform(size=(L, K, 3)) > 0.05
    ok[:, :7] = False  # patches with no usable sample at all
    kappa = _profile_kappa(img, S, G, ok)
    w = ok.astype(float)
    for ch in range(3):
        sums = [(w * x * y).sum(0)[:, ch] for x, y in ((img, S), (img, G), (S, S), (S, G), (G, G))]
        near = kappa[ch] * np.array([1 - 1e-4, 1.0, 1 + 1e-4])
        gain = _profile_gain(*sums, near, np.empty((K, 3)), np.empty((K, 3)))
        assert gain[1] >= gain[0] and gain[1] >= gain[2], ch
        live = [x[sums[2] > 0] for x in sums]
        slope, curvature = _profile_slopes(*live, kappa[ch])
        assert curvature < 0 and abs(slope / curvature) < 1e-9 * kappa[ch], ch  # Newton's next step: ~0
    assert np.all(np.abs(kappa - [0.02, 0.3, 0.6]) < 0.05)
    less = rho * (S - 0.1 * G)  # the best kappa would be negative
    assert np.array_equal(_profile_kappa(less, S, G, np.ones((L, K, 3), bool)), [0, 0, 0])


def test_a_warm_start_from_the_solution_stays_there(press):
    lin = press.linear(press.led_images)
    prior = press.reference.depth
    first = solve(lin, press.camera, press.leds, prior_depth=prior)
    warm = solve(lin, press.camera, press.leds, prior_depth=prior, init_depth=first.depth)
    assert len(warm.report["levels"]) == 1  # the finest level only
    gt = press.ground_truth
    a, b = evaluate(first, gt)["all"], evaluate(warm, gt)["all"]
    assert b["aae_deg"] <= a["aae_deg"] + 0.01, (a, b)


def test_a_pass_without_the_finest_level_is_close_and_a_warm_start_refines_it(press):
    """The outer interreflection loop's passes before the last stop at the next-to-finest level: the finest
    level is only evaluated there, near the full solve; the last pass, from that depth, solves the finest level."""
    lin = press.linear(press.led_images)
    prior = press.reference.depth
    two = SolverOptions(pyramid_levels=2)
    full = solve(lin, press.camera, press.leds, prior_depth=prior, options=two)
    rough = solve(lin, press.camera, press.leds, prior_depth=prior, options=two, unrefined=1)
    levels = rough.report["levels"]
    assert len(levels) >= 2 and levels[-1]["iterations"] == 0 and levels[-2]["iterations"] > 0
    refined = solve(lin, press.camera, press.leds, prior_depth=prior, options=two, init_depth=rough.depth)
    assert refined.report["levels"][-1]["iterations"] > 0
    # a warm start left unrefined (an outer pass before the last): the next coarser level from it, no pre-solve
    again = solve(lin, press.camera, press.leds, prior_depth=prior, init_depth=rough.depth, unrefined=1)
    levels = again.report["levels"]
    assert len(levels) == 2 and levels[0]["shape"] != levels[1]["shape"]
    assert levels[0]["estimator"] == "cauchy" and levels[0]["iterations"] > 0 and levels[1]["iterations"] == 0
    gt = press.ground_truth
    a, b, c, d = (evaluate(r, gt)["all"]["aae_deg"] for r in (full, rough, refined, again))
    assert b < a + 2.0 and d < a + 2.0, (a, b, d)  # near the answer already, not at the prior
    assert c <= a + 0.01, (a, c)


def test_two_unrefined_levels_skip_the_one_between_and_stay_near_the_answer(press):
    """An outer pass before the last on a large image leaves two levels unrefined: the level between the
    finest iterated one and the finest is not built, the finest is only evaluated, from cold and warm starts."""
    lin = press.linear(press.led_images)
    prior = press.reference.depth
    three = SolverOptions(pyramid_levels=3)
    full = solve(lin, press.camera, press.leds, prior_depth=prior, options=three)
    rough = solve(lin, press.camera, press.leds, prior_depth=prior, options=three, unrefined=2)
    every = [tuple(lv["shape"]) for lv in full.report["levels"]]  # coarse to fine (the first twice: a pre-solve)
    coarse, between, finest = every[0], every[-2], every[-1]
    shapes = [tuple(lv["shape"]) for lv in rough.report["levels"]]
    assert between not in shapes and shapes[-1] == finest and coarse in shapes, (every, shapes)
    assert rough.report["levels"][-1]["iterations"] == 0
    assert all(lv["iterations"] > 0 for lv in rough.report["levels"][:-1])
    warm = solve(lin, press.camera, press.leds, prior_depth=prior, init_depth=rough.depth, unrefined=2)
    levels = warm.report["levels"]
    assert [tuple(lv["shape"]) for lv in levels] == [coarse, finest], levels
    assert levels[0]["iterations"] > 0 and levels[1]["iterations"] == 0
    gt = press.ground_truth
    a, b, c = (evaluate(r, gt)["all"]["aae_deg"] for r in (full, rough, warm))
    assert b < a + 2.0 and c < a + 2.0, (a, b, c)
    with pytest.raises(ConfigError, match="unrefined"):
        solve(lin, press.camera, press.leds, prior_depth=prior, unrefined=-1)


def test_an_unrefined_finest_level_runs_no_model_and_brings_up_the_coarser_levels_fit(press, monkeypatch):
    """A pass left unrefined brings its finest level up from the finest iterated one: no model is made on it (its
    albedo fit cost 0.65 s of CPU per 640x480 pass), its depth is the coarser one's brought up, its normals that
    depth's, its albedo the coarser level's brought up (the image's albedo is uniform here: near it)."""
    from nlipscalib.solver import gauss_newton, kernel

    sizes = []
    plain = kernel.make_model

    def counted(be, q, *args):
        sizes.append(q.shape[0])
        return plain(be, q, *args)

    monkeypatch.setattr(gauss_newton, "make_model", counted)
    lin = press.linear(press.led_images)
    two = SolverOptions(pyramid_levels=2)
    rough = solve(lin, press.camera, press.leds, prior_depth=press.reference.depth, options=two, unrefined=1)
    finest = rough.report["levels"][-1]
    assert finest["stop"] == "brought_up" and finest["iterations"] == 0 and finest["pixels"] not in sizes
    assert finest["shape"] == list(press.camera.shape) and all(n < finest["pixels"] for n in sizes)
    rec = rough.reconstructed
    assert rec.sum() == finest["pixels"] - rough.report["pixels_no_gradient"] - rough.report["pixels_too_few_leds"]
    # the normals are the brought-up depth's: unit, facing the camera, near the truth (the dent included)
    n = rough.normals[rec]
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-5)
    assert evaluate(rough, press.ground_truth)["all"]["aae_deg"] < 5.0
    # the albedo: finite on every reconstructed pixel, the mask's edge too (the coarse mask leaves it out)
    assert np.isfinite(rough.albedo[rec]).all() and (rough.albedo[rec] > 0).all()
    full = solve(lin, press.camera, press.leds, prior_depth=press.reference.depth, options=two)
    both = rec & full.reconstructed
    np.testing.assert_allclose(np.median(rough.albedo[both], axis=0), np.median(full.albedo[both], axis=0), rtol=0.02)


def test_the_finest_levels_operators_made_ahead_on_a_thread_are_made_once_and_give_the_same_bits(press, monkeypatch):
    """A pass left unrefined makes its finest level's operators on a thread of its own while the coarser level is
    solved (:func:`operators.operators_ahead`): once, and the same result as on one core, where they are made in
    place; not again when this process keeps them."""
    import threading

    from nlipscalib.solver import operators

    made = []
    make = operators._make_operators

    def recorded(mk, **kw):
        made.append((int(mk.sum()), threading.current_thread().name))
        return make(mk, **kw)

    monkeypatch.setattr(operators, "_make_operators", recorded)
    lin = press.linear(press.led_images)
    two = SolverOptions(pyramid_levels=2)
    finest = int(np.isfinite(press.reference.depth).sum())
    before = threads.workers()
    results = {}
    try:
        for count in (1, 2):
            threads.set_workers(count)
            reuse.clear()
            made.clear()
            results[count] = solve(
                lin, press.camera, press.leds, prior_depth=press.reference.depth, options=two, unrefined=1
            )
            where = [name for n, name in made if n == finest]
            assert len(where) == 1, made
            assert where[0].startswith("nlips-operators") == (count == 2), where
        made.clear()
        solve(lin, press.camera, press.leds, prior_depth=press.reference.depth, options=two, unrefined=1)
        assert made == []  # kept: nothing made, ahead or in place
    finally:
        threads.set_workers(before)
    for key in ("depth", "normals", "albedo", "confidence"):
        np.testing.assert_array_equal(results[1].arrays()[key], results[2].arrays()[key], err_msg=key)


def test_a_pass_whose_finest_level_is_iterated_later_makes_its_assembler_ahead(press, monkeypatch):
    """``solve(..., unrefined=1, finest_later=True)`` (the outer loop's first pass on the whole mask) makes the
    finest level's normal-matrix assembler on the operators' thread beside the solve; without ``finest_later`` (a
    focus pass, whose finest level is only brought up) none is made. The results are the same bits either way."""
    import threading

    from nlipscalib.solver import operators

    made = []
    make = operators._normal_matrix

    def recorded(ops, mk, fixed=False):
        made.append((int(mk.sum()), threading.current_thread().name))
        return make(ops, mk, fixed)

    monkeypatch.setattr(operators, "_normal_matrix", recorded)
    lin = press.linear(press.led_images)
    two = SolverOptions(pyramid_levels=2)
    finest = int(np.isfinite(press.reference.depth).sum())
    before = threads.workers()
    results = {}
    try:
        threads.set_workers(2)
        for later in (True, False):
            reuse.clear()
            made.clear()
            results[later] = solve(
                lin,
                press.camera,
                press.leds,
                prior_depth=press.reference.depth,
                options=two,
                unrefined=1,
                finest_later=later,
            )
            for thread in threading.enumerate():  # the operators' thread ends with its tasks
                if thread.name.startswith("nlips-operators"):
                    thread.join(10)
            assert [name for n, name in made if n == finest] == (["nlips-operators_0"] if later else []), made
    finally:
        threads.set_workers(before)
        reuse.clear()
    for key in ("depth", "normals", "albedo", "confidence"):
        np.testing.assert_array_equal(results[True].arrays()[key], results[False].arrays()[key], err_msg=key)


def test_a_level_made_ahead_has_its_difference_operators_before_its_assembler_and_the_same_matrix(monkeypatch):
    """:func:`operators.operators_ahead` with ``assembler`` makes the level's normal-matrix assembler after its
    difference operators, on the same thread: the level's operators are there while the assembler is still being made
    (the bringing up needs no assembler), and its first assembly waits for it and gives the bits of one made in place.
    Without ``assembler`` (a level only brought up) it is made at its first assembly, once, and never if none comes."""
    import threading
    import time

    from nlipscalib.solver import operators

    mask = np.ones((40, 50), bool)
    mask[12:17, 20:31] = False
    release = threading.Event()
    make = operators._normal_matrix
    made = []

    def held(*args, **kwargs):
        made.append(threading.current_thread().name)
        assert release.wait(10)  # the level's operators are asked for first: held, they would wait here
        return make(*args, **kwargs)

    monkeypatch.setattr(operators, "_normal_matrix", held)
    n = int(mask.sum())
    rng = np.random.default_rng(3)
    M = rng.normal(size=(3, 3, n))
    M = np.einsum("abn,cbn->acn", M, M)
    weights = (rng.uniform(0.1, 1.0, n), 0.5)
    before = threads.workers()
    try:
        threads.set_workers(2)
        found = {}
        for assembler in (True, False):
            reuse.clear()
            made.clear()
            release.clear()
            lv = {"mask": mask}
            operators.operators_ahead(lv, assembler=assembler)
            ops = operators.level_operators(lv)  # returns while the assembler is held (or not asked for)
            assert not release.is_set()
            if assembler:  # the operators' thread on to its second task (a loaded machine may not have started it)
                deadline = time.monotonic() + 120
                while not made and time.monotonic() < deadline:
                    time.sleep(0.01)
            release.set()
            if not assembler:
                assert made == []  # nothing asked for it yet
            found[assembler] = ops["normal"].assemble(M, weights)
            ops["normal"].assemble(M, weights)
            assert len(made) == 1 and made[0].startswith("nlips-operators" if assembler else "MainThread"), made
    finally:
        threads.set_workers(before)
        release.set()
        reuse.clear()
    expected = make(operators._make_operators(mask), mask).assemble(M, weights)
    for H in found.values():
        for name in ("data", "indices", "indptr"):
            np.testing.assert_array_equal(getattr(H, name), getattr(expected, name))


def test_values_brought_up_to_a_finer_mask_interpolate_and_reach_its_edge():
    """:func:`coarse_to_fine._upsampled`: bilinear inside the coarse mask (a constant stays that constant, the same as
    cv2's resize of the whole field), the fine mask's edge from its valid coarse neighbours (no NaN, no zeros
    pulled in from off the mask), NaN only where the coarse level has no value at all."""
    from nlipscalib.solver.coarse_to_fine import _upsampled
    from nlipscalib.solver.pyramid import resize

    fine = np.zeros((40, 48), bool)
    fine[5:35, 7:44] = True
    coarse = resize(fine.astype(np.float32), (20, 24)) > 0.999
    cover = resize(coarse.astype(np.float32), fine.shape, linear=True)
    assert (fine & (cover < 0.5)).any()  # the premise: the fine mask's edge interpolates mostly off the coarse mask
    const = np.full((int(coarse.sum()), 3), [0.5, 0.25, 2.0])
    np.testing.assert_allclose(_upsampled(const, coarse, fine), np.broadcast_to([0.5, 0.25, 2.0], (fine.sum(), 3)))
    ramp = np.add.outer(np.arange(20.0), 2 * np.arange(24.0))
    got = _upsampled(ramp[coarse], coarse, fine)
    inner = cover > 0.999  # fine pixels whose coarse neighbours are all on the coarse mask
    np.testing.assert_allclose(got[inner[fine]], resize(ramp, fine.shape, linear=True)[inner & fine], rtol=1e-6)
    assert np.isfinite(got).all() and got.min() >= ramp[coarse].min() - 1e-9
    some = ramp[coarse].copy()
    some[::3] = np.nan  # missing values are filled from their neighbours, not spread
    assert np.isfinite(_upsampled(some, coarse, fine)).all()
    assert np.isnan(_upsampled(np.full(int(coarse.sum()), np.nan), coarse, fine)).all()


def test_the_outer_passes_leave_unrefined_the_levels_finer_than_half_a_patch():
    from nlipscalib.core.camera import Camera
    from nlipscalib.solver.outer_loop import _unrefined_levels

    def camera(w, h):
        return Camera(width=w, height=h, fx=w, fy=w, cx=w / 2, cy=h / 2)

    assert [_unrefined_levels(camera(w, h)) for w, h in ((160, 120), (320, 240), (640, 480), (1280, 960))] == [
        1,
        1,
        2,
        3,
    ]


def test_a_pass_on_the_dent_replaces_the_whole_frame_result_there_only(press):
    from nlipscalib.solver.roi import merge_focus

    lin = press.linear(press.led_images)
    prior = press.reference.depth
    whole = solve(lin, press.camera, press.leds, prior_depth=prior)
    focus = np.zeros(press.camera.shape, bool)
    focus[20:45, 30:61] = True
    part = solve(0.9 * lin, press.camera, press.leds, prior_depth=prior, mask=focus, init_depth=whole.depth)
    merged = merge_focus(whole, part, focus)
    for name in ("depth", "normals", "albedo", "confidence", "reconstructed"):
        got, a, b = getattr(merged, name), getattr(whole, name), getattr(part, name)
        np.testing.assert_array_equal(got[focus], b[focus], err_msg=name)
        np.testing.assert_array_equal(got[~focus], a[~focus], err_msg=name)
    assert not np.allclose(whole.albedo[focus], part.albedo[focus])  # the pass did change the focus
    assert merged.mask is whole.mask and merged.report["pixels_solved"] == whole.report["pixels_solved"]
    assert merged.report["pixels_reconstructed"] == int(merged.reconstructed.sum()) == int(whole.mask.sum())


def test_threads_keep_the_order_and_cover_every_item():
    assert threads.map_items(lambda x: x * x, range(7)) == [x * x for x in range(7)]
    parts = threads.chunks(10, 3)
    assert [i for s in parts for i in range(10)[s]] == list(range(10))
    assert threads.chunks(1, 4) == [slice(0, 1)]


def test_the_indirect_light_at_a_receiver_does_not_depend_on_the_other_receivers(press):
    """surface_indirect gathers and upsamples around the receivers only: a box of receivers gets the
    same light as the whole gel, cut to the box."""
    from nlipscalib.solver.indirect import IndirectModel, surface_indirect

    model = IndirectModel((0.01, 0.01, 0.01), (0.8, 0.8, 0.8), 0.3, 1, True, "test")
    ref = press.reference
    valid = np.isfinite(ref.depth)
    albedo = np.full(press.camera.shape + (3,), 80.0)
    box = np.zeros(press.camera.shape, bool)
    box[22:47, 31:58] = True
    box &= valid
    whole = surface_indirect(model, press.camera, press.leds, ref.depth, ref.normals, albedo, valid, size=4)
    part = surface_indirect(model, press.camera, press.leds, ref.depth, ref.normals, albedo, box, size=4)
    assert whole[:, box].min() > 0  # the premise: light everywhere in the box
    np.testing.assert_allclose(part[:, box], whole[:, box], rtol=1e-6)
    assert not part[:, ~box].any()


def test_the_indirect_light_on_a_window_is_the_whole_frames_cut_to_it(press):
    """surface_indirect(window=...) (the outer loop's box) returns the whole frame's light cut to the window, the
    same numbers; a window that leaves out a receiver is refused."""
    from nlipscalib.solver.indirect import IndirectModel, surface_indirect

    model = IndirectModel((0.01, 0.01, 0.01), (0.8, 0.8, 0.8), 0.3, 1, True, "test")
    ref = press.reference
    box = np.zeros(press.camera.shape, bool)
    box[22:47, 31:58] = True
    box &= np.isfinite(ref.depth)
    albedo = np.full(press.camera.shape + (3,), 80.0)

    def light(window=None):
        cam, leds = press.camera, press.leds
        return surface_indirect(model, cam, leds, ref.depth, ref.normals, albedo, box, size=4, window=window)

    whole = light()
    for window in ((slice(22, 47), slice(31, 58)), (slice(20, 60), slice(0, 96))):
        np.testing.assert_array_equal(light(window), whole[:, window[0], window[1]])
    with pytest.raises(ValueError, match="receiver"):
        light((slice(22, 40), slice(31, 58)))


def test_the_indirect_light_per_led_on_the_pool_has_the_same_bits_on_one_thread_and_on_two(press):
    """surface_indirect scales, masks and writes its upsampled light one LED per pool task: the same bits on one
    thread and on two, with an albedo that varies per pixel and a window that cuts the patches' window."""
    from nlipscalib.solver.indirect import IndirectModel, surface_indirect

    model = IndirectModel((0.01, 0.02, 0.015), (0.8, 0.8, 0.8), 0.3, 1, True, "test")
    ref = press.reference
    receivers = np.zeros(press.camera.shape, bool)
    receivers[20:50, 30:61] = True
    receivers[33, 35:50] = False  # receivers that do not fill their box: the pixels between get no light
    receivers &= np.isfinite(ref.depth)
    albedo = np.random.default_rng(4).uniform(60.0, 90.0, press.camera.shape + (3,))
    window = (slice(20, 50), slice(30, 61))  # inside the patch window (one patch of margin): cut on every side
    before = threads.workers()
    try:
        got = []
        for count in (1, 2):
            threads.set_workers(count)
            got.append(
                surface_indirect(
                    model, press.camera, press.leds, ref.depth, ref.normals, albedo, receivers, size=4, window=window
                )
            )
    finally:
        threads.set_workers(before)
    np.testing.assert_array_equal(got[0], got[1])
    inside = receivers[window]
    assert got[0][:, inside].min() > 0 and not got[0][:, ~inside].any()


def test_shading_derivatives_only_for_the_gauss_newton_steps(press, monkeypatch):
    """A level evaluated, not iterated, and a step that ends its level never use dF: one derivative shading per
    Gauss-Newton system solved, none else (each costs about two shadings at 640x480)."""
    from nlipscalib.solver import kernel

    calls = []
    plain = kernel.Model.shading

    def counted(self, t, tu, tv, derivatives=False):
        calls.append(derivatives)
        return plain(self, t, tu, tv, derivatives)

    monkeypatch.setattr(kernel.Model, "shading", counted)
    lin = press.linear(press.led_images)
    two = SolverOptions(pyramid_levels=2)
    rough = solve(lin, press.camera, press.leds, prior_depth=press.reference.depth, options=two, unrefined=1)
    levels = rough.report["levels"]
    assert levels[-1]["iterations"] == 0 and levels[-1]["gamma"] is None and levels[-1]["energy"] == []
    assert levels[-2]["stop"] == "energy_rtol"  # a converged step ended that level
    assert sum(calls) == sum(len(lv["cg_iters"]) for lv in levels)
    assert len(calls) > sum(calls)  # line-search trials and the evaluated level shade without derivatives


def test_the_intensity_scale_is_the_percentile_of_the_usable_samples(press):
    from nlipscalib.solver.samples import high_level

    lin = press.linear(press.led_images).astype(np.float32)
    for usable in (np.ones(lin.shape, bool), lin > np.median(lin), np.zeros(lin.shape, bool)):
        expected = float(np.percentile(lin[usable], 99)) if usable.any() else 1.0
        assert high_level(lin, usable) == expected
    crop = lin[:, 10:50, 20:70]  # a crop of the images: not contiguous
    assert high_level(crop, crop > 0.1) == float(np.percentile(crop[crop > 0.1], 99))


def test_the_intensity_scale_from_the_top_samples_is_numpys_percentile_to_the_bit():
    from nlipscalib.solver import samples

    rng = np.random.default_rng(3)
    for k in range(40):
        dtype = np.float32 if k % 2 else np.float64
        shape = (int(rng.integers(1, 6)), int(rng.integers(8, 40)), int(rng.integers(8, 40)), 3)
        images = rng.gamma(2.0, 0.1, shape).astype(dtype)
        if k % 5 == 0:
            images = np.round(images, 2)  # ties
        usable = rng.random(shape) < rng.uniform(0.01, 1.0)
        expected = float(np.percentile(images[usable], 99)) if usable.any() else 1.0
        assert samples.high_level(images, usable) == expected
    # a subsample unlike the whole (the bound above the percentile): every usable sample is partitioned
    images = np.zeros((2, 16, 16, 3), np.float32)
    images[:, ::8, ::8] = 1.0
    images[:, 1:, 1:] += np.linspace(0.0, 0.5, 15, dtype=np.float32)[:, None, None]
    usable = np.ones(images.shape, bool)
    top, under = samples._top_samples(images, usable, usable.size, int(0.99 * (usable.size - 1)))
    assert under == 0 and top.size == usable.size
    assert samples.high_level(images, usable) == float(np.percentile(images, 99))


def test_a_levels_geometry_is_kept_and_equals_a_fresh_one(press):
    from nlipscalib.solver import geometry, reuse
    from nlipscalib.solver.pyramid import level_geometry

    reuse.clear()
    mask = np.isfinite(press.reference.depth)
    q, basis = level_geometry(press.camera, mask)
    fq, fqu, fqv = geometry.ray_tables(press.camera)
    np.testing.assert_array_equal(q, fq[mask])
    for got, fresh in zip(basis, geometry.normal_basis(fq[mask], fqu[mask], fqv[mask])):
        np.testing.assert_array_equal(got, fresh)
    again = level_geometry(press.camera, mask.copy())  # the same mask's content: the kept arrays, read-only
    assert again[0] is q and not q.flags.writeable
    other = mask.copy()
    other[0, :] = False
    assert len(level_geometry(press.camera, other)[0]) == other.sum()


def test_a_large_levels_normals_and_their_change_by_pixel_blocks_have_the_plain_bits():
    """operators.depth_normals and pixelwise run a large level's per-pixel work by blocks on the pool (row blocks of the
    difference operators' products): the bits of the one-piece computation, on one thread or two."""
    from nlipscalib.core.metrics import angle_deg
    from nlipscalib.solver import geometry
    from nlipscalib.solver.kernel import PARALLEL_MIN_PIXELS
    from nlipscalib.solver.operators import PIXELWISE_PIXELS, _make_operators, depth_normals, pixelwise

    mask = np.ones((300, 260), bool)
    mask[100:140, 30:90] = False
    n = int(mask.sum())
    assert n > max(PARALLEL_MIN_PIXELS, PIXELWISE_PIXELS, threads.PRODUCT_MIN_ROWS)  # blocks on the pool
    ops = _make_operators(mask)
    rng = np.random.default_rng(7)
    t = np.log(15.0) + 0.05 * rng.standard_normal(n)
    A, B, C = (rng.standard_normal((n, 3)) for _ in range(3))
    plain = geometry.normals_from_gradient(ops["Du"] @ t, ops["Dv"] @ t, A, B, C)
    other = geometry.normals_from_gradient(ops["Du"] @ (1.01 * t), ops["Dv"] @ (1.01 * t), A, B, C)
    before = threads.workers()
    try:
        for count in (1, 2):
            threads.set_workers(count)
            np.testing.assert_array_equal(depth_normals(ops, t, A, B, C), plain)
            change = pixelwise(lambda p: angle_deg(plain[p], other[p]), n)
            np.testing.assert_array_equal(change, angle_deg(plain, other))
    finally:
        threads.set_workers(before)


def test_the_outer_loops_first_pass_stops_its_levels_at_the_seed_tolerance(press):
    """An unrefined solve from the prior (the outer loop's first pass, which only seeds the passes after it) stops its
    levels at ``seed_energy_rtol``, not ``energy_rtol``: the same bits as a solve whose ``energy_rtol`` is that value,
    fewer Gauss-Newton steps than at the other passes' tolerance. A warm-started unrefined pass and a refined solve
    do not read it."""
    lin = press.linear(press.led_images)
    prior = press.reference.depth

    def run(unrefined: int, init: np.ndarray | None = None, **fields):
        options = SolverOptions(pyramid_levels=3, **fields)
        return solve(
            lin, press.camera, press.leds, prior_depth=prior, options=options, unrefined=unrefined, init_depth=init
        )

    loose = run(1, seed_energy_rtol=0.05)
    assert loose.depth.tobytes() == run(1, energy_rtol=0.05, seed_energy_rtol=0.05).depth.tobytes()
    tight = run(1, seed_energy_rtol=1e-3)
    steps = [sum(lv["iterations"] for lv in r.report["levels"]) for r in (loose, tight)]
    assert 0 < steps[0] < steps[1], steps
    for unrefined, init in ((1, tight.depth), (0, None)):
        plain = run(unrefined, init).depth.tobytes()
        assert run(unrefined, init, seed_energy_rtol=0.05).depth.tobytes() == plain, unrefined
    with pytest.raises(ConfigError, match="seed_energy_rtol"):
        SolverOptions(seed_energy_rtol=0.0)


def test_the_led_and_channel_sum_has_numpys_bits():
    """``outer_loop.led_channel_sum`` (the outer loop's relaxation and image total) equals ``stack.sum(axis=(0, 3))``
    bit for bit, on contiguous stacks and on windows of them (strided), float32 and float64, with -0.0 entries."""
    from nlipscalib.solver.outer_loop import led_channel_sum

    rng = np.random.default_rng(3)
    for leds, h, w in [(1, 1, 1), (12, 16, 640), (5, 7, 33), (12, 40, 3)]:
        for dtype in (np.float32, np.float64):
            big = rng.lognormal(0.0, 2.0, (leds, h + 4, w + 6, 3)).astype(dtype)  # wide range: rounding shows
            big[big < 0.05] = -0.0
            for stack in (big, big[:, 2 : 2 + h, 3 : 3 + w], big[:, :h, 1:]):
                assert led_channel_sum(stack).tobytes() == stack.sum(axis=(0, 3)).tobytes()


@pytest.mark.parametrize("whole_crop", [False, True])
@pytest.mark.parametrize("lost_any", [False, True])
def test_a_levels_paste_is_the_filled_image_with_its_masked_assignment(whole_crop, lost_any):
    from nlipscalib.solver.crop import _pasted

    rng = np.random.default_rng(3)
    crop = (slice(5, 17), slice(0, 9))
    mask = np.ones((12, 9), bool) if whole_crop else rng.random((12, 9)) > 0.3
    n = int(mask.sum())
    lost = rng.random(n) > 0.8 if lost_any else None
    for values, fill in ((rng.normal(size=n), np.nan), (rng.normal(size=(n, 3)), 0.0)):
        want = np.full((20, 11) + values.shape[1:], fill, np.float32)
        vals = values.astype(np.float32)
        if lost is not None:
            vals[lost] = fill
        want[crop][mask] = vals
        got = _pasted(values, fill, (20, 11), crop, mask, lost)
        assert got.dtype == np.float32 and np.array_equal(got, want, equal_nan=True)
