"""What differs on Windows and macOS, checked on Linux by taking away what those systems lack (s26-portable)."""

from __future__ import annotations

import json
import os
import sys
import types

from nlipscalib.cli.infer import _StageTimes, _write_stream_report
from nlipscalib.device.live import LiveStats


def test_a_stream_report_is_written_where_there_is_no_load_average(tmp_path, monkeypatch):
    """Windows has no os.getloadavg: ``nlips infer CAMERA`` ended its stream with AttributeError, stream.json lost."""
    monkeypatch.delattr(os, "getloadavg")
    model = types.SimpleNamespace(path=tmp_path / "model", hidden=(8,), method="nlipsnet", table=None)
    predictor = types.SimpleNamespace(model=model, backend="cpu")
    _write_stream_report(tmp_path, "camera 0", predictor, LiveStats(frames=3, seconds=1.5), _StageTimes(), 0.3)
    report = json.loads((tmp_path / "stream.json").read_text(encoding="utf-8"))
    assert report["frames"] == 3 and report["load_average"] is None


def test_the_scenes_are_found_where_git_checked_their_link_out_as_a_file(tmp_path):
    """git on Windows without symbolic links writes nlipscalib/scenes as a text file holding ``../scenes``."""
    from nlipscalib.core.sensor import shipped_scenes

    package = tmp_path / "nlipscalib"
    package.mkdir()
    (tmp_path / "scenes").mkdir()
    (package / "scenes").write_text("../scenes", encoding="utf-8")
    assert shipped_scenes(package) == tmp_path / "scenes"
    (package / "scenes").unlink()
    (package / "scenes").mkdir()  # an installed copy wins
    assert shipped_scenes(package) == package / "scenes"


def test_the_shipped_scenes_of_this_checkout_hold_the_default_scene():
    from nlipscalib.core.sensor import SCENES_DIR

    assert (SCENES_DIR / "nlipstac.toml").is_file()


def test_a_mac_counts_as_a_display_without_x11_or_wayland(monkeypatch):
    """macOS names no DISPLAY: ``nlips live`` said "no display" at the Mac's own screen and showed no window."""
    import cv2

    from nlipscalib.report import live

    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    assert live.window_problem() == "no display"  # Linux without X11 or Wayland: a server, a container
    monkeypatch.setattr(sys, "platform", "darwin")
    monkeypatch.setattr(cv2, "namedWindow", lambda *args: None)  # an OpenCV with a GUI (not opened here)
    assert live.window_problem() is None
