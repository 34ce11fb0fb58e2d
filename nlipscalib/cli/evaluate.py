"""``nlips eval PATH``: AAE, MabsE and depth RMSE of reconstructions (NLiPs, NLiPsNet or the lookup table)
against ground truth.

PATH is a press folder, a folder of presses, or a reconstruction folder (PRESS/nlips, PRESS/nlipsnet, PRESS/lut:
the method is then taken from the folder's name). A result written elsewhere (`nlips solve PRESS --out
DIR`) is scored with `nlips eval PRESS --result DIR`, which refuses a result made from another capture than PRESS
(`--other-capture` scores it anyway). Several presses are scored together: one row each, then their mean (each
press counts once) and the pooled figures (over all their scored pixels). Results of image frames (`nlips infer
MODEL FRAMES --out DIR`) carry no ground truth: each is scored against the press its frame shows, one at a time
(`nlips eval PRESS --result DIR/FRAME`); infer the press folders instead to score them together. A stream's saved
frames (`nlips live --out DIR`: DIR/frame_NNNNNN.npz) record no input and are not scored. Every method
writes the core reconstruction format (docs/formats.md), so they are scored alike. A damaged NLiPs result is
re-computed from the settings recorded in its report.json, with a warning; when report.json is itself damaged or
records no settings, the press is reported with the `nlips solve PRESS --overwrite` that re-makes it. Results made
by other nlipscalib code (an earlier version) are scored as they are and named in a line below the table. NLiPsNet
and lookup-table results say whether their model learnt from the capture (report.json `trained_on`, compared by
content: a press of the same name in another dataset is unseen; since 2026-12-08 by its images and sensor record, so
a copy elsewhere with other times in its meta.json is seen, and an image frame of a trained press's tri-colour pixels
too): the table then has a `data` column (train, validation, unseen) and the mean and pooled figures of the seen
presses (trained or validated on) and the unseen ones apart, named again in a line below it; results of a model
trained before 2026-12-07 (a table fitted before s42-lutseen), or of an image frame by a model trained before
2026-12-08, are scored together, said once.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.shell_words import shell_word
from .options import add_allow_edited

if TYPE_CHECKING:  # named in hints only: imported when a result is scored
    import numpy as np

    from ..core.reconstruction import Reconstruction
    from ..core.surface_files import GroundTruth
    from ..pipeline import SolveSettings

log = logging.getLogger(__name__)
MAKES = {
    "nlips": "`nlips solve {path}`",
    "nlipsnet": "`nlips infer MODEL.pt {path}`",
    "lut": "`nlips infer TABLE.pt {path}` with a lookup table from `nlips lut`",
}
"""The command that writes each method's result, for the "no result yet" errors (``{path}``: the folder given)."""
LEARNT = {"nlipsnet": "`nlips train`", "lut": "`nlips lut`"}
"""The methods whose results may say whether their model learnt from the capture (report.json ``trained_on``), and
the command that makes such a model anew (a network trained before 2026-12-07, a table fitted before s42-lutseen,
records none)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval",
        help="score reconstructions (NLiPs, NLiPsNet or the lookup table) against the ground truth",
        description=__doc__,
    )
    p.add_argument("path", help="press folder, folder of presses, or a reconstruction folder (PRESS/nlips)")
    p.add_argument(
        "--method",
        choices=("nlips", "nlipsnet", "lut"),
        help="which reconstruction to score: PRESS/nlips (default), PRESS/nlipsnet or PRESS/lut (`nlips infer` of a "
        "lookup table from `nlips lut`)",
    )
    p.add_argument(
        "--result",
        metavar="DIR",
        help="score this reconstruction folder (e.g. from `nlips solve PRESS --out DIR`) against PATH, the press "
        "folder it was made from (its ground truth); or, with PATH a folder of presses, DIR/PRESS/<method> "
        "against each press (what `nlips infer PRESSES --out DIR` writes). The method is read from the results",
    )
    p.add_argument(
        "--other-capture",
        action="store_true",
        help="with --result: score it even though it was made from another capture than PATH (e.g. the same press "
        "rendered with another noise seed, whose ground truth is the same); without it such a result is refused",
    )
    p.add_argument(
        "--region",
        choices=("all", "contact"),
        default="all",
        help="pixels to score: all (default: every pixel valid in both the truth and the result) or contact (only "
        "those of the truth's contact region)",
    )
    add_allow_edited(p, "score against the ground truth of")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.errors import CaptureError

    if args.other_capture and not args.result:
        from ..core.errors import ConfigError

        raise ConfigError("--other-capture is only used with --result DIR (a result from another folder)")
    if args.result:
        pairs, method = _result_targets(Path(args.path), Path(args.result), args.method, args.other_capture)
    else:
        presses, method = _targets(Path(args.path), args.method)
        pairs = [(folder, None) for folder in presses]
    rows, unsolved, damaged, outdated = [], [], [], []
    seen: dict[str, str | None] = {}  # each scored learnt result's `trained_on` (learn.seen): None when not told
    for folder, out in pairs:
        rec = _load(folder, method, single=len(pairs) == 1, out=out)
        stale = None if rec is None or isinstance(rec, str) or out else _stale(folder, method)
        if rec is None:
            unsolved.append(folder.name)  # e.g. a dataset's undeformed reference: nothing solved there
        elif isinstance(rec, str):
            damaged.append((folder.name, rec))
        elif stale:
            outdated.append((folder.name, stale))
        else:
            truth = None
            try:
                truth = _ground_truth(folder, args.allow_edited)  # its arrays are inflated as they are scored
                scores = _scores(folder, rec, out if args.other_capture else None, truth)
            except CaptureError as exc:
                # in a batch, a damaged gt.npz fails its press alone, as a damaged result does (it failed the table);
                # a press without one stops it: a folder of captures has none to score against
                if len(pairs) == 1 or truth is None:
                    raise
                damaged.append((folder.name, str(exc)))
                continue
            rows.append((folder.name, scores[args.region]))
            if rec.report.get("method") in LEARNT:  # a network's or a table's: it may say whether it learnt from it
                seen[folder.name] = _trained_on(rec.report)
    if not rows and not damaged and not outdated:
        raise CaptureError(
            f"{args.path}: no press has a {method} result yet "
            f"(run {MAKES[method].format(path=shell_word(args.path))} first)"
        )
    if len(pairs) == 1 and (damaged or outdated):  # one press, nothing to tabulate: its error, on stderr, exit 2
        raise CaptureError((damaged or outdated)[0][1])
    from ..progress import say

    if rows:  # stderr: what was scored; stdout: the table alone (the command's product, for scripts)
        say(f"scoring {_scored(Path(args.path), pairs, method, args.result)}")
    _print(rows, seen)
    if rows and (line := _seen_line(rows, seen, method)):
        say(line, warning=not any(seen.values()))
    scored = {name for name, _ in rows}
    if older := [folder.name for folder, out in pairs if folder.name in scored and _other_code(folder, out, method)]:
        shown = ", ".join(older[:3]) + (f" and {len(older) - 3} more" if len(older) > 3 else "")
        remake = MAKES[method].format(path=shell_word(args.path))
        say(
            f"made by other nlipscalib code, scored as they are: {shown} ({remake} makes them with this version)",
            warning=True,
        )
    if unsolved:
        say(f"{_without_result(method)}, skipped: {', '.join(unsolved)}", warning=True)
    for name, problem in damaged:
        say(f"damaged, not scored: {name}: {problem}", warning=True)
    for name, problem in outdated:
        say(f"outdated, not scored: {name}: {problem}", warning=True)
    return 1 if damaged or outdated else 0


def _without_result(method: str) -> str:
    """How the presses left out for want of a ``method`` result are named: "not solved" only for NLiPs (said of
    presses that had no NLiPsNet or lookup-table result, it read as if `nlips solve` were missing)."""
    return "not solved" if method == "nlips" else f"no {method} result (not inferred)"


def _targets(path: Path, method: str | None) -> tuple[list[Path], str]:
    """(press folders, method): PATH as a reconstruction folder, a press, or a folder of presses."""
    from ..core.errors import CaptureError
    from ..core.press_folders import is_press_folder, no_presses_error, split_reference
    from ..core.reconstruction import METHODS, is_reconstruction_dir

    if is_reconstruction_dir(path) and is_press_folder(path.parent):
        named = path.name if path.name in METHODS else None
        if method and named and method != named:
            raise CaptureError(f"{path}: a {named} folder, but --method {method} was given")
        return [path.parent], method or named or "nlips"
    if is_reconstruction_dir(path):
        raise CaptureError(
            f"{path}: a reconstruction folder outside its press; score it with "
            f"`nlips eval PRESS --result {shell_word(path)}`"
        )
    presses, _ = split_reference(path)  # a folder's undeformed capture is not a press to score
    if not presses:
        hint = _results_hint(path)
        raise CaptureError(f"{path}: no press folders found{hint}") if hint else no_presses_error(path)
    return presses, method or "nlips"


def _results_hint(path: Path) -> str:
    """A hint when ``path`` holds results without their presses (``nlips infer PRESSES --out DIR`` writes
    DIR/PRESS/nlipsnet): they are scored against the presses with ``--result``."""
    from ..core.reconstruction import METHODS, has_reconstruction

    if not path.is_dir():
        return ""
    found = [d / m for d in sorted(path.iterdir()) for m in METHODS if has_reconstruction(d / m)]
    if not found:
        # `nlips infer MODEL FRAMES --out DIR` writes DIR/FRAME: a frame carries no ground truth, its press does
        # (the bare "no press folders found" left the user guessing, after `nlips infer` said eval scores them)
        frame = next((d for d in sorted(path.iterdir()) if has_reconstruction(d)), None)
        if frame is None:
            saved = _stream_frames(path)
            return f" ({path} {_stream_frames_said(path, saved)}){_INFER_PRESSES}" if saved else ""
        return (
            f" ({path} holds results of image frames, e.g. {frame.name}, which carry no ground truth): score one "
            f"against the press its frame shows with `nlips eval PRESS --result {shell_word(frame)}`"
        )
    if len(found) == 1:  # `nlips infer MODEL PRESS --out DIR`: DIR/PRESS/nlipsnet, scored against PRESS alone
        return (
            f" ({path} holds the result {found[0].relative_to(path)}): score it against its press with "
            f"`nlips eval PRESS --result {shell_word(found[0])}`"
        )
    found = found[0]
    return (
        f" ({path} holds results, e.g. {found.relative_to(path)}): score them against their presses with "
        f"`nlips eval PRESSES --result {shell_word(path)}`"
    )


def _result_targets(path: Path, result: Path, method: str | None, other_capture: bool):
    """([(press, result folder)], method) for ``--result DIR``: DIR scored against the press ``path``, or, when
    ``path`` is a folder of presses, DIR/PRESS/<method> (what ``nlips infer PRESSES --out DIR`` writes) against
    each press PRESS of it."""
    from ..core.errors import CaptureError
    from ..core.press_folders import is_press_folder, split_reference
    from ..core.reconstruction import METHODS, has_reconstruction

    if is_press_folder(path) or not path.is_dir() or has_reconstruction(result):  # one result: of one press
        presses, method = _result_target(path, result, method, other_capture)
        return [(presses[0], result)], method
    presses, _ = split_reference(path)
    methods = [method] if method else list(METHODS)
    pairs, missing = [], []
    for press in presses:
        found = next((result / press.name / m for m in methods if has_reconstruction(result / press.name / m)), None)
        if found is None:
            missing.append(press)
            continue
        _, method = _result_target(press, found, method, other_capture)
        pairs.append((press, found))
    if not pairs and (frames := _frame_results(result)):
        raise CaptureError(
            f"--result {result}: holds results of image frames (`nlips infer MODEL FRAMES`; e.g. {frames[0].name}), "
            f"which carry no ground truth, not results of the presses of {path}: infer the presses themselves "
            f"(`nlips infer MODEL {shell_word(path)} --out DIR`, then `nlips eval {shell_word(path)} --result DIR`), "
            f"or score one frame against the press it shows with `nlips eval PRESS --result {shell_word(frames[0])}`"
        )
    if not pairs and (saved := _stream_frames(result)):
        raise CaptureError(
            f"--result {result}: {_stream_frames_said(result, saved)}, not results of the presses of "
            f"{path}: infer the presses themselves (`nlips infer MODEL {shell_word(path)} --out DIR`, then "
            f"`nlips eval {shell_word(path)} --result DIR`)"
        )
    if not pairs:
        raise CaptureError(
            f"--result {result}: holds no result of the presses of {path} (looked for {result}/PRESS/"
            f"{'|'.join(methods)})"
        )
    return pairs + [(press, result / press.name / method) for press in missing], method  # listed as not solved


def _result_target(press: Path, result: Path, method: str | None, other_capture: bool) -> tuple[list[Path], str]:
    """([press], method) for ``--result DIR``: DIR's reconstruction scored against the one press ``press``."""
    from ..core.errors import CaptureError
    from ..core.press_folders import is_press_folder
    from ..core.reconstruction import METHODS, has_reconstruction, read_report

    if not is_press_folder(press):
        raise CaptureError(f"{press}: --result needs PATH to be the press folder the result was made from")
    if not has_reconstruction(result) and (frames := _frame_results(result)):
        shown = _tricolor_identity(press)
        mine = next((frame for frame in frames if _frame_of(frame) == shown), None)
        raise CaptureError(
            f"--result {result}: holds results of image frames (`nlips infer MODEL FRAMES`; e.g. {frames[0].name}), "
            f"not one result: score the one of {press}'s frame with `nlips eval {shell_word(press)} --result "
            f"{shell_word(mine) if mine else shell_word(result) + '/FRAME'}`"
        )
    if not has_reconstruction(result) and (inside := _press_result_in(result, press, method)):
        raise CaptureError(
            f"--result {result}: holds {press.name}'s result below it ({inside.relative_to(result)}: where `nlips "
            f"infer MODEL PRESS --out DIR` writes it), not one result: score it with `nlips eval {shell_word(press)} "
            f"--result {shell_word(inside)}`"
        )
    if not has_reconstruction(result) and (saved := _stream_frames(result)):
        raise CaptureError(
            f"--result {result}: {_stream_frames_said(result, saved)}: infer the press itself (`nlips "
            f"infer MODEL {shell_word(press)}`, then `nlips eval {shell_word(press)} --method nlipsnet`)"
        )
    if not has_reconstruction(result):
        raise CaptureError(f"--result {result}: no reconstruction there (result.npz)")
    try:
        report = read_report(result)
    except CaptureError:
        report = None  # a damaged report: loading the result says what is wrong (and re-solves NLiPs)
    named = (report or {}).get("method") if (report or {}).get("method") in METHODS else None
    if method and named and method != named:
        raise CaptureError(f"--result {result}: a {named} result, but --method {method} was given")
    if report is not None:
        _check_made_from(press, result, report, other_capture)
    return [press], method or named or "nlips"


def _frame_results(folder: Path) -> list[Path]:
    """The result folders in ``folder`` whose report.json records an image frame as input (``nlips infer MODEL
    FRAMES --out folder`` writes folder/FRAME), in name order; [] when none (or ``folder`` is no folder).

    Why: `nlips eval PRESSES --result FRAMES_OUT` said only that FRAMES_OUT "holds no result of the presses" (it
    looked for FRAMES_OUT/PRESS/nlipsnet), and `nlips eval PRESS --result FRAMES_OUT` "no reconstruction there": a
    frame's result is scored one at a time against the press it shows, or the presses are inferred themselves."""
    from ..core.reconstruction import has_reconstruction

    if not folder.is_dir():
        return []
    return [d for d in sorted(folder.iterdir()) if has_reconstruction(d) and _frame_of(d) is not None]


def _stream_frames_said(path: Path, saved: list[Path]) -> str:
    """What eval says of ``saved``, a stream's saved frames at ``path`` (:func:`_stream_frames`): the folder, or one
    of its files."""
    one = path.is_file()
    what = "is a stream's saved frame (" if one else f"holds a stream's saved frames (e.g. {saved[0].name}: "
    return (
        f"{what}what `nlips infer MODEL VIDEO --out DIR` and `nlips live --out DIR` write, a normal and depth map a "
        f"frame without the input it was made from), which {'carries' if one else 'carry'} no ground truth and "
        f"{'is' if one else 'are'} not scored"
    )


_INFER_PRESSES = (
    ": infer the presses the frames show (`nlips infer MODEL PRESSES`), then `nlips eval PRESSES --method nlipsnet`"
)
"""What eval advises, given a stream's folder as the presses to score."""


def _stream_frames(path: Path) -> list[Path]:
    """A stream's saved frames at ``path`` (the folder ``nlips live --out`` / ``nlips infer STREAM --out`` wrote, or
    one of its files), in name order; [] when it holds none.

    Why: eval said "no press folders found" or "no reconstruction there (result.npz)" of them, as of an empty folder:
    a stream's frame, unlike an image file's, is no result eval can score (nothing records what it was made from)."""
    import fnmatch

    from ..device.live import SAVED_FRAMES

    if path.is_file():
        return [path] if fnmatch.fnmatch(path.name, SAVED_FRAMES) else []
    return sorted(path.glob(SAVED_FRAMES)) if path.is_dir() else []


def _press_result_in(folder: Path, press: Path, method: str | None) -> Path | None:
    """``press``'s result where ``nlips infer MODEL PRESS --out folder`` writes it (folder/PRESS/nlipsnet; also
    folder/nlipsnet, ``folder`` being OUT/PRESS), of ``method`` or either; None when there is none.

    Why: `nlips eval PRESS --result OUT` said "no reconstruction there (result.npz)" of what `nlips infer` had just
    written for that one press (a folder of presses is looked up in OUT/PRESS/METHOD, one press was not)."""
    from ..core.reconstruction import METHODS, has_reconstruction

    methods = [method] if method else list(METHODS)
    places = [folder / press.name / m for m in methods] + [folder / m for m in methods]
    return next((place for place in places if has_reconstruction(place)), None)


def _frame_of(result: Path) -> str | None:
    """The identity of the image frame the result ``result`` records as its input; None when it records none, or
    a press, or its report.json cannot be read."""
    from ..core.errors import CaptureError
    from ..core.reconstruction import read_report

    try:
        recorded = _recorded_input(read_report(result))
    except CaptureError:
        return None
    return recorded[1] if recorded is not None and recorded[0] == "frame" else None


def _check_made_from(press: Path, result: Path, report: dict, other_capture: bool) -> None:
    """Refuse (CaptureError) a result whose recorded input is not ``press``, unless ``other_capture``; warn when
    the result records no input, or the press's identity cannot be read.

    Why refuse: the score of another press's result against this press's ground truth is a wrong number
    printed like a right one. Every kind records its input in ``provenance.inputs`` (docs/formats.md): NLiPs
    (``nlips solve``) and NLiPsNet of a press (``nlips infer``) the capture's identity (``press``), NLiPsNet of
    an image file the file's (``frame``, equal to the press's when it is the press's tri-colour image)."""
    from ..core.errors import CaptureError

    recorded = _recorded_input(report)
    if recorded is None:  # nlipscalib before inputs were recorded for NLiPsNet, save_reconstruction, a hand-made one
        log.warning(
            "%s: its report.json records no input identity (written by an older nlipscalib or outside `nlips solve` "
            "and `nlips infer`): cannot check that it was made from %s; scoring it against that press's ground "
            "truth",
            result,
            press,
        )
        return
    kind, made_from = recorded
    try:
        identity = _identity(press) if kind == "press" else _tricolor_identity(press)
    except (CaptureError, OSError, KeyError, TypeError) as exc:
        log.warning("%s: cannot check that it was made from %s (%s); scoring it anyway", result, press, exc)
        return
    if made_from == identity:
        return
    source = report.get("source")
    what = f"the image frame {source!r}" if kind == "frame" else "another capture"
    named = f" (it names {source!r})" if kind == "press" and isinstance(source, str) and source else ""
    if other_capture:
        from ..core.tolerances import OTHER_CAPTURE_DEPTH_MM

        log.warning(
            "%s: made from %s%s, not from %s; --other-capture: scored if its surface is within %s mm of the press's",
            result,
            what,
            named,
            press,
            OTHER_CAPTURE_DEPTH_MM,
        )
        return
    raise CaptureError(
        f"--result {result} was made from {what}{named}, not from {press} (the input identity in its report.json "
        f"differs from {press}'s): scored against {press}'s ground truth it would be a wrong number. Give the "
        "press it was made from, or add --other-capture to score it anyway (e.g. the same press rendered with "
        "another noise seed)"
    )


def _stale(press: Path, method: str) -> str | None:
    """Why PRESS/<method> was not made from the press as it is now (its images or reference replaced since; a
    result copied in from another press), or None: it was, or its report records no input to check.

    Why: scored against the new ground truth, a result of the old capture is a wrong number printed like a right
    one. Costs one hash of the press's inputs (~70 ms at 640x480)."""
    from ..core.errors import CaptureError
    from ..core.reconstruction import read_report, reconstruction_dir

    out = reconstruction_dir(press, method=method)
    try:
        recorded = _recorded_input(read_report(out))
        if recorded is None:
            return None
        kind, made_from = recorded
        identity = _identity(press) if kind == "press" else _tricolor_identity(press)
    except (CaptureError, OSError, KeyError, TypeError):  # unreadable: loading it said so, or nothing to check
        return None
    if made_from == identity:
        return None
    again = f"`nlips solve {shell_word(press)} --overwrite`" if method == "nlips" else _infer_command(press, out)
    return f"{out} was made from another capture than {press} holds now (its inputs changed since): remake it: {again}"


def _recorded_input(report: dict) -> tuple[str, str] | None:
    """(``"press"`` or ``"frame"``, identity) that a result's report.json records of its input; None if none."""
    provenance = report.get("provenance")
    inputs = provenance.get("inputs") if isinstance(provenance, dict) else None
    inputs = inputs if isinstance(inputs, dict) else {}
    return next(((k, inputs[k]) for k in ("press", "frame") if isinstance(inputs.get(k), str)), None)


def _identity(press: Path) -> str:
    """The press's capture identity (what NLiPs and NLiPsNet results record as ``inputs.press``)."""
    from ..pipeline import capture_identity

    return capture_identity(press)


def _tricolor_identity(press: Path) -> str:
    """The identity of the press's tri-colour image file (what an NLiPsNet result of that file records)."""
    from ..core.press_meta import read_meta
    from .infer import frame_identity

    return frame_identity(press / read_meta(press)["images"]["tricolor"])


def _load(folder: Path, method: str, single: bool, out: str | Path | None = None) -> Reconstruction | str | None:
    """The reconstruction (in ``out``, default PRESS/<method>); None when there is none; a problem string when it
    is damaged beyond repair."""
    from ..core.errors import CaptureError
    from ..core.reconstruction import has_reconstruction, load_reconstruction, reconstruction_dir

    out = reconstruction_dir(folder, out, method=method)
    if not has_reconstruction(out):
        if single:
            make = MAKES[method].format(path=shell_word(folder))
            raise CaptureError(f"{out}: no {method} result there (run {make} first)")
        return None
    try:
        return load_reconstruction(out)
    except CaptureError as exc:
        if method != "nlips":  # NLiPsNet results are re-made by `nlips infer`, not here: say how
            return f"{exc}; make it again with {_infer_command(folder, out)}"
        settings = _recorded_settings(out)
        if isinstance(settings, str):  # said before any "re-computing": there is nothing to re-compute from
            unknown = "" if settings == str(exc) else f" ({settings})"
            elsewhere = "" if out == reconstruction_dir(folder) else f" --out {shell_word(out)}"
            command = f"nlips solve {shell_word(folder)}{elsewhere}"
            return (
                f"{exc}; the settings it was solved with are unknown{unknown}: re-solve it with "
                f"`{command} --overwrite` and the options it was first solved with"
            )
        log.warning("%s; re-computing it from its recorded settings", exc)
        return _recompute(folder, out, settings)


def _infer_command(folder: Path, out: Path) -> str:
    """The `nlips infer` that re-makes the NLiPsNet or lookup-table result ``out`` of the press ``folder`` (its model
    when the report still names it)."""
    from ..core.errors import CaptureError
    from ..core.reconstruction import read_report, reconstruction_dir

    try:
        model = read_report(out).get("model")
    except CaptureError:
        model = None
    model = model if isinstance(model, str) and model else "MODEL.pt"
    method = out.name if out.name in ("nlipsnet", "lut") else "nlipsnet"
    elsewhere = out != reconstruction_dir(folder, method=method) and out.parent.name == folder.name
    command = f"`nlips infer {shell_word(model)} {shell_word(folder)}"
    return command + (f" --out {shell_word(out.parent.parent)}`" if elsewhere else "`")


def _recorded_settings(out: Path):
    """The SolveSettings recorded in ``out``'s report.json, or why they cannot be known (a string naming the file).

    A damaged report.json (garbage, cut short) or one without a usable ``provenance.settings`` (written by
    hand, or by ``core.reconstruction.save_reconstruction`` outside the pipeline) leaves nothing to re-solve
    with: guessing the options would score a result the user never asked for.
    """
    from ..core.errors import CaptureError, NlipsError
    from ..core.reconstruction import REPORT_FILE, read_report
    from ..pipeline import settings_from_record

    try:
        provenance = read_report(out).get("provenance")
    except CaptureError as exc:
        return str(exc)
    record = provenance.get("settings") if isinstance(provenance, dict) else None
    if not isinstance(record, dict):
        return f"{out / REPORT_FILE} records no solve settings"
    try:
        return settings_from_record(record)
    except NlipsError as exc:
        return f"{out / REPORT_FILE}: {exc}"


def _recompute(folder: Path, out: Path, settings: SolveSettings) -> Reconstruction | str | None:
    """The result re-solved into ``out`` with the ``settings`` it was first made with; a problem string when
    that fails."""
    from ..core.errors import NlipsError
    from ..pipeline import solve_one

    try:
        # overwrite: the result is known damaged (and said so); the solve's own check warned a second time
        result, _ = solve_one(folder, settings, out=out, overwrite=True, progress=True, wait=True)
    except NlipsError as exc:
        return f"damaged, and re-solving failed: {exc}"
    return result


def _scores(folder: Path, rec: Reconstruction, other_capture: Path | None, gt: GroundTruth | None) -> dict:
    """Scores of ``rec`` against ``gt``, the ground truth of ``folder`` (:func:`_ground_truth`: None when it has
    none); ``other_capture``, the result folder given with ``--other-capture``: first refuse it when its surface is
    not this press's (:func:`_far_from_truth`)."""
    from ..core.errors import CaptureError
    from ..core.metrics import evaluate
    from ..core.tolerances import OTHER_CAPTURE_DEPTH_MM

    if gt is None:
        raise CaptureError(
            f"{folder}: no ground truth (gt.npz) to evaluate against: only twin renders (nlips render, dataset, "
            "demo) carry one; a captured press has none"
        )
    if rec.shape != gt.depth.shape:
        raise CaptureError(f"{folder}: reconstruction is {rec.shape}, the capture {gt.depth.shape}")
    if other_capture is not None and (far := _far_from_truth(rec.depth, gt.depth)):
        raise CaptureError(
            f"--result {other_capture}: {far} {folder}'s true surface: a "
            f"result of another sensor (dome, camera) or of another press; --other-capture scores another capture of "
            f"the same press (another noise seed), whose surface is within {OTHER_CAPTURE_DEPTH_MM} mm"
        )
    return evaluate(rec, gt)


def _far_from_truth(depth: np.ndarray | None, true_depth: np.ndarray) -> str | None:
    """How far a result's depth lies from a press's true depth ("its depth is 1.20 mm (median over 19200
    pixels) from"), when beyond OTHER_CAPTURE_DEPTH_MM; None within it, or with no depth to compare.

    Why: ``--other-capture`` lifts the check that a result was made from the press; a result of another sensor
    of the same image size was then scored without a word (a NLiPsTac result against a fingertip press: 34.9 deg,
    3.8 mm). Its depth (mm, camera frame, NaN where none) is compared where both hold one."""
    import numpy as np

    if depth is None:
        return None
    both = np.isfinite(depth) & np.isfinite(true_depth)
    if not both.any():
        return None
    from ..core.tolerances import OTHER_CAPTURE_DEPTH_MM

    gap = float(np.median(np.abs(depth[both] - true_depth[both])))
    if gap <= OTHER_CAPTURE_DEPTH_MM:
        return None
    return f"its depth is {gap:.2f} mm (median over {int(both.sum())} pixels) from"


def _ground_truth(folder: Path, allow_edited: bool = False):
    """The press's GroundTruth or None, without decoding its images (only gt.npz is needed). Unless
    ``allow_edited`` (``--allow-edited``), CaptureError in one line when gt.npz is not the size the press's
    checksums.json records (:func:`nlipscalib.core.press_checksums.check_unchanged`: a stat): another press's copied
    over it passed GroundTruth's checks (the same shape) and scored the result against the wrong surface."""
    from ..core.camera import Camera
    from ..core.errors import CaptureError
    from ..core.press_checksums import check_unchanged
    from ..core.press_meta import read_meta
    from ..core.surface_files import GroundTruth

    meta = read_meta(folder)
    if not meta.get("ground_truth"):
        return None
    path = folder / meta["ground_truth"]
    if not path.is_file():
        raise CaptureError(f"{path}: listed in meta.json but missing")
    if not allow_edited:
        check_unchanged([folder], names=lambda _: {str(meta["ground_truth"])})
    try:
        shape = Camera.from_dict(meta["camera"]).shape
    except (TypeError, ValueError) as exc:
        raise CaptureError(f"{folder / 'meta.json'}: {exc}") from None
    return GroundTruth.load(path, shape)


def _other_code(press: Path, out: Path | None, method: str) -> bool:
    """Whether the result scored for ``press`` (``out``, else its default folder) was made by other code than this
    installation's (its report's ``provenance.code``; a report without one was written before 2026-12-06).

    Why: after an upgrade `nlips eval` printed an old result's scores like any other, and a lab read them as this
    version's; `nlips solve` would have made it again ("nlipscalib code", or "code unrecorded")."""
    from ..core.code_version import code_fingerprint
    from ..core.errors import CaptureError
    from ..core.reconstruction import read_report, reconstruction_dir

    try:
        provenance = read_report(reconstruction_dir(press, out, method)).get("provenance")
    except (CaptureError, OSError):
        return False
    return not isinstance(provenance, dict) or provenance.get("code") != code_fingerprint()


def _scored(path: Path, pairs: list, method: str, result: str | None) -> str:
    """What the table scores, for its header: the result folder(s) as paths the user can open. ``pairs``: (press,
    result folder or None) as scored."""
    presses = [press for press, _ in pairs]
    if result and len(pairs) == 1 and pairs[0][1] == Path(result):
        return f"{result} against {presses[0]}"
    if result:  # a folder of presses against DIR/PRESS/<method>
        return f"{Path(result) / '*' / method} against {path / '*'}"
    if presses == [path] or path.parent == presses[0]:  # a press, or its reconstruction folder
        return str(presses[0] / method)
    return str(path / "*" / method)


def _print(rows: list[tuple[str, dict]], seen: dict[str, str | None] | None = None) -> None:
    """stdout: the table of scores, a press a line (and their mean and pooled figures), its header first.

    ``seen``: each press's result's ``trained_on`` (:mod:`nlipscalib.learn.seen`; None: not told). When any is told,
    a ``data`` column gives it ("train", "validation", "unseen", "?") and the mean and pooled figures follow for the
    seen presses (trained or validated on) and the unseen ones apart (``mean seen``, ``pooled seen``, ...)."""
    import numpy as np

    if not rows:
        return
    told = {name: verdict for name, verdict in (seen or {}).items() if verdict}
    data = f" {'data':<10}" if told else ""
    print(f"{'press':<24}{data} {'pixels':>8} {'AAE(deg)':>9} {'MabsE':>8} {'RMSE(mm)':>9}")

    def line(name: str, s: dict, verdict: str = "", pixels: bool = True) -> str:
        count = f"{s['pixels']:>8d}" if pixels else f"{'':>8}"
        column = f" {verdict:<10}" if told else ""
        return f"{name:<24}{column} {count} {s['aae_deg']:>9.3f} {s['mabse']:>8.4f} {s['depth_rmse_mm']:>9.4f}"

    for name, s in rows:
        print(line(name, s, told.get(name, "?")))
    groups = {"": rows}
    if told and len(rows) > 1:
        groups |= {f" {group}": part for group, part in _split_by_seen(rows, told).items() if part}
    for group, part in groups.items():
        if len(rows) > 1:
            mean = {k: float(np.nanmean([s[k] for _, s in part])) for k in ("aae_deg", "mabse", "depth_rmse_mm")}
            print(line(f"mean{group}", mean, pixels=False))
            print(line(f"pooled{group}", pooled([s for _, s in part])))


def _trained_on(report: dict) -> str | None:
    """A result's ``trained_on`` (:func:`nlipscalib.learn.seen.trained_on`'s verdict, recorded by `nlips infer`), or
    None when it records none (its model, or the nlipscalib that inferred it, is of before 2026-12-07; an image
    frame's result by a model of before 2026-12-08; NLiPs's)."""
    from ..learn.seen import SEEN, TRAINED_ON_KEY, UNSEEN

    verdict = report.get(TRAINED_ON_KEY) if isinstance(report, dict) else None
    return verdict if verdict in (*SEEN, UNSEEN) else None


def _split_by_seen(rows: list[tuple[str, dict]], told: dict[str, str]) -> dict[str, list[tuple[str, dict]]]:
    """``rows`` as {"seen": ..., "unseen": ...} by their results' verdicts (``told``); rows not told are in neither."""
    from ..learn.seen import SEEN, UNSEEN

    return {
        "seen": [row for row in rows if told.get(row[0]) in SEEN],
        "unseen": [row for row in rows if told.get(row[0]) == UNSEEN],
    }


def _seen_line(rows: list[tuple[str, dict]], seen: dict[str, str | None], method: str) -> str | None:
    """The line below the table that names the seen and unseen presses' scores, or that says once that the results
    do not tell them apart; None without a learnt result among them (``seen``: NLiPsNet's and the lookup table's
    results alone, :data:`LEARNT`; NLiPs's never tell). ``method``: the results' (its model's command is named).

    Why: the paper scores NLiPsNet on presses like those it learnt from and on others apart; a model file records
    the presses it learnt from by name alone before 2026-12-07, so eval could not tell a trained press from another
    of the same name in another dataset, and a user who kept presses out to test on saw one table of both."""
    told = {name: verdict for name, verdict in seen.items() if verdict}
    if not told:
        if not seen:
            return None
        return (
            "seen and unseen presses not told apart: the results record no `trained_on` (an image frame's by a model "
            "trained before 2026-12-08, or inferred by an nlipscalib before 2026-12-07 or a model that records no "
            "captures it learnt from: a network trained before 2026-12-07, a table fitted before s42-lutseen, a "
            "dataset that records none; "
            f"{LEARNT.get(method, LEARNT['nlipsnet'])} and `nlips infer` again record it): scored together"
        )
    parts = []
    for group, part in _split_by_seen(rows, told).items():
        if not part:
            parts.append(f"{group}: none")
            continue
        p = pooled([s for _, s in part])
        parts.append(f"{group}: {len(part)} press(es), pooled AAE {p['aae_deg']:.3f} deg over {p['pixels']} pixels")
    untold = [name for name, _ in rows if name not in told]
    if untold:
        parts.append(f"not told ({', '.join(untold[:3])}{' ...' if len(untold) > 3 else ''}): in neither")
    return "; ".join(parts) + " (seen: trained or validated on by the model that made the result)"


def pooled(scores: list[dict]) -> dict:
    """The figures of :func:`nlipscalib.core.metrics.evaluate` over all the presses' scored pixels together.

    Why beside the mean of the presses' figures: the mean counts a press with a 300-pixel contact as much as one
    with 3,000. Exact from each press's figures: every scored pixel has a finite estimate and truth (a result
    with a NaN on a reconstructed pixel is refused as damaged), so each figure averages over its ``pixels``.

    Parameters
    ----------
    scores : list of {"pixels": int, "aae_deg": degrees, "mabse": unitless, "depth_rmse_mm": mm}
    """
    import numpy as np

    kept = [s for s in scores if s["pixels"] > 0]
    n = np.array([s["pixels"] for s in kept], float)
    if not n.sum():
        return {"pixels": 0, "aae_deg": float("nan"), "mabse": float("nan"), "depth_rmse_mm": float("nan")}

    def weighted(key: str, power: int = 1) -> float:
        return float((np.array([s[key] for s in kept]) ** power * n).sum() / n.sum()) ** (1 / power)

    return {
        "pixels": int(n.sum()),
        "aae_deg": weighted("aae_deg"),
        "mabse": weighted("mabse"),
        "depth_rmse_mm": weighted("depth_rmse_mm", power=2),
    }
