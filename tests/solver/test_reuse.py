"""Sensor-level work reused across the presses of one process, and of later processes through the disk
tier (solver/reuse.py, core/diskcache.py), changes no number."""

import os
import subprocess
import sys

import numpy as np
import pytest

from nlipscalib.core import diskcache, load_press
from nlipscalib.solver import reuse
from nlipscalib.solver.indirect import direct_shading, reference_shading
from nlipscalib.solver.press import solve_press

from . import synth


@pytest.fixture(autouse=True)
def empty_store(monkeypatch):
    """An empty store, and no disk tier unless a test turns it on: "computed alone" must mean computed."""
    monkeypatch.setenv(diskcache.ENV_DIR, "off")
    reuse.clear()
    yield
    reuse.clear()


@pytest.fixture
def disk(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv(diskcache.ENV_DIR, str(folder))
    yield folder
    diskcache.wait()  # the test's background writes, before its folder goes


def test_digest_tells_content_shape_and_dtype_apart():
    a = np.arange(12, dtype=np.float32).reshape(3, 4)
    assert reuse.digest(a) == reuse.digest(a.copy())
    b = a.copy()
    b[1, 2] += 1e-6
    assert reuse.digest(a) != reuse.digest(b)
    assert reuse.digest(a) != reuse.digest(a.reshape(4, 3))
    assert reuse.digest(a) != reuse.digest(a.astype(np.float64))
    assert reuse.digest(a[:, ::2]) == reuse.digest(np.ascontiguousarray(a[:, ::2]))  # views by content


def test_a_result_is_served_for_its_key_and_object_only_and_read_only():
    calls = []

    def compute(tag):
        calls.append(tag)
        return {"values": np.zeros(3)}

    first = reuse.reused("k", ("a",), lambda: compute("a"))
    assert reuse.reused("k", ("a",), lambda: compute("again")) is first
    with pytest.raises(ValueError):
        first["values"][0] = 1.0  # stored arrays cannot be changed under the next press
    owner, other = object(), object()
    reuse.reused("k", ("b",), lambda: compute("b"), keep=owner)
    reuse.reused("k", ("b",), lambda: compute("b2"), keep=other)  # same key, another object: computed
    assert calls == ["a", "b", "b2"]
    for tag in "cde":  # a few per kind: the oldest goes
        reuse.reused("k", (tag,), lambda tag=tag: compute(tag))
    reuse.reused("k", ("a",), lambda: compute("a3"))
    assert calls[-1] == "a3" and len(reuse._store["k"]) == reuse.PER_KIND


def test_a_result_computed_under_another_blas_thread_count_is_not_served():
    """A matrix product's last bits depend on BLAS's thread count (the radiosity gather's do): an experiment
    task runs under one thread for reproducible numbers and must not get a result computed under two."""
    from nlipscalib.core.blas import blas_setting, blas_threads
    from nlipscalib.solver.radiosity import gather

    rng = np.random.default_rng(0)
    points = rng.normal(size=(3000, 3))
    normals = points / np.linalg.norm(points, axis=1, keepdims=True)
    emitters = {"points": points[:1500] + 3.0, "normals": normals[:1500], "area": rng.uniform(size=1500)}
    light = rng.uniform(size=(4, 1500, 3))
    with blas_threads(2):
        two = reuse.reused("g", ("x",), lambda: gather(points, normals, emitters, light))
    with blas_threads(1):
        assert blas_setting() and set(blas_setting()) == {1}
        one = reuse.reused("g", ("x",), lambda: gather(points, normals, emitters, light))
        np.testing.assert_array_equal(one, gather(points, normals, emitters, light))  # as computed fresh
    assert one is not two
    with blas_threads(2):
        assert reuse.reused("g", ("x",), lambda: None) is two  # each setting keeps its own


def test_reference_shading_is_reused_for_the_same_surface_only(tmp_path):
    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(48, 36)))
    ref = press.reference
    first = reference_shading(press.camera, press.leds, ref.depth, ref.normals)
    np.testing.assert_array_equal(first, direct_shading(press.camera, press.leds, ref.depth, ref.normals))
    assert reference_shading(press.camera, press.leds, ref.depth.copy(), ref.normals) is first
    moved = ref.depth + np.float32(0.01)
    assert reference_shading(press.camera, press.leds, moved, ref.normals) is not first


def test_presses_of_one_sensor_solve_alike_with_reused_sensor_work(tmp_path):
    folders = {kind: synth.make_press(tmp_path / kind, kind, size=(96, 72)) for kind in ("none", "sphere", "cube")}
    undeformed = load_press(folders["none"])
    presses = [load_press(folders[k]) for k in ("sphere", "cube")]

    def solve(press):
        np.random.seed(0)  # pyamg draws random start vectors from numpy's global generator
        return solve_press(press, roi="auto", indirect=undeformed, interreflection="on")

    alone = []
    for press in presses:
        reuse.clear()
        alone.append(solve(press))
    reuse.clear()
    solve(presses[1])  # the store now holds the sensor's work, from another press
    for press, fresh in zip(presses, alone):
        shared = solve(press)
        for key in ("depth", "normals", "albedo"):
            np.testing.assert_array_equal(getattr(shared, key), getattr(fresh, key), err_msg=key)
    # the work was in fact reused (the shading is not among it: with an undeformed capture the fit and the
    # contact do not read it, and the outer loop's surface is the fit's, made from its own capture)
    assert {"surface", "fit", "operators"} <= set(reuse._store)


def test_solves_on_one_mask_share_its_difference_operators(tmp_path, monkeypatch):
    from nlipscalib.solver import operators

    made = []
    make = operators._make_operators
    monkeypatch.setattr(operators, "_make_operators", lambda mk, **kw: made.append(int(mk.sum())) or make(mk, **kw))
    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(96, 72)))
    first = solve_press(press, interreflection="off")
    levels = len(made)
    again = solve_press(press, interreflection="off")
    assert levels >= 1 and len(made) == levels  # the same masks: nothing built again
    for key in ("depth", "normals", "albedo"):
        np.testing.assert_array_equal(getattr(again, key), getattr(first, key), err_msg=key)
    solve_press(press, roi=(10, 10, 40, 30), interreflection="off")
    assert len(made) > levels and made[-1] == 40 * 30  # another mask: its own operators


def test_a_persisted_result_is_computed_once_for_later_processes_and_served_read_only(disk):
    calls = []

    def compute():
        calls.append(1)
        return {"values": np.arange(4.0)}

    key = ("a", reuse.digest(np.ones(3)))
    first = reuse.reused("k", key, compute, persist=True)
    reuse.clear()  # what a new process starts with
    again = reuse.reused("k", key, compute, persist=True)
    assert len(calls) == 1 and again is not first
    np.testing.assert_array_equal(again["values"], first["values"])
    with pytest.raises(ValueError):
        again["values"][0] = 1.0
    reuse.clear()
    reuse.reused("k", ("a", reuse.digest(np.zeros(3))), compute, persist=True)  # other content: computed
    assert len(calls) == 2
    assert reuse.origin(again) is None  # this process's store was cleared since
    from nlipscalib.core.blas import blas_setting

    assert reuse.origin(reuse.reused("k", key, compute)) == ("k", (key, blas_setting()))


def test_a_deferred_result_is_named_by_its_key_and_computed_only_when_its_values_are_needed():
    calls = []

    def compute():
        calls.append(1)
        return np.arange(3.0)

    later = reuse.deferred("k", ("a",), compute)
    assert not calls and reuse.values(later) is reuse.values(later) and len(calls) == 1
    assert reuse.origin(later) == reuse.origin(reuse.reused("k", ("a",), compute))  # the stored values' name
    assert reuse.values(later) is reuse.reused("k", ("a",), compute) and len(calls) == 1
    plain = np.ones(2)
    assert reuse.values(plain) is plain


def test_a_warm_solve_whose_consumers_all_hit_does_not_load_the_shading(tmp_path, disk, monkeypatch):
    """The undeformed surface's direct shading (88 MB at 640x480) is only part of the keys of its consumers (the
    fit's and the outer loop's surfaces, the contact's smoothed undeformed images) when each finds its own result
    on disk: a later process does not compute it, and solves alike. So it is not written to disk at all (writing
    it cost a cold 640x480 command 0.1-0.8 s of system time)."""
    from nlipscalib.solver import indirect

    press = load_press(synth.make_press(tmp_path / "sphere", "sphere", size=(96, 72)))

    def solve():
        np.random.seed(0)  # pyamg draws random start vectors from numpy's global generator
        result = solve_press(press, roi="auto", interreflection="on")  # the press stands in for the undeformed
        return {key: getattr(result, key) for key in ("depth", "normals", "albedo")}

    first = solve()
    diskcache.wait()
    assert any((disk / "surface").iterdir())  # its consumers' results: kept
    assert not (disk / "shading").exists()  # the first process computed it; no later one reads it
    reuse.clear()  # a new process: only the disk remembers
    loaded, shaded = [], []
    load, direct = diskcache.load, indirect.direct_shading
    monkeypatch.setattr(diskcache, "load", lambda path: loaded.append(path.parent.name) or load(path))
    monkeypatch.setattr(indirect, "direct_shading", lambda *a, **k: shaded.append(1) or direct(*a, **k))
    later = solve()
    assert "surface" in loaded and "smoothed_undeformed" in loaded  # its consumers' own results came from disk
    assert "shading" not in loaded and not shaded  # and the shading was neither loaded nor computed
    for key in first:
        np.testing.assert_array_equal(later[key], first[key], err_msg=key)


def test_a_warm_solve_against_an_undeformed_capture_does_not_linearise_its_images(tmp_path, disk):
    """The contact's blur of the undeformed capture's images is kept on disk under the capture's content key: a
    later process that finds it names the images by that key and never linearises them (44 MB at 640x480)."""
    folders = {kind: synth.make_press(tmp_path / kind, kind, size=(96, 72)) for kind in ("none", "sphere")}

    def solve(undeformed):
        np.random.seed(0)  # pyamg draws random start vectors from numpy's global generator
        result = solve_press(load_press(folders["sphere"]), roi="auto", indirect=undeformed, interreflection="on")
        return {key: getattr(result, key) for key in ("depth", "normals", "albedo")}

    first = solve(load_press(folders["none"]))
    reuse.clear()  # a new process: only the disk remembers
    undeformed = load_press(folders["none"])
    later = solve(undeformed)
    assert "linear_led_images" not in vars(undeformed)  # the cached property was never computed
    for key in first:
        np.testing.assert_array_equal(later[key], first[key], err_msg=key)


def test_a_warm_solve_against_an_undeformed_capture_does_not_decode_its_images(tmp_path, disk, monkeypatch):
    """The undeformed capture's results on disk are named by its files' bytes (``Press.images_digest``): a later
    process loads the capture undecoded (``nlips solve --reference``), finds them, and never decodes its PNGs
    (0.2-0.3 s at 640x480, only to name them); it solves alike."""
    from nlipscalib.core import stored_images  # decodes the PNGs (core.capture re-exports its loaders)

    folders = {kind: synth.make_press(tmp_path / kind, kind, size=(96, 72)) for kind in ("none", "sphere")}
    first = _solve_auto(folders["sphere"], load_press(folders["none"], decode=False))
    reuse.clear()  # a new process: only the disk remembers
    decoded, decode = [], stored_images.decode_png16

    def spy(data, path, **kw):
        decoded.append(path)
        return decode(data, path, **kw)

    monkeypatch.setattr(stored_images, "decode_png16", spy)
    later = _solve_auto(folders["sphere"], load_press(folders["none"], decode=False))
    assert decoded and not [p for p in decoded if folders["none"] in p.parents]  # the press's own: decoded
    for key in first:
        np.testing.assert_array_equal(later[key], first[key], err_msg=key)


def test_an_undeformed_capture_file_replaced_in_place_is_not_served_the_old_files_results(tmp_path, disk, monkeypatch):
    """An LED image of the undeformed capture overwritten in place (same name, inode and size, its time kept, as
    ``cp -p`` leaves it): the results on disk named by the old bytes are not served for the new ones."""
    folders = {kind: synth.make_press(tmp_path / kind, kind, size=(96, 72)) for kind in ("none", "sphere")}
    old = _solve_auto(folders["sphere"], load_press(folders["none"], decode=False))
    image = folders["none"] / "led_02.png"
    stat = image.stat()
    dimmer = (load_press(folders["none"]).led_images[1] * 0.8).astype(np.uint16)
    data = _png_of_size(dimmer, stat.st_size)
    with open(image, "r+b") as f:  # in place: the same inode
        f.write(data)
    os.utime(image, ns=(stat.st_atime_ns, stat.st_mtime_ns))
    now = image.stat()
    assert (now.st_ino, now.st_size, now.st_mtime_ns) == (stat.st_ino, stat.st_size, stat.st_mtime_ns)
    reuse.clear()  # a new process: only the disk remembers
    later = _solve_auto(folders["sphere"], load_press(folders["none"], decode=False))
    reuse.clear()
    monkeypatch.setenv(diskcache.ENV_DIR, "off")
    fresh = _solve_auto(folders["sphere"], load_press(folders["none"]))
    assert not np.array_equal(fresh["normals"], old["normals"], equal_nan=True)  # the change shows in the result
    for key in fresh:
        np.testing.assert_array_equal(later[key], fresh[key], err_msg=key)


def _png_of_size(image: np.ndarray, size: int) -> bytes:
    """``image`` as a 16-bit PNG of exactly ``size`` bytes (padded with an ancillary chunk; shorter ones only)."""
    import struct
    import zlib

    import cv2

    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    data = buf.tobytes()
    pad = size - len(data) - 12  # a chunk: length, type, data, CRC
    assert ok and pad >= 0
    body = b"teXt" + b"p" * pad
    chunk = struct.pack(">I", pad) + body + struct.pack(">I", zlib.crc32(body))
    return data[:33] + chunk + data[33:]  # after the signature and IHDR


def _solve_auto(folder, undeformed):
    np.random.seed(0)  # pyamg draws random start vectors from numpy's global generator
    result = solve_press(load_press(folder), roi="auto", indirect=undeformed, interreflection="on")
    return {key: getattr(result, key) for key in ("depth", "normals", "albedo")}


def _solve_fields(press, undeformed):
    np.random.seed(0)  # pyamg draws random start vectors from numpy's global generator
    result = solve_press(press, indirect=undeformed, interreflection="on")  # the whole gel: its operators recur
    return {key: getattr(result, key) for key in ("depth", "normals", "albedo")}


def test_a_later_process_solves_alike_from_the_sensor_work_on_disk(tmp_path, disk, monkeypatch):
    from nlipscalib.solver import contact_grid, indirect, operators

    # the whole gel's levels this large keep their operators on disk, with the fixed-pattern map
    monkeypatch.setattr(operators, "OPERATOR_PERSIST_PIXELS", 1000)
    folders = {kind: synth.make_press(tmp_path / kind, kind, size=(96, 72)) for kind in ("none", "sphere")}
    press, undeformed = load_press(folders["sphere"]), load_press(folders["none"])
    monkeypatch.setenv(diskcache.ENV_DIR, "off")
    fresh = _solve_fields(press, undeformed)
    monkeypatch.setenv(diskcache.ENV_DIR, str(disk))
    reuse.clear()
    first = _solve_fields(press, undeformed)
    diskcache.wait()
    kinds = {p.name for p in disk.iterdir() if any(p.iterdir())}
    # no "shading": with an undeformed capture the fit and the contact do not read it, and at this size the
    # outer loop's surface is the fit's (the same patch side), made from the capture
    assert {"surface", "fit", "operators", "smoothed_undeformed", "level_geometry"} <= kinds
    reuse.clear()  # a new process: only the disk remembers
    shaded, blurred = [], []
    direct, blur = indirect.direct_shading, contact_grid.gel_blur
    monkeypatch.setattr(indirect, "direct_shading", lambda *a, **k: shaded.append(1) or direct(*a, **k))
    monkeypatch.setattr(contact_grid, "gel_blur", lambda *a, **k: blurred.append(1) or blur(*a, **k))
    later = _solve_fields(press, undeformed)
    assert not shaded  # the undeformed surface's shading came from disk
    assert len(blurred) == 1  # the press's images; the undeformed capture's blur came from disk
    for key in fresh:
        np.testing.assert_array_equal(first[key], fresh[key], err_msg=key)
        np.testing.assert_array_equal(later[key], fresh[key], err_msg=key)


def test_the_whole_gels_level_rays_are_read_back_by_a_later_process_an_rois_not_kept(tmp_path, disk, monkeypatch):
    from nlipscalib.solver import geometry, pyramid

    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(96, 72)))
    gel = np.isfinite(press.reference.depth)
    first = pyramid.level_geometry(press.camera, gel, persist=True)
    diskcache.wait()
    reuse.clear()  # a new process: only the disk remembers
    made = []
    rays = geometry.ray_tables
    monkeypatch.setattr(geometry, "ray_tables", lambda *a, **k: made.append(1) or rays(*a, **k))
    later = pyramid.level_geometry(press.camera, gel, persist=True)
    assert not made
    for a, b in zip((first[0], *first[1]), (later[0], *later[1])):
        np.testing.assert_array_equal(b, a)
        assert not b.flags.writeable
    for entry in (disk / "level_geometry").iterdir():
        entry.unlink()
    solve_press(press, roi=(10, 10, 60, 40), interreflection="off")  # an ROI's levels: not the whole gel
    diskcache.wait()
    assert made and not any((disk / "level_geometry").iterdir())


def test_solve_commands_in_separate_processes_share_the_disk_cache(tmp_path, disk):
    press = synth.make_press(tmp_path / "sphere", "sphere", size=(96, 72))
    env = dict(os.environ, **{diskcache.ENV_DIR: str(disk)})

    def nlips(*args):
        cmd = [sys.executable, "-c", "import sys; from nlipscalib.cli import main; sys.exit(main(sys.argv[1:]))"]
        done = subprocess.run(cmd + list(args), env=env, capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        return done.stdout

    results = []
    for out in ("first", "second"):
        nlips("--no-progress", "solve", str(press), "--figures", "none", "--out", str(tmp_path / out))
        results.append(np.load(tmp_path / out / "result.npz"))
    for key in ("depth", "normals", "albedo"):
        np.testing.assert_array_equal(results[1][key], results[0][key], err_msg=key)
    kinds = {p.name for p in disk.iterdir() if any(p.iterdir())}
    assert {"surface", "smoothed_undeformed"} <= kinds and "shading" not in kinds
    entries, size = diskcache.usage(disk)
    assert f"{entries} entries" in nlips("cache")
    assert "removed" in nlips("cache", "--clear") and diskcache.usage(disk) == (0, 0)


def test_a_level_assembled_by_the_fixed_pattern_map_solves_as_with_products(tmp_path, monkeypatch):
    from nlipscalib.core.metrics import angular_error_map
    from nlipscalib.solver import operators

    press = load_press(synth.make_press(tmp_path / "p", "sphere", size=(96, 72)))

    def solve():
        reuse.clear()
        np.random.seed(0)
        return solve_press(press, interreflection="off")

    products = solve()
    monkeypatch.setattr(operators, "OPERATOR_PERSIST_PIXELS", 1000)  # the whole gel's levels but the coarsest
    made = []
    make = operators._make_operators
    monkeypatch.setattr(operators, "_make_operators", lambda mk, **kw: made.append(make(mk, **kw)) or made[-1])
    fixed = solve()
    assert any(ops["normal"].fixed is not None for ops in made)
    made.clear()
    solve_press(press, roi=(10, 10, 60, 40), interreflection="off")  # an ROI: its masks do not recur
    assert made and all(isinstance(ops["normal"], operators._Assembler) for ops in made)  # by the grid's diagonals
    rec = products.reconstructed & fixed.reconstructed
    assert rec.sum() > 0.9 * products.reconstructed.sum()
    # rounding differs, and the Gauss-Newton/CG iterations stop at their tolerances from slightly other
    # iterates: differences far below the solver's own accuracy (0.3-0.5 deg on the twin)
    change = angular_error_map(fixed.normals, products.normals)[rec]
    assert float(np.median(change)) < 0.005 and float(np.max(change)) < 0.05
    np.testing.assert_allclose(fixed.depth[rec], products.depth[rec], atol=1e-3)


def _whole_gel_levels() -> list[np.ndarray]:
    """The masks of the whole gel's finest two levels (as :func:`nlipscalib.solver.pyramid.build_pyramid` halves
    them) at 160x120, of the default sensor (its gel fills the frame) and of its wide view (a footprint with black
    corners: a ragged edge)."""
    from nlipscalib.core.dome import reference_surface
    from nlipscalib.sim.scene import load_scene
    from nlipscalib.solver.pyramid import resize

    masks = []
    for name in ("nlipstac", "nlipstac_wide"):
        scene = load_scene(name).replace(camera={"width": 160, "height": 120})
        gel = np.isfinite(reference_surface(scene.design, scene.camera_model()).depth)
        masks += [gel, resize(gel.astype(np.float32), (60, 80)) > 0.999]
    return masks


def test_the_whole_gels_cached_levels_assemble_as_the_grid_stencil_does(disk, monkeypatch):
    """The whole gel's large levels keep their operators on disk with the fixed-pattern map; every other level
    assembles by the grid stencil, tested on small hand-made masks only. On such levels' own masks (a whole frame, a
    wide view's footprint), their operators read back from disk by a later process: the fixed-pattern map and the
    grid stencil give the known H (the explicit sum of P_a^T diag(M_ab) P_b and the weighted second differences'
    grams) to rounding, on one pattern (an unlit third's zeros left out alike); the stencil exactly symmetric, the map
    to rounding (here up to 256 of 249,036 entries differ from their mirror, by 1-2 units in the last place)."""
    import scipy.sparse as sp

    from nlipscalib.solver import operators

    monkeypatch.setattr(operators, "OPERATOR_PERSIST_PIXELS", 1000)  # 160x120's levels as 640x480's
    masks = _whole_gel_levels()
    assert not masks[2].all() and masks[0].all()  # the wide view's footprint; the default's whole frame
    for mk in masks:  # as a whole-gel solve makes them: kept on disk
        assert operators.level_operators({"mask": mk, "recurs": True})["normal"].fixed is not None
    diskcache.wait()
    reuse.clear()  # a new process: only the disk remembers
    monkeypatch.setattr(operators, "_make_operators", lambda *a, **k: pytest.fail("made again, not read from disk"))
    rng = np.random.default_rng(7)
    for mk in masks:
        ops = operators.level_operators({"mask": mk, "recurs": True})
        grid = operators._normal_matrix(ops, mk)  # the stencil every other level assembles with
        assert ops["normal"].fixed is not None and grid.stencil is not None
        n = int(mk.sum())
        P, E = (sp.identity(n, format="csr"), ops["Du"], ops["Dv"]), ops["second"]
        M = rng.normal(size=(3, 3, n))
        M = np.einsum("abn,cbn->acn", M, M)
        weights = (rng.uniform(0.01, 1.0, E[0].shape[0]), 0.3)
        for blocks in (M, np.where(np.arange(n) < n // 3, 0.0, M)):  # all lit; a third unlit
            known = sum(P[a].T @ sp.diags(blocks[a, b]) @ P[b] for a in range(3) for b in range(3))
            known = known + E[0].T @ sp.diags(weights[0]) @ E[0] + 0.3 * (E[1].T @ E[1])
            fixed, stencil = ops["normal"].assemble(blocks, weights), grid.assemble(blocks, weights)
            np.testing.assert_array_equal(stencil.indptr, fixed.indptr)
            np.testing.assert_array_equal(stencil.indices, fixed.indices)
            scale = abs(known).max()
            for H in (fixed, stencil):
                assert abs(H - known).max() < 1e-12 * scale and H.has_sorted_indices
                assert abs(H - H.T).max() <= 4 * np.finfo(float).eps * scale
            assert abs(stencil - stencil.T).max() == 0  # the map sums an entry and its mirror in other orders
