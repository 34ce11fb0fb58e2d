"""solve_press as a script calls it: a Press or a press folder's path (str or Path), for the press and its reference
(exact-data presses, 64x48)."""

import numpy as np
import pytest

from nlipscalib.core import load_press
from nlipscalib.core.errors import CaptureError, ShapeError
from nlipscalib.solver import SolverOptions, solve_press
from tests.solver import synth

FAST = SolverOptions(max_iters=6)


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    root = tmp_path_factory.mktemp("press_paths")
    synth.make_press(root / "reference", "none", size=(64, 48))
    synth.make_press(root / "press", "cube", size=(64, 48))
    return root / "press", root / "reference"


def test_a_press_folders_path_solves_as_its_loaded_press(folders):
    press, reference = folders
    loaded = solve_press(load_press(press), roi="auto", indirect=load_press(reference), options=FAST)
    by_path = solve_press(str(press), roi="auto", indirect=reference, options=FAST)
    assert loaded.reconstructed.sum() > 0
    for name in ("normals", "depth", "albedo", "reconstructed"):
        np.testing.assert_array_equal(getattr(by_path, name), getattr(loaded, name), err_msg=name)


def test_anything_else_is_one_clear_error(folders):
    press, reference = folders
    with pytest.raises(ShapeError, match="press must be a Press .* got int"):
        solve_press(3)
    with pytest.raises(CaptureError, match="nowhere: not a press folder"):
        solve_press(press, indirect=reference.parent / "nowhere")


def test_the_solvers_bar_is_drawn_on_a_terminal_only(folders, capsys, as_terminal):
    """progress=True in a notebook or a script logging to a file: no bar (it wrote a line per Gauss-Newton
    iteration there); on a terminal the bar says the level and the iterations."""
    press, reference = folders
    solve_press(press, indirect=reference, options=FAST, progress=True)
    assert capsys.readouterr().err == ""
    terminal = as_terminal()
    solve_press(press, indirect=reference, options=FAST, progress=True)
    assert "iterations so far" in terminal.getvalue()


@pytest.mark.parametrize("interrupted_call", [1, 2])
def test_ctrl_c_in_a_solve_leaves_the_process_solving_as_before(folders, monkeypatch, interrupted_call):
    """KeyboardInterrupt (Ctrl-C in a notebook) in the first pass or in the outer interreflection loop's second, once
    the sensor's results are kept (solver.reuse) and the helper threads run: no thread is left behind, and the next
    solve of the press is bit for bit the one before. Seen by hand on sphere1/cube1 at 640x480 with a real SIGINT
    0.3 s and 1 s into the solve: the same (benchmarks/RESULTS.md, s25-api). interreflection="on": exact data have
    no indirect light, and "auto" would solve a single pass."""
    import threading

    from nlipscalib.solver import nlips

    press, reference = folders
    first = solve_press(press, roi="auto", indirect=reference, options=FAST, interreflection="on")
    threads = {t.name for t in threading.enumerate()}
    calls = []
    solve_levels = nlips.solve_coarse_to_fine

    def interrupted(*args, **kwargs):
        calls.append(1)
        if len(calls) == interrupted_call:
            raise KeyboardInterrupt
        return solve_levels(*args, **kwargs)

    monkeypatch.setattr(nlips, "solve_coarse_to_fine", interrupted)
    with pytest.raises(KeyboardInterrupt):
        solve_press(press, roi="auto", indirect=reference, options=FAST, interreflection="on")
    monkeypatch.undo()
    assert {t.name for t in threading.enumerate()} <= threads
    again = solve_press(press, roi="auto", indirect=reference, options=FAST, interreflection="on")
    for name in ("normals", "depth", "albedo", "reconstructed"):
        np.testing.assert_array_equal(getattr(again, name), getattr(first, name), err_msg=name)


def test_a_solve_draws_nothing_from_numpys_global_generator(folders):
    """The experiments seeded NumPy's global generator before every solve and calibration (pyamg once drew its
    smoothers' start vectors from it); a library must leave a notebook's generator alone, and the solve needs no
    seed: its state is the same after a solve as before (the AMG set-up is checked on its own in test_krylov)."""
    press, reference = folders
    np.random.seed(12345)
    untouched = np.random.random()  # the generator's next value had nothing drawn from it
    np.random.seed(12345)
    solve_press(press, roi="auto", indirect=reference, options=FAST)
    assert np.random.random() == untouched


def test_the_solve_again_without_the_raised_smoothness_says_the_first_solves_warnings_once(
    folders, monkeypatch, caplog
):
    """A press solved a second time (the first drifted off the gel with the noise-adapted smoothness) logged each of
    the first solve's warnings again (a capture's linearity, an override, a contact at the resolution limit); the
    second solve's new warnings are still said, and the report keeps what it found."""
    import logging
    import types

    from nlipscalib.solver import press as press_module

    press = load_press(folders[0])
    calls = []

    def solve_twice(p, **kwargs):
        calls.append(kwargs["options"])
        note = f"{p.folder}: a warning of every solve"
        press_module.log.warning("%s", note)
        notes = [note]
        if len(calls) == 2:
            press_module.log.warning("%s: only the second solve's", p.folder)
            notes.append(f"{p.folder}: only the second solve's")
        depth = p.reference.depth + (5.0 if len(calls) == 1 else 0.0)  # the first solve left the gel
        report = {"smoothness": 1.0 if len(calls) == 1 else 0.0, "warnings": notes}
        return types.SimpleNamespace(depth=depth, reconstructed=np.isfinite(depth), report=report)

    monkeypatch.setattr(press_module, "_solve_press", solve_twice)
    with caplog.at_level(logging.WARNING, logger=press_module.log.name):
        result = solve_press(press, options=SolverOptions(smoothness=0.5))
    assert len(calls) == 2 and calls[1].noise_smoothness == 0.0
    said = [r.getMessage() for r in caplog.records]
    assert said.count(f"{press.folder}: a warning of every solve") == 1, said
    assert said.count(f"{press.folder}: only the second solve's") == 1, said
    assert any("solving again without it" in line for line in said)
    assert f"{press.folder}: a warning of every solve" in result.report["warnings"]
    assert not press_module.log.filters  # the filter is gone with the second solve


def test_the_led_checks_before_the_solve_run_on_one_blas_thread(folders, monkeypatch):
    """The checks' small products (np.corrcoef of (24, 2008) samples) took 55-70 ms on OpenBLAS's two threads on a
    2-core machine, 0.1 ms on one: solve_press runs on one BLAS thread from its first check, not only in the solve."""
    from nlipscalib.core.blas import blas_setting, blas_threads
    from nlipscalib.solver import press as press_module

    seen = []
    checks = press_module.led_check_measured

    def counted(*args, **kwargs):
        seen.append(blas_setting())
        return checks(*args, **kwargs)

    monkeypatch.setattr(press_module, "led_check_measured", counted)
    press, reference = folders
    with blas_threads(2):  # the caller's count (a 2-core machine's default)
        solve_press(press, roi="auto", indirect=reference, options=FAST)
        assert set(blas_setting()) == {2}  # given back after the solve
    assert seen and all(set(setting) == {1} for setting in seen)


def test_the_whole_images_rays_are_made_once_on_a_thread_of_their_own(folders, monkeypatch):
    """The contact search's point-LED error used them first, on the main thread while the other core waited."""
    import threading

    from nlipscalib.core import load_press as load
    from nlipscalib.core.camera import Camera
    from nlipscalib.solver import threads

    made = []
    unproject = Camera.unproject

    def recorded(camera, uv):
        if uv.shape[:2] == camera.shape:
            made.append((camera.shape, threading.current_thread().name))
        return unproject(camera, uv)

    monkeypatch.setattr(Camera, "unproject", recorded)
    press, reference = folders
    loaded, against = load(press), load(press)
    before = threads.workers()
    try:
        threads.set_workers(2)
        solve_press(loaded, options=FAST)
        # against an undeformed capture the whole image's rays may go unused: not made ahead
        solve_press(against, roi="auto", indirect=reference, options=FAST)
    finally:
        threads.set_workers(before)
    assert [name for shape, name in made if shape == loaded.camera.shape] == ["camera-rays"]
    assert "rays" in vars(loaded.camera) and "rays" not in vars(against.camera)


def test_leds_or_a_box_of_another_kind_are_one_clear_error_before_any_check(folders):
    """`leds=` given as numbers, an array or an LED file's path, and a box of three numbers, failed deep inside the
    LED checks ("tuple index out of range") or the box's unpacking ("not enough values to unpack")."""
    from nlipscalib.core.leds import Led

    press, _ = folders
    with pytest.raises(ShapeError, match=r"leds must be a sequence of Led .* got a list of int"):
        solve_press(press, leds=[1, 2, 3])
    with pytest.raises(ShapeError, match=r"leds must be a sequence of Led .* got a ndarray of ndarray"):
        solve_press(press, leds=np.zeros((12, 3)))
    with pytest.raises(ShapeError, match=r"leds: 'leds.json' is a path; .*read_led_file\(path\).leds"):
        solve_press(press, leds="leds.json")
    loaded = load_press(press)
    with pytest.raises(CaptureError, match=f"{len(loaded.leds) - 1} LEDs given for {len(loaded.leds)} LED images"):
        solve_press(loaded, leds=loaded.leds[1:])
    assert all(isinstance(led, Led) for led in loaded.leds)
    with pytest.raises(ShapeError, match=r"roi must be \(x0, y0, w, h\) pixels, 'auto' or None, got \(0, 0, 10\)"):
        solve_press(press, roi=(0, 0, 10))


def test_help_of_solve_press_describes_every_keyword_it_takes():
    """help(solve_press) (a notebook's Shift-Tab) showed _solve_press's signature but said only "see _solve_press for
    the parameters", a private name: every keyword is described in its own help now."""
    import inspect
    import re

    entries = re.findall(r"^(\w+(?:, \w+)*) :", inspect.getdoc(solve_press), re.M)  # "options, backend : ..."
    described = {name for entry in entries for name in entry.split(", ")}
    assert set(inspect.signature(solve_press).parameters) - described == set()


def test_the_solves_saturated_samples_are_the_presss_own_unless_its_dark_frame_adds_some(folders):
    """A dark frame without a saturated pixel adds nothing to the LED images' saturated samples: the solve reads the
    press's own flags, not a second whole-frame copy of them (11 MB at 640x480 with 12 LEDs); one with some
    flags them in every LED's image."""
    import dataclasses

    from nlipscalib.solver.press import _saturated_samples

    press = load_press(folders[0])
    assert _saturated_samples(press) is press.saturated_led_images
    dark = press.dark.copy()
    dark[3, 5, 1] = press.response.white_level
    clipped = dataclasses.replace(press, dark=dark)
    got = _saturated_samples(clipped)
    assert got.all(axis=0)[3, 5, 1] and not got.flags.writeable
    want = clipped.saturated_led_images.copy()
    want[:, 3, 5, 1] = True
    np.testing.assert_array_equal(got, want)


def test_the_last_passs_solve_holds_neither_the_gathered_surface_nor_a_whole_frame_copy_of_the_images(
    folders, monkeypatch
):
    """The outer interreflection loop's last pass: the solved surface its light was gathered from (~9 MB of
    whole-frame maps at 640x480) is let go before the solve, and the solve's images are the press's with the box
    compensated (a :class:`FrameBox`), not a second whole-frame array of them."""
    import gc
    import weakref

    from nlipscalib.solver import outer_loop
    from nlipscalib.solver import press as press_module
    from nlipscalib.solver.frame_box import FrameBox

    surfaces, seen = [], []
    made = outer_loop._solved_surface

    def solved_surface(*args):
        surface = made(*args)
        surfaces.append(weakref.ref(surface))
        return surface

    run = press_module._Runner.__call__

    def call(self, light, init=None, unrefined=0, receivers=None):
        images = self.compensated(light, receivers)
        gc.collect()
        seen.append((init is not None, type(images), [alive() is not None for alive in surfaces]))
        return run(self, light, init, unrefined, receivers)

    monkeypatch.setattr(outer_loop, "_solved_surface", solved_surface)
    monkeypatch.setattr(press_module._Runner, "__call__", call)
    press, reference = (load_press(f) for f in folders)
    solve_press(press, roi="auto", indirect=reference, options=FAST, interreflection="on")
    later = [(kind, alive) for warm, kind, alive in seen if warm]
    assert later, "no pass after the first ran"
    assert all(kind is FrameBox for kind, _ in later)
    assert not any(any(alive) for _, alive in later)
