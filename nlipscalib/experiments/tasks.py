"""Per-press tasks of an experiment and how one is run: render, solve every variant asked, score, write JSON.

Three kinds of task, run in stages: ``reference`` (stage 0) renders the undeformed dome of one scene;
``calibration`` (stage 1) self-calibrates the LEDs from it, starting from the design LEDs with a
given error; ``press`` (stage 2) renders one press and solves it once per distinct solve variant.
Each task writes ``tasks/<id>.json`` atomically when it is done; a task whose JSON exists with the
same content hash, made with the same code and libraries (:func:`made_with`), is never run again, so an
interrupted experiment resumes where it stopped and a worker that dies loses only the task it was running.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import logging
import shutil
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.atomic import NO_SPACE_ERRNOS, write_bytes, write_json
from ..core.errors import ConfigError
from ..core.libraries import RENDER_LIBRARIES, SOLVE_LIBRARIES
from ..core.sensor import rendered_scene

if TYPE_CHECKING:  # named in hints only
    from types import ModuleType

    from ..core.capture import Press
    from ..core.leds import Led
    from ..core.reconstruction import Reconstruction

log = logging.getLogger(__name__)
STAGES = {"reference": 0, "calibration": 1, "press": 2}
SOLVES_DIR = "solves"
"""PRESS/solves/<variant hash>/: the pipeline's reconstruction of each solve variant of a press."""
REUSED = "reused"
"""What :func:`execute` returns for a task another run sharing the folder finished."""
NO_SPACE = "failed for lack of space: "
"""Start of what :func:`execute` returns for a task that failed on a full disk (or quota): the runner then starts
no other task, each of which would render for seconds to minutes and then fail too."""
RULES_HASHED_SILENTLY = {"rule": 2}
"""learn.dataset.SAMPLE_RULES when press tasks' hashes began to hold them (2026-12-05): at these versions a hash
leaves them out, so the work folders of earlier runs, whose samples these rules made, keep their tasks (a full Q2
is hours of renders and solves) rather than make them all again for a code that did not change. Never updated:
any other versions enter the hash (the first: learn.dataset.FRAME_GAIN_RULE, 2026-12-06, whose rule did change the
samples of a press dimmer than its undeformed capture)."""


GIVEN_LEDS_MODEL = "auto"
"""The LED model of the calibrations and of the solves with given LEDs (the design and calibrated rows) since
2026-12-08 (s43-expauto): ``--led-model auto``'s, the design's declared disks where its point LEDs miss them unevenly
over its gel (flat pad, oblate, capsule), points elsewhere, as the true rows' solves since s42 (before: points
always). In the hashes of the tasks that calibrate or solve with given LEDs, with the design's declared LED size
they now read, so a work folder's earlier point results of those rows are made again; the true rows' keep theirs."""


TASK_CODE = {
    "reference": ("core", "sim"),
    "calibration": ("core", "sim", "solver"),
    "press": ("core", "sim", "solver", "pipeline"),
}
"""Subpackages whose source shapes a task's result, per kind: a reference is a render (the twin and the formats:
core.code_version.RENDER_CODE); a calibration fits the LEDs (solver) to the reference's images, so the code of that
render too; a press task renders, solves (solver, pipeline) and reads the reference and calibrations. A change
elsewhere (cli, experiments' tables and figures, report, device) keeps every task; a change of the solver alone
keeps the references, whose renders cost the most a scene, and the presses' renders, which each press task keeps in
its folder and reuses when their own key, the twin's code and the render libraries, still holds
(:func:`_rendered_here`): a press task is then a solve of the same images."""
SAMPLES_CODE = ("learn",)
"""What a press task that writes NLiPsNet calibration samples (``Task.samples``) depends on besides: the samples'
rules (learn.dataset). Not the other press tasks: NLiPsNet's code changes often, and a Q1 press does not use it."""
TASK_LIBRARIES = {
    "reference": RENDER_LIBRARIES,
    "calibration": RENDER_LIBRARIES + SOLVE_LIBRARIES,
    "press": RENDER_LIBRARIES + SOLVE_LIBRARIES,
}
"""Libraries whose release shapes a task's result, per kind (core.libraries), with the same reasoning."""


def made_with(kind: str, samples: bool = False) -> dict:
    """What a task of ``kind`` (writing NLiPsNet samples: ``samples``) is made with here: ``{"code": digest of its
    TASK_CODE's source (and SAMPLES_CODE's), "libraries": {name: version}}``, recorded in each task result and
    compared when one would be reused (computed once per process and kind; a copy each call).

    Why: a task's hash holds what it computes (scene, press, solves), not the code, and the version number is the
    same in every commit, so a rerun after an upgrade reused the old code's numbers beside the new code's in one
    table, said only in a warning."""
    return json.loads(_made_with(kind, samples))


@functools.cache
def _made_with(kind: str, samples: bool) -> str:
    from ..core.code_version import subpackages_fingerprint
    from ..core.libraries import library_versions

    code = subpackages_fingerprint(task_code(kind, samples))
    return json.dumps({"code": code, "libraries": library_versions(TASK_LIBRARIES[kind])})


def task_code(kind: str, samples: bool = False) -> tuple[str, ...]:
    """The subpackages a task of ``kind`` depends on (:data:`TASK_CODE`, with :data:`SAMPLES_CODE` for ``samples``)."""
    return TASK_CODE[kind] + (SAMPLES_CODE if samples else ())


def digest(obj: object, n: int = 10) -> str:
    """Short content hash of a JSON-able object (stable across processes and machines)."""
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:n]


SOLVE_CHOICES = {
    "leds": ("true", "design", "calibrated"),
    "interreflection": ("off", "reference", "dent"),
    "roi": ("truth", "auto", "full"),
}
"""The words a :class:`SolveSpec` field (and the experiment config fields it comes from) accepts."""


@dataclasses.dataclass(frozen=True)
class SolveSpec:
    """One way of solving a press."""

    leds: str = "true"
    """LEDs given to the solver: true (the twin's), design (with ``led_error``) or calibrated
    (self-calibrated from the reference, starting from the design with ``led_error``)."""
    position_error_mm: float = 0.0
    """CAD error of every LED position, mm (fixed magnitude, random direction)."""
    direction_error_deg: float = 0.0
    """CAD error of every LED axis, degrees (fixed magnitude, random tilt)."""
    error_seed: int = 0
    """Seed of the CAD error's random directions."""
    interreflection: str = "dent"
    """off, reference (undeformed dome's indirect light) or dent (also the dent's own bounce)."""
    roi: str = "truth"
    """truth (true contact box + margin), auto (the solver's contact detector) or full."""
    options: tuple[tuple[str, object], ...] = ()
    """SolverOptions overrides as (name, value) pairs."""

    def __post_init__(self):
        # checked when the tasks are planned: an unknown word would otherwise fail every press after its render
        for name, allowed in SOLVE_CHOICES.items():
            if getattr(self, name) not in allowed:
                raise ConfigError(f"{name}: must be one of {list(allowed)}, got {getattr(self, name)!r}")
        if self.options:  # a bad solver option (e.g. Q2's normals) too, not once per press after its render
            from .adapters import solver_options

            solver_options(dict(self.options))

    def led_error(self) -> dict:
        return {
            "position_mm": self.position_error_mm,
            "direction_deg": self.direction_error_deg,
            "seed": self.error_seed,
        }

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["options"] = dict(self.options)
        return d


@dataclasses.dataclass(frozen=True)
class Task:
    """One unit of work (JSON-able fields only, so it travels to any worker)."""

    kind: str
    """reference, calibration or press."""
    id: str
    """Unique, file-safe name within the experiment."""
    scene: dict
    """The full scene mapping (SceneConfig.to_dict())."""
    press: dict | None = None
    """PressConfig mapping (press tasks)."""
    evaluations: tuple = ()
    """Press tasks: ({"labels": {...}, "solve": SolveSpec.to_dict()}, ...)."""
    led_error: dict | None = None
    """Calibration tasks: the design error the calibration starts from."""
    samples: dict | None = None
    """Press tasks of NLiPsNet experiments: the SamplingConfig mapping of the calibration samples written
    from the first solve (the NLiPs labels); None: no samples."""
    keep_old: bool = False
    """Reuse this task's finished result even when other code or libraries made it (``--keep-old``: a lab
    finishing a table with old results); False: such a result is made again. Not part of :attr:`hash`: it
    chooses which result is taken, not what the task computes."""

    @property
    def stage(self) -> int:
        return STAGES[self.kind]

    @property
    def hash(self) -> str:
        """Content hash: the task's fields and, for a task writing samples, the versions of the code that decides
        them (learn.dataset.SAMPLE_RULES, as ``nlips calibrate``'s shard stamps), so a bumped rule makes them anew.
        """
        from ..learn.dataset import SAMPLE_RULES

        d = dataclasses.asdict(self)
        del d["keep_old"]
        # the design's LED size: the true rows' solves read it (since s42) but their hashes stay as they were
        d["scene"] = rendered_scene(d["scene"])
        if self.kind == "calibration" or any(ev["solve"]["leds"] != "true" for ev in self.evaluations):
            # the given LEDs' model and the size it reads (GIVEN_LEDS_MODEL's why)
            declared = (self.scene.get("leds") or {}).get("emitter_diameter")
            d["given_leds"] = {"model": GIVEN_LEDS_MODEL, "emitter_diameter": declared}
        if d["samples"] is None:  # tasks without samples keep the hashes they had before the field existed
            del d["samples"]
        elif SAMPLE_RULES != RULES_HASHED_SILENTLY:
            d["sample_rules"] = SAMPLE_RULES
        return digest(d)


def keeping_old(tasks: list[Task], keep_old: bool) -> list[Task]:
    """``tasks``, each reusing its result made by other code or libraries too when ``keep_old`` (``--keep-old``)."""
    return [dataclasses.replace(t, keep_old=True) for t in tasks] if keep_old else tasks


def scene_key(scene: dict) -> str:
    """Name of a scene's reference folder: its content hash (render threads and the design's fields no render reads,
    ``core.sensor.rendered_scene``, excluded)."""
    scene = rendered_scene(scene)
    render = {k: v for k, v in scene.get("render", {}).items() if k != "threads"}
    return digest({**scene, "render": render})


def calibration_id(scene: dict, led_error: dict) -> str:
    return f"cal-{scene_key(scene)}-{digest(led_error, 6)}"


def result_path(out: Path, task_id: str) -> Path:
    return Path(out) / "tasks" / f"{task_id}.json"


def load_result(out: Path, task: Task) -> dict | None:
    """The task's stored result, or None when missing, unreadable, from a different task content, or naming
    samples that are not whole and this task's, or error maps that are not whole (:func:`result_files_problem`): such
    a task is run again."""
    data = stored_result(out, task)
    return data if data is not None and result_files_problem(out, task, data) is None else None


def stored_result(out: Path, task: Task) -> dict | None:
    """The task's stored result JSON, or None when missing, unreadable, from a different task content or made
    with other code or libraries (:func:`made_elsewhere`; kept with ``task.keep_old``); its samples unchecked."""
    data = finished_result(out, task)
    return data if data is not None and (task.keep_old or not made_elsewhere(task, data)) else None


def finished_result(out: Path, task: Task) -> dict | None:
    """The task's stored result JSON when it is a finished result of this task's content, whatever made it."""
    path = result_path(out, task.id)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (FileNotFoundError, json.JSONDecodeError, UnicodeDecodeError):
        return None
    ok = isinstance(data, dict) and data.get("task_hash") == task.hash and data.get("status") == "done"
    return data if ok else None


def made_elsewhere(task: Task, result: dict) -> bool:
    """Whether ``result`` was made with other code or libraries than this installation's for the task's kind
    (:func:`made_with`), or records none (written before 2026-12-06)."""
    return result.get("made_with") != made_with(task.kind, task.samples is not None)


UNRECORDED = "code and libraries unrecorded (written before 2026-12-06)"
"""What :func:`made_difference` says of a task result without ``made_with``."""


def made_difference(task: Task, result: dict) -> str:
    """What made ``result`` otherwise than this installation would, in words: "other code (core, sim, solver)",
    "numpy 1.26.4 (now 2.1.3)", both, or :data:`UNRECORDED`; "" when nothing differs."""
    was, here = result.get("made_with"), made_with(task.kind, task.samples is not None)
    if not isinstance(was, dict) or not isinstance(was.get("libraries"), dict):
        return UNRECORDED
    code = task_code(task.kind, task.samples is not None)
    said = [f"other code ({', '.join(code)})"] if was.get("code") != here["code"] else []
    libraries = was["libraries"]
    said += [f"{k} {libraries.get(k)} (now {v})" for k, v in here["libraries"].items() if libraries.get(k) != v]
    return ", ".join(said)


def result_files_problem(out: Path, task: Task, result: dict) -> str | None:
    """Why a file that a finished task's ``result`` names cannot be used (:func:`samples_problem`,
    :func:`maps_problem`), or None: then the task is reused."""
    return samples_problem(out, task, result) or maps_problem(out, result)


def maps_problem(out: Path, result: dict) -> str | None:
    """Why an error map that ``result``'s evaluations name (``maps/*.npz``) cannot be read, or None.

    Why: a map is written before its task's result (each atomically, neither synced), so a result names maps that
    were whole when it was written; a map left empty or cut short since (a power cut soon after the run, before the
    disk had it; a folder copied in part) was reused with its task, and every run after it stopped at the report
    on one line, "...npz: damaged or truncated error map", with nothing that made it again. Now its task runs again.
    Only the archive's end record is read (core.file_checks: a cut-short or empty file has none), not the arrays."""
    from ..core.file_checks import MISSING, file_problem

    for ev in result.get("evaluations") or ():
        name = ev.get("map") if isinstance(ev, dict) else None
        if not isinstance(name, str):
            continue
        path = Path(out) / name
        problem = file_problem(path)
        if problem == MISSING:
            return f"{path}: error map missing"
        if problem is not None:
            return f"{path}: error map damaged or cut short ({problem}; not a whole .npz archive)"
    return None


def samples_problem(out: Path, task: Task, result: dict) -> str | None:
    """Why the samples file that a press task's ``result`` names cannot be used, or None (no samples, or whole
    and written by this task).

    The file is named by the press alone (:func:`samples_path`), not by the settings: a run of other settings
    (sampling, solver options) rewrites it, and one killed between writing it and writing its task's result left
    it beside the result of the settings before, which a later run used as theirs. Hence each file carries its
    task's hash (``stamp`` of its entry, :func:`dataset_entry`); a file written before files carried one is kept
    when its sample count is the result's.
    """
    from ..core.errors import CaptureError
    from . import adapters

    info = result.get("samples") if task.samples is not None else None
    if not info or not info.get("file"):
        return None
    path = samples_path(out, task.id)
    try:
        entry, count = adapters.samples_entry(path)
    except CaptureError as exc:
        return str(exc)
    stamp, recorded = (entry.get("stamp"), entry.get("samples")) if entry else (task.hash, info.get("count"))
    if stamp != task.hash or recorded != count:
        return f"{path}: samples of this press written by a run of other settings"
    return None


def clean_leftovers(out: Path) -> None:
    """Remove what killed runs left in ``out``: temporaries of a task's files being written (its result in
    ``out/tasks``, its samples, figure crop and error maps), and claims whose owner is gone, anywhere in ``out``
    (the tasks' and the presses' solves').

    Why here, once per run: a run killed between writing a task's result and releasing its claim leaves a
    finished task with a dead claim beside it, and a finished task is never claimed again (:func:`run_tasks`
    skips it), so nothing else would ever remove that claim; a worker killed in a press's solve leaves that
    solve's hold (pipeline.reuse._hold) likewise. A live run's claims and temporaries stay."""
    from ..core.atomic import clean_interrupted
    from ..core.claims import remove_dead_claims

    # the folders the tasks write into: a run killed in a write leaves its temporary there
    for folder in (Path(out) / "tasks", samples_path(out, "-").parent, view_path(out, "-").parent, Path(out) / "maps"):
        for gone in clean_interrupted(folder):
            log.warning("%s: removed (left by an interrupted run)", gone)
    if Path(out).is_dir():
        remove_dead_claims(out)


def execute(task: Task, out: str | Path, threads: int = 0, keep_presses: bool = False) -> str:
    """Run one task (in any process or Dask worker) and write its JSON.

    Returns "done" (run here), "reused" (finished by another run sharing the folder, which this one waited
    for), "failed: ..." or, on a full disk, :data:`NO_SPACE` "...". Exceptions are recorded in
    ``tasks/<id>.failed.json`` (retried on the next run), never raised, so one bad press does not stop a sweep
    (a full disk stops it in the runner, which starts no other task).
    """
    from ..core.claims import claim

    out = Path(out)
    while load_result(out, task) is None:
        # another process or machine sharing the folder may be on this task: wait for it (its claim goes
        # stale at once if it died on this host, after core.claims.CLAIM_STALE_S elsewhere), never run it twice
        with claim(result_path(out, task.id)) as mine:
            if mine:
                return _execute_claimed(task, out, threads, keep_presses)
        time.sleep(1.0)
    return REUSED


def failure_text(exc: Exception) -> str:
    """A task's failure in one line. A file-system error names the file the user knows, where it goes, and its
    cause: "OUT/presses/ID/led_01.png: No space left on device (the disk is full: free space, then run again)"
    (it was "OSError: [Errno 28] No space left on device: 'OUT/presses/.tmp-ID~HOST~PID~.../led_01.png'", the
    hidden temporary that the failure removed); any other error as its type and message."""
    from ..core.atomic import named_target

    if not (isinstance(exc, OSError) and exc.filename is not None and exc.strerror):
        return f"{type(exc).__name__}: {exc}"
    cause = exc.strerror + (" (the disk is full: free space, then run again)" if exc.errno in NO_SPACE_ERRNOS else "")
    return f"{named_target(exc.filename)}: {cause}"


def _execute_claimed(task: Task, out: Path, threads: int, keep_presses: bool) -> str:
    if load_result(out, task) is not None:  # finished by another process while we waited
        return REUSED
    from threadpoolctl import threadpool_limits

    from ..core.blas import blas_threads

    start = time.perf_counter()
    try:
        # BLAS on one thread: the LED fit's bits need it (the gathers' products do not: core.blas.serial_matmul),
        # on whichever thread the task runs (core.blas.blas_threads' why). blas_threads, not threadpoolctl's limit:
        # that limits the libraries loaded when it starts, and a fresh worker's first task (a killed worker's task
        # re-run in the local pool) loads SciPy's own OpenBLAS later, which then ran on every core outside the
        # solver's blocks, switched to one and back by those blocks on the pool's threads while others computed.
        # blas_threads loads it first, and the solver's blocks inside share its count and change nothing.
        with blas_threads(1), threadpool_limits(limits=1, user_api="openmp"):
            runner = {"reference": _run_reference, "calibration": _run_calibration, "press": _run_press}[task.kind]
            body = runner(task, out, threads, keep_presses)
    except Exception as exc:  # recorded, the sweep goes on
        if _from_ctrl_c(exc):  # Ctrl-C inside a native library: stop the sweep, not record a failed press
            raise KeyboardInterrupt from exc
        error = failure_text(exc)
        full = _from_full_disk(exc)
        # on a full disk this small record may not fit either: the runner stops the sweep all the same
        with contextlib.suppress(OSError) if full else contextlib.nullcontext():
            write_json(out / "tasks" / f"{task.id}.failed.json", {"id": task.id, "error": error})
        return f"{NO_SPACE if full else 'failed: '}{error}"
    body["timing"] = body.get("timing", {}) | {"task_seconds": round(time.perf_counter() - start, 3)}
    from .provenance import made_by

    body["made_by"] = made_by()  # who made it, for the report of a run that keeps it (--keep-old; framework)
    # what it was made with: a run of other code or libraries makes it again
    body["made_with"] = made_with(task.kind, task.samples is not None)
    write_json(
        result_path(out, task.id), {"id": task.id, "kind": task.kind, "task_hash": task.hash, "status": "done"} | body
    )
    (out / "tasks" / f"{task.id}.failed.json").unlink(missing_ok=True)
    return "done"


def _from_ctrl_c(exc: BaseException) -> bool:
    """Whether ``exc`` was raised because of a KeyboardInterrupt (drjit turns Ctrl-C during a render into its
    own RuntimeError, raised from the interrupt)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _from_full_disk(exc: BaseException) -> bool:
    """Whether ``exc`` is, or was raised from, a write that found the disk full or the quota spent (a library
    may wrap the OSError in its own error)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, OSError) and exc.errno in NO_SPACE_ERRNOS:
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def reference_folder(out: Path, scene: dict) -> Path:
    return Path(out) / "refs" / scene_key(scene)


def _run_reference(task: Task, out: Path, threads: int, keep: bool) -> dict:
    from . import adapters

    folder = reference_folder(out, task.scene)
    t = time.perf_counter()
    adapters.render(task.scene, None, folder, threads)
    return {
        "folder": folder.relative_to(out).as_posix(),
        "timing": {"render_seconds": round(time.perf_counter() - t, 3)},
    }


def _run_calibration(task: Task, out: Path, threads: int, keep: bool) -> dict:
    from . import adapters

    ref = reference_folder(out, task.scene)
    design = adapters.perturb_leds(adapters.load(ref).leds, **_error_args(task.led_error))
    # the model --led-model auto solves the design's LEDs as: its disks fitted too where it takes disks
    diameter = adapters.auto_led_diameter(ref)
    leds, disks, info = adapters.calibrate(ref, design, diameter)
    body = {"led_error": task.led_error, "leds": [led.to_dict() for led in leds], "calibration": info}
    if disks:  # as an LED file holds them (docs/formats.md); a point calibration's result stays as it was
        body["emitters"] = {"radius_mm": diameter / 2, "leds": [led.to_dict() for led in disks]}
    return body


def _error_args(err: dict) -> dict:
    return {"position_mm": err["position_mm"], "direction_deg": err["direction_deg"], "seed": err["seed"]}


def _run_press(task: Task, out: Path, threads: int, keep: bool) -> dict:
    from . import adapters

    folder = out / "presses" / task.id
    t = time.perf_counter()
    if not _rendered_here(folder):  # a press rendered before an interruption (or kept) by this code is reused
        adapters.render(task.scene, task.press, folder, threads)
    render_s = time.perf_counter() - t
    press = adapters.load(folder)
    reference = reference_folder(out, task.scene)
    solved: dict[str, dict] = {}
    evaluations = []
    for ev in task.evaluations:
        key = digest(ev["solve"])
        if key not in solved:
            solved[key] = _solve_one(adapters, out, task, press, reference, ev["solve"], key)
        evaluations.append({"labels": ev["labels"], "solve": ev["solve"], **solved[key]["result"]})
    samples = None
    if task.samples is not None:
        first = solved[digest(task.evaluations[0]["solve"])]
        samples = _write_samples(adapters, out, task, press, reference, first.get("reconstruction"))
    if not keep:  # the render stays (the cache of the render stage, :func:`_rendered_here`); the solves go
        shutil.rmtree(folder / SOLVES_DIR, ignore_errors=True)
    timing = {"render_seconds": round(render_s, 3), "solve_seconds": {k: v["seconds"] for k, v in solved.items()}}
    body = {"press": task.press, "scene_key": scene_key(task.scene), "evaluations": evaluations, "timing": timing}
    return body | ({"samples": samples} if samples is not None else {})


def _rendered_here(folder: Path) -> bool:
    """Whether ``folder`` holds a press rendered with this installation's twin code and renderer (the render stage's
    key: :data:`nlipscalib.core.code_version.RENDER_CODE` and the render libraries, recorded in its meta.json); one of
    other code is rendered again, as its task is.

    Why the render is kept after its task (and only the solves removed, unless ``--keep-presses``): a press task is
    keyed by all the code it runs (:data:`TASK_CODE`), so a change of the solver alone re-runs it; with the render
    deleted, that re-rendered every press (minutes each at the full size) to solve the same images again. The
    cost is the folder's disk: ~0.6 MB a press at the quick size, ~25 MB at 640x480 (benchmarks/RESULTS.md,
    s27-stagekeys)."""
    from ..core.errors import CaptureError
    from ..core.press_folders import is_press_folder
    from ..core.press_meta import read_meta
    from ..sim.dataset_folder import missing_files
    from ..sim.press import rendered_elsewhere

    if not is_press_folder(folder) or missing_files(folder):  # a file of it deleted since: rendered again whole
        return False
    try:
        provenance = read_meta(folder).get("provenance")
    except (CaptureError, OSError):  # an unreadable meta.json: rendered again, which replaces the folder
        return False
    return isinstance(provenance, dict) and not rendered_elsewhere(provenance)


def samples_path(out: Path, task_id: str) -> Path:
    """The NLiPsNet calibration samples of a press task (a learn.dataset shard)."""
    return Path(out) / "calibration" / "samples" / f"{task_id}.npz"


def view_path(out: Path, task_id: str) -> Path:
    """Crop of a press for the NLiPsNet figure: linear tri-colour image, true normals, pixel offset."""
    return Path(out) / "views" / f"{task_id}.npz"


def _write_samples(
    adapters: ModuleType, out: Path, task: Task, press: Press, reference: Path, rec: Reconstruction | None
) -> dict:
    """Write the press's calibration samples (from the NLiPs labels ``rec``) and its figure crop.

    The samples' record (the task result's ``samples``, whence its dataset entry: :func:`dataset_entry`) carries the
    identity of the capture the labels were solved from (``capture_identity``, as ``nlips calibrate``'s: the label
    solve's ``provenance.inputs.press``), so a model trained or a table fitted on the experiment's dataset tells the
    presses it learnt from (report.json ``trained_on`` of ``nlips infer`` on OUT/presses/PRESS), and the press's
    identity by content (``press_identity``, :mod:`nlipscalib.core.press_identity`), which tells the same press
    rendered in another work folder as the same."""
    from ..learn.dataset import press_identity_entry, recorded_capture_identity

    if rec is None:  # the label solve failed: this press gives no samples (like ``nlips calibrate``)
        return {"file": None, "error": "the NLiPs label solve failed"}
    arrays = adapters.calibration_samples(press, rec, reference, task.samples)
    path = samples_path(out, task.id)
    path.parent.mkdir(parents=True, exist_ok=True)
    info = (
        {
            "file": path.relative_to(out).as_posix(),  # / on every system: a folder moves between them
            "count": int(len(arrays["rgb"])),
            "contact": int(arrays["contact"].sum()),
            "has_truth": bool(press.ground_truth is not None),
        }
        | recorded_capture_identity(getattr(rec, "report", None))
        | press_identity_entry(press.folder)
    )
    adapters.write_samples(path, arrays, dataset_entry(out, task, info))
    view = adapters.figure_view(press, reference, task.samples)
    if view:
        _save_maps(view_path(out, task.id), view)
    return info


def dataset_entry(out: Path, task: Task, info: dict) -> dict:
    """A press task's entry in the experiment's calibration dataset (learn.dataset's index.json), from the
    ``samples`` record of its result; ``stamp``, the identity of its samples, is the task's hash (its press, scene,
    solves and sampling); ``capture_identity`` where the record holds it (:func:`_write_samples`; a task run before
    2026-12-07 evening records none); ``press_identity`` where it holds one (a task run before 2026-12-08 holds
    none)."""
    from ..core.press_identity import IDENTITY_KEY, is_identity
    from ..learn.dataset import CAPTURE_IDENTITY

    ind = task.press["indenter"]
    identity = info.get(CAPTURE_IDENTITY)
    content = info.get(IDENTITY_KEY)
    return (
        {
            "name": task.id,
            "folder": str(Path(out) / "presses" / task.id),
            "samples": info["count"],
            "contact_samples": info["contact"],
            "has_truth": info["has_truth"],
            "press": {
                "indenter": ind["kind"],
                "polar_deg": task.press["polar_deg"],
                "azimuth_deg": task.press["azimuth_deg"],
                "depth_mm": task.press["depth"],
            },
            "stamp": task.hash,
        }
        | ({CAPTURE_IDENTITY: identity} if isinstance(identity, str) and identity else {})
        | ({IDENTITY_KEY: content} if is_identity(content) else {})
    )


def _solve_one(
    adapters: ModuleType, out: Path, task: Task, press: Press, reference: Path, spec: dict, key: str
) -> dict:
    """Solve one variant into PRESS/solves/<key> (pipeline) and score it; a failure is a result too."""
    t = time.perf_counter()
    try:
        leds, disks = _solver_leds(adapters, out, task, press, spec)
        result = adapters.solve(
            press,
            out=press.folder / SOLVES_DIR / key,
            leds=leds,
            disks=disks,
            interreflection=spec["interreflection"],
            reference=reference,
            roi=spec["roi"],
            options=adapters.solver_options(spec["options"]),
            albedo=None,  # the solver fits the coating's reflectance (the scene's albedo is the truth)
        )
    except (OSError, MemoryError):
        # the machine's failure, not the variant's (a full disk, a folder gone, no memory): the task fails, the run
        # says so and exits 1, and a rerun does it again. Recorded as the variant's result, a CI run whose disk filled
        # up reported "0 failed" with three NaN points in its study
        raise
    except Exception as exc:  # one failed variant (say, no contact found by --roi auto) is a result too
        return {"result": {"error": f"{type(exc).__name__}: {exc}"}, "seconds": round(time.perf_counter() - t, 3)}
    metrics = adapters.score(result, press.ground_truth)
    crop = adapters.error_crop(result, press.ground_truth)
    if crop:
        _save_maps(out / "maps" / f"{task.id}-{key}.npz", crop)
    return {
        "result": {"metrics": metrics, "map": f"maps/{task.id}-{key}.npz" if crop else None},
        "seconds": round(time.perf_counter() - t, 3),
        "reconstruction": result,  # kept in memory for the calibration samples, never written to JSON
    }


def _solver_leds(
    adapters: ModuleType, out: Path, task: Task, press: Press, spec: dict
) -> tuple[tuple[Led, ...] | None, tuple[tuple[Led, ...] | None, float] | None]:
    """The LEDs a solve variant gives the solver (None: the capture's own) and their disks, (emitters or None for
    themselves, radius mm), or None: points.

    The pipeline's ``--led-model auto`` solves them as the true row's own LEDs (:data:`GIVEN_LEDS_MODEL`): the
    design's LEDs as disks of its declared size where auto takes disks for the press, a calibration's LEDs as the
    disks it fitted, which it fits where auto takes disks for the design (``_run_calibration``)."""
    err = {
        "position_mm": spec["position_error_mm"],
        "direction_deg": spec["direction_error_deg"],
        "seed": spec["error_seed"],
    }
    if spec["leds"] == "true":
        return None, None  # the capture's own LEDs (the twin's true ones)
    if spec["leds"] == "design":  # the LEDs at their disks' centres, as the design declares their size
        diameter = float((task.scene.get("leds") or {}).get("emitter_diameter") or 0.0)
        return adapters.perturb_leds(press.leds, **_error_args(err)), ((None, diameter / 2) if diameter > 0 else None)
    from ..core.leds import Led

    cal = json.loads(result_path(out, calibration_id(task.scene, err)).read_text(encoding="utf-8"))
    leds = tuple(Led.from_dict(d) for d in cal["leds"])
    emitters = cal.get("emitters")
    if not emitters:  # a point calibration (auto took points for the design): solved as points
        return leds, None
    return leds, (tuple(Led.from_dict(d) for d in emitters["leds"]), float(emitters["radius_mm"]))


def _save_maps(path: Path, arrays: dict[str, np.ndarray]) -> None:
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    write_bytes(path, buf.getvalue())
