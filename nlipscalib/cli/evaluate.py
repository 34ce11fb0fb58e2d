"""``nlips eval PATH``: AAE, MabsE and depth RMSE of solver results against ground truth."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser("eval", help="score solver results (needs `nlips solve` results and ground truth)")
    p.add_argument("path", help="press folder or a folder of presses")
    p.add_argument("--region", choices=("all", "contact"), default="all", help="pixels to score")
    p.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    from ..core.capture import find_presses, load_press
    from ..core.reconstruction import has_reconstruction, reconstruction_dir
    from ..errors import CaptureError
    from ..solver import evaluate, load_result

    presses = find_presses(args.path)
    if not presses:
        raise CaptureError(f"{args.path}: no press folders found")
    rows, skipped = [], []
    for folder in presses:
        if len(presses) > 1 and not has_reconstruction(reconstruction_dir(folder)):
            skipped.append(folder.name)  # e.g. a dataset's undeformed reference: nothing solved there
            continue
        press = load_press(folder)
        if press.ground_truth is None:
            raise CaptureError(f"{folder}: no ground truth (gt.npz) to evaluate against")
        scores = evaluate(load_result(reconstruction_dir(folder)), press.ground_truth)[args.region]
        rows.append((folder.name, scores))
    if not rows:
        raise CaptureError(f"{args.path}: no press has a solver result yet (run `nlips solve` first)")
    print(f"{'press':<24} {'pixels':>8} {'AAE(deg)':>9} {'MabsE':>8} {'RMSE(mm)':>9}")
    for name, s in rows:
        print(f"{name:<24} {s['pixels']:>8d} {s['aae_deg']:>9.3f} {s['mabse']:>8.4f} {s['depth_rmse_mm']:>9.4f}")
    if len(rows) > 1:
        mean = {k: float(np.nanmean([s[k] for _, s in rows])) for k in ("aae_deg", "mabse", "depth_rmse_mm")}
        print(f"{'mean':<24} {'':>8} {mean['aae_deg']:>9.3f} {mean['mabse']:>8.4f} {mean['depth_rmse_mm']:>9.4f}")
    if skipped:
        print(f"not solved, skipped: {', '.join(skipped)}")
    return 0
