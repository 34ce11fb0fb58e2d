"""``nlips calibrate-camera IMAGES...``: camera intrinsics and lens distortion from checkerboard images."""

from __future__ import annotations

import argparse
from collections.abc import Iterable

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm")


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "calibrate-camera",
        help="camera intrinsics and distortion (fisheye or standard) from checkerboard images -> camera JSON",
        description="Calibrate the sensor's camera from images of a printed checkerboard (or a ChArUco board, "
        "--charuco, whose partial views count) held at several tilts: writes the camera JSON (docs/formats.md) "
        "that `nlips capture --camera-calibration` puts into every press. Prints the reprojection error and warns "
        "when it is high or when the views do not pin the camera down.",
    )
    p.add_argument("images", nargs="+", help="checkerboard images, or folders of them")
    p.add_argument(
        "--pattern", required=True, help="checkerboard: inner corners COLUMNSxROWS (9x7 squares: 8x6); ChArUco: squares"
    )
    p.add_argument("--square", type=float, required=True, help="side of one square, mm")
    p.add_argument("--charuco", type=float, metavar="MARKER_MM", help="a ChArUco board with markers of this side, mm")
    p.add_argument("--dictionary", default="DICT_4X4_50", help="ChArUco ArUco dictionary (default DICT_4X4_50)")
    p.add_argument("--model", default="fisheye", choices=("fisheye", "brown"), help="lens model (default fisheye)")
    p.add_argument("--out", required=True, help="camera JSON to write (use with `nlips capture --camera-calibration`)")
    p.set_defaults(func=run)


def _pattern(text: str) -> tuple[int, int]:
    from ..core.errors import ConfigError

    try:
        cols, rows = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--pattern must look like 8x6 (inner corners), got {text!r}") from None
    if cols < 3 or rows < 3:
        raise ConfigError(f"--pattern needs at least 3x3 inner corners, got {text!r}")
    return cols, rows


def _image_paths(items: Iterable[str]) -> list:
    from pathlib import Path

    from ..core.errors import CaptureError

    paths = []
    for item in map(Path, items):
        if item.is_dir():
            found = sorted(p for p in item.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
            if not found:
                raise CaptureError(f"{item}: no images ({', '.join(sorted(IMAGE_SUFFIXES))}) in this folder")
            paths += found
        elif item.is_file():
            paths.append(item)
        else:
            raise CaptureError(f"{item}: no such image or folder")
    # one image given twice (a folder and a file of it, the same folder twice) would count its view twice
    return list({p.resolve(): p for p in paths}.values())


def run(args: argparse.Namespace) -> int:
    import logging
    from pathlib import Path

    from ..core.atomic import write_json
    from ..core.errors import ConfigError
    from ..core.tolerances import CAMERA_CAL_HIGH_RMS_PX
    from ..device.camera_calibration import Target, calibrate_images
    from ..progress import print_result, say

    log = logging.getLogger(__name__)

    from .folders import names_a_folder

    if names_a_folder(args.out):
        example = Path(args.out) / "camera.json"
        raise ConfigError(f"--out {args.out}: a folder; give the JSON file to write (e.g. {example})")
    if not args.square > 0:
        raise ConfigError(f"--square must be > 0 mm, got {args.square}")
    target = Target(_pattern(args.pattern), args.square, args.charuco, args.dictionary)
    cal = calibrate_images(_image_paths(args.images), target, args.model)
    for name, err in zip(cal.used, cal.per_view_px):
        say(f"{name}: {err:.3f} px")
    for name in cal.rejected:
        say(f"{name}: board not found (skipped)")
    c = cal.camera
    say(
        f"{c.model} camera {c.width}x{c.height}: fx {c.fx:.2f} fy {c.fy:.2f} cx {c.cx:.2f} cy {c.cy:.2f} "
        f"dist {', '.join(f'{d:.4g}' for d in c.dist)}"  # every digit is in the JSON file
    )
    say(f"reprojection error (RMS over {len(cal.used)} views): {cal.rms_px:.3f} px")
    if cal.rms_px > CAMERA_CAL_HIGH_RMS_PX:
        worst = max(zip(cal.per_view_px, cal.used))[1]
        log.warning(
            "the reprojection error %.2f px is high (a good calibration is below %g px): check --pattern and "
            "--square, that the board is flat and sharp in every image, and the lens model (--model); worst view: %s",
            cal.rms_px,
            CAMERA_CAL_HIGH_RMS_PX,
            worst,
        )
    write_json(args.out, cal.to_dict())
    print_result(args.out)  # stdout: the camera file alone (scripts); the fit's figures on stderr
    say(f"written {args.out}")
    return 0
