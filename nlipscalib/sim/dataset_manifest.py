"""A dataset folder's record of its spec: ``dataset.json`` (the whole spec, the scene, every press with its seed),
and the claim by which the runs of one spec hold the folder while they render into it."""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from collections.abc import Iterator
from pathlib import Path

from ..core.atomic import write_if_changed
from .dataset_spec import DatasetSpec, PressJob
from .scene import SceneConfig

log = logging.getLogger(__name__)
MANIFEST = "dataset.json"
FOLDER_CLAIM = "dataset"
"""Target of the folder's claim by the runs of one spec (:func:`claim_folder`): files ``.claim-dataset*`` in it."""


def manifest_text(spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> str:
    """dataset.json's content: what was asked (the whole spec, whatever ``--limit`` renders)."""
    from ..core.config import to_mapping

    data = {
        "spec": to_mapping(spec),
        "scene": scene.to_dict(),
        "presses": [{"name": j.name, "seed": j.seed, "press": to_mapping(j.press)} for j in jobs],
    }
    return json.dumps(data, indent=2) + "\n"


def write_manifest(out: Path, spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> bool:
    """Write dataset.json beside the presses, only if its content changes (read-only re-checks work)."""
    return write_if_changed(out / MANIFEST, manifest_text(spec, scene, jobs))


def first_press_number(out: Path) -> int:
    """The number of the first press in dataset folder ``out``: 0 when it holds a dataset numbered from
    ``press_0000`` (rendered before :data:`.dataset_spec.FIRST_PRESS` was 1: its press folder or its dataset.json
    says so), so that a run resumes it under its own names instead of refusing every press as another spec's;
    else :data:`.dataset_spec.FIRST_PRESS`."""
    from .dataset_spec import FIRST_PRESS

    old = "press_0000"
    if (out / old).is_dir():
        return 0
    try:
        names = {press["name"] for press in json.loads((out / MANIFEST).read_bytes())["presses"]}
    except (OSError, ValueError, KeyError, TypeError):  # no (readable) manifest: a new folder
        return FIRST_PRESS
    return 0 if old in names else FIRST_PRESS


def spec_digest(spec: DatasetSpec, scene: SceneConfig, jobs: list[PressJob]) -> str:
    """What tells one spec's dataset from another's (hex, 16 digits): the manifest, and each press's render hash
    (which also counts the content of an indenter's mesh file, the manifest naming only its path)."""
    from .press import render_spec_hash

    digest = hashlib.sha256(manifest_text(spec, scene, jobs).encode())
    for job in jobs:
        digest.update(render_spec_hash(scene, job.press, job.seed).encode())
    return digest.hexdigest()[:16]


@contextlib.contextmanager
def claim_folder(out: Path, digest: str) -> Iterator[None]:
    """Hold ``out`` for the spec of ``digest`` while the block runs; a ConfigError, before anything is written, when
    a live run of another spec holds it.

    Why: two runs of different specs started together into one folder each published presses before either found
    the other's, and left a dataset of two specs. Runs of one spec share the folder (they split its presses); a
    killed run's claim goes stale (core.claims), and ``--overwrite`` does not pass a live run of another spec (it
    re-renders what a finished run left). A folder that cannot hold a claim file (read-only media, disk full) is
    not claimed: nothing can be published there either, and the checks that follow say why in their own words.
    """
    from ..core.claims import Owner, held_for

    def refusal(other: Owner) -> str:
        return (
            f"{out}: a run of a different spec is rendering into it ({other.who}); wait until it ends, "
            "or render into a new folder"
        )

    with held_for(out / FOLDER_CLAIM, digest, refusal):
        yield
