"""Versions of the installed libraries that shape a result: recorded in what made it (a result's provenance, a
rendered press's meta.json), compared when a result would be reused, and listed by ``nlips --version``.

Why: a library's release moves numbers (the demo's coin press: 3.82 deg contact AAE with today's NumPy/SciPy/pyamg,
4.05 deg at the lowest supported versions, both before the edge-preserving smoothness of 2026-12-06;
docs/reproducibility.md), and a result made under other versions is not
the one this installation makes. Versions are read from the installed distributions' metadata
(:mod:`importlib.metadata`): nothing is imported for it, and a library that is not installed reads as None.
"""

from __future__ import annotations

import functools
from collections.abc import Iterable
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib import metadata

SOLVE_LIBRARIES = ("numpy", "scipy", "pyamg", "opencv")
"""What shapes an NLiPs result (``nlips solve``): arrays and BLAS (numpy), sparse algebra and filters (scipy), the
multigrid preconditioner (pyamg), the pyramid's resampling and the contact region's filters (opencv)."""
_DEPTH_LIBRARIES = ("scipy", "pyamg")
INFER_LIBRARIES = {
    "torch": ("numpy", "torch", *_DEPTH_LIBRARIES),
    "onnx": ("numpy", "onnxruntime", *_DEPTH_LIBRARIES),
    "onnx-int8": ("numpy", "onnxruntime", *_DEPTH_LIBRARIES),
}
"""What shapes an NLiPsNet result (``nlips infer``), per backend (``Predictor.backend``, resolved from auto): the
network's runtime, and the depth integration's sparse solvers (scipy's SuperLU and transforms, pyamg's AMG for
large regions, learn/integrate_sparse.py) -- recorded with ``--no-depth`` too, which only re-infers once more."""
RENDER_LIBRARIES = ("mitsuba", "drjit")
"""What shapes a rendered press's images (``nlips render``, ``nlips dataset``): the renderer and its JIT."""

DISTRIBUTIONS = {"opencv": ("opencv-python-headless", "opencv-python", "opencv-contrib-python-headless",
                            "opencv-contrib-python")}  # fmt: skip
"""Libraries installed under one of several distribution names (the first installed is read); any other library's
distribution has its own name."""


def library_versions(names: Iterable[str]) -> dict[str, str | None]:
    """``{name: installed version}`` of the libraries ``names`` (None: not installed), in the order given.

    Read from each distribution's metadata, cached per process: ~0.1-0.3 ms per library once its site folder is
    listed (benchmarks/RESULTS.md, s26-provlibs); no library is imported."""
    return {name: installed_version(name) for name in names}


@functools.cache
def installed_version(name: str) -> str | None:
    """The installed version of the library ``name`` (a distribution's name, or a key of :data:`DISTRIBUTIONS`), or
    None when none of its distributions is installed."""
    from importlib import metadata

    for distribution in DISTRIBUTIONS.get(name, (name,)):
        try:
            found = metadata.distribution(distribution)
        except metadata.PackageNotFoundError:
            continue
        return _version_header(found) or found.version
    return None


def _version_header(distribution: metadata.Distribution) -> str | None:
    """The ``Version`` field of ``distribution``'s METADATA, read from its header block (None: not found there).

    Why not ``distribution.version``: it parses the whole file with :mod:`email`, 1-5 ms for a library whose METADATA
    holds its licences and readme (SciPy's: 62 kB), where the header is the first lines (core metadata spec)."""
    text = distribution.read_text("METADATA") or distribution.read_text("PKG-INFO") or ""
    for line in text.splitlines():
        if not line.strip():  # the end of the header block: the description follows
            return None
        if line.startswith("Version:"):
            return line.removeprefix("Version:").strip() or None
    return None
