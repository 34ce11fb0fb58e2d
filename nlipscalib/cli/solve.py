"""``nlips solve PRESS``: NLiPs reconstruction of a press (or a folder of presses), saved in PRESS/nlips/."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def register(subparsers) -> None:
    p = subparsers.add_parser("solve", help="reconstruct depth/normals of a press with near-light photometric stereo")
    p.add_argument("press", help="press folder, or a folder of press folders")
    p.add_argument("--roi", nargs="+", metavar="V", help="x0 y0 w h (pixels) or 'auto' (around the contact)")
    p.add_argument("--leds", help="LED subset '1,2,5' (1-based) or an LED JSON file from calibrate-leds")
    p.add_argument(
        "--reference",
        metavar="REF_PRESS",
        help="press folder of the undeformed dome (same camera, LEDs, exposure): the interreflection term is "
        "fitted on it (default: on the press itself, away from the contact) and --roi auto / anchoring compare to it",
    )
    p.add_argument(
        "--interreflection",
        choices=("auto", "on", "off"),
        default="auto",
        help="the gel's own diffuse interreflection in the image model: auto (applied when the data show "
        "indirect light; default), on, off",
    )
    p.add_argument("--bounces", type=int, choices=(1, 2), default=1, help="diffuse bounces modelled (default 1)")
    p.add_argument(
        "--dent-interreflection",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="re-solve with the indirect light of the solved surface until the normals settle (default on); "
        "off: only the undeformed surface's indirect light is subtracted",
    )
    p.add_argument(
        "--coating-albedo",
        type=float,
        default=None,
        metavar="A",
        help="override the coating's reflectance (0-1]; default: fitted from the data",
    )
    p.add_argument("--backend", choices=("numpy", "torch"), default="numpy")
    p.add_argument("--out", help="output folder (default PRESS/nlips); only for a single press")
    p.add_argument("--overwrite", action="store_true", help="recompute even if a result exists")
    p.add_argument("--config", help="TOML/YAML file with SolverOptions fields")
    p.set_defaults(func=run)


def parse_roi(values):
    from ..errors import ConfigError

    if not values:
        return None
    if values == ["auto"]:
        return "auto"
    try:
        roi = tuple(int(v) for v in values)
    except ValueError:
        roi = ()
    if len(roi) != 4:
        raise ConfigError(f"--roi needs 'x0 y0 w h' or 'auto', got {' '.join(values)}")
    return roi


def parse_leds(value):
    """(subset 0-based list or None, LED tuple from file or None)."""
    from ..errors import ConfigError
    from ..solver.io import load_leds

    if not value:
        return None, None
    if Path(value).suffix.lower() == ".json" or Path(value).is_file():
        return None, load_leds(value)
    try:
        return [int(v) - 1 for v in value.split(",")], None
    except ValueError:
        raise ConfigError(f"--leds must be like '1,2,5' or an LED .json file, got {value!r}") from None


def run(args) -> int:
    from tqdm import tqdm

    from ..config import from_mapping, read_config_file
    from ..core.capture import find_presses
    from ..core.reconstruction import has_reconstruction, reconstruction_dir
    from ..errors import ConfigError, NlipsError
    from ..solver import SolverOptions, save_result

    options = from_mapping(SolverOptions, read_config_file(args.config), args.config) if args.config else None
    roi = parse_roi(args.roi)
    subset, leds = parse_leds(args.leds)
    presses = find_presses(args.press)
    if not presses:
        raise ConfigError(f"{args.press}: no press folders found")
    if args.out and len(presses) > 1:
        raise ConfigError("--out only applies to a single press")
    if args.reference:  # the undeformed dome is the reference, not a press to solve
        presses = [p for p in presses if p.resolve() != Path(args.reference).resolve()]
    failed = []
    for folder in tqdm(presses, desc="presses", disable=len(presses) == 1):
        out = reconstruction_dir(folder, args.out)
        if has_reconstruction(out) and not args.overwrite:
            log.info("%s: result exists, skipped (use --overwrite)", out)
            continue
        try:
            press, result = _solve_one(folder, args, roi, subset, leds, options)
        except NlipsError as exc:
            if len(presses) == 1:
                raise
            failed.append(folder.name)  # one bad press must not stop a batch
            log.error("%s: %s", folder.name, exc)
            continue
        save_result(result, out, press.ground_truth, overwrite=True)
        rep = result.report
        log.info(
            "%s: %d/%d pixels reconstructed, %d with too few LEDs, dead LEDs %s, %.1f s -> %s",
            folder.name,
            rep["pixels_reconstructed"],
            rep["pixels_solved"],
            rep["pixels_too_few_leds"],
            [i + 1 for i in rep["dead_leds"]],
            rep["seconds"],
            out,
        )
    if failed:
        log.error("%d of %d presses failed: %s", len(failed), len(presses), ", ".join(failed))
    return 1 if failed else 0


def _solve_one(folder, args, roi, subset, leds, options):
    """Load one press (and the reference capture) and solve it; returns (press, result)."""
    from ..core.capture import load_press
    from ..errors import ConfigError
    from ..solver import solve_press

    press = load_press(folder, led_subset=subset)
    # the reference capture is reloaded per press: cheap, and keeps an LED subset consistent
    ref = load_press(args.reference, led_subset=subset) if args.reference else None
    if leds is not None and subset is None and len(leds) != len(press.leds):
        raise ConfigError(f"{args.leds}: {len(leds)} LEDs, but {folder} has {len(press.leds)}")
    result = solve_press(
        press,
        roi=roi,
        leds=leds,
        options=options,
        backend=args.backend,
        progress=True,
        indirect=ref,
        dent_interreflection=args.dent_interreflection,
        coating_albedo=args.coating_albedo,
        interreflection=getattr(args, "interreflection", "auto"),
        bounces=getattr(args, "bounces", 1),
    )
    return press, result
