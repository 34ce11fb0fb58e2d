"""Typed configs: frozen dataclasses filled from TOML or YAML with errors that name file and key.

Every config in the workbench (scenes, presses, dataset specs, solver options) is a frozen
dataclass whose fields carry a docstring; :func:`from_mapping` fills one from a plain dict and
checks unknown keys, missing keys and value types, so a typo such as ``raduis = 15`` fails with
``scene.toml: dome: unknown key 'raduis' (known: radius, height, ...)``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import math
import numbers
import tomllib
import types
import typing
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

from .errors import ConfigError

ConfigT = TypeVar("ConfigT")  # from_mapping returns an instance of the config class it is given


def read_config_file(path: str | Path) -> dict:
    """Parse a .toml, .yaml or .yml file into a dict; errors name the file."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: a folder, not a config file (.toml, .yaml)")
    if not path.is_file():
        raise ConfigError(f"{path}: no such config file")
    suffix = path.suffix.lower()
    try:
        if suffix == ".toml":
            with path.open("rb") as f:
                data = tomllib.load(f)
        elif suffix in (".yaml", ".yml"):
            import yaml

            data = yaml.safe_load(path.read_text(encoding="utf-8"))
            data = {} if data is None else data  # an empty (or comments-only) file, as an empty TOML file reads
        else:
            raise ConfigError(f"{path}: unknown config type '{suffix}' (use .toml, .yaml or .yml)")
    except ConfigError:
        raise
    except Exception as exc:  # tomllib / yaml parse errors
        raise ConfigError(f"{path}: cannot parse ({_parse_problem(exc)})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a table/mapping")
    return data


def _parse_problem(exc: Exception) -> str:
    """A parser's error on one line: YAML's spans several (the problem, a quote of the file, a caret)."""
    mark, problem = getattr(exc, "problem_mark", None), getattr(exc, "problem", None)
    if mark is not None and problem:
        return f"{problem} at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split())


def from_mapping(cls: type[ConfigT], data: Any, where: str = "") -> ConfigT:
    """Build dataclass ``cls`` from ``data``, recursively, validating keys and types.

    Parameters
    ----------
    cls : a dataclass type
    data : mapping of field name to value (nested dataclasses as nested mappings)
    where : location prefix for error messages, e.g. ``"scene.toml: dome"``
    """
    if isinstance(data, cls):
        return data
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table/mapping, got {type(data).__name__}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = set(data) - set(fields)
    if unknown:
        known = ", ".join(fields)
        (key,) = unknown if len(unknown) == 1 else ("",)  # one mistyped key: its close match ('raduis' -> 'radius')
        hint = _other_kind(unknown) or (did_you_mean(str(key), list(fields)) if key else "")
        raise ConfigError(f"{where}: unknown key(s) {sorted(unknown)}{hint} (known: {known})")
    kwargs = {}
    for name, field in fields.items():
        if name not in data:
            if field.default is dataclasses.MISSING and field.default_factory is dataclasses.MISSING:
                raise ConfigError(f"{where}: missing required key '{name}'")
            continue
        value = _over_default(field, data[name])
        kwargs[name] = _convert(hints[name], value, f"{where}.{name}" if where else name)
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


OTHER_FILE_KINDS = (
    ("a dataset spec? give it to `nlips dataset SPEC --out DIR`", frozenset({"grid", "random"})),
    ("a scene file? give it to `nlips render --scene FILE`", frozenset({"dome", "leds", "coating"})),
)
"""What a file is when the keys a config refuses include one of these (the words said, the keys that tell): the file
given is another command's. Why: `nlips solve PRESS --config spec.toml` (the dataset spec of the README's walk) said
only "unknown key(s) ['camera', 'random', ...]" and the solver's 40 options; `nlips render --scene spec.toml` alike."""


def _other_kind(unknown: set[str]) -> str:
    """ "; a dataset spec? give it to ..." when the refused keys tell another command's file, else ""."""
    return next((f"; {words}" for words, keys in OTHER_FILE_KINDS if unknown & keys), "")


def _over_default(field: dataclasses.Field, value: Any) -> Any:
    """A table given for a field whose default is a config (a dataclass instance): its keys over that default's.

    Why: a section sets what it names and keeps the rest of the *field's* default, not of its class; e.g. Q2's
    ``[train]`` with only ``indenters`` keeps Q2's 50 presses and seed (the class ``PressSet`` has 3), and
    ``[twin]`` with only ``spp`` keeps the experiment's 640x480 (the class ``TwinConfig`` has 320x240).
    """
    if field.default is not dataclasses.MISSING:
        default = field.default
    elif field.default_factory is not dataclasses.MISSING:
        default = field.default_factory()
    else:
        return value
    return _merged(default, value)


def _merged(default: Any, value: Any) -> Any:
    """``value`` (a mapping) over the fields of config instance ``default``, recursively; else ``value``."""
    if not isinstance(value, dict) or not dataclasses.is_dataclass(default) or isinstance(default, type):
        return value
    out = {f.name: getattr(default, f.name) for f in dataclasses.fields(default) if f.init}
    for key, given in value.items():
        out[key] = _merged(out[key], given) if key in out else given  # an unknown key is refused by from_mapping
    return out


OMIT_AT_DEFAULT = "omit_at_default"
"""Key of a config field's ``metadata`` (``dataclasses.field(default=..., metadata={OMIT_AT_DEFAULT: True})``): the
field is left out of :func:`to_mapping` while it holds its default. Why: a field added to a config that captures,
renders and experiments record and hash (a scene's, a design's) would otherwise change every record and hash made
before it existed, and re-render what is already rendered; at its default it says nothing they did not."""

OMIT_AT = "omit_at"
"""Key of a config field's ``metadata`` (``metadata={OMIT_AT: value}``): the field is left out of :func:`to_mapping`
while it holds ``value``, the one records made before the field existed meant. Why: like :data:`OMIT_AT_DEFAULT`, for
a field whose default has since changed (``SamplingConfig.smoothing_colour``: 0, then 0.08); keyed on the old value,
the old records keep their hashes and the new default is written out, so it never shares a key with them."""


def to_mapping(obj: Any) -> dict:
    """Plain JSON/TOML-able dict of a (nested) config dataclass (fields marked :data:`OMIT_AT_DEFAULT` left out at
    their default, fields marked :data:`OMIT_AT` at their value)."""

    def kept(v: Any, f: dataclasses.Field) -> bool:
        if OMIT_AT in f.metadata:
            return getattr(v, f.name) != f.metadata[OMIT_AT]
        return not (f.metadata.get(OMIT_AT_DEFAULT) and getattr(v, f.name) == f.default)

    def plain(v: Any) -> Any:
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v) if kept(v, f)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return plain(obj)


def check_count(name: str, value: int, minimum: int = 0, where: str = "") -> int:
    """A count from the command line or a config (workers, limit, spp ...) must be >= ``minimum``."""
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        prefix = f"{where}: " if where else ""
        raise ConfigError(f"{prefix}{name}: must be an integer >= {minimum}, got {value!r}")
    return value


def check_size_pair(
    width: int | None,
    height: int | None,
    scene_size: tuple[int, int],
    key: str = "--{}",
    sep: str = " ",
    join: str = " ",
    where: str = "",
) -> None:
    """A ConfigError when only one of an image's width and height is given: the other side would stay the scene's,
    and the images another shape than the scene's.

    Why: ``nlips render --width 160`` rendered 160x480 images (the dome a small disc in a tall black strip), ``nlips
    capture --emulate nlipstac --height 120`` 640x120 ones, and a dataset spec's ``[camera] width = 160`` 160x480
    presses, without a word, and every later command took that odd camera for the sensor's.

    Parameters
    ----------
    width, height : int or None
        The given sides, pixels (None: not given).
    scene_size : (int, int)
        The scene's image size (width, height), pixels, for the line's example.
    key, sep, join : how the line spells a side (``key.format("width")``), a side and its value, and two sides:
        ``--width 160 --height 120`` on the command line, ``width = 160, height = 120`` in a file.
    where : the line's prefix (a file and its section), empty for the command line.
    """
    if (width is None) == (height is None):
        return
    scene_w, scene_h = scene_size
    if width is not None:
        side, value, missing, made = "width", width, "height", f"{width}x{scene_h}"
        pair = (width, max(1, round(width * scene_h / scene_w)))
    else:
        side, value, missing, made = "height", height, "width", f"{scene_w}x{height}"
        pair = (max(1, round(height * scene_w / scene_h)), height)
    both = join.join(f"{key.format(s)}{sep}{v}" for s, v in zip(("width", "height"), pair))
    raise ConfigError(
        f"{where}{key.format(side)}{sep}{value} without {key.format(missing)}: the images would be {made} pixels (the "
        f"scene's other side kept, not its {scene_w}x{scene_h} shape); give both, e.g. {both}"
    )


def is_number(value: object) -> bool:
    """A real number as JSON, TOML or numpy give one (an int, a float, a numpy scalar); ``True`` is not one."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_finite_number(value: object) -> bool:
    """:func:`is_number` and neither NaN nor infinite."""
    return is_number(value) and math.isfinite(value)


def is_whole_number(value: object) -> bool:
    """An integer (a Python or numpy int), not a bool nor a float such as 640.0."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def check_range(
    where: str, value: float, lo: float | None = None, hi: float | None = None, *, open_lo: bool = False
) -> float:
    """``value`` within [lo, hi] (``open_lo``: strictly above lo); else ConfigError naming ``where``."""
    below = lo is not None and (value <= lo if open_lo else value < lo)
    if below or (hi is not None and value > hi) or value != value:
        left = "(" if open_lo else "["
        bounds = f"{left}{'-inf' if lo is None else lo}, {'inf' if hi is None else hi}]"
        raise ConfigError(f"{where}: must be in {bounds}, got {value!r}")
    return value


@contextlib.contextmanager
def options_named(option_of: dict[str, str]) -> Iterator[None]:
    """Inside: a ConfigError whose message starts with a config field's name (as the frozen configs' checks
    word them) is raised again with the command-line option the user typed, e.g. ``max_epochs`` -> ``--epochs``."""
    try:
        yield
    except ConfigError as exc:
        field, _, rest = str(exc).partition(" ")
        raise ConfigError(f"{option_of.get(field, field)} {rest}") from None


def said(name: str, value: object, flag: bool, quoted: bool = False) -> str:
    """An option as its caller gave it: ``--device cuda`` on the command line (``flag``; ``quoted``: the value as
    Python's repr, for a value that may hold spaces), ``device='cuda'`` in Python.

    Why: the API's errors were worded for the command line, and a notebook's ``Predictor(device="cuda")`` was told
    to "use --device cpu", a flag it has no way to give (s36-apileft). A config field's name in a frozen config's
    own check is renamed to its flag by :func:`options_named` instead; this is for a message that names an option
    with its value, and in its remedy too."""
    if not flag:
        return f"{name}={value!r}"
    return f"--{name.replace('_', '-')} {value!r}" if quoted else f"--{name.replace('_', '-')} {value}"


def digest(obj: Any) -> str:
    """Short stable hash of a config (dataclass or JSON-able mapping): what made a result.

    Recorded with results so that a re-run with a changed spec is noticed instead of silently reusing
    the old result. Key order does not matter; floats are hashed by their JSON text.
    """
    import hashlib
    import json

    text = json.dumps(to_mapping(obj) if dataclasses.is_dataclass(obj) else obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def did_you_mean(typed: str, known: Sequence[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``known`` to ``typed``, or an empty string.

    Why: a mistyped word (``--indenter sphre``, ``shape = "hemisphre"`` in a scene file) listed every choice and
    left the user to spot the one meant, where a mistyped command or option named it (``cli.help``)."""
    close = closest(typed, known)
    return f" (did you mean {close!r}?)" if close is not None else ""


def closest(typed: str, known: Sequence[str]) -> str | None:
    """The closest of ``known`` (other than ``typed``) to ``typed`` (:func:`difflib.get_close_matches`, cutoff 0.6),
    or None when none is close."""
    import difflib  # here: only a mistyped word needs it

    close = difflib.get_close_matches(typed, [k for k in known if k != typed], n=1, cutoff=0.6)
    return close[0] if close else None


def check_field_kinds(obj: Any, where: str) -> None:
    """ConfigError "``where``.FIELD: expected ..." for the first field of the config dataclass ``obj`` whose value
    is not of its annotated kind (an int field given 2.5 or "2", a float field "0.1", a flag "no"), as a config
    file's value is checked (:func:`from_mapping`); call it first in ``__post_init__``.

    Why: ``SolverOptions(max_iters=2.5)`` was taken (and ran 2.5 iterations' loop bound), ``SolverOptions(max_iters=
    "2")`` failed in Python's "'<' not supported between instances of 'str' and 'int'" (s38-apikinds)."""
    for name, hint in _field_hints(type(obj)).items():
        value = getattr(obj, name)
        if type(value) is hint or (hint is float and type(value) is int):  # the usual case, at a dict look-up's cost
            continue
        _convert(hint, value, f"{where}.{name}" if where else name)


@functools.cache
def _field_hints(cls: type) -> dict[str, Any]:
    """The annotated kind of each init field of the dataclass ``cls`` (resolved once per class)."""
    hints = typing.get_type_hints(cls)
    return {f.name: hints[f.name] for f in dataclasses.fields(cls) if f.init}


def _convert(tp: Any, value: Any, where: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in (a for a in args if a is not type(None)):
            try:
                return _convert(arg, value, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if len(errors) == 1 else f"{where}: {value!r} matches none of {args}")
    if origin is typing.Literal:
        if value not in args:
            hint = did_you_mean(value, [a for a in args if isinstance(a, str)]) if isinstance(value, str) else ""
            raise ConfigError(f"{where}: must be one of {list(args)}, got {value!r}{hint}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
            return tuple(_convert(a, v, f"{where}[{i}]") for i, (a, v) in enumerate(zip(args, value)))
        item = args[0] if args else typing.Any
        return tuple(_convert(item, v, f"{where}[{i}]") for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, where)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true or false, got {value!r}")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    if (tp is dict or origin is dict) and not isinstance(value, dict):
        # a dataset spec's `render = 16` was taken, and failed (or was dropped) later (s38-apikinds)
        raise ConfigError(f"{where}: expected a table ({{key = value, ...}}), got {value!r}")
    return value
