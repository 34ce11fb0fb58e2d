"""Reusing an earlier result and sharing its folder with other processes: its key compared, its claim taken or
waited for, interrupted writes beside it cleaned."""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.atomic import TMP_PREFIX
from ..core.errors import CaptureError
from ..core.libraries import SOLVE_LIBRARIES
from ..core.reconstruction import REPORT_FILE, load_reconstruction, read_report, reconstruction_problem
from .status import SKIPPED

if TYPE_CHECKING:
    from ..core.claims import Owner

log = logging.getLogger(__package__)  # the package's one logger: log files keep naming "nlipscalib.pipeline"


def _published_since(out: Path, since: float | None) -> bool:
    """Whether ``out``'s result was published at or after ``since`` (file-system clock; False without one)."""
    if since is None:
        return False
    try:
        return (out / REPORT_FILE).stat().st_mtime >= since
    except OSError:
        return False


def _wait_for_release(folder: Path, out: Path) -> None:
    """Wait until no live process holds the claim on ``out`` (it published its result, failed, or died:
    a dead owner's claim goes stale and is taken over)."""
    from ..core.claims import wait_for_release

    log.info("%s: being solved by another process; waiting for it", folder)
    wait_for_release(out)


def _claim(target: Path):
    from ..core.claims import claim

    return claim(target)


@contextlib.contextmanager
def _hold(folder: Path, out: Path, record: dict) -> Iterator[None]:
    """Hold ``out`` for the settings of ``record`` (provenance.run_record) while the block runs, together with every
    run of the same settings (core.claims.claim_shared): runs of one settings share the press as before.

    Raises ConfigError naming the press, ``out`` and the other run's settings when a live run of other settings holds
    it. Why refuse rather than wait and then replace: two runs of other settings each replaced what the other had
    just made (the later one's, by timing, each exiting 0), and a batch of both left a folder of mixed settings. A
    folder that cannot hold a claim file (read-only media) is not held: a result there can still be reused, and a
    solve says why it cannot write.
    """
    from ..core.claims import RUN_HOLD, held_for

    refusal = lambda other: _held_elsewhere(folder, out, other, record)  # noqa: E731
    with held_for(out.with_name(out.name + RUN_HOLD), record["key"], refusal, note=record):
        yield


def _held_elsewhere(folder: Path, out: Path, other: Owner, record: dict) -> str:
    theirs = other.note if isinstance(other.note, dict) else {}
    return (
        f"{out}: another run is solving {folder} into it with other settings ({_in_words(theirs, record)}; "
        f"{other.who}); "
        "left to it: run again once it has ended, or solve into another --out"
    )


def _reuse(out: Path, provenance: dict, want_result: bool, quiet: bool, announce: bool = True):
    """(result or None, "skipped") when ``out`` holds a sound result made with the same key; else None.

    ``quiet``: no word on why a result is not reused; ``announce``: say that one is. An empty folder (made for
    the output, or a symlink to one) holds nothing to reuse, and is no damaged result to warn about."""
    if not out.exists() or (out.is_dir() and next(out.iterdir(), None) is None):
        return None
    problem = reconstruction_problem(out, verify=not want_result)  # a loaded result is checked as it loads
    if problem is not None:
        if not quiet:
            log.warning("%s; re-computing it", problem)
        return None
    old = read_report(out).get("provenance")
    if not isinstance(old, dict):  # absent, or a hand-edited report: no record of what made it
        old = {}
    if old.get("key") != provenance["key"]:
        if not quiet:
            log.info("%s: %s", out, _why_not_reused(old, provenance))
        return None
    reused_level = logging.INFO if announce else logging.DEBUG
    if not want_result:
        log.log(reused_level, "%s: identical result exists, skipped (--overwrite re-solves)", out)
        return None, SKIPPED
    try:
        result = load_reconstruction(out)
    except CaptureError as exc:
        if not quiet:
            log.warning("%s; re-computing it", exc)
        return None
    log.log(reused_level, "%s: identical result exists, skipped (--overwrite re-solves)", out)
    return result, SKIPPED


def _why_not_reused(old: dict, new: dict) -> str:
    """Why a result recorded by ``old`` is not the one ``new`` asks for, in one line: "made with numpy 2.3.1, now
    2.4.6: re-solving" when only library versions differ, else "made with other settings or inputs (roi, numpy 2.3.1
    now 2.4.6), re-solving"."""
    differences = _differences(old, new) if old else []
    if differences and all(name in LIBRARY_NAMES for name, _, _ in differences):
        return "made with " + "; ".join(_library_change(*d) for d in differences) + ": re-solving"
    return f"made with other settings or inputs ({_what_changed(old, new)}), re-solving"


def _what_changed(old: dict, new: dict) -> str:
    if not old:
        return "no record of them"
    named = (_library_change(*d, sep=" ") if d[0] in LIBRARY_NAMES else d[0] for d in _differences(old, new))
    return ", ".join(named) or "record differs"


def _library_change(name: str, was: object, now: object, sep: str = ", ") -> str:
    """A library's version that differs, in words: "numpy 2.3.1, now 2.4.6" (None: "not installed"); ``sep`` " "
    inside a list of differences, whose items commas part."""
    text = lambda v: "not installed" if v is None else str(v)  # noqa: E731
    return f"{name} {text(was)}{sep}now {text(now)}"


def _in_words(old: dict, new: dict) -> str:
    """:func:`_what_changed` with the old values where they are short: "roi auto (this run: none)"."""
    if not old:
        return "settings unknown"
    return ", ".join(_word(name, was, now) for name, was, now in _differences(old, new)) or "record differs"


def _word(name: str, was: object, now: object) -> str:
    text = lambda v: "none" if v is None else str(v)  # noqa: E731
    if len(text(was)) + len(text(now)) > 40:  # calibrated LEDs, a capture's hash: the name says enough
        return name
    return f"{name} {text(was)} (this run: {text(now)})"


def _differences(old: dict, new: dict) -> list[tuple[str, object, object]]:
    """(name, old value, new value) of what differs between the provenance record ``old`` and ``new``."""
    settings, inputs = old.get("settings"), old.get("inputs")
    settings = settings if isinstance(settings, dict) else {}
    inputs = inputs if isinstance(inputs, dict) else {}
    changed = []
    for k, v in new["settings"].items():
        was = settings.get(k)
        if k in ("leds_file", "reference") or was == v:
            continue
        if isinstance(was, dict) and isinstance(v, dict):  # options, solver keywords: the fields that differ,
            # by the names a user gives them (--interreflection), not the record's grouping ("solver_keywords")
            changed += [(f, was.get(f), v.get(f)) for f in sorted(set(was) | set(v)) if was.get(f) != v.get(f)]
        else:
            changed.append((k, was, v))
    changed += [(f"{k} capture", inputs.get(k), v) for k, v in new["inputs"].items() if inputs.get(k) != v]
    if old.get("software_version") != new["software_version"]:
        changed.append(("software version", old.get("software_version"), new["software_version"]))
    if "code" not in old:  # written before the key had the code's fingerprint: which code made it is unknown
        changed.append((CODE_UNRECORDED, None, new["code"]))
    elif old["code"] != new["code"]:
        changed.append(("nlipscalib code", old["code"], new["code"]))
    was = old.get("libraries")
    if not isinstance(was, dict):  # written before the key had the libraries' versions: made under unknown ones
        if "code" in old:  # (a record without the code's fingerprint says so already)
            changed.append((LIBRARIES_UNRECORDED, None, new["libraries"]))
    else:
        changed += [(k, was.get(k), v) for k, v in new["libraries"].items() if was.get(k) != v]
    return changed


CODE_UNRECORDED = "code unrecorded: an nlipscalib before 2026-12-06 made it"
"""What :func:`_differences` says of a result whose provenance has no ``code`` fingerprint: never reused, as the
code that made it cannot be told from this one."""
LIBRARIES_UNRECORDED = "library versions unrecorded: an nlipscalib before 2026-12-06 made it"
"""What :func:`_differences` says of a result whose provenance has no ``libraries``: never reused, as the NumPy,
SciPy, pyamg and OpenCV that made it are unknown."""
LIBRARY_NAMES = frozenset(SOLVE_LIBRARIES)
"""The names under which :func:`_differences` reports a library whose version differs."""


def _leftovers(out: Path) -> bool:
    """Whether temporary entries of ``out`` (live or interrupted writes) or a dead run's claim lie beside it.

    Why the claim: a run killed between publishing ``out`` and releasing its claim leaves a sound result with
    the claim beside it; reusing the result without the claimed way (which takes a stale claim over and removes
    it) left that claim there for good."""
    from ..core.claims import claim_path, holder

    if any(out.parent.glob(f"{TMP_PREFIX}{out.name}[~-]*")):
        return True
    return claim_path(out).exists() and holder(out) is None  # a live run's claim: its result is reused as it is


def _clean_interrupted(out: Path) -> None:
    """Remove interrupted writes of ``out`` beside it. Call only while holding its claim.

    Owner-tagged temporary folders (``.tmp-nlips~host~pid~*``) go when their owner is gone
    (core.atomic.clean_interrupted); untagged ones of older versions (``.tmp-nlips-XXXXXXXX``, ``.tmp-nlips-old``)
    go too: holding the claim means no live process of this pipeline is writing ``out``. Only ``out``'s own:
    ``.tmp-res-2~host~pid~*`` is the live temporary of another output (``--out res-2``), which the claim on
    ``res`` does not cover (a glob ``.tmp-res-*`` removed it under a running solve).
    """
    import glob
    import re
    import shutil

    from ..core.atomic import clean_interrupted, removed_leftover

    gone = clean_interrupted(out.parent, item=out.name)
    # tempfile.mkdtemp's suffix, or "old": another item's legacy name has a second "-", a tagged one a "~"
    untagged = re.compile(re.escape(f"{TMP_PREFIX}{out.name}-") + r"[a-z0-9_]+")
    legacy = [p for p in out.parent.glob(glob.escape(f"{TMP_PREFIX}{out.name}-") + "*") if untagged.fullmatch(p.name)]
    for tmp in legacy:
        shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)
    for tmp in gone + legacy:
        log.warning("%s: removed %s", tmp, removed_leftover(tmp))
