"""NLiPsNet in the experiments: models shared by runs that share a work folder."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest

from nlipscalib.core.atomic import write_json
from nlipscalib.core.claims import claim
from nlipscalib.experiments import learning
from nlipscalib.learn import train as train_module
from nlipscalib.learn.train import TrainConfig


def test_a_model_another_run_is_training_is_waited_for_not_trained_twice(tmp_path, monkeypatch):
    """Two `nlips experiment q2` into one --out used to train each model twice over one checkpoint, and each
    report scored whichever model file the other run had written last (two reports, two sets of numbers)."""
    names, stamps, cfg = ["a", "b"], {"a": "1", "b": "2"}, TrainConfig()
    key, path, record = learning.model_files(tmp_path, names, stamps, cfg)
    trained: list[str] = []
    monkeypatch.setattr(train_module, "train", lambda *a, **k: trained.append("again"))
    theirs = {"key": key, "model": str(path.relative_to(tmp_path)), "best_epoch": 4}
    holding = threading.Event()

    def other_run():
        with claim(path) as mine:
            assert mine
            holding.set()
            time.sleep(1.5)  # training
            path.write_bytes(b"model")
            write_json(record, theirs)

    thread = threading.Thread(target=other_run)
    thread.start()
    holding.wait(10)
    got = learning.train_model(None, names, stamps, cfg, tmp_path, progress=False)
    thread.join()
    assert trained == []
    assert got == theirs == json.loads(record.read_text(encoding="utf-8"))


def test_a_model_trained_before_is_reused_and_the_log_says_so(tmp_path, monkeypatch, caplog):
    """A re-run of q2 or presses found its models silently: only the tasks' line said what was reused."""
    names, stamps, cfg = ["a", "b"], {"a": "1", "b": "2"}, TrainConfig()
    key, path, record = learning.model_files(tmp_path, names, stamps, cfg)
    path.parent.mkdir(parents=True)
    path.write_bytes(b"model")
    write_json(record, {"key": key, "model": str(path.relative_to(tmp_path))})
    monkeypatch.setattr(train_module, "train", lambda *a, **k: pytest.fail("trained again"))
    with caplog.at_level("INFO", logger="nlipscalib.experiments.learning"):
        assert learning.train_model(None, names, stamps, cfg, tmp_path, progress=False)["key"] == key
    assert f"{path}: reused" in caplog.text


def test_a_model_trains_on_the_threads_its_key_holds_not_every_core(tmp_path, monkeypatch):
    """`_train` trained on every core of the client whatever the configured count: 2.5-25x slower on a shared
    machine (each small op waits for a descheduled thread), and a model that differs with the core count."""
    from types import SimpleNamespace

    from nlipscalib.core import cpus

    names, stamps, cfg = ["a", "b"], {"a": "1", "b": "2"}, TrainConfig(hidden=(8,))
    used = []

    def fake_train(data, cfg, path, **kwargs):
        used.append(cfg)
        path.write_bytes(b"model")
        return SimpleNamespace(train_presses=["a"], val_presses=["b"], history=[], best_epoch=0)

    monkeypatch.setattr(cpus, "usable_cores", lambda: 7)
    monkeypatch.setattr(train_module, "train", fake_train)
    learning.train_model(SimpleNamespace(names=names), names, stamps, cfg, tmp_path, progress=False)
    assert used == [cfg] and cfg.threads == 1


def test_a_model_is_scored_on_the_threads_it_trained_on_then_the_process_gets_its_count_back(tmp_path, monkeypatch):
    """The reports scored their models on the process's thread count (every core) whatever the training's: on the
    shared 2-core VM 200,000 samples took 1.1-1.7 s of wall on 2 threads against 0.3-0.4 s on 1 (load ~7)."""
    import numpy as np
    import torch

    from nlipscalib.learn import evaluate, model

    seen = []
    monkeypatch.setattr(model, "load_model", lambda path: path)
    monkeypatch.setattr(evaluate, "net_predict", lambda m, pixel, rgb: seen.append(torch.get_num_threads()) or rgb)
    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        predict = learning.net_predictor(tmp_path, {"model": "m.pt"}, threads=1)
        rgb = np.ones((4, 3), np.float32)
        assert predict(np.zeros((4, 2), int), rgb) is rgb and predict(np.zeros((4, 2), int), rgb) is rgb
        assert seen == [1, 1] and torch.get_num_threads() == 3
    finally:
        torch.set_num_threads(before)


def test_a_damaged_figure_crop_is_one_error_naming_it(tmp_path):
    """Q2's NLiPsNet figure read each press's crop with np.load: a crop cut short gave numpy's traceback."""
    from nlipscalib.core.errors import CaptureError
    from nlipscalib.experiments.learning import predicted_views
    from nlipscalib.experiments.tasks import view_path

    path = view_path(tmp_path, "p1")
    path.parent.mkdir(parents=True)
    n = np.zeros((2, 2, 3), np.float32)
    np.savez(path, rgb=n, true=n + [0, 0, -1], origin=np.array([3, 4]))
    [(name, view)] = predicted_views(tmp_path, lambda pixel, rgb: np.tile([0.0, 0.0, -1.0], (len(pixel), 1)), ["p1"])
    assert name == "p1" and np.all(view["error"] == 0)
    path.write_bytes(path.read_bytes()[:100])
    with pytest.raises(CaptureError, match=f"{path}: damaged or truncated figure crop"):
        predicted_views(tmp_path, lambda pixel, rgb: pixel, ["p1"])


def test_the_default_nets_key_is_an_explicit_ratio_runs_and_a_linear_nets_is_as_before(tmp_path):
    """The colour ratio became the default in the thirty-seventh session: the models trained before with an explicit
    ``[net] colour_input = "ratio"`` are the default's (reused, not trained again), and those of linear colours keep
    their keys. The two pinned keys are those ``model_files`` gave at 752fbe70 (ratio explicit, linear the default
    then, both with weight decay 0.2); the decay's default moved to 0.5 later in that session (s37-unseen2), so the
    default's key now equals an explicit ratio run's at 0.5, and the explicit runs at 0.2 keep theirs."""
    names, stamps = ["a", "b"], {"a": "1", "b": "2"}

    def key(**options) -> str:
        return learning.model_files(tmp_path, names, stamps, TrainConfig(**options))[0]

    ratio_05 = key(colour_input="ratio", weight_decay=0.5, reference_smoothing_px=3.0)
    assert key() == ratio_05 != key(colour_input="ratio", weight_decay=0.2, reference_smoothing_px=3.0)
    assert key(colour_input="ratio", weight_decay=0.2, reference_smoothing_px=0.0) == "b67584b93f108c95"
    assert key(colour_input="linear", weight_decay=0.2) == "68a5d7deb43bc6c6"
    assert key(colour_input="linear", weight_decay=0.2, reference_smoothing_px=5.0) == "68a5d7deb43bc6c6"


def test_the_reference_smoothings_default_trains_a_new_net_and_at_zero_reuses_the_thirty_seventh_sessions(tmp_path):
    """The reference's own Gaussian (``TrainConfig.reference_smoothing_px``, 3 px) became the default in the
    thirty-eighth session: the default's key is new (its nets are other nets), and ``reference_smoothing_px = 0``
    gives the key that the default gave before (``c581871dc4f0e76b`` at bc750865), so those nets are reused."""
    names, stamps = ["a", "b"], {"a": "1", "b": "2"}

    def key(**options) -> str:
        return learning.model_files(tmp_path, names, stamps, TrainConfig(**options))[0]

    assert key(reference_smoothing_px=0.0) == "c581871dc4f0e76b" != key()
