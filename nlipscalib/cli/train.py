"""``nlips train CALIB --out MODEL.pt``: train NLiPsNet on a calibration dataset, export ONNX, check parity."""

from __future__ import annotations

import argparse
import contextlib
import logging
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.shell_words import shell_word
from .options import add_allow_edited

if TYPE_CHECKING:  # named in hints only: torch is imported when a model is trained
    from ..learn.dataset import CalibrationDataset
    from ..learn.train import TrainConfig, TrainResult

log = logging.getLogger(__name__)

OPTION_OF = {
    "hidden": "--hidden",
    "dropout": "--dropout",
    "labels": "--labels",
    "max_epochs": "--epochs",
    "patience": "--patience",
    "schedule": "--schedule",
    "batch_size": "--batch-size",
    "lr": "--lr",
    "weight_decay": "--weight-decay",
    "colour_input": "--colour-input",
    "reference_smoothing_px": "--reference-smoothing",
    "seed": "--seed",
    "max_seconds": "--max-minutes",
    "threads": "--threads",
    "synthetic_share": "--synthetic-share",
    "synthetic_reflectance": "--gel-reflectance",
}
"""The option of `nlips train` that sets each TrainConfig field (its validation messages name the field)."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "train",
        help="train NLiPsNet (u, v, r, g, b) -> normal on a calibration dataset from `nlips calibrate`",
        description="Train the paper's NLiPsNet (MLP 256-256-128, BatchNorm, ReLU, dropout 0.2, cosine loss) with "
        "a split by press and early stopping on validation AAE; writes MODEL.pt, MODEL.onnx, MODEL_curve.png and "
        "a resumable MODEL.checkpoint.pt, published together when it ends. The same training run again (same options "
        "and samples) reuses its finished model and makes the ONNX files beside it its own (one left from another "
        "model, or cut short, is made again, or removed with --no-onnx); started while it trains, it waits for it "
        "first. Another training into an --out that one trains into is refused until that one ends (then it replaces "
        "the model, saying so).",
    )
    p.add_argument("dataset", help="calibration dataset folder (from `nlips calibrate`)")
    p.add_argument("--out", required=True, help="model file to write (.pt)")
    p.add_argument(
        "--hidden", default="256,256,128", help="hidden widths (default 256,256,128: the paper's; fast 64,64,64)"
    )
    p.add_argument(
        "--dropout",
        type=float,
        default=0.2,
        help="dropout after each hidden layer (default 0.2: the paper's; 0 for the small real-time variants, "
        "which it underfits)",
    )
    p.add_argument(
        "--labels",
        choices=("nlips", "true"),
        default="nlips",
        help="targets: NLiPs or true normals (default nlips; true needs presses with ground truth, e.g. the twin's)",
    )
    p.add_argument("--epochs", type=int, default=200, help="maximum epochs (default 200)")
    p.add_argument("--patience", type=int, help="early-stopping patience, epochs (default 8)")
    p.add_argument(  # the values are checked once, by TrainConfig
        "--schedule",
        help="learning rate: plateau (default: lowered when validation stalls) or cosine (annealed over --epochs)",
    )
    p.add_argument("--batch-size", type=int, default=1024, help="samples per optimiser step (default 1024)")
    p.add_argument(
        "--lr",
        type=float,
        default=2e-3,
        help="the optimiser's learning rate (AdamW, or Adam with --weight-decay 0; default 0.002)",
    )
    p.add_argument(
        "--weight-decay",
        type=float,
        help="decoupled weight decay (AdamW; default: TrainConfig's, 0.5: the net extrapolates more gently to "
        "colours no calibration press showed, which lifted Q2's unseen indenters; 0: Adam without decay, as before "
        "the thirty-fifth session)",
    )
    p.add_argument(  # the value is checked once, by TrainConfig
        "--colour-input",
        help="the network's colour inputs: ratio (default: each filtered colour over the undeformed reference's at "
        "that pixel, which takes the LEDs' fall-off over the image out of what the net must learn; the model file "
        "records it and `nlips infer` divides alike; Q2 full size unseen 3.27 -> 3.05 deg vs truth) or linear (the "
        "filtered colours: the paper's, and the default before the thirty-seventh session)",
    )
    p.add_argument(
        "--reference-smoothing",
        type=float,
        help="sigma (px) of the Gaussian the undeformed reference frame gets before the ratio divides by it (default: "
        "TrainConfig's, 3: its noise would otherwise be a fixed pattern in every press's ratio; Q2 medium seen "
        "-0.10 to -0.15 deg vs truth; 0: filtered as the samples, as before the thirty-eighth session)",
    )
    p.add_argument(
        "--seed", type=int, default=0, help="seed of the validation split, weights, batch order, dropout (default 0)"
    )
    p.add_argument("--val-presses", help="comma-separated validation presses (default: a seeded 20%% of them)")
    p.add_argument("--exclude", help="comma-separated presses kept out of training and validation (a test set)")
    p.add_argument("--max-minutes", type=float, default=0.0, help="stop training after this long (default 0: no limit)")
    p.add_argument(
        "--threads",
        type=int,
        help="PyTorch CPU threads (default 1: faster than more whenever another process uses a core, and the same "
        "model on every machine; 0: every core this process may use, fastest on an idle machine)",
    )
    p.add_argument(
        "--device",
        default="cpu",
        help="where to train: cpu (default), cuda or cuda:N (a GPU: the samples are moved there once; the model, "
        "checkpoint and ONNX files are the same kind as a CPU run's, and a run interrupted on one device resumes on "
        "the other). A GPU run's weights differ slightly from a CPU run's (other rounding and dropout draws); the same "
        "training run again reuses the finished model whichever device made it, and says so",
    )
    p.add_argument(
        "--synthetic-share",
        type=float,
        default=0.0,
        help="add model-made samples of steep relief (normals tilted 30-75 deg, from the LED model, the undeformed "
        "surface and the reference frame; needs the dataset's reference capture and press folders) to the training "
        "samples, this many per real one (default 0: none; measured on the twin's Q2 in docs/experiments/RESULTS.md)",
    )
    p.add_argument(
        "--gel-reflectance",
        type=float,
        default=0.0,
        help="the gel coat's diffuse reflectance, for the synthetic samples' indirect light (default 0: direct light "
        "only; a white matte coat: about 0.8)",
    )
    p.add_argument("--no-onnx", action="store_true", help="skip the ONNX export (`nlips export MODEL` makes it later)")
    add_allow_edited(p, "train on the samples of")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (none either when not on a terminal)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..core.config import check_count, options_named
    from ..core.cpus import usable_cores
    from ..core.errors import CaptureError, ConfigError
    from ..learn.checkpoint import training_run
    from ..learn.dataset import CalibrationDataset
    from ..learn.onnx_fullframe import frame_graph_path
    from ..learn.publish import hold_training, model_stage, publish_model, reusable_model
    from ..learn.torch_device import check_device
    from ..learn.train import TrainConfig, train
    from ..progress import print_result, say
    from ..report.learn import training_curve

    try:
        hidden = tuple(int(h) for h in args.hidden.split(","))
    except ValueError:
        raise ConfigError(f"--hidden must be like 256,256,128, got {args.hidden!r}") from None
    from .folders import names_a_folder

    out = Path(args.out)
    # `--out models` for the folder to train into: the model file in it is meant; `--out models.pt/` (typed as a
    # folder) wrote the file models.pt, pathlib dropping the slash
    if names_a_folder(args.out):
        example = out / "nlipsnet.pt"
        raise ConfigError(f"--out {args.out}: a folder; give the model file to write in it (e.g. {example})")
    if out.suffix != ".pt":
        raise ConfigError(f"--out {out}: the model file must end in .pt")
    given = {
        k: v
        for k, v in (
            ("patience", args.patience),
            ("schedule", args.schedule),
            ("weight_decay", args.weight_decay),
            ("colour_input", args.colour_input),
            ("reference_smoothing_px", args.reference_smoothing),
        )
        if v is not None
    }
    if args.threads is not None:  # else TrainConfig's default
        given["threads"] = check_count("--threads", args.threads, minimum=0) or usable_cores()
    if not args.max_minutes >= 0:  # NaN too
        raise ConfigError(f"--max-minutes must be >= 0 (0: no limit), got {args.max_minutes}")
    with options_named(OPTION_OF):  # TrainConfig names its field; the user typed the option
        cfg = TrainConfig(
            hidden=hidden,
            dropout=args.dropout,
            labels=args.labels,
            max_epochs=args.epochs,
            **given,
            batch_size=args.batch_size,
            lr=args.lr,
            seed=args.seed,
            max_seconds=args.max_minutes * 60,
            synthetic_share=args.synthetic_share,
            synthetic_reflectance=args.gel_reflectance,
        )
    device = check_device(args.device, flag=True)  # before the dataset loads: a machine without the GPU is told at once
    data = CalibrationDataset(args.dataset)
    if older := data.older_sampling():
        log.warning("%s", older)
    if left := [gone["name"] for gone in data.tricolor_left_out]:  # said by calibrate; the run's log says it too
        log.info(
            "%s: %d press%s left out by `nlips calibrate` (a tri-colour frame unlike its LED images): %s",
            data.folder,
            len(left),
            "es" if len(left) != 1 else "",
            ", ".join(left),
        )
    if kept := data.tricolor_kept:  # kept on request: the user knows, the model trained on them is said to
        shown = ", ".join(kept[:5]) + (f" and {len(kept) - 5} more" if len(kept) > 5 else "")
        log.warning(
            "%s: %d of its %d presses have a tri-colour frame that does not hold their LED images' light, kept by "
            "`nlips calibrate --keep-tricolor-mismatch` (%s): the network learns their colours as captured; frames "
            "given to `nlips infer` must be captured alike",
            data.folder,
            len(kept),
            len(data.entries),
            shown,
        )
    if not args.allow_edited and (changed := data.changed_presses()):
        raise CaptureError(next(iter(changed.values())) + _more_changed(changed))
    val = _names(args.val_presses) or None
    exclude = _names(args.exclude)
    onnx_path = out.with_suffix(".onnx")
    curve = out.with_name(out.stem + "_curve.png")
    # held for the whole run: the same training started twice waits (then reuses the model), another is refused;
    # this run's files are made in a folder of their own and published together, never a .pt beside another's .onnx
    with hold_training(out, training_run(cfg, data.folder, val, exclude)), model_stage(out) as stage:
        reuse = args.no_onnx or onnx_path.is_file()  # a finished model whose export is missing: exported again
        model, damaged = None, None
        if reuse:  # the dataset's load said what its record lacks; the model holds that record
            with _quiet_sensor_record():
                model, damaged = reusable_model(out, with_onnx=not args.no_onnx)
        if damaged is not None:  # a file torn by a power cut, or cut short: made again, not reused as it is
            log.warning("%s; made again from its training's checkpoint", damaged)
            reuse = False
        result = train(
            data,
            cfg,
            out,
            val_names=val,
            exclude=exclude,
            progress=not args.no_progress,
            stage=stage,
            reuse=reuse,
            device=str(device),
        )
        if result.reused:
            best = result.history[result.best_epoch]
            print_result(out)  # stdout: the model's file alone (scripts); what it is, on stderr
            say(
                f"{out}: reused, trained before with the same options on the same samples (best epoch "
                f"{result.best_epoch + 1} of {len(result.history)}, validation AAE {best['val_aae_deg']:.2f} deg); "
                f"{_device_note(result.history, device.type)}other options or --out train another"
            )
            from ..learn.model import load_model

            reused = (
                model if model is not None else load_model(out)
            )  # read once, before the reuse: its digest and its record
            _companions_made_current(out, args.no_onnx, reused.digest)
            if older := _older_model(out, reused.info):
                log.warning("%s", older)
            return 0
        training_curve(result.history, stage / curve.name, f"NLiPsNet {args.hidden}", result.val_presses)
        best = result.history[result.best_epoch]
        summary = (  # epochs numbered from 1 here (the stored history counts from 0)
            f"{out}: best epoch {result.best_epoch + 1} of {len(result.history)}, "
            f"validation AAE {best['val_aae_deg']:.2f} deg "
            f"({_contact_figure(best['val_contact_aae_deg'])}) on {', '.join(result.val_presses)} "
            f"({_trained_on(result, exclude)}); {_why_stopped(result, cfg)}; curve {curve}"
        )
        angle = frame_angle = None
        # the full-frame graph of the model this run replaces (`nlips export MODEL --full-frame`): made again for the
        # new one and published with it, or removed in the same publish (said): never left beside the new model
        frame = frame_graph_path(out)
        why_not = {onnx_path: "--no-onnx", frame: "--no-onnx"} if args.no_onnx else {}
        try:
            if not args.no_onnx:
                angle = export_and_check(stage / out.name, data, result.val_presses)[1]
                if frame.is_file():
                    frame_angle, why_not[frame] = _frame_graph_again(stage, out)
        except Exception:  # a failed export costs the export, not the training: the model goes out without one
            if angle is None:
                (stage / onnx_path.name).unlink(missing_ok=True)  # written, then failed its parity check
            (stage / frame.name).unlink(missing_ok=True)
            removed = publish_model(stage, out, result).removed
            print_result(out)
            say(summary)
            _say_removed(removed, out, {onnx_path: "its export failed", frame: "its export failed"} | why_not)
            raise
        removed = publish_model(stage, out, result).removed
    print_result(out)  # stdout: the model's file alone (scripts); how it trained, on stderr
    say(summary)
    if angle is not None:
        say(f"{onnx_path}: onnxruntime vs PyTorch max angular difference {angle:.4f} deg on the validation samples")
    if frame_angle is not None:
        say(
            f"{frame}: made again for the new model (the one it replaced had it): onnxruntime's normal map vs "
            f"PyTorch's full-frame path max angular difference {frame_angle:.4f} deg"
        )
    _say_removed(removed, out, why_not)
    say(f"next: nlips infer {shell_word(out)} INPUT (press folders, tri-colour frames, a video or --camera N)")
    return 0


def _frame_graph_again(stage: Path, out: Path) -> tuple[float | None, str | None]:
    """The full-frame graph of the model trained into ``stage`` (to be published as ``out``), written there beside it
    and checked against PyTorch's full-frame path as `nlips export --full-frame` writes it (it takes no other
    options): (the largest angle, None), or (None, why not, naming the files as they will be published) when the new
    model has no such graph (a bilateral prefilter too wide to unroll) or its check failed."""
    from ..core.errors import CaptureError, ConfigError
    from ..learn.model import load_model
    from ..learn.onnx_fullframe import export_full_frame, frame_graph_path

    staged = stage / out.name
    try:
        with _quiet_sensor_record():
            model = load_model(staged)
        return export_full_frame(model, frame_graph_path(staged))[1], None
    except (CaptureError, ConfigError) as exc:  # the user's paths, not the stage's
        why = str(exc).replace(str(frame_graph_path(staged)), str(frame_graph_path(out)))
        return None, why.replace(str(staged), str(out))


def _companions_made_current(out: Path, no_onnx: bool, digest: str) -> None:
    """After the model at ``out`` was reused: each ONNX file beside it that is not its current export (MODEL.onnx,
    MODEL.frame.onnx recording another model's digest or none, a ratio model's export of before 2026-12-07:
    ``learn.exports.not_current``) made again as a training makes it, or removed (``--no-onnx``, or it cannot be
    made), each said in the lines a training that replaces a model says.

    Why: a reuse published nothing, so a full-frame graph left stale by an earlier nlipscalib's retrain (which did
    not make it again) stayed beside the model, and `--backend auto` skipped it on every run; with ``--no-onnx`` a
    stale MODEL.onnx stayed alike (without it, a stale MODEL.onnx makes the run publish its files again:
    ``learn.publish.reusable_model``). Cheap when both are current: ``digest`` (the model file's,
    ``LoadedModel.digest``, of the model the reuse loads anyway) against a few hundred bytes of each export
    (``onnx_export.recorded_metadata``)."""
    from ..learn.exports import not_current
    from ..learn.onnx_fullframe import frame_graph_path
    from ..learn.publish import model_files_held
    from ..progress import say

    exports = {frame_graph_path(out): True}  # MODEL.onnx was checked whole before the reuse, unless --no-onnx
    if no_onnx:
        exports[out.with_suffix(".onnx")] = False
    if not any(path.is_file() for path in exports):
        return
    with model_files_held(out):  # as `nlips export` beside the model: never in the middle of another's write
        for path, full in exports.items():
            why = not_current(path, digest, full)
            if why is None:
                continue
            why, reason = why.format(model=out), "--no-onnx"
            if not no_onnx:  # the full-frame graph, made as a training that replaces the model makes it
                angle, reason = _frame_graph_again(out.parent, out)
                if reason is None:
                    say(
                        f"{path}: made again ({why}): onnxruntime's normal map vs PyTorch's full-frame path max "
                        f"angular difference {angle:.4f} deg"
                    )
                    continue
            path.unlink(missing_ok=True)
            _say_removed([path], out, {path: reason}, why)


def _say_removed(removed: Sequence[Path], out: Path, why: dict[Path, str], stale: str | None = None) -> None:
    """One warning for each export of the model this run replaced (MODEL.onnx, MODEL.frame.onnx: the keys of
    ``why``, the reason it was not made again) that its publish removed, with the command that writes the new
    model's; with ``stale`` (what was wrong with it), of an export beside a reused model that was not its current
    one (:func:`_companions_made_current`)."""
    from ..learn.exports import remake_command
    from ..learn.onnx_fullframe import frame_graph_path

    for path in removed:
        if path not in why:
            continue
        full = path == frame_graph_path(out)
        what = "full-frame ONNX graph" if full else "ONNX export"
        whose = "of the model this training replaced" if stale is None else f"beside the reused model, {stale}"
        log.warning(
            "%s: the %s %s, removed (not made again: %s); `%s` writes the %s",
            path,
            what,
            whose,
            why[path],
            remake_command(out, full),
            "new model's" if stale is None else "model's",
        )


def _more_changed(changed: dict[str, str]) -> str:
    """What follows the first line of :meth:`CalibrationDataset.changed_presses` in the refusal: the other presses
    changed (" (2 others changed too: press_0004, press_0007)") and the option that trains anyway."""
    from ..core.press_checksums import CHANGED_SHOWN, EDITED_OPTION

    others = list(changed)[1:]
    anyway = f"; or pass {EDITED_OPTION} to train on the samples as they are"
    if not others:
        return anyway
    shown = ", ".join(others[:CHANGED_SHOWN])
    shown += f" and {len(others) - CHANGED_SHOWN} more" if len(others) > CHANGED_SHOWN else ""
    return f" ({len(others)} other{'s' if len(others) > 1 else ''} changed too: {shown}){anyway}"


def _older_model(out: Path, info: dict) -> str | None:
    """Why the reused model at ``out`` lacks what a training of this version records, in one line, or None.

    Why: a training of the same options on the same samples reuses the model whatever nlipscalib trained it (its
    weights are what training again would give); one trained before 2026-12-06 records no calibrated contacts
    (``learn.resolution.INFO_KEY``), so `nlips infer` could not judge a contact against the steepest calibration
    press, and a lab that re-ran `nlips train` after upgrading kept that model without a word. One trained before
    2026-12-08 records its presses by their meta.json's bytes too (no ``press_identities``,
    :mod:`nlipscalib.learn.seen`): a copy of one with another meta.json counts as unseen. ``info``: the reused
    model's (``LoadedModel.info``)."""
    from ..core.press_identity import is_identity
    from ..learn.resolution import INFO_KEY
    from ..learn.seen import IDENTITIES_KEY

    if INFO_KEY not in info:
        return (
            f"{out}: trained by an nlipscalib before 2026-12-06: it records no calibrated contacts, so `nlips infer` "
            "judges a contact's steepness by NLiPsNet's own limit only; train into another --out to record them"
        )
    known = info.get(IDENTITIES_KEY)
    if not (isinstance(known, dict) and known and all(is_identity(r) for r in known.values())):
        return (
            f"{out}: trained before 2026-12-08 or on a dataset built before it: it records the presses it learnt from "
            "by their meta.json's bytes too, so `nlips infer` counts a copy of one whose meta.json differs (rendered "
            "or copied elsewhere) as unseen; run `nlips calibrate` on the presses again and train into another --out "
            "to record them by their images"
        )
    return None


def _device_note(history: list[dict], device: str) -> str:
    """'trained on cpu, not cuda: ' when the reused model's last epoch ran on another device type than ``device``
    (the one asked for), else "".

    Why the device is not part of what makes two runs the same training (and so a CPU model is reused for a
    `--device cuda` run and the other way round): the device decides how fast and how the weights round (and which
    generator draws the dropout masks), not what is trained: the options and samples are the same, the validation
    AAE alike, and training again would spend the time this rule saves on a model no better. ``--threads`` is
    treated alike. Reused without a word, though, a user who asked for a GPU run (to time it, or to compare) would
    take the CPU's model for the GPU's: the line says which device made it, and another --out trains anew."""
    made = history[-1].get("device", "cpu") if history and isinstance(history[-1], dict) else "cpu"
    return "" if made == device else f"trained on {made}, not {device} (another --out trains on {device}); "


def _names(option: str | None) -> list[str]:
    """Press names of a comma-separated option, as typed ("press_1, press_2" too: the spaces are no part of them)."""
    return [name.strip() for name in (option or "").split(",") if name.strip()]


def export_and_check(model_path: Path, dataset: CalibrationDataset, names: Sequence[str]) -> tuple[Path, float]:
    """Export MODEL.onnx and return (path, max angle in degrees between onnxruntime and PyTorch normals) on the
    samples of presses ``names``; CaptureError beyond ``core.tolerances.ONNX_PARITY_DEG``."""
    from ..learn.model import load_model, model_inputs
    from ..learn.onnx_export import checked_parity, export_onnx

    with _quiet_sensor_record():
        model = load_model(model_path)
    s = dataset.arrays(names)
    angles = []  # on the written file, before it takes its name (export_onnx)
    path = export_onnx(
        model,
        model_path.with_suffix(".onnx"),
        check=lambda tmp: angles.append(checked_parity(model, tmp, model_inputs(s["pixel"], s["rgb"]))),
    )
    return path, angles[0]


@contextlib.contextmanager
def _quiet_sensor_record() -> Iterator[None]:
    """Without the sensor record's warnings while the fresh model is read back for its export: the model holds the
    dataset's record, whose warning (an old dataset's missing LED geometry) the dataset's load gave already, and
    here it named the model's temporary file, a path the user never sees (`.tmp-MODEL.pt~HOST~PID~.../MODEL.pt`)."""
    record_log = logging.getLogger("nlipscalib.core.sensor_record")
    level = record_log.level
    record_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        record_log.setLevel(level)


def _contact_figure(aae: float | None) -> str:
    """'contact 3.20 deg', or 'no contact samples' when the validation presses hold none (their AAE is NaN)."""
    import math

    return f"contact {aae:.2f} deg" if aae is not None and math.isfinite(aae) else "no contact samples"


def _trained_on(result: TrainResult, exclude: Sequence[str]) -> str:
    """'6 presses trained on; kept out: press_0009, press_0010': a user who kept presses out to test on was not told
    the run had left them out (nor how many presses the net learnt from)."""
    kept = f"; kept out: {', '.join(exclude)}" if exclude else ""
    return f"{len(result.train_presses)} presses trained on{kept}"


def _why_stopped(result: TrainResult, cfg: TrainConfig) -> str:
    """What ended the training: the epoch limit, early stopping, or the time limit (--max-minutes)."""
    done = len(result.history)
    if done >= cfg.max_epochs:
        # the README's quick walk (`--epochs 3`) ends so with a net far from trained: say when it still improved
        still = "; still improving at its last epoch: more --epochs may help" if result.best_epoch == done - 1 else ""
        return f"stopped at the epoch limit (--epochs {cfg.max_epochs}){still}"
    if done - 1 - result.best_epoch >= cfg.patience:
        return f"stopped early ({cfg.patience} epochs without a better validation AAE)"
    return f"stopped by the time limit (--max-minutes {cfg.max_seconds / 60:g}; more epochs may help)"
