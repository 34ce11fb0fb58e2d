"""A folder watched for frames (device.watch_folder): files read once whole, in the order they land; the rest skipped.

No sleeps and no timing asserts: each test writes after the watch started (its observer runs from the constructor)
and waits on the watch's own state; ``stop`` bounds every wait (a failure, never a hang)."""

import logging
import os
import time

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")
pytest.importorskip("watchdog")

from nlipscalib.core.errors import CaptureError  # noqa: E402
from nlipscalib.core.imageio import write_png16  # noqa: E402
from nlipscalib.device.live import StopLive  # noqa: E402
from nlipscalib.device.watch_folder import WatchedFolder, network_file_system  # noqa: E402

SHAPE = (12, 16)
GIVE_UP_S = 300.0
"""A wait that has not ended by then is a failure (an event that never came), not a hang."""


def _frame(value: int, shape=SHAPE) -> np.ndarray:
    return np.full(shape + (3,), value, np.uint16)


def _png_bytes(value: int, tmp_path, shape=SHAPE) -> bytes:
    scratch = tmp_path / f"scratch_{value}.png"
    write_png16(scratch, _frame(value, shape))
    return scratch.read_bytes()


def _renamed_into_place(folder, name: str, value: int, shape=SHAPE) -> None:
    """Write a frame as most camera programs do: into a hidden temporary, then renamed to its name."""
    tmp = folder / f".{name}.part"
    write_png16(tmp, _frame(value, shape))
    os.replace(tmp, folder / name)


def _bounded(source: WatchedFolder, until=lambda: False) -> None:
    """Make ``source.read`` give up (StopLive) once ``until()`` holds, and fail after :data:`GIVE_UP_S`."""
    deadline = time.monotonic() + GIVE_UP_S

    def stop() -> bool:
        if time.monotonic() > deadline:
            pytest.fail("the watch waited past the test's limit")
        return until()

    source.stop = stop


def _read_all(source: WatchedFolder, n: int) -> list[tuple[str, int]]:
    _bounded(source)
    return [(lambda f: (source.current.name, int(f[0, 0, 0])))(source.read()) for _ in range(n)]


@pytest.fixture
def folder(tmp_path):
    watched = tmp_path / "incoming"
    watched.mkdir()
    return watched


def test_frames_renamed_in_or_written_in_place_are_read_in_the_order_they_land(folder, tmp_path):
    with WatchedFolder(folder, SHAPE) as source:
        _renamed_into_place(folder, "z_first.png", 1000)
        (folder / "a_second.png").write_bytes(_png_bytes(2000, tmp_path))  # written in place: its close says whole
        _renamed_into_place(folder, "m_third.png", 3000)
        assert _read_all(source, 3) == [("z_first.png", 1000), ("a_second.png", 2000), ("m_third.png", 3000)]


def test_a_file_being_written_in_place_is_not_read_before_its_writer_closes_it(folder, tmp_path):
    """A writer that pauses mid-file longer than the settle time: on inotify (Linux) its file waits for the close."""
    data = _png_bytes(4242, tmp_path)
    with WatchedFolder(folder, SHAPE, settle_s=0.05) as source:
        if not source._closes:
            pytest.skip("no close events here (not inotify): the settle time alone decides")
        path = str(folder / "slow.png")
        with open(path, "wb") as writer:
            writer.write(data[: len(data) // 2])
            writer.flush()

            def settled_but_open() -> bool:  # the settle rule would take it now, were its writer not known to write
                landing = source._landing.get(path)
                return (
                    landing is not None
                    and landing.signature is not None
                    and landing.writing
                    and time.monotonic() - landing.since > 4 * source.settle_s
                )

            _bounded(source, settled_but_open)
            with pytest.raises(StopLive):
                source.read()  # returned nothing: half a file is never read
            writer.write(data[len(data) // 2 :])
        _bounded(source)
        np.testing.assert_array_equal(source.read(), _frame(4242))
        assert source.current.name == "slow.png"


def test_a_file_written_again_is_read_again_and_an_unchanged_one_never(folder):
    with WatchedFolder(folder, SHAPE) as source:
        _renamed_into_place(folder, "latest.png", 100)
        assert _read_all(source, 1) == [("latest.png", 100)]
        _renamed_into_place(folder, "latest.png", 200)  # a camera that rewrites one file
        _renamed_into_place(folder, "next.png", 300)
        assert _read_all(source, 2) == [("latest.png", 200), ("next.png", 300)]


def test_other_files_unreadable_images_and_other_sizes_are_skipped_with_a_warning(folder, caplog):
    with caplog.at_level(logging.WARNING), WatchedFolder(folder, SHAPE) as source:
        (folder / "notes.txt").write_text("not a frame", encoding="utf-8")
        (folder / "frame.png.tmp").write_text("a writer's temporary", encoding="utf-8")
        (folder / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\x00" * 40)
        _renamed_into_place(folder, "big.png", 7, shape=(13, 16))
        _renamed_into_place(folder, "good.png", 500)
        assert _read_all(source, 1) == [("good.png", 500)]
    said = [r.getMessage() for r in caplog.records]
    assert any(m.startswith(f"{folder / 'notes.txt'}: not an image (.png") for m in said), said
    assert any(m.startswith(f"{folder / 'broken.png'}:") and "skipped, the watch goes on" in m for m in said), said
    assert f"{folder / 'big.png'}: image is 16x13, the model's frames are 16x12; skipped, the watch goes on" in said
    assert not any("frame.png.tmp" in m for m in said), said  # a temporary is a writer's work in progress
    assert source.skipped == 3


def test_images_already_there_are_skipped_or_read_first_in_name_order(folder):
    for name, value in (("b.png", 2), ("a.png", 1)):
        write_png16(folder / name, _frame(value))
    with WatchedFolder(folder, SHAPE) as source:
        assert source.existing == 2
        _renamed_into_place(folder, "c.png", 3)
        assert _read_all(source, 1) == [("c.png", 3)]
    with WatchedFolder(folder, SHAPE, existing="infer", settle_s=0.0) as source:
        assert _read_all(source, 3) == [("a.png", 1), ("b.png", 2), ("c.png", 3)]


def test_polling_reads_a_file_once_it_stops_changing(folder, tmp_path):
    """Where no event says a file is whole (a network share: polled), it is read once unchanged for the settle time."""
    with WatchedFolder(folder, SHAPE, poll=True, settle_s=0.05) as source:
        assert source.polling and not source._closes
        (folder / "f.png").write_bytes(_png_bytes(77, tmp_path))
        assert _read_all(source, 1) == [("f.png", 77)]


def test_stop_ends_a_wait_and_a_removed_folder_is_one_line(folder):
    with WatchedFolder(folder, SHAPE) as source:
        _bounded(source, lambda: True)
        with pytest.raises(StopLive):
            source.read()
        folder.rmdir()
        _bounded(source)
        with pytest.raises(CaptureError, match="the watched folder was removed"):
            source.read()


def test_a_missing_folder_or_a_file_is_refused_in_one_line(tmp_path):
    with pytest.raises(CaptureError, match=f"^{tmp_path / 'nope'}: no such folder to watch$"):
        WatchedFolder(tmp_path / "nope", SHAPE)
    (tmp_path / "file.png").write_bytes(b"x")
    with pytest.raises(CaptureError, match="not a folder"):
        WatchedFolder(tmp_path / "file.png", SHAPE)


def test_network_file_systems_are_told_by_the_folders_mount():
    mountinfo = (
        "22 1 8:1 / / rw,relatime shared:1 - ext4 /dev/sda1 rw\n"
        "40 22 0:45 / /mnt/lab rw,relatime shared:20 - nfs4 server:/export rw,vers=4.2\n"
        "41 40 0:46 / /mnt/lab/local rw shared:21 - tmpfs tmpfs rw\n"
        "42 22 0:47 / /mnt/my\\040share rw - cifs //pc/share rw\n"
    )
    assert network_file_system("/mnt/lab/frames", mountinfo) == "nfs4"
    assert network_file_system("/mnt/lab", mountinfo) == "nfs4"
    assert network_file_system("/mnt/lab/local/frames", mountinfo) is None  # a local mount inside the share
    assert network_file_system("/mnt/labs", mountinfo) is None  # not under /mnt/lab
    assert network_file_system("/mnt/my share/x", mountinfo) == "cifs"
    assert network_file_system("/home/u/frames", mountinfo) is None


def test_a_long_watch_remembers_a_bounded_number_of_files_and_a_rescan_reads_none_again(folder, monkeypatch):
    """Each file read is remembered (not to be read again) among the latest READ_MEMORY only: a watch of hours keeps
    no entry per frame. Lost events (inotify's queue overflowed) make the watch look at every file again: the files
    read before, remembered or forgotten, and those skipped at the start are not read again; a new one is."""
    from nlipscalib.device import watch_folder

    monkeypatch.setattr(watch_folder, "READ_MEMORY", 2)
    write_png16(folder / "before.png", _frame(9))
    with WatchedFolder(folder, SHAPE) as source:
        for i in range(5):
            _renamed_into_place(folder, f"f{i}.png", i + 1)
        assert [v for _, v in _read_all(source, 5)] == [1, 2, 3, 4, 5]
        assert len(source._read) == 2
        source._rescan()
        _renamed_into_place(folder, "new.png", 6)
        assert _read_all(source, 1) == [("new.png", 6)]
        assert set(source._landing) <= {str(folder / "new.png")}


def test_without_a_shape_the_first_image_read_sets_it_and_another_size_is_skipped_naming_it(folder, caplog):
    """A --predictor stream has no model to give the size: the first image read sets it."""
    with WatchedFolder(folder, None) as source:
        assert source.shape is None
        _renamed_into_place(folder, "first.png", 1000, shape=(6, 8))
        _renamed_into_place(folder, "big.png", 2000)
        _renamed_into_place(folder, "second.png", 3000, shape=(6, 8))
        with caplog.at_level(logging.WARNING):
            assert _read_all(source, 2) == [("first.png", 1000), ("second.png", 3000)]
        assert source.shape == (6, 8) and source.skipped == 1
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert any(
        m.startswith(f"{folder / 'big.png'}: image is 16x12, the stream's first frame (first.png) is 8x6; skipped")
        for m in warned
    ), warned
