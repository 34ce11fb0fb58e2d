"""The torch device a command runs on (``--device cpu|cuda|cuda:N``): checked once, before any work, for
``nlips infer``, ``nlips live`` and ``nlips train`` alike."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import TYPE_CHECKING

from ..core.config import said
from ..core.errors import ConfigError, require

if TYPE_CHECKING:  # torch is optional and imported where it is used: named for the hints only
    import torch


def check_device(device: str, flag: bool = False) -> torch.device:
    """The torch device ``device`` names ("cpu", "cuda", "cuda:1"), or ConfigError naming what is missing.

    ``flag``: worded for the command line (``--device cuda``) rather than for a Python caller (``device='cuda'``),
    as :func:`nlipscalib.core.config.said` does."""
    torch = require("torch", "torch", said("device", device, flag))
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError) as exc:
        raise ConfigError(
            f"{said('device', device, flag, quoted=True)}: not a torch device ({exc}); use cpu, cuda or cuda:N"
        ) from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            raise ConfigError(
                f"{said('device', device, flag)}: torch {torch.__version__} sees no CUDA device (a CPU build, or no "
                f"GPU here); use {said('device', 'cpu', flag)}"
            )
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(f"{said('device', device, flag)}: there are {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise ConfigError(f"{said('device', device, flag)}: only cpu and cuda devices are supported")
    return dev


@contextlib.contextmanager
def torch_threads(count: int) -> Iterator[None]:
    """PyTorch's CPU threads set to ``count`` in the block, then back to the process's (0: left as they are).

    Why scoped: the count is the process's, so a library call must not keep its own. A training's count kept would
    make what runs after it (the experiments score their models in the same process) run on another count after a
    training than after reusing its model; a ``Predictor(threads=N)``'s kept would change a notebook's own torch
    work behind its back. Setting the count costs well under a microsecond, so each predict call sets it again."""
    if count <= 0:
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(count)
    try:
        yield
    finally:
        torch.set_num_threads(before)
