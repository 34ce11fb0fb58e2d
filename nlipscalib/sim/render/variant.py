"""Choosing and loading the Mitsuba variant (GPU, LLVM JIT or scalar fallback).

Why a subprocess probe: with an LLVM older than 16 drjit's LLVM backend *aborts the whole process*
(``LLVM ERROR: Cannot select ... fminimum``) on the first render, so the test render runs in a child
process once; the verdict is cached in this module and in ``NLIPS_LLVM_OK`` for child processes.
"""

from __future__ import annotations

import glob
import logging
import os
import subprocess
import sys
from typing import TYPE_CHECKING

from ...core.cpus import usable_cores
from ...core.errors import ConfigError, require

if TYPE_CHECKING:  # mitsuba is loaded at run time in a chosen variant (``load_mitsuba``), passed as ``mi``
    from types import ModuleType

log = logging.getLogger(__name__)

VARIANTS = ("auto", "cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
LLVM_ENV = "NLIPS_LLVM_OK"
INSTALL_HINT = "'nlipscalib[sim]'"
_LLVM_GLOBS = (
    "libLLVM.so.19*",
    "libLLVM-19.so*",
    "libLLVM.so.18*",
    "libLLVM-18.so*",
    "libLLVM.so.17*",
    "libLLVM-17.so*",
    "libLLVM.so.16*",
    "libLLVM-16.so*",
)
_LIB_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib", "/usr/local/lib")
_PROBE = """
import mitsuba as mi
mi.set_variant('llvm_ad_rgb')
s = mi.load_dict({'type': 'scene', 'integrator': {'type': 'direct'}, 'e': {'type': 'point', 'position': [0, 0, 0]},
    'shape': {'type': 'sphere', 'radius': 5.0},
    'sensor': {'type': 'perspective', 'film': {'type': 'hdrfilm', 'width': 4, 'height': 4}}})
import numpy as np
print(float(np.array(mi.render(s, spp=1)).sum()) >= 0)
"""
_state: dict = {}


def find_libllvm() -> str | None:
    """Path of a libLLVM 16..19 shared library, newest first, or None."""
    for pattern in _LLVM_GLOBS:
        for d in _LIB_DIRS + tuple(sorted(glob.glob("/usr/lib/llvm-*/lib"), reverse=True)):
            hits = sorted(glob.glob(os.path.join(d, pattern)))
            if hits:
                return hits[0]
    return None


def _prepare_env() -> None:
    # Must happen before drjit is first imported: drjit reads it when it loads LLVM.
    if "DRJIT_LIBLLVM_PATH" not in os.environ and "drjit" not in sys.modules:
        lib = find_libllvm()
        if lib:
            os.environ["DRJIT_LIBLLVM_PATH"] = lib


def llvm_usable() -> bool:
    """True when a tiny ``llvm_ad_rgb`` render succeeds in a child process (cached)."""
    if LLVM_ENV in os.environ:
        return os.environ[LLVM_ENV] == "1"
    _prepare_env()
    try:
        res = subprocess.run([sys.executable, "-c", _PROBE], capture_output=True, text=True, timeout=120)
        ok = res.returncode == 0 and res.stdout.strip().endswith("True")
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    os.environ[LLVM_ENV] = "1" if ok else "0"
    return ok


def _cuda_usable(mi: ModuleType) -> bool:
    if "cuda_ad_rgb" not in mi.variants():
        return False
    import drjit as dr

    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # any driver trouble means no GPU for us
        return False


def pick_variant(name: str = "auto") -> str:
    """Resolve ``auto`` to cuda_ad_rgb, llvm_ad_rgb or scalar_rgb (with a warning)."""
    if name not in VARIANTS:
        raise ConfigError(f"render.variant must be one of {VARIANTS}, got {name!r}")
    if name != "auto":
        return name
    if "auto" in _state:
        return _state["auto"]
    _prepare_env()
    mi = require("mitsuba", INSTALL_HINT, "Rendering the digital twin")
    if _cuda_usable(mi):
        chosen = "cuda_ad_rgb"
    elif llvm_usable():
        chosen = "llvm_ad_rgb"
    else:
        log.warning("no GPU and no usable LLVM (>= 16) for drjit: rendering with scalar_rgb, ~50x slower")
        chosen = "scalar_rgb"
    _state["auto"] = chosen
    return chosen


def load_mitsuba(variant: str = "auto", threads: int = 0) -> tuple[ModuleType, str]:
    """Import mitsuba, set the variant and thread count, register the workbench plugins.

    Parameters
    ----------
    variant : one of ``VARIANTS``
    threads : worker threads; 0 = all cores

    Returns
    -------
    (mi, variant) : the mitsuba module and the variant now active
    """
    _prepare_env()
    chosen = pick_variant(variant)
    if chosen == "llvm_ad_rgb" and not llvm_usable():
        raise ConfigError("llvm_ad_rgb is not usable here (needs libLLVM 16..19); use variant 'auto' or 'scalar_rgb'")
    mi = require("mitsuba", INSTALL_HINT, "Rendering the digital twin")
    import drjit as dr

    if mi.variant() != chosen:
        mi.set_variant(chosen)
    if threads > 0 and dr.thread_count() != threads:
        dr.set_thread_count(threads)
    elif threads <= 0 and dr.thread_count() != usable_cores():
        dr.set_thread_count(usable_cores())
    from .plugins import register_plugins

    register_plugins(mi)
    return mi, chosen
