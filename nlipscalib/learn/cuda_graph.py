"""Recording a function of fixed-shape tensors once as a CUDA graph, to replay it with new values.

A frame of NLiPsNet inference is ~100 small kernels; launched one by one from Python their overhead is as
long as their arithmetic. ``torch.cuda.CUDAGraph`` records them once and replays them in one launch, reading
and writing the same (static) tensors every time: the caller copies new values into :attr:`Replay.inputs`,
replays, and reads :attr:`Replay.outputs` before the next replay overwrites them.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..core.errors import require

if TYPE_CHECKING:  # torch is optional and imported where it is used: named for the hints only
    import torch

log = logging.getLogger(__name__)

WARM_UP_RUNS = 3
"""Runs on a side stream before recording (cuFFT plans, the allocator's pools), as torch.cuda.graphs requires."""


@dataclasses.dataclass
class Replay:
    """A recorded CUDA graph with its static input and output tensors."""

    graph: object
    """torch.cuda.CUDAGraph"""
    inputs: tuple
    """The tensors (and other arguments) the function was recorded with; copy new values into the tensors."""
    outputs: object
    """What the function returned while recorded: rewritten by every replay."""

    def __call__(self) -> object:
        """Replay; returns :attr:`outputs`."""
        self.graph.replay()
        return self.outputs


def record(function: Callable[..., object], inputs: tuple, device: torch.device, what: str) -> Replay | None:
    """``function(*inputs)`` recorded as a CUDA graph on ``device``; None, with a warning naming ``what``, when this
    torch build cannot record one of its operations (the caller then runs it eagerly, with the same results)."""
    torch = require("torch", "torch", "Recording a CUDA graph")
    try:
        side = torch.cuda.Stream(device)
        side.wait_stream(torch.cuda.current_stream(device))
        with torch.cuda.stream(side):
            for _ in range(WARM_UP_RUNS):
                function(*inputs)
        torch.cuda.current_stream(device).wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph):
            outputs = function(*inputs)
    except RuntimeError as exc:
        log.warning("%s runs without a CUDA graph (slower): %s", what, exc)
        return None
    return Replay(graph, inputs, outputs)
