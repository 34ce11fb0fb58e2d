"""`nlips train --device`: where a training runs (exact-data presses, 64x48, no rendering: seconds).

The GPU itself is checked on a machine with one (``benchmarks/bench_train_step.py --dataset``); here, what a
machine without CUDA says, the CPU's model unchanged, the net moved to the device asked for, and files that
load anywhere.
"""

import logging

import pytest

from nlipscalib.cli import main
from nlipscalib.learn.checkpoint import checkpoint_path
from nlipscalib.learn.dataset import CalibrationDataset
from nlipscalib.learn.train import TrainConfig, _fresh_training, train
from tests.cli.test_bad_input import _one_line_error
from tests.learn.test_resume import _interrupted_after_two_epochs, built, solved  # noqa: F401 (fixtures)

torch = pytest.importorskip("torch")

NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="what a machine without CUDA says")
CFG = TrainConfig(hidden=(8,), dropout=0.2, max_epochs=4, patience=10)


@NO_CUDA
@pytest.mark.parametrize("device", ["cuda", "cuda:1"])
def test_device_cuda_without_one_is_one_line_before_the_dataset_loads(tmp_path, capsys, device):
    """The dataset does not exist: the device is refused first, not after loading ~2M samples."""
    args = ["train", str(tmp_path / "missing"), "--out", str(tmp_path / "m.pt"), "--device", device]
    assert main(args) == 2
    _one_line_error(capsys.readouterr().err, f"--device {device}: torch ", "sees no CUDA device", "use --device cpu")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize(
    ("device", "problem"), [("tpu", "not a torch device"), ("mps", "only cpu and cuda devices are supported")]
)
def test_a_device_other_than_cpu_or_cuda_is_one_line(tmp_path, capsys, device, problem):
    args = ["train", str(tmp_path / "missing"), "--out", str(tmp_path / "m.pt"), "--device", device]
    assert main(args) == 2
    _one_line_error(capsys.readouterr().err, "--device", problem)


def test_device_cpu_trains_the_model_the_default_trains(built, tmp_path):  # noqa: F811
    """Bit for bit: weights, and every epoch's loss and validation figures (dropout on, so the masks count too)."""
    args = ["train", str(built), "--hidden", "8", "--epochs", "3", "--no-onnx", "--no-progress"]
    assert main([*args, "--out", str(tmp_path / "default.pt")]) == 0
    assert main([*args, "--out", str(tmp_path / "cpu.pt"), "--device", "cpu"]) == 0
    default, cpu = (torch.load(tmp_path / f"{n}.pt", weights_only=True) for n in ("default", "cpu"))
    assert default["state_dict"].keys() == cpu["state_dict"].keys()
    for name, weights in default["state_dict"].items():
        assert torch.equal(weights, cpu["state_dict"][name]), name
    timeless = [[{k: v for k, v in h.items() if k != "seconds"} for h in m["info"]["history"]] for m in (default, cpu)]
    assert timeless[0] == timeless[1]
    assert [h["device"] for h in timeless[1]] == ["cpu"] * 3


def test_a_fresh_training_on_a_device_has_its_weights_and_optimiser_there():
    """The net moves before the optimiser is made: Adam's state then lives beside the weights it updates."""
    import numpy as np

    x = np.random.default_rng(0).random((16, 5), dtype=np.float32)
    net, opt, _ = _fresh_training(CFG, {"width": 64, "height": 48}, x, torch.device("meta"))
    assert {t.device.type for t in [*net.parameters(), *net.buffers()]} == {"meta"}
    assert [id(p) for p in opt.param_groups[0]["params"]] == [id(p) for p in net.parameters()]


def _tensors(obj):
    if isinstance(obj, torch.Tensor):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _tensors(v)
    elif isinstance(obj, (list, tuple)):
        for v in obj:
            yield from _tensors(v)


def test_the_model_and_its_checkpoint_hold_cpu_tensors_that_load_without_map_location(built, tmp_path):  # noqa: F811
    out = tmp_path / "net.pt"
    train(CalibrationDataset(built), CFG, out, progress=False, device="cpu")
    for path in (out, checkpoint_path(out)):
        state = torch.load(path, weights_only=True)  # no map_location: a GPU's tensors would load on the GPU
        devices = {t.device.type for t in _tensors(state)}
        assert devices == {"cpu"}, path


def _as_if_trained_on(path, device: str) -> None:
    """Rewrite the checkpoint at ``path`` as a run on ``device`` writes it (CPU tensors, its epochs' device)."""
    state = torch.load(path, weights_only=True)
    for epoch in state["history"]:
        epoch["device"] = device
    torch.save(state, path)


def test_a_checkpoint_of_another_device_resumes_and_says_so(built, tmp_path, monkeypatch, caplog):  # noqa: F811
    """The device is left out of what a checkpoint must match (as the thread count is): a run interrupted on a GPU
    goes on without one, saying that its model will differ from an uninterrupted run's on either device."""
    data, out = CalibrationDataset(built), tmp_path / "net.pt"
    _interrupted_after_two_epochs(monkeypatch, lambda: train(data, CFG, out, progress=False))
    (progress,) = (p for p in tmp_path.glob("net.*.checkpoint.pt") if p != checkpoint_path(out))
    _as_if_trained_on(progress, "cuda")
    caplog.set_level(logging.INFO)
    resumed = train(data, CFG, out, progress=False, device="cpu")
    assert "resuming after epoch 2, trained on cuda so far and on cpu from here" in caplog.text
    assert [h["device"] for h in resumed.history] == ["cuda", "cuda", "cpu", "cpu"]


def test_a_finished_model_of_another_device_is_reused_saying_which_device_made_it(built, tmp_path, capsys):  # noqa: F811
    """Reused (the same options on the same samples: another draw would be no better), never silently: a user who
    asked for one device is told the model came from the other."""
    args = ["train", str(built), "--out", str(tmp_path / "net.pt"), "--hidden", "8", "--epochs", "2", "--no-onnx"]
    assert main([*args, "--no-progress"]) == 0
    capsys.readouterr()
    assert main([*args, "--no-progress"]) == 0
    same = capsys.readouterr().err
    assert "reused" in same and "trained on" not in same
    _as_if_trained_on(checkpoint_path(tmp_path / "net.pt"), "cuda")
    assert main([*args, "--no-progress", "--device", "cpu"]) == 0
    assert "trained on cuda, not cpu (another --out trains on cpu)" in capsys.readouterr().err


@NO_CUDA
def test_trains_device_error_names_its_keyword(tmp_path):
    """From Python the keyword, not the flag: ``device='cuda'`` ... ``use device='cpu'``."""
    from nlipscalib.core.errors import ConfigError

    with pytest.raises(ConfigError, match=r"device='cuda': torch .* sees no CUDA device .*use device='cpu'"):
        train(tmp_path / "missing", CFG, tmp_path / "m.pt", device="cuda")
