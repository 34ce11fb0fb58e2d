"""What a dataset folder already holds, judged against a spec: a press complete (its meta.json records this very
spec and every file it lists is there), rendered from another spec or damaged (an error before a run), or not
named by the spec at all (a warning)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

from ..core import said_once
from ..core.errors import CaptureError, ConfigError, NlipsError
from ..core.press_folders import is_press_folder
from ..core.press_meta import META_FILE, SOURCE_SENSOR, press_source
from .dataset_spec import PressJob
from .indent import PressConfig
from .scene import SceneConfig

log = logging.getLogger(__name__)


def is_complete(scene: SceneConfig, job: PressJob, out: Path, overwrite: bool = False, verify: bool = False) -> bool:
    """A whole folder rendered from this very spec: meta.json records the spec, and every file it lists is there
    and unchanged since it was written (:func:`missing_files`; with ``verify`` every byte of it); with ``overwrite``
    also rendered by this installation's twin code and renderer (the others are rendered again)."""
    folder = out / job.name
    if not is_press_folder(folder) or not same_spec(scene, job, out) or missing_files(folder, verify):
        return False
    return not (overwrite and rendered_elsewhere_in(folder))


def same_spec(scene: SceneConfig, job: PressJob, out: Path) -> bool:
    """Whether the press folder of ``job`` in ``out`` records this very spec (scene, press, seed; not the renderer:
    :func:`check_existing` warns about presses of other twin code or another Mitsuba)."""
    return _recorded_hash(out / job.name) == _expected_hash(scene, job)


def missing_files(folder: Path, verify: bool = False) -> dict[str, str]:
    """Files ``folder``'s meta.json lists that are gone (deleted or lost since it was rendered), empty, cut short
    (core.file_checks) or of another size than its checksums.json records, and with ``verify`` of other content
    (core.press_checksums), each with its problem in a few words; {} when whole, or when meta.json cannot say (its
    format is for the commands that load the press to judge).

    Why empty or cut short ones: no file a render writes is either, and that is what a power cut soon after the
    press was published leaves (its folder renamed into place, its files' data not yet on the disk: the writes are
    atomic, not synced). Such a press was "already there" at every run; the commands reading it named the file,
    and only deleting the folder by hand rendered it again. Only the ends of each file are read (~10-20 us a file),
    and its size compared with the record (one small JSON file a press). Why the size and content: a file damaged
    inside, or another press's image copied over it, is whole at its ends; the press was kept, and failed late
    (a solve, training) or never."""
    from ..core.press_checksums import press_file_problems
    from ..core.press_meta import listed_files

    try:
        names = listed_files(json.loads((folder / META_FILE).read_bytes()))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}
    return press_file_problems(folder, names, verify)


def torn_own_meta(scene: SceneConfig, job: PressJob, out: Path) -> str | None:
    """Why the meta.json of ``job``'s press folder in ``out`` cannot be read (cut short, emptied, not JSON), when the
    folder is this dataset's own render of ``job``: the dataset's record (dataset.json) lists the press under its
    name with this very scene, press and seed. None when meta.json is readable, or the folder is not known to be
    the dataset's own (no readable dataset.json, another spec's record): :func:`check_existing` refuses that one.

    Why: a power cut soon after a press was published can leave its meta.json cut short (writes are atomic, not
    synced), and ``nlips dataset`` then stopped with "the press folder is damaged: delete it ... or use
    --overwrite" -- for a folder that is nothing but this dataset's render, made again as a torn image is."""
    problem = _meta_problem(out / job.name)
    if problem is None or not _listed_in_manifest(scene, job, out):
        return None
    return problem.removeprefix(f"{out / job.name / META_FILE}: ")


def described_missing(problems: dict[str, str], most: int = 3) -> str:
    """``problems`` (:func:`missing_files`) in words: "led_02.png missing, led_05.png cut short (no PNG end chunk)
    and 2 more"."""
    from ..core.press_checksums import described_file_problems

    return described_file_problems(problems, most)


def check_existing(scene: SceneConfig, jobs: list[PressJob], out: Path, overwrite: bool) -> None:
    """Finished presses made from another spec, or with a damaged meta.json, are an error (or
    re-rendered with ``overwrite``); ones of this spec that other twin code or render libraries made are kept with a
    warning (re-rendered with ``overwrite``)."""
    captured = [j.name for j in jobs if is_press_folder(out / j.name) and press_source(out / j.name) == SOURCE_SENSOR]
    if captured:
        # said "rendered from a different scene or spec (...: an older nlipscalib rendered it)", and --overwrite
        # then rendered over the captured presses
        raise ConfigError(
            f"{out / captured[0]}: a press captured on a sensor (nlips capture), not a twin render; nothing is "
            "replaced, even with --overwrite: render the dataset into a new folder"
        )
    if overwrite:
        return
    found = [j for j in jobs if is_press_folder(out / j.name)]
    own_torn = {j.name for j in found if torn_own_meta(scene, j, out)}  # rendered again by the run (_render_job)
    damaged = [p for p in (_meta_problem(out / j.name) for j in found if j.name not in own_torn) if p]
    if damaged:
        more = f" ({len(damaged) - 1} more press folders are damaged too)" if len(damaged) > 1 else ""
        raise CaptureError(
            f"{damaged[0]}; the press folder is damaged{more}: delete it to render it again, or use --overwrite"
        )
    found = [j for j in found if j.name not in own_torn]
    other_renderer = [j.name for j in found if _recorded_hash(out / j.name) == _expected_hash(scene, j)]
    other_renderer = [name for name in other_renderer if rendered_elsewhere_in(out / name)]
    # said once a command: `nlips dataset` checks before its manifest is written and again as the renders start
    if other_renderer and said_once.first_time(f"rendered elsewhere\0{out.resolve()}"):
        names = ", ".join(other_renderer[:3]) + (
            f" and {len(other_renderer) - 3} more" if len(other_renderer) > 3 else ""
        )
        # kept, not refused: `nlips demo` or a dataset's resume after an upgrade must not stop on hours of renders
        log.warning(
            "%s: %s were rendered by other twin code or render libraries (%s); kept, so the dataset mixes renderers: "
            "--overwrite renders them again",
            out,
            names,
            render_difference(out / other_renderer[0]),
        )
    changed = [j.name for j in found if not same_spec(scene, j, out)]
    if changed:
        names = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
        meshes = any(j.press is not None and j.press.indenter.kind == "mesh" for j in jobs if j.name in changed)
        edited = " (or from another version of an indenter's mesh file: its content counts)" if meshes else ""
        first = next(j for j in jobs if j.name == changed[0])
        why = spec_change(scene, first.press, first.seed, out / first.name)
        why = f" ({first.name}: {why})" if why else ""
        raise ConfigError(
            f"{out}: {names} were rendered from a different scene or spec{edited}{why}; render into a new folder, "
            "or use --overwrite to re-render them"
        )


SPEC_CHANGES_SHOWN = 3
"""How many of the differing settings :func:`spec_change` names (the rest are counted)."""


def spec_change(scene: SceneConfig, press: PressConfig | None, seed: int | None, folder: Path) -> str:
    """What differs between the spec the press folder ``folder`` records and this one (``scene``, ``press``,
    ``seed``; None: the scene's seed for the press), for the refusals of :func:`check_existing` and ``nlips render``:
    "scene.render.bounces: 0 -> 1", naming up to :data:`SPEC_CHANGES_SHOWN` settings, and saying so when every one of
    them is a setting its record lacks (a folder an older nlipscalib rendered, before the setting existed); "" when
    the record cannot say (no scene recorded, a mesh file edited).

    Why: after an upgrade a dataset's resume was refused as "rendered from a different scene or spec" while the
    user had changed neither: the scene had gained render settings (``render.denoise``) since."""
    from ..core.config import to_mapping
    from ..core.sensor_record import setting_differences
    from .press import hashed_spec, press_seed

    was = _provenance(folder)
    if not isinstance(was.get("scene"), dict) or not isinstance(was["scene"].get("render"), dict):
        return ""
    press_dict = None if press is None else to_mapping(press)
    seed = press_seed(scene.render.seed, press_dict) if seed is None else int(seed)
    try:
        old = hashed_spec(was["scene"], was.get("press"), was.get("seed"))
    except (TypeError, ValueError, AttributeError):
        return ""
    changes = setting_differences(old, hashed_spec(scene.to_dict(), press_dict, seed))
    if not changes:
        return ""
    more = f" and {len(changes) - SPEC_CHANGES_SHOWN} more" if len(changes) > SPEC_CHANGES_SHOWN else ""
    unrecorded = all(": None -> " in change for change in changes)
    older = "; settings its record lacks: an older nlipscalib rendered it" if unrecorded else ""
    return f"{', '.join(changes[:SPEC_CHANGES_SHOWN])}{more}{older}"


def changed_error(scene: SceneConfig, job: PressJob, out: Path) -> str:
    """The line :func:`check_existing` gives for ``job``'s folder, rendered from another spec (or damaged)."""
    try:
        check_existing(scene, [job], out, overwrite=False)
    except NlipsError as exc:
        return str(exc)
    return f"{out}: {job.name} was rendered meanwhile from a different scene or spec"  # and replaced since


def warn_unlisted(jobs: list[PressJob], out: Path) -> list[str]:
    """Warn about press folders in ``out`` that the spec does not name (left by an earlier, longer spec, or a
    reference the spec no longer asks for): every later command on the folder (solve, calibrate) still takes
    them as part of the dataset. Returns their names."""
    named = {j.name for j in jobs}
    extra = sorted(p.name for p in out.iterdir() if p.is_dir() and p.name not in named and is_press_folder(p))
    if extra:
        more = f" and {len(extra) - 3} more" if len(extra) > 3 else ""
        are, them = ("is", "it") if len(extra) == 1 else ("are", "them")
        log.warning(
            "%s: %s%s %s not in this spec (left from an earlier one); later commands on the folder still use "
            "%s: remove %s, or render into a new folder",
            out,
            ", ".join(extra[:3]),
            more,
            are,
            them,
            them,
        )
    return extra


def live_claim_inside(folder: Path) -> str | None:
    """Who works inside ``folder`` now (a live claim there, e.g. a solve's ``.claim-nlips``), or None."""
    from ..core.claims import CLAIM_PREFIX, holder

    if not folder.is_dir():
        return None
    for path in folder.glob(CLAIM_PREFIX + "*"):
        name = path.name[len(CLAIM_PREFIX) :]
        owner = holder(folder / name) if "." not in name else None  # NAME.token, NAME.stale.x: not claims
        if owner is not None:
            return f"process {owner.pid} on {owner.host} holds {path.name} in it"
    return None


def results_inside(folder: Path) -> list[str]:
    """Names of the result folders inside a press folder (``nlips/``, ``nlipsnet/``, a solve's ``--out``)."""
    return sorted(p.name + "/" for p in folder.iterdir() if p.is_dir() and not p.name.startswith("."))


def rendered_elsewhere_in(folder: Path) -> bool:
    """Whether the press in ``folder`` was rendered by other twin code or render libraries than this installation's
    (or records none): ``nlips dataset`` and ``nlips render`` keep it with a warning, ``--overwrite`` renders it again.
    """
    from .press import rendered_elsewhere

    return rendered_elsewhere(_provenance(folder))


def render_difference(folder: Path) -> str:
    """What rendered ``folder`` otherwise than this installation would, in words ("other code of sim/ or core/",
    "mitsuba 3.5.0 (now 3.9.1)"), for the warnings of :func:`rendered_elsewhere_in`."""
    from .press import render_identity

    was, here = _provenance(folder), render_identity()
    if "code" not in was:
        return "twin code unrecorded: rendered before 2026-12-06"
    said = ["other code of sim/ or core/"] if was.get("code") != here["code"] else []
    libraries = was.get("libraries") if isinstance(was.get("libraries"), dict) else {}
    said += [f"{k} {libraries.get(k)} (now {v})" for k, v in here["libraries"].items() if libraries.get(k) != v]
    return ", ".join(said)


# ---------------------------------------------------------------------- internals
def _meta_problem(folder: Path) -> str | None:
    """Why ``folder``'s meta.json cannot be read as JSON (unreadable, not JSON, not an object), or None."""
    path = folder / META_FILE
    try:
        meta = json.loads(path.read_bytes())
    except OSError as exc:
        return f"{path}: cannot be read ({exc.strerror or exc})"
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        return f"{path}: not valid JSON ({exc})"
    if not isinstance(meta, dict):
        return f"{path}: not a JSON object"
    return None


def _listed_in_manifest(scene: SceneConfig, job: PressJob, out: Path) -> bool:
    """Whether ``out``'s dataset.json records ``job`` under its name with the scene, press and seed of ``scene`` and
    ``job``: what the run that made the folder asked for (:func:`.dataset_manifest.manifest_text`). Compared as a
    render's spec hash takes them (:func:`.press.hashed_spec`: not the thread count), as JSON values."""
    from ..core.config import to_mapping
    from .dataset_manifest import MANIFEST
    from .press import hashed_spec

    def as_json(value: object) -> object:
        return json.loads(json.dumps(value))

    try:
        record = json.loads((out / MANIFEST).read_bytes())
        entry = {press["name"]: press for press in record["presses"]}[job.name]
        theirs = hashed_spec(record["scene"], entry["press"], entry["seed"])
        press = None if job.press is None else to_mapping(job.press)  # the reference: none
        return as_json(theirs) == as_json(hashed_spec(scene.to_dict(), press, job.seed))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return False


def _recorded_hash(folder: Path) -> str | None:
    from .press import recorded_spec_hash

    try:
        return recorded_spec_hash(json.loads((folder / "meta.json").read_text(encoding="utf-8"))["provenance"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None


def _provenance(folder: Path) -> dict:
    try:
        provenance = json.loads((folder / META_FILE).read_text(encoding="utf-8"))["provenance"]
    except (OSError, ValueError, KeyError, TypeError):
        return {}
    return provenance if isinstance(provenance, dict) else {}


def _expected_hash(scene: SceneConfig, job: PressJob) -> str:
    from .press import render_spec_hash

    return render_spec_hash(scene, job.press, job.seed)
