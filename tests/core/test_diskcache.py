"""The disk tier for sensor-level results (core/diskcache.py): keys by content, atomic entries, size bound."""

import dataclasses
import logging
import os
import threading

import numpy as np
import pytest

from nlipscalib.core import diskcache


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setenv(diskcache.ENV_DIR, str(tmp_path / "cache"))
    return tmp_path / "cache"


@dataclasses.dataclass(frozen=True)
class _Thing:
    size: float
    values: tuple


def test_stable_key_names_content_not_identity():
    a = np.arange(6, dtype=np.float32).reshape(2, 3)
    assert diskcache.stable_key((a, "x", 1.5)) == diskcache.stable_key((a.copy(), "x", 1.5))
    b = a.copy()
    b[0, 0] += 1e-6
    assert diskcache.stable_key(a) != diskcache.stable_key(b)
    assert diskcache.stable_key(a) != diskcache.stable_key(a.astype(np.float64))
    assert diskcache.stable_key(a) != diskcache.stable_key(a.reshape(3, 2))
    # a large array is named by its whole content (repr would elide the middle: "...")
    big = np.zeros(10_000)
    other = big.copy()
    other[5_000] = 1.0
    assert diskcache.stable_key(big) != diskcache.stable_key(other)
    assert diskcache.stable_key(_Thing(1.0, (2, 3))) == diskcache.stable_key(_Thing(1.0, (2, 3)))
    assert diskcache.stable_key(_Thing(1.0, (2, 3))) != diskcache.stable_key(_Thing(1.0, (2, 4)))
    assert diskcache.stable_key(np.float64(0.1)) == diskcache.stable_key(0.1)


def test_a_size_bound_that_is_no_number_is_said_and_the_default_kept(monkeypatch, caplog):
    monkeypatch.setenv(diskcache.ENV_MB, "lots")
    assert diskcache.limit_bytes() == diskcache.DEFAULT_MB * 2**20
    assert "NLIPS_CACHE_MB='lots' is not a number" in caplog.text
    monkeypatch.setenv(diskcache.ENV_MB, "1.5")
    assert diskcache.limit_bytes() == int(1.5 * 2**20)


def test_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(diskcache.ENV_DIR, "off")
    assert diskcache.folder() is None and diskcache.entry("k", ("a",)) is None
    monkeypatch.delenv(diskcache.ENV_DIR)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert diskcache.folder() == tmp_path / "nlipscalib"


def test_an_entry_round_trips_and_a_damaged_one_is_a_miss(cache_dir):
    path = diskcache.entry("shading", ("camera", np.ones(3)))
    assert path.parent.parent == cache_dir
    with pytest.raises(KeyError):
        diskcache.load(path)
    value = {"a": np.arange(5.0), "b": (1, "x")}
    diskcache.store(path, value)
    back = diskcache.load(path)
    np.testing.assert_array_equal(back["a"], value["a"])
    assert back["b"] == (1, "x")
    path.write_bytes(path.read_bytes()[:20])  # truncated (a full disk, a killed writer of another tool)
    with pytest.raises(KeyError):
        diskcache.load(path)
    assert diskcache.entry("shading", ("camera", np.ones(3))) == path
    assert diskcache.entry("shading", ("camera", np.zeros(3))) != path


def test_another_source_salt_misses_every_earlier_entry(cache_dir, monkeypatch):
    before = diskcache.entry("k", ("a",))
    monkeypatch.setattr(diskcache, "_salt", "an edited formula")
    assert diskcache.entry("k", ("a",)) != before


def test_a_write_that_fails_costs_only_the_computation(cache_dir):
    path = diskcache.entry("k", ("lambda",))
    diskcache.store(path, {"f": lambda: 1})  # not picklable: logged, not raised
    assert not path.exists() and not (path.parent.exists() and list(path.parent.iterdir()))  # nor half an entry
    diskcache.store_later(path, {"f": lambda: 1})  # in the background: the same
    diskcache.wait()
    assert not path.exists() and not (path.parent.exists() and list(path.parent.iterdir()))
    blocked = diskcache.entry("blocked", ("x",))
    cache_dir.mkdir(parents=True, exist_ok=True)
    (cache_dir / "blocked").write_text("a file where the kind's folder should be", encoding="utf-8")
    diskcache.store(blocked, np.zeros(3))  # OSError: logged, not raised
    assert not blocked.is_file()


def test_writers_of_one_key_at_once_leave_one_readable_entry(cache_dir):
    path = diskcache.entry("k", ("shared",))
    value = np.arange(200_000, dtype=np.float64)
    errors = []

    def write():
        try:
            for _ in range(5):
                diskcache.store(path, value)
                np.testing.assert_array_equal(diskcache.load(path), value)
        except Exception as exc:  # noqa: BLE001 - collected and asserted below
            errors.append(exc)

    threads = [threading.Thread(target=write) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert [p.name for p in path.parent.iterdir()] == [path.name]  # no temporary file left behind


def test_a_dead_writers_temporary_file_goes_with_the_next_write(cache_dir):
    from nlipscalib.core import atomic

    path = diskcache.entry("k", ("x",))
    path.parent.mkdir(parents=True)
    dead = path.parent / (atomic.TMP_PREFIX + path.name + f"~{atomic.HOST}~999999999~abc")
    dead.write_bytes(b"half a pickle")
    alive = path.parent / (atomic.tmp_prefix(path.name) + "def")  # this process: a write in progress
    alive.write_bytes(b"being written")
    diskcache.store(path, np.zeros(3))
    assert not dead.exists() and alive.exists() and path.is_file()


def test_the_size_bound_removes_the_least_recently_used(cache_dir, monkeypatch):
    paths = [diskcache.entry("k", (i,)) for i in range(4)]
    for i, path in enumerate(paths):
        diskcache.store(path, np.zeros(100_000, np.uint8))
        os.utime(path, (1000.0 + i, 1000.0 + i))
    diskcache.load(paths[0])  # read now: the most recently used
    monkeypatch.setenv(diskcache.ENV_MB, str(2.5 * 100_000 / 2**20))
    diskcache.store(diskcache.entry("k", ("new",)), np.zeros(10, np.uint8))
    left = {p for p in paths if p.exists()}
    assert left == {paths[0], paths[3]}
    entries, size = diskcache.usage()
    assert entries == 3 and size <= diskcache.limit_bytes()
    assert diskcache.clear() == size and diskcache.usage() == (0, 0)


def test_an_entry_holding_another_object_is_removed_with_a_warning_and_recomputed(cache_dir, caplog):
    """A readable pickle that is no entry of this program (``{'wrong': 1}`` under an entry's name) was served:
    the solver failed on it with "AttributeError: 'dict' object has no attribute 'size'"."""
    import logging
    import pickle

    from nlipscalib.core.blas import blas_setting
    from nlipscalib.solver import reuse

    path = diskcache.entry("thing", ("x",))
    diskcache.store(path, _Thing(1.0, (2,)))
    assert diskcache.load(path) == _Thing(1.0, (2,))
    path.write_bytes(pickle.dumps({"wrong": 1}))
    caplog.set_level(logging.WARNING)
    with pytest.raises(KeyError):
        diskcache.load(path)
    assert "holds no result of this program: removed, recomputing" in caplog.text and str(path) in caplog.text
    assert not path.exists()
    reuse.clear()
    served = diskcache.entry("thing", (("x",), blas_setting()))  # where reused() looks
    served.write_bytes(pickle.dumps({"wrong": 1}))
    assert reuse.reused("thing", ("x",), lambda: _Thing(3.0, ()), persist=True) == _Thing(3.0, ())
    assert diskcache.load(served) == _Thing(3.0, ())  # replaced by the recomputed result
    reuse.clear()


@pytest.mark.parametrize("text", ["-5", "inf", "nan"])
def test_a_size_bound_below_zero_or_infinite_is_said_once_and_the_default_kept(monkeypatch, caplog, text):
    """``NLIPS_CACHE_MB=-5`` was taken (``nlips cache`` printed "at most -5 MB"); ``inf`` overflowed."""
    import logging

    caplog.set_level(logging.WARNING)
    monkeypatch.setattr(diskcache, "_warned", set())
    monkeypatch.setenv(diskcache.ENV_MB, text)
    assert diskcache.limit_bytes() == diskcache.limit_bytes() == diskcache.DEFAULT_MB * 2**20
    said = [r for r in caplog.records if "is not a number of megabytes >= 0" in r.getMessage()]
    assert len(said) == 1 and repr(text) in said[0].getMessage()


def test_a_cache_folder_that_is_a_file_turns_the_cache_off_with_one_warning(tmp_path, monkeypatch, caplog):
    """It turned the cache off without a word (``nlips cache`` printed "0 entries")."""
    import logging

    caplog.set_level(logging.WARNING)
    monkeypatch.setattr(diskcache, "_warned", set())
    (tmp_path / "cache").write_text("not a folder", encoding="utf-8")
    monkeypatch.setenv(diskcache.ENV_DIR, str(tmp_path / "cache"))
    assert diskcache.folder() is None and diskcache.entry("k", ("a",)) is None
    said = [r for r in caplog.records if "is a file, not a folder: the disk cache is off" in r.getMessage()]
    assert len(said) == 1 and str(tmp_path / "cache") in said[0].getMessage()


def test_a_cache_folder_that_cannot_be_written_is_said_once(tmp_path, monkeypatch, caplog):
    """NLIPS_CACHE_DIR=/proc/nope showed as a working, empty cache, and every command recomputed unsaid."""
    import errno
    import logging

    from nlipscalib.core import atomic

    caplog.set_level(logging.WARNING)
    monkeypatch.setattr(diskcache, "_warned", set())
    monkeypatch.setenv(diskcache.ENV_DIR, str(tmp_path / "cache"))

    def refused(path, writer):
        raise OSError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(atomic, "write_with", refused)
    for value in (1, 2):
        diskcache.store(diskcache.entry("k", (value,)), value)
    said = [r for r in caplog.records if "cannot be written (Permission denied)" in r.getMessage()]
    assert len(said) == 1 and str(tmp_path / "cache") in said[0].getMessage()


def test_a_full_cache_disk_is_said_once_as_full_and_leaves_a_miss(tmp_path, monkeypatch, caplog):
    """A cache on a full disk (s25 walk, a 3 MB tmpfs) was "cannot be written (No space left on device): ... set
    NLIPS_CACHE_DIR to a writable folder" beside the entries that fit; it is said once as full, and the entry is a
    miss (recomputed), never an error."""
    import errno
    import logging
    import os

    from nlipscalib.core import atomic

    caplog.set_level(logging.WARNING)
    monkeypatch.setattr(diskcache, "_warned", set())
    monkeypatch.setenv(diskcache.ENV_DIR, str(tmp_path / "cache"))

    def full(path, writer):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(atomic, "write_with", full)
    for value in (1, 2):
        path = diskcache.entry("k", (value,))
        diskcache.store(path, value)
        with pytest.raises(KeyError):  # a miss: recomputed, never a half entry
            diskcache.load(path)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "is on a full disk (No space left on device)" in said[0], said
    assert str(tmp_path / "cache") in said[0] and diskcache.ENV_MB in said[0]


def test_usage_skips_an_entry_removed_while_it_is_counted(cache_dir, monkeypatch):
    """`nlips cache` next to a `--clear` or the size bound of another process: an entry listed, then removed,
    was a FileNotFoundError traceback."""
    from pathlib import Path

    path = diskcache.entry("shading", ("camera", np.ones(3)))
    diskcache.store(path, {"a": np.arange(5.0)})
    gone = path.with_name("removed-meanwhile" + diskcache.SUFFIX)
    listed = Path.glob
    monkeypatch.setattr(Path, "glob", lambda self, pattern: [*listed(self, pattern), gone])
    assert diskcache.usage(cache_dir) == (1, path.stat().st_size)


def test_a_background_write_is_waited_for_by_a_read_of_its_entry(cache_dir, monkeypatch):
    """``store_later`` returns before the entry is written; a read of it in the same process waits, and the
    entry holds every array as it was, bit for bit (out-of-band buffers), in C and Fortran order."""
    release = threading.Event()
    write = diskcache._write

    def slow(path, parts):
        release.wait(10)
        write(path, parts)

    monkeypatch.setattr(diskcache, "_write", slow)
    path = diskcache.entry("k", ("later",))
    value = {"a": np.random.default_rng(0).normal(size=(300, 7)), "f": np.asfortranarray(np.ones((4, 5), np.float32))}
    value["t"] = (value["a"][::2], "text", 3)  # not contiguous: pickled in band
    diskcache.store_later(path, value)
    assert not path.exists()  # still being written
    threading.Timer(0.2, release.set).start()
    back = diskcache.load(path)  # waits for the write
    for key in ("a", "f"):
        np.testing.assert_array_equal(back[key], value[key])
        assert back[key].dtype == value[key].dtype and back[key].flags.f_contiguous == value[key].flags.f_contiguous
    np.testing.assert_array_equal(back["t"][0], value["t"][0])
    assert back["t"][1:] == ("text", 3)
    assert not diskcache._pending


def test_an_entry_is_the_arrays_bytes_and_a_short_header(cache_dir):
    """No pickled copy of the arrays next to them: the entry is their bytes plus a header of a few hundred bytes."""
    path = diskcache.entry("k", ("size",))
    value = {"a": np.zeros(100_000), "b": np.zeros((100, 3), np.int32)}
    diskcache.store(path, value)
    assert 0 <= path.stat().st_size - (value["a"].nbytes + value["b"].nbytes) < 1000


def test_a_loaded_entry_views_the_mapped_file_aligned_and_copy_on_write(cache_dir):
    """Loading maps the file: the arrays are not read into memory of their own (a whole 640x480 frame's entries
    are ~300 MB of fresh pages otherwise), each starts aligned, and changing one in place leaves the file as it
    was."""
    import tracemalloc

    path = diskcache.entry("k", ("mapped",))
    value = {"odd": np.arange(3, dtype=np.uint8), "a": np.arange(1_000_000.0), "b": np.arange(7, dtype=np.int32)}
    diskcache.store(path, value)
    tracemalloc.start()
    try:
        back = diskcache.load(path)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert peak < value["a"].nbytes // 10  # 8 MB of values, not allocated
    for name, array in value.items():
        np.testing.assert_array_equal(back[name], array)
        assert back[name].ctypes.data % diskcache.ALIGN == 0
    back["a"][:] = -1.0  # copy on write: this process's pages only
    np.testing.assert_array_equal(diskcache.load(path)["a"], value["a"])


@pytest.mark.parametrize(
    "ending, complete",
    [
        ("import os; os._exit(0)", False),  # the end a signal handler takes (cli._end_at_once): no wait
        ("pass", True),  # the interpreter's own exit waits for the non-daemon writer
        ("from nlipscalib.cli import _exit; _exit(0)", True),  # the nlips command's exit path
    ],
)
def test_a_process_that_ends_while_writing_leaves_a_whole_entry_or_none(cache_dir, ending, complete):
    """A background write cut short by the process's end never leaves a partial entry; a normal exit, and the
    ``nlips`` command's (:func:`nlipscalib.cli._exit`), wait for it."""
    import subprocess
    import sys
    import textwrap

    size = 5_000_000  # 40 MB: tens of milliseconds to write
    code = textwrap.dedent(f"""
        import numpy as np
        from nlipscalib.core import diskcache
        path = diskcache.entry("k", ("big",))
        diskcache.store_later(path, np.arange({size}, dtype=np.float64))
        {ending}
    """)
    env = dict(os.environ, **{diskcache.ENV_DIR: str(cache_dir)})
    subprocess.run([sys.executable, "-c", code], env=env, check=True, timeout=300)
    path = diskcache.entry("k", ("big",))
    if complete or path.exists():  # os._exit: the entry whole (had the write been that quick) or none
        np.testing.assert_array_equal(diskcache.load(path), np.arange(size, dtype=np.float64))
    if not complete:  # its temporary file, if any, is a dead process's: the next write removes it
        small = diskcache.entry("k", ("small",))
        diskcache.store(small, 1)
        assert {p.name for p in path.parent.iterdir()} <= {small.name, path.name}


def test_an_entry_above_half_the_size_bound_is_not_written_and_evicts_nothing(cache_dir, monkeypatch, caplog):
    small = diskcache.entry("k", ("small",))
    diskcache.store(small, np.zeros(100_000, np.uint8))
    monkeypatch.setenv(diskcache.ENV_MB, str(300_000 / 2**20))  # 300 kB: an entry may take 150 kB
    caplog.set_level(logging.DEBUG, logger="nlipscalib.core.diskcache")
    big = diskcache.entry("k", ("big",))
    diskcache.store(big, np.zeros(200_000, np.uint8))  # written, it would leave room for nothing else
    diskcache.store_later(diskcache.entry("k", ("big later",)), np.zeros(200_000, np.uint8))
    diskcache.wait()
    assert not big.exists() and small.exists() and diskcache.usage()[0] == 1
    assert "not written: 0 MB, more than 50 % of the cache's 0 MB (NLIPS_CACHE_MB)" in caplog.text
    with pytest.raises(KeyError):
        diskcache.load(big)  # a miss: the next process computes it again
    medium = diskcache.entry("k", ("medium",))
    diskcache.store(medium, np.zeros(140_000, np.uint8))  # within the share: written, the bound then trims
    assert medium.exists()
