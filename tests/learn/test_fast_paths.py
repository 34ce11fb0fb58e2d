"""The speed paths give what the plain formulation gives: folded layers, threaded slices, OpenCV change rule."""

import numpy as np
import pytest

from nlipscalib.core import tolerances
from nlipscalib.learn import change
from nlipscalib.learn.model import PAPER_HIDDEN, build_net, folded_layers, fused_net


def _trained_like_net(hidden=(32, 16)):
    """A net with non-trivial BatchNorm statistics and input normalisation (as after training)."""
    import torch

    torch.manual_seed(0)
    net = build_net(hidden=hidden, dropout=0.2, width=64, height=48)
    with torch.no_grad():
        for m in net.mlp:
            if isinstance(m, torch.nn.BatchNorm1d):
                m.running_mean.uniform_(-1, 1)
                m.running_var.uniform_(0.5, 2)
                m.weight.uniform_(0.5, 1.5)
                m.bias.uniform_(-0.5, 0.5)
        net.in_offset[2:] = torch.tensor([0.2, 0.3, 0.1])
        net.in_scale[2:] = torch.tensor([0.05, 0.08, 0.03])
    return net.eval()


def _inputs(n, seed=1):
    rng = np.random.default_rng(seed)
    return np.column_stack([rng.uniform(0, 64, n), rng.uniform(0, 48, n), rng.uniform(0, 0.5, (n, 3))]).astype(
        np.float32
    )


def test_folded_layers_give_the_same_normals():
    import torch

    net = _trained_like_net()
    x = torch.from_numpy(_inputs(2000))
    with torch.inference_mode():
        a, b = net(x).numpy(), fused_net(net)(x).numpy()
    assert np.abs(a - b).max() < 1e-5


def _module_built_layers(net):
    """(W, b) float32 of each folded layer as fused_net made them up to s27-onnxfast: torch float64 arithmetic on the
    modules, copied into new torch.nn.Linear layers (the oracle the NumPy folding must equal bit for bit)."""
    import torch

    nn = torch.nn
    modules = list(net.mlp)
    linear_at = [i for i, m in enumerate(modules) if isinstance(m, nn.Linear)]
    offset, scale = net.in_offset.double(), net.in_scale.double()
    layers = []
    for k, i in enumerate(linear_at):
        W, b = modules[i].weight.detach().double(), modules[i].bias.detach().double()
        if k == 0:
            W = W / scale
            b = b - W @ offset
        nxt = modules[i + 1] if i + 1 < len(modules) else None
        if isinstance(nxt, nn.BatchNorm1d):
            s = nxt.weight.detach().double() / torch.sqrt(nxt.running_var.double() + nxt.eps)
            W, b = W * s[:, None], s * (b - nxt.running_mean.double()) + nxt.bias.detach().double()
        layer = nn.Linear(W.shape[1], W.shape[0])
        with torch.no_grad():
            layer.weight.copy_(W.float())
            layer.bias.copy_(b.float())
        layers.append((layer.weight.detach().numpy(), layer.bias.detach().numpy()))
    return layers


@pytest.mark.parametrize("hidden", [(32, 16), (64, 64, 64), PAPER_HIDDEN])
def test_the_numpy_folding_equals_the_module_built_layers_bit_for_bit(hidden):
    """folded_layers (NumPy on the state dict: no nn.Linear built) gives the float32 weights the module-built folding
    gave, exactly; and fused_net's forward the normals of nn.Linear layers holding them, exactly (a model's normals
    and depth stay bit-identical on the torch and ONNX backends)."""
    import torch

    net = _trained_like_net(hidden)
    folded, oracle = folded_layers(net.state_dict()), _module_built_layers(net)
    assert (
        [W.shape for W, _ in folded]
        == [W.shape for W, _ in oracle]
        == [(n_out, n_in) for n_in, n_out in zip((5, *hidden), (*hidden, 3))]
    )
    for (W, b), (W_ref, b_ref) in zip(folded, oracle):
        assert W.dtype == b.dtype == np.float32
        np.testing.assert_array_equal(W, W_ref)
        np.testing.assert_array_equal(b, b_ref)
    layers = []
    for k, (W, b) in enumerate(oracle):
        linear = torch.nn.Linear(W.shape[1], W.shape[0])
        with torch.no_grad():
            linear.weight.copy_(torch.from_numpy(W))
            linear.bias.copy_(torch.from_numpy(b))
        layers += [linear, torch.nn.ReLU()] if k < len(oracle) - 1 else [linear]
    x = torch.from_numpy(_inputs(3000))
    with torch.inference_mode():
        out = torch.nn.Sequential(*layers)(x)
        expected = (out / torch.linalg.vector_norm(out, dim=-1, keepdim=True).clamp_min(1e-8)).numpy()
        np.testing.assert_array_equal(fused_net(net)(x).numpy(), expected)


def _sensor(width: int, height: int) -> dict:
    """The default design's sensor description at ``width`` x ``height`` (what a model file records)."""
    import dataclasses

    from nlipscalib.core.capture import SensorResponse
    from nlipscalib.core.sensor import SensorDesign
    from nlipscalib.core.sensor_record import describe_sensor

    design = SensorDesign()
    design = dataclasses.replace(design, camera=dataclasses.replace(design.camera, width=width, height=height))
    return describe_sensor(design.camera_model(), design.led_models(), SensorResponse())


def _reference(width: int, height: int) -> dict:
    """Reference arrays of the sensor's image size (load_model checks them; their values do not matter here)."""
    colour, grey = np.zeros((height, width, 3), np.float32), np.zeros((height, width), np.float32)
    return {"tricolor": colour, "dark": colour, "depth": grey, "normals": colour, "valid": grey > 0}


def test_threaded_slices_equal_one_call(tmp_path):
    from nlipscalib.learn.model import load_model, save_model
    from nlipscalib.learn.onnx_export import OnnxNet, export_onnx

    pytest.importorskip("onnxruntime")
    net = _trained_like_net()
    path = save_model(
        tmp_path / "m.pt",
        net,
        hidden=(32, 16),
        dropout=0.2,
        sensor=_sensor(64, 48),
        reference=_reference(64, 48),
        info={},
    )
    onnx_path = export_onnx(load_model(path), tmp_path / "m.onnx")
    x = _inputs(3 * OnnxNet.MIN_SLICE + 123)
    one, three = OnnxNet(onnx_path, threads=1)(x), OnnxNet(onnx_path, threads=3)(x)
    assert three.shape == (len(x), 3)
    np.testing.assert_array_equal(one, three)  # same rows, same order, same arithmetic


def _scipy_rule(frame, reference, valid):
    """The change rule written with scipy.ndimage, as it was first defined (sums of 2x2 blocks), with its second
    pass on the frame whose per-colour gain over the reference (on the blocks the first pass left unchanged) is
    taken out (rule 3)."""
    from scipy import ndimage

    h2, w2 = valid.shape[0] // 2, valid.shape[1] // 2

    def blocks(a):
        a = a[: 2 * h2, : 2 * w2]
        return a[0::2, 0::2] + a[0::2, 1::2] + a[1::2, 0::2] + a[1::2, 1::2]

    ref_b = blocks(np.where(valid[..., None], reference, 0).astype(np.float32))
    valid_b = blocks(valid.astype(np.float32)) == 4
    sampled = np.flatnonzero(valid_b)[:: change.NOISE_STRIDE]

    def hits(frame_b):
        signed = np.where(valid_b[..., None], frame_b - ref_b, 0)
        smooth = ndimage.uniform_filter(signed, size=(change.SMOOTH_BLOCKS, change.SMOOTH_BLOCKS, 1), mode="nearest")
        diff = np.abs(smooth).sum(-1)
        sample = diff.ravel()[sampled]
        median = float(np.median(sample))
        sigma = 1.4826 * float(np.median(np.abs(sample - median))) + 1e-6
        hit = (
            valid_b
            & (diff > median + tolerances.CHANGE_NOISE_SIGMAS * sigma)
            & (diff > tolerances.CHANGE_MIN_REL * ref_b.sum(-1))
        )
        return ndimage.binary_dilation(ndimage.binary_opening(hit), iterations=change.DILATE_BLOCKS)

    frame_b = blocks(frame.astype(np.float32))
    rest = ~hits(frame_b).ravel()[sampled]
    ratios = np.sort((frame_b.reshape(-1, 3)[sampled] / ref_b.reshape(-1, 3)[sampled])[rest], axis=0)
    gain = np.clip(ratios[len(ratios) // 2], 1 - tolerances.FRAME_CHANNEL_DRIFT, 1 + tolerances.FRAME_CHANNEL_DRIFT)
    hit = hits(frame_b / gain.astype(np.float32))
    out = np.zeros(valid.shape, bool)
    out[: 2 * h2, : 2 * w2] = hit.repeat(2, 0).repeat(2, 1)
    return out & valid


def test_opencv_change_rule_matches_the_scipy_definition():
    """A noisy gel with a dent and a change touching the image border (where border handling matters), its colours
    1 % off the reference's (the rule's second pass)."""
    rng = np.random.default_rng(3)
    H, W = 60, 80
    yy, xx = np.mgrid[0:H, 0:W]
    valid = (yy - 30) ** 2 / 28**2 + (xx - 40) ** 2 / 42**2 < 1.2
    valid[:, :3] = True  # gel reaching the left border
    reference = (0.3 + 0.1 * np.sin(xx / 9)[..., None] * np.array([1, 0.5, 0.2])).astype(np.float32)
    frame = reference * np.float32([0.99, 1.01, 0.995]) + rng.normal(0, 0.004, reference.shape).astype(np.float32)
    frame[(yy - 25) ** 2 + (xx - 45) ** 2 < 64] *= 1.2  # a dent
    frame[20:32, 0:6] *= 0.8  # a change at the border
    got = change.ChangeDetector(reference, valid)(frame)
    want = _scipy_rule(frame, reference, valid)
    assert want.sum() > 100
    assert want[:, :4].any()  # the border change is found
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("p", [0.2, 0.3, 1 / 3])
def test_byte_mask_dropout_keeps_torch_dropouts_rate_scale_and_gradient(p):
    """The training net's dropout: the rate p, kept values scaled by 1 / (1 - p), gradient through the same
    mask, the identity in eval mode, and a torch.nn.Dropout (architecture checks look for one)."""
    import torch

    torch.manual_seed(0)
    dropout = build_net(hidden=(8,), dropout=p, width=64, height=48).mlp[3]
    assert isinstance(dropout, torch.nn.Dropout) and dropout.p == p
    x = torch.full((1000, 1000), 2.0, requires_grad=True)
    out = dropout.train()(x)
    dropped = out == 0
    assert abs(float(dropped.float().mean()) - p) < 0.002  # 1e6 draws: 5 standard deviations
    np.testing.assert_allclose(out[~dropped].detach().numpy(), 2.0 / (1 - p), rtol=1e-6)
    out.sum().backward()
    np.testing.assert_allclose(x.grad.numpy(), (out / 2.0).detach().numpy(), rtol=1e-6)
    assert torch.equal(dropout.eval()(x), x)
