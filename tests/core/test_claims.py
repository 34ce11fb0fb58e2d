"""Per-item claims across processes: exclusive, released, taken over when the owner dies or stalls."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import time
import types
from pathlib import Path

import pytest

from nlipscalib.core.claims import claim, claim_path, holder
from tests.processes import wait_until

ROOT = Path(__file__).resolve().parents[2]


def _spawn(code: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(code)], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )


def _hold(target: Path, stale_s: float = 60.0) -> subprocess.Popen:
    """A child process that claims ``target``, prints its verdict, then holds it until its stdin closes (the test's
    ``communicate()``): not for a fixed time, which a loaded machine's start of the next process could outlast."""
    return _spawn(
        f"""
        import sys
        from nlipscalib.core.claims import claim
        with claim({str(target)!r}, stale_s={stale_s}) as mine:
            print("held" if mine else "busy", flush=True)
            sys.stdin.read()
        """
    )


def test_claim_is_exclusive_and_released(tmp_path):
    target = tmp_path / "press_0000"
    with claim(target) as mine:
        assert mine
        assert claim_path(target).is_file()
        with claim(target) as again:  # even the same process does not get it twice
            assert not again
        assert holder(target).pid == os.getpid()
    assert not claim_path(target).exists()
    assert holder(target) is None


def test_second_process_is_refused_while_first_holds(tmp_path):
    target = tmp_path / "item"
    first = _hold(target)
    assert first.stdout.readline().strip() == "held"
    second = _hold(target)
    assert second.stdout.readline().strip() == "busy"
    second.communicate(timeout=30)
    with claim(target) as mine:
        assert not mine
    first.communicate(timeout=30)
    with claim(target) as mine:  # released on exit
        assert mine


def test_killed_owner_is_taken_over(tmp_path):
    target = tmp_path / "item"
    with _hold(target) as owner:  # its pipes closed on leaving (ResourceWarning: unclosed file, before)
        assert owner.stdout.readline().strip() == "held"
        owner.kill()
        owner.wait(30)
    assert claim_path(target).exists()  # a killed process leaves its claim behind
    with claim(target) as mine:
        assert mine
        assert holder(target).pid == os.getpid()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="zombies are told from /proc")
def test_a_killed_owner_not_yet_reaped_is_taken_over(tmp_path):
    """Right after ``kill -9`` a worker stays a zombie until reaped (late on some containers' init), and its
    claims looked held: a re-run skipped its presses as "being solved by another process"."""
    import signal

    target = tmp_path / "item"
    with _hold(target) as owner:  # its pipes closed on leaving (ResourceWarning: unclosed file, before)
        assert owner.stdout.readline().strip() == "held"
        os.kill(owner.pid, signal.SIGKILL)
        deadline = time.monotonic() + 30
        while (
            "Z" not in Path(f"/proc/{owner.pid}/stat").read_text(encoding="utf-8").rsplit(")", 1)[1][:3]
        ):  # not reaped: no wait()
            assert time.monotonic() < deadline
            time.sleep(0.01)
        with claim(target) as mine:
            assert mine
        owner.wait(30)


def test_on_windows_a_process_is_looked_up_without_os_kill(monkeypatch):
    """Windows has no signal 0: its ``os.kill(pid, 0)`` ends the process (TerminateProcess), so a liveness check
    killed the claim's owner, or a worker's own command (s26-portable)."""
    pytest.importorskip("psutil")
    from nlipscalib.core import claims

    def kill(pid, sig):
        raise AssertionError(f"os.kill({pid}, {sig}) would end process {pid} on Windows")

    ended = subprocess.Popen([sys.executable, "-c", "pass"])
    ended.wait(30)
    monkeypatch.setattr(sys, "platform", "win32")
    # the module's own os only: psutil, standing in here for its Windows self, asks os.kill on Linux
    monkeypatch.setattr(claims, "os", types.SimpleNamespace(**{**vars(os), "kill": kill}))
    assert claims.pid_alive(os.getpid())
    assert not claims.pid_alive(ended.pid)


def test_claim_without_heartbeat_is_stale(tmp_path):
    """A claim from another machine (pid not checkable) whose heartbeat stopped is taken over."""
    target = tmp_path / "item"
    path = claim_path(target)
    path.write_text(json.dumps({"host": "other-machine", "pid": 1, "token": "x"}), encoding="utf-8")
    with claim(target, stale_s=30) as mine:
        assert not mine  # fresh heartbeat: respected
    old = time.time() - 120
    os.utime(path, (old, old))
    with claim(target, stale_s=30) as mine:
        assert mine


def test_heartbeat_keeps_a_long_claim_alive(tmp_path):
    target = tmp_path / "item"
    owner = _hold(target, stale_s=0.5)
    assert owner.stdout.readline().strip() == "held"
    time.sleep(1.2)  # several stale periods: only the heartbeat keeps the claim fresh
    with claim(target, stale_s=0.5) as mine:
        assert not mine
    owner.communicate(timeout=30)


def test_many_claims_held_at_once_share_one_heartbeat_thread_and_all_stay_fresh(tmp_path):
    """A batch holds a claim per press for its whole run: one thread keeps them all fresh, not one thread each."""
    import threading
    from contextlib import ExitStack

    from nlipscalib.core.claims import claim_path

    targets = [tmp_path / f"press_{i:03d}" for i in range(40)]
    before = threading.active_count()
    with ExitStack() as stack:
        assert all(stack.enter_context(claim(t, stale_s=0.4)) for t in targets)
        assert threading.active_count() <= before + 1
        start = time.time()
        time.sleep(0.9)  # two stale periods: only the beats keep them fresh
        # polled, not read once: on a loaded machine the beat thread may not have run within the two periods
        assert wait_until(lambda: all(os.stat(claim_path(t)).st_mtime > start for t in targets), 30)
    assert not any(claim_path(t).exists() for t in targets)
    assert wait_until(lambda: threading.active_count() <= before, 30)  # the thread ends with the last claim


def test_a_claim_taken_over_is_no_longer_refreshed(tmp_path, caplog):
    from nlipscalib.core.claims import claim_path

    target = tmp_path / "item"
    with claim(target, stale_s=0.4) as mine:
        assert mine
        path = claim_path(target)
        path.write_text(json.dumps({"host": "elsewhere", "pid": 1, "token": "theirs"}), encoding="utf-8")
        old = time.time() - 60
        os.utime(path, (old, old))
        assert wait_until(lambda: "taken over" in caplog.text, 30)  # a beat came due (0.1 s): it found another owner
        assert os.stat(path).st_mtime < time.time() - 30  # not refreshed
    assert path.exists()  # not ours: left as it is


@pytest.mark.parametrize("n", [3])
def test_racing_processes_get_one_claim_each_item(tmp_path, n):
    """n processes race over 6 items: each item is produced by exactly one of them."""
    code = f"""
        import time
        from pathlib import Path
        from nlipscalib.core.claims import claim
        got = []
        for i in range(6):
            item = Path({str(tmp_path)!r}) / f"item{{i}}"
            with claim(item) as mine:
                if mine and not item.exists():  # the real pattern: claim, then check it is not done
                    got.append(i)
                    time.sleep(0.3)
                    item.mkdir()
        print(",".join(map(str, got)))
        """
    procs = [_spawn(code) for _ in range(n)]
    outs = [p.communicate(timeout=60)[0].strip() for p in procs]
    claimed = [int(i) for out in outs for i in out.split(",") if i]
    assert sorted(claimed) == list(range(6))  # every item produced exactly once
    assert not list(tmp_path.glob(".claim-*"))


def test_fresh_unreadable_claim_counts_as_held(tmp_path):
    """A claim file being written (exclusive-create fallback) is not free; once old, it is."""
    target = tmp_path / "item"
    claim_path(target).write_bytes(b"")
    assert holder(target) is not None
    with claim(target) as mine:
        assert not mine
    os.utime(claim_path(target), (0, 0))
    assert holder(target) is None
    with claim(target) as mine:
        assert mine


def test_release_all_removes_a_clock_probe_being_written(tmp_path, monkeypatch):
    """A worker SIGTERM'd while it reads the file system's clock (its handler calls release_all, then os._exit:
    no ``finally`` runs) leaves no ``.claim-probe.*`` behind."""
    from nlipscalib.core import claims

    before, after = [], []
    stat = Path.stat

    def signal_while_probing(path, *args, **kwargs):  # the signal lands between the probe's write and stat
        if path.name.startswith(".claim-probe.") and not before:
            before.extend(tmp_path.glob(".claim-probe.*"))
            claims.release_all()  # what the handler does before os._exit
            after.extend(tmp_path.glob(".claim-probe.*"))
        return stat(path, *args, **kwargs)

    monkeypatch.setattr(claims.Path, "stat", signal_while_probing)
    claims.fs_now(tmp_path)
    monkeypatch.undo()
    assert before and not after


def test_a_signal_handler_exiting_while_a_claim_is_made_leaves_no_file(tmp_path, monkeypatch):
    """Ctrl-C of `nlips experiment --workers 2` left `.claim-TASK.json.TOKEN` (the claim's temporary): the
    worker's handler (release_all, then exit: no `finally` runs) struck between writing it and linking it."""
    import nlipscalib.core.claims as claims

    seen = []
    real_link = os.link

    def link_then_the_handler_runs(src, dst):
        real_link(src, dst)
        claims.release_all()  # what the worker's SIGINT/SIGTERM handler does before os._exit
        seen.extend(p.name for p in tmp_path.iterdir())
        raise SystemExit(130)

    monkeypatch.setattr(claims.os, "link", link_then_the_handler_runs)
    with pytest.raises(SystemExit), claim(tmp_path / "item"):
        pass
    assert seen == []  # neither the claim nor its temporary outlived the handler


def test_a_claim_that_could_not_be_written_leaves_no_registration(tmp_path, monkeypatch):
    """A claim whose file could not be written (disk full) stayed registered: the next claim of that path was
    then not the registered one, and release_all on SIGTERM left its file behind."""
    import errno

    import nlipscalib.core.claims as claims

    real_link = os.link

    def disk_full(src, dst):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(claims.os, "link", disk_full)
    with pytest.raises(OSError), claim(tmp_path / "item"):
        pass
    monkeypatch.setattr(claims.os, "link", real_link)
    with claim(tmp_path / "item") as mine:
        assert mine
        claims.release_all()  # what a SIGTERM handler does before exiting
        assert not claim_path(tmp_path / "item").exists()


def test_wait_for_release_returns_when_the_holder_lets_go_and_says_so_once(tmp_path, monkeypatch):
    """The one wait on another's claim (the solve pipeline's and a dataset build's): returns once the claim is
    released, with ``on_wait`` called once while it was held, and not at all when nothing holds it."""
    import threading

    from nlipscalib.core import claims

    monkeypatch.setattr(claims, "CLAIM_POLL_S", 0.01)
    target, said = tmp_path / "nlips", []
    claims.wait_for_release(target, on_wait=lambda: said.append("free"))
    assert said == []
    holding, waiting, letting_go = threading.Event(), threading.Event(), threading.Event()

    def other():  # a thread standing for another process (claims are per process)
        with claim(target):
            holding.set()
            waiting.wait(30)  # released only once the wait has begun: a late main thread cannot miss the claim
            time.sleep(0.3)
            letting_go.set()  # the claim is still held here: a wait that returned already did not wait for it

    def on_wait():
        said.append("held")
        waiting.set()

    thread = threading.Thread(target=other)
    thread.start()
    holding.wait()
    claims.wait_for_release(target, on_wait=on_wait)
    assert letting_go.is_set() and holder(target) is None and said == ["held"]
    thread.join()


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait(30)
    return proc.pid


def test_a_shared_claim_holds_for_its_key_refuses_another_and_forgets_a_dead_holder(tmp_path):
    """claim_shared: holders of one key share the target; a holder of another key is refused while one lives, and
    gets it once they have left; a killed holder's claim does not count, and the last to leave removes it."""
    from nlipscalib.core.claims import HOST, claim_shared

    target = tmp_path / "dataset"
    dead = tmp_path / ".claim-dataset~cccc~0123456789abcdef"  # a run of key "cccc" killed while it held the folder
    dead.write_text(json.dumps({"host": HOST, "pid": _dead_pid(), "token": "x"}), encoding="utf-8")
    with claim_shared(target, "aaaa") as first, claim_shared(target, "aaaa") as second:
        assert first is None and second is None  # one key: both hold it
        assert len(list(tmp_path.glob(".claim-dataset~aaaa~*"))) == 2
        with claim_shared(target, "bbbb") as other:
            assert other is not None and other.pid == os.getpid()  # refused, naming a holder
        assert not list(tmp_path.glob(".claim-dataset~bbbb~*"))  # and nothing held
    assert not list(tmp_path.glob(".claim-*"))  # released, the dead holder's claim swept, no mutex left
    with claim_shared(target, "bbbb") as other:
        assert other is None
    with pytest.raises(ValueError, match="key"):
        with claim_shared(target, "a.b"):
            pass


def test_a_shared_holders_note_reaches_the_process_it_refuses_and_is_not_part_of_who_owns_it(tmp_path):
    """A solve refused for another run's settings names them (pipeline.reuse._hold): the holder's ``note`` is read
    back with its claim, and comparing owners (release, takeover) still goes by host, pid and token alone."""
    from nlipscalib.core.claims import Owner, _read_owner, claim_shared

    target = tmp_path / "nlips~run"
    with claim_shared(target, "aaaa", note={"settings": {"roi": "auto"}}):
        with claim_shared(target, "bbbb", note={"settings": {"roi": None}}) as other:
            assert other is not None and other.note == {"settings": {"roi": "auto"}}
        (member,) = tmp_path.glob(".claim-nlips~run~aaaa~*")
        assert _read_owner(member) == Owner(other.host, other.pid, other.token)  # the note aside
    assert not list(tmp_path.glob(".claim-*"))
    (tmp_path / ".claim-x").write_text("[1, 2]", encoding="utf-8")  # not an object: no owner, not an AttributeError
    assert _read_owner(tmp_path / ".claim-x") is None


def test_dead_owners_claims_anywhere_under_a_folder_are_removed_and_live_ones_kept(tmp_path):
    """An experiment's Dask worker killed mid-task leaves its task's claim and its press's solve hold
    (``.claim-nlips~run~KEY~TOKEN`` deep in the presses' folders): all removed, a live claim kept."""
    from nlipscalib.core.claims import HOST, claim_shared, remove_dead_claims

    dead = json.dumps({"host": HOST, "pid": _dead_pid(), "token": "dead"})
    task = tmp_path / "tasks" / ".claim-t1.json"
    hold = tmp_path / "presses" / "p1" / "solves" / ".claim-nlips~run~abc~dead"
    for path in (task, hold):
        path.parent.mkdir(parents=True)
        path.write_text(dead, encoding="utf-8")
    other = tmp_path / "presses" / ".claim-notes"  # not a claim (no owner in it): left alone
    other.write_text("notes", encoding="utf-8")
    with claim(tmp_path / "tasks" / "t2.json") as mine, claim_shared(tmp_path / "presses" / "p2", "k") as held:
        assert mine and held is None
        removed = remove_dead_claims(tmp_path)
        assert sorted(removed) == sorted([task, hold])
        assert claim_path(tmp_path / "tasks" / "t2.json").exists()  # live: kept
        assert list((tmp_path / "presses").glob(".claim-p2~k~*"))
    assert not task.exists() and not hold.exists() and other.exists()


def test_held_for_shares_one_key_and_refuses_another_with_the_callers_words(tmp_path):
    """held_for, the one copy of what `nlips solve`, `nlips dataset` and `nlips calibrate` each wrote around
    claim_shared: the same key holds together, another key is a ConfigError of the caller's message naming the
    holder, and a folder where no claim file can be made is not held (its writes say why)."""
    from nlipscalib.core.claims import held_for
    from nlipscalib.core.errors import ConfigError

    target = tmp_path / "out"
    with held_for(target, "aaaa", lambda o: "unused"), held_for(target, "aaaa", lambda o: "unused"):
        with pytest.raises(ConfigError, match=rf"^held by process {os.getpid()} on "):
            with held_for(target, "bbbb", lambda other: f"held by {other.who}"):
                pass
    with held_for(target, "bbbb", lambda o: "unused"):  # the first key's holders left
        pass
    with held_for(tmp_path / "missing" / "out", "aaaa", lambda o: "unused"):  # no folder for the claim file
        pass


def test_the_file_systems_clock_on_a_read_only_disk_is_this_machines(tmp_path, monkeypatch):
    """On a read-only mount the probe is never made, and unlinking it (even missing) raises EROFS: that error
    stopped `nlips calibrate ro/ds --out writable/` and `nlips solve ro/ds` of presses all solved already, in one
    line "ro/ds: Read-only file system" (s25 walk); only a write the run needs may fail there."""
    import errno
    import os
    import time

    from nlipscalib.core import claims

    def read_only(path, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))

    monkeypatch.setattr(claims.Path, "write_bytes", read_only)
    monkeypatch.setattr(claims.Path, "unlink", read_only)
    # this call's own entries only: earlier tests of the suite (tests/cli/test_faults.py's real read-only mounts)
    # leave theirs, removed at exit as designed
    monkeypatch.setattr(claims, "_PROBES", set())
    before = time.time()
    assert before <= claims.fs_now(tmp_path) <= time.time()
    assert not claims._PROBES  # nothing left to remove on exit
