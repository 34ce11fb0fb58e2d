"""NLiPsNet: the paper's per-pixel MLP (u, v, r, g, b) -> n, and its model file.

Architecture (Quéau-style NLiPsNet of the NLiPsCalib paper): 5 inputs, hidden layers 256-256-128, each
Linear -> BatchNorm -> ReLU -> Dropout(0.2), a Linear to 3 outputs normalised to unit length.
Smaller variants change ``hidden`` (and train better without dropout, which underfits them: measured
in benchmarks/RESULTS.md).

Input normalisation (inside the network, so PyTorch and ONNX take the same raw inputs):

- u, v: pixel centre coordinates (column, row), mapped to [-1, 1] over the image:
  u_n = (u - (W - 1) / 2) / (W / 2), v_n = (v - (H - 1) / 2) / (H / 2)
- r, g, b: linear tri-colour intensity (``Press.linear``: dark-subtracted, 1 = full scale), low-pass
  filtered over the gel with the file's ``smoothing_px`` (:mod:`.prefilter`; outside the network, as
  it needs the neighbours; with the file's ``smoothing_colour``, if any, it stops at colour edges),
  standardised with the training samples' per-channel mean and deviation. With the file's ``colour_input``
  ``"ratio"`` each filtered colour is first divided by the undeformed reference's, filtered alike, at the same pixel
  (:func:`input_reference`; outside the network, as the prefilter is): the LEDs' fall-off over the image is then
  no part of what the network must learn from (u, v).

The model file (``.pt``, read with ``torch.load(weights_only=True)``: no pickled code) holds the
weights, the architecture, the normalisation, what it was trained on, the sensor it was calibrated
for (camera, image size, LED grouping, sensor levels) and the undeformed reference (tri-colour frame,
dark frame, depth, normals) that inference compares frames with and integrates depth on.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping, Sequence
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import CaptureError, require

if TYPE_CHECKING:  # torch is optional and imported where it is used (``_torch``): named for the hints only
    import torch

    from .lut import LookupTable

MODEL_FORMAT = "nlipscalib.nlipsnet"
MODEL_VERSION = 2
"""The version ``nlips train`` writes: 2 since 2026-12-07 (s42-trainid), whose ``info`` records the capture identities
of the presses it learnt from (``captures``) and its samples' identity (``samples_key``); 1 lacks them."""
MODEL_READ_VERSIONS = (1, 2)
"""The versions :func:`load_model` reads: a version 1 file loads as before (``nlips infer`` then cannot tell a press
it learnt from from another, and `nlips eval` says so)."""
TABLE_FORMAT = "nlipscalib.lut"
"""The lookup-table baseline's model file (:mod:`.lut`, ``nlips lut``): this file's container, a table for weights."""
TABLE_VERSION = 1
PAPER_HIDDEN = (256, 256, 128)
"""Hidden layer widths of the paper's NLiPsNet."""
PAPER_DROPOUT = 0.2
BATCHNORM_EPS = 1e-5
"""BatchNorm's epsilon (torch's default): the layers of :func:`build_net` and their folding (:func:`folded_layers`);
a model file's state holds no epsilon."""


def _torch():
    return require("torch", "torch", "NLiPsNet")


def build_net(
    hidden: Sequence[int] = PAPER_HIDDEN, dropout: float = PAPER_DROPOUT, width: int = 640, height: int = 480
) -> torch.nn.Module:
    """A fresh NLiPsNet (torch.nn.Module) for ``width`` x ``height`` images; forward((N, 5)) -> (N, 3) unit."""
    torch = _torch()
    nn = torch.nn

    class ByteMaskDropout(nn.Dropout):
        """torch.nn.Dropout's rate and scaling, its training mask drawn as uint8 integers.

        On the CPU, torch.nn.Dropout's float Bernoulli draw was the largest cost of a training step after the
        matrix products (about 30 % of the paper's net at batch 1024); integers uniform in [0, m), kept where
        >= k (k / m the rate), cost a third of it (benchmarks/RESULTS.md). The rate is exactly ``p`` when it is
        a fraction with a denominator up to 255 (0.2 = 1 / 5), otherwise the nearest such fraction; kept values
        are scaled by 1 / (1 - k / m), so the expectation is unchanged. The identity in eval mode; drawn from
        torch's global generator (seeded by ``torch.manual_seed``).
        """

        def __init__(self, p: float):
            super().__init__(p)
            rate = Fraction(float(p)).limit_denominator(255)
            self.keep_from, self.draw_below = rate.numerator, rate.denominator
            self.keep_scale = 1.0 / (1.0 - float(rate)) if rate < 1 else 0.0

        def forward(self, x: torch.Tensor):
            if not self.training or self.keep_from == 0:
                return x
            draw = torch.randint(0, self.draw_below, x.shape, dtype=torch.uint8, device=x.device)
            return x * ((draw >= self.keep_from).to(x.dtype) * self.keep_scale)

    class NLiPsNet(nn.Module):
        def __init__(self):
            super().__init__()
            layers, n_in = [], 5
            for n_out in hidden:
                layers += [
                    nn.Linear(n_in, n_out),
                    nn.BatchNorm1d(n_out, eps=BATCHNORM_EPS),
                    nn.ReLU(),
                    ByteMaskDropout(dropout),
                ]
                n_in = n_out
            layers.append(nn.Linear(n_in, 3))
            self.mlp = nn.Sequential(*layers)
            offset = [(width - 1) / 2, (height - 1) / 2, 0.0, 0.0, 0.0]
            scale = [width / 2, height / 2, 1.0, 1.0, 1.0]
            self.register_buffer("in_offset", torch.tensor(offset, dtype=torch.float32))
            self.register_buffer("in_scale", torch.tensor(scale, dtype=torch.float32))

        def forward(self, x: torch.Tensor):
            out = self.mlp((x - self.in_offset) / self.in_scale)
            return out / torch.linalg.vector_norm(out, dim=-1, keepdim=True).clamp_min(1e-8)

    return NLiPsNet()


def folded_layers(state: Mapping[str, torch.Tensor]) -> list[tuple[np.ndarray, np.ndarray]]:
    """The inference form's linear layers, from an NLiPsNet's ``state_dict`` (of :func:`build_net`'s layout).

    The input normalisation folds into the first layer (W' = W / scale, b' = b - W' offset) and each
    eval-mode BatchNorm into the layer before it (W' = s W, b' = s (b - mean) + beta, s = gamma /
    sqrt(var + eps)); dropout is the identity in eval mode. What remains is Linear-ReLU-...-Linear and the
    normalisation to unit length: 25-40 % less work on a frame, the same outputs up to float32 rounding.
    The one copy of the folding: :func:`fused_net` (PyTorch) and the ONNX export (``learn.onnx_export``) run it.

    Folded in float64 with NumPy on the state's arrays: building ``torch.nn.Linear`` layers to hold them, with
    torch's element-wise kernels (slow on a busy machine), cost 25-31 ms of CPU for the paper's net at every
    ``nlips infer`` start, against 1 ms now (benchmarks/RESULTS.md, s27-onnxfast); the same float64 operations in
    the same order, so the same float32 weights.

    Returns
    -------
    list of (W, b) : W (out, in) float32, b (out,) float32; ``x @ W.T + b`` on (N, in) inputs, raw (u, v, r, g, b)
        pixels and linear colours for the first.
    """
    offset, scale = _float64(state["in_offset"]), _float64(state["in_scale"])
    layers = []
    k = 0
    while f"mlp.{4 * k}.weight" in state:  # each hidden width adds Linear, BatchNorm1d, ReLU, dropout (build_net)
        W, b = _float64(state[f"mlp.{4 * k}.weight"]), _float64(state[f"mlp.{4 * k}.bias"])
        if k == 0:
            W = W / scale
            b = b - W @ offset
        norm = f"mlp.{4 * k + 1}."
        if norm + "running_var" in state:  # the last linear layer has no BatchNorm after it
            s = _float64(state[norm + "weight"]) / np.sqrt(_float64(state[norm + "running_var"]) + BATCHNORM_EPS)
            W, b = W * s[:, None], s * (b - _float64(state[norm + "running_mean"])) + _float64(state[norm + "bias"])
        layers.append((W.astype(np.float32), b.astype(np.float32)))
        k += 1
    return layers


def _float64(tensor: torch.Tensor) -> np.ndarray:
    return tensor.detach().cpu().numpy().astype(np.float64)


def fused_net(net: torch.nn.Module) -> torch.nn.Module:
    """The same network in eval mode, its affine steps folded into the linear layers (:func:`folded_layers`).

    Takes an NLiPsNet (:func:`build_net`) and returns a torch.nn.Module: forward((N, 5) raw) -> (N, 3) unit. Its
    layers are the folded weights as buffers run with ``torch.nn.functional.linear`` and ``relu`` (what
    ``nn.Linear`` and ``nn.ReLU`` run), without ``nn.Linear`` modules (each drew random initial weights first).
    """
    torch = _torch()
    functional = torch.nn.functional
    layers = folded_layers(net.state_dict())

    class FusedNLiPsNet(torch.nn.Module):
        def __init__(self):
            super().__init__()
            for k, (W, b) in enumerate(layers):
                self.register_buffer(f"weight{k}", torch.from_numpy(W))
                self.register_buffer(f"bias{k}", torch.from_numpy(b))

        def forward(self, x: torch.Tensor):
            for k in range(len(layers)):
                x = functional.linear(x, getattr(self, f"weight{k}"), getattr(self, f"bias{k}"))
                x = functional.relu(x) if k < len(layers) - 1 else x
            return x / torch.linalg.vector_norm(x, dim=-1, keepdim=True).clamp_min(1e-8)

    return FusedNLiPsNet().eval()


def set_colour_normalisation(net: torch.nn.Module, rgb: np.ndarray) -> None:
    """Standardise r, g, b with the mean and standard deviation of ``rgb`` ((N, 3) float, linear)."""
    torch = _torch()
    mean, std = rgb.mean(0), rgb.std(0) + 1e-6
    with torch.no_grad():
        net.in_offset[2:] = torch.as_tensor(mean, dtype=torch.float32)
        net.in_scale[2:] = torch.as_tensor(std, dtype=torch.float32)


COLOUR_INPUTS = ("linear", "ratio")
"""What a model's r, g, b inputs are (:attr:`learn.train.TrainConfig.colour_input`): the filtered linear colours, or
those over the filtered undeformed reference's at the same pixel (:func:`input_reference`)."""


def input_reference(
    reference: Mapping[str, np.ndarray],
    smoothing_px: float,
    smoothing_colour: float,
    colour_input: str,
    reference_smoothing_px: float = 0.0,
) -> np.ndarray | None:
    """What a model's colours are divided by before the network (:func:`model_inputs`), or None for ``"linear"``.

    Parameters
    ----------
    reference : the undeformed reference arrays (``learn.dataset.reference_arrays``: ``tricolor`` (H, W, 3) linear,
        ``valid`` (H, W) bool), a dataset's or the ones a model file carries
    smoothing_px, smoothing_colour : the samples' prefilter (:class:`.prefilter.Prefilter`)
    colour_input : one of :data:`COLOUR_INPUTS`
    reference_smoothing_px : float, px, optional
        > 0: the reference frame gets a Gaussian of this sigma (normalised over the gel, no colour sigma) instead
        of the samples' prefilter. Why: the undeformed dome's shading is smooth, so its frame's per-pixel noise is
        all the filter needs to take out, and what the samples' 1 px leaves of it is a fixed pattern every press's
        ratio is divided by (:attr:`learn.train.TrainConfig.reference_smoothing_px`). 0: filtered as the samples
        (every model file before the option).

    Returns
    -------
    (H, W, 3) float32 or None: the filtered reference frame, at least
    :data:`~nlipscalib.core.tolerances.MIN_REFERENCE_COLOUR` on the gel and 1 off it (a ratio never divides by 0)
    """
    from ..core.tolerances import MIN_REFERENCE_COLOUR
    from .prefilter import Prefilter

    if colour_input == "linear":
        return None
    valid = np.asarray(reference["valid"]).astype(bool)
    if reference_smoothing_px > 0:
        smoothing_px, smoothing_colour = reference_smoothing_px, 0.0
    filtered = Prefilter(valid, smoothing_px, smoothing_colour)(np.asarray(reference["tricolor"], np.float32))
    return np.where(valid[..., None], np.maximum(filtered, MIN_REFERENCE_COLOUR), 1.0).astype(np.float32)


def model_inputs(pixel: np.ndarray, rgb: np.ndarray, reference: np.ndarray | None = None) -> np.ndarray:
    """(N, 5) float32 network input from pixels ((N, 2) (u, v)) and linear colours ((N, 3)); with ``reference``
    ((H, W, 3) float32, :func:`input_reference`) each colour over the reference's at its pixel (``"ratio"``)."""
    rgb = rgb.astype(np.float32)
    if reference is not None:
        rgb = rgb / reference[pixel[:, 1].astype(np.intp), pixel[:, 0].astype(np.intp)]
    return np.concatenate([pixel.astype(np.float32), rgb], axis=1)


def cosine_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """Mean of 1 - n_hat . n (both (N, 3) unit)."""
    return (1.0 - (pred * target).sum(-1)).mean()


# ---------------------------------------------------------------------- model file
def save_model(
    path: str | Path,
    net: torch.nn.Module,
    *,
    hidden: Sequence[int],
    dropout: float,
    sensor: dict,
    reference: dict,
    info: dict,
    smoothing_px: float = 0.0,
    smoothing_colour: float = 0.0,
    colour_input: str = "linear",
    reference_smoothing_px: float = 0.0,
) -> Path:
    """Write the model file atomically (see module docstring); ``smoothing_px``: the inputs' prefilter sigma,
    ``smoothing_colour`` its colour sigma (written only when > 0: the files of the Gaussian alone stay as they were),
    ``colour_input`` what its colour inputs are (:data:`COLOUR_INPUTS`; written only when not ``"linear"``, so the
    files of linear colours stay as they were), ``reference_smoothing_px`` the sigma of the reference a ratio is
    taken over (:func:`input_reference`; written only when > 0 with the ratio: absent = the samples' prefilter).
    """
    import io

    from ..core.atomic import write_bytes

    torch = _torch()
    payload = {
        "format": MODEL_FORMAT,
        "format_version": MODEL_VERSION,
        "hidden": [int(h) for h in hidden],
        "dropout": float(dropout),
        "state_dict": {k: v.detach().cpu() for k, v in net.state_dict().items()},
        "sensor": sensor,
        "reference": {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in reference.items()},
        "info": info,
        "smoothing_px": float(smoothing_px),
    }
    if smoothing_colour:
        payload["smoothing_colour"] = float(smoothing_colour)
    if colour_input != "linear":
        payload["colour_input"] = str(colour_input)
        if reference_smoothing_px > 0:
            payload["reference_smoothing_px"] = float(reference_smoothing_px)
    buf = io.BytesIO()
    torch.save(payload, buf)
    return write_bytes(path, buf.getvalue())


class LoadedModel:
    """A model file, validated: ``net`` (eval mode), ``sensor``, ``reference`` arrays, ``info``; ``digest``: that
    of the file's bytes these came from (``learn.onnx_export.bytes_digest``; by default, of the file at ``path``
    now), which an ONNX export records and inference checks. A lookup table's file (:data:`TABLE_FORMAT`) has
    ``table`` (:class:`.lut.LookupTable`) and no ``net`` (None)."""

    def __init__(
        self,
        path: str | Path,
        net: torch.nn.Module | None,
        payload: dict,
        digest: str | None = None,
        table: LookupTable | None = None,
    ):
        from .onnx_export import file_digest

        self.path = Path(path)
        self.digest = digest if digest is not None else file_digest(self.path)
        self.net = net
        self.table = table
        """:class:`.lut.LookupTable` of a lookup table's file, else None."""
        self.method = "nlipsnet" if table is None else "lut"
        """The reconstruction method its results are (``core.reconstruction.METHODS``): their folder's name."""
        self.hidden = tuple(payload.get("hidden", ()))  # a table has no layers
        self.sensor: dict = payload["sensor"]
        self.reference: dict = {k: v.numpy() for k, v in payload["reference"].items()}
        self.info: dict = payload["info"]
        self.smoothing_px = float(payload.get("smoothing_px", 0.0))  # files from before the prefilter: raw inputs
        self.smoothing_colour = float(payload.get("smoothing_colour", 0.0))  # the prefilter's colour sigma (0: none)
        self.colour_input: str = payload.get("colour_input", "linear")  # files from before the option: linear
        # files from before the option: the reference filtered as the samples (0)
        self.reference_smoothing_px = float(payload.get("reference_smoothing_px", 0.0))
        self.input_reference = input_reference(
            self.reference, self.smoothing_px, self.smoothing_colour, self.colour_input, self.reference_smoothing_px
        )
        """(H, W, 3) float32 or None: what the colours are divided by before the network (:func:`model_inputs`)."""

    @property
    def shape(self) -> tuple[int, int]:
        cam = self.sensor["camera"]
        return (cam["height"], cam["width"])

    def describe(self) -> str:
        """What it is, for the summary lines: "NLiPsNet 64-64-64", "lookup table 16 levels, 8x8 regions"."""
        if self.table is not None:
            return f"lookup table {self.table.bins} levels, {self.table.cells}x{self.table.cells} regions"
        return f"NLiPsNet {'-'.join(map(str, self.hidden))}"


def load_model(path: str | Path) -> LoadedModel:
    """Load and validate a model file (an NLiPsNet's, or a lookup table's: :data:`TABLE_FORMAT`); every problem is
    one CaptureError naming the file."""
    _torch()
    path = Path(path)
    _check_model_path(path)
    payload, data = _read_torch_bytes(path, _meant_as)  # a damaged file named as what it was meant to be
    if isinstance(payload, dict) and payload.get("format") == TABLE_FORMAT:
        return _load_table(path, payload, data)
    if not isinstance(payload, dict) or payload.get("format") != MODEL_FORMAT:
        raise CaptureError(
            f"{path}: not an NLiPsNet model file (format must be {MODEL_FORMAT!r}, or {TABLE_FORMAT!r} for a lookup "
            "table)"
        )
    if payload.get("format_version") not in MODEL_READ_VERSIONS or isinstance(payload.get("format_version"), bool):
        from ..core.formatfile import version_problem

        remake = "train it again (`nlips train`) on its calibration dataset"
        raise CaptureError(version_problem(path, payload, MODEL_READ_VERSIONS, remake))
    for key in ("hidden", "dropout", "state_dict", "sensor", "reference", "info"):
        if key not in payload:
            raise CaptureError(f"{path}: model file lacks '{key}'")
    cam = _check_container(payload, path, "train it again (`nlips train`) on a calibration dataset that records it")
    hidden, dropout = payload["hidden"], payload["dropout"]
    if not isinstance(hidden, (list, tuple)) or not hidden or any(type(h) is not int or h < 1 for h in hidden):
        raise CaptureError(f"{path}: 'hidden' must list positive layer widths, got {hidden!r}")
    if isinstance(dropout, bool) or not isinstance(dropout, (int, float)) or not 0 <= dropout < 1:
        raise CaptureError(f"{path}: 'dropout' must be in [0, 1), got {dropout!r}")
    if payload.get("colour_input", "linear") not in COLOUR_INPUTS:
        raise CaptureError(
            f"{path}: 'colour_input' must be one of {', '.join(COLOUR_INPUTS)}, got {payload['colour_input']!r}"
        )
    _check_layer_shapes(hidden, payload["state_dict"], path)
    net = build_net(hidden, float(dropout), cam["width"], cam["height"])
    _check_finite_weights(payload["state_dict"], path)
    try:
        net.load_state_dict(payload["state_dict"])
    except (RuntimeError, KeyError, TypeError, AttributeError) as exc:
        raise CaptureError(f"{path}: weights do not fit the architecture ({str(exc).splitlines()[0]})") from None
    net.eval()
    from .onnx_export import bytes_digest

    # the digest of the bytes read, not of the file at the path later: a model published there meanwhile (`nlips
    # train --out`) would otherwise lend its digest to this one's export, which inference then takes as current
    return LoadedModel(path, net, payload, digest=bytes_digest(data))


def _check_container(payload: dict, path: Path, remedy: str) -> dict:
    """The camera of a model file's ``sensor`` once what an NLiPsNet and a lookup table's file share is checked (the
    sensor description, the five reference arrays, ``info``, the prefilter's sigmas); CaptureError naming the file
    otherwise (``remedy``: what makes one that records the sensor). A hand-edited or foreign file: each field named
    here, not as a TypeError deep inside inference."""
    from ..core.errors import ConfigError
    from ..core.sensor_record import check_sensor_record
    from .prefilter import check_colour_sigma, check_sigma

    torch = _torch()
    cam = check_sensor_record(payload["sensor"], path, remedy)["camera"]
    reference = payload["reference"]
    if not isinstance(reference, dict) or not all(isinstance(v, torch.Tensor) for v in reference.values()):
        raise CaptureError(f"{path}: 'reference' must map names to arrays")
    _check_reference(reference, (cam["height"], cam["width"]), path)
    if not isinstance(payload["info"], dict):
        raise CaptureError(f"{path}: 'info' must be a mapping, got {type(payload['info']).__name__}")
    try:  # a bad sigma is named here, not by the prefilter at inference ("prefilter sigma must be ...")
        check_sigma(payload.get("smoothing_px", 0.0), "'smoothing_px'")
        check_colour_sigma(payload.get("smoothing_colour", 0.0), "'smoothing_colour'")
        check_sigma(payload.get("reference_smoothing_px", 0.0), "'reference_smoothing_px'")
    except ConfigError as exc:
        raise CaptureError(f"{path}: {exc}") from None
    return cam


def save_table(
    path: str | Path,
    table: LookupTable,
    *,
    sensor: dict,
    reference: dict,
    info: dict,
    smoothing_px: float = 0.0,
    smoothing_colour: float = 0.0,
) -> Path:
    """Write a lookup table's model file atomically (:data:`TABLE_FORMAT`; docs/formats.md): ``table``
    (:class:`.lut.LookupTable`) as :meth:`~.lut.LookupTable.arrays`, the sensor and reference arrays it was
    calibrated for and the samples' prefilter, as :func:`save_model` writes them."""
    import io

    from ..core.atomic import write_bytes

    torch = _torch()
    entry = {k: torch.from_numpy(v) if isinstance(v, np.ndarray) else v for k, v in table.arrays().items()}
    payload = {
        "format": TABLE_FORMAT,
        "format_version": TABLE_VERSION,
        "table": entry,
        "sensor": sensor,
        "reference": {k: torch.from_numpy(np.ascontiguousarray(v)) for k, v in reference.items()},
        "info": info,
        "smoothing_px": float(smoothing_px),
    }
    if smoothing_colour:
        payload["smoothing_colour"] = float(smoothing_colour)
    buf = io.BytesIO()
    torch.save(payload, buf)
    return write_bytes(path, buf.getvalue())


def _load_table(path: Path, payload: dict, data: bytes) -> LoadedModel:
    """:func:`load_model` of a lookup table's file (:data:`TABLE_FORMAT`), checked alike."""
    from .lut import TABLE_ARRAYS, LookupTable
    from .onnx_export import bytes_digest
    from .prefilter import Prefilter

    torch = _torch()
    if payload.get("format_version") != TABLE_VERSION:
        from ..core.formatfile import version_problem

        remake = "fit it again (`nlips lut`) on its calibration dataset"
        raise CaptureError(version_problem(path, payload, (TABLE_VERSION,), remake))
    for key in ("table", "sensor", "reference", "info"):
        if key not in payload:
            raise CaptureError(f"{path}: lookup-table file lacks '{key}'")
    _check_container(payload, path, "fit it again (`nlips lut`) on a calibration dataset that records it")
    entry = payload["table"]
    if not isinstance(entry, dict) or not all(isinstance(entry.get(k), torch.Tensor) for k in TABLE_ARRAYS):
        raise CaptureError(f"{path}: 'table' must hold the arrays {', '.join(TABLE_ARRAYS)}")
    arrays = {k: v.numpy() if isinstance(v, torch.Tensor) else v for k, v in entry.items()}
    reference = {k: v.numpy() for k, v in payload["reference"].items()}
    valid = reference["valid"].astype(bool)
    smoothing_px, smoothing_colour = float(payload.get("smoothing_px", 0.0)), float(payload.get("smoothing_colour", 0))
    # the colours are binned as differences from the reference filtered as the samples were (CalibrationDataset.
    # filtered_reference): made again from the reference the file carries, not stored twice
    filtered = Prefilter(valid, smoothing_px, smoothing_colour)(reference["tricolor"].astype(np.float32))
    table = LookupTable.from_arrays(arrays, filtered, path)
    return LoadedModel(path, None, payload, digest=bytes_digest(data), table=table)


def model_method(path: str | Path) -> str:
    """ "lut" when ``path`` is a lookup table's model file, else "nlipsnet" (an NLiPsNet's, or no readable model
    file: its load names the problem), told from the file's first pickled strings without unpickling it or
    importing torch (``pickletools`` reads the opcodes alone), so ``nlips infer`` knows where the results go and
    which runtime it records before the model loads. A file cut short (no zip directory) is told from its first
    entry (:func:`_first_entry`)."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            name = next((n for n in archive.namelist() if n.endswith("/data.pkl")), None)
            if name is None or archive.getinfo(name).file_size > PICKLE_READ:
                return "nlipsnet"
            return _method_of_pickle(archive.read(name))
    except zipfile.BadZipFile:  # cut short: its first entry, data.pkl, is still at its start
        try:
            with open(path, "rb") as f:
                return _method_of_pickle(_first_entry(f.read(PICKLE_READ)))
        except OSError:
            return "nlipsnet"
    except (OSError, ValueError, EOFError, KeyError):
        return "nlipsnet"


PICKLE_READ = 1 << 20
"""Most bytes of a model file's pickle (its data.pkl: the keys and small values, the arrays are entries of their
own) :func:`model_method` reads to tell a table's file from a network's."""


def _method_of_pickle(pickle: bytes) -> str:
    """ "lut" when the pickle's first two strings are the payload's first key, "format", and :data:`TABLE_FORMAT`,
    else "nlipsnet"; read with ``pickletools`` (opcodes only, nothing unpickled), up to where a cut pickle ends."""
    import pickletools

    strings = []
    try:
        for op, arg, _ in pickletools.genops(pickle):
            if isinstance(arg, str) and "UNICODE" in op.name:
                strings.append(arg)
                if len(strings) == 2:  # the payload's first key, "format", and its value
                    break
    except (ValueError, EOFError):  # the pickle cut short before them
        pass
    return "lut" if strings == ["format", TABLE_FORMAT] else "nlipsnet"


def _first_entry(data: bytes) -> bytes:
    """The bytes after the first local header of a zip archive's ``data`` when that entry is a ``torch.save``
    pickle (``.../data.pkl``, stored: torch.save's first entry), else b"": what a file cut short (its directory at
    the end lost) still holds. The header's layout is the zip format's (PKWARE APPNOTE 4.3.7): 30 bytes, the name's
    and the extra field's lengths at bytes 26-29."""
    import struct

    if len(data) < 30 or data[:4] != b"PK\x03\x04":
        return b""
    method, (name_len, extra_len) = struct.unpack_from("<H", data, 8)[0], struct.unpack_from("<2H", data, 26)
    name = data[30 : 30 + name_len]
    if method != 0 or not name.endswith(b"/data.pkl"):
        return b""
    return data[30 + name_len + extra_len :]


def _meant_as(data: bytes) -> str:
    """What a model file whose bytes are ``data`` was meant to be, for the error that finds it damaged: a lookup
    table's (told as :func:`model_method` tells it, from a file cut short too) or an NLiPsNet's."""
    import io
    import zipfile

    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            name = next((n for n in archive.namelist() if n.endswith("/data.pkl")), None)
            pickle = archive.read(name)[:PICKLE_READ] if name else b""
    except (zipfile.BadZipFile, OSError, ValueError, EOFError, KeyError):  # cut short, or entries damaged
        pickle = _first_entry(data[:PICKLE_READ])
    return TABLE_FILE if _method_of_pickle(pickle) == "lut" else MODEL_FILE


MODEL_FILE, TABLE_FILE = "an NLiPsNet model file", "a lookup table's file from `nlips lut`"
"""What a model file is meant to be, in the errors that find it damaged (:func:`_read_torch_bytes`)."""


def _check_layer_shapes(hidden: Sequence[int], state: object, path: Path) -> None:
    """CaptureError naming the model file unless each linear layer :func:`build_net` makes of ``hidden`` has its
    weights in ``state`` (the file's ``state_dict``), of the layer's shape: checked before the net is built.

    Why: a file from elsewhere may declare widths its weights do not have; the net of ``hidden`` [20000, 20000]
    took 1.8 GB and 8 s to build before ``load_state_dict`` refused it, and widths of 1e5 would ask for 80 GB
    (docs/formats.md, "Files from others")."""
    torch = _torch()
    n_in = 5
    for i, n_out in enumerate([*hidden, 3]):
        key = f"mlp.{4 * i}.weight"  # each hidden width adds Linear, BatchNorm1d, ReLU, dropout; then the last Linear
        weight = state.get(key) if isinstance(state, dict) else None
        found = tuple(weight.shape) if isinstance(weight, torch.Tensor) else None
        if found != (n_out, n_in):
            raise CaptureError(
                f"{path}: weights do not fit the architecture ('hidden' {list(hidden)} needs {key} of shape "
                f"{(n_out, n_in)}, the file holds {found})"
            )
        n_in = n_out


def _check_finite_weights(state: object, path: Path) -> None:
    """CaptureError naming the model file when a weight is NaN or infinite (a diverged training or a damaged
    file): such a net gives NaN normals, which nothing downstream could tell from a result."""
    torch = _torch()
    if not isinstance(state, dict):
        return  # load_state_dict names the problem
    for name, value in state.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise CaptureError(f"{path}: weights {name!r} are not finite (NaN or inf): train it again")


REFERENCE_ARRAYS = {"tricolor": 3, "dark": 3, "depth": 2, "normals": 3, "valid": 2}
"""The reference arrays inference reads, with their number of dimensions ((H, W, 3) or (H, W))."""


def _check_reference(reference: dict, shape: tuple[int, int], path: Path) -> None:
    """CaptureError naming the model file when a reference array inference reads is missing or not of the
    sensor's image size (a hand-edited or foreign file: else a KeyError or a shape error without the file)."""
    from .dataset import check_reference_values

    for key, ndim in REFERENCE_ARRAYS.items():
        if key not in reference:
            raise CaptureError(f"{path}: 'reference' lacks the array {key!r} (the model file is damaged or foreign)")
        want = shape + (3,) if ndim == 3 else shape
        if tuple(reference[key].shape) != want:
            got = "x".join(map(str, reference[key].shape))
            raise CaptureError(
                f"{path}: 'reference' array {key!r} is {got}, the sensor's images need {'x'.join(map(str, want))}"
            )
    check_reference_values({k: reference[k].numpy() for k in REFERENCE_ARRAYS}, path)


def _check_model_path(path: Path) -> None:
    """CaptureError for a path that is no model file: missing, a folder, or the ONNX export given instead."""
    if path.is_dir():
        models = sorted(p.name for p in path.glob("*.pt") if not p.name.endswith(".checkpoint.pt"))
        hint = f" (it holds {', '.join(models[:5])})" if models else ""
        raise CaptureError(f"{path}: a folder, not a model file: give the .pt file from `nlips train`{hint}")
    if path.is_file() and (model := _model_of_checkpoint(path)) is not None:
        how = "give the model file" if model.is_file() else "run the same `nlips train` again to finish it, then give"
        raise CaptureError(
            f"{path}: a training checkpoint (`nlips train` resumes from it), not the model file: {how} {model}"
        )
    if path.suffix.lower() == ".npz":  # a dataset's sensor.npz or a result.npz given instead: it was "its entries
        # inflate to 672640 bytes from a file of 433899 (torch.save stores them uncompressed)", true but no help
        raise CaptureError(
            f"{path}: a NumPy archive (a calibration dataset's or a result's arrays), not the model file: give the "
            ".pt file from `nlips train`"
        )
    if path.suffix.lower() in (".json", ".toml", ".yaml", ".yml"):  # an LED file given for the model (s34-walk): it
        # was "not an NLiPsNet model file (not a torch.save archive)", naming neither what it is nor what to give
        raise CaptureError(
            f"{path}: a text file ({path.suffix.lower()[1:].upper()}: an LED file, a camera calibration, a config?), "
            "not the model file: give the .pt file from `nlips train`"
        )
    if path.suffix.lower() == ".onnx":  # the export beside the model: it lacks the sensor and reference frame
        beside = path.with_suffix(".pt")
        hint = f" ({beside})" if beside.is_file() else ""
        raise CaptureError(
            f"{path}: the ONNX export, not the model file: give the .pt file from `nlips train`{hint}; the .onnx "
            "beside it is used with --backend onnx (and by default)"
        )
    if not path.is_file():
        raise CaptureError(f"{path}: model file is missing")


def _model_of_checkpoint(path: Path) -> Path | None:
    """The model file a training checkpoint's name belongs to (``MODEL.checkpoint.pt``, a run's
    ``MODEL.<run>.checkpoint.pt``: learn.checkpoint), or None for another name.

    Why: given to `nlips infer` or `nlips export` (it lies beside the model, a ``.pt`` too, and is the only one
    while a training runs or after it was stopped) it was "not an NLiPsNet model file (format must be
    'nlipscalib.nlipsnet')", which told neither what it is nor which file to give."""
    import re

    from .checkpoint import CHECKPOINT_FILE

    stem = re.fullmatch(rf"(.+?)(\.[0-9a-f]{{12}})?\.{re.escape(CHECKPOINT_FILE)}", path.name)
    return path.with_name(f"{stem.group(1)}.pt") if stem else None


def read_torch_file(path: str | Path, what: str) -> object:
    """``torch.load(path, weights_only=True)`` on the CPU; a damaged file is one CaptureError saying how.

    ``what`` names the file the caller expects, with its article ("an NLiPsNet model file").

    torch's own messages for these cases run to several lines and, for a file that is not a checkpoint
    at all, advise loading it with ``weights_only=False`` (running code from the file): never the advice
    here. An empty file, one that is not a ``torch.save`` archive (a zip file), and one cut short (the zip
    directory at its end missing: an interrupted copy) are told apart from its bytes.
    """
    return _read_torch_bytes(path, what)[0]


def _read_torch_bytes(path: str | Path, what: str | Callable[[bytes], str]) -> tuple[object, bytes]:
    """:func:`read_torch_file`, and the bytes it loaded: the file is read once, so both are of one version of it
    even while another process replaces the file. ``what`` may be told from the bytes (:func:`_meant_as`), only
    when an error needs it."""
    import io
    import zipfile

    torch = _torch()
    path = Path(path)
    try:
        data = _read_bounded(path, what if isinstance(what, str) else MODEL_FILE)
    except OSError as exc:
        raise CaptureError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if not data:
        raise CaptureError(f"{path}: empty, not {_named(what, data)} (an interrupted copy?)")
    if data[:4] != b"PK\x03\x04":
        raise CaptureError(f"{path}: not {_named(what, data)} (not a torch.save archive)")
    if not zipfile.is_zipfile(io.BytesIO(data)):
        what = _named(what, data)
        raise CaptureError(f"{path}: truncated or damaged, not usable as {what} (the archive's directory is missing)")
    _check_inflated_size(path, data, what)
    try:
        return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True), data
    except Exception as exc:  # torch raises many kinds (RuntimeError, UnpicklingError, EOFError ...)
        first = (str(exc).strip().splitlines() or [""])[0]
        if "weights_only" in first or "Weights only load failed" in first:
            first = "it holds objects other than tensors and plain data"
        detail = f"{type(exc).__name__}: {first[:160]}" if first else type(exc).__name__
        raise CaptureError(f"{path}: damaged, not usable as {_named(what, data)} ({detail})") from None


def _named(what: str | Callable[[bytes], str], data: bytes) -> str:
    """``what`` in words: as given, or told from the file's bytes ``data`` (:func:`_meant_as`)."""
    return what if isinstance(what, str) else what(data)


def _read_bounded(path: Path, what: str) -> bytes:
    """The file's bytes; CaptureError naming it when it holds more than
    :data:`~nlipscalib.core.tolerances.MAX_TORCH_FILE_BYTES` (said from its size before a byte is read; one growing
    meanwhile is read no further than the limit)."""
    from ..core.tolerances import MAX_TORCH_FILE_BYTES

    with path.open("rb") as f:
        size = os.fstat(f.fileno()).st_size
        # read(n) allocates n bytes first: the stat's size (+1 to see growth), not the limit (4 ms more CPU a read)
        data = f.read(size + 1) if size <= MAX_TORCH_FILE_BYTES else b""
        if len(data) > size:  # grown since the stat (another process writing it): on, to the limit at most
            data += f.read(MAX_TORCH_FILE_BYTES + 1 - len(data))
    if size > MAX_TORCH_FILE_BYTES or len(data) > MAX_TORCH_FILE_BYTES:
        size = max(size, len(data))
        raise CaptureError(
            f"{path}: {size / 2**30:.1f} GiB, more than the {MAX_TORCH_FILE_BYTES / 2**30:.0f} GiB that "
            f"{what} of the largest net at the largest camera size needs: not read (a file from elsewhere?)"
        )
    return data


def _check_inflated_size(path: Path, data: bytes, what: str | Callable[[bytes], str]) -> None:
    """CaptureError naming the file when its zip entries declare more bytes than the file holds.

    torch.save stores its entries uncompressed, but torch.load inflates deflated ones too: a received file of
    64 KB could hold a tensor of 64 MB of zeros (1000:1), and of gigabytes at a few MB (docs/formats.md, "Files
    from others"). Checked from the archive's directory, before torch reads an entry."""
    import io
    import zipfile

    try:
        inflated = sum(entry.file_size for entry in zipfile.ZipFile(io.BytesIO(data)).infolist())
    except (zipfile.BadZipFile, OSError, ValueError) as exc:  # a directory that names impossible entries
        raise CaptureError(f"{path}: damaged, not usable as {_named(what, data)} ({type(exc).__name__})") from None
    if inflated > len(data):
        raise CaptureError(
            f"{path}: its entries inflate to {inflated} bytes from a file of {len(data)} (torch.save stores them "
            f"uncompressed): not usable as {_named(what, data)}"
        )
