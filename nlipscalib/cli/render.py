"""``nlips render``: render one press (or the undeformed dome) of a scene into a press folder."""

from __future__ import annotations

import argparse
import contextlib
import logging
import re
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # named in hints only: the twin (Mitsuba) is imported when a press is rendered
    from pathlib import Path

    from ..sim.indent import PressConfig
    from ..sim.scene import SceneConfig

log = logging.getLogger(__name__)
DEFAULT_PRESS = {"indenter": "sphere", "polar_deg": 20.0, "azimuth_deg": 0.0, "spin_deg": 0.0, "depth": 1.0}
"""The press rendered when no indenter, pose or press file is given: a sphere 1 mm deep, 20 deg off the apex."""


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "render",
        help="render one press of the digital twin into a press folder",
        description="Render one press (or, with --undeformed, the undeformed dome) of a scene with the digital "
        "twin into a press folder (docs/formats.md): the dark frame, one image per LED, the tri-colour image and "
        "the per-pixel ground truth. Press options not typed come from --press-file, else from the default press "
        "(a 6 mm sphere 1 mm deep at polar 20 deg, azimuth 0); render and image options not typed come from the "
        "scene file (nlipstac: 640x480, 4 spp, direct light). Re-running with the same options does nothing (a press "
        "rendered by other twin code or another Mitsuba is kept, with a warning; --overwrite renders it again).",
    )
    p.add_argument("--scene", default=None, help="scene file or shipped scene name (default: nlipstac)")
    p.add_argument(
        "--indenter",
        default=None,
        help="indenter kind: sphere (default), cube, cylinder, cone, screw, coin, cap, gear, key, brick or mesh",
    )
    p.add_argument("--size", type=float, default=None, help="indenter size, mm (diameter, side or length; default 6)")
    p.add_argument(
        "--orientation",
        default=None,
        help="which side meets the gel: cube face/edge/corner, cylinder end/side, screw side/end, coin face/side, "
        "cap side/face, gear face/side, key face/side (default: the kind's first)",
    )
    p.add_argument(
        "--mesh",
        default=None,
        help="STL/OBJ/PLY file of your own indenter (implies --indenter mesh; in millimetres, scaled to --size "
        "unless the press file sets scale_to_size = false)",
    )
    p.add_argument("--polar", type=float, default=None, help="press direction from the apex, degrees (default 20)")
    p.add_argument("--azimuth", type=float, default=None, help="press direction around the axis, degrees (default 0)")
    p.add_argument(
        "--spin", type=float, default=None, help="indenter rotation about the press axis, degrees (default 0)"
    )
    p.add_argument("--depth", type=float, default=None, help="indentation depth, mm (default 1)")
    p.add_argument("--press-file", default=None, help="TOML/YAML press spec (indenter, polar_deg, ...)")
    p.add_argument("--undeformed", action="store_true", help="render the undeformed dome (LED calibration)")
    p.add_argument(
        "--spp", type=int, default=None, help="samples per pixel (default: the scene's [render] spp; nlipstac 4)"
    )
    p.add_argument(
        "--bounces",
        type=int,
        default=None,
        help="interreflection bounces, 0 = direct light (default: the scene's; nlipstac 0)",
    )
    p.add_argument(
        "--variant",
        default=None,
        help="Mitsuba variant: auto, llvm_ad_rgb, scalar_rgb or cuda_ad_rgb (default: the scene's; nlipstac auto)",
    )
    p.add_argument(
        "--threads", type=int, default=None, help="render threads, 0 = all cores (default: the scene's; nlipstac 0)"
    )
    p.add_argument(
        "--seed",
        type=int,
        default=None,
        help="render and noise seed (default: derived from the scene seed and the press)",
    )
    p.add_argument("--width", type=int, default=None, help="image width, pixels (default: the scene's; nlipstac 640)")
    p.add_argument("--height", type=int, default=None, help="image height, pixels (default: the scene's; nlipstac 480)")
    p.add_argument(
        "--bayer",
        default=None,
        choices=("none", "RGGB", "BGGR", "GRBG", "GBRG"),
        help="a Bayer camera's colour filter pattern from the top-left pixel: every frame mosaiced and demosaiced "
        "by OpenCV as a webcam delivers it (default: the scene's [camera_effects] bayer; nlipstac none)",
    )
    p.add_argument(
        "--demosaic",
        default=None,
        choices=("edge_aware", "bilinear"),
        help="the Bayer camera's demosaicing (default: the scene's; edge_aware, like a webcam's processor)",
    )
    p.add_argument(
        "--crosstalk",
        default=None,
        choices=("typical", "identity"),
        help="the camera filters' colour crosstalk: a typical webcam sensor's (5-15 %% of the neighbouring colours) "
        "or none (default: the scene's [camera_effects] crosstalk; nlipstac none)",
    )
    p.add_argument("--out", required=True, help="press folder to write")
    p.add_argument("--overwrite", action="store_true", help="replace an existing press folder")
    p.set_defaults(func=run)


ARG_MINIMA = {"spp": 1, "bounces": 0, "threads": 0, "seed": 0, "width": 8, "height": 8}
"""Smallest value of each integer option (checked before anything is loaded or rendered)."""
PRESS_OPTIONS = ("indenter", "size", "orientation", "mesh", "polar", "azimuth", "spin", "depth", "press_file")
"""Options that describe the press: --undeformed renders none, so they do not apply to it."""


def _check_args(args: argparse.Namespace) -> None:
    import math

    from ..core.config import check_count, check_range
    from ..core.errors import ConfigError

    if args.undeformed:
        given = [name for name in PRESS_OPTIONS if getattr(args, name) is not None]
        if given:
            flag = "--" + given[0].replace("_", "-")
            raise ConfigError(f"{flag} is not used with --undeformed: the undeformed dome has no press; drop {flag}")
    for name, minimum in ARG_MINIMA.items():
        if getattr(args, name) is not None:
            check_count(f"--{name}", getattr(args, name), minimum=minimum)
    if args.polar is not None:
        from ..sim.indent import check_polar

        check_polar("--polar", args.polar)
    if args.size is not None:
        check_range("--size", args.size, 0.0, open_lo=True)
    for name in ("azimuth", "spin"):
        value = getattr(args, name)
        if value is not None and not math.isfinite(value):
            raise ConfigError(f"--{name}: must be a finite angle in degrees, got {value}")
    if args.mesh and args.indenter not in (None, "mesh"):
        raise ConfigError(f"--mesh is for --indenter mesh, not --indenter {args.indenter}: drop one of them")


def _scene(args: argparse.Namespace) -> SceneConfig:
    from ..sim.scene import load_scene
    from .options import check_size_pair

    _check_args(args)
    scene = load_scene(args.scene)
    render = {k: getattr(args, k) for k in ("spp", "bounces", "variant", "threads", "seed")}
    camera = {"width": args.width, "height": args.height}
    with _scene_keys_as_flags():
        changed = scene.replace(
            render={k: v for k, v in render.items() if v is not None},
            camera={k: v for k, v in camera.items() if v is not None},
            camera_effects=_camera_effects(args),
        )
    check_size_pair(args.width, args.height, (scene.camera.width, scene.camera.height))  # after the ranges
    return changed


def _camera_effects(args: argparse.Namespace) -> dict:
    """The scene's ``[camera_effects]`` fields that --bayer, --demosaic and --crosstalk change."""
    from ..sim.bayer import IDENTITY_CROSSTALK, TYPICAL_CROSSTALK

    changes = {k: getattr(args, k) for k in ("bayer", "demosaic") if getattr(args, k) is not None}
    if args.crosstalk is not None:
        changes["crosstalk"] = TYPICAL_CROSSTALK if args.crosstalk == "typical" else IDENTITY_CROSSTALK
    return changes


@contextlib.contextmanager
def _scene_keys_as_flags():
    """A typed value the scene refuses is named by its flag (``--width``), not by its scene key.

    Why: the scene file itself was checked when it loaded, so what ``scene.replace`` refuses is a value from the
    command line, and ``scene.camera: width: ...`` names a key the user never wrote.
    """
    from ..core.errors import ConfigError

    try:
        yield
    except ConfigError as exc:
        found = re.fullmatch(r"scene\.(?:camera|render): (\w+):? (.*)", str(exc), re.DOTALL)
        if found is None:
            raise
        raise ConfigError(f"--{found[1]}: {found[2]}") from None


def _check_depth(where: str, depth: float, scene: SceneConfig) -> None:
    """The press depth within (0, gel thickness], checked before the render starts (and its INFO line).

    Parameters
    ----------
    where : str
        What set the depth, for the message (``--depth``, or the press file).
    depth : float
        Indentation depth, mm.
    scene : SceneConfig
        The scene rendered: its gel thickness is the deepest press.
    """
    from ..core.errors import ConfigError

    thickness = scene.dome.thickness
    if not 0 < depth <= thickness:
        raise ConfigError(
            f"{where}: must be in (0, {thickness:g}] mm (the scene's gel is {thickness:g} mm thick), got {depth:g}"
        )


def _press(args: argparse.Namespace) -> PressConfig:
    from pathlib import Path

    from ..core.config import from_mapping, read_config_file
    from ..core.errors import ConfigError
    from ..sim.indent import PressConfig
    from ..sim.indenters import with_mesh_beside

    data = dict(DEFAULT_PRESS)
    if args.press_file:
        data |= read_config_file(args.press_file)
    pose = {"polar_deg": args.polar, "azimuth_deg": args.azimuth, "spin_deg": args.spin, "depth": args.depth}
    data |= {k: v for k, v in pose.items() if v is not None}
    if isinstance(data.get("indenter"), str):
        data["indenter"] = {"kind": data["indenter"]}
    indenter = {"kind": args.indenter or ("mesh" if args.mesh else None), "size": args.size}
    indenter |= {"orientation": args.orientation, "mesh": args.mesh}
    if indenter["kind"] and isinstance(data.get("indenter"), dict) and data["indenter"].get("kind") != indenter["kind"]:
        data["indenter"] = {}  # another kind from the command line: the press file's indenter fields do not apply
    if isinstance(data.get("indenter"), dict):
        data["indenter"] = data["indenter"] | {k: v for k, v in indenter.items() if v is not None}
        if args.press_file and not args.mesh:
            data["indenter"] = with_mesh_beside(data["indenter"], Path(args.press_file).parent)
    try:
        return from_mapping(PressConfig, data, args.press_file or "press")
    except TypeError as exc:
        raise ConfigError(f"press: {exc}") from None
    except ConfigError as exc:  # a typed word named by its flag, not by the key it sets ("press.indenter.kind")
        if mesh := re.search(r"indenter mesh .*", str(exc)):  # names its file itself (IndenterConfig checks it)
            raise ConfigError(_mesh_problem(mesh[0], args, data.get("indenter"))) from None
        found = None if args.press_file else re.fullmatch(r"press\.indenter\.(kind|orientation): (.*)", str(exc))
        if found is None:
            raise
        raise ConfigError(f"{INDENTER_FLAGS[found[1]]}: {found[2]}") from None


def _mesh_problem(problem: str, args: argparse.Namespace, indenter: object) -> str:
    """The line for a mesh file that cannot be used (``problem``, IndenterConfig's "indenter mesh M: ..."), naming
    the press file that gave it, and where a relative path was looked for (``sim.indenters.with_mesh_beside``:
    from the working directory, then beside the press file).

    Why: a press file naming a mesh that was not there said only "indenter mesh shapes/pyramid.stl: no such file",
    neither the press file nor that the path is read beside it (s36-apileft)."""
    from pathlib import Path

    if not args.press_file or args.mesh or not isinstance(indenter, dict):  # --mesh: the flag's path, as typed
        return problem
    problem = problem.replace("--mesh takes a path", "the press file's mesh takes a path")
    written = Path(str(indenter.get("mesh"))).expanduser()
    if written.is_absolute():
        return f"{args.press_file}: {problem}"
    beside = Path(args.press_file).parent / written
    return (
        f"{args.press_file}: {problem}; a relative path is looked for from the working directory "
        f"({written.resolve()}), then beside the press file ({beside})"
    )


INDENTER_FLAGS = {"kind": "--indenter", "orientation": "--orientation"}
"""The flag that sets each indenter key a mistyped word is refused for."""


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from ..core.atomic import check_writable
    from ..core.press_folders import check_render_out
    from ..progress import print_result, say, working
    from ..sim.dataset_folder import missing_files
    from ..sim.press import render_press

    scene = _scene(args)
    if args.depth is not None:
        _check_depth("--depth", args.depth, scene)
    press = None if args.undeformed else _press(args)
    if press is not None and args.depth is None:  # a press file's depth
        _check_depth(f"{args.press_file or 'press'}: depth", press.depth, scene)
    if press is not None and press.indenter.kind == "mesh":
        from ..sim.indenters import make_indenter

        make_indenter(press.indenter)  # a missing or unreadable mesh is named now, not taken for an edited one
    out = Path(args.out)
    check_render_out(out, args.overwrite, flag=True)
    if not args.overwrite and _up_to_date(out, scene, press, args.seed):
        print_result(out)  # stdout: the press folder alone, done before or now (scripts); the how on stderr
        say(f"{out}: already rendered from this scene and press, nothing to do")
        return 0
    try:
        check_writable(out.parent, longest_name=len(out.name))  # before the render, not after it
    except OSError as exc:  # named by the folder asked for, not by the probe's name (romnt/xxxxxxx)
        raise type(exc)(exc.errno, exc.strerror or str(exc), str(out)) from None
    what = "undeformed dome" if press is None else "press"
    # the light said too: a direct-light press and a one-bounce calibration differ by 31 % (infer warns of it later)
    bounces = scene.render.bounces
    light = "direct light" if bounces == 0 else f"{bounces} bounce{'s' if bounces > 1 else ''}"
    try:
        with working(f"rendering {what} ({scene.camera.width}x{scene.camera.height}, spp {scene.render.spp}, {light})"):
            replace = args.overwrite or (out.is_dir() and bool(missing_files(out)))  # a torn press: _up_to_date
            path = render_press(scene, press, out, seed=args.seed, overwrite=replace)
    except FileExistsError:
        # another run published the folder meanwhile: its very render is done, as a run after it would say
        if args.overwrite or not out.is_dir() or not _up_to_date(out, scene, press, args.seed):
            raise
        print_result(out)
        say(f"{out}: already rendered from this scene and press (by another run meanwhile), nothing to do")
        return 0
    print_result(path)
    say(f"rendered {what} to {path}")
    return 0


def _press_or_dome(provenance: dict | None, press: PressConfig | None) -> str:
    """ "a coin of 6 mm pressed 1.00 mm deep -> the undeformed dome" where the folder's render (its meta.json's
    ``provenance``) and this one are a press and the undeformed dome; "" otherwise. Why: the settings' difference
    printed the whole press description against None, a Python dict of nine fields."""
    from ..core.config import to_mapping
    from .folders import pressed_words

    if not isinstance(provenance, dict) or "press" not in provenance:
        return ""
    was = provenance["press"]
    if (was is None) == (press is None) or not (was is None or isinstance(was, dict)):
        return ""
    dome = "the undeformed dome"
    now = dome if press is None else pressed_words(to_mapping(press))
    return f"{dome if was is None else pressed_words(was)} -> {now}"


def _up_to_date(out: Path, scene: SceneConfig, press: PressConfig | None, seed: int | None) -> bool:
    """True when ``out`` holds this very render; an existing folder from another spec is an error."""
    import json

    from ..core.errors import ConfigError
    from ..core.file_checks import file_problem
    from ..core.press_folders import is_press_folder
    from ..sim.dataset_folder import spec_change
    from ..sim.press import recorded_spec_hash, render_spec_hash

    if not out.exists():
        return False
    if not is_press_folder(out):
        raise ConfigError(f"{out}: exists and is not a press folder; choose another --out or use --overwrite")
    if problem := file_problem(out / "meta.json"):
        # a power cut (writes are atomic, not synced) or a copy cut short: nothing records what the folder was
        # rendered from, so it is neither this render nor another one (which the next error would have claimed)
        raise ConfigError(
            f"{out}: its meta.json is {problem}, so what it was rendered from is unknown; "
            "use --overwrite to render it again, or another --out"
        )
    try:
        provenance = json.loads((out / "meta.json").read_text(encoding="utf-8"))["provenance"]
        recorded = recorded_spec_hash(provenance)
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        provenance, recorded = None, None
    if recorded != render_spec_hash(scene, press, seed):
        mesh = press.indenter.mesh if press is not None and press.indenter.kind == "mesh" else None
        edited = f" (or from another version of {mesh}: the mesh file's content counts)" if mesh else ""
        why = _press_or_dome(provenance, press) or spec_change(scene, press, seed, out)
        raise ConfigError(
            f"{out}: already holds a press rendered from a different scene, press or seed{edited}"
            f"{f' ({why})' if why else ''}; "
            "use --overwrite to replace it, or another --out"
        )
    if _torn_files(out):
        return False
    _warn_other_renderer(out)
    return True


def _torn_files(out: Path) -> dict[str, str]:
    """Files of the press in ``out`` that are gone, empty, cut short or changed in size since it was written
    (sim.dataset_folder.missing_files), each with its problem, said in a warning: the press is then rendered again
    in place of them.

    Why: writes are atomic but not synced, so a power cut soon after a render was published can leave a file empty
    or cut short; "already rendered ..., nothing to do" kept it at every run, and the solve failed on it."""
    from ..sim.dataset_folder import described_missing, missing_files

    torn = missing_files(out)
    if torn:
        log.warning("%s: %s; rendering it again", out, described_missing(torn))
    return torn


def _warn_other_renderer(out: Path) -> None:
    """Warn that the press kept in ``out`` was rendered by other twin code or render libraries than this
    installation's, as ``nlips dataset`` does (:func:`nlipscalib.sim.dataset_folder.check_existing`).

    Why: the press spec alone was compared, so after an upgrade of Mitsuba or of sim/ the old images were kept
    without a word. Kept, not re-rendered: a script re-running its renders must not spend minutes a press on
    each upgrade; ``--overwrite`` renders it again."""
    from ..sim.dataset_folder import render_difference, rendered_elsewhere_in

    if rendered_elsewhere_in(out):
        log.warning(
            "%s: rendered by other twin code or render libraries (%s); kept: --overwrite renders it again",
            out,
            render_difference(out),
        )
