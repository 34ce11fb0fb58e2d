"""The CPU threads a training runs on: 1 unless asked (what is fast on a shared machine and the same on every
machine), ``nlips train --threads`` wins, and the process gets its own count back (exact-data presses, 64x48)."""

import pytest

from nlipscalib.cli import main
from nlipscalib.core import cpus
from nlipscalib.learn import train as train_module
from nlipscalib.learn.dataset import build_dataset
from nlipscalib.pipeline import solve_folder
from nlipscalib.solver import SolverOptions
from tests.solver import synth

NAMES = ("a_sphere", "b_cube")


@pytest.fixture(scope="module")
def calib(tmp_path_factory):
    """A calibration dataset of two exact-data presses, solved with NLiPs."""
    root = tmp_path_factory.mktemp("threads_presses")
    synth.make_press(root / "reference", "none", size=(64, 48))
    for name, kind in zip(NAMES, ("sphere", "cube")):
        synth.make_press(root / name, kind, depth=1.5, size=(64, 48))
        solve_folder(root / name, options=SolverOptions(max_iters=6), figures=False, progress=False)
    out = root / "calib"
    build_dataset([root / n for n in NAMES], root / "reference", out, progress=False)
    return out


@pytest.fixture
def epoch_threads(monkeypatch):
    """The torch thread count of every epoch trained, and the process's count set to 3 beforehand."""
    import torch

    seen: list[int] = []
    epoch = train_module._epoch

    def counted(*args, **kwargs):
        seen.append(torch.get_num_threads())
        return epoch(*args, **kwargs)

    monkeypatch.setattr(train_module, "_epoch", counted)
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    yield seen
    torch.set_num_threads(before)


@pytest.mark.parametrize(("option", "expected"), [((), 1), (("--threads", "2"), 2), (("--threads", "0"), 5)])
def test_nlips_train_runs_on_one_thread_unless_told_and_gives_the_count_back(
    calib, tmp_path, epoch_threads, monkeypatch, option, expected
):
    """Default 1 (every core before: 2.5-25x slower whenever another process held one, and a model that depended
    on the machine's core count); --threads N wins; 0 is every core this process may use."""
    import torch

    monkeypatch.setattr(cpus, "usable_cores", lambda: 5)
    args = ["train", str(calib), "--out", str(tmp_path / "m.pt"), "--hidden", "8", "--epochs", "2"]
    assert main([*args, "--dropout", "0", "--no-onnx", "--no-progress", *option]) == 0
    assert epoch_threads == [expected, expected]
    assert torch.get_num_threads() == 3  # the process's, as before the training


def test_the_default_training_config_is_one_thread():
    from nlipscalib.experiments.q2 import QUICK_NET, Q2Config

    assert train_module.TrainConfig().threads == QUICK_NET.threads == Q2Config().net.threads == 1


def test_a_training_gives_torchs_generator_back_and_takes_the_datasets_path(calib, tmp_path):
    """A notebook's own draws after train() are those it would have had without it (the training seeded torch's
    global generator with the config's seed and left it there), and train() takes the dataset's folder too."""
    import torch

    from nlipscalib.learn.dataset import CalibrationDataset

    cfg = train_module.TrainConfig(hidden=(8,), max_epochs=2, dropout=0.1)
    torch.manual_seed(1234)
    torch.rand(3)
    expected = torch.rand(3)
    torch.manual_seed(1234)
    torch.rand(3)
    by_object = train_module.train(CalibrationDataset(calib), cfg, tmp_path / "a.pt", progress=False)
    assert torch.equal(torch.rand(3), expected) and torch.initial_seed() == 1234
    by_path = train_module.train(str(calib), cfg, tmp_path / "b.pt", progress=False)
    assert by_path.history[-1]["train_loss"] == by_object.history[-1]["train_loss"]
