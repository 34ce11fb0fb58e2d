"""``nlips experiment NAME|all``: the paper's experiments and the twin-only studies, with reports.

Runs (or resumes) the experiment's per-press tasks into --out, then writes --report (report.md,
results.json, PNG figures). Local processes by default; --scheduler tcp://HOST:PORT uses a running
Dask cluster, --scheduler local:N starts a LocalCluster of N workers. --check BASELINE exits 1 with a
table of the accuracy figures that got worse than the baseline by more than their tolerance.
--redraw REPORT draws a report's figures and report.md again from its results.json alone (its config
included; no work folder, nothing run): what the current drawing code makes of the stored numbers. The
figures drawn from the work folder's per-press arrays (error maps, normal maps) are kept as they are.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # named in hints only: imported when an experiment runs
    from ..experiments.framework import Experiment


def register(sub: argparse._SubParsersAction) -> None:
    import argparse

    from ..experiments import shipped_baselines

    p = sub.add_parser(
        "experiment",
        help="run an experiment (q1, q2, ablation, q3, studies, presses, all) and write its report",
        description=__doc__,
        epilog=_guide(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("name", help="q1, q2, ablation, q3, studies, presses (number of calibration presses), or all")
    # no argparse default: `--size quick --config F` must be refused like `--size full --config F`
    p.add_argument("--size", help="quick (CI), medium or full (default quick)")
    p.add_argument("--config", help="TOML/YAML file with the experiment's config fields (instead of --size)")
    p.add_argument("--out", help="work folder: per-task results (default out/experiments)")
    p.add_argument("--report", help="report folder (default OUT/NAME-SIZE/report); with 'all' one subfolder each")
    p.add_argument(
        "--workers",
        type=int,
        help="local worker processes (default 1: one task at a time, in this process, rendering and solving on all "
        "usable cores' threads; N: up to N tasks at a time, one per process, the processes sharing the cores out "
        "as threads, a container's CPU quota counted; not with --scheduler)",
    )
    p.add_argument(
        "--scheduler",
        help="Dask scheduler address tcp://HOST:PORT, or local:N for a LocalCluster "
        "(default: local processes, --workers)",
    )
    p.add_argument(
        "--solver-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a SolverOptions field in every solve (repeatable), e.g. max_iters=2",
    )
    p.add_argument(
        "--check",
        metavar="BASELINE",
        help="baseline JSON file, or the name of one shipped with nlipscalib "
        f"({', '.join(shipped_baselines())}): exit 1 when an accuracy figure got worse than it",
    )
    p.add_argument("--write-baseline", help="write this run's accuracy figures as a baseline JSON")
    p.add_argument("--plan", action="store_true", help="only print how many tasks the experiment has (and done)")
    p.add_argument(
        "--keep-presses",
        action="store_true",
        help="keep each press folder whole, its solves' reconstructions (PRESS/solves/) too; the renders are kept "
        "without it, so a rerun after a change of the solver solves them again without rendering",
    )
    p.add_argument(
        "--keep-old",
        action="store_true",
        help="reuse finished tasks that other code or library versions made (default: make them again); the report "
        "names them: their numbers are the old code's",
    )
    p.add_argument(
        "--redraw",
        metavar="REPORT",
        help="draw the figures and report.md of this report folder again from its results.json, without the "
        "work folder (error maps and normal maps are kept); no other option",
    )
    p.set_defaults(func=run)


ALL_TAKES = "~10 min / ~50 min / ~4.5 h"
"""Wall time of ``nlips experiment all`` per size, as the experiments' (docs/experiments/RESULTS.md)."""


def _guide() -> str:
    """The experiments, what each measures and how long it takes per size (``nlips experiment --help``)."""
    import textwrap

    from ..experiments import GUIDE

    lines = ["experiments (wall time with --workers 2 on a shared 2-core machine: quick / medium / full):"]
    for name, (what, took) in GUIDE.items():
        lines += textwrap.wrap(what, 96, initial_indent=f"  {name:9s}", subsequent_indent=" " * 11)
        lines.append(" " * 11 + " / ".join(took[size] for size in ("quick", "medium", "full")))
    lines.append(f"  {'all':9s}every one of them in turn: {ALL_TAKES}")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ..core.atomic import check_replaceable, write_json
    from ..core.config import check_count
    from ..core.errors import ConfigError
    from ..core.long_paths import warn_if_too_long
    from ..experiments import EXPERIMENTS, UNAVAILABLE, check, get
    from ..experiments.framework import RESULTS, run_experiment
    from ..experiments.runner import check_scheduler
    from ..experiments.summary import clean
    from ..progress import EXPERIMENT, press_lines, print_result, say
    from .folders import left_empty_removed
    from .options import fill_defaults

    press_lines(EXPERIMENT)  # its task bar and report say how the presses went; each press's lines with -v
    if args.redraw is not None:
        return _redraw(args)
    if args.name == "all" and (args.check or args.write_baseline or args.config):
        raise ConfigError("--check, --write-baseline and --config need one experiment, not 'all'")
    if args.config and args.size is not None:
        raise ConfigError(
            f"--size {args.size} and --config {args.config}: the config file replaces the size's settings; "
            "give one of them"
        )
    if args.scheduler is not None and args.workers is not None:
        # the Dask workers run the tasks: --workers started no process and was dropped without a word
        raise ConfigError(
            f"--workers is not used with --scheduler {args.scheduler}: the cluster's workers run the tasks "
            "(local:N starts N of them); drop --workers"
        )
    fill_defaults(args, {"size": "quick", "out": "out/experiments", "workers": 1})
    check_count("--workers", args.workers, minimum=1)
    check_scheduler(args.scheduler)  # before anything: --plan never reached the runner, which checked it
    names = list(EXPERIMENTS) if args.name == "all" else [args.name]
    options = _options(args.solver_option)
    size = "custom" if args.config else args.size
    # fail fast: a missing or unfit baseline is refused before the run, not after it
    baseline = check.load_baseline(check.baseline_path(args.check), args.name, size) if args.check else None
    runs = []
    for name in names:
        exp = get(name)
        # a study may share another's tasks; absolute for a scheduler's workers, whose working folder is theirs
        work = (Path(args.out).absolute() if args.scheduler else Path(args.out)) / f"{exp.work_name or name}-{size}"
        own = Path(args.out) / f"{name}-{size}"
        report = Path(args.report) / name if args.report and args.name == "all" else Path(args.report or own / "report")
        runs.append((name, exp, exp.config(args.size, args.config), work, report))
    # a run stopped (Ctrl-C, SIGTERM) or failed before its first write leaves no empty work or report folder made
    # (the writability probes below make them)
    with left_empty_removed([folder for *_, work, report in runs for folder in (work, report)], kept=lambda: True):
        warn_if_too_long(args.out, "experiment")  # Windows' 260 characters: before hours of work
        for _, _, _, work, report in runs:  # every output checked before hours of work, not at the first report
            _writable_folder("--out", args.out, work, probe=not args.plan)
            _writable_folder("--report", args.report, report, probe=not args.plan)
            if not args.plan:  # the report replaces the folder whole: never a folder of other files
                check_replaceable(report, RESULTS)
        if args.write_baseline:
            _writable_file("--write-baseline", args.write_baseline, probe=not args.plan)
        code = 0
        for name, exp, cfg, work, report in runs:
            if args.plan:
                _print_plan(name, size, exp, cfg, work, options, args.keep_old)
                continue
            doc = run_experiment(
                exp,
                cfg,
                work,
                report,
                size=size,
                workers=args.workers,
                scheduler=args.scheduler,
                solver_options=options,
                keep_presses=args.keep_presses,
                keep_old=args.keep_old,
            )
            failed = doc["tasks"]["failed"]
            print_result(report)  # stdout: each report's folder alone (scripts); how its run went on stderr
            say(
                f"{name}: {_summary(doc['tasks'])}, {doc['wall_seconds']} s; report {report / 'report.md'}",
                warning=bool(failed),
            )
            code = code or (1 if failed else 0)
            if args.write_baseline:
                write_json(args.write_baseline, clean(check.baseline_document(name, size, doc["check_figures"])))
            if args.check:
                worse = check.compare(doc["check_figures"], baseline)
                if worse:
                    say(f"{name}: {len(worse)} accuracy figure(s) worse than {args.check}:", warning=True)
                    say(check.format_worse(worse), warning=True)
                    return 1
                say(f"{name}: no accuracy figure worse than {args.check}")
        if args.name == "all":
            for name, why in UNAVAILABLE.items():
                say(f"{name}: not run: {why}", warning=True)
        return code


RUN_OPTIONS = (
    "size",
    "config",
    "out",
    "report",
    "workers",
    "scheduler",
    "solver_option",
    "check",
    "write_baseline",
    "plan",
    "keep_presses",
    "keep_old",
)
"""Options of a run, which ``--redraw`` refuses: it draws from the report's results.json alone, config included."""


def _redraw(args: argparse.Namespace) -> int:
    """``--redraw REPORT``: the report's figures and report.md drawn again from its results.json."""
    from ..core.errors import ConfigError
    from ..experiments import get
    from ..experiments.redraw import RESULTS, redraw
    from ..progress import print_result, say
    from .options import option

    if args.name == "all":
        raise ConfigError("--redraw needs the one experiment that wrote the report, not 'all'")
    given = [option(d) for d in RUN_OPTIONS if getattr(args, d) not in (None, False, [])]
    if given:
        raise ConfigError(
            f"--redraw takes everything (the config too) from the report's {RESULTS}; drop {', '.join(given)}"
        )
    report = Path(args.redraw)
    if report.name == RESULTS and report.is_file():  # the file itself named: its folder
        report = report.parent
    if report.is_file():  # was "no such folder", of a path that exists
        raise ConfigError(f"{report}: a file, not a report folder of nlips experiment (the folder holding {RESULTS})")
    done = redraw(get(args.name), report)
    print_result(report)  # stdout: the report's folder alone (scripts); what was redrawn on stderr
    say(f"{args.name}: redrew {', '.join(done.drawn)} in {report} from its {RESULTS}")
    for f in done.kept:
        say(f"{args.name}: kept {f.file}: drawn from {f.needs}, which {RESULTS} does not hold")
    return 0


def _writable_folder(option: str, given: str | Path | None, folder: Path, probe: bool = True) -> None:
    """``folder`` (under the option's value ``given``) can be made and written: ConfigError naming the option
    when a file stands in its way; with ``probe``, OSError naming the folder (one line from the CLI) when it
    cannot be written (read-only, permission)."""
    from ..core.atomic import check_writable
    from ..core.errors import ConfigError
    from ..core.press_folders import is_press_folder

    given = Path(given or folder)
    for part in (folder, *folder.parents):
        if part.exists():
            if not part.is_dir():
                where = "" if part == given else f"{part} "
                raise ConfigError(f"{option} {given}: {where}is a file, not a folder")
            if is_press_folder(part):  # its files would be mixed in among a capture's images
                where = "" if part == given else f"{part} "
                raise ConfigError(f"{option} {given}: {where}is a press folder; choose another {option}")
            break
    if not probe:
        return
    try:
        check_writable(folder, longest_name=len(folder.name))
    except OSError as exc:  # name the folder, not the probe made in it
        raise OSError(exc.errno, exc.strerror, str(folder)) from None


def _writable_file(option: str, path: str, probe: bool = True) -> None:
    """``path`` (as typed: a trailing slash kept) can be written as a file: no folder has its name, nor is it typed as
    one, its folder is writable."""
    from ..core.errors import ConfigError
    from .folders import names_a_folder

    if names_a_folder(path):  # `base.json/` (typed as a folder) was written as the file base.json
        raise ConfigError(f"{option} {path}: is a folder; give a file name")
    _writable_folder(option, Path(path), Path(path).parent, probe)


def _summary(tasks: dict) -> str:
    """What this run did with the tasks, in the report's words: run now, reused (done by an earlier or a concurrent run
    sharing the folder), failed."""
    return (
        f"{tasks['total']} tasks ({tasks['run_now']} run now, {tasks['already_done']} reused), "
        f"{len(tasks['failed'])} failed"
    )


def _print_plan(
    name: str, size: str, exp: Experiment, cfg: object, work: Path, options: dict, keep_old: bool = False
) -> None:
    from ..experiments.tasks import finished_result, keeping_old, load_result

    tasks = keeping_old(exp.tasks(cfg, options), keep_old)
    kinds = {k: sum(t.kind == k for t in tasks) for k in ("reference", "calibration", "press")}
    solves = sum(len({str(e["solve"]) for e in t.evaluations}) for t in tasks)
    done = [load_result(work, t) is not None for t in tasks]
    # finished, but by other code or libraries: the run makes them again (the plan said "done" of them before)
    old = sum(not ok and finished_result(work, t) is not None for t, ok in zip(tasks, done, strict=True))
    counts = " + ".join(_counted(kinds[k], k) for k in ("reference", "calibration", "press"))
    again = f" ({old} more made by other code or libraries: run again; --keep-old keeps them)" if old else ""
    solved = _counted(solves, "solve")
    print(f"{name} ({size}): {len(tasks)} tasks = {counts} ({solved}); {sum(done)} done in {work}{again}")


def _counted(n: int, noun: str) -> str:
    """'1 press', '3 presses'."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}{'es' if noun.endswith('s') else 's'}"


def _options(pairs: list[str]) -> dict:
    """KEY=VALUE strings to typed SolverOptions overrides (validated by building SolverOptions)."""
    import dataclasses
    import json

    from ..core.errors import ConfigError
    from ..solver import SolverOptions

    known = {f.name for f in dataclasses.fields(SolverOptions)}
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in known:
            raise ConfigError(
                f"--solver-option {pair!r}: expected KEY=VALUE with KEY one of {', '.join(sorted(known))}"
            )
        try:
            out[key] = json.loads(value)
        except json.JSONDecodeError:
            out[key] = value
    from ..core.config import from_mapping

    try:
        from_mapping(SolverOptions, out, "--solver-option")
    except ConfigError as exc:  # "--solver-option.max_iters: ..." reads as one word: name the option, then the key
        raise ConfigError(str(exc).replace("--solver-option.", "--solver-option ", 1)) from None
    return out
