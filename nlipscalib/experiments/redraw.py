"""A report redrawn from its results.json alone (``nlips experiment NAME --redraw REPORT``).

A report's work folder (per-task results, error maps, trained models) is often gone -- the committed reports keep
only report.md, results.json and the PNGs -- and a full-size run takes up to hours. results.json holds every
number the bar charts, sweeps and training curves are drawn from (the evaluations, the learned scores and
training histories, the config), and everything report.md shows, so the current code draws both again. The
figures drawn from the work folder's per-press arrays (``Experiment.work_figures``) are kept as they are.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

from ..core.atomic import whole_dir, write_text
from ..core.config import from_mapping
from ..core.errors import ConfigError
from ..core.shell_words import shell_word
from . import markdown
from .framework import RESULTS, Experiment, WorkFigure
from .provenance import software
from .summary import rows_from_json


@dataclasses.dataclass
class Redrawn:
    """What a redraw wrote and what it kept."""

    drawn: list[str]
    """Files written again: the figures, then report.md."""
    kept: list[WorkFigure]
    """Figures of the report drawn from the work folder, left as they were."""


def redraw(exp: Experiment, report: Path) -> Redrawn:
    """Draw the figures and report.md of the report folder ``report`` again from its results.json.

    Parameters
    ----------
    exp : the experiment that wrote the report (a results.json of another one is refused)
    report : report folder holding results.json; replaced whole (core.atomic.whole_dir) by one holding results.json,
        the figures drawn from the work folder that it held, the files that are not the report's own (anything but
        report.md and PNG figures: a ``config.toml`` placed beside it) and the figures and report.md drawn now: none
        of a figure the current code no longer draws is left, and a redraw that fails leaves the folder as it was

    Returns
    -------
    Redrawn; ConfigError (one line naming the file) when results.json is missing, not JSON, another
    experiment's, or lacks what the report needs
    """
    report = Path(report)
    path = report / RESULTS
    doc = read_results(path, exp.name)
    try:
        return _redraw(exp, doc, report)
    except ConfigError:
        raise
    except (KeyError, TypeError, AttributeError, IndexError, ValueError) as exc:  # a damaged or foreign document
        lacks = f"it lacks {exc}" if isinstance(exc, KeyError) else f"{type(exc).__name__}: {exc}"
        raise ConfigError(f"{path}: not a complete results.json of nlips experiment {exp.name} ({lacks})") from None


def read_results(path: Path, name: str) -> dict:
    """The results.json ``path`` of experiment ``name``, or ConfigError saying why it is not one."""
    if not path.parent.is_dir():
        raise ConfigError(f"{path.parent}: no such folder")
    if not path.is_file():
        raise ConfigError(f"{path.parent}: no {RESULTS} here (not a report folder of nlips experiment)")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or "experiment" not in doc:
        raise ConfigError(f"{path}: not the results of an nlips experiment (no 'experiment' key)")
    if doc["experiment"] != name:
        raise ConfigError(
            f"{path}: the results of experiment {doc['experiment']!r}, not {name!r}; "
            f"redraw it with: nlips experiment {doc['experiment']} --redraw {shell_word(path.parent)}"
        )
    return doc


def _redraw(exp: Experiment, doc: dict, report: Path) -> Redrawn:
    cfg = from_mapping(exp.config_cls, doc["config"], f"{report / RESULTS}: config")
    rows = rows_from_json(doc["evaluations"])
    learned = doc.get("learned") or {}
    tables = exp.tables(cfg, rows, learned)
    by = software()  # before drawing: the figures rewritten in a checkout would mark it "+dirty"
    kept = [f for f in exp.work_figures if (report / f.file).is_file()]
    with whole_dir(report, RESULTS) as folder:
        for name in (RESULTS, *(f.file for f in kept), *_not_drawn(report)):  # what the new folder keeps of the old
            shutil.copy2(report / name, folder / name)
        figures = exp.figures(cfg, rows, tables, folder, learned)
        listed = figures + [(f.caption, f.file) for f in kept]  # the order of a run's report
        write_text(folder / "report.md", markdown.report(exp, doc, tables, listed, _note(kept, by)))
    return Redrawn([name for _, name in figures] + ["report.md"], kept)


def _not_drawn(report: Path) -> list[str]:
    """The files of ``report`` that no report writes (not results.json, report.md or a PNG figure): kept by a redraw.

    Why: docs/experiments' Q2 variants keep the ``config.toml`` they were run from beside their report, and a redraw
    that replaced the folder whole deleted it."""
    owned = {RESULTS, "report.md"}
    return sorted(p.name for p in report.iterdir() if p.is_file() and p.name not in owned and p.suffix != ".png")


def _note(kept: list[WorkFigure], sw: dict) -> str:
    """The report's line saying that its figures are newer than its numbers (and which ones are not); ``sw``:
    :func:`.provenance.software` of this process, taken before anything was written."""
    note = f"Figures and page redrawn from `results.json` by nlipscalib {sw['nlipscalib']} at `{sw['git_commit']}`"
    if kept:
        note += "; kept as the run drew them (from its work folder): " + ", ".join(f"`{f.file}`" for f in kept)
    return note + "."
