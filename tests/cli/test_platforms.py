"""What differs on Windows and macOS, checked on Linux by taking away what those systems lack (s26-portable)."""

from __future__ import annotations

import json
import os
import types

from nlipscalib.cli.infer import _StageTimes, _write_stream_report
from nlipscalib.device.live import LiveStats


def test_a_stream_report_is_written_where_there_is_no_load_average(tmp_path, monkeypatch):
    """Windows has no os.getloadavg: ``nlips infer CAMERA`` ended its stream with AttributeError, stream.json lost."""
    monkeypatch.delattr(os, "getloadavg")
    model = types.SimpleNamespace(path=tmp_path / "model", hidden=(8,))
    predictor = types.SimpleNamespace(model=model, backend="cpu")
    _write_stream_report(tmp_path, "camera 0", predictor, LiveStats(frames=3, seconds=1.5), _StageTimes(), 0.3)
    report = json.loads((tmp_path / "stream.json").read_text(encoding="utf-8"))
    assert report["frames"] == 3 and report["load_average"] is None
