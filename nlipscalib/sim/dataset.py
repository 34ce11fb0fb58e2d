"""Many presses from one spec: a grid (indenters x locations x depths) or a seeded random draw.

The public names of datasets, each from the module that does one job:

- :mod:`.dataset_spec`: the spec (dataclasses, file loading, checks) and its expansion to press jobs;
- :mod:`.dataset_manifest`: ``dataset.json`` and the folder's claim by the runs of one spec;
- :mod:`.dataset_folder`: what the folder already holds (complete, from another spec, damaged, unlisted presses);
- :mod:`.dataset_pool`: rendering the jobs, in parallel and resumably, from several processes at once.
"""

from __future__ import annotations

from .dataset_folder import check_existing, is_complete, warn_unlisted
from .dataset_manifest import (
    FOLDER_CLAIM,
    MANIFEST,
    claim_folder,
    first_press_number,
    manifest_text,
    spec_digest,
    write_manifest,
)
from .dataset_pool import check_space, press_bytes, run_dataset
from .dataset_spec import (
    FIRST_PRESS,
    REFERENCE_NAME,
    DatasetSpec,
    GridSpec,
    PressJob,
    RandomSpec,
    expand_jobs,
    limit_presses,
    load_dataset_spec,
)

__all__ = [
    "FIRST_PRESS",
    "FOLDER_CLAIM",
    "MANIFEST",
    "REFERENCE_NAME",
    "DatasetSpec",
    "GridSpec",
    "PressJob",
    "RandomSpec",
    "check_existing",
    "check_space",
    "claim_folder",
    "expand_jobs",
    "first_press_number",
    "is_complete",
    "limit_presses",
    "load_dataset_spec",
    "manifest_text",
    "press_bytes",
    "run_dataset",
    "spec_digest",
    "warn_unlisted",
    "write_manifest",
]
