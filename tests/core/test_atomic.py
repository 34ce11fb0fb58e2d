"""Atomic folders under concurrency: never replace a complete folder, never clean a live process's work."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import types
from pathlib import Path

import pytest

from nlipscalib.core.atomic import TMP_PREFIX, atomic_dir, clean_interrupted, tmp_prefix, write_if_changed
from nlipscalib.core.claims import claim, claim_path


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_publish_never_replaces_a_complete_folder(tmp_path):
    final = tmp_path / "press"
    with pytest.raises(FileExistsError):
        with atomic_dir(final) as tmp:
            (tmp / "mine.txt").write_text("mine", encoding="utf-8")
            final.mkdir()  # another process publishes meanwhile
            (final / "meta.json").write_text("{}", encoding="utf-8")
    assert sorted(p.name for p in final.iterdir()) == ["meta.json"]
    assert not list(tmp_path.glob(TMP_PREFIX + "*"))


def test_existing_folder_error_names_path_without_api_advice(tmp_path):
    (tmp_path / "p").mkdir()
    with pytest.raises(FileExistsError) as info:
        with atomic_dir(tmp_path / "p"):
            pass
    assert info.value.filename == str(tmp_path / "p")
    assert "overwrite=True" not in str(info.value)


def test_clean_keeps_live_work_and_removes_dead(tmp_path):
    live = tmp_path / (tmp_prefix("press_0001") + "abc")  # this (live) process's work in progress
    live.mkdir()
    dead = tmp_path / (tmp_prefix("press_0002").replace(f"~{os.getpid()}~", f"~{_dead_pid()}~") + "abc")
    dead.mkdir()
    gone = clean_interrupted(tmp_path)
    assert gone == [dead] and live.is_dir() and not dead.exists()


def test_clean_other_machine_work_only_when_unclaimed_and_old(tmp_path):
    remote = tmp_path / f"{TMP_PREFIX}press_0003~othermachine~123~abc"
    remote.mkdir()
    assert clean_interrupted(tmp_path) == []  # fresh: may be a live process over there
    os.utime(remote, (0, 0))
    with claim(tmp_path / "press_0003") as mine:  # old, but its item is claimed by a live process
        assert mine
        assert clean_interrupted(tmp_path) == []
    assert clean_interrupted(tmp_path) == [remote]


def test_clean_removes_claims_of_dead_owners_only(tmp_path):
    with claim(tmp_path / "a") as mine:
        assert mine
        claim_path(tmp_path / "b").write_text(
            f'{{"host": "{os.uname().nodename}", "pid": {_dead_pid()}, "token": "t"}}', encoding="utf-8"
        )
        gone = clean_interrupted(tmp_path)
        assert gone == [claim_path(tmp_path / "b")] and claim_path(tmp_path / "a").exists()


def test_write_if_changed_skips_identical_content(tmp_path, monkeypatch):
    path = tmp_path / "dataset.json"
    assert write_if_changed(path, "x\n")
    monkeypatch.setattr(os, "replace", lambda *a: (_ for _ in ()).throw(OSError(30, "Read-only file system")))
    assert not write_if_changed(path, "x\n")  # read-only media: an identical file is not rewritten
    with pytest.raises(OSError):
        write_if_changed(path, "y\n")


def test_next_write_of_a_folder_cleans_its_killed_predecessor(tmp_path):
    """A killed `nlips solve` left PRESS/.tmp-nlips~host~pid~xyz: the next write of PRESS/nlips removes it."""
    dead = tmp_path / (tmp_prefix("nlips").replace(f"~{os.getpid()}~", f"~{_dead_pid()}~") + "xyz")
    dead.mkdir()
    (dead / "result.npz").write_bytes(b"half")
    old_style = tmp_path / f"{TMP_PREFIX}nlips-abc123"
    old_style.mkdir()
    os.utime(old_style, (0, 0))
    other_item = tmp_path / (tmp_prefix("press_0001").replace(f"~{os.getpid()}~", f"~{_dead_pid()}~") + "q")
    other_item.mkdir()
    with atomic_dir(tmp_path / "nlips") as tmp:
        (tmp / "result.npz").write_bytes(b"whole")
    assert not dead.exists() and not old_style.exists()
    assert other_item.exists()  # only this folder's leftovers
    assert (tmp_path / "nlips" / "result.npz").read_bytes() == b"whole"


def test_error_messages_name_the_entry_the_user_asked_for_not_its_hidden_siblings(tmp_path):
    import errno

    from nlipscalib.cli import describe_os_error
    from nlipscalib.core.atomic import named_target, tmp_prefix

    out = tmp_path / "nlips"
    assert named_target(tmp_path / (tmp_prefix("nlips") + "abc")) == out
    assert named_target(tmp_path / ".claim-nlips") == out
    assert named_target(tmp_path / ".claim-nlips.667b44a0096d6a8b") == out
    assert named_target(tmp_path / ".claim-nlips.stale.0123456789ab") == out
    assert named_target(tmp_path / ".claim-probe.host.12.abcd1234") == tmp_path
    assert named_target(tmp_path / (tmp_prefix("") + "probe")) == tmp_path  # check_writable(folder)'s own probe
    assert named_target(tmp_path / "led_01.png") == tmp_path / "led_01.png"
    inside = tmp_path / (tmp_prefix("press") + "abc") / "led_03.png"  # a file of a folder being written
    assert named_target(inside) == tmp_path / "press" / "led_03.png"
    assert named_target(Path("rel") / (tmp_prefix("press") + "abc") / "sub" / "a.png") == Path("rel/press/sub/a.png")
    from nlipscalib.core.atomic import SCRATCH_MARK

    staged = tmp_path / (tmp_prefix("net.pt") + SCRATCH_MARK + "abc") / "net_curve.png"  # scratch_dir: moved beside
    assert named_target(staged) == tmp_path / "net_curve.png"
    full_inside = OSError(errno.ENOSPC, "No space left on device", str(inside))
    assert describe_os_error(full_inside).startswith(f"{tmp_path / 'press' / 'led_03.png'}: No space left")
    denied = PermissionError(errno.EACCES, "Permission denied", str(tmp_path / ".claim-nlips.667b44a0096d6a8b"))
    assert describe_os_error(denied).startswith(f"{out}: Permission denied")
    full = OSError(errno.ENOSPC, "No space left on device")  # found while writing: no path in the error
    assert describe_os_error(full, where=tmp_path / "press").startswith(f"{tmp_path / 'press'}: No space left")


def test_a_file_written_by_name_is_atomic_owner_tagged_and_removed_on_termination(tmp_path):
    from nlipscalib.core.atomic import _IN_PROGRESS, remove_in_progress, write_by_name

    target = tmp_path / "samples" / "press_0001.npz"
    seen = []

    def writer(tmp):
        seen.append(tmp)
        assert tmp.name.startswith(tmp_prefix(target.name))  # this process's name: never another writer's file
        assert tmp in _IN_PROGRESS and not target.exists()
        tmp.write_bytes(b"whole")

    write_by_name(target, writer)
    assert target.read_bytes() == b"whole" and not seen[0].exists() and not _IN_PROGRESS

    def killed(tmp):  # SIGTERM while writing: the handler removes what this process was filling
        tmp.write_bytes(b"ha")
        remove_in_progress()
        assert not tmp.exists()
        raise SystemExit(143)

    with pytest.raises(SystemExit):
        write_by_name(target, killed)
    assert target.read_bytes() == b"whole" and sorted(p.name for p in target.parent.iterdir()) == [target.name]


def test_clean_removes_the_short_lived_claim_files_of_killed_processes(tmp_path):
    from nlipscalib.core.claims import HOST

    def owner(pid):
        return f'{{"host": "{HOST}", "pid": {pid}, "token": "0123456789abcdef"}}'

    dead = _dead_pid()
    killed = {  # a SIGKILL between creating and removing each of them
        tmp_path / ".claim-nlips.0123456789abcdef": owner(dead),  # the owner's JSON, before the link
        tmp_path / ".claim-nlips.stale.0123456789ab": owner(dead),  # moved aside during a takeover
        tmp_path / f".claim-probe.{HOST}.{dead}.0a1b2c3d": "",  # the file-system clock probe
    }
    live = {
        tmp_path / ".claim-other.fedcba9876543210": owner(os.getpid()),
        tmp_path / f".claim-probe.{HOST}.{os.getpid()}.0a1b2c3d": "",
        tmp_path / ".claim-probe.elsewhere.12.0a1b2c3d": "",  # another machine's, fresh
    }
    for path, text in (killed | live).items():
        path.write_text(text, encoding="utf-8")
    assert sorted(clean_interrupted(tmp_path, item="nlips")) == sorted(killed)
    assert all(p.exists() for p in live)


def test_concurrent_overwrites_of_one_folder_all_succeed_and_leave_nothing_behind(tmp_path):
    """Two `nlips infer` runs of one press publish PRESS/nlipsnet with overwrite at once: every write
    succeeds (the last one wins), the folder is always whole, and no moved-aside copy is left."""
    import threading

    final, errors = tmp_path / "nlipsnet", []

    def writer(k):
        for i in range(60):
            try:
                with atomic_dir(final, overwrite=True) as tmp:
                    (tmp / "result.npz").write_text(f"{k} {i}", encoding="utf-8")
                    (tmp / "report.json").write_text("{}", encoding="utf-8")
            except Exception as exc:  # before: ENOTEMPTY, FileNotFoundError, "already exists"
                errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert errors == []
    assert [p.name for p in tmp_path.iterdir()] == ["nlipsnet"]
    assert sorted(p.name for p in final.iterdir()) == ["report.json", "result.npz"]


def test_a_folder_removed_on_termination_is_gone_while_threads_still_write_into_it(tmp_path):
    """SIGTERM while write_press's image threads fill a press folder: the handler's removal must not race them
    (rmtree emptied the folder, a thread created a file, the folder stayed under its temporary name)."""
    import threading

    from nlipscalib.core.atomic import remove_in_progress

    stop = threading.Event()

    def keep_writing(folder):
        i = 0
        while not stop.is_set():
            try:
                (folder / f"led_{i % 12:02d}.png").write_bytes(b"x" * 4096)
            except OSError:  # the folder went away under the thread: its writes fail from now on
                pass
            i += 1

    with pytest.raises(SystemExit), atomic_dir(tmp_path / "press_0001") as tmp:
        writers = [threading.Thread(target=keep_writing, args=(tmp,)) for _ in range(2)]
        for t in writers:
            t.start()
        try:
            for _ in range(50):  # files keep appearing while the folder is being removed
                (tmp / "meta.json").write_text("{}", encoding="utf-8")
            remove_in_progress()
            assert not tmp.exists()
        finally:
            stop.set()
            for t in writers:
                t.join()
        assert not tmp.exists()  # nothing wrote the folder back under its name
        raise SystemExit(143)
    left = [p.name for p in tmp_path.iterdir()]
    assert "press_0001" not in left and all(n.startswith(tmp.name) for n in left), left


def test_a_file_written_into_a_temporary_folder_removed_meanwhile_fails_and_nothing_is_published(tmp_path):
    """A clean-up elsewhere removed a live solve's temporary folder; write_by_name quietly made it again for the
    next figure, and atomic_dir published the near-empty folder (a result without result.npz, exit 0)."""
    import shutil

    from nlipscalib.core.atomic import write_text

    final = tmp_path / "res-2"
    with pytest.raises(FileNotFoundError, match="removed while being written"):
        with atomic_dir(final) as tmp:
            write_text(tmp / "result.npz", "data")
            shutil.rmtree(tmp)  # what another process's clean-up did
            write_text(tmp / "figures" / "summary.png", "png")
    assert not final.exists() and not list(tmp_path.glob(TMP_PREFIX + "*"))


def test_a_temporary_folder_removed_and_made_again_is_not_published(tmp_path):
    import shutil

    final = tmp_path / "res-2"
    with pytest.raises(FileNotFoundError, match="removed while being written"):
        with atomic_dir(final) as tmp:
            (tmp / "result.npz").write_text("data", encoding="utf-8")
            shutil.rmtree(tmp)
            tmp.mkdir()  # e.g. an os.makedirs of a writer
            (tmp / "summary.png").write_text("png", encoding="utf-8")
    assert not final.exists()


def _no_folder_opened(monkeypatch) -> None:
    """atomic's os.open as on Windows, where a folder cannot be opened: PermissionError (Errno 13). Its own only:
    shutil.rmtree opens folders on Linux."""
    from nlipscalib.core import atomic

    real_open = os.open

    def windows_open(path, flags, *args, **kwargs):
        if os.path.isdir(path):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, flags, *args, **kwargs)

    monkeypatch.setattr(atomic, "os", types.SimpleNamespace(**{**vars(os), "open": windows_open}))


def test_a_folder_is_published_where_folders_cannot_be_opened(tmp_path, monkeypatch):
    """Windows: every result folder failed with PermissionError, as atomic_dir held its temporary folder open
    (os.open of a folder) to tell it from one made again under its name (s26-portable)."""
    from nlipscalib.core.atomic import write_text

    _no_folder_opened(monkeypatch)
    final = tmp_path / "res-1"
    with atomic_dir(final) as tmp:
        write_text(tmp / "result.npz", "data")
    assert (final / "result.npz").read_text(encoding="utf-8") == "data"
    with pytest.raises(FileNotFoundError, match="removed while being written"):  # the check still holds
        with atomic_dir(tmp_path / "res-2") as tmp:
            write_text(tmp / "result.npz", "data")
            shutil.rmtree(tmp)
    assert not (tmp_path / "res-2").exists() and not list(tmp_path.glob(TMP_PREFIX + "*"))


def test_a_writability_probe_goes_with_the_temporaries_removed_on_termination(tmp_path, monkeypatch):
    """A solve worker terminated between check_writable's mkdir and rmdir left its probe folder
    (``.tmp-xxxxx~HOST~PID~probe``) in the press: seen by tests/cli/test_interrupt.py once the kill came right after
    a press was published, as the worker began the next one."""
    from pathlib import Path

    from nlipscalib.core import atomic

    def terminated(self):  # the SIGTERM handler's clean-up, then os._exit: the rmdir never runs
        atomic.remove_in_progress()
        raise SystemExit(143)

    monkeypatch.setattr(Path, "rmdir", terminated)
    with pytest.raises(SystemExit):
        atomic.check_writable(tmp_path / "press", longest_name=len("nlips"))
    monkeypatch.undo()
    assert list((tmp_path / "press").iterdir()) == []


def test_a_folder_given_as_a_link_is_written_where_it_points_and_the_link_stays(tmp_path):
    """``--report reports/latest`` where latest is a link to a run's folder: the swap renamed the new folder onto
    the link, so the link became a real folder and the folder it named kept the old report."""
    from nlipscalib.core.atomic import whole_dir

    run = tmp_path / "runs" / "run-7"
    run.mkdir(parents=True)
    (run / "results.json").write_text("old", encoding="utf-8")
    (run / "stale.png").write_text("old figure", encoding="utf-8")
    latest = tmp_path / "latest"
    latest.symlink_to(run, target_is_directory=True)
    with whole_dir(latest, "results.json") as tmp:
        (tmp / "results.json").write_text("new", encoding="utf-8")
    assert latest.is_symlink() and latest.resolve() == run.resolve()
    assert (run / "results.json").read_text(encoding="utf-8") == "new"
    assert not (run / "stale.png").exists()  # the target is one run's whole report

    later = tmp_path / "later"
    later.symlink_to(tmp_path / "runs" / "run-8", target_is_directory=True)  # a link to a folder not made yet
    with atomic_dir(later) as tmp:
        (tmp / "a.txt").write_text("a", encoding="utf-8")
    assert later.is_symlink() and (tmp_path / "runs" / "run-8" / "a.txt").read_text(encoding="utf-8") == "a"


@pytest.mark.parametrize("how", ["atomic_dir", "write_bytes", "scratch_dir"])
def test_a_ctrl_c_right_as_the_temporary_is_made_leaves_no_temporary(tmp_path, monkeypatch, how):
    """tempfile.mkdtemp/mkstemp made the temporary and only then returned its name: a Ctrl-C landing between (the
    KeyboardInterrupt raised as the mkdir returned) left `.tmp-f0003~host~pid~...` that no one removed until a
    later write of that item (3 of 16 Ctrl-C of `nlips infer FRAMES --out DIR`). Here the interrupt lands
    exactly there, for each way a temporary is made: nothing is left, and nothing stays registered."""
    from nlipscalib.core import atomic

    real_mkdir, real_open = os.mkdir, os.open

    def mkdir_then_interrupt(path, *args, **kwargs):
        real_mkdir(path, *args, **kwargs)
        if Path(path).name.startswith(TMP_PREFIX):
            raise KeyboardInterrupt

    def open_then_interrupt(path, flags, *args, **kwargs):
        fd = real_open(path, flags, *args, **kwargs)
        if Path(path).name.startswith(TMP_PREFIX) and flags & os.O_CREAT:
            os.close(fd)
            raise KeyboardInterrupt
        return fd

    monkeypatch.setattr(os, "mkdir", mkdir_then_interrupt)
    monkeypatch.setattr(os, "open", open_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        if how == "atomic_dir":
            with atomic_dir(tmp_path / "result") as tmp:
                (tmp / "a.txt").write_text("x", encoding="utf-8")
        elif how == "write_bytes":
            atomic.write_bytes(tmp_path / "a.txt", b"x")
        else:
            with atomic.scratch_dir(tmp_path / "work"):
                pass
    monkeypatch.undo()
    assert sorted(p.name for p in tmp_path.iterdir()) == [] and not atomic._IN_PROGRESS


def test_a_killed_process_scratch_folder_in_the_system_temporary_folder_goes_with_the_next(tmp_path, monkeypatch):
    """A Mitsuba log folder of a render, a said-once folder of a command with workers: made in /tmp under a name
    nothing else writes, so each one a ``kill -9`` left stayed there for good (13 and 37 of them on the walk's
    machine). The next one made removes those of this machine's dead processes, never a live one's or another
    machine's (whose processes cannot be checked: it may be idle for hours)."""
    import tempfile

    from nlipscalib.core import said_once
    from nlipscalib.core.atomic import system_scratch_dir
    from nlipscalib.core.claims import HOST

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))

    def left(name: str, host: str, pid: int) -> Path:
        folder = tmp_path / f"{TMP_PREFIX}{name}~{host}~{pid}~scratch-0123456789ab"
        folder.mkdir()
        (folder / "render.log").write_text("x", encoding="utf-8")
        return folder

    for name in ("nlips-mitsuba-log", "nlips-said"):
        dead, live, other = left(name, HOST, _dead_pid()), left(name, HOST, os.getppid()), left(name, "elsewhere", 7)
        if name == "nlips-said":
            with said_once.shared_between_processes() as folder:
                assert Path(folder).parent == tmp_path and Path(folder).name.startswith(f"{TMP_PREFIX}{name}~")
        else:
            with system_scratch_dir(name) as folder:
                assert folder.is_dir()
        assert not dead.exists() and live.is_dir() and other.is_dir()
        assert not Path(folder).exists()  # its own, removed at the end
