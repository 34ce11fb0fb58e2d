"""``nlips lut CALIB --out TABLE.pt``: fit the GelSight-style lookup-table baseline (Yuan et al. 2017) on a
calibration dataset, the one `nlips train` reads; `nlips infer` and `nlips eval` then run and score it as they do
NLiPsNet (its results in PRESS/lut, beside PRESS/nlipsnet).

Why a command of its own rather than `nlips train --model lut`: fitting a table has none of training's options
(layers, dropout, epochs, learning rate, device, the checkpoint, the ONNX export) and two of its own (levels,
regions); in `nlips train` most options would be refused or ignored for it, and its help would describe a network.
"""

from __future__ import annotations

import argparse
import logging

from ..core.shell_words import shell_word
from .options import add_allow_edited

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    from ..learn.lut import DEFAULT_BINS, DEFAULT_CELLS, MAX_BINS, MAX_CELLS

    p = subparsers.add_parser(
        "lut",
        help="fit the GelSight-style lookup table (colour -> normal per image region) on a calibration dataset",
        description="Fit the classic GelSight lookup table (Yuan et al. 2017: each pixel's colour change from the "
        "undeformed frame, binned per channel, -> the mean label normal of that bin, one table per image region) on "
        "the samples of a calibration dataset from `nlips calibrate`, the ones `nlips train` trains NLiPsNet on, and "
        "write it as a model file (.pt) carrying the sensor and undeformed reference it is valid for. `nlips infer "
        "TABLE.pt PRESSES` then writes PRESS/lut/ (normals, depth, --ply) and `nlips eval PRESSES --method lut` "
        "scores it as NLiPsNet's PRESS/nlipsnet is, the presses it was fitted on (the captures the file records) and "
        "the others apart. The same fit again writes the same file.",
    )
    p.add_argument("dataset", help="calibration dataset folder (from `nlips calibrate`)")
    p.add_argument("--out", required=True, help="table's model file to write (.pt)")
    p.add_argument(
        "--bins",
        type=int,
        default=DEFAULT_BINS,
        help=f"levels per colour channel (default {DEFAULT_BINS}; 2 to {MAX_BINS}), over the samples' 0.5-99.5 "
        "percentile of colour change",
    )
    p.add_argument(
        "--cells",
        type=int,
        default=DEFAULT_CELLS,
        help=f"image regions per side, each with its own table (default {DEFAULT_CELLS}: 8x8; 1 to {MAX_CELLS})",
    )
    p.add_argument(
        "--labels",
        choices=("nlips", "true"),
        default="nlips",
        help="normals the bins average: NLiPs' (default) or the true ones (presses with ground truth, the twin's)",
    )
    p.add_argument("--exclude", help="comma-separated presses kept out of the fit (a test set)")
    add_allow_edited(p, "fit on the samples of")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import time
    from pathlib import Path

    from ..core.errors import CaptureError, ConfigError
    from ..learn.dataset import CalibrationDataset
    from ..learn.lut import fit_table_file
    from ..progress import print_result, say
    from .folders import names_a_folder
    from .train import _more_changed, _names

    t0 = time.perf_counter()
    out = Path(args.out)
    if names_a_folder(args.out):
        raise ConfigError(f"--out {args.out}: a folder; give the table's file to write in it (e.g. {out / 'lut.pt'})")
    if out.suffix != ".pt":
        raise ConfigError(f"--out {out}: the table's model file must end in .pt")
    data = CalibrationDataset(args.dataset)
    if older := data.older_sampling():
        log.warning("%s", older)
    if not args.allow_edited and (changed := data.changed_presses()):
        raise CaptureError(next(iter(changed.values())) + _more_changed(changed))
    with _options_named():
        table, info = fit_table_file(data, out, _names(args.exclude), args.labels, args.cells, args.bins)
    print_result(out)  # stdout: the file alone (scripts); what it is, on stderr
    say(
        f"{out}: lookup table {table.bins} levels, {table.cells}x{table.cells} regions, {info['filled_bins']} bins "
        f"filled from {info['train_samples']} samples ({info['contact_samples']} in contact) of "
        f"{len(info['train_presses'])} presses, {args.labels} labels; {time.perf_counter() - t0:.1f} s"
    )
    say(
        f"next: nlips infer {shell_word(out)} PRESSES (PRESS/lut), then nlips eval PRESSES --method lut; "
        "tri-colour frames, a video or --camera N as for NLiPsNet"
    )
    return 0


def _options_named():
    """fit_table_file's messages name its parameters; the user typed the options."""
    from ..core.config import options_named

    return options_named({"bins": "--bins", "cells": "--cells"})
