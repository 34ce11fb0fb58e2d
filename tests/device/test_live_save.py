"""`nlips infer/live --out DIR` frame saving: streams into one folder never share a temporary, and none is left."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nlipscalib.core import atomic
from nlipscalib.device import live
from nlipscalib.device.live import LiveResult, SaveSink
from nlipscalib.report.live import NormalMapPng


def _result() -> LiveResult:
    normals = np.zeros((6, 8, 3), np.float32)
    normals[..., 2] = 1.0
    return LiveResult(normals, np.ones((6, 8), np.float32))


def _sink(folder: Path) -> SaveSink:
    return SaveSink(folder, pictures=NormalMapPng())


def test_streams_saving_into_one_folder_never_share_a_temporary(tmp_path):
    """Every stream wrote frame N through `.tmp-frame_N.npz`: one stream moved another's half-written file into
    place, or failed with "DIR/frame_000007.npz -> DIR/frame_000007.npz: No such file or directory"."""
    other = tmp_path / ".tmp-frame_000000.npz"  # the name another stream writing frame 0 used
    other.write_bytes(b"another stream's half-written frame")
    _sink(tmp_path)(0, np.zeros((6, 8, 3), np.uint8), _result())
    assert other.read_bytes() == b"another stream's half-written frame"  # left to its writer
    with np.load(tmp_path / "frame_000000.npz") as saved:
        assert saved["normals"].shape == (6, 8, 3) and saved["depth"].shape == (6, 8)
    assert sorted(p.name for p in tmp_path.iterdir()) == [other.name, "frame_000000.npz", "frame_000000_normals.png"]


def test_a_frame_being_written_is_removed_by_sigterm_and_an_interrupted_one_leaves_nothing(tmp_path, monkeypatch):
    """SIGTERM of `nlips infer ... --out DIR` left `.tmp-frame_000011.npz`: the frame's temporary was not one the
    terminated command removes (core.atomic.remove_in_progress)."""
    seen = []

    def interrupted(path, arrays, compress=True):
        Path(path).write_bytes(b"half")
        seen.append(Path(path) in atomic._IN_PROGRESS)  # what the SIGTERM handler removes
        raise KeyboardInterrupt

    monkeypatch.setattr(live, "save_npz", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _sink(tmp_path)(0, np.zeros((6, 8, 3), np.uint8), _result())
    assert seen == [True]
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(atomic.TMP_PREFIX)]


def test_a_frame_stopped_between_its_picture_and_its_arrays_leaves_neither(tmp_path, monkeypatch):
    """Ctrl-C of `nlips live --out DIR` (s24 walk) left frame_000005_normals.png without frame_000005.npz, the
    summary saying "5 of 5 frames" saved."""
    _sink(tmp_path)(0, np.zeros((6, 8, 3), np.uint8), _result())

    def interrupted(path, arrays, compress=True):
        raise KeyboardInterrupt

    monkeypatch.setattr(live, "save_npz", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _sink(tmp_path)(1, np.zeros((6, 8, 3), np.uint8), _result())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_000000.npz", "frame_000000_normals.png"]


def test_dense_maps_of_a_stream_are_stored_not_deflated(tmp_path):
    """Deflating a 640x480 frame's normals and depth took 112 ms (s24 walk: `nlips live --out` saved 6 frames/s) for a
    file 14 % smaller; stored, 6 ms."""
    import zipfile

    rng = np.random.default_rng(0)
    normals = rng.normal(size=(6, 8, 3)).astype(np.float32)  # a frame's maps: dense, unlike _result()'s flat ones
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    depth = 20 + rng.normal(size=(6, 8)).astype(np.float32)
    _sink(tmp_path)(0, np.zeros((6, 8, 3), np.uint8), LiveResult(normals, depth))
    with zipfile.ZipFile(tmp_path / "frame_000000.npz") as saved:
        assert {i.filename: i.compress_type for i in saved.infolist()} == {
            "normals.npy": zipfile.ZIP_STORED,
            "depth.npy": zipfile.ZIP_STORED,
        }
