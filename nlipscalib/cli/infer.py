"""``nlips infer MODEL INPUT...``: normals, depth on the dome and point clouds from tri-colour frames with NLiPsNet."""

from __future__ import annotations

import logging

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "infer",
        help="NLiPsNet normals + depth (+ PLY) from tri-colour frames: press folders, PNG files or a folder of frames",
        description="Run a trained NLiPsNet on press folders (writes PRESS/nlipsnet/ in the reconstruction format) "
        "or on 16-bit tri-colour PNG frames (a file, several, or a folder of frames processed as a stream). "
        "Only pixels that differ from the calibration's reference frame go through the network; depth integrates "
        "the normals on the dome. Prints frames per second.",
    )
    p.add_argument("model", help="model file (.pt) from `nlips train`")
    p.add_argument("inputs", nargs="+", help="press folder(s), a folder of presses, PNG file(s) or a folder of PNGs")
    p.add_argument("--backend", choices=("torch", "onnx"), default="torch", help="network runtime (default torch)")
    p.add_argument("--out", help="output folder (PNG frames: required to save results; presses: default PRESS/)")
    p.add_argument("--ply", action="store_true", help="also write a PLY point cloud per frame")
    p.add_argument("--mesh", action="store_true", help="PLY with grid triangles (implies --ply)")
    p.add_argument("--no-depth", action="store_true", help="normals only (skip the integration)")
    p.add_argument("--threads", type=int, default=0, help="CPU threads for the network (0: default)")
    p.set_defaults(func=run)


def run(args) -> int:
    import time

    import numpy as np

    from ..learn.infer import Predictor

    t_start = time.perf_counter()
    predictor = Predictor(args.model, backend=args.backend, threads=args.threads, depth=not args.no_depth)
    frames = list(_frames(args.inputs))
    inner, n = [], 0
    for name, load, press_folder in frames:
        frame_linear = load(predictor)
        result = predictor.predict(frame_linear)
        inner.append(result.seconds["total"])
        n += 1
        _save(args, predictor, result, name, press_folder)
    wall = time.perf_counter() - t_start
    med = float(np.median(inner))
    print(
        f"{n} frame(s), {predictor.backend}, net {'-'.join(map(str, predictor.model.hidden))}: "
        f"median {med * 1000:.1f} ms/frame = {1 / med:.1f} frames/s (normals{'' if args.no_depth else ' + depth'}); "
        f"whole command {wall:.1f} s"
    )
    return 0


def _frames(inputs):
    """(name, loader(predictor) -> linear frame, press folder or None) for every input, in order."""
    from pathlib import Path

    from ..core.capture import find_presses, is_press_folder
    from ..errors import CaptureError

    for item in inputs:
        path = Path(item)
        if path.is_file():
            yield path.stem, _png_loader(path), None
        elif path.is_dir() and (is_press_folder(path) or find_presses(path)):
            for folder in find_presses(path):
                yield folder.name, _press_loader(folder), folder
        elif path.is_dir():
            pngs = sorted(path.glob("*.png"))
            if not pngs:
                raise CaptureError(f"{path}: no press folders and no .png frames in it")
            for png in pngs:
                yield png.stem, _png_loader(png), None
        else:
            raise CaptureError(f"{path}: no such file or folder")


def _png_loader(path):
    def load(predictor):
        from ..core.imageio import read_png16
        from ..errors import CaptureError

        img = read_png16(path)
        if img.ndim != 3:
            raise CaptureError(f"{path}: a tri-colour frame must have 3 colour channels")
        return predictor.linear(img, path)

    return load


def _press_loader(folder):
    def load(predictor):
        from ..learn.infer import load_tricolor
        from ..learn.sensor import check_sensor

        frame, sensor = load_tricolor(folder)
        check_sensor(predictor.model.sensor, sensor, folder)
        return frame

    return load


def _save(args, predictor, result, name, press_folder) -> None:
    from pathlib import Path

    from ..core.reconstruction import save_reconstruction
    from ..learn.infer import RESULT_DIR, to_reconstruction
    from ..learn.ply import write_ply

    if press_folder is not None:
        folder = Path(args.out) / name / RESULT_DIR if args.out else press_folder / RESULT_DIR
    elif args.out:
        folder = Path(args.out) / name
    else:
        return  # a stream of frames without --out: only the frame rate is reported
    save_reconstruction(to_reconstruction(result, predictor, name), folder, overwrite=True)
    if args.ply or args.mesh:
        write_ply(folder / "points.ply", result.points, result.normals, mesh=args.mesh)
