import re

import numpy as np
import pytest

from nlipscalib.core.errors import CaptureError
from nlipscalib.core.reconstruction import Reconstruction, load_reconstruction, save_reconstruction


def _rec(h=4, w=5):
    f = np.float32
    return Reconstruction(
        depth=np.full((h, w), 10, f),
        points=np.zeros((h, w, 3), f),
        normals=np.tile(np.array([0, 0, -1], f), (h, w, 1)),
        albedo=np.ones((h, w, 3), f),
        residual=np.zeros((h, w), f),
        confidence=np.ones((h, w), f),
        usable_leds=np.full((h, w), 12, np.int16),
        mask=np.ones((h, w), bool),
        reconstructed=np.ones((h, w), bool),
        report={"seconds": np.float64(1.5), "dead_leds": [3]},
    )


def test_round_trip_keeps_maps_and_report(tmp_path):
    save_reconstruction(_rec(), tmp_path / "nlips")
    back = load_reconstruction(tmp_path / "nlips", shape=(4, 5))
    assert np.array_equal(back.depth, _rec().depth) and back.report["dead_leds"] == [3]
    assert back.report["format"] == "nlipscalib.reconstruction"


def test_extra_files_are_published_with_the_result_or_nothing_is(tmp_path):
    """``extra_files`` (the figures) runs on a thread beside the arrays' writing: its files appear with the result,
    and its error is the save's, the folder then not published (an earlier result left as it was)."""
    import threading

    def figure(tmp):
        (tmp / "figure.png").write_bytes(threading.current_thread().name.encode())

    folder = save_reconstruction(_rec(), tmp_path / "nlips", extra_files=figure)
    assert (folder / "figure.png").read_bytes().startswith(b"save-extra")  # not the caller's thread
    assert load_reconstruction(folder).report["dead_leds"] == [3]

    def broken(tmp):
        (tmp / "half.png").write_bytes(b"x")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space left"):
        save_reconstruction(_rec(3, 3), folder, overwrite=True, extra_files=broken)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nlips"]  # no temporary folder left
    assert load_reconstruction(folder).shape == (4, 5) and (folder / "figure.png").is_file()


def test_damaged_or_mismatched_reconstruction_names_the_file(tmp_path):
    folder = save_reconstruction(_rec(), tmp_path / "nlips")
    with pytest.raises(CaptureError, match="result.npz.*expected"):
        load_reconstruction(folder, shape=(8, 8))
    data = (folder / "result.npz").read_bytes()
    (folder / "result.npz").write_bytes(data[: len(data) // 2])
    with pytest.raises(CaptureError, match="result.npz: damaged"):
        load_reconstruction(folder)
    (folder / "report.json").write_text('{"format": "other"}', encoding="utf-8")
    with pytest.raises(CaptureError, match="report.json"):
        load_reconstruction(folder)


def test_problem_check_is_cheap_and_names_the_damage(tmp_path):
    from nlipscalib.core.reconstruction import reconstruction_dir, reconstruction_problem

    folder = save_reconstruction(_rec(), tmp_path / "nlips")
    assert reconstruction_problem(folder) is None
    data = (folder / "result.npz").read_bytes()
    (folder / "result.npz").write_bytes(data[:-30])
    assert "damaged or truncated" in reconstruction_problem(folder)
    assert "missing" in reconstruction_problem(tmp_path / "none")
    assert reconstruction_dir(tmp_path, method="nlipsnet") == tmp_path / "nlipsnet"
    with pytest.raises(CaptureError, match="method"):
        reconstruction_dir(tmp_path, method="other")


def test_auto_compression_stores_dense_maps_and_deflates_sparse_ones(tmp_path):
    import zipfile

    from nlipscalib.core.imageio import save_npz

    dense = np.random.default_rng(0).random((40, 50)).astype(np.float32)
    roi_only = np.full((40, 50), np.nan, np.float32)
    roi_only[5:10, 5:10] = 1.0
    path = save_npz(tmp_path / "a.npz", {"dense": dense, "roi": roi_only, "mask": dense > 0.5}, compress="auto")
    kinds = {i.filename: i.compress_type for i in zipfile.ZipFile(path).infolist()}
    assert kinds == {"dense.npy": zipfile.ZIP_STORED, "roi.npy": zipfile.ZIP_DEFLATED, "mask.npy": zipfile.ZIP_DEFLATED}
    with np.load(path) as data:
        assert np.array_equal(data["dense"], dense) and np.array_equal(data["roi"], roi_only, equal_nan=True)


def _spoil_deflated_member(path, member: str) -> None:
    """Overwrite a deflated member's data with 0xFF: zlib then fails ("invalid block type"), not the zip layer."""
    import zipfile

    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
        assert info.compress_type == zipfile.ZIP_DEFLATED
    data = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)  # past the local header
    data[start : start + info.compress_size] = b"\xff" * info.compress_size
    path.write_bytes(bytes(data))


def test_a_damaged_deflated_array_is_named_not_a_zlib_traceback(tmp_path):
    save_reconstruction(_rec(40, 50), tmp_path / "nlips")
    _spoil_deflated_member(tmp_path / "nlips" / "result.npz", "mask.npy")
    with pytest.raises(
        CaptureError, match=r"result\.npz: damaged or truncated reconstruction \(compressed data damaged"
    ):
        load_reconstruction(tmp_path / "nlips")


def test_verifying_finds_damage_the_zip_directory_does_not_show(tmp_path):
    from nlipscalib.core.reconstruction import reconstruction_problem

    save_reconstruction(_rec(40, 50), tmp_path / "nlips")
    _spoil_deflated_member(tmp_path / "nlips" / "result.npz", "mask.npy")
    assert reconstruction_problem(tmp_path / "nlips") is None  # the cheap check: every array is listed
    problem = reconstruction_problem(tmp_path / "nlips", verify=True)
    assert "result.npz: damaged" in problem and "mask" in problem


@pytest.mark.parametrize("spoil", ["nan normals", "nan depth", "not unit"])
def test_a_result_that_breaks_its_own_promise_is_refused_and_not_reused(tmp_path, spoil):
    """Reconstructed pixels carry a finite depth and a finite unit normal: a result of NaN (a diverged solve, a
    network with NaN weights, a hand-made file) is named by the loader and by the reuse check, not scored."""
    from nlipscalib.core.reconstruction import reconstruction_problem

    rec = _rec()
    if spoil == "nan normals":
        rec.normals[1:3] = np.nan
    elif spoil == "nan depth":
        rec.depth[0, 0] = np.nan
    else:
        rec.normals[0, 0] = (0, 0, -0.5)
    folder = save_reconstruction(rec, tmp_path / "nlips")
    word = "depth" if spoil == "nan depth" else "normals"
    with pytest.raises(CaptureError, match=f"result.npz: array '{word}' is not .*finite.* reconstructed pixels"):
        load_reconstruction(folder)
    assert reconstruction_problem(folder) is None  # the cheap check reads no array
    assert f"array '{word}'" in reconstruction_problem(folder, verify=True)
    rec.reconstructed[...] = False  # NaN where nothing was reconstructed is what the format says
    assert load_reconstruction(save_reconstruction(rec, tmp_path / "other")).reconstructed.sum() == 0


def test_only_an_empty_folder_or_a_reconstruction_is_replaced(tmp_path):
    from nlipscalib.core.reconstruction import replace_problem

    assert replace_problem(tmp_path / "absent") is None
    (tmp_path / "empty").mkdir()
    assert replace_problem(tmp_path / "empty") is None
    old = save_reconstruction(_rec(), tmp_path / "old")
    (old / "result.npz").write_bytes(b"damaged")
    assert replace_problem(old) is None
    (tmp_path / "file").write_text("x", encoding="utf-8")
    assert "is not a folder (a file" in replace_problem(tmp_path / "file")
    (old / "sub").mkdir()
    assert "other things" in replace_problem(old)
    with pytest.raises(CaptureError, match="other things"):
        save_reconstruction(_rec(), old, overwrite=True)


def _roi_rec(h=12, w=16):
    """A result solved on a box inside the frame: NaN, 0 and False outside its mask, as the solver writes it."""
    rng = np.random.default_rng(1)
    rec = _rec(h, w)
    mask = np.zeros((h, w), bool)
    mask[3:9, 4:11] = True
    mask[3, 4] = False  # the box is the mask's bounding box, not its every pixel
    for name, fill in (("depth", np.nan), ("residual", np.nan), ("confidence", 0), ("usable_leds", 0)):
        a = getattr(rec, name)
        a[mask] = rng.random(int(mask.sum())) * 5 + 1
        a[~mask] = fill
    for name in ("points", "normals", "albedo"):
        getattr(rec, name)[~mask] = np.nan
    rec.mask[...] = mask
    rec.reconstructed[...] = mask
    return rec


def _same_bits(a: Reconstruction, b: Reconstruction) -> bool:
    return all(
        x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
        for x, y in zip(a.arrays().values(), b.arrays().values(), strict=True)
    )


def test_an_roi_result_is_stored_on_its_box_and_read_back_full_frame_bit_for_bit(tmp_path):
    folder = save_reconstruction(_roi_rec(), tmp_path / "nlips")
    with np.load(folder / "result.npz") as npz:
        assert npz["box"].tolist() == [4, 3, 7, 6] and npz["frame"].tolist() == [12, 16]
        assert npz["depth"].shape == (6, 7) and npz["normals"].shape == (6, 7, 3)
    back = load_reconstruction(folder, shape=(12, 16))
    assert _same_bits(back, _roi_rec()) and back.report["format_version"] == 2


def test_the_box_covers_whatever_a_map_says_outside_the_mask(tmp_path):
    """A value off the mask (here a NaN of the other sign, which compares equal to NaN but not bit for bit)
    widens the box, so the maps still come back as they were written."""
    rec = _roi_rec()
    rec.albedo[10, 1, 2] = -np.float32(np.nan)
    folder = save_reconstruction(rec, tmp_path / "nlips")
    with np.load(folder / "result.npz") as npz:
        assert npz["box"].tolist() == [1, 3, 10, 8]
    assert _same_bits(load_reconstruction(folder), rec)


def test_a_result_with_nothing_solved_has_an_empty_box(tmp_path):
    rec = _roi_rec()
    for name, a in rec.arrays().items():
        a[...] = {"confidence": 0, "usable_leds": 0, "mask": False, "reconstructed": False}.get(name, np.nan)
    folder = save_reconstruction(rec, tmp_path / "nlips")
    with np.load(folder / "result.npz") as npz:
        assert npz["box"].tolist() == [0, 0, 0, 0] and npz["depth"].shape == (0, 0)
    assert _same_bits(load_reconstruction(folder, shape=(12, 16)), rec)


def _save_version_1(rec: Reconstruction, folder):
    """What the version 1 writer (nlipscalib up to 202cd61) wrote: full-frame maps, the same member compression."""
    from nlipscalib import __version__
    from nlipscalib.core.atomic import write_json
    from nlipscalib.core.imageio import save_npz
    from nlipscalib.core.reconstruction import FORMAT_NAME, jsonable

    folder.mkdir()
    save_npz(folder / "result.npz", rec.arrays(), compress="auto")
    head = {"format": FORMAT_NAME, "format_version": 1, "software_version": __version__}
    write_json(folder / "report.json", head | jsonable(rec.report))
    return folder


def test_version_1_results_still_load_and_are_rewritten_as_version_2(tmp_path):
    from nlipscalib.core.reconstruction import reconstruction_problem

    old = _save_version_1(_roi_rec(), tmp_path / "old")
    with np.load(old / "result.npz") as npz:
        assert npz["depth"].shape == (12, 16) and "box" not in npz.files
    assert reconstruction_problem(old, verify=True) is None
    back = load_reconstruction(old, shape=(12, 16))
    assert _same_bits(back, _roi_rec()) and back.report["format_version"] == 1
    with pytest.raises(CaptureError, match=r"result\.npz: array 'depth' is \(12, 16\) float32, expected \(8, 8\)"):
        load_reconstruction(old, shape=(8, 8))
    new = save_reconstruction(back, tmp_path / "new")  # its report says version 1: the header written wins
    assert load_reconstruction(new).report["format_version"] == 2 and _same_bits(load_reconstruction(new), back)


def _rewrite(folder, **changes):
    """Replace arrays of ``folder``'s result.npz (a damaged or hand-made file)."""
    from nlipscalib.core.imageio import save_npz

    with np.load(folder / "result.npz") as npz:
        arrays = {k: npz[k] for k in npz.files}
    save_npz(folder / "result.npz", arrays | changes)


@pytest.mark.parametrize(
    ("changes", "problem"),
    [
        ({"box": np.array([10, 3, 7, 6])}, r"box \[x0, y0, w, h\] = \[10, 3, 7, 6\] is not inside its 12x16 frame"),
        ({"box": np.array([-1, 3, 7, 6])}, r"box \[x0, y0, w, h\] = \[-1, 3, 7, 6\] is not inside"),
        ({"box": np.array([4, 3, 7])}, r"damaged reconstruction \(box \(3,\) int64 and frame"),
        ({"box": np.array([4.0, 3, 7, 6])}, r"expected 4 and 2 integers"),
        ({"frame": np.array([0, 16])}, r"frame \[H, W\] = \[0, 16\] is not an image size"),
        (
            {"box": np.array([4, 3, 7, 5])},
            r"array 'depth' is \(6, 7\) float32, expected \(5, 7\) of kind 'f' \(its",
        ),
        ({"normals": np.zeros((6, 8, 3), np.float32)}, r"array 'normals' is \(6, 8, 3\) float32, expected \(6, 7, 3\)"),
    ],
)
def test_a_damaged_or_inconsistent_box_is_named_with_the_file(tmp_path, changes, problem):
    from nlipscalib.core.reconstruction import reconstruction_problem

    folder = save_reconstruction(_roi_rec(), tmp_path / "nlips")
    _rewrite(folder, **changes)
    with pytest.raises(CaptureError, match=rf"nlips/result\.npz: .*{problem}"):
        load_reconstruction(folder)
    assert re.search(problem, reconstruction_problem(folder, verify=True))  # the reuse check says the same


def test_a_box_result_of_another_image_size_is_refused(tmp_path):
    from nlipscalib.core.reconstruction import reconstruction_problem

    folder = save_reconstruction(_roi_rec(), tmp_path / "nlips")
    with pytest.raises(
        CaptureError, match=r"result\.npz: a result of a \(12, 16\) image \(H, W\), expected \(480, 640\)"
    ):
        load_reconstruction(folder, shape=(480, 640))
    import zipfile

    with zipfile.ZipFile(folder / "result.npz") as zf:  # a version 2 file without its box
        arrays = {n: zf.read(n) for n in zf.namelist() if n != "box.npy"}
    with zipfile.ZipFile(folder / "result.npz", "w") as zf:
        for n, data in arrays.items():
            zf.writestr(n, data)
    assert "missing arrays ['box']" in reconstruction_problem(folder)
    with pytest.raises(CaptureError, match=r"result\.npz: missing arrays \['box'\]"):
        load_reconstruction(folder)


def test_a_later_format_version_is_named(tmp_path):
    import json

    folder = save_reconstruction(_rec(), tmp_path / "nlips")
    report = json.loads((folder / "report.json").read_text(encoding="utf-8")) | {"format_version": 3}
    (folder / "report.json").write_text(json.dumps(report), encoding="utf-8")
    with pytest.raises(CaptureError, match=r"report\.json: format_version 3 is not supported \(expected 1 or 2\)"):
        load_reconstruction(folder)


def test_an_error_names_the_folder_as_given_not_its_absolute_path(tmp_path, monkeypatch):
    """`nlips infer ... --out bad/../ro/inf` on read-only media said "/home/.../bad/../ro/inf: Read-only file
    system": the folder was made absolute before any write."""
    import errno
    import os

    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad").mkdir()
    real_mkdir = os.mkdir

    def mkdir(path, *args, **kwargs):
        if "ro" in os.fspath(path).split(os.sep):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), os.fspath(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(os, "mkdir", mkdir)
    with pytest.raises(OSError) as caught:
        save_reconstruction(_rec(), "bad/../ro/inf")
    assert str(caught.value.filename).startswith("bad/../ro"), caught.value.filename
    (tmp_path / "here").mkdir()
    monkeypatch.chdir(tmp_path / "here")
    save_reconstruction(_rec(), ".", overwrite=True)  # "." still has a name to write beside: the working folder's
    assert load_reconstruction(tmp_path / "here").shape == (4, 5)


def test_save_and_load_of_another_kind_name_the_argument(tmp_path):
    """save_reconstruction("x", folder) failed with an AttributeError from inside the write."""
    from nlipscalib.core.errors import ShapeError

    with pytest.raises(ShapeError, match="rec must be a Reconstruction .*got str 'x'"):
        save_reconstruction("x", tmp_path / "r")
    with pytest.raises(ShapeError, match="folder must be the output folder's path .*got NoneType"):
        save_reconstruction(_rec(), None)
    with pytest.raises(ShapeError, match="folder must be a reconstruction folder's path"):
        load_reconstruction(1.5)
    assert not (tmp_path / "r").exists()
