"""`nlips live --emulate --model`: an NLiPsNet model file streamed on the emulated sensor."""

import numpy as np
import pytest

pytest.importorskip("mitsuba")
pytest.importorskip("torch")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402

ARGS = ["--emulate", "nlipstac", "--width", "64", "--height", "48"]


def _untrained_model(reference_press, path):
    """A model file for this sensor with an untrained network: enough to test the streaming path."""
    from nlipscalib.learn.dataset import reference_arrays
    from nlipscalib.learn.model import build_net, save_model
    from nlipscalib.learn.sensor import sensor_of

    net = build_net(hidden=(16, 16), dropout=0.0, width=64, height=48)
    sensor, reference = sensor_of(reference_press), reference_arrays(reference_press)
    return save_model(path, net, hidden=(16, 16), dropout=0.0, sensor=sensor, reference=reference, info={})


def test_live_streams_the_emulated_sensor_through_nlipsnet(tmp_path, capsys):
    assert main(["capture", *ARGS, "--presses", "0", "--spp", "1", "--out", str(tmp_path / "s")]) == 0
    reference = load_press(tmp_path / "s" / "reference")
    model = _untrained_model(reference, tmp_path / "net.pt")
    maps = tmp_path / "maps"
    args = ["live", *ARGS, "--model", str(model), "--frames", "6", "--frames-per-press", "3", "--save", str(maps)]
    assert main(args) == 0
    summary = capsys.readouterr().out
    assert "6 frames in" in summary and "fps" in summary
    first = np.load(maps / "frame_000001.npz")  # the undeformed gel: the reference normals where nothing changed
    valid = np.isfinite(reference.reference.depth)
    same = np.all(np.abs(first["normals"] - reference.reference.normals) < 1e-5, axis=-1)
    assert same[valid].mean() > 0.9
    assert len(list(maps.glob("*_normals.png"))) == 6
