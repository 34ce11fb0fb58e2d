"""``nlips render`` on a tiny image."""

import pytest

pytest.importorskip("mitsuba")

from nlipscalib.cli import main  # noqa: E402
from nlipscalib.core import load_press  # noqa: E402


def test_cli_renders_undeformed_dome(tmp_path, capsys):
    out = tmp_path / "ref"
    rc = main(
        [
            "render",
            "--undeformed",
            "--width",
            "32",
            "--height",
            "24",
            "--spp",
            "1",
            "--threads",
            "2",
            "--seed",
            "4",
            "--out",
            str(out),
        ]
    )
    assert rc == 0
    assert str(out) in capsys.readouterr().out
    p = load_press(out)
    assert p.camera.shape == (24, 32) and p.meta["provenance"]["seed"] == 4
    assert main(["render", "--undeformed", "--width", "32", "--height", "24", "--out", str(out)]) == 2  # exists
