"""``nlips demo``: the main job (render, reconstruct, score) on the built-in default scene.

Renders the undeformed NLiPsTac dome and a few presses with the digital twin, reconstructs each press
with NLiPs around its contact, compares with the ground truth and writes a contact sheet PNG.
Resumable: presses and solutions already on disk are reused.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING

from .options import RENDER_WORKERS_HELP, SOLVE_WORKERS_HELP

if TYPE_CHECKING:  # named in hints only: imported when the demo runs
    import numpy as np

    from ..core.capture import Press
    from ..core.reconstruction import Reconstruction
    from ..report import Panel


SHEET_PRESSES = 8
"""Presses the contact sheet shows at most, a row each (the first ones; the scores' table has them all): `nlips demo
--spec train50` drew 50 rows, a 1468 x ~11400 px sheet of 250 panels."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="render presses on the default scene, reconstruct them with NLiPs, write a contact sheet",
        description=__doc__,
    )
    p.add_argument("--out", default="out/demo", help="output folder (default: out/demo)")
    p.add_argument(
        "--spec",
        default="demo",
        help="dataset spec to render: a file or a shipped spec's name (default: demo)",
    )
    p.add_argument("--workers", type=int, default=0, help=RENDER_WORKERS_HELP)
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="re-render the presses in --out that another scene, spec or twin version made; presses of this "
        "very spec are kept, and their solutions reused (delete --out to start anew)",
    )
    p.add_argument("--no-solve", action="store_true", help="only render and show the ground truth")
    p.add_argument("--no-figures", action="store_true", help="no per-press figure maps next to the results")
    p.add_argument(
        "--solve-workers",
        type=int,
        default=0,
        help=SOLVE_WORKERS_HELP,
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.capture import load_press
    from ..core.config import check_count
    from ..progress import BATCH, press_lines, print_result, say
    from ..sim.dataset import (
        REFERENCE_NAME,
        claim_folder,
        expand_jobs,
        first_press_number,
        load_dataset_spec,
        run_dataset,
        spec_digest,
        write_manifest,
    )
    from ..sim.scene import dataset_spec_path
    from .folders import check_not_in_press

    press_lines(BATCH)  # its table says how each press went; a line per solved press, how with -v
    check_count("--workers", args.workers, minimum=0)  # before minutes of rendering, not after
    check_count("--solve-workers", args.solve_workers, minimum=0)
    out = Path(args.out)
    check_not_in_press(out, "render the demo")
    spec, scene = load_dataset_spec(dataset_spec_path(args.spec))
    jobs = expand_jobs(spec, first=first_press_number(out))  # an earlier demo's press_0000, ... are reused
    out.mkdir(parents=True, exist_ok=True)
    with claim_folder(out, spec_digest(spec, scene, jobs)):  # a `nlips dataset` of another spec there: refused
        write_manifest(out, spec, scene, jobs)
        rendered = run_dataset(scene, jobs, out, workers=args.workers, overwrite=args.overwrite)
    if rendered["failed"]:
        for name, error in rendered["failed"]:
            say(f"{name}: {error}", warning=True)
        return 1
    presses = [j for j in jobs if j.name != REFERENCE_NAME]
    failed = set()
    if not args.no_solve:
        from ..core.cpus import SOLVE_ROI_MEMORY, solve_worker_count
        from ..pipeline import solve_presses

        folders = [out / job.name for job in presses]
        workers = solve_worker_count(args.solve_workers, SOLVE_ROI_MEMORY, scene.camera.width, scene.camera.height)
        statuses = solve_presses(folders, roi="auto", workers=workers, figures=not args.no_figures)
        failed = {name for name, status in statuses.items() if status.startswith("failed")}
        for name in sorted(failed):
            say(f"{name}: {statuses[name]}", warning=True)
    rows, table = [], []
    for job in presses:
        press = load_press(out / job.name)
        title = f"{job.name}\n{job.press.indenter.kind}, {job.press.depth:.1f} mm"
        solve = not args.no_solve and job.name not in failed
        result = _solve(press, figures=not args.no_figures) if solve else None  # solved above: this loads it
        if len(rows) < SHEET_PRESSES:
            rows.append((title, _panels(press, result)))
        if result is not None:
            table.append((job.name, job.press.indenter.kind, _scores(press, result)))
    from ..report import contact_sheet
    from ..report.figures import NORMALS_KEY

    title = _sheet_title(Path(spec.scene).stem, scene.camera.width, scene.camera.height, not args.no_solve)
    if len(rows) < len(presses):  # the table below still scores every press
        title += f"; the first {len(rows)} of {len(presses)} presses"
    sheet = contact_sheet(rows, out / "contact_sheet.png", caption=NORMALS_KEY, title=title)
    print_result(sheet)  # stdout: the demo's product, the contact sheet, alone (scripts); its scores on stderr
    _say_table(table)
    say(f"contact sheet: {sheet}")
    return 1 if failed else 0


def _sheet_title(scene: str, width: int, height: int, solved: bool) -> str:
    """The contact sheet's title: what it shows, of which twin (the sheet opened alone said nothing of it).

    Parameters
    ----------
    scene : the spec's scene name
    width, height : the presses' image size, pixels
    solved : whether the presses were reconstructed (not ``--no-solve``)
    """
    shown = "NLiPs around each press's contact vs the true normals" if solved else "the true normals (--no-solve)"
    return f"nlips demo on the {scene} twin ({width}x{height} px): {shown}"


def _solve(press: Press, figures: bool) -> Reconstruction | None:
    """NLiPs around the contact, through the shared pipeline: an identical result in PRESS/nlips/ is
    reused, a damaged or differently made one is re-solved."""
    from ..pipeline import solve_folder

    # the presses were solved (or found solved, and said so) just before: loading them is not news
    result, _ = solve_folder(press.folder, roi="auto", progress=True, figures=figures, announce_reuse=False)
    return result


def _scores(press: Press, result: Reconstruction) -> dict:
    from ..core.metrics import evaluate

    return evaluate(result, press.ground_truth)  # reconstructed pixels: all of the ROI, and its contact part


def _panels(press: Press, result: Reconstruction | None) -> list[Panel]:
    import numpy as np

    from ..core.metrics import angular_error_map
    from ..report import Panel, display_image, normals_to_rgb

    gt = press.ground_truth
    panels = [
        Panel("tri-colour image", display_image(press.linear(press.tricolor))),
        Panel("LED 1 alone", display_image(press.linear(press.led_images[0]))),
        Panel("true normals", normals_to_rgb(gt.normals, gt.valid)),
        Panel("contact mask (truth)", gt.contact.astype(float), cmap="gray", legend=("no contact", "contact")),
    ]
    if result is not None:
        shown = result.reconstructed & gt.valid
        err = np.where(shown, angular_error_map(result.normals, gt.normals), np.nan)
        panels[3:] = [
            Panel("NLiPs normals", normals_to_rgb(result.normals, shown)),
            _error_panel(err, gt.contact),
        ]
    return panels


def _error_panel(err: np.ndarray, contact: np.ndarray | None = None) -> Panel:
    """The angular error panel of one press (err: (H, W) float, degrees, NaN where not scored), titled with its AAE
    (over the same pixels, as the summary figure prints it), in a colour range fitted to this press's errors
    (``error_scale``): a fixed 0-10 deg, or one range shared with a coin's 20-deg edges, showed the sphere's and
    the cube's half-degree errors as black squares. The rows compare by their AAE and colour bars. The title gives
    the contact AAE too (``contact``: the truth's (H, W) bool contact region), as the table and the summary do."""
    from ..report.figures import error_panel
    from ..report.reconstruction import error_title

    # the table's "AAE roi" (every scored pixel) and "AAE contact"
    return error_panel(error_title(err, contact), err)


def _say_table(table: list[tuple[str, str, dict]]) -> None:
    """The scores of each solved press, a line each, on stderr (:func:`nlipscalib.progress.say`): the demo's product
    is its contact sheet; ``nlips eval`` prints such a table as its stdout."""
    from ..progress import say

    if not table:
        return
    say(f"{'press':<12} {'indenter':<10} {'AAE roi':>8} {'MabsE roi':>10} {'AAE contact':>12} {'depth RMSE':>11}")
    for name, kind, s in table:
        roi, contact = s["all"], s["contact"]
        say(
            f"{name:<12} {kind:<10} {roi['aae_deg']:>7.2f}° {roi['mabse']:>10.4f} "
            f"{contact['aae_deg']:>11.2f}° {roi['depth_rmse_mm']:>8.3f} mm"
        )
