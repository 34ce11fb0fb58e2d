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
    (folder / "report.json").write_text('{"format": "other"}')
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
    (tmp_path / "file").write_text("x")
    assert "is not a folder (a file" in replace_problem(tmp_path / "file")
    (old / "sub").mkdir()
    assert "other things" in replace_problem(old)
    with pytest.raises(CaptureError, match="other things"):
        save_reconstruction(_rec(), old, overwrite=True)
