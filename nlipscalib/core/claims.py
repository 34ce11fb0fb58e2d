"""Per-item claims: several processes (on one machine or several sharing a file system) split work.

A claim on ``target`` (a folder some process will produce) is a small JSON file beside it,
``.claim-<name>``, holding its owner (host, pid, a random token). It is created atomically with a
hard link (``os.link`` fails if the name exists, also on NFS), falling back to ``O_CREAT|O_EXCL``
where hard links are not supported. While held, a daemon thread refreshes the file's modification
time (the heartbeat). A claim is *stale*, and taken over, when its owner process is gone (same host)
or its heartbeat is older than ``stale_s``. Ages are measured against the shared file system's own
clock (the mtime of a file we just wrote), so clock skew between machines does not matter.

Claims avoid duplicate work; they are not what keeps data correct. Folders are still published with
an atomic rename that never replaces a complete folder (core.atomic.atomic_dir), so even a lost race
costs only wasted work.
"""

from __future__ import annotations

import contextlib
import errno
import glob
import json
import logging
import os
import secrets
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

CLAIM_PREFIX = ".claim-"
"""Prefix of claim files (never starts with core.atomic.TMP_PREFIX, so cleaners leave them alone)."""
CLAIM_STALE_S = 60.0
"""A claim without heartbeat for this long (s) is abandoned (its owner died) and taken over. One value for every
process sharing a folder: it is an agreement between them (a build waiting on a solver's claim judged the solver
dead, or alive, by its own copy), so callers use this default rather than their own. The heartbeat beats every
quarter of it, so a live owner looks dead only after missing three beats."""
CLAIM_POLL_S = 0.5
"""How often (s) a process waiting for another's claim to be released checks it again (short against a solve)."""
SHARE_SEP = "~"
"""Joins a shared claim's target name, key and token into its holder's claim (``.claim-NAME~KEY~TOKEN``). Not a dot:
a name with a dot after ``.claim-`` is a claim's short-lived sibling to the cleaners (core.atomic), not a claim."""
RUN_HOLD = "~run"
"""Suffix of the name under which runs hold an output for their settings from their start to their end
(``.claim-NAME~run~KEY~TOKEN`` beside ``NAME``, :func:`held_for`): ``nlips solve``'s results, ``nlips infer``'s
results and streams' folders. Not the output's own name, whose exclusive claim a process writing it holds for
seconds."""
HOST = socket.gethostname()
_HELD: dict[Path, Owner] = {}
"""Claims this process holds now (released by ``release_all`` when it is terminated)."""
_PROBES: set[Path] = set()
"""Files this process is writing now: clock probes (:func:`fs_now`) and claim files' temporaries (:func:`_create`)."""


@dataclass(frozen=True)
class Owner:
    """Who holds a claim."""

    host: str
    pid: int
    token: str
    note: dict | None = field(default=None, compare=False, repr=False)
    """What the owner wrote into its claim for others to read (e.g. a solve's settings), or None. Not part of who
    owns it: a claim is compared by host, pid and token alone."""

    @property
    def who(self) -> str:
        """The owner in words, for a message: "process PID on HOST" (or "another process" while unknown)."""
        return f"process {self.pid} on {self.host}" if self.pid else "another process"


UNKNOWN_OWNER = Owner("unknown", 0, "")
"""Owner of a fresh claim file whose content is not written yet."""


def claim_path(target: str | Path) -> Path:
    """The claim file of ``target``: a hidden sibling ``.claim-<name>``."""
    target = Path(target)
    return target.parent / (CLAIM_PREFIX + target.name)


@contextlib.contextmanager
def claim(target: str | Path, *, stale_s: float = CLAIM_STALE_S, note: dict | None = None) -> Iterator[bool]:
    """Claim exclusive work on ``target`` for the duration of the block.

    Parameters
    ----------
    target : folder (or file) this process means to produce; its parent is created if missing.
    stale_s : seconds without heartbeat after which another process's claim counts as abandoned; keep the
        default (:data:`CLAIM_STALE_S`) unless every process sharing the folder passes the same value.
    note : JSON-able dict written into the claim file, for other processes to read as the holder's ``note``

    Yields
    ------
    bool
        True when this process holds the claim (do the work), False when another live process holds
        it (skip the item). The claim is released (its file removed) when the block exits.
    """
    if stale_s <= 0:
        raise ValueError(f"stale_s must be > 0, got {stale_s}")
    path = claim_path(target)
    path.parent.mkdir(parents=True, exist_ok=True)
    me = Owner(HOST, os.getpid(), secrets.token_hex(8), note)
    # registered before the file exists: a signal handler exiting right after the link still removes it
    # (a claim this process already holds stays registered as its holder's: claims are not re-entrant)
    registered = _HELD.setdefault(path, me) is me
    try:
        acquired = _acquire(path, me, stale_s)
    except BaseException:  # disk full, permission: no claim, and no registration left to mislead release_all
        acquired = False
        if registered:  # Ctrl-C right after the link: the file is this process's (it was left behind, s36-apiwalk)
            with contextlib.suppress(OSError):
                _release(path, me)
        raise
    finally:
        if registered and not acquired:
            _HELD.pop(path, None)
    if not acquired:
        yield False
        return
    try:
        _HEARTBEATS.add(path, me, interval=max(0.05, stale_s / 4))  # in the try: a Ctrl-C here releases it too
        yield True
    finally:
        _HEARTBEATS.remove(path)
        _release(path, me)
        _HELD.pop(path, None)


@contextlib.contextmanager
def claim_shared(
    target: str | Path, key: str, *, stale_s: float = CLAIM_STALE_S, note: dict | None = None
) -> Iterator[Owner | None]:
    """Hold ``target`` for the duration of the block together with every process holding it for the same ``key``.

    Processes of one key share the target (runs of one dataset spec filling one folder); a process of another
    key is refused while any live process holds it. Each holder has a claim of its own,
    ``.claim-NAME~KEY~TOKEN``, with the heartbeat and staleness of :func:`claim` (a killed holder stops counting).
    Looking at the other holders and adding this one happen under ``target``'s own exclusive claim, held for
    milliseconds: two keys arriving at once are put in order, so the first holds the target and the second is
    refused, where each could otherwise see no one else and both go on.

    Parameters
    ----------
    target : what the holders share (e.g. a folder's ``OUT/dataset``: its claim files are ``OUT/.claim-dataset*``)
    key : what the holders of one group have in common (e.g. a spec digest); no ``~``, ``.`` or ``/``
    stale_s : as for :func:`claim`; keep the default
    note : as for :func:`claim`, in this holder's claim (what a refused process of another key is told)

    Yields
    ------
    Owner or None
        None when this process holds the target (released when the block exits); else a live holder of another
        key (with its ``note``), and nothing is held.
    """
    if not key or any(c in key for c in (SHARE_SEP, ".", "/", os.sep)):
        raise ValueError(f"a shared claim's key must be non-empty, without '~', '.' or '/': got {key!r}")
    target = Path(target)
    with contextlib.ExitStack() as stack:
        other = _join(stack, target, key, stale_s, note)
        if other is None:  # on leaving: a killed holder's claim goes, its heartbeat stopped (once nobody needs it)
            stack.callback(_sweep_shared, target, stale_s)
        yield other


@contextlib.contextmanager
def held_for(
    target: str | Path, key: str, refusal: Callable[[Owner], str], *, note: dict | None = None
) -> Iterator[None]:
    """Hold ``target`` for ``key`` while the block runs (:func:`claim_shared`), or refuse before anything is done.

    A live holder of another key: ConfigError with ``refusal(holder)`` (the message naming what differs). A folder
    that cannot hold a claim file (read-only media, disk full) is not held: nothing can be written there either,
    and the writes that follow say why in their own words. Used by the runs that share an output for one set of
    settings (``nlips solve``'s results, ``nlips dataset``'s folder, ``nlips calibrate``'s samples).
    """
    from .errors import ConfigError

    with contextlib.ExitStack() as stack:
        try:
            other = stack.enter_context(claim_shared(target, key, note=note))
        except OSError as exc:
            log.debug("%s: not held for %s (%s)", target, key, exc.strerror or exc)
            other = None
        if other is not None:
            raise ConfigError(refusal(other))
        yield


def holder(target: str | Path, *, stale_s: float = CLAIM_STALE_S) -> Owner | None:
    """The live owner of ``target``'s claim, or None when it is unclaimed or the claim is stale.

    A fresh claim file that cannot be read yet (being written) gives ``UNKNOWN_OWNER``.
    """
    path = claim_path(target)
    owner = _read_owner(path)
    if owner is None and not path.exists():
        return None
    if _is_stale(path, owner, stale_s, now=fs_now(path.parent)):
        return None
    return owner or UNKNOWN_OWNER


def remove_dead_claims(folder: str | Path) -> list[Path]:
    """Remove every claim under ``folder`` (at any depth: exclusive claims, shared holders' claims, their
    temporaries) whose owner is gone, and return their paths. Live owners' claims stay.

    Why: a run killed while holding a claim on finished work (an experiment's Dask worker closed mid-task, its
    press's solve hold) leaves it where nothing claims again; each is taken over and released here, as
    :func:`claim` does with a stale claim (logged)."""
    removed = []
    for path in sorted(Path(folder).rglob(glob.escape(CLAIM_PREFIX) + "*")):
        target = path.with_name(path.name[len(CLAIM_PREFIX) :])
        if path.is_file() and _read_owner(path) is not None and holder(target) is None:
            with contextlib.suppress(OSError), claim(target):  # taken over; releasing it removes the file
                pass
            if not path.exists():
                removed.append(path)
    return removed


def wait_for_release(target: str | Path, on_wait: Callable[[], None] | None = None) -> None:
    """Return once no live process holds ``target``'s claim (its owner released it, or died: a dead owner's claim
    goes stale). Judged with the default staleness, the value every process sharing a folder agrees on.

    ``on_wait`` is called once, before the first pause, when there is something to wait for (to say so).
    """
    while holder(target) is not None:
        if on_wait is not None:
            on_wait()
            on_wait = None
        time.sleep(CLAIM_POLL_S)  # read at each pass, so a test's patch of it holds


def release_all() -> None:
    """Release every claim this process holds, and remove its clock probe if one is being written (for a
    signal handler about to exit the process: a worker SIGTERM'd by a broken process pool left one behind)."""
    for path, me in list(_HELD.items()):
        with contextlib.suppress(OSError):
            _release(path, me)
    _HELD.clear()
    for probe in list(_PROBES):
        with contextlib.suppress(OSError):
            probe.unlink(missing_ok=True)


def pid_alive(pid: int) -> bool:
    """Whether a process with this id runs on this machine (a zombie -- exited, not yet reaped -- does not).

    Windows: asked of psutil, never ``os.kill``. Why: Windows has no signal 0; its ``os.kill`` ends the process
    with ``TerminateProcess`` for any signal but Ctrl-C's, so the check killed what it asked about (a claim's
    owner, or a worker's own command: :func:`nlipscalib.core.processes.end_with_parent`)."""
    if sys.platform == "win32":
        import psutil  # a dependency on Windows only (pyproject); imported here, as the check is rare

        return psutil.pid_exists(pid)
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by another user
        return not _zombie(pid)
    return not _zombie(pid)


def _zombie(pid: int) -> bool:
    """True when Linux reports the process as exited but not yet reaped (state Z or X in /proc/PID/stat).

    Why: a worker killed with SIGKILL stays a zombie until its parent or init reaps it, which some containers'
    init does late; ``kill(pid, 0)`` succeeds on it, and its claims looked held by a live process."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text(encoding="utf-8")
    except OSError:  # no procfs (macOS, Windows) or gone meanwhile: kill() had the last word
        return False
    return stat[stat.rfind(")") + 2 :][:1] in ("Z", "X")  # the name in parentheses may hold spaces


# ---------------------------------------------------------------------- internals
def _acquire(path: Path, me: Owner, stale_s: float) -> bool:
    for _ in range(3):  # a takeover can race another process's; retry a couple of times
        if _create(path, me):
            return True
        owner = _read_owner(path)
        now = fs_now(path.parent)
        if not _is_stale(path, owner, stale_s, now):
            return False
        log.info("taking over stale claim %s (owner %s)", path, owner)
        _remove_if_same(path, owner)
    return False


def _join(stack: contextlib.ExitStack, target: Path, key: str, stale_s: float, note: dict | None) -> Owner | None:
    """Add this process to ``target``'s holders of ``key`` (its claim entered into ``stack``), unless a live holder of
    another key holds it (returned)."""
    while True:
        with claim(target, stale_s=stale_s) as mine:
            if mine:
                other = _shared_holder(target, stale_s, unlike=key)
                if other is None:
                    member = target.with_name(SHARE_SEP.join((target.name, key, secrets.token_hex(8))))
                    stack.enter_context(claim(member, stale_s=stale_s, note=note))  # a name of its own: always acquired
                return other
        time.sleep(CLAIM_POLL_S)  # another process is adding or looking: milliseconds


def _shared_members(target: Path) -> Iterator[tuple[str, Path]]:
    """(key, member target) of each claim of a holder of ``target`` (:func:`claim_shared`), live or not."""
    prefix = CLAIM_PREFIX + target.name + SHARE_SEP
    for path in target.parent.glob(glob.escape(prefix) + "*"):
        rest = path.name[len(prefix) :]
        if "." not in rest and SHARE_SEP in rest:  # NAME~KEY~TOKEN.x: a claim's temporary or one moved aside
            yield rest.rsplit(SHARE_SEP, 1)[0], path.with_name(path.name[len(CLAIM_PREFIX) :])


def _shared_holder(target: Path, stale_s: float, unlike: str) -> Owner | None:
    """A live holder of ``target`` whose key is not ``unlike``, or None."""
    for key, member in _shared_members(target):
        owner = holder(member, stale_s=stale_s) if key != unlike else None
        if owner is not None:
            return owner
    return None


def _sweep_shared(target: Path, stale_s: float) -> None:
    """Remove the claims of ``target``'s dead holders (and a dead process's claim of ``target`` itself, taken over
    here), so that a killed run leaves nothing behind once a later one ends. Best effort: a failed write here (a
    disk filled meanwhile) must not turn the work done under the claim into an error."""
    with contextlib.suppress(OSError), claim(target, stale_s=stale_s) as mine:
        if not mine:
            return  # another process is joining: the next one to leave sweeps
        for _, member in _shared_members(target):
            path = claim_path(member)
            owner = _read_owner(path)
            if owner is not None and _is_stale(path, owner, stale_s, now=fs_now(path.parent)):
                _remove_if_same(path, owner)


def _create(path: Path, me: Owner) -> bool:
    """Atomically create the claim file holding ``me``; False if it exists already."""
    fields = {"host": me.host, "pid": me.pid, "token": me.token}
    data = json.dumps(fields if me.note is None else fields | {"note": me.note}).encode()
    tmp = path.with_name(f"{path.name}.{me.token}")
    _PROBES.add(tmp)  # a signal handler exiting meanwhile removes it (release_all): no finally runs then
    try:
        tmp.write_bytes(data)
        os.link(tmp, path)
        return True
    except FileExistsError:
        return False
    except OSError as exc:  # file systems without hard links: exclusive create instead
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK):
            raise
        return _create_exclusive(path, data)
    finally:
        tmp.unlink(missing_ok=True)
        _PROBES.discard(tmp)


def _create_exclusive(path: Path, data: bytes) -> bool:
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
    except FileExistsError:
        return False
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    return True


def _read_owner(path: Path) -> Owner | None:
    try:
        d = json.loads(path.read_bytes())
        note = d.get("note")
        return Owner(str(d["host"]), int(d["pid"]), str(d["token"]), note if isinstance(note, dict) else None)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None  # missing, or being written by an O_EXCL creator


def _is_stale(path: Path, owner: Owner | None, stale_s: float, now: float) -> bool:
    try:
        age = now - path.stat().st_mtime
    except FileNotFoundError:
        return True
    if owner is not None and owner.host == HOST and not pid_alive(owner.pid):
        return True
    return age > stale_s


def fs_now(folder: Path) -> float:
    """The current time by the file system's clock (matters when machines' clocks disagree)."""
    probe = folder / f"{CLAIM_PREFIX}probe.{HOST}.{os.getpid()}.{secrets.token_hex(4)}"
    _PROBES.add(probe)  # a signal handler exiting meanwhile removes it (release_all): no finally runs then
    try:
        probe.write_bytes(b"")
        return probe.stat().st_mtime
    except OSError:
        return time.time()
    finally:
        with contextlib.suppress(OSError):  # a read-only disk refuses to unlink even a file that is not there
            probe.unlink(missing_ok=True)
        _PROBES.discard(probe)


def _remove_if_same(path: Path, owner: Owner | None) -> None:
    """Remove a stale claim, unless another process replaced it meanwhile (then it is not stale)."""
    aside = path.with_name(f"{path.name}.stale.{secrets.token_hex(6)}")
    try:
        os.rename(path, aside)  # only one of several racing takers wins this rename
    except FileNotFoundError:
        return
    if _read_owner(aside) != owner:  # we moved a fresh claim: put it back
        with contextlib.suppress(FileExistsError):
            os.link(aside, path)
    aside.unlink(missing_ok=True)


def _release(path: Path, me: Owner) -> None:
    if _read_owner(path) == me:
        path.unlink(missing_ok=True)


class _Heartbeats:
    """One thread that refreshes the mtime of every claim this process holds, each at its own interval, and notices
    (and logs) a claim lost to a takeover. Why one: a batch of solves holds a claim per press for the whole run
    (pipeline.reuse._hold), and a thread per claim would be hundreds of threads for a large folder."""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # held for a whole round of beats: remove() returns between rounds
        self._changed = threading.Condition(threading.Lock())
        self._due: dict[Path, tuple[Owner, float, float]] = {}  # path -> (owner, interval, next beat's time)
        self._thread: threading.Thread | None = None

    def add(self, path: Path, me: Owner, interval: float) -> None:
        with self._changed:
            self._due[path] = (me, interval, time.monotonic() + interval)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._run, name="claim-heartbeats", daemon=True)
                self._thread.start()
            self._changed.notify()

    def remove(self, path: Path) -> None:
        """Stop beating ``path``; once this returns no beat of it is under way (its file can be released)."""
        with self._lock, self._changed:
            self._due.pop(path, None)
            self._changed.notify()

    def count(self) -> int:
        with self._changed:
            return len(self._due)

    def _run(self) -> None:
        while True:
            with self._changed:
                if not self._due:
                    self._thread = None  # ends; the next add() starts another
                    return
                now = time.monotonic()
                wait = min(due for _, _, due in self._due.values()) - now
                if wait > 0:
                    self._changed.wait(wait)
                    continue
            with self._lock:
                for path in self._take_due():
                    self._beat(path)

    def _take_due(self) -> list[Path]:
        """The claims due for a beat now, their next beat scheduled."""
        with self._changed:
            now, due = time.monotonic(), []
            for path, (me, interval, at) in list(self._due.items()):
                if at <= now:
                    self._due[path] = (me, interval, now + interval)
                    due.append(path)
            return due

    def _beat(self, path: Path) -> None:
        with self._changed:
            entry = self._due.get(path)
        if entry is None:
            return
        if _read_owner(path) != entry[0]:
            log.warning("claim %s was taken over by another process", path)
            with self._changed:
                self._due.pop(path, None)  # no longer ours: not refreshed
            return
        with contextlib.suppress(OSError):
            os.utime(path)


_HEARTBEATS = _Heartbeats()
# a forked child holds none of its parent's claims (the parent's heartbeat thread is not copied into it either)
os.register_at_fork(after_in_child=lambda: _HEARTBEATS.__init__())
