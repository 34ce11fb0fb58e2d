"""Reusing an earlier result and sharing its folder with other processes: its key compared, its claim taken or
waited for, interrupted writes beside it cleaned."""

from __future__ import annotations

import logging
from pathlib import Path

from ..core.atomic import TMP_PREFIX
from ..core.errors import CaptureError
from ..core.reconstruction import REPORT_FILE, load_reconstruction, read_report, reconstruction_problem
from .status import SKIPPED

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


def _reuse(out: Path, provenance: dict, want_result: bool, quiet: bool, announce: bool = True):
    """(result or None, "skipped") when ``out`` holds a sound result made with the same key; else None.

    ``quiet``: no word on why a result is not reused; ``announce``: say that one is."""
    if not out.exists():
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
            log.info("%s: made with other settings or inputs (%s), re-solving", out, _what_changed(old, provenance))
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


def _what_changed(old: dict, new: dict) -> str:
    if not old:
        return "no record of them"
    settings, inputs = old.get("settings"), old.get("inputs")
    settings = settings if isinstance(settings, dict) else {}
    inputs = inputs if isinstance(inputs, dict) else {}
    changed = [k for k, v in new["settings"].items() if k not in ("leds_file", "reference") and settings.get(k) != v]
    changed += [f"{k} capture" for k, v in new["inputs"].items() if inputs.get(k) != v]
    if old.get("software_version") != new["software_version"]:
        changed.append("software version")
    return ", ".join(changed) or "record differs"


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

    from ..core.atomic import clean_interrupted

    gone = clean_interrupted(out.parent, item=out.name)
    # tempfile.mkdtemp's suffix, or "old": another item's legacy name has a second "-", a tagged one a "~"
    untagged = re.compile(re.escape(f"{TMP_PREFIX}{out.name}-") + r"[a-z0-9_]+")
    legacy = [p for p in out.parent.glob(glob.escape(f"{TMP_PREFIX}{out.name}-") + "*") if untagged.fullmatch(p.name)]
    for tmp in legacy:
        shutil.rmtree(tmp, ignore_errors=True) if tmp.is_dir() else tmp.unlink(missing_ok=True)
    for tmp in gone + legacy:
        log.warning("%s: removed an interrupted write", tmp)
