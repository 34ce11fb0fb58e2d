import json

import numpy as np

from nlipscalib.cli import main
from nlipscalib.solver import load_result


def test_solve_eval_calibrate_cli(presses, tmp_path, capsys):
    import shutil

    press = tmp_path / "set" / "sphere"
    shutil.copytree(presses["sphere"], press)
    cfg = tmp_path / "solver.toml"
    cfg.write_text("max_iters = 5\n")
    assert main(["solve", str(press), "--config", str(cfg)]) == 0
    out = press / "nlips"
    for name in ("result.npz", "report.json", "normals.png", "depth.png", "residual.png", "error.png"):
        assert (out / name).is_file(), name
    stamp = (out / "result.npz").stat().st_mtime_ns
    assert main(["solve", str(press), "--config", str(cfg)]) == 0  # resumable: skipped
    assert (out / "result.npz").stat().st_mtime_ns == stamp
    capsys.readouterr()
    assert main(["eval", str(tmp_path / "set")]) == 0
    table = capsys.readouterr().out
    assert "AAE" in table and "sphere" in table
    leds = tmp_path / "leds.json"
    assert main(["calibrate-leds", str(presses["none"]), "--out", str(leds), "--stride", "4"]) == 0
    assert len(json.loads(leds.read_text())["leds"]) == 12
    assert (
        main(
            [
                "solve",
                str(press),
                "--leds",
                str(leds),
                "--overwrite",
                "--config",
                str(cfg),
                "--out",
                str(tmp_path / "o"),
            ]
        )
        == 0
    )
    assert np.isfinite(load_result(tmp_path / "o").normals).all()
    assert main(["solve", str(press), "--roi", "1", "2"]) == 2
