"""``nlips calibrate-leds PRESS...``: LED parameters from captures of the undeformed dome -> LED JSON file."""

from __future__ import annotations

import argparse
import contextlib
import logging
import time
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.shell_words import shell_word
from .options import add_allow_edited

if TYPE_CHECKING:  # named in hints only: the solver is imported when the fit runs
    from ..solver import LedCalibration

log = logging.getLogger(__name__)


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "calibrate-leds",
        help="fit each LED's position, axis, brightness and spread (Psi, mu, n_s, x_s) to undeformed-dome captures "
        "-> LED JSON",
        description="LED self-calibration: each LED's intensity Psi (per colour), emission exponent mu, axis n_s "
        "and position x_s, fitted to captures of the undeformed dome (its known shape, reference.npz) minus the "
        "dome's own interreflection where they show it, written as an LED file (docs/formats.md) for "
        "`nlips solve --leds FILE` or `nlips calibrate --leds FILE` (NLiPsNet's labels); where the capture's sensor "
        "design declares its LEDs' emitting diameter (leds.emitter_diameter: the shipped designs' 3.6 mm), each LED "
        "also as a disk of that size (--led-diameter overrides; 0: points only). Prints the LEDs with their "
        "1-sigma uncertainties and how well the fit explains the images; warns when it is unreliable (render the "
        "reference at 16 spp or more, or average more frames), and names a single LED not to be trusted (far off its "
        "design, blocked or dim: check it).",
    )
    p.add_argument("presses", nargs="+", help="press folders of the undeformed dome (with reference.npz)")
    p.add_argument(
        "--out",
        required=True,
        help="LED JSON file to write (use with `nlips solve --leds FILE` or `nlips calibrate --leds FILE`)",
    )
    p.add_argument(
        "--stride",
        type=int,
        default=None,
        help="use every N-th pixel in u and v (default: 2 up to 640x480; on larger frames the stride that keeps as "
        "many pixels, e.g. 3 at 1280x720, 4 at 1280x960)",
    )
    p.add_argument(
        "--loss",
        default="cauchy",
        choices=("cauchy", "soft_l1", "huber", "linear"),
        help="robust loss of the least-squares fit (default cauchy; linear: plain least squares)",
    )
    p.add_argument(
        "--interreflection",
        choices=("auto", "on", "off"),
        default="auto",
        help="fit the LEDs to the images minus the dome's own diffuse interreflection: auto (used when its "
        "share of the light is >= 0.1 with the starting LEDs, or when the LEDs alone leave more than the images' "
        "noise and the term does not; default), on, off",
    )
    p.add_argument("--bounces", type=int, choices=(1, 2), default=1, help="diffuse bounces modelled (default 1)")
    p.add_argument(
        "--led-diameter",
        type=float,
        default=None,
        metavar="MM",
        help="diameter of each LED's light-emitting area, mm (WS2812B: 3.6): also fit the LEDs as such disks, "
        "the physical LEDs to compare with the CAD (written as 'emitters'; solves take them with --led-model "
        "disks, and by default where the design's own LEDs are solved as disks: the flat pad, oblate, capsule; else "
        "the point LEDs). "
        "Default: the capture's sensor design's leds.emitter_diameter (the shipped designs: 3.6), point LEDs only "
        "where it declares none; 0: point LEDs only",
    )
    p.add_argument(
        "--coating-reflectance",
        type=float,
        default=None,
        metavar="A",
        help="the coating's diffuse reflectance 0-1 when known (measured or from its datasheet). It fixes the "
        "interreflection term's magnitude, which the LED axes otherwise trade against; default: fitted, and with "
        "LED disks (the design's size or --led-diameter) chosen where the disk fit leaves the least residual",
    )
    p.add_argument(
        "--allow-contact",
        action="store_true",
        help="calibrate on a capture that shows a press after all, its contact's pixels left out of the fit (with a "
        "warning); default: such a capture is refused, as it is not the undeformed dome",
    )
    p.add_argument(
        "--keep-led-order",
        dest="reorder_leds",
        action="store_false",
        help="fit LED images that show other LEDs' light (a wiring error: two swapped, or a cycle) in the order "
        "captured; by default they are fitted in the order they show, with a warning and the file's led_order. "
        "Neighbours' images exchanged (each LED fitted at the other's design place, which the images alone do not "
        "tell) are refused by default, naming both images (warned of, not refused, where the other LEDs scatter too "
        "far about their design places to be sure: LEDs designed closer than ~5 times that); with this flag "
        "calibrated as captured, with a warning",
    )
    p.add_argument(
        "--previous",
        metavar="OLD_LEDS.json",
        help="an earlier LED file of this sensor: say which LEDs or tri-colour groups changed brightness (aged, "
        "replaced), whether all LEDs dimmed or brightened alike (or the exposure changed), or moved since, one warning "
        "line each, in the table and in the new file ('previous'); what only one of the files holds (an older file's "
        "missing light_level, disks in one) is said as not compared; a file of another sensor is refused. It may be "
        "the --out file itself (read before it is replaced)",
    )
    add_allow_edited(p, "calibrate on")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..core.atomic import check_writable
    from ..core.config import check_count
    from ..core.errors import ConfigError
    from ..core.sensor import MAX_EMITTER_DIAMETER_MM
    from .folders import check_one_capture, check_undeformed

    if args.stride is not None:
        check_count("--stride", args.stride, minimum=1)
    if args.coating_reflectance is not None and not 0 < args.coating_reflectance <= 1:
        raise ConfigError(f"--coating-reflectance must be in (0, 1], got {args.coating_reflectance}")
    if args.led_diameter is not None and not 0 <= args.led_diameter <= MAX_EMITTER_DIAMETER_MM:
        raise ConfigError(f"--led-diameter must be 0-{MAX_EMITTER_DIAMETER_MM:g} mm, got {args.led_diameter}")
    from .folders import names_a_folder

    if names_a_folder(args.out):  # found after the fit as "OUT -> OUT: Is a directory"
        example = Path(args.out) / "leds.json"
        raise ConfigError(f"--out {args.out}: a folder; give the LED file to write (e.g. {example})")
    check_writable(Path(args.out).parent)  # a file in its place or a read-only disk: before the fit, not after it
    if args.previous is not None:  # a bad file: one line before the fit
        from ..core.errors import CaptureError
        from ..core.ledfile import read_led_file

        try:
            args.previous_file = read_led_file(args.previous)
        except CaptureError as exc:  # the line names the file; say which option gave it
            raise CaptureError(f"--previous {exc}") from None
    for folder in args.presses:
        check_one_capture(folder, "a capture of the undeformed dome")
        if not args.allow_contact:
            check_undeformed(folder, "a capture of the undeformed dome", "or pass --allow-contact to fit on it anyway")
    if not args.allow_edited:  # a file copied over one: one line now, not LEDs fitted to the wrong image
        from ..core.press_checksums import check_unchanged

        check_unchanged(args.presses, remedy="copy or capture it again")
    with _fit_held(Path(args.out), _fit_key(args)) as done_by:
        if done_by is not None:
            from ..progress import print_result, say

            print_result(args.out)  # stdout: the LED file alone (scripts); whose it is on stderr
            say(
                f"{args.out}: written by {done_by} meanwhile, from the same captures and options (its table is "
                "that run's); nothing to do"
            )
            return 0
        return _fit_and_write(args)


FIT_KEY_OPTIONS = (
    "stride",
    "loss",
    "interreflection",
    "bounces",
    "led_diameter",
    "coating_reflectance",
    "allow_contact",
    "reorder_leds",
    "previous",
)
"""The options of ``nlips calibrate-leds`` that decide its LED file (with the captures): runs into one --out that
agree on them and on the captures fit the same file (:func:`_fit_held`)."""


def _fit_key(args: argparse.Namespace) -> str:
    """What tells one fit from another for runs at once: the captures (their folders, resolved) and
    :data:`FIT_KEY_OPTIONS`, hashed (16 hex digits). Folders, not contents: it is compared between runs under way at
    the same time, which read the same files."""
    import hashlib
    import json

    fit = {"presses": [str(Path(p).resolve()) for p in args.presses]}
    fit |= {name: getattr(args, name) for name in FIT_KEY_OPTIONS}
    return hashlib.sha256(json.dumps(fit, sort_keys=True).encode()).hexdigest()[:16]


FIT_POLL_S = 0.05
"""How often a run finding another's claim being written looks again, s (milliseconds: its owner writes it)."""


@contextlib.contextmanager
def _fit_held(out: Path, key: str) -> Iterator[str | None]:
    """Hold the LED file ``out`` (its claim, core.claims, noting ``key``) while the block fits and writes it; yields
    None. While another live run holds it: the same fit (``key``): wait for it, then yield who it was (in words)
    when it wrote the file meanwhile, or hold it and fit here when it did not (failed, killed); another fit: a
    ConfigError at once.

    Why: three runs at once into one --out each fitted the same LEDs and wrote the file in turn (whole each time,
    written atomically: the last one's was left), seconds of work done three times; a run of other captures or
    options replaced the other's file without a word. Now they behave as ``nlips train`` into one model: one fits,
    the others wait for it and say so; another fit into the file is refused. A folder that cannot hold a claim
    file (read-only media) is not held: the write says why."""
    from ..core.claims import claim, holder, wait_for_release
    from ..core.errors import ConfigError

    while True:
        before = _stamp(out)
        with contextlib.ExitStack() as held:
            try:
                mine = held.enter_context(claim(out, note={"key": key}))
            except OSError as exc:
                log.debug("%s: not claimed (%s)", out, exc.strerror or exc)
                mine = True
            if mine:
                yield None
                return
        other = holder(out)
        if other is None or other.note is None:  # released meanwhile, or its claim being written
            time.sleep(FIT_POLL_S)
            continue
        if other.note.get("key") != key:
            raise ConfigError(
                f"{out}: {other.who} is calibrating LEDs into it from other captures or options; wait until it "
                "ends, or write another --out file"
            )
        log.info("%s: %s is fitting the same LEDs (the same captures and options); waiting for it", out, other.who)
        wait_for_release(out)
        if _stamp(out) != before:
            yield other.who
            return


def _stamp(path: Path) -> tuple[int, int, int] | None:
    """(inode, mtime ns, size) of ``path``, None when there is none: a file written in its place changes it."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _fit_and_write(args: argparse.Namespace) -> int:
    """Load the captures, fit the LEDs, write ``args.out`` and print the table (:func:`run`, its file held)."""
    import numpy as np

    from ..core.atomic import check_free_space
    from ..core.capture import load_press
    from ..core.led_change import light_level
    from ..core.ledfile import led_file_bytes, save_leds
    from ..core.metrics import angle_deg
    from ..core.sensor_record import sensor_of
    from ..progress import print_result, say, track, working
    from ..solver import calibrate_leds

    presses = [load_press(f) for f in track(args.presses, desc="loading", unit="press")]
    if args.previous is not None:  # another sensor's earlier file: refused before the fit, not after it
        from ..core.led_change import check_previous_sensor

        check_previous_sensor(args.previous_file, args.previous, sensor_of(presses[0]), args.presses[0])
    led_model = _led_model(args.led_diameter, presses)
    log.info(led_model["said"])
    diameter = led_model["diameter_mm"]
    # a full disk, which the probe above passes (a folder takes no block on tmpfs), is found before the 1-2 s fit
    check_free_space(Path(args.out).parent, led_file_bytes(len(presses[0].leds), len(presses)), "the LED file")
    with working(f"calibrating {len(presses[0].leds)} LEDs from {len(presses)} capture(s)"):
        cal = calibrate_leds(
            presses,
            stride=args.stride,
            loss=args.loss,
            interreflection=args.interreflection,
            bounces=args.bounces,
            led_radius=diameter / 2,
            coating_reflectance=args.coating_reflectance,
            allow_contact=args.allow_contact,
            reorder_leds=args.reorder_leds,
        )
    # the sensor it was calibrated on: `nlips solve/calibrate --leds` refuse the file for a capture of another one
    record = {k: led_model[k] for k in ("fitted", "diameter_mm", "from")}
    # how bright the LEDs lit the gel: what a later --previous compares all LEDs' light by (the gauge hides it)
    extra = {"led_model": record, "sensor": sensor_of(presses[0]), "light_level": light_level(presses, cal.led_order)}
    previous = _compared(args, cal, extra["light_level"])
    if previous is not None:
        extra["previous"] = previous
    save_leds(args.out, cal.leds, cal.to_json() | extra)
    print_result(args.out)  # stdout: the LED file alone (scripts); the fit's table and the next step on stderr
    head = ("LED", "Psi R", "Psi G", "Psi B", "mu", "+-mu", "+-dir(deg)", "+-pos(mm)")
    widths = (3, 7, 7, 7, 6, 6, 10, 9)
    if previous is not None:  # each LED against the earlier file: its share of the light, and how far it moved
        head, widths = head + ("x prev", "moved(mm)", "turned(deg)"), widths + (7, 9, 11)
    say(" ".join(f"{h:>{w}}" for h, w in zip(head, widths)))
    for i, (led, sd) in enumerate(zip(cal.leds, cal.std)):
        r, g, b = led.intensity
        # an LED not fitted (its image a stale frame in every capture): its starting values, said in its warning
        spread = (
            f"{sd['mu']:>6.3f} {sd['direction_deg']:>10.3f} {max(sd['position_mm']):>9.4f}"
            if i not in cal.not_fitted
            else "  not fitted: starting values"
        )
        say(f"{i + 1:>3} {r:>7.3f} {g:>7.3f} {b:>7.3f} {led.mu:>6.3f} {spread}{_against_previous(previous, i)}")
    if cal.emitters:
        say(f"LEDs as {diameter:g} mm disks (the physical centre and axis, written as emitters):")
        for i, (disk, led) in enumerate(zip(cal.emitters, cal.leds)):
            if i in cal.not_fitted:
                say(f"{i + 1:>3} not fitted: its starting values")
                continue
            shift = np.subtract(led.position, disk.position)
            tilt = float(angle_deg(disk.direction, led.direction))
            along = float(shift @ np.asarray(disk.direction))
            say(
                f"{i + 1:>3} centre ({', '.join(f'{c:.3f}' for c in disk.position)}) mm; the point LED sits "
                f"{abs(along):.3f} mm {'behind' if along < 0 else 'in front of'} it, axes {tilt:.2f} deg apart"
            )
    if cal.reflectance_profile is not None:
        prof = cal.reflectance_profile
        say(
            f"coating reflectance from the images alone: {np.round(prof['chosen'], 3).tolist()} (least disk-fit "
            f"residual over {len(prof['scales'])} tries; the free fit gave {np.round(prof['fitted'], 3).tolist()})"
        )
    for i, model in enumerate(cal.interreflection):
        say(f"capture {i + 1}: {model.get('reason', '')}")
    say(_fit_line(cal.quality))
    if previous is not None:
        said = f"{len(previous['changes'])} change(s), warned above, also in the file's 'previous'"
        overall = previous["overall_brightness"]
        said = said if previous["changes"] else "no LED changed beyond the tolerances"
        together = "" if overall is None else f"all LEDs together x{overall:.3f}; "
        # what only one of the files holds (an OLD file written before light_level, disks in one): said, not implied
        missing = "; not compared: " + "; ".join(previous["not_compared"]) if previous["not_compared"] else ""
        say(f"against {args.previous}: {together}{said}{missing}")
    # the warnings were logged while calibrating, above the table: say so where the user looks last
    seen = f"; {len(cal.warnings)} warning(s) above, also in the file" if cal.warnings else ""
    albedo = ", ".join(f"{a:.4g}" for a in cal.albedo)  # the file keeps every digit; four say what it is
    say(f"written {args.out} (gauge: mean Psi = 1 per channel; albedo {albedo}){seen}")
    leds = shell_word(args.out)
    say(f"next: nlips solve PRESS --leds {leds}, or nlips calibrate FOLDER --leds {leds} (NLiPsNet's labels)")
    return 0


def _compared(args: argparse.Namespace, cal: LedCalibration, level: dict) -> dict | None:
    """With ``--previous``: the new calibration against the earlier file
    (:func:`nlipscalib.core.led_change.compare_calibrations`, ``level`` the new captures' light level), each change
    warned in one line; None without it."""
    if args.previous is None:
        return None
    from ..core.led_change import compare_calibrations

    previous = compare_calibrations(args.previous_file, args.previous, cal.leds, cal.not_fitted, level, cal.emitters)
    for line in previous["changes"]:
        log.warning("%s", line)
    return previous


def _against_previous(previous: dict | None, i: int) -> str:
    """LED ``i``'s columns against the earlier file (brightness ratio, moved, turned); blank where not compared."""
    if previous is None:
        return ""
    ratio, moved, turned = (previous[key][i] for key in ("brightness", "moved_mm", "turned_deg"))
    if ratio != ratio:  # NaN: not fitted here or there
        return f" {'-':>7} {'-':>9} {'-':>11}"
    return f" {ratio:>7.3f} {moved:>9.3f} {turned:>11.2f}"


def _led_model(given: float | None, presses: list) -> dict:
    """What the LEDs are fitted as: ``{"fitted": "disks" or "points", "diameter_mm", "from", "said"}``; ``said``: the
    INFO line. ``given``: ``--led-diameter`` (None: not typed), else the captures' design
    (:func:`nlipscalib.core.sensor.capture_led_diameter`); captures that declare different sizes are refused (one
    sensor's captures declare one).

    Why by default from the design: the twin's LEDs, and a WS2812B sensor's, are 3.6 mm disks 8-15 mm from the gel;
    fitted as points, a sensor built 2-3 mm / 15-25 deg off its design calibrates its worst LED 0.35 mm off, as disks
    0.2 mm (benchmarks/RESULTS.md, s29-ledsize), and the user had to know to pass ``--led-diameter``."""
    from ..core.errors import ConfigError
    from ..core.press_meta import META_FILE
    from ..core.sensor import capture_led_diameter

    if given is not None:
        diameter, source = float(given), "--led-diameter"
    else:
        found = [capture_led_diameter(p.meta, str(p.folder / META_FILE)) for p in presses]
        if len({d for d, _ in found}) > 1:
            sizes = ", ".join(f"{p.folder}: {d:g} mm" for p, (d, _) in zip(presses, found))
            raise ConfigError(f"the captures' designs declare different LED sizes ({sizes}): pass --led-diameter")
        diameter, source = found[0]
    if diameter > 0:
        said = f"LEDs fitted as {diameter:g} mm disks ({source}) and as the solver's points; --led-diameter 0: "
        said += "points only"
    else:
        why = "--led-diameter 0" if given is not None else source
        said = f"LEDs fitted as points ({why}); --led-diameter D also fits them as D mm disks (a WS2812B's: 3.6)"
    return {"fitted": "disks" if diameter > 0 else "points", "diameter_mm": diameter, "from": source, "said": said}


def _fit_line(q: dict) -> str:
    """The fit's quality in one line: the median ratio decides, and the worst LED is named beside it (one LED far
    off shows only there: the median of 12 hides it)."""
    import numpy as np

    ratio = np.asarray(q["ratio"], float)
    worst = int(np.nanargmax(ratio))
    return (
        f"fit: residual {q['median_ratio']:.2f}x the images' noise and the LED model's own error (median over the "
        f"LEDs; reliable up to {q['threshold']}; worst LED {worst + 1} {ratio[worst]:.2f}x): "
        f"{'reliable' if q['reliable'] else 'UNRELIABLE, see the warning'}"
    )
