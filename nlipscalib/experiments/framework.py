"""An experiment = a frozen-dataclass config with named sizes, expanded into per-press tasks, run, reported.

Subclasses of :class:`Experiment` say what to evaluate (``evaluations``), how to tabulate it
(``tables``), what to draw (``figures`` from the numbers, ``draw_work_figures`` from the work folder's
per-press arrays) and which table the regression check reads; running, resuming, the report's JSON and
Markdown are common.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import json
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..core.atomic import whole_dir, write_text
from ..core.config import did_you_mean, from_mapping, read_config_file, to_mapping
from ..core.errors import ConfigError, NlipsError, check_flag
from . import check, markdown
from .plan import build_tasks
from .provenance import machine, made_by, software
from .runner import check_scheduler, run_tasks
from .summary import dumps, evaluation_rows
from .tasks import keeping_old

if TYPE_CHECKING:  # named in hints only
    from ..core.claims import Owner
    from .tasks import Task

RESULTS = "results.json"
"""The report's numbers (and config), which every report folder holds: what ``--redraw`` reads, and how an existing
report folder is told from a folder of other files (core.atomic.whole_dir)."""
WORK_HOLD = "run"
"""Target of the claims by which the runs of one set of tasks hold their work folder (:func:`hold_outputs`):
``OUT/NAME-SIZE/.claim-run~KEY~TOKEN``, one per run."""


@dataclasses.dataclass
class Table:
    """One table of a report."""

    name: str
    caption: str
    by: tuple[str, ...]
    """Group labels (the first columns)."""
    rows: list[dict]
    """Aggregated rows (:func:`summary.aggregate`), possibly with paper columns added."""
    paper: dict[str, str] = dataclasses.field(default_factory=dict)
    """Extra columns: key in the rows -> header (the paper's numbers)."""
    columns: tuple[tuple[str, str, int], ...] = ()
    """Columns (row key, header, decimals) after ``by`` instead of the NLiPs accuracy columns (tables that
    are not per-press NLiPs metrics, e.g. NLiPsNet scores)."""


@dataclasses.dataclass(frozen=True)
class WorkFigure:
    """A figure drawn from the work folder's per-press arrays (error maps, normal maps), not from results.json."""

    file: str
    """PNG name in the report folder."""
    caption: str
    needs: str
    """What of the work folder it is drawn from: why a redraw from results.json (``redraw``) keeps it as it is."""


class Experiment:
    """Base of every experiment (subclasses set the class attributes and the three methods)."""

    name: str = ""
    title: str = ""
    description: str = ""
    config_cls: type = object
    sizes: dict = {}
    """Size name -> config instance (quick: CI; medium: what fits a small machine; full: the paper's scale)."""
    paper: dict = {}
    """The paper's numbers, shown side by side and stored in the JSON."""
    check_table: str = ""
    """Name of the table whose figures ``--check`` compares."""
    not_done: tuple[str, ...] = ()
    """Parts of the issue this experiment does not run (and why), listed in the report."""
    work_name: str = ""
    """Work folder OUT/<work_name>-SIZE shared with another experiment whose tasks this one reuses
    (default: its own name)."""
    work_figures: tuple[WorkFigure, ...] = ()
    """Every figure ``draw_work_figures`` may draw."""

    # ``cfg: Any``: each subclass's methods take its own ``config_cls`` (an instance of it), which they name
    def evaluations(self, cfg: Any) -> list[tuple[dict, dict, dict, dict]]:
        raise NotImplementedError

    def samples(self, cfg: Any) -> dict | None:
        """SamplingConfig mapping when press tasks must write NLiPsNet calibration samples (else None)."""
        return None

    def learn(self, cfg: Any, tasks: list[Task], out: Path, progress: bool = True) -> dict:
        """Work after the press tasks, in this process (NLiPsNet training); JSON-able results or {}."""
        return {}

    def tables(self, cfg: Any, rows: list[dict], learned: dict) -> list[Table]:
        raise NotImplementedError

    def figures(
        self, cfg: Any, rows: list[dict], tables: list[Table], folder: Path, learned: dict
    ) -> list[tuple[str, str]]:
        """Draw into ``folder`` the figures that come from the numbers alone (all of them are in results.json, so
        ``redraw`` can draw them again without the work folder); (caption, file name) each, in report order."""
        return []

    def draw_work_figures(self, cfg: Any, rows: list[dict], out: Path, folder: Path, learned: dict) -> list[WorkFigure]:
        """Draw into ``folder`` those of ``work_figures`` that the work folder ``out`` has the arrays for."""
        return []

    # ------------------------------------------------------------------ common machinery
    def config(self, size: str = "quick", config_file: str | Path | None = None) -> Any:
        """The config of a named size, or read from a TOML/YAML file (fields of ``config_cls``)."""
        if config_file is not None:
            cfg = from_mapping(self.config_cls, read_config_file(config_file), str(config_file))
            try:  # what only planning checks (scenes, LED counts, press depths) is refused now, naming the file
                tasks = self.tasks(cfg)
            except ConfigError as exc:
                raise ConfigError(f"{config_file}: {exc}") from None
            if not tasks:
                raise ConfigError(f"{config_file}: nothing to run (an empty list of presses, LED counts or shapes?)")
            return cfg
        if size not in self.sizes:
            hint = did_you_mean(size, list(self.sizes))
            raise ConfigError(f"experiment {self.name}: unknown size {size!r}{hint} (known: {', '.join(self.sizes)})")
        return self.sizes[size]

    def tasks(self, cfg: Any, solver_options: dict | None = None) -> list[Task]:
        return build_tasks(with_solver_options(self.evaluations(cfg), solver_options or {}), self.samples(cfg))


def _task_seconds(tasks: list[Task], out: Path) -> dict:
    """Seconds the finished tasks took, summed per kind (kept across resumes, unlike this run's wall time)."""
    from .tasks import stored_result

    total: dict[str, float] = {}
    for t in tasks:
        result = stored_result(out, t)  # its timing: the samples were checked as the tasks ran
        if result is not None:
            total[t.kind] = total.get(t.kind, 0.0) + result.get("timing", {}).get("task_seconds", 0.0)
    return {k: round(v, 1) for k, v in total.items()} | {"all": round(sum(total.values()), 1)}


def _calibrations(tasks: list[Task], out: Path) -> list[dict]:
    """Each LED self-calibration's id and fit quality (``adapters.calibrate``; None for older results)."""
    from .tasks import load_result

    found = []
    for t in tasks:
        result = load_result(out, t) if t.kind == "calibration" else None
        if result is not None:
            found.append({"id": t.id, "quality": result.get("calibration", {}).get("quality")})
    return found


def with_solver_options(
    evaluations: list[tuple[dict, dict, dict, dict]], options: dict
) -> list[tuple[dict, dict, dict, dict]]:
    """The same evaluations with extra SolverOptions overrides in every solve (e.g. a worsened solver)."""
    if not options:
        return evaluations
    out = []
    for scene, press, labels, solve in evaluations:
        merged = dict(solve["options"]) | options
        out.append((scene, press, labels, solve | {"options": dict(sorted(merged.items()))}))
    return out


def _check_memory(tasks: list[Task], workers: int) -> None:
    """Warn when ``workers`` local processes likely need more memory than is available: each renders and solves
    (on the whole frame: the larger of the two) its tasks' largest images."""
    from ..core.cpus import SOLVE_WHOLE_MEMORY, worker_count

    sizes = [(t.scene["camera"]["width"], t.scene["camera"]["height"]) for t in tasks if "camera" in t.scene]
    if sizes:
        worker_count(workers, 1, SOLVE_WHOLE_MEMORY, *max(sizes, key=lambda wh: wh[0] * wh[1]))


def _check_guarded(workers: int, scheduler: str | None) -> None:
    """ConfigError naming the script and line when the tasks would run in worker processes (``workers`` > 1, or a
    ``local:N`` Dask cluster's) started from a script's top level outside ``if __name__ == "__main__":``
    (:func:`nlipscalib.core.main_guard.check_main_guarded`, as ``solve_presses`` does).

    ``workers`` (a whole number >= 1: "2" failed in Python's comparison of str and int, 0 ran) and ``scheduler`` are
    checked first (s38-apikinds).

    Why: the spawned workers import the caller's script again and so ran its ``run_experiment`` again, each failing
    in multiprocessing's bootstrapping traceback, and every task came back failed (s36-apileft)."""
    from ..core.errors import check_kind, check_whole
    from ..core.main_guard import check_main_guarded

    check_whole(workers, "workers", minimum=1)
    check_kind(scheduler, (str, type(None)), "scheduler", "None, 'local:N' or a Dask scheduler's address")
    local = check_scheduler(scheduler)
    if scheduler is None and workers > 1:
        check_main_guarded(f"running the experiment's tasks in {workers} processes (workers={workers})")
    elif local is not None:
        check_main_guarded(
            f"running the experiment's tasks on a local cluster of {local} processes ({scheduler})",
            in_process="scheduler=None and workers=1",
        )


def _check_arguments(
    exp: object,
    cfg: object,
    out: object,
    report: object,
    size: object,
    solver_options: object,
) -> tuple[Path, Path]:
    """``out`` and ``report`` as Paths; an NlipsError naming the argument of :func:`run_experiment` that is of
    another kind than it takes (or out of range), before any task is planned or folder held.

    Why: ``run_experiment("q1", ...)``, a dict or another experiment's config for ``cfg``, ``out`` None,
    or ``solver_options="fast"`` failed in Python's AttributeError or TypeError from inside the planning, and
    ``size=3`` ran (s38-apikinds; ``workers`` and ``scheduler``: :func:`_check_guarded`)."""
    from ..core.errors import PATH, check_kind

    check_kind(exp, Experiment, "exp", "an Experiment (nlipscalib.experiments.get(name))")
    made_by_size = f"exp.config(size), e.g. {exp.name}.config('quick')"
    check_kind(cfg, exp.config_cls, "cfg", f"a {exp.config_cls.__name__} ({made_by_size})")
    check_kind(out, PATH, "out", "the work folder's path (str or Path)")
    check_kind(report, PATH, "report", "the report folder's path (str or Path)")
    check_kind(size, str, "size", f"the size's name ({', '.join(exp.sizes)}, or 'custom' for a config of your own)")
    check_kind(solver_options, (dict, type(None)), "solver_options", "a dict of SolverOptions fields, or None")
    if solver_options:  # each field and its value checked as a SolverOptions, before hours of tasks fail on it
        from ..solver import SolverOptions

        from_mapping(SolverOptions, dict(solver_options), "solver_options")
    return Path(out), Path(report)


def run_experiment(
    exp: Experiment,
    cfg: Any,
    out: Path,
    report: Path,
    *,
    size: str,
    workers: int = 1,
    scheduler: str | None = None,
    solver_options: dict | None = None,
    keep_presses: bool = False,
    keep_old: bool = False,
    progress: bool = True,
) -> dict:
    """Run (or resume) an experiment into ``out`` and write its report into ``report``; ``keep_old``: reuse
    finished tasks made by other code or libraries too (named in the report), rather than make them again.

    Returns the report's JSON document (also written to ``report/results.json``).
    """
    start = time.perf_counter()
    _check_guarded(workers, scheduler)  # its kinds first; said before the rest: the script's own mistake
    out, report = _check_arguments(exp, cfg, out, report, size, solver_options)
    for name, flag in (("keep_presses", keep_presses), ("keep_old", keep_old), ("progress", progress)):
        check_flag(flag, name)
    tasks = keeping_old(exp.tasks(cfg, solver_options), keep_old)
    settings = run_settings(exp, cfg, size, solver_options)
    if workers > 1 and scheduler is None:  # the count asked for, said when it likely exceeds the memory available
        _check_memory(tasks, workers)
    with hold_outputs(tasks, settings, out, report):
        status = run_tasks(
            tasks,
            out,
            workers=workers,
            scheduler=scheduler,
            keep_presses=keep_presses,
            progress=progress,
            name=exp.name,
        )
        if status.no_space:  # no report: learning, scoring and the report's files would fail on it too
            raise NlipsError(
                f"{out}: no space left on device: free space, then run the same command again (finished tasks are kept)"
            )
        learned = exp.learn(cfg, tasks, out, progress=progress)
        run_s = time.perf_counter() - start
        rows = evaluation_rows(tasks, out)
        tables = exp.tables(cfg, rows, learned)
        main = next((t for t in tables if t.name == exp.check_table), tables[0] if tables else None)
        doc = {
            "experiment": exp.name,
            "title": exp.title,
            "size": size,
            "config": to_mapping(cfg),
            "solver_option_overrides": solver_options or {},
            "software": software(),
            "machine": machine(),
            "execution": {"workers": workers, "scheduler": scheduler, "output": str(out), "keep_old": keep_old},
            "paper": exp.paper,
            "tables": {t.name: {"caption": t.caption, "by": list(t.by), "rows": t.rows} for t in tables},
            "check_figures": check.headline(main.rows, main.by) if main else {},
            "calibrations": _calibrations(tasks, out),
            "evaluations": rows,
            **({"learned": learned} if learned else {}),
            "tasks": {
                "total": len(tasks),
                "run_now": len(status.done),
                "already_done": len(status.skipped),
                "failed": status.failed,
                "made_by_other_software": _made_by_other_software(tasks, out),
            },
            "wall_seconds": round(run_s, 1),
            "task_seconds": _task_seconds(tasks, out),
            "not_done": list(exp.not_done),
        }
        with whole_dir(report, RESULTS) as folder:  # the earlier report stays whole until this one is complete
            figures = exp.figures(cfg, rows, tables, folder, learned)
            figures += [(f.caption, f.file) for f in exp.draw_work_figures(cfg, rows, out, folder, learned)]
            write_text(folder / RESULTS, dumps(doc))
            write_text(folder / "report.md", markdown.report(exp, doc, tables, figures))
        return doc


def _made_by_other_software(tasks: list[Task], out: Path) -> dict[str, str]:
    """Task id -> what made its result otherwise than this installation would ("nlipscalib VERSION at COMMIT:
    other code (core, sim, solver)", its library versions, or unrecorded), for every finished task kept by
    ``--keep-old``.

    Without ``--keep-old`` a task made by other code or libraries is made again (tasks.made_elsewhere), so this is
    empty; with it, the report must not attribute those numbers to this run's code: logged as one warning, listed in
    results.json and report.md. A task another commit made with the same code of its kind is not named: its numbers
    are the ones this code makes."""
    from .tasks import load_result, made_difference, made_elsewhere

    here = made_by()
    other = {}
    for task in tasks:
        result = load_result(out, task)
        if result is not None and made_elsewhere(task, result):
            maker = result.get("made_by")
            name = _maker_name(maker) if isinstance(maker, dict) else "nlipscalib unrecorded"
            other[task.id] = f"{name}: {made_difference(task, result)}"
    if other:
        logging.getLogger(__name__).warning(
            "%s: %d of %d tasks kept by --keep-old were made by other code or libraries (%s), not %s: their numbers "
            "are that code's; run without --keep-old to make them all with this one",
            out,
            len(other),
            len(tasks),
            "; ".join(sorted(set(other.values()))),
            _maker_name(here),
        )
    return other


def _maker_name(maker: dict) -> str:
    return f"nlipscalib {maker.get('nlipscalib')} at {maker.get('git_commit')}"


def run_settings(exp: Experiment, cfg: Any, size: str, solver_options: dict | None) -> dict:
    """What decides a run's report: the experiment, its size and config, the solver option overrides (as JSON
    gives them back, so a holder's note compares equal to them)."""
    settings = {"experiment": exp.name, "size": size, "config": to_mapping(cfg), "solver_options": solver_options or {}}
    return json.loads(json.dumps(settings, default=str))


@contextlib.contextmanager
def hold_outputs(tasks: list[Task], settings: dict, out: Path, report: Path) -> Iterator[None]:
    """Hold the work folder ``out`` for these ``tasks`` and the folder ``report`` for these ``settings``
    (:func:`run_settings`) while the block runs; ConfigError, before anything is run, when a live run of other
    tasks or settings holds either (core.claims.held_for).

    Why: the task claims split the tasks between runs, but nothing else in the folder is a task's: each run writes
    the NLiPsNet dataset (``calibration/index.json``, ``sensor.npz``) from its own tasks and reads it while it
    trains and scores, and the report folder (``NAME-custom/report`` for every --config) is written last by each.
    Two configs at once (other twins) exited 0 with one report, and one run's ``sensor.npz`` could replace the
    other's in the middle of its training; two of one press but other sampling took turns rewriting its task
    result and samples. Runs of the same tasks share the work folder as before (a second terminal; ``presses``
    beside ``q2``, whose tasks it reuses), runs of the same settings the report.
    """
    from ..core.claims import held_for
    from .tasks import digest

    out, report = Path(out), Path(report)
    holds = (
        (out / WORK_HOLD, digest(sorted(t.hash for t in tasks), 16), out, "--out"),
        # the report's claims beside it: a claim file inside would travel with a copied report
        (report, digest(settings, 16), report, "--report"),
    )
    with contextlib.ExitStack() as stack:
        for target, key, folder, option in holds:
            refusal = functools.partial(_held_elsewhere, folder, option, settings=settings)
            stack.enter_context(held_for(target, key, refusal, note=settings))
        yield


def _held_elsewhere(folder: Path, option: str, other: Owner, *, settings: dict) -> str:
    """The refusal of a run whose ``folder`` a live run of other settings (``other``, its note theirs) holds."""
    theirs = other.note if isinstance(other.note, dict) else {}
    mine, was = _flat(settings), _flat(theirs)
    changed = [
        f"{k} {was.get(k)} (this run: {mine.get(k)})" for k in sorted(set(mine) | set(was)) if was.get(k) != mine.get(k)
    ]
    said = ", ".join(changed[:3]) + (f" and {len(changed) - 3} more" if len(changed) > 3 else "")
    return (
        f"{folder}: {other.who} is running an experiment of other settings into it ({said or 'other settings'}); "
        f"left to it: give another {option}, or run again once it has ended"
    )


def _flat(mapping: dict, prefix: str = "") -> dict:
    """Nested mappings as one of dotted keys (``config.twin.seed``)."""
    flat = {}
    for k, v in mapping.items():
        if isinstance(v, dict) and v:
            flat |= _flat(v, f"{prefix}{k}.")
        else:
            flat[f"{prefix}{k}"] = v
    return flat
